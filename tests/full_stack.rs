//! Simulator and gateway together over real ptys (SLCAN on a pty for CAN) and the real
//! binaries, judged by the simulator's world truth, never by the gateway's belief. These run
//! in real time: the demo command, SIGINT to `flowgate run`, the exclusive serial port, and
//! the serial device vanishing. Every other fault, and the paper's runs, are tested in
//! deterministic virtual time (tests/virtual_stack.rs).

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use flowgate::gateway::core::State;
use flowgate::lab::Scenario;
use flowgate_sim::truth::TruthRecord;

fn scenario(name: &str) -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)).unwrap()
}

/// E2 through `flowgate demo --drive cia402`: the simulator's two CiA 402 drives over an
/// SLCAN pty, configured by SDO, started by NMT and commanded by RPDO, reach the goal.
#[test]
fn e2_through_the_demo_with_cia402_drives() {
    let out = std::env::temp_dir().join(format!("flowgate-demo-cia402-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let result = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["demo", "--drive", "cia402", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(result.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&result.stderr));
    assert!(stdout.contains("CiA 402 drives") && stdout.contains("goal reached, no contact"), "{stdout}");
    let can = std::fs::read_to_string(out.join("can.log")).unwrap();
    let count = |prefix: &str| can.lines().filter(|l| l.contains(&format!(" slcan0 {prefix}"))).count();
    // Both drives: 30 configuration writes each, an NMT start each, and an RPDO a cycle each
    // with controlword enable operation (0x000F).
    assert_eq!((count("601#"), count("602#")), (30, 30), "SDO writes");
    assert_eq!((count("000#0101"), count("000#0102")), (1, 1), "NMT starts");
    let cycles = std::fs::read_to_string(out.join("cycles.csv")).unwrap().lines().count() - 1;
    assert!(count("201#0F00") >= cycles && count("202#0F00") >= cycles, "{cycles} cycles");
    assert_eq!(count("101#"), 0, "no PCL-80K-like velocity frame");
    let _ = std::fs::remove_dir_all(&out);
}

/// E2 through the `flowgate demo` command a newcomer runs: it succeeds and writes its files.
#[test]
fn e2_through_the_demo_command() {
    let out = std::env::temp_dir().join(format!("flowgate-demo-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let result = Command::new(env!("CARGO_BIN_EXE_flowgate")).args(["demo", "--out"]).arg(&out).output().unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(result.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&result.stderr));
    assert!(stdout.contains("goal reached, no contact"), "{stdout}");
    assert!(stdout.contains("e2e latency"), "{stdout}");
    let cycles = std::fs::read_to_string(out.join("cycles.csv")).unwrap();
    assert!(
        cycles.starts_with("cycle,frame,t_ctrl_us,rx_ns,decode_ns,checks_ns,track_ns,plan_ns,encode_ns,can_write_ns,")
    );
    // The per-stage summary, printed and in report.json: every stage, timed on this host.
    assert!(stdout.contains("stages (µs)"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let stages = report["stages"].as_array().unwrap();
    let names: Vec<&str> = stages.iter().map(|s| s["stage"].as_str().unwrap()).collect();
    assert_eq!(names, ["decode", "checks", "track", "plan", "encode", "can_write"]);
    for s in stages {
        let (min, p50, p99, max) = (
            s["min_us"].as_f64().unwrap(),
            s["p50_us"].as_f64().unwrap(),
            s["p99_us"].as_f64().unwrap(),
            s["max_us"].as_f64().unwrap(),
        );
        assert!(min <= p50 && p50 <= p99 && p99 <= max && max > 0.0, "{s}");
    }
    assert!(cycles.lines().count() > 100);
    let trace: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("trace.json")).unwrap()).unwrap();
    assert!(trace["traceEvents"].as_array().unwrap().len() > 400);
    let can = std::fs::read_to_string(out.join("can.log")).unwrap();
    assert!(can.lines().any(|l| l.contains(" slcan0 101#")), "velocity frames in can.log");
    assert!(std::fs::read_to_string(out.join("trajectory.svg")).unwrap().contains("<polyline"));
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("truth.json")).unwrap()).unwrap();
    assert!(truth["summary"]["first_contact"].is_null());
    let _ = std::fs::remove_dir_all(&out);
}

/// From the world's truth: the wheels stood still from `by` seconds (sim time) onwards, and
/// were moving before the fault at `fault`.
fn assert_stopped(truth: &TruthRecord, fault: f64, by: f64) {
    let moving_before =
        truth.samples.iter().filter(|s| s.t > 1.0 && s.t < fault).any(|s| s.wheel_speeds[0].abs() > 0.02);
    assert!(moving_before, "the robot was not moving before the fault");
    let after: Vec<_> = truth.samples.iter().filter(|s| s.t >= by).collect();
    assert!(!after.is_empty(), "truth ends before {by} s");
    for s in &after {
        assert!(
            s.wheel_speeds.iter().all(|v| v.abs() < 1e-6),
            "wheels still turning at t = {:.2} s: {:?}",
            s.t,
            s.wheel_speeds
        );
    }
    let stop_at =
        truth.samples.iter().find(|s| s.t >= fault && s.wheel_speeds.iter().all(|v| v.abs() < 1e-6)).map(|s| s.t);
    eprintln!("fault at {fault:.2} s, wheels at rest at {stop_at:?} s");
}

/// SIGINT to `flowgate run`: an orderly stop (ramp down, disable). Budget 0.5 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigint_stops_the_wheels() {
    let s = scenario("e1-standing-obstacle.toml");
    let origin = tokio::time::Instant::now();
    let handle = flowgate_sim::rig::start(flowgate_sim::rig::RigConfig::new(s.sim.clone())).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
    let cfg = s.rig_file(&handle.psd_path, &can, None);
    let dir = std::env::temp_dir().join(format!("flowgate-sigint-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config_path = dir.join("rig.toml");
    std::fs::write(&config_path, cfg.to_toml()).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["run", "--arm", "--config"])
        .arg(&config_path)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    // Await the event: the gateway announces `state: running`.
    // Read the gateway's output throughout; tell the test when it announces `state: running`.
    let (running_tx, running_rx) = tokio::sync::oneshot::channel();
    let reader = std::thread::spawn(move || {
        let mut running_tx = Some(running_tx);
        let mut seen = Vec::new();
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if line == "state: running" {
                if let Some(tx) = running_tx.take() {
                    let _ = tx.send(());
                }
            }
            seen.push(line);
        }
        seen
    });
    tokio::time::timeout(Duration::from_secs(10), running_rx).await.expect("gateway runs within 10 s").unwrap();
    // Let it drive a second, then interrupt.
    tokio::time::sleep(Duration::from_secs(1)).await; // the robot must be moving; not a synchronisation
    let sigint_at = origin.elapsed().as_secs_f64();
    #[allow(unsafe_code)]
    // SAFETY: kill(2) on our own child's pid with a valid signal.
    unsafe {
        libc::kill(child.id() as i32, libc::SIGINT);
    }
    let status = tokio::task::spawn_blocking(move || child.wait().unwrap()).await.unwrap();
    let lines = reader.join().unwrap();
    assert!(status.success(), "{status:?}: {lines:?}");
    assert!(lines.iter().any(|l| l.contains("shutdown signal")), "{lines:?}");
    // The world keeps running past the stop budget, so its truth covers it.
    tokio::time::sleep_until(origin + Duration::from_secs_f64(sigint_at + 0.8)).await;
    let truth = handle.stop().await;
    assert_stopped(&truth, sigint_at, sigint_at + 0.5);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A second gateway on the same serial port is refused with a clear error.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_gateway_on_the_same_port_is_refused() {
    let s = scenario("e1-standing-obstacle.toml");
    let handle = flowgate_sim::rig::start(flowgate_sim::rig::RigConfig::new(s.sim.clone())).await.unwrap();
    let first = flowgate::gateway::shell::link::open_serial(&handle.psd_path, 921_600).unwrap();
    let err = flowgate::gateway::shell::link::open_serial(&handle.psd_path, 921_600).unwrap_err();
    assert!(err.to_string().contains("in use by another program"), "{err}");
    drop(first);
    // Closing releases the lock at once, unless another test thread of this binary is spawning
    // a process at that instant: the child holds a copy of every descriptor from fork to exec
    // (O_CLOEXEC closes it only at exec), and with it the flock. So the port must be free again
    // within a bound, not at the same instant. Seen once in CI under load.
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    loop {
        match flowgate::gateway::shell::link::open_serial(&handle.psd_path, 921_600) {
            Ok(_) => break,
            Err(flowgate::gateway::shell::link::SerialError::Busy { .. }) if std::time::Instant::now() < deadline => {
                tokio::time::sleep(Duration::from_millis(10)).await; // polling a lock held by another process
            }
            Err(e) => panic!("free again: {e}"),
        }
    }
    handle.stop().await;
}

/// Two gateway processes on one serial port, both as an ordinary user (`nobody` when the
/// tests run as root, who is not bound by TIOCEXCL): the second is refused by name.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_gateway_process_is_refused_as_an_ordinary_user() {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let s = scenario("e1-standing-obstacle.toml");
    let handle = flowgate_sim::rig::start(flowgate_sim::rig::RigConfig::new(s.sim.clone())).await.unwrap();
    let root = std::fs::metadata("/proc/self").unwrap().uid() == 0;
    // The pty itself, open to its user (as the dialout group makes a real port).
    let device = std::fs::canonicalize(&handle.psd_path).unwrap();
    std::fs::set_permissions(&device, std::fs::Permissions::from_mode(0o666)).unwrap();
    let dir = std::env::temp_dir().join(format!("flowgate-exclusive-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
    let config_path = dir.join("rig.toml");
    std::fs::write(&config_path, s.rig_file(&device, "memory", None).to_toml()).unwrap();
    let gateway = || {
        let mut c = if root {
            let mut c = Command::new("setpriv");
            c.args(["--reuid=65534", "--regid=65534", "--clear-groups", env!("CARGO_BIN_EXE_flowgate")]);
            c
        } else {
            Command::new(env!("CARGO_BIN_EXE_flowgate"))
        };
        c.args(["run", "--arm", "--config"]).arg(&config_path);
        c
    };
    let mut first = gateway().stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    // Await the event: the first gateway holds the port once its controller streams and it arms.
    let stdout = first.stdout.take().unwrap();
    let (armed_tx, armed_rx) = tokio::sync::oneshot::channel();
    std::thread::spawn(move || {
        let mut armed_tx = Some(armed_tx);
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if line.starts_with("state: armed") {
                if let Some(tx) = armed_tx.take() {
                    let _ = tx.send(());
                }
            }
        }
    });
    if tokio::time::timeout(Duration::from_secs(10), armed_rx).await.is_err() {
        let _ = first.kill();
        let out = first.wait_with_output().unwrap();
        panic!("the first gateway did not arm: {}", String::from_utf8_lossy(&out.stderr));
    }
    let mut second = gateway();
    let second = tokio::task::spawn_blocking(move || second.output().unwrap());
    let second = tokio::time::timeout(Duration::from_secs(10), second).await.expect("the second exits").unwrap();
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert!(!second.status.success());
    assert!(stderr.contains("is in use by another program"), "{stderr}");
    let _ = first.kill();
    let _ = first.wait();
    handle.stop().await;
    let _ = std::fs::remove_dir_all(&dir);
}

/// The serial device vanishes at 2 s and comes back 0.6 s later: the robot stops, the gateway
/// reconnects on its own, stays in fault until the operator resets, arms and starts it, then
/// carries on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serial_vanishing_stops_reconnects_and_waits_for_rearm() {
    use flowgate::gateway;
    use flowgate::gateway::core::operator::Request;
    use flowgate::gateway::core::Progress;
    use flowgate::gateway::shell::control_socket::Peer;
    use flowgate::gateway::shell::Controls;
    use flowgate_sim::rig::{RigConfig, SerialEndpoint};
    let mut s = scenario("e1-standing-obstacle.toml");
    s.faults = s.faults.with_settings(&["serial_vanish_at=2.0".into(), "serial_vanish_s=0.6".into()]).unwrap();
    let dir = std::env::temp_dir().join(format!("flowgate-vanish-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("psd");
    let mut rig_cfg = RigConfig::new(s.sim.clone());
    rig_cfg.psd = SerialEndpoint::Pty { link: Some(link.clone()) };
    let origin = tokio::time::Instant::now();
    let handle = flowgate_sim::rig::start(rig_cfg).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
    let rig = s.rig_file(&link, &can, None).rig("test").unwrap();
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let (progress_tx, mut progress) = tokio::sync::watch::channel(Progress::default());
    let controls = Controls::new(stop_rx, true);
    let operator = controls.sender();
    let gw = tokio::spawn(gateway::shell::run(rig, controls, Some(progress_tx)));
    // The operator's request, as the control socket would pass it on.
    let ask = |request: Request| {
        let operator = operator.clone();
        async move {
            let reply = operator.ask(request, Peer::Socket { uid: 0, gid: 0, pid: None }).await;
            assert!(reply.ok, "{reply:?}");
        }
    };
    let wait_for = |progress: &mut tokio::sync::watch::Receiver<Progress>, pred: fn(&Progress) -> bool| {
        let mut rx = progress.clone();
        let look = progress.clone();
        async move {
            match tokio::time::timeout(Duration::from_secs(10), rx.wait_for(pred)).await {
                Ok(p) => p.unwrap().to_owned(),
                Err(_) => panic!("not within 10 s; progress {:?}", *look.borrow()),
            }
        }
    };
    wait_for(&mut progress, |p| p.state == State::Running).await;
    wait_for(&mut progress, |p| matches!(p.state, State::Fault(_))).await;
    let fault_at = origin.elapsed().as_secs_f64();
    // It reconnects by itself, and stays in fault: no automatic restart.
    wait_for(&mut progress, |p| p.serial_reconnects >= 1).await;
    assert!(matches!(progress.borrow().state, State::Fault(_)));
    let rearm_at = origin.elapsed().as_secs_f64();
    ask(Request::Reset).await;
    ask(Request::Arm).await;
    ask(Request::Start).await;
    wait_for(&mut progress, |p| p.state == State::Running).await;
    wait_for(&mut progress, |p| matches!(p.state, State::Stopped(_))).await;
    stop_tx.send(true).unwrap();
    let report = gw.await.unwrap().unwrap();
    let truth = handle.stop().await;
    // The first fault latches: the board's own command timeout (commands stop with the
    // samples) or the gateway's serial or sample watchdog, whichever fires first.
    use flowgate::gateway::core::StopReason;
    let faults: Vec<State> =
        report.transitions.iter().map(|(_, s)| *s).filter(|s| matches!(s, State::Fault(_))).collect();
    assert_eq!(faults.len(), 1, "{:?}", report.transitions);
    assert!(
        [StopReason::SerialLost, StopReason::SamplesStopped, StopReason::BoardFault { node: 1 }]
            .contains(&faults[0].reason().unwrap()),
        "{:?}",
        report.transitions
    );
    assert!(report.counters.serial_reconnects >= 1, "{report}");
    assert_eq!(report.stop_reason, Some(StopReason::GoalReached), "{report}");
    // Truth: at rest from half a second after the fault until re-armed, then at the goal.
    let resting: Vec<_> = truth.samples.iter().filter(|x| x.t > fault_at + 0.5 && x.t < rearm_at).collect();
    assert!(!resting.is_empty());
    assert!(resting.iter().all(|x| x.wheel_speeds.iter().all(|v| v.abs() < 1e-6)), "moved while faulted");
    let end = truth.summary.final_position;
    assert!((end[0] - s.goal.position[0]).hypot(end[1] - s.goal.position[1]) < s.goal.tolerance + 0.01);
    assert!(truth.summary.first_contact.is_none());
    let _ = std::fs::remove_dir_all(&dir);
}
