//! Replay of an MCAP recording through the gateway core (`flowgate replay`).
//!
//! A recording holds every input the core took, with its host time (see
//! [`crate::gateway::shell::recording`]). The replay hands them to a fresh core in the same order
//! at the same times, in virtual time: no clock, no I/O. With the recorded configuration the
//! core asks for the same CAN frames, byte for byte, and the replay checks that it does. With
//! another configuration (a what-if) it reports where the commands part and how far apart
//! the paths they would drive are. The robot's measured path is the recorded one either way:
//! a replay cannot move the robot, so a what-if's path is dead-reckoned from its commands.

use std::collections::BTreeMap;
use std::path::Path;

use crate::Point;
use flowgate_protocol::CanFrame;
use serde::Serialize;

use crate::config::{Rig, RigFile};
use crate::gateway::core::input::InputRecord;
use crate::gateway::core::{Core, NoClock, Output};
use crate::gateway::shell::recording::{self, frame_from_json};
use crate::planner::Space;
use crate::svg::{Axes, Svg};
use crate::time::HostTime;

pub mod records;
#[cfg(feature = "ros2")]
pub mod ros2_bag;

use records::{Chunks, McapRecords};

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("{path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error("{path} is not an MCAP file: {source}")]
    NotMcap { path: String, source: mcap::McapError },
    #[error("{path} is not an MCAP file: no MCAP header in its {bytes} bytes")]
    NoHeader { path: String, bytes: u64 },
    #[error("{path} is not a flowgate recording: no `{what}`")]
    NotFlowgate { path: String, what: &'static str },
    #[error("{path}: message {index} on {topic}: {why}")]
    BadMessage { path: String, index: usize, topic: String, why: String },
    #[error("the recorded configuration: {0}")]
    Config(#[from] crate::config::ConfigError),
    #[error("--set {0}: expected KEY=VALUE with a dotted key (planner.kc=0.2)")]
    BadSet(String),
    #[error("--set {key}: {why}")]
    SetFailed { key: String, why: String },
    #[error("the recorded run gave no velocity command: nothing to compare")]
    NoCommands,
}

/// What the gateway sent on CAN in a recording, in order, and whether it was written (the
/// link may have been down).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SentFrame {
    pub frame: CanFrame,
    pub written: bool,
}

/// A recording, read.
#[derive(Debug, Clone)]
pub struct Recording {
    /// The configuration of the recorded run (TOML).
    pub config_toml: String,
    pub inputs: Vec<InputRecord>,
    /// CAN frames the core asked for, in order.
    pub can_sent: Vec<SentFrame>,
    /// What the end record says: inputs taken by the loop, and records dropped. `None`: the
    /// recording was not closed (the gateway was killed).
    pub end: Option<(u64, u64)>,
    /// Inputs missing from the sequence (dropped by a full queue), counted.
    pub inputs_missing: u64,
    /// The recording stopped early (damaged or cut): what the reader said.
    pub truncated: Option<String>,
    /// The host clock's zero on the Unix clock, ns (a host time plus this is a log time).
    pub origin_unix_ns: u64,
}

impl Recording {
    /// Read a recording. A file cut short (the gateway killed mid-write) or damaged is read
    /// up to where it stops, and says so in `truncated`.
    pub fn read(path: &Path) -> Result<Self, ReplayError> {
        let name = path.display().to_string();
        let file = std::fs::File::open(path).map_err(|source| ReplayError::Read { path: name.clone(), source })?;
        Self::from_reader(file, &name)
    }

    /// Read a recording from any source, a piece at a time; `name` names it in errors.
    pub fn from_reader(source: impl std::io::Read, name: &str) -> Result<Self, ReplayError> {
        let mut records = McapRecords::new(source, Chunks::Opened);
        let mut gathered = Gathered::default();
        let mut truncated = None;
        while let Some(record) = records.next_record() {
            match record {
                Ok(r) => gathered.record(name, r)?,
                Err(e) if gathered.index == 0 && gathered.config.is_none() => {
                    return Err(ReplayError::NotMcap { path: name.to_string(), source: e });
                }
                Err(e) => {
                    truncated = Some(format!("{e} (at byte {})", records.bytes_read()));
                    break;
                }
            }
        }
        if truncated.is_none() && !records.saw_footer() {
            truncated = Some(format!("ends at byte {} without its footer", records.bytes_read()));
        }
        gathered.finish(name, truncated)
    }

    /// The recorded configuration, parsed.
    pub fn config(&self) -> Result<RigFile, ReplayError> {
        Ok(RigFile::from_toml(&self.config_toml, "the recording")?)
    }

    /// Whether every input the loop took is here: the replay can then be exact.
    pub fn is_whole(&self) -> bool {
        self.truncated.is_none()
            && self.inputs_missing == 0
            && self.end.is_some_and(|(taken, _)| taken == self.inputs.len() as u64)
    }

    /// The recorded run's length, s (first input to last).
    pub fn duration(&self) -> f64 {
        match (self.inputs.first(), self.inputs.last()) {
            (Some(a), Some(b)) => b.at.since(a.at).as_secs_f64(),
            _ => 0.0,
        }
    }
}

/// Apply `--set key=value` edits to a config's TOML: the key is dotted (`planner.kc`), the
/// value is TOML (`0.2`, `true`, `"text"`). The key must already exist (a typo is an error,
/// not a new key the config then refuses to know).
pub fn apply_sets(toml_text: &str, sets: &[String]) -> Result<String, ReplayError> {
    let mut doc: toml_edit::DocumentMut = toml_text
        .parse()
        .map_err(|e: toml_edit::TomlError| ReplayError::SetFailed { key: "-".into(), why: e.to_string() })?;
    for set in sets {
        let (key, value) = set.split_once('=').ok_or_else(|| ReplayError::BadSet(set.clone()))?;
        let (key, value) = (key.trim(), value.trim());
        let path: Vec<&str> = key.split('.').collect();
        if key.is_empty() || path.iter().any(|p| p.is_empty()) {
            return Err(ReplayError::BadSet(set.clone()));
        }
        let failed = |why: String| ReplayError::SetFailed { key: key.to_string(), why };
        let parsed: toml_edit::Value =
            value.parse().map_err(|e: toml_edit::TomlError| failed(format!("`{value}` is not a TOML value: {e}")))?;
        let (last, parents) = path.split_last().ok_or_else(|| ReplayError::BadSet(set.clone()))?;
        let missing = |name: &str| failed(format!("the recorded configuration has no `{name}` there"));
        let mut table = doc.as_table_mut() as &mut dyn toml_edit::TableLike;
        for p in parents {
            table = table.get_mut(p).and_then(toml_edit::Item::as_table_like_mut).ok_or_else(|| missing(p))?;
        }
        let slot = table.get_mut(last).filter(|i| i.is_value()).ok_or_else(|| missing(last))?;
        *slot = toml_edit::Item::Value(parsed);
    }
    Ok(doc.to_string())
}

/// One velocity command the core gave.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Command {
    pub t: f64,
    pub pulses: [i32; 2],
    /// The robot's estimated pose then (from the recorded samples).
    pub x: f64,
    pub y: f64,
    pub heading: f64,
}

