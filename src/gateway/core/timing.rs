//! The timing of every sample: each cycle's record with its stage durations, and the run's
//! latency, period and per-stage statistics (HDR histograms).

use hdrhistogram::Histogram;
use serde::Serialize;

use super::safety::State;
use crate::time::HostTime;

/// One control cycle's timing. Times are ns since the gateway started (host monotonic clock;
/// virtual time in the deterministic simulation).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CycleRecord {
    pub cycle: u64,
    /// The controller's frame counter and the frame's end on its clock (µs).
    pub frame: u32,
    pub t_ctrl_us: u64,
    /// When the bytes completing the frame were read from the serial port.
    pub rx_ns: u64,
    /// Durations of the stages, ns: decoding the frame's packets (COBS, CRC, fields);
    /// checking them (sequence, time mapping, schedule, frame assembly); tracking (pose,
    /// obstacles); planning (the control step); encoding the command frame; writing it.
    pub decode_ns: u64,
    pub checks_ns: u64,
    pub track_ns: u64,
    pub plan_ns: u64,
    pub encode_ns: u64,
    pub can_write_ns: u64,
    /// When the CAN write completed.
    pub can_done_ns: u64,
    /// From `rx_ns` to `can_done_ns`.
    pub e2e_ns: u64,
    /// Since the previous command was written.
    pub period_ns: u64,
    pub deadline_miss: bool,
    /// Measured sensing-to-actuation delay used by the planner, s.
    pub delay_s: f64,
    pub state: State,
    pub pulses: [i32; 2],
    pub x: f64,
    pub y: f64,
    pub goal_distance: f64,
    /// The wheels' rim speeds the planner asked for (the field, or an outside planner), and
    /// those the supervisor passed, m/s: left, right.
    pub asked: [f64; 2],
    pub passed: [f64; 2],
}

impl CycleRecord {
    pub const CSV_HEADER: &'static str = "cycle,frame,t_ctrl_us,rx_ns,decode_ns,checks_ns,track_ns,plan_ns,encode_ns,can_write_ns,can_done_ns,e2e_ns,period_ns,deadline_miss,delay_s,state,pulses_left,pulses_right,x,y,goal_distance,asked_left,asked_right,passed_left,passed_right";

    /// The command frame was written: it took `write_ns` and was done at `done`.
    pub fn written(&mut self, write_ns: u64, done: HostTime, sample_period: std::time::Duration) {
        self.can_write_ns = write_ns;
        self.can_done_ns = done.as_nanos();
        self.e2e_ns = self.can_done_ns.saturating_sub(self.rx_ns);
        self.deadline_miss = u128::from(self.e2e_ns) > sample_period.as_nanos();
    }

    /// Where column `name` of `cycles.csv` is (readers find columns by name, not position).
    pub fn column(name: &str) -> Option<usize> {
        Self::CSV_HEADER.split(',').position(|c| c == name)
    }

    /// The stages in their order, named as in [`Stage`], with their durations (ns).
    pub fn stages(&self) -> [(&'static str, u64); Stage::COUNT] {
        Stage::ALL.map(|stage| (stage.name(), self.stage_ns(stage)))
    }

    pub fn stage_ns(&self, stage: Stage) -> u64 {
        match stage {
            Stage::Decode => self.decode_ns,
            Stage::Checks => self.checks_ns,
            Stage::Track => self.track_ns,
            Stage::Plan => self.plan_ns,
            Stage::Encode => self.encode_ns,
            Stage::CanWrite => self.can_write_ns,
        }
    }

    /// One `cycles.csv` row.
    pub fn csv(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.6},{},{},{},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5}",
            self.cycle,
            self.frame,
            self.t_ctrl_us,
            self.rx_ns,
            self.decode_ns,
            self.checks_ns,
            self.track_ns,
            self.plan_ns,
            self.encode_ns,
            self.can_write_ns,
            self.can_done_ns,
            self.e2e_ns,
            self.period_ns,
            u8::from(self.deadline_miss),
            self.delay_s,
            self.state.name(),
            self.pulses[0],
            self.pulses[1],
            self.x,
            self.y,
            self.goal_distance,
            self.asked[0],
            self.asked[1],
            self.passed[0],
            self.passed[1]
        )
    }
}

