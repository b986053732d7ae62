//! `/metrics`: the gateway's counters and cycle latency in the Prometheus text format
//! (version 0.0.4), for the monitoring a lab already runs.
//!
//! The loop never serves a scrape itself. About once a second it publishes a [`Snapshot`]
//! (its counters, its state and a copy of its latency histogram: one allocation a second,
//! none per cycle) into a `watch` channel; the HTTP task renders the latest one for each
//! request. A slow or stuck client costs the loop nothing, and a scrape is at most a second
//! old.

use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Duration;

use hdrhistogram::Histogram;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;

use super::http::{self, Asked};
use crate::gateway::core::timing::{Stage, Timing};
use crate::gateway::core::{Counters, State, StopReason};

/// How often the loop publishes a snapshot.
pub const PUBLISH_EVERY: Duration = Duration::from_secs(1);
/// How long a client may take to send its request, and to take the answer.
const CLIENT_DEADLINE: Duration = Duration::from_secs(2);
/// The latency histogram's bucket bounds, s: 10 µs to 100 ms.
pub const BUCKETS_S: [f64; 14] = [1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 1e-1, 1.0];
/// The stages' bucket bounds, s: 1 µs to 10 ms.
pub const STAGE_BUCKETS_S: [f64; 11] = [1e-6, 2e-6, 5e-6, 1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 1e-2];

/// What the loop publishes.
#[derive(Debug, Clone)]
pub struct Snapshot {
    pub state: State,
    pub counters: Counters,
    /// End-to-end cycle latency, ns (serial frame read to CAN write done).
    pub e2e_ns: Histogram<u64>,
    pub deadline_misses: u64,
    pub uptime_s: f64,
    /// Stops and faults so far, by reason (`snake_case`), with whether it is a fault.
    pub stops: Vec<(String, bool, u64)>,
    /// Frames the live view's clients skipped.
    pub view_frames_dropped: u64,
    /// Each stage's durations, ns, in [`Stage::ALL`]'s order.
    pub stages: [Histogram<u64>; Stage::COUNT],
    /// When the gateway started, s since the Unix epoch.
    pub start_time_s: f64,
}

impl Snapshot {
    /// Before the loop's first publication.
    pub fn empty(start_time_s: f64) -> Self {
        let timing = Timing::default();
        Self {
            state: State::Idle,
            counters: Counters::default(),
            e2e_ns: timing.e2e_histogram().clone(),
            deadline_misses: 0,
            uptime_s: 0.0,
            stops: Vec::new(),
            view_frames_dropped: 0,
            stages: timing.stage_histograms().clone(),
            start_time_s,
        }
    }
}

/// Every state's name ([`State::name`]), for the one-hot state gauge.
const STATES: [&str; 6] = ["idle", "armed", "running", "stopping", "stopped", "fault"];

/// The snapshot in the Prometheus text format.
pub fn render(s: &Snapshot) -> String {
    let mut out = String::with_capacity(4096);
    write_counters(&mut out, s);
    write_stops(&mut out, s);
    write_gauges(&mut out, s);
    write_latency(&mut out, &s.e2e_ns);
    write_stages(&mut out, &s.stages);
    write_process(&mut out, s.start_time_s);
    out
}

