//! MCAP recordings of a run (`flowgate run --record FILE.mcap`).
//!
//! The loop queues records (the same bounded queue as the other telemetry: a full queue
//! drops and counts, never waits); the writer thread encodes them here. Channels:
//! - inputs to the core, in the order it took them, each with its host time in ns: `/psd/rx`
//!   (raw bytes as read), `/can/rx` (CAN events), `/gateway/input` (links opening and
//!   failing, operator requests, ticks, shutdown). The MCAP `sequence` of an input is its
//!   index over all three, so a replay merges them back and sees any gap;
//! - what the gateway sent: `/psd/tx` (packets to the controller), `/can/tx` (frames);
//! - per cycle: `/cycle` (the timing record: every stage, the command, the state);
//! - for the eye, at most every [`ARENA_EVERY_NS`]: `/obstacles` (position, velocity,
//!   covariance, planning radius), `/robot/pose` (`foxglove.PoseInFrame`)
//!   and `/arena` (`foxglove.SceneUpdate`: the lane's lines, the room's walls, static
//!   obstacles and view's edge, goal, obstacles with their planning circles, the robot); in a
//!   fleet also each vehicle's `/<name>/pose` and `/vehicles` (each one's state, pose, speeds,
//!   goal and script error), and `/arena` draws every vehicle, named, with its goal; and
//!   `/log` (`foxglove.Log`: state changes, operator requests and answers, and the core's
//!   notices, each at its level);
//! - metadata `flowgate`: the configuration the run used (TOML), the version, the clock's
//!   origin; `flowgate.end`: how many inputs and records were written and dropped.
//!
//! The CAN-frame and event records the text telemetry writes too live here.
//!
//! The well-known channels (`/robot/pose`, `/arena`, `/log`) are Foxglove's own schemas in
//! full, protobuf-encoded with the Foxglove SDK's types, their descriptors in the file, so
//! Foxglove draws them without set-up and any MCAP reader with protobuf support decodes
//! them. flowgate's own channels are JSON with a `jsonschema` schema naming each field's
//! type, so Foxglove plots any field and any MCAP reader can check it.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use flowgate_protocol::psd::{self, Packet};
use flowgate_protocol::CanFrame;
use foxglove::messages::{
    ArrowPrimitive, Duration, LinePrimitive, Log, PoseInFrame, SceneEntity, SceneUpdate, Timestamp,
};
use foxglove::{Encode, Schema};
use serde_json::{json, Value};

use super::foxglove::Live;
use crate::config::RecordCompression;
use crate::gateway::core::input::{InputRecord, PSD_CHUNK};
use crate::gateway::core::scene::{FleetScene, SceneRecord, SceneVehicle, VehicleChunk, VehicleLabel};
use crate::gateway::core::timing::CycleRecord;
use crate::gateway::core::{Level, Notice};
use crate::planner::room::{OutlineKind, RoomShape};
use crate::time::HostTime;

mod floor;
mod inputs;
use floor::{disc, floor_line, floor_pose, floor_text, heading_arrow, rgba, FRAME, SCRIPTED_COLOR, VEHICLE_COLOR};
use inputs::hex;
pub use inputs::{frame_from_json, frame_json, input_channel, input_from_json, input_json};
/// The metadata record holding the configuration.
pub const METADATA: &str = "flowgate";
/// The metadata record written at the end.
pub const METADATA_END: &str = "flowgate.end";
/// Input channels.
pub const PSD_RX: &str = "/psd/rx";
pub const CAN_RX: &str = "/can/rx";
pub const GATEWAY_INPUT: &str = "/gateway/input";
/// Output channels.
pub const PSD_TX: &str = "/psd/tx";
pub const CAN_TX: &str = "/can/tx";
pub const CYCLE: &str = "/cycle";
/// Per-cycle channels.
pub const OBSTACLES: &str = "/obstacles";
pub const POSE: &str = "/robot/pose";
/// The scene, at most every [`ARENA_EVERY_NS`].
pub const ARENA: &str = "/arena";
pub const LOG: &str = "/log";
/// A fleet's vehicles, each one's numbers (each one's pose is also `/<name>/pose`).
pub const VEHICLES: &str = "/vehicles";

