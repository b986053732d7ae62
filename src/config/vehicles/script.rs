//! A `[[vehicles]]` entry's role: a navigating vehicle (its `goal`, or the operator's), or
//! a scripted one (`role = "script"`, its `start` and `motion` written as a scenario's
//! obstacle's are), checked against the vehicle's wheels and cut where it would leave the
//! room's free region.

use serde::{Deserialize, Serialize};

use super::super::checks::{invalid, Invalid};
use super::{key, Room, VehicleSection};
use crate::control::script::{Script, Wheels, DEFAULT_TOLERANCE, PRECISION};
use crate::track::LedGeometry;
use crate::Point;

/// What a vehicle does (`role`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RoleName {
    /// Driven to its goals by its own field (the default).
    #[default]
    Navigate,
    /// Follows its `motion` from its `start` once started, guarded by its supervisor.
    Script,
}

/// A script's motion, as a scenario's obstacle's is written.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MotionSection {
    Stationary,
    /// Constant velocity, m/s, from `start` until it would leave the room's free region.
    Constant {
        velocity: [f64; 2],
    },
    /// From `start` through each point at `speed` (m/s), then standing (or round again
    /// from `start` when `repeat`).
    Waypoints {
        points: Vec<[f64; 2]>,
        speed: f64,
        #[serde(default)]
        repeat: bool,
    },
}

/// A scripted vehicle's script as the gateway follows it.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleScript {
    pub script: Script,
    /// Further than this from its script, m, the vehicle is stopped, named.
    pub tolerance: f64,
    /// Where the script was cut, said at load: it would have left the room's free region.
    pub cut: Option<String>,
}

/// How far a constant motion is laid out before it is cut at the free region's edge, m:
/// beyond any camera's view.
const CONSTANT_REACH: f64 = 100.0;

fn at(p: [f64; 2]) -> Point {
    Point::new(p[0], p[1])
}

impl VehicleSection {
    /// Its script, for a scripted vehicle; the keys that belong to the other role refused.
    /// `leds`: where its LEDs sit on its body (without a room, a script is cut where the
    /// camera would lose either).
    pub(super) fn script(
        &self,
        i: usize,
        wheels: &Wheels,
        leds: LedGeometry,
        room: &Room<'_>,
    ) -> Result<Option<VehicleScript>, Invalid> {
        let role = self.role.unwrap_or_default();
        if role == RoleName::Navigate {
            for (leaf, set) in [
                ("start", self.start.is_some()),
                ("motion", self.motion.is_some()),
                ("script_tolerance", self.script_tolerance.is_some()),
            ] {
                if set {
                    return invalid(
                        &key(i, leaf),
                        "is a scripted vehicle's (role = \"script\"); a navigating vehicle starts where it stands",
                    );
                }
            }
            return Ok(None);
        }
        if self.goal.is_some() || self.goal_tolerance.is_some() {
            return invalid(&key(i, "goal"), "is a navigating vehicle's; a scripted vehicle follows its `motion`");
        }
        let (Some(start), Some(motion)) = (self.start, self.motion.as_ref()) else {
            let leaf = if self.start.is_none() { "start" } else { "motion" };
            return invalid(&key(i, leaf), "is missing: a scripted vehicle needs its `start` and its `motion`");
        };
        finite(&key(i, "start"), &[start])?;
        if let Some(why) = room.blocked(at(start)) {
            return invalid(&key(i, "start"), format!("{start:?}{why}"));
        }
        let tolerance = self.script_tolerance.unwrap_or(DEFAULT_TOLERANCE);
        if !(PRECISION..=super::super::checks::BODY.0).contains(&tolerance) {
            return invalid(
                &key(i, "script_tolerance"),
                format!("must be {PRECISION} to {} m, is {tolerance}", super::super::checks::BODY.0),
            );
        }
        let script = laid_out(i, at(start), motion)?;
        script.followable(wheels).or_else(|why| invalid(&key(i, "motion"), why.to_string()))?;
        let seen = |p: Point, way: Point| {
            let along = if way.norm() > 0.0 { way / way.norm() } else { Point::new(1.0, 0.0) };
            let (front, rear) = leds.leds(p, along);
            room.room.is_some() || (room.calibration.in_view(front) && room.calibration.in_view(rear))
        };
        let Some((cut, end, t)) = script.cut(|p, way| room.blocked(p).is_none() && seen(p, way)) else {
            return Ok(Some(VehicleScript { script, tolerance, cut: None }));
        };
        let cut_note = format!(
            "vehicles[{i}] ({}): its script leaves the room's free region at ({:.3}, {:.3}) after {t:.2} s: the \
             vehicle stops there",
            self.name, end.re, end.im
        );
        Ok(Some(VehicleScript { script: cut, tolerance, cut: Some(cut_note) }))
    }
}

/// The motion from `start` as a script.
fn laid_out(i: usize, start: Point, motion: &MotionSection) -> Result<Script, Invalid> {
    let k = key(i, "motion");
    match motion {
        MotionSection::Stationary => Ok(Script::standing(start)),
        MotionSection::Constant { velocity } => {
            finite(&k, &[*velocity])?;
            let v = at(*velocity);
            if v.norm() == 0.0 {
                return Ok(Script::standing(start));
            }
            Ok(Script::through(start, &[start + v / v.norm() * CONSTANT_REACH], v.norm(), false))
        }
        MotionSection::Waypoints { points, speed, repeat } => {
            finite(&k, points)?;
            if points.is_empty() {
                return invalid(&format!("{k}.points"), "is empty: at least one point");
            }
            if !(speed.is_finite() && *speed > 0.0) {
                return invalid(&format!("{k}.speed"), format!("must be above 0 m/s, is {speed}"));
            }
            let points: Vec<Point> = points.iter().map(|p| at(*p)).collect();
            Ok(Script::through(start, &points, *speed, *repeat))
        }
    }
}

fn finite(key: &str, points: &[[f64; 2]]) -> Result<(), Invalid> {
    match points.iter().find(|p| !(p[0].is_finite() && p[1].is_finite())) {
        Some(p) => invalid(key, format!("{p:?} must be finite")),
        None => Ok(()),
    }
}
