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
//! - `events.jsonl`: state changes, operator requests (who asked, and the answer) and the
//!   core's notices (its warnings and errors, obstacles entering and leaving the view), one
//!   JSON object a line: `{"t_s": 1.234567, "level": "warning", "kind": "sequence_rebased",
//!   "text": "...", "fields": {"seq": 4096}}` (`flowgate events` reads it).
//!
//! The text files are flushed at every drain, so a process killed outright (SIGKILL, the
//! service manager's watchdog) loses at most the last drain's records; `flowgate run` puts
//! each run in its own directory ([`run_directory`]).
//!
//! The loop keeps HDR histograms of end-to-end latency and command period in memory for the
//! summary printed at exit.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use flowgate_protocol::psd::Packet;
use flowgate_protocol::CanFrame;
use serde::Serialize;
use tokio::sync::mpsc;

pub use super::recording::{CanRecord, EventRecord};
use super::recording::{McapSink, RecordingSummary};
use crate::gateway::core::input::InputRecord;
use crate::gateway::core::scene::{FleetScene, SceneRecord, VehicleChunk};
pub use crate::gateway::core::timing::{write_stage_table, CycleRecord, Distribution, Stage, StageSummary, Timing};
use crate::time::HostTime;

// Large by design: a record is copied into the queue, never boxed (no allocation per cycle).
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum Record {
    Cycle(CycleRecord),
    Can(CanRecord),
    /// Events (rare: they may allocate).
    Event(EventRecord),
    /// For a recording only: an input the core took, a packet sent to the PSD controller,
    /// a cycle's scene.
    Input(InputRecord),
    PsdSent {
        at: HostTime,
        packet: Packet,
    },
    Scene(SceneRecord),
    /// Part of a fleet's other vehicles, ahead of the scene they belong to.
    Vehicles(VehicleChunk),
    /// A frame the core asked for while the CAN link was down (not written, not in can.log).
    CanUnwritten {
        at: HostTime,
        frame: CanFrame,
    },
}

/// The loop's end of the telemetry queue.
#[derive(Debug, Clone)]
pub struct Recorder {
    tx: Option<mpsc::Sender<Record>>,
    dropped: Arc<AtomicU64>,
    /// An MCAP recording is being written: inputs and scenes are wanted.
    recording: bool,
}

impl Recorder {
    /// A recorder that writes nothing.
    pub fn disabled() -> Self {
        Self { tx: None, dropped: Arc::new(AtomicU64::new(0)), recording: false }
    }

