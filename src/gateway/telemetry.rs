//! Per-sample timing and run records.
//!
//! Every cycle produces one [`CycleRecord`] with its stage timings. Records and CAN frames go
//! to a writer thread through a bounded queue, so the control loop never waits on a disk:
//! when the queue is full a record is dropped and counted, and the count is reported at
//! exit. The writer drains the queue every [`DRAIN_EVERY`] instead of waiting on it, so no
//! record has to wake it: queueing one costs the loop no system call. The writer produces:
//! - `cycles.csv`: one row per cycle (columns in [`CycleRecord::CSV_HEADER`]);
//! - `trace.json`: Chrome/Perfetto trace events, one complete event per stage per cycle;
//! - `can.log`: every CAN frame sent and received, candump `-L` format;
//! - `events.log`: state changes and operator requests (who asked, and the answer).
//!
//! The loop keeps HDR histograms of end-to-end latency and command period in memory for the
//! summary printed at exit.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use flowgate_protocol::CanFrame;
use hdrhistogram::Histogram;
use serde::Serialize;
use tokio::sync::mpsc;

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
    /// Durations of the stages, ns.
    pub decode_ns: u64,
    pub track_ns: u64,
    pub plan_ns: u64,
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
}

impl CycleRecord {
    pub const CSV_HEADER: &'static str = "cycle,frame,t_ctrl_us,rx_ns,decode_ns,track_ns,plan_ns,can_write_ns,can_done_ns,e2e_ns,period_ns,deadline_miss,delay_s,state,pulses_left,pulses_right,x,y,goal_distance";

    /// The command frame was written: it took `write_ns` and was done at `done`.
    pub fn written(&mut self, write_ns: u64, done: HostTime, sample_period: std::time::Duration) {
        self.can_write_ns = write_ns;
        self.can_done_ns = done.as_nanos();
        self.e2e_ns = self.can_done_ns.saturating_sub(self.rx_ns);
        self.deadline_miss = u128::from(self.e2e_ns) > sample_period.as_nanos();
    }

    /// One `cycles.csv` row.
    pub fn csv(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{:.6},{},{},{},{:.5},{:.5},{:.5}",
            self.cycle,
            self.frame,
            self.t_ctrl_us,
            self.rx_ns,
            self.decode_ns,
            self.track_ns,
            self.plan_ns,
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
            self.goal_distance
        )
    }
}

/// A CAN frame seen by the gateway, for `can.log`.
#[derive(Debug, Clone, Copy)]
pub struct CanRecord {
    /// When, s: since the Unix epoch on the rig (candump's format), virtual time in
    /// simulation.
    pub at_s: f64,
    pub frame: CanFrame,
    pub sent: bool,
}

impl CanRecord {
    /// One `can.log` line, candump `-L` format: `(1700000000.000123) can0 101#0102`.
    pub fn candump(&self, interface: &str, out: &mut impl std::io::Write) -> std::io::Result<()> {
        write!(out, "({:.6}) {interface} ", self.at_s)?;
        match self.frame.id() {
            flowgate_protocol::CanId::Standard(id) => write!(out, "{id:03X}#")?,
            flowgate_protocol::CanId::Extended(id) => write!(out, "{id:08X}#")?,
        }
        if self.frame.is_remote() {
            write!(out, "R{}", self.frame.dlc())?;
        } else {
            for b in self.frame.data() {
                write!(out, "{b:02X}")?;
            }
        }
        writeln!(out)
    }
}

/// Something that happened, in words: a state change, an operator's request and its answer.
#[derive(Debug, Clone)]
pub struct EventRecord {
    pub at_s: f64,
    pub text: String,
}

#[derive(Debug, Clone)]
pub enum Record {
    Cycle(CycleRecord),
    Can(CanRecord),
    /// Events (rare: they may allocate).
    Event(EventRecord),
}

/// The loop's end of the telemetry queue.
#[derive(Debug, Clone)]
pub struct Recorder {
    tx: Option<mpsc::Sender<Record>>,
    dropped: Arc<AtomicU64>,
}

impl Recorder {
    /// A recorder that writes nothing.
    pub fn disabled() -> Self {
        Self { tx: None, dropped: Arc::new(AtomicU64::new(0)) }
    }

