//! The gateway's scene and statistics as ROS 2 messages: pure functions of what the loop
//! published, so the live node and a bag export say the same.

use super::msgs::{
    ColorRgba, DiagnosticArray, DiagnosticStatus, Header, KeyValue, Marker, MarkerArray, Odometry, Path, Point, Pose,
    PoseStamped, PoseWithCovariance, Quaternion, TfMessage, Time, Transform, TransformStamped, Twist,
    TwistWithCovariance,
};
use crate::gateway::core::scene::{FleetScene, SceneRecord, SceneVehicle, VehicleLabel};
use crate::gateway::core::State;
use crate::gateway::shell::metrics;
use crate::gateway::shell::view::{self, ViewSetup};
use crate::planner::room::OutlineKind;
use crate::planner::streamlines;

/// The frames the messages are in.
#[derive(Debug, Clone, PartialEq)]
pub struct Frames {
    /// The calibrated floor, fixed in the room.
    pub floor: String,
    /// The robot's centre, x forward.
    pub base: String,
}

fn header(stamp: Time, frame: &str) -> Header {
    Header { stamp, frame_id: frame.to_owned() }
}

fn floor_pose([x, y, heading]: [f64; 3]) -> Pose {
    Pose { position: Point { x, y, z: 0.0 }, orientation: Quaternion::yaw(heading) }
}

/// A `[[vehicles]]` entry's own frame: its name before the robot's (`v1/base_link`).
pub fn vehicle_frame(name: &str, frames: &Frames) -> String {
    format!("{name}/{}", frames.base)
}

/// A vehicle's odometry topic: `/<name>/odom`.
pub fn vehicle_odometry_topic(name: &str) -> String {
    format!("/{name}/odom")
}

fn odometry_at(pose: [f64; 3], [v, w]: [f64; 2], stamp: Time, floor: &str, child: String) -> Odometry {
    let twist = Twist { linear: Point { x: v, y: 0.0, z: 0.0 }, angular: Point { x: 0.0, y: 0.0, z: w } };
    Odometry {
        header: header(stamp, floor),
        child_frame_id: child,
        pose: PoseWithCovariance { pose: floor_pose(pose), covariance: Default::default() },
        twist: TwistWithCovariance { twist, covariance: Default::default() },
    }
}

/// `/odom`: the tracker's pose in the floor frame, its twist in the robot's.
pub fn odometry(s: &SceneRecord, stamp: Time, frames: &Frames) -> Odometry {
    odometry_at(s.pose, s.twist, stamp, &frames.floor, frames.base.clone())
}

/// `/<name>/odom`: another vehicle's, its twist in its own frame ([`vehicle_frame`]).
pub fn vehicle_odometry(label: &VehicleLabel, v: &SceneVehicle, stamp: Time, frames: &Frames) -> Odometry {
    let (pose, twist) = (v.pose.map(f64::from), v.twist.map(f64::from));
    odometry_at(pose, twist, stamp, &frames.floor, vehicle_frame(&label.name, frames))
}

/// `/tf`: the floor frame to the robot's.
pub fn transform(s: &SceneRecord, stamp: Time, frames: &Frames) -> TfMessage {
    TfMessage { transforms: vec![floor_to(frames.base.clone(), s.pose, stamp, frames)] }
}

/// The floor frame to each of a fleet's other vehicles the camera has shown
/// ([`vehicle_frame`]): `/tf` carries them after the robot's.
pub fn vehicle_transforms(
    fleet: &FleetScene,
    vehicles: &[VehicleLabel],
    stamp: Time,
    frames: &Frames,
) -> Vec<TransformStamped> {
    let shown = vehicles.iter().zip(fleet.vehicles()).filter(|(_, v)| v.seen);
    shown.map(|(label, v)| floor_to(vehicle_frame(&label.name, frames), v.pose.map(f64::from), stamp, frames)).collect()
}

fn floor_to(child: String, pose: [f64; 3], stamp: Time, frames: &Frames) -> TransformStamped {
    let p = floor_pose(pose);
    TransformStamped {
        header: header(stamp, &frames.floor),
        child_frame_id: child,
        transform: Transform { translation: p.position, rotation: p.orientation },
    }
}

fn rgba(r: f32, g: f32, b: f32, a: f32) -> ColorRgba {
    ColorRgba { r, g, b, a }
}