/// What the core did with the recorded inputs.
#[derive(Debug, Clone)]
pub struct Replayed {
    pub can: Vec<CanFrame>,
    pub commands: Vec<Command>,
    pub final_state: String,
    /// How long handing the core every input took, s (wall clock).
    pub elapsed: f64,
}

/// Feed `inputs` through a fresh core built on `rig`, in virtual time.
pub fn run(rig: Rig, inputs: &[InputRecord]) -> Replayed {
    let started = std::time::Instant::now();
    let mut core = Core::new(rig, NoClock);
    let mut can = Vec::with_capacity(inputs.len());
    let mut commands = Vec::new();
    let mut take = |core: &mut Core<NoClock>| {
        while let Some(out) = core.poll() {
            match out {
                Output::Can(frame) => can.push(frame),
                Output::Command { frame, record } => {
                    can.push(frame);
                    let at = HostTime::from_nanos(record.rx_ns);
                    commands.push(Command {
                        t: at.secs(),
                        pulses: record.pulses,
                        x: record.x,
                        y: record.y,
                        heading: core.scene(at).pose[2],
                    });
                }
                _ => {}
            }
        }
    };
    for input in inputs {
        core.handle(input.at, input.input.as_input());
        take(&mut core);
    }
    Replayed { can, commands, final_state: core.state().to_string(), elapsed: started.elapsed().as_secs_f64() }
}

