//! `[[vehicles]]`: the rig's other vehicles, under the same camera and on the same CAN bus
//! as the robot (the first vehicle, `[leds]`, `[can]`, `[drive]` and `[robot]`).
//!
//! Each vehicle has its LED pair, its motors (a board, or a CiA 402 drive a wheel) and its
//! body and limits, by default the robot's. What is checked here is what the hardware
//! allows: every LED on the PSD controller's bus once, one schedule for all of them, and no
//! CAN identifier used by two devices (node numbers apart is not enough: the boards' and the
//! drives' tables overlap, and the gateway's broadcasts to one kind are frames the other
//! kind acts on).

use std::time::Duration;

use flowgate_protocol::can::IdUse;
use flowgate_protocol::psd::{Schedule, MAX_SCHEDULE_LEDS};
use flowgate_protocol::{canopen, motor};
use serde::{Deserialize, Serialize};

use super::checks::{invalid, non_negative, positive, Invalid, BODY};
use super::motors::{DriveSection, MotorProtocolName};
use super::planning::RobotSection;
use super::RigFile;
use crate::planner::MAX_OBSTACLES;
use crate::track::LedGeometry;

mod script;
pub use script::{MotionSection, RoleName, VehicleScript};

/// One `[[vehicles]]` entry as written. Every key after the motors' defaults to the robot's
/// (`[leds]`, `[robot]`, `[drive]`).
#[derive(Debug, Clone, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleSection {
    /// Lower-case letters, digits and `_`: a ROS name and a file name; `robot` is the first
    /// vehicle's.
    pub name: String,
    /// The LED ids on the controller's driver bus.
    pub front_led: u8,
    pub rear_led: u8,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub front_offset: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rear_offset: Option<f64>,
    /// What its motors speak (default: `can.protocol`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub protocol: Option<MotorProtocolName>,
    /// Its board's node id, 1-15 (a board).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub node: Option<u8>,
    /// Its wheels' drives' node ids, 1-127 (CiA 402 drives, set up as `[cia402]` says).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub left_node: Option<u8>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub right_node: Option<u8>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_speed: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wheel_radius: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steps_per_rev: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub microsteps: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wheel_base: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_wheel_speed: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wheel_accel: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_timeout_ms: Option<u16>,
    /// Where it drives when armed at start (`flowgate run --arm`), as `[goal]` is the
    /// robot's, m; and how close counts as there (default 0.02 m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub goal: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub goal_tolerance: Option<f64>,
    /// `"navigate"` (the default) or `"script"`: a scripted vehicle follows its `motion`
    /// from its `start` once started, further than `script_tolerance` (default 0.05 m)
    /// from it stopped, named.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub role: Option<RoleName>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion: Option<MotionSection>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub script_tolerance: Option<f64>,
}

/// A vehicle's motors on the rig's bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VehicleMotors {
    Board(motor::NodeId),
    Drives { left: canopen::NodeId, right: canopen::NodeId },
}

/// A vehicle as the rig has it: checked and typed.
#[derive(Debug, Clone)]
pub struct Vehicle {
    pub name: String,
    pub front_led: u8,
    pub rear_led: u8,
    pub led_geometry: LedGeometry,
    pub motors: VehicleMotors,
    pub robot: RobotSection,
    pub drive: DriveSection,
    /// How the gateway drives it: what the robot's would be with this vehicle's body,
    /// wheels, limits, LEDs and motors.
    pub driven: DrivenSettings,
    /// Its goal when armed at start (`goal`, `goal_tolerance`).
    pub goal: Option<super::Goal>,
    /// A scripted vehicle's script (`role = "script"`).
    pub script: Option<VehicleScript>,
}

/// What the gateway drives a vehicle with, typed as the robot's are in [`Rig`](super::Rig).
#[derive(Debug, Clone)]
pub struct DrivenSettings {
    pub control: crate::control::ControlConfig,
    pub tracking: crate::track::TrackingSettings,
    pub motors: super::Motors,
    /// Its board's node (a board), as [`Rig::node`](super::Rig::node) is the robot's.
    pub node: motor::NodeId,
    pub board: super::BoardSettings,
}

/// The room every vehicle plans in, as the robot's control is built in it.
pub(super) struct Room<'a> {
    /// The rig's file as the robot's control is built from it (two walls that make a lane
    /// read as the lane).
    pub(super) file: &'a RigFile,
    pub(super) calibration: &'a crate::calibration::Calibration,
    pub(super) room: Option<std::sync::Arc<crate::planner::room::Room>>,
}

