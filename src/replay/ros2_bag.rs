//! `flowgate record export --ros2 DIR`: a recording as a rosbag2 (MCAP storage, profile
//! `ros2`, CDR messages with `ros2msg` schemas, and `metadata.yaml`), with the topics the
//! live ROS 2 node publishes. The recording is replayed through the core, which rebuilds
//! every cycle's scene exactly; each cycle gives `/odom` and `/tf` stamped at its log time,
//! `~/obstacles` and `~/path` on the first cycle of each `1 / [ros2] publish_hz` of host
//! time (at the default 20 Hz, at each instant of the recording's own 10 Hz `/obstacles`),
//! `/diagnostics` once a second; a fleet's other vehicles' `/<name>/odom` and their frames on
//! `/tf` at `publish_hz` from the first input on, whether or not the robot has cycles.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::{Recording, ReplayError};
use crate::config::Ros2Section;
use crate::gateway::core::scene::FleetScene;
use crate::gateway::core::{Core, NoClock, Output};
use crate::gateway::shell::metrics::Snapshot;
use crate::gateway::shell::recording::first_in_slot;
use crate::gateway::shell::ros2::convert::{self, Frames};
use crate::gateway::shell::ros2::msgs::{TfMessage, Time};
use crate::gateway::shell::view::ViewSetup;
use crate::time::HostTime;

/// Each message type's definition (`.msg`, without comments), by `package/Name`: a schema is
/// its type's definition followed by every type it uses, as rosbag2 writes them.
const DEFINITIONS: &[(&str, &str)] = &[
    ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
    ("builtin_interfaces/Duration", "int32 sec\nuint32 nanosec\n"),
    ("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
    ("std_msgs/ColorRGBA", "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n"),
    ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Quaternion", "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"),
    ("geometry_msgs/Pose", "Point position\nQuaternion orientation\n"),
    ("geometry_msgs/PoseWithCovariance", "Pose pose\nfloat64[36] covariance\n"),
    ("geometry_msgs/Twist", "Vector3 linear\nVector3 angular\n"),
    ("geometry_msgs/TwistWithCovariance", "Twist twist\nfloat64[36] covariance\n"),
    ("geometry_msgs/PoseStamped", "std_msgs/Header header\nPose pose\n"),
    ("geometry_msgs/Transform", "Vector3 translation\nQuaternion rotation\n"),
    ("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"),
    (
        "nav_msgs/Odometry",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n\
         geometry_msgs/TwistWithCovariance twist\n",
    ),
    ("nav_msgs/Path", "std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses\n"),
    ("tf2_msgs/TFMessage", "geometry_msgs/TransformStamped[] transforms\n"),
    ("sensor_msgs/CompressedImage", "std_msgs/Header header\nstring format\nuint8[] data\n"),
    ("visualization_msgs/UVCoordinate", "float32 u\nfloat32 v\n"),
    ("visualization_msgs/MeshFile", "string filename\nuint8[] data\n"),
    (
        "visualization_msgs/Marker",
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\nint32 LINE_LIST=5\n\
         int32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\nint32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\n\
         int32 TRIANGLE_LIST=11\nint32 ARROW_STRIP=12\nint32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n\
         std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Pose pose\n\
         geometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\n\
         bool frame_locked\ngeometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\n\
         sensor_msgs/CompressedImage texture\nUVCoordinate[] uv_coordinates\nstring text\nstring mesh_resource\n\
         MeshFile mesh_file\nbool mesh_use_embedded_materials\n",
    ),
    ("visualization_msgs/MarkerArray", "Marker[] markers\n"),
    ("diagnostic_msgs/KeyValue", "string key\nstring value\n"),
    (
        "diagnostic_msgs/DiagnosticStatus",
        "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\nstring message\n\
         string hardware_id\nKeyValue[] values\n",
    ),
    ("diagnostic_msgs/DiagnosticArray", "std_msgs/Header header\nDiagnosticStatus[] status\n"),
];

fn definition(name: &str) -> &'static str {
    DEFINITIONS.iter().find(|(n, _)| *n == name).map(|(_, d)| *d).expect("every type used is defined")
}

