//! `/metrics`: the gateway's counters and cycle latency in the OpenMetrics text format
//! (which Prometheus scrapes), encoded by Prometheus's own Rust client (`prometheus-client`),
//! for the monitoring a lab already runs.
//!
//! The loop never serves a scrape itself. About once a second it publishes a [`Snapshot`]
//! (its counters, its state and a copy of its latency histogram: one allocation a second,
//! none per cycle) into a `watch` channel; the HTTP task renders the latest one for each
//! request. A slow or stuck client costs the loop nothing, and a scrape is at most a second
//! old.

use std::fmt;
use std::sync::Arc;
use std::time::Duration;

use hdrhistogram::Histogram;
use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, EncodeMetric, MetricEncoder, NoLabelSet};
use prometheus_client::metrics::counter::ConstCounter;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::metrics::MetricType;
use prometheus_client::registry::Registry;
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
    /// Each of the rig's other vehicles (`[[vehicles]]`) by name, and its state.
    pub vehicles: Vec<(String, State)>,
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
            vehicles: Vec::new(),
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

/// The HTTP content type of [`render`]'s text.
pub const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// The snapshot in the OpenMetrics text format (Prometheus scrapes it as it is), encoded
/// by Prometheus's own Rust client.
pub fn render(snapshot: Arc<Snapshot>) -> String {
    let mut registry = Registry::default();
    registry.register_collector(Box::new(Scrape(snapshot)));
    let mut out = String::with_capacity(8192);
    // Writing into a String cannot fail.
    let _ = prometheus_client::encoding::text::encode(&mut out, &registry);
    out
}

/// One scrape's metrics, all read from one snapshot.
#[derive(Debug)]
struct Scrape(Arc<Snapshot>);

impl Collector for Scrape {
    fn encode(&self, mut encoder: DescriptorEncoder<'_>) -> fmt::Result {
        let s = &*self.0;
        encode_counters(&mut encoder, s)?;
        encode_stops(&mut encoder, s)?;
        encode_gauges(&mut encoder, s)?;
        let family = encoder.encode_descriptor(
            "flowgate_cycle_latency_seconds",
            "End-to-end cycle latency: serial frame read to CAN write done.",
            None,
            MetricType::Histogram,
        )?;
        Buckets { histogram: &s.e2e_ns, bounds: &BUCKETS_S }.encode(family)?;
        let mut family = encoder.encode_descriptor(
            "flowgate_stage_seconds",
            "Each stage of a cycle: how long it took.",
            None,
            MetricType::Histogram,
        )?;
        for (stage, h) in Stage::ALL.iter().zip(&s.stages) {
            Buckets { histogram: h, bounds: &STAGE_BUCKETS_S }
                .encode(family.encode_family(&[("stage", stage.name())])?)?;
        }
        encode_process(&mut encoder, s.start_time_s)
    }
}

/// A counter of one sample.
fn counter(encoder: &mut DescriptorEncoder<'_>, name: &str, help: &str, value: u64) -> fmt::Result {
    ConstCounter::new(value).encode(encoder.encode_descriptor(name, help, None, MetricType::Counter)?)
}

/// A counter family with a sample for each value of the label `key`.
fn counter_by(
    encoder: &mut DescriptorEncoder<'_>,
    name: &str,
    help: &str,
    key: &str,
    samples: &[(&str, u64)],
) -> fmt::Result {
    let mut family = encoder.encode_descriptor(name, help, None, MetricType::Counter)?;
    samples.iter().try_for_each(|&(value, v)| ConstCounter::new(v).encode(family.encode_family(&[(key, value)])?))
}