/// What reading a recording gathers, record by record.
#[derive(Debug, Default)]
struct Gathered {
    topics: BTreeMap<u16, String>,
    config: Option<String>,
    origin_unix_ns: u64,
    end: Option<(u64, u64)>,
    /// Each input's JSON with its header's full sequence number and log time: the times
    /// become host times once the clock's origin is known.
    input_messages: Vec<(usize, String, serde_json::Value, u64, u64)>,
    last_seq: Option<u64>,
    can_sent: Vec<SentFrame>,
    /// Messages read so far.
    index: usize,
}

impl Gathered {
    fn record(&mut self, name: &str, record: mcap::records::Record<'_>) -> Result<(), ReplayError> {
        match record {
            mcap::records::Record::Channel(ch) => {
                self.topics.insert(ch.id, ch.topic);
            }
            mcap::records::Record::Metadata(m) if m.name == recording::METADATA => {
                self.config = m.metadata.get("config").cloned();
                self.origin_unix_ns = m.metadata.get("origin_unix_ns").and_then(|v| v.parse().ok()).unwrap_or(0);
            }
            mcap::records::Record::Metadata(m) if m.name == recording::METADATA_END => {
                let count = |k: &str| m.metadata.get(k).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0);
                self.end = Some((count("inputs_taken"), count("records_dropped")));
            }
            mcap::records::Record::Message { header, data } => self.message(name, &header, &data)?,
            _ => {}
        }
        Ok(())
    }

    fn message(&mut self, name: &str, header: &mcap::records::MessageHeader, data: &[u8]) -> Result<(), ReplayError> {
        self.index += 1;
        let index = self.index;
        let Some(topic) = self.topics.get(&header.channel_id) else { return Ok(()) };
        let bad = |why: String| ReplayError::BadMessage { path: name.to_string(), index, topic: topic.clone(), why };
        let is_input = [recording::PSD_RX, recording::CAN_RX, recording::GATEWAY_INPUT].contains(&topic.as_str());
        if !is_input && topic != recording::CAN_TX {
            return Ok(());
        }
        let value: serde_json::Value = serde_json::from_slice(data).map_err(|e| bad(e.to_string()))?;
        if is_input {
            // MCAP's sequence is 32 bits; inputs are written in order, so the full count is
            // the last one moved on by the (wrapping) difference.
            let seq = self
                .last_seq
                .map_or(u64::from(header.sequence), |last| last + u64::from(header.sequence.wrapping_sub(last as u32)));
            self.last_seq = Some(seq);
            self.input_messages.push((index, topic.clone(), value, seq, header.log_time));
        } else {
            let frame = frame_from_json(&value).ok_or_else(|| bad("not a CAN frame".into()))?;
            let written = value.get("written").and_then(serde_json::Value::as_bool).unwrap_or(true);
            self.can_sent.push(SentFrame { frame, written });
        }
        Ok(())
    }

    fn finish(self, name: &str, truncated: Option<String>) -> Result<Recording, ReplayError> {
        let path = name.to_string();
        let config_toml = self.config.ok_or(ReplayError::NotFlowgate { path, what: "configuration metadata" })?;
        let mut inputs = Vec::with_capacity(self.input_messages.len());
        for (index, topic, value, seq, log_time) in self.input_messages {
            let at = HostTime::from_nanos(log_time.saturating_sub(self.origin_unix_ns));
            let input = recording::input_from_json(&value, seq, at).map_err(|why| ReplayError::BadMessage {
                path: name.to_string(),
                index,
                topic,
                why,
            })?;
            inputs.push(input);
        }
        // The three input channels interleave in the file by write order, which is `seq`
        // order already; sorting makes that a guarantee rather than an assumption.
        inputs.sort_by_key(|i| i.seq);
        let inputs_missing = inputs.windows(2).map(|w| w[1].seq.saturating_sub(w[0].seq + 1)).sum::<u64>()
            + inputs.first().map_or(0, |i| i.seq);
        let origin_unix_ns = self.origin_unix_ns;
        Ok(Recording {
            config_toml,
            inputs,
            can_sent: self.can_sent,
            end: self.end,
            inputs_missing,
            truncated,
            origin_unix_ns,
        })
    }
}

