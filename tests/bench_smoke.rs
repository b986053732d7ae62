//! The benchmark harness itself works: a short run of the real gateway process, its null
//! gateway (its own process) and each other row's pair (low-latency, real-time, recording,
//! CiA 402 drives) answers every frame with exactly one command and reports sane figures. No timing is asserted here;
//! performance is measured by `flowgate bench`, not by tests.

use flowgate::gateway::shell::realtime::RealtimeSettings;
use flowgate::lab::bench::{Mode, PhaseSpec, Transport};

#[tokio::test(flavor = "current_thread")]
async fn bench_harness_runs_the_gateway_and_accounts_for_every_cycle() {
    let dir = std::env::temp_dir().join(format!("flowgate-bench-smoke-{}", std::process::id()));
    let exe = std::path::Path::new(env!("CARGO_BIN_EXE_flowgate"));
    // The real-time row asks only for what any process may: a CPU of its own.
    let also = vec![
        Mode { spin_us: 500, ..Mode::default() },
        Mode { realtime: RealtimeSettings { cpus: vec![0], ..RealtimeSettings::default() }, ..Mode::default() },
        Mode { record: true, ..Mode::default() },
        Mode { cia402: true, ..Mode::default() },
        Mode { ros2: true, ..Mode::default() },
    ];
    let phases = [PhaseSpec { name: "smoke", frame_rate_hz: 100.0, cycles: 100, floor: true, also }];
    let report = flowgate::lab::bench::run(exe, &Transport::SlcanPty, &phases, &dir).await.expect("bench runs");
    let p = &report.phases[0];
    assert_eq!(p.cycles_sent, 100);
    assert_eq!(p.commands_received, 100, "one command per frame");
    let floor = p.floor.expect("a floor was asked for");
    assert_eq!(floor.commands_received, 100, "the null gateway answers every frame too");
    assert!(floor.latency_us.p50 > 0.0);
    assert!(p.latency_us.p50 > 0.0 && p.latency_us.max >= p.latency_us.p99);
    assert!(p.rss_mb[1] > 0.0, "RSS read from /proc");
    // What flowgate adds is the difference of the two, quantile by quantile.
    let added = p.added_us.expect("a floor gives a difference");
    assert_eq!(added.p50, p.latency_us.p50 - floor.latency_us.p50);
    // The gateway's own stage timings for the phase, from its control socket.
    let names: Vec<&str> = p.stages.iter().map(|s| s.stage.as_str()).collect();
    assert_eq!(names, ["decode", "checks", "track", "plan", "encode", "can_write"]);
    assert!(p.stages.iter().all(|s| s.max_us > 0.0 && s.min_us <= s.p50_us), "{:?}", p.stages);
    // The low-latency row: a second gateway and null gateway, both answering every frame.
    let low = &report.phases[1];
    assert_eq!((low.name.as_str(), low.spin_us), ("smoke, low-latency", Some(500)));
    assert_eq!((low.cycles_sent, low.commands_received), (100, 100));
    assert_eq!(low.floor.expect("its own floor").commands_received, 100);
    // The real-time row: a third pair, with the settings named.
    let rt = &report.phases[2];
    assert_eq!((rt.name.as_str(), rt.realtime.as_deref()), ("smoke, real-time", Some("CPUs [0]")));
    assert_eq!((rt.cycles_sent, rt.commands_received), (100, 100));
    assert_eq!(rt.floor.expect("its own floor").commands_received, 100);
    // The recording row: a fourth pair, its gateway writing an MCAP recording that replays
    // to the frames it sent.
    let rec = &report.phases[3];
    assert_eq!((rec.name.as_str(), rec.recording), ("smoke, recording", true));
    assert_eq!((rec.cycles_sent, rec.commands_received), (100, 100));
    let sockets = std::env::temp_dir().join(format!("flowgate-bench-{}", std::process::id()));
    let recording = flowgate::replay::Recording::read(&sockets.join("gateway-recording.mcap")).expect("a recording");
    let rig = recording.config().unwrap().rig("recorded").unwrap();
    let replayed = flowgate::replay::run(rig, &recording.inputs);
    assert!(replayed.commands.len() >= 100, "{} commands replayed", replayed.commands.len());
    let n = recording.can_sent.len().min(replayed.can.len());
    assert!(n > 100);
    assert_eq!(flowgate::replay::first_difference(&recording.can_sent[..n], &replayed.can[..n]), None);
    // The CiA 402 row: its gateway configures the bench's drives by SDO, and each frame's
    // command is its second RPDO; its null gateway sends two RPDOs too.
    let drives = &report.phases[4];
    assert_eq!((drives.name.as_str(), drives.cia402), ("smoke, CiA 402", true));
    assert_eq!((drives.cycles_sent, drives.commands_received), (100, 100));
    assert_eq!(drives.floor.expect("its own floor").commands_received, 100);
    assert!(report.wire_per_cycle_cia402_us > report.wire_per_cycle_us);
    // The ROS 2 row: its gateway runs its node (no one listening) and answers every frame.
    let ros2 = &report.phases[5];
    assert_eq!((ros2.name.as_str(), ros2.ros2), ("smoke, ROS 2", true));
    assert_eq!((ros2.cycles_sent, ros2.commands_received), (100, 100));
    assert!(report.gateway_states.iter().all(|s| !s.starts_with("fault")), "{:?}", report.gateway_states);
    assert_eq!(report.other_states.len(), 5);
    for (name, states) in &report.other_states {
        assert!(states.iter().all(|s| !s.starts_with("fault")) && !states.is_empty(), "{name}: {states:?}");
    }
    let json = serde_json::to_string(&report).unwrap();
    assert!(json.contains("late_percent"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// `flowgate bench` refuses its flags' bad values before it starts anything, naming the
/// flag: a real-time CPU beyond what Linux numbers, no cycles at the paper's rate, a
/// low-latency window that does not fit in a frame.
#[test]
fn bench_refuses_bad_flags_before_it_starts() {
    let refused = |args: &[&str], code: i32, says: &str| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_flowgate")).arg("bench").args(args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{args:?}: {stderr}");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
    };
    refused(&["--rt-cpu", "1024"], 2, "invalid value '1024' for '--rt-cpu <N>': 1024 is not in 0..1024");
    refused(&["--paper-cycles", "0"], 1, "--paper-cycles must be positive");
    refused(&["--spin-us", "30001"], 1, "--spin-us 30001: at most 30000 µs");
}