/// The counters of everything unusual (`_total` each).
fn encode_counters(encoder: &mut DescriptorEncoder<'_>, s: &Snapshot) -> fmt::Result {
    let c = &s.counters;
    counter(encoder, "flowgate_cycles", "Control cycles run (commands computed).", c.cycles)?;
    counter(encoder, "flowgate_samples", "PSD samples received.", c.samples)?;
    counter(
        encoder,
        "flowgate_deadline_misses",
        "Cycles whose end-to-end latency exceeded the control period.",
        s.deadline_misses,
    )?;
    counter_by(
        encoder,
        "flowgate_psd_discarded",
        "Controller packets and samples discarded, by why.",
        "why",
        &[
            ("bad_frame", c.bad_serial_frames),
            ("duplicate", c.psd_duplicates),
            ("out_of_order", c.psd_out_of_order),
            ("unsynced", c.samples_unsynced),
            ("from_future", c.samples_from_future),
            ("unscheduled", c.samples_unscheduled),
            ("frame_repeated", c.frames_repeated),
        ],
    )?;
    counter(encoder, "flowgate_psd_packets_lost", "Controller packets lost (sequence gaps).", c.psd_packets_lost)?;
    counter(encoder, "flowgate_frames_lost", "Time-division frames that never ended.", c.frames_lost)?;
    counter(
        encoder,
        "flowgate_serial_dropped_bytes",
        "Serial bytes dropped while resynchronising.",
        c.serial_dropped_bytes,
    )?;
    counter_by(
        encoder,
        "flowgate_reconnects",
        "Links lost and opened again.",
        "link",
        &[("serial", c.serial_reconnects), ("can", c.can_reconnects)],
    )?;
    counter_by(
        encoder,
        "flowgate_can_ignored",
        "CAN frames and events ignored, by why.",
        "why",
        &[
            ("foreign", c.can_foreign),
            ("undecodable", c.can_undecodable),
            ("error_frame", c.can_error_frames),
            ("tx_refused", c.can_tx_refused),
            ("error_passive", c.can_error_passive),
        ],
    )?;
    encode_control_counters(encoder, s)?;
    counter(encoder, "flowgate_view_frames_dropped", "Live-view frames a slow client skipped.", s.view_frames_dropped)
}

/// The counters of the motors, the tracker, the planner and the supervisor.
fn encode_control_counters(encoder: &mut DescriptorEncoder<'_>, s: &Snapshot) -> fmt::Result {
    let c = &s.counters;
    counter(
        encoder,
        "flowgate_board_seq_errors",
        "Sequence errors the motor board counted in our commands.",
        c.board_seq_errors,
    )?;
    counter(encoder, "flowgate_poses_implausible", "Robot poses discarded as implausible.", c.poses_implausible)?;
    counter(encoder, "flowgate_planner_invalid", "Cycles the planner could not command.", c.planner_invalid)?;
    counter_by(
        encoder,
        "flowgate_supervisor_interventions",
        "Cycles whose command the safety supervisor changed, by how.",
        "how",
        &[("slowed", c.supervisor_slowed), ("braking", c.supervisor_braking), ("evaded", c.supervisor_evaded)],
    )?;
    counter(
        encoder,
        "flowgate_outside_commands",
        "Commands taken from a planner outside flowgate (planner.method).",
        c.outside_commands,
    )?;
    counter(
        encoder,
        "flowgate_outside_commands_saturated",
        "Cycles that drove on an outside planner's command beyond the robot's limits, scaled down to them.",
        c.outside_commands_saturated,
    )?;
    counter(
        encoder,
        "flowgate_obstacle_outran_robot",
        "Cycles in which an obstacle outran what the robot can deliver.",
        c.obstacle_outran_robot,
    )?;
    counter(
        encoder,
        "flowgate_goal_occupied",
        "Cycles the robot held still while the goal was inside an obstacle's planning circle.",
        c.goal_occupied,
    )?;
    counter_by(
        encoder,
        "flowgate_planner_flags",
        "Cycles whose plan raised a planner flag, by flag.",
        "flag",
        &[
            ("saturated", c.planner_saturated),
            ("tie_break", c.planner_tie_break),
            ("margin_shrunk", c.planner_margin_shrunk),
            ("unclosed_at_a_wall", c.planner_unclosed_at_a_wall),
        ],
    )?;
    counter(encoder, "flowgate_telemetry_dropped", "Telemetry records dropped (queue full).", c.telemetry_dropped)?;
    counter(
        encoder,
        "flowgate_requests_expired",
        "Operator requests dropped unanswered: their client had been told they failed.",
        c.requests_expired,
    )?;
    counter_by(
        encoder,
        "flowgate_control_clients_closed",
        "Control-socket connections closed by the gateway, by why.",
        "why",
        &[
            ("evicted", c.control_clients_evicted),
            ("timed_out", c.control_clients_timed_out),
            ("refused", c.control_clients_refused),
        ],
    )?;
    Ok(())
}