fn cylinder(stamp: Time, frames: &Frames, ns: &str, id: i32, at: [f32; 2], radius: f32, color: ColorRgba) -> Marker {
    Marker {
        header: header(stamp, &frames.floor),
        ns: ns.into(),
        id,
        kind: Marker::CYLINDER,
        action: Marker::ADD,
        pose: Pose {
            position: Point { x: f64::from(at[0]), y: f64::from(at[1]), z: 0.05 },
            orientation: Quaternion::default(),
        },
        scale: Point { x: 2.0 * f64::from(radius), y: 2.0 * f64::from(radius), z: 0.1 },
        color,
        ..Marker::default()
    }
}

/// `~/obstacles`: a clearing marker, then each tracked obstacle (its body, its planning
/// circle, its velocity as an arrow over a second), each other vehicle of a fleet (its body,
/// its name over it, its goal) and the room's walls, static obstacles and view's edge as line
/// strips.
pub fn obstacles(s: &SceneRecord, fleet: &FleetScene, setup: &ViewSetup, stamp: Time, frames: &Frames) -> MarkerArray {
    let mut markers = vec![Marker { action: Marker::DELETEALL, ..Marker::default() }];
    for (k, o) in s.obstacles().iter().enumerate() {
        let id = k as i32;
        markers.push(cylinder(stamp, frames, "obstacle", id, o.position, o.radius, rgba(0.9, 0.3, 0.1, 0.9)));
        let planning = rgba(0.9, 0.6, 0.1, 0.25);
        markers.push(cylinder(stamp, frames, "planning_circle", id, o.position, o.planning_radius, planning));
        let from = Point { x: f64::from(o.position[0]), y: f64::from(o.position[1]), z: 0.1 };
        let to = Point { x: from.x + f64::from(o.velocity[0]), y: from.y + f64::from(o.velocity[1]), z: 0.1 };
        markers.push(Marker {
            header: header(stamp, &frames.floor),
            ns: "velocity".into(),
            id,
            kind: Marker::ARROW,
            action: Marker::ADD,
            scale: Point { x: 0.02, y: 0.04, z: 0.04 },
            color: rgba(0.9, 0.3, 0.1, 1.0),
            points: vec![from, to],
            ..Marker::default()
        });
    }
    markers.extend(vehicle_markers(fleet, setup, stamp, frames));
    if let Some(outline) = &setup.outline {
        for (k, (kind, points)) in outline.outlines().enumerate() {
            let (ns, color) = match kind {
                OutlineKind::Wall => ("wall", rgba(0.2, 0.2, 0.2, 1.0)),
                OutlineKind::StaticObstacle => ("static_obstacle", rgba(0.4, 0.3, 0.2, 1.0)),
                OutlineKind::View => ("view_edge", rgba(0.3, 0.5, 0.9, 0.6)),
            };
            let mut line: Vec<Point> = points.iter().map(|p| Point { x: p.re, y: p.im, z: 0.0 }).collect();
            if kind != OutlineKind::Wall {
                line.extend(line.first().copied());
            }
            markers.push(Marker {
                header: header(stamp, &frames.floor),
                ns: ns.into(),
                id: k as i32,
                kind: Marker::LINE_STRIP,
                action: Marker::ADD,
                scale: Point { x: 0.01, y: 0.0, z: 0.0 },
                color,
                points: line,
                ..Marker::default()
            });
        }
    }
    MarkerArray { markers }
}

/// Each other vehicle's markers: its body where seen (`vehicle`), its name over it
/// (`vehicle_name`), its goal (`vehicle_goal`), each with the vehicle's index as its id.
fn vehicle_markers(fleet: &FleetScene, setup: &ViewSetup, stamp: Time, frames: &Frames) -> Vec<Marker> {
    let mut markers = Vec::new();
    for (k, (label, v)) in setup.vehicles.iter().zip(fleet.vehicles()).enumerate() {
        let id = k as i32;
        let color = if label.scripted { rgba(0.6, 0.3, 0.8, 0.9) } else { rgba(0.1, 0.6, 0.6, 0.9) };
        markers.push(cylinder(stamp, frames, "vehicle_goal", id, v.goal, 0.02, color));
        if !v.seen {
            continue;
        }
        let at = [v.pose[0], v.pose[1]];
        markers.push(cylinder(stamp, frames, "vehicle", id, at, label.radius as f32, color));
        let position = Point { x: f64::from(at[0]), y: f64::from(at[1]), z: 0.2 };
        markers.push(Marker {
            header: header(stamp, &frames.floor),
            ns: "vehicle_name".into(),
            id,
            kind: Marker::TEXT_VIEW_FACING,
            action: Marker::ADD,
            pose: Pose { position, orientation: Quaternion::default() },
            scale: Point { x: 0.0, y: 0.0, z: 0.05 },
            color: rgba(0.1, 0.1, 0.1, 1.0),
            text: label.name.clone(),
            ..Marker::default()
        });
    }
    markers
}