/// A stage of a cycle, in the order they run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// COBS, CRC and fields of the frame's packets.
    Decode,
    /// Sequence numbers, time mapping, schedule, frame assembly.
    Checks,
    /// Calibration, the robot's pose, the obstacles' Kalman filters.
    Track,
    /// The control step: margins, the navigation field, the wheels.
    Plan,
    /// The velocity command's CAN frame.
    Encode,
    /// Writing it to the CAN link (an SLCAN line, or a SocketCAN frame).
    CanWrite,
}

impl Stage {
    pub const COUNT: usize = 6;
    pub const ALL: [Stage; Self::COUNT] =
        [Stage::Decode, Stage::Checks, Stage::Track, Stage::Plan, Stage::Encode, Stage::CanWrite];

    pub fn name(self) -> &'static str {
        match self {
            Stage::Decode => "decode",
            Stage::Checks => "checks",
            Stage::Track => "track",
            Stage::Plan => "plan",
            Stage::Encode => "encode",
            Stage::CanWrite => "can_write",
        }
    }
}

/// One stage's statistics over the cycles recorded, µs. Jitter is the standard deviation of
/// its duration.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct StageSummary {
    pub stage: String,
    pub min_us: f64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub max_us: f64,
    pub mean_us: f64,
    pub jitter_us: f64,
}

/// Latency, period and per-stage statistics of a run. Everything is an HDR histogram
/// allocated up front: recording a cycle is a few array increments, no allocation, no lock,
/// no system call (benches/telemetry.rs times it).
#[derive(Debug, Clone)]
pub struct Timing {
    e2e: Histogram<u64>,
    period: Histogram<u64>,
    stages: [Histogram<u64>; Stage::COUNT],
    pub deadline_misses: u64,
    pub cycles: u64,
}

/// Histogram bounds: 1 ns to 60 s at three significant digits (0.1%; the latency and the
/// period) or two (1%, the stages: a sixth of the memory, which `ctl stats` windows copy).
fn histogram(digits: u8) -> Histogram<u64> {
    Histogram::new_with_bounds(1, 60_000_000_000, digits).expect("bounds")
}

/// Percentiles, µs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Distribution {
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
    pub mean_us: f64,
    pub stdev_us: f64,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            e2e: histogram(3),
            period: histogram(3),
            stages: std::array::from_fn(|_| histogram(2)),
            deadline_misses: 0,
            cycles: 0,
        }
    }
}

impl Timing {
    /// Count a cycle. Durations beyond the bounds are recorded at the bound (`saturating`).
    pub fn add(&mut self, c: &CycleRecord) {
        self.cycles += 1;
        self.e2e.saturating_record(c.e2e_ns.max(1));
        if c.period_ns > 0 {
            self.period.saturating_record(c.period_ns);
        }
        for (h, stage) in self.stages.iter_mut().zip(Stage::ALL) {
            h.saturating_record(c.stage_ns(stage));
        }
        self.deadline_misses += u64::from(c.deadline_miss);
    }

    /// What was recorded since `base`, an earlier copy of this (`flowgate ctl stats
    /// --reset` starts a window of the run; the run's own figures go on). Allocates: for
    /// operator requests, never per cycle.
    pub fn since(&self, base: &Timing) -> Timing {
        let mut window = self.clone();
        // Counts only grow, so every value of `base` is in `self`: subtracting cannot fail.
        let _ = window.e2e.subtract(&base.e2e);
        let _ = window.period.subtract(&base.period);
        for (h, b) in window.stages.iter_mut().zip(&base.stages) {
            let _ = h.subtract(b);
        }
        window.cycles -= base.cycles.min(window.cycles);
        window.deadline_misses -= base.deadline_misses.min(window.deadline_misses);
        window
    }

    /// Each stage's statistics, in the order they run.
    pub fn stages(&self) -> Vec<StageSummary> {
        let us = |v: u64| v as f64 / 1e3;
        self.stages
            .iter()
            .zip(Stage::ALL)
            .map(|(h, stage)| {
                let empty = h.is_empty();
                StageSummary {
                    stage: stage.name().to_string(),
                    min_us: if empty { 0.0 } else { us(h.min()) },
                    p50_us: us(h.value_at_quantile(0.5)),
                    p99_us: us(h.value_at_quantile(0.99)),
                    max_us: us(h.max()),
                    mean_us: h.mean() / 1e3,
                    jitter_us: h.stdev() / 1e3,
                }
            })
            .collect()
    }