/// A vehicle's pose channel: `/robot/pose`'s for a `[[vehicles]]` entry.
pub fn vehicle_pose_topic(name: &str) -> String {
    format!("/{name}/pose")
}

/// What the recording holds about the rig itself (drawn in every `/arena` update).
#[derive(Debug, Clone)]
pub struct RecordingSetup {
    /// The configuration the run used, as TOML (replay rebuilds the rig from it).
    pub config_toml: String,
    /// The lane's half-width, when the robot drives in a lane.
    pub lane_half_width: Option<f64>,
    /// The room's walls, static obstacles and view's edge, when the planner keeps to a room.
    pub room: Option<RoomShape>,
    pub robot_radius: f64,
    /// A fleet's other vehicles (`[[vehicles]]`), in order.
    pub vehicles: Vec<VehicleLabel>,
    /// Where the host clock's zero is, ns since the Unix epoch (MCAP log times are absolute).
    pub origin_unix_ns: u64,
    /// How the chunks are compressed.
    pub compression: RecordCompression,
}

/// Everything the writer thread writes into the MCAP file.
pub struct McapSink {
    /// The recording, when one is written: its path and writer.
    file: Option<(PathBuf, mcap::Writer<BufWriter<File>>)>,
    channels: BTreeMap<String, u16>,
    /// Foxglove live, when served: the same messages to its clients.
    live: Option<Live>,
    setup: RecordingSetup,
    inputs: u64,
    messages: u64,
    cycles: u64,
    /// When `/arena` was last drawn (host ns): once in each [`ARENA_EVERY_NS`] of host time.
    arena_at: Option<u64>,
    /// A fleet's other vehicles as their chunks last brought them, for the next scene.
    fleet: FleetScene,
    /// When the still entities (lane walls, goals) were last drawn, and the goals drawn
    /// (the robot's, then each vehicle's).
    still_at: Option<(u64, Vec<[f64; 2]>)>,
    flushed: std::time::Instant,
}

/// The MCAP chunk size, bytes.
const CHUNK_BYTES: u64 = 256 * 1024;
/// zstd's level (lz4 ignores it): a second's chunk of JSON compresses about 8 times, in
/// well under a millisecond of the writer thread's time.
const COMPRESSION_LEVEL: u32 = 9;
/// How often the writer closes the current chunk, so a reader sees it even if the gateway
/// is killed later. Two seconds: a chunk twice as long compresses a few percent better.
const FLUSH_EVERY: std::time::Duration = std::time::Duration::from_secs(2);

/// The display channels (`/obstacles`, `/robot/pose`, `/arena`) are for the eye: the first
/// cycle of each tenth of a second of host time, the live view's frame rate (`/cycle` keeps every cycle, and a replay
/// recomputes every cycle's estimates). At 20 they would be a sixth of the recording.
pub const ARENA_EVERY_NS: u64 = 100_000_000;
/// The still entities (lane walls, goal) are drawn again once a second, and when the goal
/// moves: Foxglove keeps an entity until it is replaced, and a client that joins live or
/// seeks in a recording has them within a second.
pub const STILL_EVERY_NS: u64 = 1_000_000_000;

/// Whether a cycle at `at` (host ns) is the first in its slot of `every` ns, `last` being the
/// last one drawn. Slots of host time rather than `every` after the last: cadences whose
/// periods divide each other pick the same cycles, so a bag exported at 20 Hz has a scene at
/// each of the recording's 10 Hz ones.
pub fn first_in_slot(last: Option<u64>, at: u64, every: u64) -> bool {
    last.is_none_or(|last| at / every.max(1) > last / every.max(1))
}

impl std::fmt::Debug for McapSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let path = self.file.as_ref().map(|(p, _)| p);
        f.debug_struct("McapSink").field("path", &path).field("live", &self.live).finish_non_exhaustive()
    }
}

/// What a recording holds, once written.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct RecordingSummary {
    pub path: Option<PathBuf>,
    pub inputs: u64,
    pub messages: u64,
    pub cycles: u64,
}

/// A minimal JSON Schema for an object with these properties (Foxglove takes the schema's
/// name for the well-known ones and the properties for plots).
fn object_schema(title: &str, properties: &[(&str, &str)]) -> Vec<u8> {
    let props: serde_json::Map<String, Value> =
        properties.iter().map(|(name, ty)| (name.to_string(), json!({ "type": ty }))).collect();
    serde_json::to_vec(&json!({ "title": title, "type": "object", "properties": props })).unwrap_or_default()
}