impl Room<'_> {
    /// Why a vehicle could not stand at `at`, to follow the point as written: outside the calibrated arena, outside the
    /// lane, in a wall or the furniture.
    pub(super) fn blocked(&self, at: crate::Point) -> Option<String> {
        let c = self.calibration;
        if !c.in_view(at) {
            return Some(format!(" lies outside the calibrated arena: {}", c.view_extent()));
        }
        if let Some(lane) = self.file.lane.filter(|l| at.im.abs() >= l.half_width) {
            return Some(format!(" lies outside the lane (|y| >= {} m)", lane.half_width));
        }
        self.room.as_ref().and_then(|r| r.blocked_at(at)).map(|why| format!(": {why}"))
    }
}

/// A key of `vehicles[i]`.
fn key(i: usize, leaf: &str) -> String {
    format!("vehicles[{i}].{leaf}")
}

/// The longest vehicle name (a scenario's vehicles have the same rule).
const MAX_NAME_LEN: usize = 32;

/// Whether `name` names a vehicle: a ROS name's token (`[ros2]`'s rule), in lower case and
/// starting with a letter, so that it is a file name too.
fn vehicle_name(name: &str) -> bool {
    name.len() <= MAX_NAME_LEN
        && super::ros2::name_token(name)
        && name.starts_with(|c: char| c.is_ascii_lowercase())
        && !name.chars().any(|c| c.is_ascii_uppercase())
}

impl VehicleSection {
    fn check_name(&self, i: usize) -> Result<(), Invalid> {
        if !vehicle_name(&self.name) {
            return invalid(
                &key(i, "name"),
                format!("{:?} is not a name: 1-32 lower-case letters, digits and `_`, a letter first", self.name),
            );
        }
        if self.name == "robot" {
            return invalid(&key(i, "name"), "\"robot\" is the first vehicle's ([leds], [can], [robot])");
        }
        Ok(())
    }

    /// The vehicle's body, limits and motors; its name and LEDs are checked already.
    fn validate(&self, i: usize, rig: &RigFile, sample_period: Duration, room: &Room<'_>) -> Result<Vehicle, Invalid> {
        let led_geometry = LedGeometry {
            front: self.front_offset.unwrap_or(rig.leds.front_offset),
            rear: self.rear_offset.unwrap_or(rig.leds.rear_offset),
        };
        non_negative(&key(i, "front_offset"), led_geometry.front, BODY)?;
        non_negative(&key(i, "rear_offset"), led_geometry.rear, BODY)?;
        positive(&key(i, "front_offset"), led_geometry.front + led_geometry.rear, BODY)?;
        let d = &rig.drive;
        let drive = DriveSection {
            wheel_radius: self.wheel_radius.unwrap_or(d.wheel_radius),
            steps_per_rev: self.steps_per_rev.unwrap_or(d.steps_per_rev),
            microsteps: self.microsteps.unwrap_or(d.microsteps),
            wheel_base: self.wheel_base.unwrap_or(d.wheel_base),
            max_wheel_speed: self.max_wheel_speed.unwrap_or(d.max_wheel_speed),
            wheel_accel: self.wheel_accel.unwrap_or(d.wheel_accel),
            command_timeout_ms: self.command_timeout_ms.unwrap_or(d.command_timeout_ms),
        };
        let robot = RobotSection {
            radius: self.radius.unwrap_or(rig.robot.radius),
            max_speed: self.max_speed.unwrap_or(rig.robot.max_speed),
        };
        // The robot's rules, named as this vehicle's keys.
        let renamed = |e: Invalid| {
            let leaf = e.key.rsplit('.').next().unwrap_or(&e.key).to_string();
            Invalid { key: key(i, &leaf), why: e.why }
        };
        drive.validate(sample_period).map_err(renamed)?;
        robot.validate(&drive).map_err(renamed)?;
        // The gateway's watchdogs must fire before this vehicle's board stops by itself.
        rig.safety.validate(sample_period, drive.command_timeout_ms).map_err(|e| Invalid {
            key: key(i, "command_timeout_ms"),
            why: format!("is {} ms: `{}` {}", drive.command_timeout_ms, e.key, e.why),
        })?;
        let pulses_per_metre =
            f64::from(drive.steps_per_rev) * f64::from(drive.microsteps) / (std::f64::consts::TAU * drive.wheel_radius);
        let board = drive.board_settings(pulses_per_metre).map_err(renamed)?;
        let motors = self.motors(i, rig)?;
        let as_robot = self.as_robot(room.file, motors, robot, drive);
        let typed_motors = match (motors, &as_robot.cia402) {
            (VehicleMotors::Drives { .. }, Some(c)) => {
                super::Motors::Cia402(c.settings(&rig.safety, &drive, pulses_per_metre).map_err(renamed)?)
            }
            _ => super::Motors::Pcl80k,
        };
        let node = match motors {
            VehicleMotors::Board(n) => n,
            VehicleMotors::Drives { .. } => motor::NodeId::new(1).expect("1 is a node id"),
        };
        let wheels = crate::control::script::Wheels {
            max_speed: robot.max_speed,
            max_wheel_speed: drive.max_wheel_speed,
            wheel_accel: drive.wheel_accel,
            wheel_base: drive.wheel_base,
        };
        let script = self.script(i, &wheels, led_geometry, room)?;
        let mut control = as_robot.control_config(sample_period, room.calibration, room.room.clone());
        if let Some(s) = &script {
            // The follower's command, a cycle old at most, is what its supervisor checks;
            // the script, not a goal, says when it is done.
            control.source = crate::control::CommandSource::Outside { max_age: 2.0 * sample_period.as_secs_f64() };
            control.goal = s.script.last_point();
            control.goal_tolerance = 0.0;
        }
        let driven =
            DrivenSettings { control, tracking: as_robot.tracking_settings(), motors: typed_motors, node, board };
        Ok(Vehicle {
            name: self.name.clone(),
            front_led: self.front_led,
            rear_led: self.rear_led,
            led_geometry,
            motors,
            robot,
            drive,
            driven,
            goal: self.goal(i, room)?,
            script,
        })
    }