    fn dist(h: &Histogram<u64>) -> Distribution {
        if h.is_empty() {
            return Distribution::default();
        }
        let us = |v: u64| v as f64 / 1e3;
        Distribution {
            p50_us: us(h.value_at_quantile(0.5)),
            p99_us: us(h.value_at_quantile(0.99)),
            p999_us: us(h.value_at_quantile(0.999)),
            max_us: us(h.max()),
            mean_us: h.mean() / 1e3,
            stdev_us: h.stdev() / 1e3,
        }
    }

    /// The end-to-end latency histogram itself, ns (for `/metrics`).
    pub fn e2e_histogram(&self) -> &Histogram<u64> {
        &self.e2e
    }

    /// Each stage's durations, ns, in [`Stage::ALL`]'s order.
    pub fn stage_histograms(&self) -> &[Histogram<u64>; Stage::COUNT] {
        &self.stages
    }

    pub fn e2e(&self) -> Distribution {
        Self::dist(&self.e2e)
    }
    pub fn period(&self) -> Distribution {
        Self::dist(&self.period)
    }
}

/// The per-stage table: a header line, then one line per stage, each starting with
/// `indent` (the first with `title`, padded to the same width).
pub fn write_stage_table(f: &mut impl std::fmt::Write, stages: &[StageSummary], title: &str) -> std::fmt::Result {
    let indent = " ".repeat(title.chars().count());
    writeln!(
        f,
        "{title}{:<10} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "stage", "min", "p50", "p99", "max", "mean", "jitter"
    )?;
    for s in stages {
        writeln!(
            f,
            "{indent}{:<10} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2}",
            s.stage, s.min_us, s.p50_us, s.p99_us, s.max_us, s.mean_us, s.jitter_us
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cycle(scale: u64) -> CycleRecord {
        CycleRecord {
            decode_ns: 1000 * scale,
            checks_ns: 2000 * scale,
            track_ns: 3000 * scale,
            plan_ns: 4000 * scale,
            encode_ns: 500 * scale,
            can_write_ns: 6000 * scale,
            e2e_ns: 20_000 * scale,
            period_ns: 17_000_000,
            ..CycleRecord::default()
        }
    }

    fn near(value: f64, expected: f64) -> bool {
        (value - expected).abs() <= 0.01 * expected
    }

    fn stage<'a>(stages: &'a [StageSummary], name: &str) -> &'a StageSummary {
        stages.iter().find(|s| s.stage == name).unwrap()
    }

    #[test]
    fn every_stage_is_summarised_in_order() {
        let mut t = Timing::default();
        for scale in [1, 1, 1, 3] {
            t.add(&cycle(scale));
        }
        let stages = t.stages();
        let names: Vec<&str> = stages.iter().map(|s| s.stage.as_str()).collect();
        assert_eq!(names, ["decode", "checks", "track", "plan", "encode", "can_write"]);
        let plan = stage(&stages, "plan");
        // Stage histograms keep two significant digits: values within 1%.
        assert!(near(plan.min_us, 4.0) && near(plan.p50_us, 4.0), "{plan:?}");
        assert!(near(plan.max_us, 12.0) && near(plan.p99_us, 12.0), "{plan:?}");
        assert!(near(plan.mean_us, 6.0), "{plan:?}");
        // σ of 4, 4, 4, 12 µs is sqrt(12) µs.
        assert!(near(plan.jitter_us, 12f64.sqrt()), "{plan:?}");
    }

    #[test]
    fn a_window_holds_only_what_came_after_it_began() {
        let mut t = Timing::default();
        t.add(&cycle(10));
        let base = t.clone();
        t.add(&cycle(1));
        t.add(&cycle(2));
        let window = t.since(&base);
        assert_eq!(window.cycles, 2);
        let decode = stage(&window.stages(), "decode").clone();
        assert!(near(decode.min_us, 1.0) && near(decode.max_us, 2.0), "{decode:?}");
        // The latency keeps three digits: within 0.1%.
        assert!((window.e2e().max_us - 40.0).abs() < 0.04);
        // The run's own figures keep everything.
        assert_eq!(t.cycles, 3);
        assert!(near(stage(&t.stages(), "decode").max_us, 10.0));
    }
}