/// A channel's topic, schema and message encoding.
struct ChannelSpec {
    topic: String,
    schema: Schema,
    message_encoding: &'static str,
}

/// A channel of JSON messages with a JSON Schema.
fn json_channel(topic: &str, schema_name: &str, schema: Vec<u8>) -> ChannelSpec {
    ChannelSpec {
        topic: topic.into(),
        schema: Schema::new(schema_name, "jsonschema", schema),
        message_encoding: "json",
    }
}

/// A channel of one of Foxglove's well-known messages, protobuf-encoded, with the SDK's
/// descriptor of it.
fn foxglove_channel<M: Encode>(topic: &str) -> std::io::Result<ChannelSpec> {
    let schema =
        M::get_schema().ok_or_else(|| std::io::Error::other(format!("the Foxglove SDK has no schema for {topic}")))?;
    Ok(ChannelSpec { topic: topic.into(), schema, message_encoding: "protobuf" })
}

/// Every channel: the fixed ones, then a fleet's (`/vehicles`, each vehicle's pose).
fn channel_table(vehicles: &[VehicleLabel]) -> std::io::Result<Vec<ChannelSpec>> {
    let mut table = fixed_channels()?.into_iter().collect::<Vec<_>>();
    if !vehicles.is_empty() {
        table.push(json_channel(VEHICLES, "flowgate.Vehicles", vehicles_schema()));
        for v in vehicles {
            table.push(foxglove_channel::<PoseInFrame>(&vehicle_pose_topic(&v.name))?);
        }
    }
    Ok(table)
}

fn fixed_channels() -> std::io::Result<[ChannelSpec; 10]> {
    let input_schema = object_schema(
        "flowgate.Input",
        &[("seq", "integer"), ("t_ns", "integer"), ("kind", "string"), ("bytes", "string"), ("event", "string")],
    );
    let frame_schema = object_schema(
        "flowgate.CanFrame",
        &[("id", "integer"), ("extended", "boolean"), ("remote", "boolean"), ("data", "string")],
    );
    let cycle_props: Vec<(&str, &str)> = CycleRecord::CSV_HEADER
        .split(',')
        .filter(|c| !CYCLE_DERIVED.contains(c))
        .map(|c| (c, cycle_field_type(c)))
        .collect();
    Ok([
        json_channel(PSD_RX, "flowgate.Input", input_schema.clone()),
        json_channel(CAN_RX, "flowgate.Input", input_schema.clone()),
        json_channel(GATEWAY_INPUT, "flowgate.Input", input_schema),
        json_channel(
            PSD_TX,
            "flowgate.PsdPacket",
            object_schema(
                "flowgate.PsdPacket",
                &[("t_ns", "integer"), ("seq", "integer"), ("message", "string"), ("wire", "string")],
            ),
        ),
        json_channel(CAN_TX, "flowgate.CanFrame", frame_schema),
        json_channel(CYCLE, "flowgate.Cycle", object_schema("flowgate.Cycle", &cycle_props)),
        json_channel(OBSTACLES, "flowgate.Obstacles", obstacles_schema()),
        foxglove_channel::<PoseInFrame>(POSE)?,
        foxglove_channel::<SceneUpdate>(ARENA)?,
        foxglove_channel::<Log>(LOG)?,
    ])
}

/// `/obstacles`: each tracked obstacle as the planner saw it.
fn obstacles_schema() -> Vec<u8> {
    let pair = json!({ "type": "array", "items": { "type": "number" }, "minItems": 2, "maxItems": 2 });
    let obstacle = json!({
        "type": "object",
        "properties": {
            "position": pair, "velocity": pair,
            "covariance": { "type": "array", "items": { "type": "number" }, "minItems": 3, "maxItems": 3,
                            "description": "xx, xy, yy, m²" },
            "planning_radius": { "type": "number" }, "radius": { "type": "number" }
        }
    });
    stamped_list_schema("flowgate.Obstacles", "obstacles", obstacle)
}