/// The counters of everything unusual, each a `_total` family.
fn write_counters(out: &mut String, s: &Snapshot) {
    let c = &s.counters;
    let mut counter = |name: &str, help: &str, samples: &[(&str, u64)]| {
        let _ = writeln!(out, "# HELP flowgate_{name}_total {help}");
        let _ = writeln!(out, "# TYPE flowgate_{name}_total counter");
        for (labels, v) in samples {
            let _ = writeln!(out, "flowgate_{name}_total{labels} {v}");
        }
    };
    counter("cycles", "Control cycles run (commands computed).", &[("", c.cycles)]);
    counter("samples", "PSD samples received.", &[("", c.samples)]);
    counter(
        "deadline_misses",
        "Cycles whose end-to-end latency exceeded the control period.",
        &[("", s.deadline_misses)],
    );
    counter(
        "psd_discarded",
        "Controller packets and samples discarded, by why.",
        &[
            ("{why=\"bad_frame\"}", c.bad_serial_frames),
            ("{why=\"duplicate\"}", c.psd_duplicates),
            ("{why=\"out_of_order\"}", c.psd_out_of_order),
            ("{why=\"unsynced\"}", c.samples_unsynced),
            ("{why=\"from_future\"}", c.samples_from_future),
            ("{why=\"unscheduled\"}", c.samples_unscheduled),
            ("{why=\"frame_repeated\"}", c.frames_repeated),
        ],
    );
    counter("psd_packets_lost", "Controller packets lost (sequence gaps).", &[("", c.psd_packets_lost)]);
    counter("frames_lost", "Time-division frames that never ended.", &[("", c.frames_lost)]);
    counter("serial_dropped_bytes", "Serial bytes dropped while resynchronising.", &[("", c.serial_dropped_bytes)]);
    counter(
        "reconnects",
        "Links lost and opened again.",
        &[("{link=\"serial\"}", c.serial_reconnects), ("{link=\"can\"}", c.can_reconnects)],
    );
    counter(
        "can_ignored",
        "CAN frames and events ignored, by why.",
        &[
            ("{why=\"foreign\"}", c.can_foreign),
            ("{why=\"undecodable\"}", c.can_undecodable),
            ("{why=\"error_frame\"}", c.can_error_frames),
            ("{why=\"tx_refused\"}", c.can_tx_refused),
            ("{why=\"error_passive\"}", c.can_error_passive),
        ],
    );
    counter(
        "board_seq_errors",
        "Sequence errors the motor board counted in our commands.",
        &[("", c.board_seq_errors)],
    );
    counter("poses_implausible", "Robot poses discarded as implausible.", &[("", c.poses_implausible)]);
    counter("planner_invalid", "Cycles the planner could not command.", &[("", c.planner_invalid)]);
    counter(
        "supervisor_interventions",
        "Cycles whose command the safety supervisor changed, by how.",
        &[("{how=\"slowed\"}", c.supervisor_slowed), ("{how=\"braking\"}", c.supervisor_braking)],
    );
    counter(
        "obstacle_outran_robot",
        "Cycles in which an obstacle outran what the robot can deliver.",
        &[("", c.obstacle_outran_robot)],
    );
    counter(
        "goal_occupied",
        "Cycles the robot held still while the goal was inside an obstacle's planning circle.",
        &[("", c.goal_occupied)],
    );
    counter(
        "planner_flags",
        "Cycles whose plan raised a planner flag, by flag.",
        &[
            ("{flag=\"saturated\"}", c.planner_saturated),
            ("{flag=\"tie_break\"}", c.planner_tie_break),
            ("{flag=\"margin_shrunk\"}", c.planner_margin_shrunk),
            ("{flag=\"unclosed_at_a_wall\"}", c.planner_unclosed_at_a_wall),
        ],
    );
    counter("telemetry_dropped", "Telemetry records dropped (queue full).", &[("", c.telemetry_dropped)]);

    counter("view_frames_dropped", "Live-view frames a slow client skipped.", &[("", s.view_frames_dropped)]);
}

/// Faults and orderly stops, by reason.
fn write_stops(out: &mut String, s: &Snapshot) {
    for (family, help, faults) in
        [("faults", "Faults (latched until reset), by reason.", true), ("stops", "Orderly stops, by reason.", false)]
    {
        let _ = writeln!(out, "# HELP flowgate_{family}_total {help}");
        let _ = writeln!(out, "# TYPE flowgate_{family}_total counter");
        // Every reason from the start, at 0 until it happens: a rate() over it is defined.
        for reason in StopReason::ALL.iter().filter(|r| r.is_fault() == faults) {
            let name = reason.snake_name();
            let n = s.stops.iter().find(|(r, ..)| *r == name).map_or(0, |(.., n)| *n);
            let _ = writeln!(out, "flowgate_{family}_total{{reason=\"{name}\"}} {n}");
        }
    }
}