/// The types a definition's fields name, as `package/Name` (a bare name is of `package`).
fn used_types(package: &str, text: &str) -> Vec<String> {
    text.lines()
        .filter_map(|line| line.split_whitespace().next())
        .filter(|kind| !line_is_constant(kind))
        .map(|kind| kind.split('[').next().unwrap_or(kind))
        .filter(|kind| kind.contains('/') || kind.starts_with(|c: char| c.is_ascii_uppercase()))
        .map(|kind| if kind.contains('/') { kind.to_owned() } else { format!("{package}/{kind}") })
        .collect()
}

fn line_is_constant(first_word: &str) -> bool {
    first_word.contains('=')
}

/// The `ros2msg` schema of `name` (`nav_msgs/Odometry`): its definition, then each type it
/// uses, depth first, once.
pub fn schema(name: &str) -> String {
    let mut text = definition(name).to_owned();
    let mut seen = vec![name.to_owned()];
    let mut stack: Vec<String> = used_types(name.split('/').next().unwrap_or(""), definition(name));
    stack.reverse();
    while let Some(t) = stack.pop() {
        if seen.contains(&t) {
            continue;
        }
        let def = definition(&t);
        text.push_str(&format!("{}\nMSG: {t}\n{def}", "=".repeat(80)));
        let mut more = used_types(t.split('/').next().unwrap_or(""), def);
        more.reverse();
        stack.extend(more);
        seen.push(t);
    }
    text
}