/// Faults and orderly stops, by reason: every reason from the start, at 0 until it
/// happens, so a rate() over it is defined.
fn encode_stops(encoder: &mut DescriptorEncoder<'_>, s: &Snapshot) -> fmt::Result {
    for (family, help, faults) in [
        ("flowgate_faults", "Faults (latched until reset), by reason.", true),
        ("flowgate_stops", "Orderly stops, by reason.", false),
    ] {
        let names: Vec<String> =
            StopReason::ALL.iter().filter(|r| r.is_fault() == faults).map(|r| r.snake_name()).collect();
        let samples: Vec<(&str, u64)> = names
            .iter()
            .map(|name| (name.as_str(), s.stops.iter().find(|(r, ..)| r == name).map_or(0, |(.., n)| *n)))
            .collect();
        counter_by(encoder, family, help, "reason", &samples)?;
    }
    Ok(())
}

/// The safety state, the uptime and the build.
fn encode_gauges(encoder: &mut DescriptorEncoder<'_>, s: &Snapshot) -> fmt::Result {
    let mut state = encoder.encode_descriptor(
        "flowgate_state",
        "The safety state (1 for the current one).",
        None,
        MetricType::Gauge,
    )?;
    let now = s.state.name();
    for st in STATES {
        ConstGauge::new(i64::from(st == now)).encode(state.encode_family(&[("state", st)])?)?;
    }
    if !s.vehicles.is_empty() {
        let mut vehicles = encoder.encode_descriptor(
            "flowgate_vehicle_state",
            "Each of the rig's other vehicles' safety state (1 for the current one), by its name.",
            None,
            MetricType::Gauge,
        )?;
        for (name, state) in &s.vehicles {
            for st in STATES {
                let labels = [("vehicle", name.as_str()), ("state", st)];
                ConstGauge::new(i64::from(st == state.name())).encode(vehicles.encode_family(&labels)?)?;
            }
        }
    }
    let uptime = encoder.encode_descriptor(
        "flowgate_uptime_seconds",
        "Seconds since the gateway started.",
        None,
        MetricType::Gauge,
    )?;
    ConstGauge::new(s.uptime_s).encode(uptime)?;
    let commit = env!("FLOWGATE_COMMIT").trim_start_matches("commit ");
    let mut build =
        encoder.encode_descriptor("flowgate_build", "The build: version and git commit.", None, MetricType::Info)?;
    build.encode_info(&[("version", env!("CARGO_PKG_VERSION")), ("commit", commit)])
}

/// An hdrhistogram of ns as a Prometheus histogram of seconds with these bucket bounds.
#[derive(Debug)]
struct Buckets<'a> {
    histogram: &'a Histogram<u64>,
    bounds: &'a [f64],
}

impl EncodeMetric for Buckets<'_> {
    fn encode(&self, mut encoder: MetricEncoder<'_>) -> fmt::Result {
        let h = self.histogram;
        let mut below = 0;
        // Each bucket's own count (the encoder sums them), then the rest in +Inf.
        let mut buckets: Vec<(f64, u64)> = self
            .bounds
            .iter()
            .map(|&le| {
                let bound_ns = (le * 1e9) as u64;
                let n: u64 =
                    h.iter_recorded().filter(|v| v.value_iterated_to() <= bound_ns).map(|v| v.count_at_value()).sum();
                let own = n - below;
                below = n;
                (le, own)
            })
            .collect();
        buckets.push((f64::MAX, h.len() - below));
        let sum_s =
            h.iter_recorded().map(|v| v.value_iterated_to() as f64 * v.count_at_value() as f64).sum::<f64>() / 1e9;
        encoder.encode_histogram::<NoLabelSet>(sum_s, h.len(), &buckets, None)
    }

    fn metric_type(&self) -> MetricType {
        MetricType::Histogram
    }
}

