//! The stack on real SocketCAN, with can-utils and cantools as the peers a user has.
//!
//! Needs a vcan interface named by `FLOWGATE_VCAN`:
//! - natively: `modprobe vcan; ip link add vcan0 type vcan; ip link set up vcan0`, then
//!   `FLOWGATE_VCAN=vcan0 scripts/test --test vcan`;
//! - on machines without CAN (these): `scripts/vcan-vm cargo test --test vcan`.
//!
//! Without `FLOWGATE_VCAN` each test says it was skipped and passes; CI runs the suite in the
//! VM and fails unless every test printed that it ran (`vcan-ran: NAME`). The tests run in
//! real time: run them one at a time (`--test-threads=1`) under emulation.

#[path = "support/python.rs"]
mod python;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use flowgate::lab::demo;
use flowgate::lab::Scenario;
use flowgate_protocol::motor::MotorMessage;
use flowgate_protocol::{CanFrame, CanId};

fn vcan(test: &str) -> Option<String> {
    match std::env::var("FLOWGATE_VCAN") {
        Ok(iface) => {
            println!("vcan-ran: {test} on {iface}");
            Some(iface)
        }
        Err(_) => {
            eprintln!("vcan: {test} skipped: FLOWGATE_VCAN is not set (see tests/vcan.rs)");
            None
        }
    }
}

