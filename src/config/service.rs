//! `[operator]`, `[telemetry]` and `[realtime]`: how the gateway serves its operator and its
//! host.

use super::checks::{invalid, Invalid};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::PathBuf;
use std::time::Duration;

/// How the gateway trades CPU for latency on a rig that gives it a core.
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RealtimeSection {
    /// Low-latency mode: poll for the next frame from this long before it is due until this
    /// long after, instead of sleeping (src/gateway/shell/low_latency.rs); 0 = off (default). Costs
    /// about (spin_us + 1 ms) / T of a core (`flowgate bench` measures it).
    #[serde(default)]
    pub spin_us: u32,
    /// With the low-latency mode: as each window opens, run the cycle's code (decode,
    /// calibration, tracking, the plan, the supervisor, encoding) once on the last state and
    /// discard the result, so that code and its data are in cache when the frame comes
    /// ([`crate::gateway::core::Core::rehearse`]). Off by default.
    #[serde(default)]
    pub warm_up: bool,
    /// Run the control loop on these CPUs only (e.g. `[3]`, a core kept free with
    /// `isolcpus=`); empty = anywhere (default).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cpus: Vec<usize>,
    /// `SCHED_FIFO` priority of the control loop, 1-99; 0 = the normal policy (default).
    /// Needs CAP_SYS_NICE or `LimitRTPRIO=` in the unit.
    #[serde(default)]
    pub fifo_priority: u8,
    /// Lock the gateway's memory (`mlockall`): no page faults on the rig path. Needs
    /// CAP_IPC_LOCK or `LimitMEMLOCK=infinity` in the unit.
    #[serde(default)]
    pub lock_memory: bool,
}

/// The local control interface: the only way to command motion.
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OperatorSection {
    /// The control socket (a unix socket, mode 0660); none = no control interface.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub socket: Option<PathBuf>,
    /// The group that may use it (by name, from /etc/group); default: the gateway's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
    /// Serve `/metrics` (OpenMetrics text, for Prometheus) here, e.g. `127.0.0.1:9187`; none = not served.
    /// Read-only; keep it on loopback unless the network is the lab's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metrics: Option<std::net::SocketAddr>,
    /// Serve the live view (a page drawing the arena, updated live) here, e.g.
    /// `127.0.0.1:8080`; none = not served. Read-only, like `metrics`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<std::net::SocketAddr>,
    /// Serve the recording's channels live over the Foxglove WebSocket protocol here, e.g.
    /// `127.0.0.1:8765` (Foxglove's default): Foxglove connects to the running gateway.
    /// None = not served. Read-only, like `metrics`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub foxglove: Option<std::net::SocketAddr>,
}

/// Largest telemetry queue accepted, records.
pub(super) const MAX_QUEUE: usize = 1 << 20;

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TelemetrySection {
    /// Where trace.json, cycles.csv and can.log go; none = no files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub out_dir: Option<PathBuf>,
    /// An MCAP recording of the run (`flowgate run --record`): every input the core took,
    /// what it sent, each cycle's scene; `flowgate replay` plays it back.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub record: Option<PathBuf>,
    /// How the recording's chunks are compressed: `zstd` (default), `lz4` or `none`.
    /// Recordings are read whatever their compression.
    #[serde(default)]
    pub record_compression: RecordCompression,
    /// Capacity of the queue to the writer task (records beyond it are dropped and counted).
    #[serde(default = "default_queue")]
    pub queue: usize,
}

/// The compression of a recording's chunks.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RecordCompression {
    #[default]
    Zstd,
    Lz4,
    None,
}

pub(super) fn default_queue() -> usize {
    8192
}

impl Default for TelemetrySection {
    fn default() -> Self {
        Self { out_dir: None, record: None, record_compression: RecordCompression::default(), queue: default_queue() }
    }
}

impl OperatorSection {
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        if self.socket.as_ref().is_some_and(|p| p.as_os_str().is_empty()) {
            return invalid("operator.socket", "is empty");
        }
        Ok(())
    }
}

impl TelemetrySection {
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        if self.queue == 0 || self.queue > MAX_QUEUE {
            return invalid("telemetry.queue", format!("must be 1-{MAX_QUEUE} records, is {}", self.queue));
        }
        Ok(())
    }
}

impl RealtimeSection {
    pub(super) fn validate(&self, sample_period: Duration) -> Result<(), Invalid> {
        let spin = Duration::from_micros(u64::from(self.spin_us));
        if spin * 2 >= sample_period {
            return invalid(
                "realtime.spin_us",
                format!(
                    "{} µs: the window (twice it) must be shorter than the control period T = {} µs, or the gateway \
                     never sleeps",
                    self.spin_us,
                    sample_period.as_micros()
                ),
            );
        }
        if self.warm_up && self.spin_us == 0 {
            return invalid(
                "realtime.warm_up",
                "warms the cycle up as the low-latency window opens: set realtime.spin_us too",
            );
        }
        if self.fifo_priority > 99 {
            return invalid("realtime.fifo_priority", format!("must be 1-99 (0: off), is {}", self.fifo_priority));
        }
        for (i, &cpu) in self.cpus.iter().enumerate() {
            if cpu >= rustix::thread::CpuSet::MAX_CPU {
                return invalid(&format!("realtime.cpus[{i}]"), format!("CPU {cpu} is beyond what Linux numbers"));
            }
            if self.cpus[..i].contains(&cpu) {
                return invalid(&format!("realtime.cpus[{i}]"), format!("CPU {cpu} is listed twice"));
            }
        }
        Ok(())
    }

    pub(super) fn settings(&self) -> RealtimeSettings {
        RealtimeSettings {
            cpus: self.cpus.clone(),
            fifo_priority: (self.fifo_priority > 0).then_some(self.fifo_priority),
            lock_memory: self.lock_memory,
        }
    }
}

/// The real-time settings of `[realtime]`, as checked at load (applied by
/// `gateway::realtime`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RealtimeSettings {
    /// Run the control loop on these CPUs only (empty: wherever the scheduler likes).
    pub cpus: Vec<usize>,
    /// `SCHED_FIFO` at this priority (1-99) for the control loop.
    pub fifo_priority: Option<u8>,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)`: no page fault on the rig path.
    pub lock_memory: bool,
}

impl RealtimeSettings {
    pub fn is_empty(&self) -> bool {
        self.cpus.is_empty() && self.fifo_priority.is_none() && !self.lock_memory
    }
}

impl fmt::Display for RealtimeSettings {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut parts = Vec::new();
        if !self.cpus.is_empty() {
            parts.push(format!("CPUs {:?}", self.cpus));
        }
        if let Some(p) = self.fifo_priority {
            parts.push(format!("SCHED_FIFO {p}"));
        }
        if self.lock_memory {
            parts.push("memory locked".to_string());
        }
        if parts.is_empty() {
            f.write_str("none")
        } else {
            f.write_str(&parts.join(", "))
        }
    }
}