/// A replay with the recorded configuration, held against the frames the recording says the
/// gateway sent.
#[derive(Debug, Clone)]
pub struct Verification {
    pub replayed: Replayed,
    /// Frames the recording says were sent, and how many of them were written (the link may
    /// have been down).
    pub recorded: usize,
    pub written: usize,
    /// The recording holds every input the gateway took. One that is not whole ends at an
    /// arbitrary point (its last inputs' frames may be missing), so only the first
    /// `compared` frames are compared.
    pub whole: bool,
    pub compared: usize,
    /// The first frame that differs, if any.
    pub difference: Option<Divergence>,
}

impl Verification {
    /// The replay reproduced the whole run, byte for byte.
    pub fn reproduced(&self) -> bool {
        self.whole && self.difference.is_none()
    }
}

/// A what-if: the recorded inputs through another configuration, both command streams
/// dead-reckoned from the first measured pose, and both paths drawn.
#[derive(Debug, Clone)]
pub struct WhatIf {
    pub replayed: Replayed,
    pub diff: CommandDiff,
    pub svg: String,
}

impl Recording {
    /// Replay with the recorded configuration and compare the CAN frames.
    pub fn verify(&self) -> Result<Verification, ReplayError> {
        let replayed = run(self.config()?.rig("the recorded configuration")?, &self.inputs);
        let whole = self.is_whole();
        let compared = if whole { self.can_sent.len() } else { self.can_sent.len().min(replayed.can.len()) };
        let again = if whole { &replayed.can[..] } else { &replayed.can[..compared] };
        let difference = first_difference(&self.can_sent[..compared], again);
        let written = self.can_sent.iter().filter(|f| f.written).count();
        Ok(Verification { recorded: self.can_sent.len(), written, whole, compared, difference, replayed })
    }

    /// Replay with `rig` instead of the recorded configuration; `title` heads the drawing.
    pub fn what_if(&self, rig: Rig, title: &str) -> Result<WhatIf, ReplayError> {
        let (pulses_per_metre, wheel_base) = (rig.control.drive.pulses_per_metre(), rig.control.drive.wheel_base);
        let space = rig.control.planner.space;
        let recorded = run(self.config()?.rig("the recorded configuration")?, &self.inputs);
        let replayed = run(rig, &self.inputs);
        let first = recorded.commands.first().copied().ok_or(ReplayError::NoCommands)?;
        let (start, heading) = (Point::new(first.x, first.y), first.heading);
        let path_a = dead_reckon(&recorded.commands, start, heading, pulses_per_metre, wheel_base);
        let path_b = dead_reckon(&replayed.commands, start, heading, pulses_per_metre, wheel_base);
        let diff = diff_commands(&recorded.commands, &replayed.commands, (&path_a, &path_b), first.t);
        let measured: Vec<Point> = recorded.commands.iter().map(|c| Point::new(c.x, c.y)).collect();
        let svg = paths_svg(&measured, &path_a, &path_b, space, title);
        Ok(WhatIf { replayed, diff, svg })
    }
}