fn scenario(name: &str) -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)).unwrap()
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("flowgate-vcan-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `candump -L IFACE` into `file`, returning once it provably captures (a marker frame seen).
async fn candump(iface: &str, file: &Path) -> Child {
    let out = std::fs::File::create(file).unwrap();
    let mut child =
        Command::new("candump").args(["-L", iface]).stdout(out).spawn().expect("candump (can-utils) installed");
    for _ in 0..200 {
        cansend(iface, "7F0#C0FFEE");
        tokio::time::sleep(Duration::from_millis(20)).await; // polling the capture file for the marker
        if std::fs::read_to_string(file).unwrap_or_default().contains("7F0#C0FFEE") {
            return child;
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    panic!("candump never captured the marker frame");
}

fn cansend(iface: &str, frame: &str) {
    let ok = Command::new("cansend").args([iface, frame]).status().expect("cansend (can-utils) installed").success();
    assert!(ok, "cansend {iface} {frame}");
}

fn stop(mut child: Child) {
    #[allow(unsafe_code)]
    // SAFETY: kill(2) on our own child's pid with a valid signal.
    unsafe {
        libc::kill(child.id() as i32, libc::SIGINT);
    }
    let _ = child.wait();
}

/// `(ID#DATA)` lines of a candump -L log (or the gateway's can.log), in order.
fn frames(log: &str) -> Vec<CanFrame> {
    log.lines()
        .filter_map(|l| l.split_whitespace().nth(2))
        .filter_map(|f| {
            let (id, data) = f.split_once('#')?;
            let raw = u32::from_str_radix(id, 16).ok()?;
            let id = if id.len() == 3 { CanId::Standard(raw as u16) } else { CanId::Extended(raw) };
            let bytes: Vec<u8> =
                (0..data.len() / 2).filter_map(|i| u8::from_str_radix(&data[2 * i..2 * i + 2], 16).ok()).collect();
            CanFrame::new(id, &bytes).ok()
        })
        .collect()
}

fn velocities(fs: &[CanFrame]) -> Vec<(i32, i32, u8)> {
    fs.iter()
        .filter_map(|f| match MotorMessage::parse(f) {
            Ok(MotorMessage::Velocity { left, right, seq, .. }) => Some((left, right, seq)),
            _ => None,
        })
        .collect()
}

/// E2 through the demo over SocketCAN on `iface` with `drive`, candump capturing the bus
/// meanwhile: the run, its output folder (a fresh temporary one named `name`) and the
/// capture in it.
async fn e2_with_candump(iface: &str, name: &str, drive: demo::DemoDrive) -> (demo::DemoRun, PathBuf, PathBuf) {
    let dir = temp(name);
    let capture = dir.join("candump.log");
    let dump = candump(iface, &capture).await;
    let run = demo::run(
        &scenario("e2-lane-head-on.toml"),
        &format!("socketcan:{iface}"),
        drive,
        demo::Outputs { dir: Some(dir.clone()), ..demo::Outputs::default() },
        |_| {},
    )
    .await
    .expect("demo over vcan");
    stop(dump);
    (run, dir, capture)
}

/// E2 over SocketCAN: the goal without contact, and the bus as candump saw it agrees with
/// the gateway's own can.log, decoded by the project's decoder and by cantools.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn e2_over_socketcan_agrees_with_candump_and_cantools() {
    let Some(iface) = vcan("e2_over_socketcan_agrees_with_candump_and_cantools") else { return };
    let (run, dir, capture) = e2_with_candump(&iface, "e2", demo::DemoDrive::Pcl80k).await;
    assert!(run.reached_goal && !run.contact, "{}\n{:?}", run.report, run.truth.summary);

    let on_bus = velocities(&frames(&std::fs::read_to_string(&capture).unwrap()));
    let gateway_log = std::fs::read_to_string(dir.join("can.log")).unwrap();
    assert!(gateway_log.lines().all(|l| l.contains(&format!(" {iface} "))));
    let sent = velocities(&frames(&gateway_log));
    assert!(sent.len() > 300, "{} velocity frames", sent.len());
    assert_eq!(on_bus, sent, "candump's velocity frames equal the gateway's can.log");

    // cantools reads the candump capture with protocol/motor.dbc.
    let python = python::python();
    let script = python::peer("vcan");
    let dbc = Path::new(env!("CARGO_MANIFEST_DIR")).join("protocol/motor.dbc");
    let out =
        Command::new(python).arg(script).arg(&dbc).arg(&capture).stderr(Stdio::inherit()).output().expect("python");
    assert!(out.status.success(), "cantools check failed: {}", String::from_utf8_lossy(&out.stdout));
    let decoded: Vec<(i32, i32, u8)> = serde_json::from_slice(&out.stdout).expect("JSON from tests/peers/vcan.py");
    assert_eq!(decoded, on_bus, "cantools and the Rust decoder agree");
    let _ = std::fs::remove_dir_all(&dir);
}

/// E2 over SocketCAN with the simulator's CiA 402 drives: the goal without contact, and on
/// the bus as candump saw it, each drive's 30 configuration writes after its last boot-up,
/// every one answered, and an RPDO a cycle to each.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn e2_over_socketcan_with_cia402_drives() {
    let Some(iface) = vcan("e2_over_socketcan_with_cia402_drives") else { return };
    let (run, dir, capture) = e2_with_candump(&iface, "e2-cia402", demo::DemoDrive::Cia402).await;
    let log = std::fs::read_to_string(&capture).unwrap();
    // On failure, the state machine's first exchanges as the bus saw them.
    let ids = [" 000#", " 181#", " 182#", " 201#", " 202#"];
    let first: Vec<&str> = log.lines().filter(|l| ids.iter().any(|id| l.contains(id))).take(60).collect();
    assert!(run.reached_goal && !run.contact, "{}\n{:?}\n{}", run.report, run.truth.summary, first.join("\n"));
    let bus = frames(&log);
    let count = |frames: &[CanFrame], id: u32| frames.iter().filter(|f| f.id().raw() == id).count();
    for node in [1, 2] {
        // A drive that boots while the gateway configures it is configured afresh: its whole
        // configuration follows its last boot-up (a heartbeat of state 0). A boot-up on the
        // bus just before the arm may reach the gateway just after it, when the first write
        // is out: that write then goes again.
        let boot_up = |f: &CanFrame| f.id().raw() == 0x700 + node && f.data() == [0];
        let after = &bus[bus.iter().rposition(boot_up).map_or(0, |k| k + 1)..];
        let requests: Vec<&CanFrame> = after.iter().filter(|f| f.id().raw() == 0x600 + node).collect();
        let exchange = || {
            after
                .iter()
                .filter(|f| [0x600 + node, 0x580 + node, 0x700 + node, 0].contains(&f.id().raw()))
                .map(|f| format!("{:03X}#{:02X?}", f.id().raw(), f.data()))
                .collect::<Vec<_>>()
                .join("\n")
        };
        let again = requests.len().saturating_sub(30);
        assert!(
            requests.len() >= 30 && again <= 1 && requests[..=again].iter().all(|f| f == &requests[0]),
            "drive {node}: the 30 writes after its last boot-up, the first at most twice:\n{}",
            exchange()
        );
        assert_eq!(count(after, 0x580 + node), requests.len(), "drive {node}: every write answered:\n{}", exchange());
    }
    let count = |id: u32| count(&bus, id);
    let cycles = run.report.counters.cycles as usize;
    assert!(count(0x201) >= cycles && count(0x202) >= cycles, "{cycles} cycles");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Start E1 over SocketCAN on `iface`; return once the gateway has been running past `t` s.
async fn e1_running_for(iface: &str, t: f64) -> tokio::task::JoinHandle<Result<demo::DemoRun, demo::DemoError>> {
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let s = scenario("e1-standing-obstacle.toml");
    let url = format!("socketcan:{iface}");
    let run = tokio::spawn(async move {
        let mut sent = false;
        demo::run(&s, &url, demo::DemoDrive::Pcl80k, demo::Outputs::default(), move |p| {
            if !sent && p.state == flowgate::gateway::core::State::Running && p.t > t {
                sent = true;
                let _ = tx.send(());
            }
        })
        .await
    });
    rx.recv().await.expect("the gateway runs");
    run
}

/// cansend injects malformed frames and then an emergency stop: the malformed ones are
/// counted and ignored, the e-stop stops the wheels at once, nothing crashes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cansend_estop_and_malformed_frames() {
    let Some(iface) = vcan("cansend_estop_and_malformed_frames") else { return };
    let run = e1_running_for(&iface, 1.5).await;
    for f in ["101#00", "7FF#DEADBEEF", "109#0000000000000000", "011#55"] {
        cansend(&iface, f);
    }
    cansend(&iface, "001#01"); // e-stop node 1, reason operator
    let r = run.await.unwrap().expect("both sides survive");
    assert!(matches!(r.report.final_state, flowgate::gateway::core::State::Fault(_)), "{}", r.report);
    assert!(r.report.counters.can_undecodable >= 2, "{:?}", r.report.counters);
    // The board stopped at once: the truth's last samples are at rest.
    let last = r.truth.samples.last().unwrap();
    assert!(last.wheel_speeds.iter().all(|v| v.abs() < 1e-6), "{last:?}\n{:?}", r.report.transitions);
}

/// A bus-off error frame reaches the gateway (error frames enabled on its socket) and faults it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bus_off_error_frame_faults_the_gateway() {
    let Some(iface) = vcan("a_bus_off_error_frame_faults_the_gateway") else { return };
    let run = e1_running_for(&iface, 1.0).await;
    // CAN_ERR_FLAG | CAN_ERR_BUSOFF, as a controller driver would report it.
    cansend(&iface, "20000040#0000000000000000");
    let r = run.await.unwrap().expect("both sides survive");
    assert_eq!(r.report.stop_reason, Some(flowgate::gateway::core::StopReason::BusOff), "{}", r.report);
    assert!(r.report.counters.can_error_frames >= 1);
}

