//! A scripted vehicle's run along its script: the script's clock from the cycle the vehicle
//! entered Running, the follower's command each cycle (through the vehicle's supervisor as
//! any outside planner's is), and its distance from the script, reported every cycle and
//! stopping the vehicle, named, beyond its tolerance.

use serde::{Deserialize, Serialize};

use crate::config::VehicleScript;
use crate::control::fleet::{follow, FollowerGains};
use crate::control::script::Script;
use crate::control::OutsideCommand;
use crate::Point;

/// What the follower makes of a cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Followed {
    /// Drive on this command; the vehicle is `error` m from its script.
    Command { command: OutsideCommand, error: f64 },
    /// Further from its script than its tolerance: stop it.
    Lost { error: f64, tolerance: f64 },
    /// The script came to rest at its last point: stop it there.
    Ended,
}

/// How far a scripted vehicle is from its script, as `status` reports it, m.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ScriptStatus {
    /// Its distance from its script at its last cycle in Running.
    pub error: f64,
    /// The largest where its supervisor passed the follower's command.
    pub largest: f64,
    /// The largest over the run, held or not.
    pub largest_held: f64,
    /// Seconds along its script (since it entered Running).
    pub along: f64,
}

#[derive(Debug)]
pub(super) struct ScriptRun {
    script: Script,
    tolerance: f64,
    gains: FollowerGains,
    /// When the vehicle entered Running: the script's clock starts there.
    since: Option<f64>,
    status: ScriptStatus,
}

impl ScriptRun {
    pub(super) fn new(s: &VehicleScript) -> Self {
        Self {
            script: s.script.clone(),
            tolerance: s.tolerance,
            gains: FollowerGains::default(),
            since: None,
            status: ScriptStatus::default(),
        }
    }

    /// The vehicle enters Running at `t`: the script starts from its beginning.
    pub(super) fn start(&mut self, t: f64) {
        self.since = Some(t);
        self.status = ScriptStatus::default();
    }

    /// How far `position` is from where the script starts, m.
    pub(super) fn distance_from_start(&self, position: Point) -> f64 {
        (self.script.start() - position).norm()
    }

    /// Where the script starts, m.
    pub(super) fn start_point(&self) -> [f64; 2] {
        let p = self.script.start();
        [p.re, p.im]
    }

    pub(super) fn tolerance(&self) -> f64 {
        self.tolerance
    }

    /// The cycle at `t` of a vehicle at `position` facing `facing` (a unit vector).
    pub(super) fn follow(&mut self, t: f64, position: Point, facing: Point) -> Followed {
        let along = t - self.since.unwrap_or(t);
        self.status.along = along;
        let reference = self.script.position(along);
        let error = (reference - position).norm();
        self.status.error = error;
        self.status.largest_held = self.status.largest_held.max(error);
        if error > self.tolerance {
            return Followed::Lost { error, tolerance: self.tolerance };
        }
        if self.script.end_time().is_some_and(|end| along >= end) {
            return Followed::Ended;
        }
        let (v, w) = follow(&self.gains, position, facing, reference, self.script.velocity(along));
        Followed::Command { command: OutsideCommand::Twist { v, w }, error }
    }

    /// The supervisor passed the follower's command this cycle, the vehicle `error` m off.
    pub(super) fn passed(&mut self, error: f64) {
        self.status.largest = self.status.largest.max(error);
    }

    pub(super) fn status(&self) -> ScriptStatus {
        self.status
    }
}