/// Where two runs' CAN frames first differ.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Divergence {
    /// Index of the first differing frame.
    pub index: usize,
    pub recorded: Option<String>,
    pub replayed: Option<String>,
}

/// The frames the recorded gateway asked for against the replay's: `None` when identical
/// byte for byte (id, kind, length, data), otherwise the first difference.
pub fn first_difference(recorded: &[SentFrame], replayed: &[CanFrame]) -> Option<Divergence> {
    let n = recorded.len().max(replayed.len());
    (0..n).find_map(|i| {
        let a = recorded.get(i).map(|s| s.frame);
        let b = replayed.get(i).copied();
        (a != b).then(|| Divergence {
            index: i,
            recorded: a.map(|f| format!("{f:?}")),
            replayed: b.map(|f| format!("{f:?}")),
        })
    })
}

/// The path a robot would drive under `commands` (pulse rates held until the next), from
/// `start` heading `heading`: differential-drive dead reckoning.
pub fn dead_reckon(
    commands: &[Command],
    start: Point,
    heading: f64,
    pulses_per_metre: f64,
    wheel_base: f64,
) -> Vec<Point> {
    let mut path = Vec::with_capacity(commands.len() + 1);
    let (mut p, mut th) = (start, heading);
    path.push(p);
    for w in commands.windows(2) {
        let dt = w[1].t - w[0].t;
        let [l, r] = w[0].pulses.map(|v| f64::from(v) / pulses_per_metre);
        let v = 0.5 * (l + r);
        let omega = (r - l) / wheel_base;
        // Midpoint heading: exact enough at a command period's turn.
        let mid = th + 0.5 * omega * dt;
        p += Point::from_polar(v * dt, mid);
        th += omega * dt;
        path.push(p);
    }
    path
}

/// How a what-if's commands differ from the recorded run's.
#[derive(Debug, Clone, Serialize)]
pub struct CommandDiff {
    pub recorded_commands: usize,
    pub replayed_commands: usize,
    /// Commands (by index) whose pulses differ.
    pub differing: usize,
    /// When the first differing command was given, s from the start.
    pub first_differs_at: Option<f64>,
    /// Largest difference of a wheel's pulse rate, pulses/s.
    pub max_pulse_difference: i64,
    /// Largest distance between the two dead-reckoned paths, and between their ends, m.
    pub max_path_gap: f64,
    pub end_gap: f64,
}

pub fn diff_commands(recorded: &[Command], replayed: &[Command], paths: (&[Point], &[Point]), t0: f64) -> CommandDiff {
    let pairs = recorded.iter().zip(replayed);
    let differing: Vec<(&Command, &Command)> = pairs.clone().filter(|(a, b)| a.pulses != b.pulses).collect();
    let max_pulse_difference = pairs
        .flat_map(|(a, b)| [(a.pulses[0] - b.pulses[0]).abs(), (a.pulses[1] - b.pulses[1]).abs()])
        .max()
        .map_or(0, i64::from);
    let (a, b) = paths;
    let max_path_gap = a.iter().zip(b).map(|(p, q)| (p - q).norm()).fold(0.0, f64::max);
    let end_gap = match (a.last(), b.last()) {
        (Some(p), Some(q)) => (p - q).norm(),
        _ => 0.0,
    };
    CommandDiff {
        recorded_commands: recorded.len(),
        replayed_commands: replayed.len(),
        differing: differing.len() + recorded.len().abs_diff(replayed.len()),
        first_differs_at: differing.first().map(|(a, _)| a.t - t0),
        max_pulse_difference,
        max_path_gap,
        end_gap,
    }
}