/// The safety state and the uptime.
fn write_gauges(out: &mut String, s: &Snapshot) {
    let _ = writeln!(out, "# HELP flowgate_state The safety state (1 for the current one).");
    let _ = writeln!(out, "# TYPE flowgate_state gauge");
    let now = s.state.name();
    for st in STATES {
        let _ = writeln!(out, "flowgate_state{{state=\"{st}\"}} {}", u8::from(st == now));
    }
    let _ = writeln!(out, "# HELP flowgate_uptime_seconds Seconds since the gateway started.");
    let _ = writeln!(out, "# TYPE flowgate_uptime_seconds gauge");
    let _ = writeln!(out, "flowgate_uptime_seconds {:.3}", s.uptime_s);
    let commit = env!("FLOWGATE_COMMIT").trim_start_matches("commit ");
    let _ = writeln!(out, "# HELP flowgate_build_info The build: version and git commit (always 1).");
    let _ = writeln!(out, "# TYPE flowgate_build_info gauge");
    let _ = writeln!(out, "flowgate_build_info{{version=\"{}\",commit=\"{commit}\"}} 1", env!("CARGO_PKG_VERSION"));
}

/// Cumulative buckets of `h` (ns) at `bounds` (s), with `labels` before `le`.
fn write_buckets(out: &mut String, name: &str, labels: &str, h: &Histogram<u64>, bounds: &[f64]) {
    for le in bounds {
        let bound_ns = (le * 1e9) as u64;
        let count: u64 =
            h.iter_recorded().filter(|v| v.value_iterated_to() <= bound_ns).map(|v| v.count_at_value()).sum();
        let _ = writeln!(out, "{name}_bucket{{{labels}le=\"{le}\"}} {count}");
    }
    let _ = writeln!(out, "{name}_bucket{{{labels}le=\"+Inf\"}} {}", h.len());
    let sum_s: f64 =
        h.iter_recorded().map(|v| v.value_iterated_to() as f64 * v.count_at_value() as f64).sum::<f64>() / 1e9;
    let braces = labels.trim_end_matches(',');
    let braces = if braces.is_empty() { String::new() } else { format!("{{{braces}}}") };
    let _ = writeln!(out, "{name}_sum{braces} {sum_s}");
    let _ = writeln!(out, "{name}_count{braces} {}", h.len());
}

/// Each stage's duration as a cumulative histogram, by stage.
fn write_stages(out: &mut String, stages: &[Histogram<u64>; Stage::COUNT]) {
    let _ = writeln!(out, "# HELP flowgate_stage_seconds Each stage of a cycle: how long it took.");
    let _ = writeln!(out, "# TYPE flowgate_stage_seconds histogram");
    for (stage, h) in Stage::ALL.iter().zip(stages) {
        write_buckets(out, "flowgate_stage_seconds", &format!("stage=\"{}\",", stage.name()), h, &STAGE_BUCKETS_S);
    }
}

/// The process's own figures, as Prometheus's client libraries name them (read from /proc
/// when scraped, never by the loop).
fn write_process(out: &mut String, start_time_s: f64) {
    let mut gauge = |name: &str, kind: &str, help: &str, v: Option<f64>| {
        if let Some(v) = v {
            let _ = writeln!(out, "# HELP {name} {help}");
            let _ = writeln!(out, "# TYPE {name} {kind}");
            let _ = writeln!(out, "{name} {v}");
        }
    };
    let stat = std::fs::read_to_string("/proc/self/stat").ok();
    // Fields after the command's closing parenthesis: utime and stime are the 12th and 13th.
    let cpu = stat.as_deref().and_then(|s| {
        let fields: Vec<&str> = s.rsplit_once(')')?.1.split_whitespace().collect();
        let ticks = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
        Some(ticks / rustix::param::clock_ticks_per_second() as f64)
    });
    gauge("process_cpu_seconds_total", "counter", "User and system CPU time spent, s.", cpu);
    let rss = std::fs::read_to_string("/proc/self/status").ok().and_then(|s| {
        let kib = s.lines().find_map(|l| l.strip_prefix("VmRSS:"))?.trim().trim_end_matches("kB").trim();
        Some(kib.parse::<f64>().ok()? * 1024.0)
    });
    gauge("process_resident_memory_bytes", "gauge", "Resident memory, bytes.", rss);
    let fds = std::fs::read_dir("/proc/self/fd").ok().map(|d| d.count() as f64);
    gauge("process_open_fds", "gauge", "Open file descriptors.", fds);
    let max_fds = rustix::process::getrlimit(rustix::process::Resource::Nofile).current.map(|n| n as f64);
    gauge("process_max_fds", "gauge", "The most file descriptors it may open.", max_fds);
    gauge(
        "process_start_time_seconds",
        "gauge",
        "When the gateway started, s since the Unix epoch.",
        Some(start_time_s),
    );
}

