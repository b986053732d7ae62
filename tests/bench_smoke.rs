//! The benchmark harness itself works: a short run of the real gateway process answers every
//! frame with exactly one command and reports sane figures. No timing is asserted here;
//! performance is measured by `flowgate bench`, not by tests.

use flowgate::lab::bench::{PhaseSpec, Transport};

#[tokio::test(flavor = "current_thread")]
async fn bench_harness_runs_the_gateway_and_accounts_for_every_cycle() {
    let dir = std::env::temp_dir().join(format!("flowgate-bench-smoke-{}", std::process::id()));
    let exe = std::path::Path::new(env!("CARGO_BIN_EXE_flowgate"));
    let phases = [PhaseSpec { name: "smoke", frame_rate_hz: 100.0, cycles: 100, floor: true }];
    let report = flowgate::lab::bench::run(exe, &Transport::SlcanPty, &phases, &dir).await.expect("bench runs");
    let p = &report.phases[0];
    assert_eq!(p.cycles_sent, 100);
    assert_eq!(p.commands_received, 100, "one command per frame");
    let floor = p.floor.expect("a floor was asked for");
    assert_eq!(floor.commands_received, 100, "the null gateway answers every frame too");
    assert!(floor.latency_us.p50 > 0.0);
    assert!(p.latency_us.p50 > 0.0 && p.latency_us.max >= p.latency_us.p99);
    assert!(p.rss_mb[1] > 0.0, "RSS read from /proc");
    let json = serde_json::to_string(&report).unwrap();
    assert!(json.contains("late_percent"));
    let _ = std::fs::remove_dir_all(&dir);
}