/// The recorded and the what-if paths (dead-reckoned from their commands) beside the
/// measured path, with the lane's walls: `plan`'s style.
pub fn paths_svg(measured: &[Point], recorded: &[Point], what_if: &[Point], space: Space, title: &str) -> String {
    let all = measured.iter().chain(recorded).chain(what_if);
    let (mut lo, mut hi) = (Point::new(f64::INFINITY, f64::INFINITY), Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY));
    for p in all.clone() {
        lo = Point::new(lo.re.min(p.re), lo.im.min(p.im));
        hi = Point::new(hi.re.max(p.re), hi.im.max(p.im));
    }
    if let Space::Lane { half_width } = space {
        lo.im = lo.im.min(-half_width);
        hi.im = hi.im.max(half_width);
    }
    if !(lo.re.is_finite() && hi.re.is_finite()) {
        (lo, hi) = (Point::new(-1.0, -1.0), Point::new(1.0, 1.0));
    }
    let pad = Point::new(0.05, 0.05);
    let mut svg = Svg::new(760.0, 460.0);
    let axes = Axes::equal(&svg, lo - pad, hi + pad, (60.0, 40.0, 50.0, 20.0));
    axes.frame(&mut svg, "x (m)", "y (m)");
    if let Space::Lane { half_width } = space {
        for y in [-half_width, half_width] {
            axes.polyline(&mut svg, &[Point::new(lo.re - pad.re, y), Point::new(hi.re + pad.re, y)], "#444", 2.0, None);
        }
    }
    axes.polyline(&mut svg, measured, "#999", 3.0, None);
    axes.polyline(&mut svg, recorded, "#1f5fbf", 1.5, None);
    axes.polyline(&mut svg, what_if, "#d9480f", 1.5, Some("6 3"));
    svg.text(380.0, 22.0, title, "middle", 14.0, "#222");
    svg.text(70.0, 445.0, "grey: measured path (recorded samples)   blue: recorded commands, dead-reckoned   orange dashed: what-if commands, dead-reckoned", "start", 11.0, "#333");
    svg.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    const CONFIG: &str = "[planner]\nkc = 0.1 # gain\nmargin = { factor = 1.1 }\n\n[robot]\nradius = 0.05\n";

    #[test]
    fn a_set_changes_one_existing_key_and_keeps_the_rest() {
        let text = apply_sets(CONFIG, &["planner.kc=0.2".into(), "planner.margin.factor = 1.3".into()]).unwrap();
        let doc: toml::Table = text.parse().unwrap();
        assert_eq!(doc["planner"]["kc"].as_float(), Some(0.2));
        assert_eq!(doc["planner"]["margin"]["factor"].as_float(), Some(1.3));
        assert_eq!(doc["robot"]["radius"].as_float(), Some(0.05));
    }

    #[test]
    fn a_set_naming_no_key_or_no_value_is_refused() {
        let err = |set: &str| apply_sets(CONFIG, &[set.to_string()]).unwrap_err().to_string();
        assert_eq!(err("planner.kd=1"), "--set planner.kd: the recorded configuration has no `kd` there");
        assert_eq!(err("plan.kc=1"), "--set plan.kc: the recorded configuration has no `plan` there");
        // A table is not a value to overwrite.
        assert_eq!(err("planner=1"), "--set planner: the recorded configuration has no `planner` there");
        assert!(err("planner.kc").contains("expected KEY=VALUE"));
        assert!(err("planner..kc=1").contains("expected KEY=VALUE"));
        assert!(err("planner.kc=abc").starts_with("--set planner.kc: `abc` is not a TOML value"));
    }

    fn command(t: f64, pulses: [i32; 2]) -> Command {
        Command { t, pulses, x: 0.0, y: 0.0, heading: 0.0 }
    }

    #[test]
    fn dead_reckoning_drives_straight_and_turns_on_the_spot() {
        // 1000 pulses/m: 100 pulses/s on both wheels for 2 s is 0.2 m straight ahead.
        let straight: Vec<Command> = (0..=20).map(|k| command(0.1 * f64::from(k), [100, 100])).collect();
        let path = dead_reckon(&straight, Point::new(1.0, 0.0), std::f64::consts::FRAC_PI_2, 1000.0, 0.1);
        assert!((path.last().unwrap() - Point::new(1.0, 0.2)).norm() < 1e-12, "{:?}", path.last());
        // Opposite wheels at 0.05 m/s, wheel base 0.1 m: 1 rad/s, no travel.
        let spin: Vec<Command> = (0..=10).map(|k| command(0.1 * f64::from(k), [-50, 50])).collect();
        let path = dead_reckon(&spin, Point::new(0.0, 0.0), 0.0, 1000.0, 0.1);
        assert!(path.iter().all(|p| p.norm() < 1e-12));
    }

    #[test]
    fn frames_compare_byte_for_byte() {
        let f = |data: &[u8]| CanFrame::new(flowgate_protocol::CanId::Standard(0x101), data).unwrap();
        let sent = |data: &[u8]| SentFrame { frame: f(data), written: true };
        assert_eq!(first_difference(&[sent(&[1, 2]), sent(&[3])], &[f(&[1, 2]), f(&[3])]), None);
        let d = first_difference(&[sent(&[1, 2]), sent(&[3])], &[f(&[1, 2]), f(&[4])]).unwrap();
        assert_eq!((d.index, d.recorded.as_deref(), d.replayed.as_deref()), (1, Some("101#03"), Some("101#04")));
        let d = first_difference(&[sent(&[1, 2])], &[f(&[1, 2]), f(&[3])]).unwrap();
        assert_eq!((d.index, d.recorded, d.replayed.as_deref()), (1, None, Some("101#03")));
    }
}