/// The process's own figures, as Prometheus's client libraries name them (read from /proc
/// when scraped, never by the loop).
fn encode_process(encoder: &mut DescriptorEncoder<'_>, start_time_s: f64) -> fmt::Result {
    let stat = std::fs::read_to_string("/proc/self/stat").ok();
    // Fields after the command's closing parenthesis: utime and stime are the 12th and 13th.
    let cpu = stat.as_deref().and_then(|s| {
        let fields: Vec<&str> = s.rsplit_once(')')?.1.split_whitespace().collect();
        let ticks = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
        Some(ticks / rustix::param::clock_ticks_per_second() as f64)
    });
    if let Some(cpu) = cpu {
        let family = encoder.encode_descriptor(
            "process_cpu_seconds",
            "User and system CPU time spent, s.",
            None,
            MetricType::Counter,
        )?;
        ConstCounter::new(cpu).encode(family)?;
    }
    let rss = std::fs::read_to_string("/proc/self/status").ok().and_then(|s| {
        let kib = s.lines().find_map(|l| l.strip_prefix("VmRSS:"))?.trim().trim_end_matches("kB").trim();
        Some(kib.parse::<f64>().ok()? * 1024.0)
    });
    let fds = std::fs::read_dir("/proc/self/fd").ok().map(|d| d.count() as f64);
    let max_fds = rustix::process::getrlimit(rustix::process::Resource::Nofile).current.map(|n| n as f64);
    for (name, help, value) in [
        ("process_resident_memory_bytes", "Resident memory, bytes.", rss),
        ("process_open_fds", "Open file descriptors.", fds),
        ("process_max_fds", "The most file descriptors it may open.", max_fds),
        ("process_start_time_seconds", "When the gateway started, s since the Unix epoch.", Some(start_time_s)),
    ] {
        if let Some(v) = value {
            ConstGauge::new(v).encode(encoder.encode_descriptor(name, help, None, MetricType::Gauge)?)?;
        }
    }
    Ok(())
}

/// Serve `/metrics` on `listener` from the latest snapshot, until the channel closes.
pub async fn serve(listener: TcpListener, snapshots: watch::Receiver<Arc<Snapshot>>) {
    loop {
        let Ok((stream, _)) = listener.accept().await else { continue };
        let latest = snapshots.borrow().clone();
        tokio::spawn(async move {
            if let Err(e) = tokio::time::timeout(CLIENT_DEADLINE, answer(stream, latest)).await {
                tracing::debug!("metrics client: {e}");
            }
        });
    }
}

async fn answer(mut stream: TcpStream, snapshot: Arc<Snapshot>) -> std::io::Result<()> {
    match http::read_request(&mut stream).await? {
        None => Ok(()),
        Some(Asked::Get(path)) if path == "/metrics" => {
            let body = render(snapshot);
            http::reply(&mut stream, "200 OK", CONTENT_TYPE, body.as_bytes()).await
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
            vehicles: vec![("v1".into(), State::Armed)],
            ..Snapshot::empty(1_700_000_000.0)
        };
        let text = render(Arc::new(s));
        assert!(text.contains("flowgate_vehicle_state{vehicle=\"v1\",state=\"armed\"} 1\n"), "{text}");
        assert!(text.contains("flowgate_vehicle_state{vehicle=\"v1\",state=\"running\"} 0\n"), "{text}");
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
        assert!(text.contains("flowgate_stage_seconds_bucket{le=\"0.000001\",stage=\"plan\"} 0\n"), "{text}");
        assert!(text.contains("process_start_time_seconds 1700000000.0\n"), "{text}");
        assert!(text.contains("process_open_fds "), "{text}");
        assert!(text.ends_with("# EOF\n"), "an OpenMetrics exposition ends so: {text}");
    }
}
