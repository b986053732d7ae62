//! The report of a run: its final state and transitions, the timing of its cycles, its
//! counters and the files it wrote. The rig's shell and the virtual rig both end with one.

use serde::Serialize;

use super::telemetry::WrittenFiles;
use crate::gateway::core::timing::{self, Distribution, StageSummary, Timing};
use crate::gateway::core::{Core, Counters, StageClock, State, StopReason};

/// The run's report.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub final_state: State,
    pub stop_reason: Option<StopReason>,
    pub transitions: Vec<(f64, State)>,
    pub e2e: Distribution,
    pub period: Distribution,
    pub deadline_misses: u64,
    /// Each stage of a cycle: min, p50, p99, max, mean, jitter (σ), µs (empty in virtual
    /// time, where the stages take none).
    pub stages: Vec<StageSummary>,
    /// The control period the schedule gives, s.
    pub sample_time: f64,
    pub counters: Counters,
    pub files: WrittenFiles,
}

impl Report {
    /// The report as `report.json` in `dir`, beside a run's other files; its path.
    pub fn write_json(&self, dir: &std::path::Path) -> std::io::Result<std::path::PathBuf> {
        let path = dir.join("report.json");
        std::fs::write(&path, serde_json::to_string_pretty(self)?)?;
        Ok(path)
    }

    /// The report of a run that ended with `core` in its final state; `counters` are the
    /// core's with the shell's own counts added.
    pub fn new<K: StageClock>(
        core: &Core<K>,
        timing: Option<&Timing>,
        counters: Counters,
        files: WrittenFiles,
    ) -> Self {
        let state = core.state();
        Report {
            final_state: state,
            stop_reason: state.reason(),
            transitions: core.safety().history.clone(),
            e2e: timing.map(Timing::e2e).unwrap_or_default(),
            period: timing.map(Timing::period).unwrap_or_default(),
            deadline_misses: timing.map_or(0, |t| t.deadline_misses),
            stages: timing.map(Timing::stages).unwrap_or_default(),
            sample_time: core.rig().sample_period.as_secs_f64(),
            counters,
            files,
        }
    }
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.counters;
        writeln!(f, "final state      {}", self.final_state)?;
        writeln!(
            f,
            "cycles           {} at T = {:.1} ms, {} deadline misses (e2e > T)",
            c.cycles,
            self.sample_time * 1e3,
            self.deadline_misses
        )?;
        writeln!(
            f,
            "e2e latency      p50 {:.0} µs  p99 {:.0} µs  p99.9 {:.0} µs  max {:.0} µs   (serial frame read -> CAN write done)",
            self.e2e.p50_us, self.e2e.p99_us, self.e2e.p999_us, self.e2e.max_us
        )?;
        writeln!(
            f,
            "command period   p50 {:.2} ms  p99 {:.2} ms  max {:.2} ms  jitter (σ) {:.0} µs",
            self.period.p50_us / 1e3,
            self.period.p99_us / 1e3,
            self.period.max_us / 1e3,
            self.period.stdev_us
        )?;
        if self.stages.iter().any(|s| s.max_us > 0.0) {
            timing::write_stage_table(f, &self.stages, "stages (µs)      ")?;
        }
        writeln!(
            f,
            "serial           {} samples, {} bad frames, {} bytes dropped, {} reconnects",
            c.samples, c.bad_serial_frames, c.serial_dropped_bytes, c.serial_reconnects
        )?;
        writeln!(
            f,
            "                 {} samples before time sync, {} stamped in the future (discarded)",
            c.samples_unsynced, c.samples_from_future
        )?;
        writeln!(
            f,
            "psd link         {} packets lost, {} duplicated, {} out of order; frames: {} lost, {} repeated, {} incomplete; {} unscheduled samples",
            c.psd_packets_lost,
            c.psd_duplicates,
            c.psd_out_of_order,
            c.frames_lost,
            c.frames_repeated,
            c.frames_incomplete,
            c.samples_unscheduled
        )?;
        writeln!(
            f,
            "can              {} frames in, {} from other nodes, {} undecodable, {} error frames (all ignored)",
            c.can_frames_in, c.can_foreign, c.can_undecodable, c.can_error_frames
        )?;
        writeln!(f, "telemetry        {} records dropped (queue full)", c.telemetry_dropped)?;
        write!(
            f,
            "operator         {} requests dropped (expired before taken), control socket: {} connections closed to make room, {} timed out, {} refused",
            c.requests_expired, c.control_clients_evicted, c.control_clients_timed_out, c.control_clients_refused
        )
    }
}