/// `/vehicles`: each of a fleet's other vehicles as its last cycle estimated it.
fn vehicles_schema() -> Vec<u8> {
    let numbers = |n: usize, description: &str| {
        json!({ "type": "array", "items": { "type": "number" }, "minItems": n, "maxItems": n,
                "description": description })
    };
    let vehicle = json!({
        "type": "object",
        "properties": {
            "name": { "type": "string" }, "state": { "type": "string" }, "seen": { "type": "boolean" },
            "pose": numbers(3, "x, y (m), heading (rad)"), "twist": numbers(2, "forward m/s, yaw rad/s"),
            "goal": numbers(2, "x, y (m)"),
            "script_error": { "type": "number", "description": "a scripted vehicle's distance from its script, m" }
        }
    });
    stamped_list_schema("flowgate.Vehicles", "vehicles", vehicle)
}

/// A message of a timestamp and a list under `key`, each item as `item` says.
fn stamped_list_schema(title: &str, key: &str, item: Value) -> Vec<u8> {
    let timestamp =
        json!({ "type": "object", "properties": { "sec": { "type": "integer" }, "nsec": { "type": "integer" } } });
    let mut properties = serde_json::Map::new();
    properties.insert("timestamp".into(), timestamp);
    properties.insert(key.into(), json!({ "type": "array", "items": item }));
    serde_json::to_vec(&json!({ "title": title, "type": "object", "properties": properties })).unwrap_or_default()
}

/// Columns of `cycles.csv` that `/cycle` leaves out, each exactly another's sum:
/// `can_done_ns` is `rx_ns + e2e_ns` (0 when no frame was written, as `e2e_ns`).
const CYCLE_DERIVED: [&str; 1] = ["can_done_ns"];

/// The JSON type of a `/cycle` field: its times and counts are integers.
fn cycle_field_type(name: &str) -> &'static str {
    match name {
        "state" => "string",
        "delay_s" | "goal_distance" | "x" | "y" | "asked_left" | "asked_right" | "passed_left" | "passed_right" => {
            "number"
        }
        _ => "integer",
    }
}

/// An `f32` of the scene to `places` decimals: a position to 10 µm and a speed to 0.1 mm/s
/// are finer than the camera resolves, and the digits past them would be most of the
/// compressed channel.
fn decimals(v: f32, places: i32) -> f64 {
    let scale = 10f64.powi(places);
    (f64::from(v) * scale).round() / scale
}

/// An `f32` to three significant digits (a variance of 1.38e-5 m²).
fn significant3(v: f32) -> f64 {
    format!("{v:.2e}").parse().unwrap_or(0.0)
}

/// A vehicle's line in `/vehicles`.
fn vehicle_json(label: &VehicleLabel, v: &SceneVehicle) -> Value {
    let mut line = json!({
        "name": label.name, "state": v.state.name(), "seen": v.seen,
        "pose": [decimals(v.pose[0], 5), decimals(v.pose[1], 5), decimals(v.pose[2], 4)],
        "twist": v.twist.map(|x| decimals(x, 4)), "goal": v.goal.map(|x| decimals(x, 5)),
    });
    if let Some(error) = v.script_error {
        line["script_error"] = json!(decimals(error, 5));
    }
    line
}

fn io_error(e: mcap::McapError) -> std::io::Error {
    std::io::Error::other(e)
}