    /// Its goal: finite, where the camera sees it, inside the lane, clear of the walls and
    /// the furniture.
    fn goal(&self, i: usize, room: &Room<'_>) -> Result<Option<super::Goal>, Invalid> {
        if self.goal_tolerance.is_some() && self.goal.is_none() {
            return invalid(&key(i, "goal_tolerance"), "is set, but `goal` is not");
        }
        let Some(position) = self.goal else { return Ok(None) };
        let tolerance = self.goal_tolerance.unwrap_or(super::planning::default_tolerance());
        let at = crate::Point::new(position[0], position[1]);
        if !(at.re.is_finite() && at.im.is_finite()) {
            return invalid(&key(i, "goal"), "must be finite");
        }
        positive(&key(i, "goal_tolerance"), tolerance, super::checks::Most(super::MAX_GOAL_TOLERANCE, "m"))?;
        if let Some(why) = room.blocked(at) {
            return invalid(&key(i, "goal"), format!("{position:?}{why}"));
        }
        Ok(Some(super::Goal { position, tolerance }))
    }

    /// The rig's file with this vehicle in the robot's place: its LEDs, motors, body and
    /// wheels, and no goal or other vehicles.
    fn as_robot(&self, rig: &RigFile, motors: VehicleMotors, robot: RobotSection, drive: DriveSection) -> RigFile {
        let mut file = RigFile { vehicles: Vec::new(), goal: None, robot, drive, ..rig.clone() };
        file.leds.robot_front = self.front_led;
        file.leds.robot_rear = self.rear_led;
        file.leds.front_offset = self.front_offset.unwrap_or(rig.leds.front_offset);
        file.leds.rear_offset = self.rear_offset.unwrap_or(rig.leds.rear_offset);
        match motors {
            VehicleMotors::Board(n) => {
                file.can.protocol = MotorProtocolName::Pcl80k;
                file.can.node = n.get();
            }
            VehicleMotors::Drives { left, right } => {
                file.can.protocol = MotorProtocolName::Cia402;
                if let Some(c) = file.cia402.as_mut() {
                    (c.left_node, c.right_node) = (left.get(), right.get());
                }
            }
        }
        file
    }

    fn motors(&self, i: usize, rig: &RigFile) -> Result<VehicleMotors, Invalid> {
        match (self.protocol.unwrap_or(rig.can.protocol), self.node, self.left_node, self.right_node) {
            (MotorProtocolName::Pcl80k, Some(n), None, None) => motor::NodeId::new(n)
                .map(VehicleMotors::Board)
                .map_or_else(|| invalid(&key(i, "node"), format!("must be 1-15, is {n}")), Ok),
            (MotorProtocolName::Pcl80k, _, _, _) => {
                invalid(&key(i, "node"), "a board's vehicle takes `node` (1-15), not `left_node`/`right_node`")
            }
            (MotorProtocolName::Cia402, None, Some(l), Some(r)) => {
                if rig.cia402.is_none() {
                    return invalid(
                        &key(i, "protocol"),
                        "is \"cia402\": its drives are set up as [cia402] says, and the section is missing",
                    );
                }
                let node = |leaf: &str, v: u8| {
                    canopen::NodeId::new(v).map_or_else(|| invalid(&key(i, leaf), format!("must be 1-127, is {v}")), Ok)
                };
                let (left, right) = (node("left_node", l)?, node("right_node", r)?);
                if left == right {
                    return invalid(&key(i, "right_node"), format!("is {r}, the left wheel's drive's too"));
                }
                Ok(VehicleMotors::Drives { left, right })
            }
            (MotorProtocolName::Cia402, _, _, _) => {
                invalid(&key(i, "left_node"), "CiA 402 drives take `left_node` and `right_node` (1-127), not `node`")
            }
        }
    }
}