/// How far ahead `~/path` follows the field, m.
const PATH_AHEAD: f64 = 4.0;
const PATH_STEP: f64 = 0.01;

/// `~/path`: the streamline of the planner's field from the robot toward the goal (empty
/// before a pose).
pub fn path(s: &SceneRecord, fleet: &FleetScene, setup: &ViewSetup, stamp: Time, frames: &Frames) -> Path {
    let mut out = Path { header: header(stamp, &frames.floor), poses: Vec::new() };
    if s.pose == [0.0; 3] && s.goal == [0.0; 2] {
        return out;
    }
    let Some(field) = view::field(s, fleet, setup) else { return out };
    let robot = crate::Point::new(s.pose[0], s.pose[1]);
    let reach = crate::Point::new(PATH_AHEAD, PATH_AHEAD);
    let steps = (PATH_AHEAD / PATH_STEP) as usize;
    let line = streamlines(&field, &[robot], PATH_STEP, steps, (robot - reach, robot + reach));
    let mut points: Vec<crate::Point> = line.into_iter().next().unwrap_or_default();
    points.push(crate::Point::new(s.goal[0], s.goal[1]));
    for (k, p) in points.iter().enumerate() {
        let next = points.get(k + 1).copied().unwrap_or(*p);
        let heading = if next == *p { s.pose[2] } else { (next - *p).im.atan2((next - *p).re) };
        out.poses.push(PoseStamped {
            header: header(stamp, &frames.floor),
            pose: Pose { position: Point { x: p.re, y: p.im, z: 0.0 }, orientation: Quaternion::yaw(heading) },
        });
    }
    out
}

/// Level of a state: running and its way there fine, a stop a warning, a fault an error.
fn level(state: State) -> u8 {
    match state {
        State::Fault(_) => DiagnosticStatus::ERROR,
        State::Stopped(_) | State::Stopping(_) => DiagnosticStatus::WARN,
        _ => DiagnosticStatus::OK,
    }
}

/// `/diagnostics`: the state and its reason, both links' counters, the cycle's latency, and
/// the last request ROS 2 made that was refused (with the control socket's words).
pub fn diagnostics(
    stats: &metrics::Snapshot,
    last_refusal: Option<&str>,
    stamp: Time,
    hardware_id: &str,
) -> DiagnosticArray {
    let kv = |key: &str, value: String| KeyValue { key: key.into(), value };
    let mut values = vec![kv("state", stats.state.to_string()), kv("uptime_s", format!("{:.1}", stats.uptime_s))];
    if let Ok(serde_json::Value::Object(counters)) = serde_json::to_value(stats.counters) {
        values.extend(counters.into_iter().map(|(k, v)| kv(&k, v.to_string())));
    }
    let h = &stats.e2e_ns;
    if !h.is_empty() {
        for (name, q) in [("latency_p50_us", 0.5), ("latency_p99_us", 0.99), ("latency_max_us", 1.0)] {
            values.push(kv(name, format!("{:.1}", h.value_at_quantile(q) as f64 / 1e3)));
        }
    }
    values.push(kv("deadline_misses", stats.deadline_misses.to_string()));
    let mut status = vec![DiagnosticStatus {
        level: level(stats.state),
        name: "flowgate: gateway".into(),
        message: stats.state.to_string(),
        hardware_id: hardware_id.into(),
        values,
    }];
    if let Some(text) = last_refusal {
        status.push(DiagnosticStatus {
            level: DiagnosticStatus::WARN,
            name: "flowgate: requests".into(),
            message: text.into(),
            hardware_id: hardware_id.into(),
            values: Vec::new(),
        });
    }
    DiagnosticArray { header: Header { stamp, frame_id: String::new() }, status }
}