impl McapSink {
    /// Create the recording at `path` (none: no file) and write its channels and the
    /// configuration; advertise the same channels on `live` when it is served.
    pub fn create(path: Option<&Path>, setup: RecordingSetup, mut live: Option<Live>) -> std::io::Result<Self> {
        let mut writer = match path {
            Some(path) => Some((path.to_path_buf(), Self::create_file(path, &setup)?)),
            None => None,
        };
        let mut channels = BTreeMap::new();
        for spec in channel_table(&setup.vehicles)? {
            if let Some((_, writer)) = &mut writer {
                let schema_id =
                    writer.add_schema(&spec.schema.name, &spec.schema.encoding, &spec.schema.data).map_err(io_error)?;
                let id = writer
                    .add_channel(schema_id, &spec.topic, spec.message_encoding, &BTreeMap::new())
                    .map_err(io_error)?;
                channels.insert(spec.topic.clone(), id);
            }
            if let Some(live) = &mut live {
                live.add_channel(&spec.topic, spec.schema, spec.message_encoding).map_err(std::io::Error::other)?;
            }
        }
        if let Some((_, writer)) = &mut writer {
            let metadata = BTreeMap::from([
                ("config".to_string(), setup.config_toml.clone()),
                ("version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
                ("origin_unix_ns".to_string(), setup.origin_unix_ns.to_string()),
                ("psd_chunk".to_string(), PSD_CHUNK.to_string()),
            ]);
            writer.write_metadata(&mcap::records::Metadata { name: METADATA.into(), metadata }).map_err(io_error)?;
        }
        Ok(Self {
            file: writer,
            channels,
            live,
            setup,
            inputs: 0,
            messages: 0,
            cycles: 0,
            arena_at: None,
            fleet: FleetScene::default(),
            still_at: None,
            flushed: std::time::Instant::now(),
        })
    }

    fn create_file(path: &Path, setup: &RecordingSetup) -> std::io::Result<mcap::Writer<BufWriter<File>>> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        let file = BufWriter::new(File::create(path)?);
        // Small chunks, and a flush every two seconds (`flush_if_due`): a gateway killed
        // outright loses at most about the last two seconds of its recording.
        let compression = match setup.compression {
            RecordCompression::Zstd => Some(mcap::Compression::Zstd),
            RecordCompression::Lz4 => Some(mcap::Compression::Lz4),
            RecordCompression::None => None,
        };
        // No message indexes: a reader scans a second's chunk as fast as it seeks in it, and
        // they would be a quarter of a compressed file.
        let options = mcap::WriteOptions::new()
            .compression(compression)
            .compression_level(COMPRESSION_LEVEL)
            .emit_message_indexes(false)
            .profile("flowgate")
            .chunk_size(Some(CHUNK_BYTES));
        options.create(file).map_err(io_error)
    }

    fn put(&mut self, topic: &str, sequence: u32, host_ns: u64, value: &Value) -> std::io::Result<()> {
        let data = serde_json::to_vec(value).map_err(std::io::Error::other)?;
        self.put_bytes(topic, sequence, host_ns, &data)
    }

    /// Put one of Foxglove's well-known messages.
    fn put_message<M: Encode>(&mut self, topic: &str, sequence: u32, host_ns: u64, message: &M) -> std::io::Result<()> {
        let mut data = Vec::with_capacity(message.encoded_len().unwrap_or(256));
        message.encode(&mut data).map_err(|e| std::io::Error::other(e.to_string()))?;
        self.put_bytes(topic, sequence, host_ns, &data)
    }

    fn put_bytes(&mut self, topic: &str, sequence: u32, host_ns: u64, data: &[u8]) -> std::io::Result<()> {
        let log_time = self.setup.origin_unix_ns.saturating_add(host_ns);
        if let Some(live) = &self.live {
            live.log(topic, log_time, data);
        }
        let (Some((_, writer)), Some(&channel_id)) = (&mut self.file, self.channels.get(topic)) else { return Ok(()) };
        let header = mcap::records::MessageHeader { channel_id, sequence, log_time, publish_time: log_time };
        writer.write_to_known_channel(&header, data).map_err(io_error)?;
        self.messages += 1;
        Ok(())
    }

    /// Close the current chunk if the last flush was a second ago (the writer calls this
    /// when its queue is empty).
    pub fn flush_if_due(&mut self) -> std::io::Result<()> {
        if let (Some((_, writer)), true) = (&mut self.file, self.flushed.elapsed() >= FLUSH_EVERY) {
            self.flushed = std::time::Instant::now();
            writer.flush().map_err(io_error)?;
        }
        Ok(())
    }

    pub fn input(&mut self, r: &InputRecord) -> std::io::Result<()> {
        self.inputs += 1;
        // MCAP's sequence is 32 bits: a run at 1 kHz takes weeks to wrap it; `seq` in the
        // message is the full count.
        self.put(input_channel(&r.input), r.seq as u32, r.at.as_nanos(), &input_json(r))
    }

    pub fn psd_sent(&mut self, at: HostTime, packet: &Packet) -> std::io::Result<()> {
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let n = packet.encode(&mut wire).unwrap_or(0);
        let v = json!({ "t_ns": at.as_nanos(), "seq": packet.seq, "message": format!("{:?}", packet.message), "wire": hex(&wire[..n]) });
        self.put(PSD_TX, u32::from(packet.seq), at.as_nanos(), &v)
    }

