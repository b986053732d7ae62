//! The real `flowgate run` as a systemd service sees it, against the simulator over real
//! ptys: the notification protocol on a real unix datagram socket (`NOTIFY_SOCKET`), and log
//! lines for the journal.

use std::io::{BufRead, BufReader};
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use flowgate::lab::Scenario;

/// The simulated rig (E1) and a gateway config for it, idle (no goal), in `dir`.
async fn rig(dir: &Path) -> (flowgate_sim::rig::RigHandle, PathBuf) {
    std::fs::create_dir_all(dir).unwrap();
    let s = Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let handle = flowgate_sim::rig::start(flowgate_sim::rig::RigConfig::new(s.sim.clone())).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
    let mut cfg = s.rig_file(&handle.psd_path, &can, None);
    cfg.goal = None;
    // Its control socket: the gateway logs it at info level on start.
    cfg.operator.socket = Some(dir.join("control.sock"));
    let config = dir.join("rig.toml");
    std::fs::write(&config, cfg.to_toml()).unwrap();
    (handle, config)
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("flowgate-service-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn signal(child: &Child, sig: &str) {
    assert!(Command::new("kill").arg(format!("-{sig}")).arg(child.id().to_string()).status().unwrap().success());
}

/// The next message, within `within`.
fn next(socket: &UnixDatagram, within: Duration) -> Option<String> {
    socket.set_read_timeout(Some(within)).unwrap();
    let mut buf = [0u8; 512];
    let n = socket.recv(&mut buf).ok()?;
    // One message, its assignments a line each (the last line's newline is optional).
    Some(String::from_utf8_lossy(&buf[..n]).trim_end_matches('\n').to_owned())
}

/// READY once the controller streams, STATUS with the state, WATCHDOG from the loop at a
/// quarter of the interval (under half, as sd_watchdog_enabled(3) asks), none while the
/// process is wedged (SIGSTOP), again after, and STOPPING on SIGTERM.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn systemd_hears_ready_watchdog_and_stopping() {
    let dir = temp("notify");
    let (handle, config) = rig(&dir).await;
    let notify = dir.join("notify.sock");
    let socket = UnixDatagram::bind(&notify).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["run", "--config"])
        .arg(&config)
        .env("NOTIFY_SOCKET", &notify)
        .env("WATCHDOG_USEC", "1000000")
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let first = next(&socket, Duration::from_secs(10)).expect("a message within 10 s");
    let first = if first == "WATCHDOG=1" { next(&socket, Duration::from_secs(10)).unwrap() } else { first };
    assert_eq!(first, "READY=1\nSTATUS=idle");

    // Ten watchdog messages in a row, each under half the 1 s interval after the last.
    let mut last: Option<Instant> = None;
    let mut fed = 0;
    while fed < 10 {
        let m = next(&socket, Duration::from_millis(500)).expect("the watchdog fed within half its interval");
        if m == "WATCHDOG=1" {
            if let Some(l) = last {
                assert!(l.elapsed() < Duration::from_millis(500), "{:?} between watchdog messages", l.elapsed());
            }
            last = Some(Instant::now());
            fed += 1;
        }
    }

    // Wedged: nothing for over a whole interval; systemd would kill it. Then it goes on.
    signal(&child, "STOP");
    while next(&socket, Duration::from_millis(50)).is_some() {} // what was in flight
    assert_eq!(next(&socket, Duration::from_millis(1500)), None, "no watchdog from a wedged gateway");
    signal(&child, "CONT");
    let resumed = std::iter::from_fn(|| next(&socket, Duration::from_secs(2))).find(|m| m == "WATCHDOG=1");
    assert!(resumed.is_some(), "the watchdog resumes with the loop");

    signal(&child, "TERM");
    let stopping = std::iter::from_fn(|| next(&socket, Duration::from_secs(2))).find(|m| m == "STOPPING=1");
    assert!(stopping.is_some(), "STOPPING=1 on an orderly stop");
    assert!(child.wait().unwrap().success());
    handle.stop().await;
    let _ = std::fs::remove_dir_all(&dir);
}

/// Under the journal (stderr is the stream `JOURNAL_STREAM` names) each line carries its
/// syslog priority and no colour; elsewhere, piped, no colour either.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn log_lines_fit_the_journal() {
    let dir = temp("journal");
    let (handle, config) = rig(&dir).await;
    for journal in [true, false] {
        let (reader, writer) = std::io::pipe().unwrap();
        let stat = rustix::fs::fstat(&writer).unwrap();
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_flowgate"));
        cmd.args(["run", "--config"]).arg(&config).env("RUST_LOG", "flowgate=info").env_remove("JOURNAL_STREAM");
        if journal {
            cmd.env("JOURNAL_STREAM", format!("{}:{}", stat.st_dev, stat.st_ino));
        }
        let mut child = cmd.stdout(Stdio::null()).stderr(writer).spawn().unwrap();
        drop(cmd); // the parent's copy of the pipe's write end: EOF once the child exits
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(reader).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    return;
                }
            }
        });
        let mut seen = Vec::new();
        let line = loop {
            match rx.recv_timeout(Duration::from_secs(10)) {
                Ok(l) if l.contains("control socket") => break l,
                Ok(l) => seen.push(l),
                Err(_) => panic!("no `control socket` line within 10 s: {seen:#?}"),
            }
        };
        assert!(!line.contains('\u{1b}'), "no colour codes off a terminal: {line:?}");
        if journal {
            assert!(line.starts_with("<6>flowgate::gateway::shell::services: control socket "), "{line:?}");
        } else {
            assert!(line.contains(" INFO ") && !line.starts_with('<'), "{line:?}");
        }
        signal(&child, "TERM");
        assert!(child.wait().unwrap().success());
    }
    handle.stop().await;
    let _ = std::fs::remove_dir_all(&dir);
}