/// The end-to-end latency as a cumulative histogram.
fn write_latency(out: &mut String, h: &Histogram<u64>) {
    let _ = writeln!(
        out,
        "# HELP flowgate_cycle_latency_seconds End-to-end cycle latency: serial frame read to CAN write done."
    );
    let _ = writeln!(out, "# TYPE flowgate_cycle_latency_seconds histogram");
    write_buckets(out, "flowgate_cycle_latency_seconds", "", h, &BUCKETS_S);
}

/// Serve `/metrics` on `listener` from the latest snapshot, until the channel closes.
pub async fn serve(listener: TcpListener, snapshots: watch::Receiver<Arc<Snapshot>>) {
    loop {
        let Ok((stream, _)) = listener.accept().await else { continue };
        let latest = snapshots.borrow().clone();
        tokio::spawn(async move {
            if let Err(e) = tokio::time::timeout(CLIENT_DEADLINE, answer(stream, &latest)).await {
                tracing::debug!("metrics client: {e}");
            }
        });
    }
}

async fn answer(mut stream: TcpStream, snapshot: &Snapshot) -> std::io::Result<()> {
    match http::read_request(&mut stream).await? {
        None => Ok(()),
        Some(Asked::Get(path)) if path == "/metrics" => {
            let body = render(snapshot);
            http::reply(&mut stream, "200 OK", "text/plain; version=0.0.4; charset=utf-8", body.as_bytes()).await
        }
        Some(Asked::Get(_)) => {
            http::reply(&mut stream, "404 Not Found", "text/plain", b"only /metrics is served here\n").await
        }
        Some(Asked::Other) => http::method_not_allowed(&mut stream).await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_counters_state_and_a_cumulative_histogram() {
        let mut e2e = Histogram::new_with_bounds(1, 60_000_000_000, 3).unwrap();
        for ns in [15_000u64, 40_000, 40_000, 3_000_000] {
            e2e.record(ns).unwrap();
        }
        let s = Snapshot {
            state: State::Running,
            counters: Counters { cycles: 4, psd_duplicates: 2, ..Counters::default() },
            e2e_ns: e2e,
            deadline_misses: 0,
            uptime_s: 12.5,
            stops: vec![("pose_lost".into(), true, 2), ("goal_reached".into(), false, 1)],
            view_frames_dropped: 3,
            ..Snapshot::empty(1_700_000_000.0)
        };
        let text = render(&s);
        assert!(text.contains("flowgate_cycles_total 4\n"), "{text}");
        assert!(text.contains("flowgate_faults_total{reason=\"pose_lost\"} 2\n"), "{text}");
        assert!(text.contains("flowgate_stops_total{reason=\"goal_reached\"} 1\n"), "{text}");
        assert!(text.contains("flowgate_view_frames_dropped_total 3\n"), "{text}");
        assert!(text.contains("flowgate_psd_discarded_total{why=\"duplicate\"} 2\n"), "{text}");
        assert!(text.contains("flowgate_state{state=\"running\"} 1\nflowgate_state{state=\"stopping\"} 0\n"), "{text}");
        assert!(text.contains("flowgate_cycle_latency_seconds_bucket{le=\"0.00002\"} 1\n"), "{text}");
        assert!(text.contains("flowgate_cycle_latency_seconds_bucket{le=\"0.00005\"} 3\n"), "{text}");
        assert!(text.contains("flowgate_cycle_latency_seconds_bucket{le=\"+Inf\"} 4\n"), "{text}");
        assert!(text.contains("flowgate_cycle_latency_seconds_count 4\n"), "{text}");
        // Every reason from the start, at 0 until it happens.
        assert!(text.contains("flowgate_faults_total{reason=\"heartbeat_lost\"} 0\n"), "{text}");
        assert!(text.contains("flowgate_stops_total{reason=\"shutdown\"} 0\n"), "{text}");
        assert!(text.contains("flowgate_build_info{version=\""), "{text}");
        assert!(text.contains("flowgate_stage_seconds_bucket{stage=\"plan\",le=\"0.000001\"} 0\n"), "{text}");
        assert!(text.contains("process_start_time_seconds 1700000000\n"), "{text}");
        assert!(text.contains("process_open_fds "), "{text}");
    }
}