    pub fn can(&mut self, r: &CanRecord) -> std::io::Result<()> {
        if !r.sent {
            // Received frames are inputs (`/can/rx`).
            return Ok(());
        }
        let host_ns = ((r.at_s * 1e9) as u64).saturating_sub(self.setup.origin_unix_ns);
        let mut v = frame_json(&r.frame);
        v["written"] = json!(true);
        self.put(CAN_TX, 0, host_ns, &v)
    }

    /// A frame the core asked for while the link was down: in `/can/tx` with `written`
    /// false, so a replay compares everything the core decided.
    pub fn can_unwritten(&mut self, at: HostTime, frame: &CanFrame) -> std::io::Result<()> {
        let mut v = frame_json(frame);
        v["written"] = json!(false);
        self.put(CAN_TX, 0, at.as_nanos(), &v)
    }

    pub fn cycle(&mut self, c: &CycleRecord) -> std::io::Result<()> {
        self.cycles += 1;
        let mut row = Vec::with_capacity(160);
        c.csv(&mut row)?;
        let text = String::from_utf8_lossy(&row);
        let fields: serde_json::Map<String, Value> = CycleRecord::CSV_HEADER
            .split(',')
            .zip(text.trim_end().split(','))
            .filter(|(name, _)| !CYCLE_DERIVED.contains(name))
            .map(|(name, value)| {
                let v = match cycle_field_type(name) {
                    "integer" => value.parse::<i64>().map_or_else(|_| json!(value), |x| json!(x)),
                    "number" => value.parse::<f64>().map_or_else(|_| json!(value), |x| json!(x)),
                    _ => json!(value),
                };
                (name.to_string(), v)
            })
            .collect();
        self.put(CYCLE, c.cycle as u32, c.rx_ns, &Value::Object(fields))
    }

    pub fn event(&mut self, e: &EventRecord) -> std::io::Result<()> {
        let at_ns = (e.at_s * 1e9) as u64;
        let log = Log {
            timestamp: Some(self.stamp(at_ns)),
            level: match e.level {
                Level::Info => foxglove::messages::log::Level::Info,
                Level::Warning => foxglove::messages::log::Level::Warning,
                Level::Error => foxglove::messages::log::Level::Error,
            } as i32,
            message: e.text.clone(),
            name: "flowgate".into(),
            file: String::new(),
            line: 0,
        };
        self.put_message(LOG, 0, at_ns, &log)
    }

    /// A host time as a Foxglove timestamp (since the Unix epoch).
    fn stamp(&self, host_ns: u64) -> Timestamp {
        let t = self.setup.origin_unix_ns.saturating_add(host_ns);
        Timestamp::new((t / 1_000_000_000).min(u64::from(u32::MAX)) as u32, (t % 1_000_000_000) as u32)
    }

    fn stamp_json(&self, host_ns: u64) -> Value {
        let t = self.setup.origin_unix_ns.saturating_add(host_ns);
        json!({ "sec": t / 1_000_000_000, "nsec": t % 1_000_000_000 })
    }

    /// Part of the fleet's vehicles, for the scene that follows it.
    pub fn vehicles_chunk(&mut self, chunk: &VehicleChunk) {
        self.fleet.take(chunk);
    }

    /// A cycle's scene, with the fleet's vehicles as their chunks brought them.
    pub fn scene(&mut self, s: &SceneRecord) -> std::io::Result<()> {
        // For the eye, at a display's rate (`/cycle` has every cycle's position, and a
        // replay recomputes every cycle's estimates from the inputs).
        let at = s.at.as_nanos();
        if !first_in_slot(self.arena_at, at, ARENA_EVERY_NS) {
            return Ok(());
        }
        self.arena_at = Some(at);
        let obstacles: Vec<Value> = s
            .obstacles()
            .iter()
            .map(|o| {
                json!({
                    "position": o.position.map(|v| decimals(v, 5)), "velocity": o.velocity.map(|v| decimals(v, 4)),
                    "covariance": o.covariance.map(significant3), "planning_radius": decimals(o.planning_radius, 5),
                    "radius": decimals(o.radius, 5)
                })
            })
            .collect();
        self.put(OBSTACLES, s.cycle as u32, at, &json!({ "timestamp": self.stamp_json(at), "obstacles": obstacles }))?;
        let [x, y, heading] = s.pose;
        let pose = PoseInFrame {
            timestamp: Some(self.stamp(at)),
            frame_id: FRAME.into(),
            pose: Some(floor_pose(x, y, heading, 0.0)),
        };
        self.put_message(POSE, s.cycle as u32, at, &pose)?;
        self.vehicles(s)?;
        let goals: Vec<[f64; 2]> =
            std::iter::once(s.goal).chain(self.fleet.vehicles().iter().map(|v| v.goal.map(f64::from))).collect();
        let still = self.still_at.as_ref().is_none_or(|(last, drawn)| at >= last + STILL_EVERY_NS || *drawn != goals);
        if still {
            self.still_at = Some((at, goals));
        }
        let arena = self.arena(s, self.stamp(at), still);
        self.put_message(ARENA, s.cycle as u32, at, &arena)
    }