#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{0} exists: a rosbag2 goes into a new folder")]
    Exists(String),
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("writing the bag: {0}")]
    Mcap(#[from] mcap::McapError),
    #[error("encoding a message: {0}")]
    Cdr(String),
    #[error(transparent)]
    Replay(#[from] ReplayError),
    #[error("the recorded [ros2]: {0}")]
    Ros2(crate::config::Invalid),
    #[error("the recording has no cycle: nothing to export")]
    Empty,
}

/// What an export wrote.
#[derive(Debug, Clone, Serialize)]
pub struct BagSummary {
    pub dir: PathBuf,
    pub file: PathBuf,
    /// Messages by topic.
    pub messages: BTreeMap<String, u64>,
    pub start_ns: u64,
    pub end_ns: u64,
}

/// The QoS rosbag2 records for each topic (what `ros2 bag play` offers again): the live
/// node's, reliable and volatile.
fn offered_qos(depth: u16) -> String {
    format!(
        "- history: 1\n  depth: {depth}\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n  avoid_ros_namespace_conventions: false\n"
    )
}

/// The bag's MCAP file as it is written: a channel per topic, counted.
struct BagWriter {
    mcap: mcap::Writer<std::io::BufWriter<std::fs::File>>,
    /// Topic: channel id, ROS type, sequence, messages.
    channels: BTreeMap<String, (u16, String, u32)>,
    qos: String,
    start_ns: u64,
    end_ns: u64,
}

impl BagWriter {
    fn create(path: &Path, depth: u16) -> Result<Self, BagError> {
        let file =
            std::fs::File::create(path).map_err(|source| BagError::Io { path: path.display().to_string(), source })?;
        let mcap = mcap::WriteOptions::new()
            .profile("ros2")
            .compression(Some(mcap::Compression::Zstd))
            .create(std::io::BufWriter::new(file))?;
        Ok(Self { mcap, channels: BTreeMap::new(), qos: offered_qos(depth), start_ns: u64::MAX, end_ns: 0 })
    }

    /// Put `message` of ROS type `kind` (`nav_msgs/msg/Odometry`) on `topic` at `stamp_ns`.
    fn put<M: Serialize>(&mut self, topic: &str, kind: &str, stamp_ns: u64, message: &M) -> Result<(), BagError> {
        if !self.channels.contains_key(topic) {
            let short = kind.replace("/msg/", "/");
            let schema = self.mcap.add_schema(kind, "ros2msg", schema(&short).as_bytes())?;
            let metadata = BTreeMap::from([("offered_qos_profiles".to_owned(), self.qos.clone())]);
            let id = self.mcap.add_channel(schema, topic, "cdr", &metadata)?;
            self.channels.insert(topic.to_owned(), (id, kind.to_owned(), 0));
        }
        let (id, _, sequence) = self.channels.get_mut(topic).expect("added above");
        // CDR, little-endian: the encapsulation header, then the message.
        let mut data = vec![0x00, 0x01, 0x00, 0x00];
        data.extend(
            cdr_encoding::to_vec::<M, byteorder::LittleEndian>(message).map_err(|e| BagError::Cdr(e.to_string()))?,
        );
        let header = mcap::records::MessageHeader {
            channel_id: *id,
            sequence: *sequence,
            log_time: stamp_ns,
            publish_time: stamp_ns,
        };
        self.mcap.write_to_known_channel(&header, &data)?;
        *sequence += 1;
        self.start_ns = self.start_ns.min(stamp_ns);
        self.end_ns = self.end_ns.max(stamp_ns);
        Ok(())
    }
}

/// The time a host time of the recording is on the Unix clock.
fn unix_stamp(origin_unix_ns: u64, at: HostTime) -> (u64, Time) {
    let ns = origin_unix_ns + at.as_nanos();
    let stamp = Time { sec: (ns / 1_000_000_000) as i32, nanosec: (ns % 1_000_000_000) as u32 };
    (ns, stamp)
}

/// Export `recording` as a rosbag2 in `dir` (a new folder): `<dir name>_0.mcap` and
/// `metadata.yaml`. The bag is written in a hidden folder beside `dir` and renamed to it
/// once whole: a failed export leaves nothing behind, and `dir` never holds half a bag.
pub fn export(recording: &Recording, dir: &Path) -> Result<BagSummary, BagError> {
    if dir.exists() {
        return Err(BagError::Exists(dir.display().to_string()));
    }
    let io = |path: &Path| {
        let path = path.display().to_string();
        move |source| BagError::Io { path, source }
    };
    let name = dir.file_name().map_or("flowgate".into(), |n| n.to_string_lossy().into_owned());
    let parent = dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(io(parent))?;
    let partial = parent.join(format!(".{name}.partial-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&partial);
    std::fs::create_dir(&partial).map_err(io(&partial))?;
    let written = write_bag(recording, &partial, &name).and_then(|summary| {
        std::fs::rename(&partial, dir).map_err(io(dir))?;
        Ok(BagSummary { dir: dir.to_path_buf(), file: dir.join(format!("{name}_0.mcap")), ..summary })
    });
    if written.is_err() {
        let _ = std::fs::remove_dir_all(&partial);
    }
    written
}

/// The bag's files in `dir`, named after `name`.
fn write_bag(recording: &Recording, dir: &Path, name: &str) -> Result<BagSummary, BagError> {
    let config = recording.config()?;
    let rig = config.rig("the recorded configuration").map_err(ReplayError::from)?;
    let settings =
        config.ros2.clone().unwrap_or_else(Ros2Section::default).resolve(|_| None).map_err(BagError::Ros2)?;
    let frames = Frames { floor: settings.floor_frame.clone(), base: settings.base_frame.clone() };
    let fqn = format!("{}/{}", settings.namespace.trim_end_matches('/'), settings.node_name);
    let view = ViewSetup::of(&rig);
    let file = dir.join(format!("{name}_0.mcap"));
    let mut bag = BagWriter::create(&file, settings.qos_depth)?;
    let origin = recording.origin_unix_ns;
    let start_s = origin as f64 * 1e-9;
    let every = u64::try_from(settings.publish_every.as_nanos()).unwrap_or(u64::MAX);
    let (mut last_scene, mut next_stats) = (None, HostTime::ZERO);
    let mut core = Core::new(rig, NoClock);
    // A fleet's other vehicles at the node's rate, whether or not the robot has cycles.
    let mut next_fleet = (!view.vehicles.is_empty()).then_some(HostTime::ZERO);
    for input in &recording.inputs {
        core.handle(input.at, input.input.as_input());
        if let Some(next) = next_fleet.as_mut().filter(|next| input.at >= **next) {
            put_fleet(&mut bag, &core.fleet_scene().unwrap_or_default(), &view, &frames, unix_stamp(origin, input.at))?;
            *next = input.at + settings.publish_every;
        }
        while let Some(out) = core.poll() {
            let Output::Command { record, .. } = out else { continue };
            let at = HostTime::from_nanos(record.rx_ns);
            let (ns, stamp) = unix_stamp(origin, at);
            let (scene, fleet) = (core.scene(at), core.fleet_scene().unwrap_or_default());
            bag.put("/odom", "nav_msgs/msg/Odometry", ns, &convert::odometry(&scene, stamp, &frames))?;
            bag.put("/tf", "tf2_msgs/msg/TFMessage", ns, &convert::transform(&scene, stamp, &frames))?;
            if first_in_slot(last_scene, at.as_nanos(), every) {
                let obstacles = convert::obstacles(&scene, &fleet, &view, stamp, &frames);
                bag.put(&format!("{fqn}/obstacles"), "visualization_msgs/msg/MarkerArray", ns, &obstacles)?;
                let path = convert::path(&scene, &fleet, &view, stamp, &frames);
                bag.put(&format!("{fqn}/path"), "nav_msgs/msg/Path", ns, &path)?;
                last_scene = Some(at.as_nanos());
            }
            if at >= next_stats {
                let stats = Snapshot {
                    state: core.state(),
                    counters: core.counters(),
                    uptime_s: at.secs(),
                    ..Snapshot::empty(start_s)
                };
                let diagnostics = convert::diagnostics(&stats, None, stamp, &fqn);
                bag.put("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", ns, &diagnostics)?;
                next_stats = at + std::time::Duration::from_secs(1);
            }
        }
    }
    // The state the recording ends in, at its last input.
    if let Some(last) = recording.inputs.last() {
        let (ns, stamp) = unix_stamp(origin, last.at);
        let stats = Snapshot {
            state: core.state(),
            counters: core.counters(),
            uptime_s: last.at.secs(),
            ..Snapshot::empty(start_s)
        };
        let diagnostics = convert::diagnostics(&stats, None, stamp, &fqn);
        bag.put("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", ns, &diagnostics)?;
    }
    finish(bag, dir, &file, name)
}

/// Each of a fleet's other vehicles the camera has shown: its `/<name>/odom` and its frame
/// on `/tf`.
fn put_fleet(
    bag: &mut BagWriter,
    fleet: &FleetScene,
    view: &ViewSetup,
    frames: &Frames,
    (ns, stamp): (u64, Time),
) -> Result<(), BagError> {
    for (label, v) in view.vehicles.iter().zip(fleet.vehicles()).filter(|(_, v)| v.seen) {
        let odom = convert::vehicle_odometry(label, v, stamp, frames);
        bag.put(&convert::vehicle_odometry_topic(&label.name), "nav_msgs/msg/Odometry", ns, &odom)?;
    }
    let transforms = convert::vehicle_transforms(fleet, &view.vehicles, stamp, frames);
    if !transforms.is_empty() {
        bag.put("/tf", "tf2_msgs/msg/TFMessage", ns, &TfMessage { transforms })?;
    }
    Ok(())
}

/// Close the MCAP file and write `metadata.yaml` beside it, as rosbag2 (Jazzy) does.
fn finish(mut bag: BagWriter, dir: &Path, file: &Path, name: &str) -> Result<BagSummary, BagError> {
    bag.mcap.finish()?;
    if bag.channels.is_empty() {
        return Err(BagError::Empty);
    }
    let counts: BTreeMap<String, u64> =
        bag.channels.iter().map(|(topic, (_, _, n))| (topic.clone(), u64::from(*n))).collect();
    let total: u64 = counts.values().sum();
    let (start, duration) = (bag.start_ns, bag.end_ns - bag.start_ns);
    let file_name = format!("{name}_0.mcap");
    let mut topics = String::new();
    for (topic, (_, kind, n)) in &bag.channels {
        let qos = bag.qos.replace('\n', "\\n").replace('"', "\\\"");
        topics.push_str(&format!(
            "    - topic_metadata:\n        name: {topic}\n        type: {kind}\n        serialization_format: cdr\n        offered_qos_profiles: \"{qos}\"\n        type_description_hash: \"\"\n      message_count: {n}\n"
        ));
    }
    let yaml = format!(
        "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  duration:\n    nanoseconds: {duration}\n  starting_time:\n    nanoseconds_since_epoch: {start}\n  message_count: {total}\n  topics_with_message_count:\n{topics}  compression_format: \"\"\n  compression_mode: \"\"\n  relative_file_paths:\n    - {file_name}\n  files:\n    - path: {file_name}\n      starting_time:\n        nanoseconds_since_epoch: {start}\n      duration:\n        nanoseconds: {duration}\n      message_count: {total}\n  custom_data: ~\n  ros_distro: jazzy\n"
    );
    let meta = dir.join("metadata.yaml");
    std::fs::write(&meta, yaml).map_err(|source| BagError::Io { path: meta.display().to_string(), source })?;
    Ok(BagSummary {
        dir: dir.to_path_buf(),
        file: file.to_path_buf(),
        messages: counts,
        start_ns: bag.start_ns,
        end_ns: bag.end_ns,
    })
}