    /// Queue a record; never waits. A full queue drops it and counts the drop.
    pub fn record(&self, r: Record) {
        if let Some(tx) = &self.tx {
            if tx.try_send(r).is_err() {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// What the writer wrote.
#[derive(Debug, Clone, Default, Serialize)]
pub struct WrittenFiles {
    pub cycles_csv: Option<PathBuf>,
    pub trace_json: Option<PathBuf>,
    pub can_log: Option<PathBuf>,
    pub cycles: u64,
    pub can_frames: u64,
}

/// How often the writer drains the queue. The queue must hold this long's records: the
/// default 8192 is over five times what 20,000 cycles/s queue meanwhile (a cycle record and
/// a CAN frame or two each).
pub const DRAIN_EVERY: std::time::Duration = std::time::Duration::from_millis(25);

/// Start the writer task on `dir` with a queue of `capacity` records.
pub fn start_writer(
    dir: &Path,
    capacity: usize,
    interface: String,
) -> std::io::Result<(Recorder, tokio::task::JoinHandle<std::io::Result<WrittenFiles>>)> {
    std::fs::create_dir_all(dir)?;
    let (tx, mut rx) = mpsc::channel::<Record>(capacity);
    let paths = (dir.join("cycles.csv"), dir.join("trace.json"), dir.join("can.log"));
    let mut events = std::io::BufWriter::new(std::fs::File::create(dir.join("events.log"))?);
    let mut cycles = std::io::BufWriter::new(std::fs::File::create(&paths.0)?);
    let mut trace = std::io::BufWriter::new(std::fs::File::create(&paths.1)?);
    let mut can = std::io::BufWriter::new(std::fs::File::create(&paths.2)?);
    let task = tokio::task::spawn_blocking(move || {
        writeln!(cycles, "{}", CycleRecord::CSV_HEADER)?;
        write!(trace, "{{\"traceEvents\":[")?;
        let mut first = true;
        let mut written = WrittenFiles {
            cycles_csv: Some(paths.0),
            trace_json: Some(paths.1),
            can_log: Some(paths.2),
            ..WrittenFiles::default()
        };
        loop {
            let r = match rx.try_recv() {
                Ok(r) => r,
                Err(mpsc::error::TryRecvError::Empty) => {
                    std::thread::sleep(DRAIN_EVERY);
                    continue;
                }
                Err(mpsc::error::TryRecvError::Disconnected) => break,
            };
            match r {
                Record::Cycle(c) => {
                    c.csv(&mut cycles)?;
                    written.cycles += 1;
                    // Stages laid end to end, ending at the CAN write.
                    let us = |ns: u64| ns as f64 / 1e3;
                    let mut start = c.can_done_ns.saturating_sub(c.can_write_ns + c.plan_ns + c.track_ns + c.decode_ns);
                    for (name, dur) in [
                        ("decode", c.decode_ns),
                        ("track", c.track_ns),
                        ("plan", c.plan_ns),
                        ("can_write", c.can_write_ns),
                    ] {
                        if !first {
                            write!(trace, ",")?;
                        }
                        first = false;
                        write!(
                            trace,
                            "{{\"name\":\"{name}\",\"cat\":\"cycle\",\"ph\":\"X\",\"ts\":{:.3},\"dur\":{:.3},\"pid\":1,\"tid\":1,\"args\":{{\"cycle\":{},\"frame\":{}}}}}",
                            us(start),
                            us(dur),
                            c.cycle,
                            c.frame
                        )?;
                        start += dur;
                    }
                    write!(
                        trace,
                        ",{{\"name\":\"e2e\",\"cat\":\"cycle\",\"ph\":\"X\",\"ts\":{:.3},\"dur\":{:.3},\"pid\":1,\"tid\":2,\"args\":{{\"cycle\":{},\"miss\":{}}}}}",
                        us(c.rx_ns),
                        us(c.e2e_ns),
                        c.cycle,
                        c.deadline_miss
                    )?;
                }
                Record::Can(f) => {
                    f.candump(&interface, &mut can)?;
                    written.can_frames += 1;
                }
                Record::Event(e) => writeln!(events, "({:.6}) {}", e.at_s, e.text)?,
            }
        }
        write!(trace, "],\"displayTimeUnit\":\"ms\"}}")?;
        cycles.flush()?;
        events.flush()?;
        trace.flush()?;
        can.flush()?;
        Ok(written)
    });
    Ok((Recorder { tx: Some(tx), dropped: Arc::new(AtomicU64::new(0)) }, task))
}

/// Latency and period statistics of a run.
#[derive(Debug, Clone)]
pub struct Timing {
    e2e: Histogram<u64>,
    period: Histogram<u64>,
    pub deadline_misses: u64,
    pub cycles: u64,
}

/// Percentiles, µs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
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
            e2e: Histogram::new_with_bounds(1, 60_000_000_000, 3).expect("bounds"),
            period: Histogram::new_with_bounds(1, 60_000_000_000, 3).expect("bounds"),
            deadline_misses: 0,
            cycles: 0,
        }
    }
}

impl Timing {
    pub fn add(&mut self, c: &CycleRecord) {
        self.cycles += 1;
        let _ = self.e2e.record(c.e2e_ns.max(1));
        if c.period_ns > 0 {
            let _ = self.period.record(c.period_ns);
        }
        self.deadline_misses += u64::from(c.deadline_miss);
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

    pub fn e2e(&self) -> Distribution {
        Self::dist(&self.e2e)
    }
    pub fn period(&self) -> Distribution {
        Self::dist(&self.period)
    }
}