    /// A fleet's `/vehicles`, and each seen vehicle's `/<name>/pose`.
    fn vehicles(&mut self, s: &SceneRecord) -> std::io::Result<()> {
        if self.setup.vehicles.is_empty() {
            return Ok(());
        }
        let (at, stamp) = (s.at.as_nanos(), self.stamp(s.at.as_nanos()));
        let labelled = || self.setup.vehicles.iter().zip(self.fleet.vehicles());
        let listed: Vec<Value> = labelled().map(|(l, v)| vehicle_json(l, v)).collect();
        let poses: Vec<(String, PoseInFrame)> = labelled()
            .filter(|(_, v)| v.seen)
            .map(|(label, v)| {
                let [x, y, heading] = v.pose.map(f64::from);
                let pose = floor_pose(x, y, heading, 0.0);
                (
                    vehicle_pose_topic(&label.name),
                    PoseInFrame { timestamp: Some(stamp), frame_id: FRAME.into(), pose: Some(pose) },
                )
            })
            .collect();
        self.put(VEHICLES, s.cycle as u32, at, &json!({ "timestamp": self.stamp_json(at), "vehicles": listed }))?;
        for (topic, pose) in &poses {
            self.put_message(topic, s.cycle as u32, at, pose)?;
        }
        Ok(())
    }