/// No two of `places` (each its key, where, and its vehicle's radius) closer than their
/// radii.
fn places_apart(places: &[(String, [f64; 2], f64)]) -> Result<(), Invalid> {
    for (k, (name, at, radius)) in places.iter().enumerate() {
        for (other, there, r) in &places[..k] {
            let apart = (at[0] - there[0]).hypot(at[1] - there[1]);
            if apart < radius + r {
                return invalid(
                    name,
                    format!(
                        "{at:?} is {apart:.3} m from {other} {there:?}: two vehicles {:.3} m across could not both stand there",
                        radius + r
                    ),
                );
            }
        }
    }
    Ok(())
}

impl RigFile {
    /// The schedule of every LED: the robot's and the obstacles' (`leds`, as
    /// [`LedSection`](super::LedSection) gave them), then each vehicle's pair, each LED once;
    /// the vehicles' names.
    pub(super) fn schedule_with_vehicles(&self, mut leds: Vec<u8>) -> Result<Schedule, Invalid> {
        for (i, v) in self.vehicles.iter().enumerate() {
            v.check_name(i)?;
            if let Some(other) = self.vehicles[..i].iter().position(|o| o.name == v.name) {
                return invalid(&key(i, "name"), format!("{:?} is vehicles[{other}]'s name too", v.name));
            }
            if v.front_led == v.rear_led {
                return invalid(&key(i, "rear_led"), format!("is {}, the vehicle's front LED too", v.rear_led));
            }
            for (leaf, led) in [("front_led", v.front_led), ("rear_led", v.rear_led)] {
                if let Some(owner) = self.led_owner(led, i) {
                    return invalid(&key(i, leaf), format!("LED {led} is {owner}"));
                }
            }
        }
        let n = leds.len() + 2 * self.vehicles.len();
        if !self.vehicles.is_empty() && n > MAX_SCHEDULE_LEDS {
            return invalid(
                "vehicles",
                format!(
                    "{n} LEDs (the robot's 2, {} obstacles', 2 for each of {} vehicles): the schedule holds at most {MAX_SCHEDULE_LEDS}",
                    leds.len() - 2,
                    self.vehicles.len()
                ),
            );
        }
        // Each vehicle's field takes every other vehicle and every obstacle as a circle.
        let others = self.vehicles.len() + self.leds.obstacles.len();
        if others > MAX_OBSTACLES {
            return invalid(
                "vehicles",
                format!(
                    "{} vehicles and {} obstacles: each vehicle's field would take {others} circles, at most {MAX_OBSTACLES}",
                    self.vehicles.len() + 1,
                    self.leds.obstacles.len()
                ),
            );
        }
        leds.extend(self.vehicles.iter().flat_map(|v| [v.front_led, v.rear_led]));
        self.schedule.build(&leds)
    }

    /// Each vehicle's body, limits and motors, once the robot's have passed (`sample_period`:
    /// the schedule's, every vehicle's LEDs in it), and every CAN identifier apart.
    pub(super) fn validate_vehicles(&self, sample_period: Duration, room: &Room<'_>) -> Result<Vec<Vehicle>, Invalid> {
        // Every device on the bus first: a drive typed as the robot's would be refused on a
        // node another device takes, named less well than the bus's own check names it.
        let motors = self.vehicles.iter().enumerate().map(|(i, v)| v.motors(i, self)).collect::<Result<Vec<_>, _>>()?;
        self.check_can_ids(&motors)?;
        let vehicles: Vec<Vehicle> = self
            .vehicles
            .iter()
            .enumerate()
            .map(|(i, v)| v.validate(i, self, sample_period, room))
            .collect::<Result<_, _>>()?;
        self.check_goals_apart(&vehicles)?;
        Ok(vehicles)
    }

