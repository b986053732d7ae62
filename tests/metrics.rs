//! `/metrics` of a real `flowgate run` driving the simulator over ptys, scraped over HTTP
//! and parsed by Prometheus's own Python client (`prometheus_client`, an independent
//! parser): the families are there with their types, the counters count, the state gauge
//! is one-hot, the latency histogram is cumulative and counts every cycle.

#[path = "support/python.rs"]
mod python;

use std::io::{Read, Write};
use std::process::{Command, Stdio};
use std::time::Duration;

mod support;

/// One HTTP GET, whole reply; `None` while nothing listens yet.
fn scrape(addr: std::net::SocketAddr, path: &str) -> Option<String> {
    let mut s = std::net::TcpStream::connect(addr).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(s, "GET {path} HTTP/1.1\r\nHost: localhost\r\n\r\n").unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    Some(out)
}

fn parse(body: &str) -> serde_json::Value {
    let python = python::python();
    let mut child =
        Command::new(python).arg(python::peer("metrics")).stdin(Stdio::piped()).stdout(Stdio::piped()).spawn().unwrap();
    child.stdin.take().unwrap().write_all(body.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "prometheus_client could not parse:\n{body}");
    serde_json::from_slice(&out.stdout).unwrap()
}

fn value(families: &serde_json::Value, family: &str, sample: &str, label: Option<(&str, &str)>) -> f64 {
    families[family]["samples"]
        .as_array()
        .unwrap_or_else(|| panic!("no family {family}"))
        .iter()
        .find(|s| s[0] == sample && label.is_none_or(|(k, v)| s[1][k] == v))
        .unwrap_or_else(|| panic!("no sample {sample} {label:?} in {family}"))[2]
        .as_f64()
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_scraped_and_parsed_by_prometheus_client() {
    let addr = support::free_loopback_addr();
    let gateway = support::run_on_sim("metrics", |cfg| cfg.operator.metrics = Some(addr)).await;
    // Scrape until the gateway has run a hundred cycles (it publishes once a second).
    let mut families = serde_json::Value::Null;
    for _ in 0..40 {
        tokio::time::sleep(Duration::from_millis(250)).await; // polling the endpoint for progress
        let Some(reply) = scrape(addr, "/metrics") else { continue };
        let (head, body) = reply.split_once("\r\n\r\n").unwrap();
        assert!(
            head.starts_with("HTTP/1.1 200 OK") && head.contains("application/openmetrics-text; version=1.0.0"),
            "{head}"
        );
        families = parse(body);
        if value(&families, "flowgate_cycles", "flowgate_cycles_total", None) >= 100.0 {
            break;
        }
    }
    let not_found = scrape(addr, "/other").unwrap();
    gateway.stop().await;
    assert!(not_found.starts_with("HTTP/1.1 404"), "{not_found}");

    let cycles = value(&families, "flowgate_cycles", "flowgate_cycles_total", None);
    assert!(cycles >= 100.0, "{families}");
    assert_eq!(families["flowgate_cycles"]["type"], "counter");
    assert!(value(&families, "flowgate_samples", "flowgate_samples_total", None) >= 2.0 * cycles);
    // One state at a time.
    let states: f64 =
        families["flowgate_state"]["samples"].as_array().unwrap().iter().map(|s| s[2].as_f64().unwrap()).sum();
    assert_eq!(states, 1.0, "{families}");
    assert_eq!(value(&families, "flowgate_state", "flowgate_state", Some(("state", "running"))), 1.0);
    // The planner's flags, by flag, each at most one a cycle.
    for flag in ["saturated", "tie_break", "margin_shrunk", "unclosed_at_a_wall"] {
        let n = value(&families, "flowgate_planner_flags", "flowgate_planner_flags_total", Some(("flag", flag)));
        assert!((0.0..=cycles).contains(&n), "{flag}: {n} of {cycles} cycles");
    }
    // The histogram: cumulative buckets, +Inf = count = every timed cycle.
    let h = &families["flowgate_cycle_latency_seconds"];
    assert_eq!(h["type"], "histogram");
    let buckets: Vec<f64> = h["samples"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|s| s[0] == "flowgate_cycle_latency_seconds_bucket")
        .map(|s| s[2].as_f64().unwrap())
        .collect();
    assert!(buckets.windows(2).all(|w| w[0] <= w[1]), "{buckets:?}");
    let count = value(&families, "flowgate_cycle_latency_seconds", "flowgate_cycle_latency_seconds_count", None);
    assert_eq!(*buckets.last().unwrap(), count);
    assert!(count >= 100.0, "{count}");
    for why in ["duplicate", "bad_frame", "out_of_order"] {
        assert_eq!(value(&families, "flowgate_psd_discarded", "flowgate_psd_discarded_total", Some(("why", why))), 0.0);
    }
    // Every fault and stop reason is there before it happens, at 0.
    let faults = |reason| value(&families, "flowgate_faults", "flowgate_faults_total", Some(("reason", reason)));
    assert_eq!(faults("heartbeat_lost"), 0.0);
    assert_eq!(faults("board_e_stop"), 0.0);
    assert_eq!(faults("drive_emergency"), 0.0);
    assert_eq!(faults("obstacle_reached_robot"), 0.0);
    assert_eq!(families["flowgate_faults"]["samples"].as_array().unwrap().len(), 38, "{families}");
    assert_eq!(families["flowgate_stops"]["samples"].as_array().unwrap().len(), 8, "{families}");
    assert_eq!(families["flowgate_build"]["type"], "info");
    assert_eq!(value(&families, "flowgate_build", "flowgate_build_info", Some(("version", "0.1.0"))), 1.0);
    // The process, as Prometheus's client libraries name it.
    assert!(value(&families, "process_cpu_seconds", "process_cpu_seconds_total", None) > 0.0, "{families}");
    assert!(value(&families, "process_resident_memory_bytes", "process_resident_memory_bytes", None) > 1e6);
    assert!(value(&families, "process_open_fds", "process_open_fds", None) >= 5.0);
    let started = value(&families, "process_start_time_seconds", "process_start_time_seconds", None);
    assert!(started > 1.7e9, "{started}");
    // Each stage's histogram, counting every timed cycle.
    let stages = &families["flowgate_stage_seconds"];
    assert_eq!(stages["type"], "histogram");
    for stage in ["decode", "checks", "track", "plan", "encode", "can_write"] {
        let n = stages["samples"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s[0] == "flowgate_stage_seconds_count" && s[1]["stage"] == stage)
            .unwrap_or_else(|| panic!("no count for {stage}"))[2]
            .as_f64()
            .unwrap();
        assert_eq!(n, count, "{stage}");
    }
}