    /// The arena as Foxglove scene entities: `arena` (the robot, each obstacle's planning
    /// circle and velocity arrow), and with `still` the lane's lines (`lane`, in a lane),
    /// the room (`room`: walls as line strips, static obstacles and the view's edge as line
    /// loops, in that order) and the `goal`.
    fn arena(&self, s: &SceneRecord, stamp: Timestamp, still: bool) -> SceneUpdate {
        let mut cylinders = vec![disc(s.pose[0], s.pose[1], self.setup.robot_radius, 0.05, [0.1, 0.3, 0.9, 0.9])];
        let mut arrows = Vec::new();
        let mut texts = Vec::new();
        if !self.setup.vehicles.is_empty() {
            texts.push(floor_text(s.pose[0], s.pose[1], "robot"));
        }
        for (label, v) in self.setup.vehicles.iter().zip(self.fleet.vehicles()).filter(|(_, v)| v.seen) {
            let [x, y, heading] = v.pose.map(f64::from);
            let color = if label.scripted { SCRIPTED_COLOR } else { VEHICLE_COLOR };
            cylinders.push(disc(x, y, label.radius, 0.05, color));
            arrows.push(heading_arrow(x, y, heading, label.radius));
            texts.push(floor_text(x, y, &label.name));
        }
        for o in s.obstacles() {
            let [x, y] = o.position.map(f64::from);
            cylinders.push(disc(x, y, f64::from(o.planning_radius), 0.01, [0.9, 0.5, 0.1, 0.25]));
            let [vx, vy] = o.velocity.map(f64::from);
            let speed = vx.hypot(vy);
            if speed > 1e-3 {
                arrows.push(ArrowPrimitive {
                    pose: Some(floor_pose(x, y, vy.atan2(vx), 0.06)),
                    shaft_length: speed,
                    shaft_diameter: 0.01,
                    head_length: 0.03,
                    head_diameter: 0.03,
                    color: Some(rgba([0.9, 0.2, 0.1, 1.0])),
                });
            }
        }
        let lane: Vec<LinePrimitive> = self
            .setup
            .lane_half_width
            .map(|h| [-h, h].map(|y| floor_line(&[[-10.0, y], [10.0, y]], false, 0.01, [0.2, 0.2, 0.2, 1.0])))
            .into_iter()
            .flatten()
            .collect();
        let room: Vec<LinePrimitive> = self
            .setup
            .room
            .iter()
            .flat_map(RoomShape::outlines)
            .map(|(kind, points)| {
                let points: Vec<[f64; 2]> = points.iter().map(|p| [p.re, p.im]).collect();
                match kind {
                    OutlineKind::Wall => floor_line(&points, false, 0.02, [0.2, 0.2, 0.2, 1.0]),
                    OutlineKind::StaticObstacle => floor_line(&points, true, 0.015, [0.45, 0.3, 0.15, 1.0]),
                    OutlineKind::View => floor_line(&points, true, 0.005, [0.5, 0.5, 0.5, 0.6]),
                }
            })
            .collect();
        let entity = |id: &str| SceneEntity {
            timestamp: Some(stamp),
            frame_id: FRAME.into(),
            id: id.into(),
            lifetime: Some(Duration::new(0, 0)),
            ..Default::default()
        };
        let mut entities = vec![SceneEntity { arrows, cylinders, texts, ..entity("arena") }];
        if still {
            if !lane.is_empty() {
                entities.push(SceneEntity { lines: lane, ..entity("lane") });
            }
            if !room.is_empty() {
                entities.push(SceneEntity { lines: room, ..entity("room") });
            }
            let mut goals = vec![disc(s.goal[0], s.goal[1], 0.02, 0.002, [0.1, 0.7, 0.2, 1.0])];
            for (label, v) in self.setup.vehicles.iter().zip(self.fleet.vehicles()) {
                let color = if label.scripted { SCRIPTED_COLOR } else { VEHICLE_COLOR };
                let [x, y] = v.goal.map(f64::from);
                goals.push(disc(x, y, 0.02, 0.002, color));
            }
            entities.push(SceneEntity { cylinders: goals, ..entity("goal") });
        }
        SceneUpdate { deletions: Vec::new(), entities }
    }

    /// Close the file: the end record says how many inputs the loop took (`taken`) and how
    /// many records the queue dropped, so a reader knows whether the recording is whole.
    /// Stop serving live. None: there was no recording to close.
    pub fn finish(mut self, taken: u64, dropped: u64) -> std::io::Result<Option<RecordingSummary>> {
        if let Some(live) = self.live.take() {
            live.stop();
        }
        let Some((path, mut writer)) = self.file.take() else { return Ok(None) };
        let metadata = BTreeMap::from([
            ("inputs_taken".to_string(), taken.to_string()),
            ("inputs_written".to_string(), self.inputs.to_string()),
            ("records_dropped".to_string(), dropped.to_string()),
        ]);
        writer.write_metadata(&mcap::records::Metadata { name: METADATA_END.into(), metadata }).map_err(io_error)?;
        writer.finish().map_err(io_error)?;
        Ok(Some(RecordingSummary {
            path: Some(path),
            inputs: self.inputs,
            messages: self.messages,
            cycles: self.cycles,
        }))
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

/// Something that happened, in words: a state change, an operator's request and its answer,
/// or a notice of the core's (its warnings and errors among them), with its fields.
#[derive(Debug, Clone)]
pub struct EventRecord {
    pub at_s: f64,
    pub level: Level,
    /// What it is: `state`, `request`, or a notice's kind (`sequence_rebased`, ...).
    pub kind: &'static str,
    pub text: String,
    pub fields: Option<Value>,
}

impl EventRecord {
    /// A notice of the core's at `at_s`.
    pub fn notice(at_s: f64, notice: &Notice) -> Self {
        Self {
            at_s,
            level: notice.level(),
            kind: notice.kind(),
            text: notice.to_string(),
            fields: Some(notice.fields()),
        }
    }

    /// Its line in `events.jsonl`.
    pub fn json(&self) -> Value {
        let mut line = json!({ "t_s": self.at_s, "level": self.level.name(), "kind": self.kind, "text": self.text });
        if let Some(fields) = &self.fields {
            line["fields"] = fields.clone();
        }
        line
    }
}

#[cfg(test)]
mod tests;