    /// Queue a record; never waits. A full queue drops it and counts the drop.
    pub fn record(&self, r: Record) {
        if let Some(tx) = &self.tx {
            if tx.try_send(r).is_err() {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// A scene, a fleet's other vehicles ahead of it in chunks (a record each, so that every
    /// record stays small enough to queue by value).
    pub fn scene(&self, scene: SceneRecord, fleet: Option<FleetScene>) {
        for chunk in fleet.iter().flat_map(FleetScene::chunks) {
            self.record(Record::Vehicles(chunk));
        }
        self.record(Record::Scene(scene));
    }

    /// Whether an MCAP recording wants the core's inputs and each cycle's scene.
    pub fn recording(&self) -> bool {
        self.recording
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
    /// The MCAP recording, when one was asked for.
    pub recording: Option<RecordingSummary>,
}

/// The text files of a telemetry directory.
struct TextFiles {
    events: std::io::BufWriter<std::fs::File>,
    cycles: std::io::BufWriter<std::fs::File>,
    trace: std::io::BufWriter<std::fs::File>,
    can: std::io::BufWriter<std::fs::File>,
    interface: String,
    first: bool,
}

impl TextFiles {
    fn create(dir: &Path, interface: String, written: &mut WrittenFiles) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let paths = (dir.join("cycles.csv"), dir.join("trace.json"), dir.join("can.log"));
        let create = |p: &Path| std::fs::File::create(p).map(std::io::BufWriter::new);
        let mut files = Self {
            events: create(&dir.join("events.jsonl"))?,
            cycles: create(&paths.0)?,
            trace: create(&paths.1)?,
            can: create(&paths.2)?,
            interface,
            first: true,
        };
        writeln!(files.cycles, "{}", CycleRecord::CSV_HEADER)?;
        write!(files.trace, "{{\"traceEvents\":[")?;
        (written.cycles_csv, written.trace_json, written.can_log) = (Some(paths.0), Some(paths.1), Some(paths.2));
        Ok(files)
    }

    fn write(&mut self, r: &Record) -> std::io::Result<()> {
        match r {
            Record::Cycle(c) => {
                c.csv(&mut self.cycles)?;
                // Stages laid end to end, ending at the CAN write.
                let us = |ns: u64| ns as f64 / 1e3;
                let stages = c.stages();
                let mut start = c.can_done_ns.saturating_sub(stages.iter().map(|(_, ns)| ns).sum());
                for (name, dur) in stages {
                    if !self.first {
                        write!(self.trace, ",")?;
                    }
                    self.first = false;
                    write!(
                        self.trace,
                        "{{\"name\":\"{name}\",\"cat\":\"cycle\",\"ph\":\"X\",\"ts\":{:.3},\"dur\":{:.3},\"pid\":1,\"tid\":1,\"args\":{{\"cycle\":{},\"frame\":{}}}}}",
                        us(start),
                        us(dur),
                        c.cycle,
                        c.frame
                    )?;
                    start += dur;
                }
                write!(
                    self.trace,
                    ",{{\"name\":\"e2e\",\"cat\":\"cycle\",\"ph\":\"X\",\"ts\":{:.3},\"dur\":{:.3},\"pid\":1,\"tid\":2,\"args\":{{\"cycle\":{},\"miss\":{}}}}}",
                    us(c.rx_ns),
                    us(c.e2e_ns),
                    c.cycle,
                    c.deadline_miss
                )?;
            }
            Record::Can(f) => f.candump(&self.interface, &mut self.can)?,
            Record::Event(e) => {
                serde_json::to_writer(&mut self.events, &e.json())?;
                writeln!(self.events)?;
            }
            Record::Input(_)
            | Record::PsdSent { .. }
            | Record::Scene(_)
            | Record::Vehicles(_)
            | Record::CanUnwritten { .. } => {}
        }
        Ok(())
    }

    /// Everything written so far onto the disk's page cache: what a killed process leaves.
    fn flush(&mut self) -> std::io::Result<()> {
        self.cycles.flush()?;
        self.events.flush()?;
        self.trace.flush()?;
        self.can.flush()
    }

    fn finish(mut self) -> std::io::Result<()> {
        write!(self.trace, "],\"displayTimeUnit\":\"ms\"}}")?;
        self.cycles.flush()?;
        self.events.flush()?;
        self.trace.flush()?;
        self.can.flush()
    }
}

/// Where the writer puts the records.
#[derive(Debug, Default)]
pub struct Sinks {
    /// A telemetry directory (cycles.csv, trace.json, can.log, events.jsonl) and the CAN
    /// interface's name for can.log.
    pub dir: Option<(PathBuf, String)>,
    /// An MCAP recording.
    pub mcap: Option<McapSink>,
}

impl Sinks {
    pub fn is_empty(&self) -> bool {
        self.dir.is_none() && self.mcap.is_none()
    }
}

/// How often the writer drains the queue. The queue must hold this long's records: the
/// default 8192 is over five times what 20,000 cycles/s queue meanwhile (a cycle record and
/// a CAN frame or two each).
pub const DRAIN_EVERY: std::time::Duration = std::time::Duration::from_millis(25);

/// Start the writer task with a queue of `capacity` records. `inputs_taken` is the loop's
/// count of inputs, read when the recording closes (its end record compares it with what was
/// written).
pub fn start_writer(
    sinks: Sinks,
    capacity: usize,
    inputs_taken: Arc<AtomicU64>,
) -> std::io::Result<(Recorder, tokio::task::JoinHandle<std::io::Result<WrittenFiles>>)> {
    let (tx, mut rx) = mpsc::channel::<Record>(capacity);
    let mut written = WrittenFiles::default();
    let mut files = match sinks.dir {
        Some((dir, interface)) => Some(TextFiles::create(&dir, interface, &mut written)?),
        None => None,
    };
    let recording = sinks.mcap.is_some();
    let mut mcap = sinks.mcap;
    let dropped = Arc::new(AtomicU64::new(0));
    let dropped_seen = dropped.clone();
    let task = tokio::task::spawn_blocking(move || {
        loop {
            let r = match rx.try_recv() {
                Ok(r) => r,
                Err(mpsc::error::TryRecvError::Empty) => {
                    if let Some(m) = &mut mcap {
                        m.flush_if_due()?;
                    }
                    if let Some(files) = &mut files {
                        files.flush()?;
                    }
                    std::thread::sleep(DRAIN_EVERY);
                    continue;
                }
                Err(mpsc::error::TryRecvError::Disconnected) => break,
            };
            match &r {
                Record::Cycle(_) => written.cycles += 1,
                Record::Can(_) => written.can_frames += 1,
                _ => {}
            }
            if let Some(files) = &mut files {
                files.write(&r)?;
            }
            if let Some(m) = &mut mcap {
                match &r {
                    Record::Cycle(c) => m.cycle(c)?,
                    Record::Can(f) => m.can(f)?,
                    Record::Event(e) => m.event(e)?,
                    Record::Input(i) => m.input(i)?,
                    Record::PsdSent { at, packet } => m.psd_sent(*at, packet)?,
                    Record::Scene(s) => m.scene(s)?,
                    Record::Vehicles(chunk) => m.vehicles_chunk(chunk),
                    Record::CanUnwritten { at, frame } => m.can_unwritten(*at, frame)?,
                }
            }
        }
        if let Some(files) = files {
            files.finish()?;
        }
        if let Some(m) = mcap {
            let taken = inputs_taken.load(Ordering::Relaxed);
            written.recording = m.finish(taken, dropped_seen.load(Ordering::Relaxed))?;
        }
        Ok(written)
    });
    Ok((Recorder { tx: Some(tx), dropped, recording }, task))
}

/// A new directory for one run under `out_dir`, named by its start in UTC
/// (`20261125T213000Z`, a suffix `-2`, `-3`, ... if that second is taken), and `out_dir/latest`
/// pointed at it. A run never overwrites another's files.
pub fn run_directory(out_dir: &Path, start: std::time::SystemTime) -> std::io::Result<PathBuf> {
    std::fs::create_dir_all(out_dir)?;
    let stamp = utc_stamp(start);
    let mut dir = out_dir.join(&stamp);
    let mut n = 1;
    loop {
        match std::fs::create_dir(&dir) {
            Ok(()) => break,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && n < 1000 => {
                n += 1;
                dir = out_dir.join(format!("{stamp}-{n}"));
            }
            Err(e) => return Err(e),
        }
    }
    // Replaced atomically: a reader of `latest` sees the old run or the new, never neither.
    let name = dir.file_name().map(PathBuf::from).unwrap_or_default();
    let staging = out_dir.join(format!(".latest-{}", std::process::id()));
    let _ = std::fs::remove_file(&staging);
    std::os::unix::fs::symlink(&name, &staging)?;
    std::fs::rename(&staging, out_dir.join("latest"))?;
    Ok(dir)
}

/// Undo [`run_directory`] for a run that failed before writing anything: `dir` is removed
/// if it is empty, and `out_dir/latest` pointed back at `previous` (the run it named
/// before; none: removed) if it still names `dir`. A directory with files in it is kept.
pub fn abandon_run_directory(out_dir: &Path, dir: &Path, previous: Option<&Path>) {
    if std::fs::remove_dir(dir).is_err() {
        return;
    }
    let latest = out_dir.join("latest");
    if std::fs::read_link(&latest).ok().as_deref() != dir.file_name().map(Path::new) {
        return;
    }
    match previous {
        Some(previous) => {
            let staging = out_dir.join(format!(".latest-{}", std::process::id()));
            let _ = std::fs::remove_file(&staging);
            if std::os::unix::fs::symlink(previous, &staging).is_ok() {
                let _ = std::fs::rename(&staging, &latest);
            }
        }
        None => {
            let _ = std::fs::remove_file(&latest);
        }
    }
}

/// `YYYYMMDDTHHMMSSZ` of a time on the Unix clock (civil from days: H. Hinnant's algorithm).
fn utc_stamp(t: std::time::SystemTime) -> String {
    let secs = t.duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let (days, rem) = (secs / 86_400, secs % 86_400);
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}{month:02}{day:02}T{:02}{:02}{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_stamps_name_the_civil_time() {
        let at = |s: u64| std::time::UNIX_EPOCH + std::time::Duration::from_secs(s);
        assert_eq!(utc_stamp(at(0)), "19700101T000000Z");
        assert_eq!(utc_stamp(at(951_782_400)), "20000229T000000Z");
        assert_eq!(utc_stamp(at(1_795_642_245)), "20261125T213045Z");
    }

    #[test]
    fn each_run_gets_its_own_directory_and_latest_follows() {
        let out = std::env::temp_dir().join(format!("flowgate-rundir-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let t = std::time::UNIX_EPOCH + std::time::Duration::from_secs(1_795_642_245);
        let a = run_directory(&out, t).unwrap();
        let b = run_directory(&out, t).unwrap();
        assert_eq!(a, out.join("20261125T213045Z"));
        assert_eq!(b, out.join("20261125T213045Z-2"));
        assert_eq!(std::fs::read_link(out.join("latest")).unwrap(), PathBuf::from("20261125T213045Z-2"));
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn a_record_stays_small_enough_to_queue_by_value() {
        // The queue holds records by value (no allocation per cycle): 8192 of the largest,
        // a cycle's scene, are under 6 MB.
        assert!(std::mem::size_of::<Record>() <= 672, "{} bytes", std::mem::size_of::<Record>());
    }
}

/// One line of `events.jsonl`, as read back.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, Serialize)]
pub struct LoggedEvent {
    pub t_s: f64,
    /// `info` in a log written before events had levels.
    #[serde(default = "info")]
    pub level: String,
    #[serde(default)]
    pub kind: String,
    pub text: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fields: Option<serde_json::Value>,
}

fn info() -> String {
    "info".into()
}

impl LoggedEvent {
    /// Its level's rank: info 0, warning 1, error 2.
    pub fn rank(&self) -> u8 {
        match self.level.as_str() {
            "error" => 2,
            "warning" => 1,
            _ => 0,
        }
    }
}

/// What reading an event log refuses, naming the file and the line.
#[derive(Debug, thiserror::Error)]
pub enum EventsError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}, line {line}: not an event ({why})")]
    Bad { path: String, line: usize, why: String },
}

/// The largest `events.jsonl` read, bytes: a run's events are state changes, requests and
/// notices, a few hundred bytes each; a file past this is no run's log.
pub const MAX_EVENTS_BYTES: u64 = 256 << 20;

/// The events of a run: `path` is its `events.jsonl` or the telemetry directory holding it.
pub fn read_events(path: &Path) -> Result<Vec<LoggedEvent>, EventsError> {
    let file = if path.is_dir() { path.join("events.jsonl") } else { path.to_path_buf() };
    let name = file.display().to_string();
    let text = crate::config::read_text(&file, MAX_EVENTS_BYTES)
        .map_err(|source| EventsError::Io { path: name.clone(), source })?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(k, l)| {
            serde_json::from_str(l).map_err(|e| EventsError::Bad {
                path: name.clone(),
                line: k + 1,
                why: e.to_string(),
            })
        })
        .collect()
}
