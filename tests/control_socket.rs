//! The control socket of the real `flowgate run`, against the simulator over real ptys:
//! `flowgate ctl` drives a session (status, arm, goal, start); bad requests get clear errors
//! and change nothing; the socket admits only its owner and group.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::mpsc;
use std::time::Duration;

#[path = "support/lines.rs"]
mod lines;

use flowgate::gateway::core::operator::{Reply, StateName, Status};
use flowgate::gateway::shell::control_client::ControlClient;
use flowgate::lab::Scenario;
use lines::{await_line, lines};

fn flowgate() -> Command {
    Command::new(env!("CARGO_BIN_EXE_flowgate"))
}

fn ctl(socket: &Path, args: &[&str]) -> Output {
    flowgate().args(["ctl", "--socket"]).arg(socket).args(args).output().unwrap()
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// One raw request line (whatever its bytes), one reply.
fn raw(socket: &Path, line: &[u8]) -> Reply {
    let mut s = UnixStream::connect(socket).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    s.write_all(line).unwrap();
    let mut reply = String::new();
    BufReader::new(&s).read_line(&mut reply).unwrap();
    serde_json::from_str(&reply).unwrap_or_else(|e| panic!("{e}: {reply}"))
}

/// The gateway's status, through the client `flowgate ctl` uses.
fn status_of(socket: &Path) -> Status {
    ControlClient::connect(socket).unwrap().status().unwrap()
}

/// A running `flowgate run --config CONFIG` and its output lines, once its control socket
/// is up and the controller streams (its log goes on being read, so its stderr never fills).
struct Gateway {
    child: std::process::Child,
    out: mpsc::Receiver<String>,
}

fn run_gateway(config: &Path) -> Gateway {
    let mut child = flowgate()
        .args(["run", "--config"])
        .arg(config)
        .env("RUST_LOG", "flowgate=info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let out = lines(child.stdout.take().unwrap());
    let log = lines(child.stderr.take().unwrap());
    let mut seen = Vec::new();
    await_line(&log, "control socket", &mut seen);
    // An arm is refused until the controller streams: wait for it, as an operator would.
    if !seen.iter().any(|l| l.contains("PSD controller streaming")) {
        await_line(&log, "PSD controller streaming", &mut seen);
    }
    Gateway { child, out }
}

/// E1's simulator over real ptys, and in a new directory `flowgate-NAME-PID` a rig config
/// pointed at it (goals from the operator, a control socket, telemetry there).
async fn e1_rig(name: &str) -> (flowgate_sim::rig::RigHandle, PathBuf, PathBuf) {
    e1_rig_with(name, &[]).await
}

/// The same, the simulator given `faults` (key=value).
async fn e1_rig_with(name: &str, faults: &[&str]) -> (flowgate_sim::rig::RigHandle, PathBuf, PathBuf) {
    let s = Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let mut rig = flowgate_sim::rig::RigConfig::new(s.sim.clone());
    let settings: Vec<String> = faults.iter().map(|f| f.to_string()).collect();
    rig.faults = rig.faults.with_settings(&settings).unwrap();
    let handle = flowgate_sim::rig::start(rig).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
    let dir: PathBuf = std::env::temp_dir().join(format!("flowgate-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
    let socket = dir.join("control.sock");
    let mut cfg = s.rig_file(&handle.psd_path, &can, Some(dir.join("telemetry")));
    cfg.goal = None; // goals come from the operator
    cfg.operator.socket = Some(socket.clone());
    std::fs::write(dir.join("rig.toml"), cfg.to_toml()).unwrap();
    (handle, dir, socket)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_operator_session_over_the_control_socket() {
    let (handle, dir, socket) = e1_rig("ctl").await;
    let Gateway { mut child, out } = run_gateway(&dir.join("rig.toml"));
    let mut seen = Vec::new();

    // Idle: nothing moves until asked.
    let status = ctl(&socket, &["status"]);
    assert!(status.status.success() && text(&status).contains("state      idle"), "{}", text(&status));
    assert_eq!(std::fs::metadata(&socket).unwrap().permissions().mode() & 0o777, 0o660);

    // Bad requests: a clear error each, and nothing changes.
    let malformed = raw(&socket, b"{\"cmd\":\n");
    assert!(malformed.error.unwrap().starts_with("malformed request"));
    let unknown = raw(&socket, b"{\"cmd\":\"fly\"}\n");
    assert!(unknown.error.unwrap().contains("unknown variant `fly`"));
    let mut long = vec![b' '; 5000];
    long.push(b'\n');
    let oversized = raw(&socket, &long);
    assert_eq!(oversized.error.unwrap(), "request longer than 4096 bytes: ignored");
    let refused = ctl(&socket, &["start"]);
    assert!(
        !refused.status.success() && text(&refused).contains("refused: not armed (state idle)"),
        "{}",
        text(&refused)
    );
    // Await the first pose and obstacle estimate (the controller's first frames).
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while status_of(&socket).obstacles.is_empty() {
        assert!(std::time::Instant::now() < deadline, "no obstacle estimate within 10 s");
    }
    let inside = ctl(&socket, &["goal", "0.0", "0.02"]);
    assert!(!inside.status.success(), "{}", text(&inside));
    assert_eq!(status_of(&socket).state.name, StateName::Idle);
    // An implausible tolerance is refused; negative coordinates in a queue are coordinates.
    let wide = ctl(&socket, &["goal", "0.35", "0.05", "--tolerance", "1e300"]);
    assert!(!wide.status.success() && text(&wide).contains("tolerance 1e300 m: at most 1 m"), "{}", text(&wide));
    let queue = ctl(&socket, &["goal", "--queue", "-0.2,-0.05", "0.35,0.05"]);
    assert!(
        queue.status.success() && text(&queue).contains("goals      (-0.2, -0.05) then (0.35, 0.05)"),
        "{}",
        text(&queue)
    );

    // A flooding client is served at most once per 10 ms, on its own connection.
    let mut flood = UnixStream::connect(&socket).unwrap();
    let started = std::time::Instant::now();
    flood.write_all(&b"{\"cmd\":\"status\"}\n".repeat(20)).unwrap();
    let mut replies = BufReader::new(&flood);
    for _ in 0..20 {
        let mut reply = String::new();
        replies.read_line(&mut reply).unwrap();
        assert!(reply.contains("\"ok\":true"), "{reply}");
    }
    assert!(started.elapsed() >= Duration::from_millis(190), "{:?}", started.elapsed());

    // Only the owner and the group: another user is refused by the socket's permissions.
    if std::fs::metadata("/proc/self").unwrap().uid() == 0 {
        let other = Command::new("setpriv")
            .args([
                "--reuid=65534",
                "--regid=65534",
                "--clear-groups",
                env!("CARGO_BIN_EXE_flowgate"),
                "ctl",
                "--socket",
            ])
            .arg(&socket)
            .arg("status")
            .output()
            .unwrap();
        assert!(!other.status.success(), "{}", text(&other));
        assert!(text(&other).contains("Permission denied"), "{}", text(&other));
    }

    // The session: arm, a goal, start; the robot drives there and stops.
    for args in [&["arm"][..], &["goal", "0.35", "0.05"], &["start"]] {
        let o = ctl(&socket, args);
        assert!(o.status.success(), "{args:?}: {}", text(&o));
    }
    await_line(&out, "state: running", &mut seen);
    await_line(&out, "state: stopped: goal reached", &mut seen);
    let done = ctl(&socket, &["status"]);
    assert!(text(&done).contains("last stop  goal reached"), "{}", text(&done));
    assert!(text(&done).contains("latency    p50 "), "{}", text(&done));

    // Where the time goes: every stage, then a new window that holds no cycle yet (the
    // robot stands at its goal, no commands are computed).
    let stats = ctl(&socket, &["stats", "--reset"]);
    for stage in ["decode", "checks", "track", "plan", "encode", "can_write"] {
        assert!(text(&stats).lines().any(|l| l.contains(stage)), "{stage}: {}", text(&stats));
    }
    let window = ControlClient::connect(&socket).unwrap().stats(false).unwrap();
    assert!(window.latency_us.is_none(), "{window:?}");
    let stages = window.stages.as_ref().unwrap();
    assert_eq!(stages.len(), 6);
    assert!(stages.iter().all(|s| s.max_us == 0.0), "{window:?}");
    // `status` carries no stage table, and the run's latency still counts every cycle.
    let now = status_of(&socket);
    assert!(now.stages.is_none() && now.latency_us.is_some(), "{now:?}");

    let _ = Command::new("kill").arg("-INT").arg(child.id().to_string()).status();
    assert!(child.wait().unwrap().success());
    let truth = handle.stop().await;
    let end = truth.summary.final_position;
    assert!((end[0] - 0.35).hypot(end[1] - 0.05) < 0.03, "{end:?}");
    assert!(truth.summary.first_contact.is_none());
    // Who asked what, in the telemetry.
    let events = std::fs::read_to_string(dir.join("telemetry/latest/events.jsonl")).unwrap();
    assert!(events.contains("uid 0") || events.contains("uid "), "{events}");
    assert!(events.contains("Start accepted") && events.contains("refused: not armed"), "{events}");
    // One JSON object a line.
    for line in events.lines() {
        let event: serde_json::Value = serde_json::from_str(line).unwrap_or_else(|e| panic!("{e}: {line}"));
        assert!(event["t_s"].is_f64() && event["text"].is_string(), "{line}");
    }
    // The run's report covers the whole run, whatever windows the operator started.
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("telemetry/latest/report.json")).unwrap()).unwrap();
    assert!(report["counters"]["cycles"].as_u64().unwrap() > 0, "{report}");
    assert!(report["stages"].as_array().unwrap().iter().all(|s| s["max_us"].as_f64().unwrap() > 0.0), "{report}");
    assert!(!socket.exists(), "the socket is removed at exit");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The operator session of docs/operating.md, as written: `rig.example.toml` (two obstacle LEDs, of
/// which E1 has one: LED 4 is never seen and is absent, not a fault) pointed at the
/// simulator's ptys, driven with `flowgate ctl --config`, from idle through a refused start
/// and a refused goal to a queue of two goals reached.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_documented_operator_session_reaches_its_goals() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let s = Scenario::load(&root.join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let handle = flowgate_sim::rig::start(flowgate_sim::rig::RigConfig::new(s.sim.clone())).await.unwrap();
    let dir: PathBuf = std::env::temp_dir().join(format!("flowgate-session-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut rig: toml_edit::DocumentMut =
        std::fs::read_to_string(root.join("rig.example.toml")).unwrap().parse().unwrap();
    rig["serial"]["port"] = toml_edit::value(handle.psd_path.display().to_string());
    rig["can"]["endpoint"] =
        toml_edit::value(format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display()));
    rig["operator"]["socket"] = toml_edit::value(dir.join("control.sock").display().to_string());
    rig["telemetry"]["out_dir"] = toml_edit::value(dir.join("out").display().to_string());
    let config = dir.join("rig.toml");
    std::fs::write(&config, rig.to_string()).unwrap();
    let Gateway { mut child, out } = run_gateway(&config);
    let mut seen = Vec::new();
    let ctl = |args: &[&str]| {
        let o = flowgate().args(["ctl", "--config"]).arg(&config).args(args).output().unwrap();
        (o.status.success(), text(&o))
    };

    // Idle, with the obstacle E1 has tracked and the one it has not listed as not in view.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let status = loop {
        let (ok, status) = ctl(&["status"]);
        assert!(ok, "{status}");
        if status.contains("obstacle LED 3 at") {
            break status;
        }
        assert!(std::time::Instant::now() < deadline, "no obstacle estimate within 10 s: {status}");
    };
    assert!(status.contains("state      idle") && status.contains("not in view LED 4"), "{status}");
    let (ok, start) = ctl(&["start"]);
    assert!(!ok && start.contains("refused: not armed (state idle): arm first"), "{start}");
    let (ok, arm) = ctl(&["arm"]);
    assert!(ok && arm.contains("state      armed"), "{arm}");
    let (ok, inside) = ctl(&["goal", "0.0", "0.02"]);
    assert!(!ok && inside.contains("inside obstacle LED 3's planning circle"), "{inside}");
    let (ok, queue) = ctl(&["goal", "--queue", "0.35,-0.25", "0.35,0.05"]);
    assert!(ok && queue.contains("goals      (0.35, -0.25) then (0.35, 0.05)"), "{queue}");
    let (ok, start) = ctl(&["start"]);
    assert!(ok, "{start}");
    await_line(&out, "state: running", &mut seen);
    await_line(&out, "state: stopped: goal reached", &mut seen);
    let (_, done) = ctl(&["status"]);
    assert!(done.contains("state      stopped: goal reached") && done.contains("goals      -"), "{done}");
    // `ctl status | true`: ended quietly, never a panic.
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let closed = flowgate().args(["ctl", "--config"]).arg(&config).arg("status").stdout(writer).output().unwrap();
    assert_eq!(closed.status.code(), Some(141), "{}", String::from_utf8_lossy(&closed.stderr));
    assert!(!seen.iter().any(|l| l.contains("fault")), "{seen:#?}");

    let _ = Command::new("kill").arg("-INT").arg(child.id().to_string()).status();
    assert!(child.wait().unwrap().success());
    let truth = handle.stop().await;
    let end = truth.summary.final_position;
    assert!((end[0] - 0.35).hypot(end[1] - 0.05) < 0.03, "{end:?}");
    assert!(truth.summary.first_contact.is_none());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A gateway killed outright (SIGKILL, as a service manager's watchdog does) leaves its
/// events on disk: they are flushed at every drain of the telemetry queue, not at exit.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn events_survive_a_sigkill() {
    let (handle, dir, socket) = e1_rig("kill").await;
    let Gateway { mut child, .. } = run_gateway(&dir.join("rig.toml"));
    let arm = ctl(&socket, &["arm"]);
    assert!(arm.status.success(), "{}", text(&arm));
    // The event reaches the file while the gateway runs (within a drain or two).
    let events = dir.join("telemetry/latest/events.jsonl");
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while !std::fs::read_to_string(&events).unwrap_or_default().contains("Arm accepted") {
        assert!(std::time::Instant::now() < deadline, "the arm's event never reached {}", events.display());
        std::thread::sleep(Duration::from_millis(5)); // polling the file, bounded by the deadline
    }
    child.kill().unwrap();
    child.wait().unwrap();
    handle.stop().await;
    let text = std::fs::read_to_string(&events).unwrap();
    assert!(text.contains("Arm accepted"), "{text}");
    for line in text.lines() {
        serde_json::from_str::<serde_json::Value>(line).unwrap_or_else(|e| panic!("{e}: {line}"));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The gateway's warnings reach the durable log with their time and fields, as its state
/// changes do: a time sync the controller's clock answered 80 ms off is refused and noted,
/// and `flowgate record events --level warning` shows it, and not the run's info.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn warnings_reach_the_durable_log() {
    let (handle, dir, _socket) = e1_rig_with("notices", &["sync_reply_step=[1.0, 80.0]"]).await;
    let Gateway { mut child, .. } = run_gateway(&dir.join("rig.toml"));
    let events = dir.join("telemetry/latest/events.jsonl");
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    while !std::fs::read_to_string(&events).unwrap_or_default().contains("clock_step_refused") {
        assert!(std::time::Instant::now() < deadline, "no refused time sync in {}", events.display());
        std::thread::sleep(Duration::from_millis(20)); // polling the file, bounded by the deadline
    }
    let _ = Command::new("kill").arg("-INT").arg(child.id().to_string()).status();
    assert!(child.wait().unwrap().success());
    handle.stop().await;
    let text = std::fs::read_to_string(&events).unwrap();
    let lines: Vec<serde_json::Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let step = lines.iter().find(|e| e["kind"] == "clock_step_refused").unwrap();
    assert_eq!(step["level"], "warning", "{step}");
    assert!(step["t_s"].as_f64().unwrap() > 0.5, "{step}");
    assert!(step["fields"]["step_us"].as_i64().unwrap().abs() > 50_000, "{step}");
    assert!(step["text"].as_str().unwrap().starts_with("time sync refused: the controller's clock moved"), "{step}");
    // The controller's start and the obstacle coming into view are there too, as info.
    assert!(lines.iter().any(|e| e["kind"] == "streaming" && e["level"] == "info"), "{text}");
    assert!(lines.iter().any(|e| e["kind"] == "obstacle_entered" && e["fields"]["led"] == 3), "{text}");

    let shown = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["record", "events", dir.join("telemetry/latest").to_str().unwrap(), "--level", "warning"])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&shown.stdout);
    assert!(shown.status.success(), "{out}{}", String::from_utf8_lossy(&shown.stderr));
    assert!(out.lines().any(|l| l.contains("warning") && l.contains("clock_step_refused")), "{out}");
    assert!(!out.contains("streaming") && !out.contains("obstacle_entered"), "{out}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Seconds since the Unix epoch, as can.log stamps its frames.
fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_secs_f64()
}

/// Nobody on the control socket can deny the operator's stop. While the robot drives, other
/// clients hold eight idle connections, four half-open ones (a request begun and never
/// finished) and a flood of requests on another; `ctl` still works, and an `estop` from a
/// new connection puts the e-stop frame on CAN within 100 ms of the request's write.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_client_can_deny_the_operators_estop() {
    const ESTOP_BOUND_S: f64 = 0.100;
    let (handle, dir, socket) = e1_rig("deny").await;
    let Gateway { mut child, out } = run_gateway(&dir.join("rig.toml"));
    let mut seen = Vec::new();
    let hold = |n: usize, begun: &[u8]| -> Vec<UnixStream> {
        (0..n)
            .map(|_| {
                let mut s = UnixStream::connect(&socket).unwrap();
                s.write_all(begun).unwrap();
                s
            })
            .collect()
    };
    let _idle = hold(8, b"");
    let _half_open = hold(4, b"{\"cmd\":");
    let stop_flood = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flood = std::thread::spawn({
        let (socket, stop) = (socket.clone(), stop_flood.clone());
        move || {
            let mut answered = 0u32;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                let Ok(mut s) = UnixStream::connect(&socket) else { continue };
                s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
                let mut replies = BufReader::new(s.try_clone().unwrap());
                for _ in 0..50 {
                    if s.write_all(b"{\"cmd\":\"status\"}\n").is_err() {
                        break;
                    }
                    let mut reply = String::new();
                    if replies.read_line(&mut reply).unwrap_or(0) == 0 {
                        break;
                    }
                    answered += 1;
                }
            }
            answered
        }
    });
    // The operator's session goes on around them, each request a new connection.
    for args in [&["arm"][..], &["goal", "0.35", "0.05"], &["start"]] {
        let o = ctl(&socket, args);
        assert!(o.status.success(), "{args:?}: {}", text(&o));
    }
    await_line(&out, "state: running", &mut seen);
    // More idle connections, to fill the cap again just before the stop.
    let _idle_again = hold(8, b"");
    let mut estop = UnixStream::connect(&socket).unwrap();
    estop.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let written_at = unix_now();
    estop.write_all(b"{\"cmd\":\"estop\"}\n").unwrap();
    let mut reply = String::new();
    BufReader::new(&estop).read_line(&mut reply).unwrap();
    assert!(reply.contains("\"ok\":true"), "{reply}");
    await_line(&out, "state: fault: operator emergency stop", &mut seen);
    stop_flood.store(true, std::sync::atomic::Ordering::Relaxed);
    assert!(flood.join().unwrap() > 0, "the flood was served too, on its own connections");
    // `ctl` still answers, and says what stopped the robot.
    let status = ctl(&socket, &["status"]);
    assert!(text(&status).contains("state      fault: operator emergency stop"), "{}", text(&status));

    let _ = Command::new("kill").arg("-INT").arg(child.id().to_string()).status();
    assert!(child.wait().unwrap().success());
    handle.stop().await;
    // The board's e-stop frame (0x001, reason operator), as the gateway wrote it on CAN.
    let can = std::fs::read_to_string(dir.join("telemetry/latest/can.log")).unwrap();
    let stop_at = can
        .lines()
        .filter(|l| l.ends_with(" 001#01"))
        .filter_map(|l| l.strip_prefix('(')?.split(')').next()?.parse::<f64>().ok())
        .find(|&t| t >= written_at)
        .unwrap_or_else(|| panic!("no e-stop frame after the request in can.log"));
    println!("e-stop frame on CAN {:.2} ms after the request's write", (stop_at - written_at) * 1e3);
    assert!(
        stop_at - written_at < ESTOP_BOUND_S,
        "e-stop on CAN {:.1} ms after the request",
        (stop_at - written_at) * 1e3
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("telemetry/latest/report.json")).unwrap()).unwrap();
    // Every idle and half-open connection was closed: to make room, or for its silence.
    let closed = |k: &str| report["counters"][k].as_u64().unwrap();
    assert!(closed("control_clients_evicted") + closed("control_clients_timed_out") >= 12, "{report}");
    let _ = std::fs::remove_dir_all(&dir);
}