/// Sets a network interface up again when dropped (whatever the test's outcome).
struct UpAgain<'a>(&'a str);

impl Drop for UpAgain<'_> {
    fn drop(&mut self) {
        let _ = Command::new("ip").args(["link", "set", self.0, "up"]).status();
    }
}

/// The host's own interface going down under a running gateway (`ip link set down`, as a
/// `slcand` that exits or a USB adapter pulled) is named as such, not bus-off.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_interface_set_down_is_named_as_such() {
    let Some(iface) = vcan("an_interface_set_down_is_named_as_such") else { return };
    let run = e1_running_for(&iface, 1.0).await;
    let up_again = UpAgain(&iface);
    let ok = Command::new("ip").args(["link", "set", &iface, "down"]).status().expect("ip (iproute2)").success();
    assert!(ok, "ip link set {iface} down");
    let r = run.await.unwrap().expect("both sides survive");
    drop(up_again);
    assert_eq!(r.report.stop_reason, Some(flowgate::gateway::core::StopReason::CanInterfaceDown), "{}", r.report);
}

/// `flowgate bench --can socketcan:IFACE` works end to end: the gateway process and the null
/// gateway both answer every frame over SocketCAN, and the bench's raw-socket reader sees
/// every command. No timing is asserted (performance is measured by the bench, not tests).
#[tokio::test(flavor = "current_thread")]
async fn the_bench_runs_over_socketcan() {
    let Some(iface) = vcan("the_bench_runs_over_socketcan") else { return };
    use flowgate::lab::bench::{PhaseSpec, Transport};
    let dir = temp("bench");
    let exe = Path::new(env!("CARGO_BIN_EXE_flowgate"));
    let phases = [PhaseSpec { name: "smoke", frame_rate_hz: 50.0, cycles: 100, floor: true, also: Vec::new() }];
    let report = flowgate::lab::bench::run(exe, &Transport::SocketCan { interface: iface }, &phases, &dir)
        .await
        .expect("bench runs over SocketCAN");
    let p = &report.phases[0];
    assert_eq!(
        (p.cycles_sent, p.commands_received),
        (100, 100),
        "one gateway command per frame; gateway states {:?}",
        report.gateway_states
    );
    assert_eq!(p.floor.expect("floor asked for").commands_received, 100, "one null-gateway command per frame");
    assert!(report.transport.contains("SocketCAN"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// `flowgate check` on SocketCAN: the interface is up and error-free, the board heartbeats
/// and takes its config; an interface that does not exist fails by name.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_preflight_checks_a_socketcan_interface() {
    let Some(iface) = vcan("the_preflight_checks_a_socketcan_interface") else { return };
    let dir = temp("check");
    let s = scenario("e1-standing-obstacle.toml");
    let mut rig = flowgate_sim::rig::RigConfig::new(s.sim.clone());
    rig.can = flowgate_sim::rig::CanEndpoint::SocketCan { interface: iface.clone() };
    let handle = flowgate_sim::rig::start(rig).await.unwrap();
    let check = |endpoint: &str, name: &str| {
        let cfg = s.rig_file(&handle.psd_path, endpoint, None);
        let path = dir.join(format!("{name}.toml"));
        std::fs::write(&path, cfg.to_toml()).unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_flowgate")).args(["check", "--config"]).arg(&path).output().unwrap();
        (out.status.success(), String::from_utf8(out.stdout).unwrap())
    };
    let (ok, out) = check(&format!("socketcan:{iface}"), "up");
    let line = |item: &str| {
        out.lines().find(|l| l.get(6..).is_some_and(|r| r.starts_with(item))).unwrap_or_default().to_string()
    };
    assert!(ok, "{out}");
    assert!(
        line("CAN interface").starts_with("PASS") && line("CAN interface").contains("up, no error frames"),
        "{out}"
    );
    assert!(line("board heartbeat").starts_with("PASS") && line("board config").starts_with("PASS"), "{out}");

    let (ok, out) = check("socketcan:fgnone0", "missing");
    handle.stop().await;
    assert!(!ok, "{out}");
    let can = out.lines().find(|l| l.get(6..).is_some_and(|r| r.starts_with("CAN interface"))).unwrap();
    assert!(can.starts_with("FAIL") && can.contains("fgnone0") && can.contains("no such interface"), "{out}");
    let _ = std::fs::remove_dir_all(&dir);
}