/// What a recording holds, at a glance (as `mcap info` or `ros2 bag info` say it).
#[derive(Debug, Clone, Default, Serialize)]
pub struct RecordingInfo {
    /// The file's size, bytes.
    pub bytes: u64,
    /// The profile its header names (`flowgate` for the gateway's own).
    pub profile: String,
    /// The first and last message's log times, ns since the Unix epoch.
    pub start_ns: Option<u64>,
    pub end_ns: Option<u64>,
    /// Each channel: topic, message encoding, schema name, messages.
    pub channels: Vec<(String, String, String, u64)>,
    /// Chunks by compression (`""` is none): how many, compressed and uncompressed bytes.
    pub chunks: Vec<(String, u64, u64, u64)>,
    /// Cycles (messages on `/cycle`) and the file's bytes per cycle.
    pub cycles: u64,
    /// The reader stopped early (damaged or cut): what it said.
    pub truncated: Option<String>,
}

impl RecordingInfo {
    /// Read the summary of any MCAP file, compressed or not, whole or cut short, a piece at
    /// a time (two passes: the chunks as stored, then their messages).
    pub fn read(path: &Path) -> Result<Self, ReplayError> {
        let name = path.display().to_string();
        let bytes = std::fs::metadata(path).map_err(|source| ReplayError::Read { path: name.clone(), source })?.len();
        Self::scan(|| std::fs::File::open(path), bytes, &name)
    }