    /// No two vehicles' goals (the robot's `[goal]` among them), and no two scripts'
    /// starts, closer than their radii: both could never stand there.
    fn check_goals_apart(&self, vehicles: &[Vehicle]) -> Result<(), Invalid> {
        let robot = self.goal.map(|g| ("goal.position".to_string(), g.position, self.robot.radius));
        let goals =
            vehicles.iter().enumerate().filter_map(|(i, v)| Some((key(i, "goal"), v.goal?.position, v.robot.radius)));
        let starts = vehicles.iter().enumerate().filter_map(|(i, v)| {
            let start = v.script.as_ref()?.script.start();
            Some((key(i, "start"), [start.re, start.im], v.robot.radius))
        });
        places_apart(&robot.into_iter().chain(goals).collect::<Vec<_>>())?;
        places_apart(&starts.collect::<Vec<_>>())
    }

    /// Who uses `led` besides vehicle `i`: the robot, an obstacle or a vehicle before it.
    fn led_owner(&self, led: u8, i: usize) -> Option<String> {
        let l = &self.leds;
        if led == l.robot_front || led == l.robot_rear {
            let leaf = if led == l.robot_front { "robot_front" } else { "robot_rear" };
            return Some(format!("the robot's (leds.{leaf})"));
        }
        if let Some(k) = l.obstacles.iter().position(|o| o.led == led) {
            return Some(format!("an obstacle's (leds.obstacles[{k}].led)"));
        }
        self.vehicles[..i]
            .iter()
            .enumerate()
            .find(|(_, v)| v.front_led == led || v.rear_led == led)
            .map(|(k, v)| format!("vehicles[{k}] ({})'s", v.name))
    }

    /// Every CAN identifier on the bus, each with the key of the device (or the gateway's
    /// broadcasts) that uses it: none may be used twice.
    fn check_can_ids(&self, motors: &[VehicleMotors]) -> Result<(), Invalid> {
        let mut devices = vec![("the robot".to_string(), self.robot_motors()?)];
        let names = self.vehicles.iter().enumerate().map(|(i, v)| format!("vehicles[{i}] ({})", v.name));
        devices.extend(names.zip(motors.iter().copied()));
        let mut uses: Vec<(String, IdUse)> = Vec::new();
        for (owner, motors) in &devices {
            match *motors {
                VehicleMotors::Board(n) => uses.extend(motor::board_ids(n).map(|u| (owner.clone(), u))),
                VehicleMotors::Drives { left, right } => {
                    uses.extend(canopen::drive_ids(left).map(|u| (format!("{owner}, left"), u)));
                    uses.extend(canopen::drive_ids(right).map(|u| (format!("{owner}, right"), u)));
                }
            }
        }
        if devices.iter().any(|(_, m)| matches!(m, VehicleMotors::Board(_))) {
            uses.extend(motor::GATEWAY_IDS.map(|u| ("the gateway, to the boards".to_string(), u)));
        }
        if devices.iter().any(|(_, m)| matches!(m, VehicleMotors::Drives { .. })) {
            let gateway = self.cia402.map_or(super::motors::default_gateway_node(), |c| c.gateway_node);
            if let Some(node) = canopen::NodeId::new(gateway) {
                uses.extend(canopen::gateway_ids(node).map(|u| ("the gateway, to the drives".to_string(), u)));
            }
        }
        for (k, (owner, u)) in uses.iter().enumerate() {
            if let Some((first, f)) = uses[..k].iter().find(|(o, f)| f.id == u.id && o != owner) {
                return invalid(
                    "vehicles",
                    format!(
                        "CAN id 0x{:03X} is {} ({first}) and {} ({owner}): on one bus each would take the other's frames",
                        u.id, f.what, u.what
                    ),
                );
            }
        }
        Ok(())
    }

    /// The robot's motors, as `[can]` and `[cia402]` give them (checked by their sections).
    fn robot_motors(&self) -> Result<VehicleMotors, Invalid> {
        let node = |key: &str, v: u8| {
            canopen::NodeId::new(v).map_or_else(|| invalid(key, format!("must be 1-127, is {v}")), Ok)
        };
        match (self.can.protocol, &self.cia402) {
            (MotorProtocolName::Cia402, Some(c)) => Ok(VehicleMotors::Drives {
                left: node("cia402.left_node", c.left_node)?,
                right: node("cia402.right_node", c.right_node)?,
            }),
            _ => motor::NodeId::new(self.can.node)
                .map(VehicleMotors::Board)
                .map_or_else(|| invalid("can.node", format!("must be 1-15, is {}", self.can.node)), Ok),
        }
    }
}

#[cfg(test)]
mod tests;