    /// The same from any source that `open` gives afresh for each pass, `bytes` long.
    pub fn scan<R: std::io::Read>(
        open: impl Fn() -> std::io::Result<R>,
        bytes: u64,
        name: &str,
    ) -> Result<Self, ReplayError> {
        let open = || open().map_err(|source| ReplayError::Read { path: name.to_string(), source });
        let name = name.to_string();
        let mut info = RecordingInfo { bytes, ..Self::default() };
        let mut stored = McapRecords::new(open()?, Chunks::AsStored);
        let mut header = false;
        while let Some(record) = stored.next_record() {
            match record {
                Ok(mcap::records::Record::Header(h)) => {
                    header = true;
                    info.profile = h.profile;
                }
                Ok(mcap::records::Record::Chunk { header, .. }) => info.count_chunk(&header),
                Ok(_) => {}
                Err(e) if !header => return Err(ReplayError::NotMcap { path: name, source: e }),
                Err(e) => {
                    info.truncated = Some(format!("{e} (at byte {})", stored.bytes_read()));
                    break;
                }
            }
        }
        if !header {
            return Err(ReplayError::NoHeader { path: name, bytes });
        }
        if info.truncated.is_none() && !stored.saw_footer() {
            info.truncated = Some(format!("ends at byte {} without its footer", stored.bytes_read()));
        }
        let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
        let mut channels: BTreeMap<u16, usize> = BTreeMap::new();
        for record in McapRecords::new(open()?, Chunks::Opened) {
            match record {
                Ok(mcap::records::Record::Schema { header, .. }) => {
                    schemas.insert(header.id, header.name);
                }
                Ok(mcap::records::Record::Channel(ch)) => {
                    let schema = schemas.get(&ch.schema_id).cloned().unwrap_or_default();
                    channels.entry(ch.id).or_insert_with(|| {
                        info.channels.push((ch.topic, ch.message_encoding, schema, 0));
                        info.channels.len() - 1
                    });
                }
                Ok(mcap::records::Record::Message { header, .. }) => {
                    if let Some(&k) = channels.get(&header.channel_id) {
                        info.channels[k].3 += 1;
                        if info.channels[k].0 == recording::CYCLE {
                            info.cycles += 1;
                        }
                    }
                    info.start_ns = Some(info.start_ns.map_or(header.log_time, |t| t.min(header.log_time)));
                    info.end_ns = Some(info.end_ns.map_or(header.log_time, |t| t.max(header.log_time)));
                }
                Ok(_) => {}
                Err(e) => {
                    info.truncated.get_or_insert(e.to_string());
                    break;
                }
            }
        }
        Ok(info)
    }

    fn count_chunk(&mut self, header: &mcap::records::ChunkHeader) {
        let compression = header.compression.clone();
        match self.chunks.iter_mut().find(|c| c.0 == compression) {
            Some(c) => {
                c.1 += 1;
                c.2 += header.compressed_size;
                c.3 += header.uncompressed_size;
            }
            None => self.chunks.push((compression, 1, header.compressed_size, header.uncompressed_size)),
        }
    }

    /// The chunks' bytes as stored: the messages, which grow with the run (the rest of a
    /// file, written once, is the schemas, metadata and summary).
    pub fn chunk_bytes(&self) -> u64 {
        self.chunks.iter().map(|c| c.2).sum()
    }

    /// Seconds from the first message to the last.
    pub fn duration(&self) -> f64 {
        match (self.start_ns, self.end_ns) {
            (Some(a), Some(b)) => b.saturating_sub(a) as f64 * 1e-9,
            _ => 0.0,
        }
    }
}

impl std::fmt::Display for RecordingInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let profile = if self.profile.is_empty() { "(none)" } else { &self.profile };
        writeln!(f, "profile      {profile}")?;
        writeln!(f, "size         {} bytes", self.bytes)?;
        writeln!(f, "duration     {:.3} s", self.duration())?;
        let messages: u64 = self.channels.iter().map(|c| c.3).sum();
        writeln!(f, "messages     {messages}")?;
        if self.cycles > 0 {
            writeln!(
                f,
                "cycles       {} ({:.0} bytes of messages a cycle; {:.0} of file with the schemas, metadata and index)",
                self.cycles,
                self.chunk_bytes() as f64 / self.cycles as f64,
                self.bytes as f64 / self.cycles as f64
            )?;
        }
        for (compression, n, stored, raw) in &self.chunks {
            let name = if compression.is_empty() { "none" } else { compression };
            let ratio = if *stored > 0 { *raw as f64 / *stored as f64 } else { 0.0 };
            writeln!(f, "chunks       {n} {name}: {stored} bytes stored, {raw} uncompressed ({ratio:.1}x)")?;
        }
        writeln!(f, "channels")?;
        for (topic, encoding, schema, n) in &self.channels {
            writeln!(f, "  {topic:<16} {n:>8} msgs  {encoding} {schema}")?;
        }
        match &self.truncated {
            Some(why) => write!(f, "cut short    {why}"),
            None => write!(f, "whole"),
        }
    }
}
