//! An outside policy driving one vehicle of a fleet (`flowgate plan --policy CMD --vehicle
//! NAME`), at the planner level as fleets run: the same JSON lines as through the whole
//! stack (docs/policies.md), the vehicle observing its own pose and every other vehicle and
//! obstacle as they truly move. Its commands go through its own supervisor, as a scripted
//! vehicle's do, and the other vehicles plan round it on what it was commanded. A policy
//! that fails stops its vehicle, named (`policy: ...`); the others go on.

use flowgate_sim::world::fleet::Fleet;

use super::{drive_with, FleetControl, FleetOptions, FleetSummary, FleetTrace};
use crate::lab::policy::{self, Ending, Observation, ObstacleObservation, PolicyError, RobotObservation, Worker};
use crate::lab::Scenario;

/// Run `s` with vehicle `k` driven by the policy `worker` runs (its trace kept if asked),
/// and how the policy failed, if it did.
pub fn run(
    s: &Scenario,
    options: FleetOptions,
    k: usize,
    worker: &mut Worker,
    trace: Option<&mut FleetTrace>,
) -> (FleetSummary, Option<PolicyError>) {
    let alone = s.vehicle(k);
    let gateway = alone.rig();
    let wheel_base = gateway.control.drive.wheel_base;
    let mut failure = worker.open(&policy::hello(&alone, &gateway)).err();
    let control = FleetControl::driven(s, options, Some(k));
    let summary = drive_with(s, control, trace, |fleet, control| {
        let t = fleet.time();
        if control.is_done(k) {
            return;
        }
        if let Some(e) = &failure {
            control.stop(k, t, e.to_string());
            return;
        }
        match worker.ask(&observe(fleet, control, k, wheel_base)) {
            Ok(command) => control.command(k, t, command),
            Err(e) => {
                control.stop(k, t, e.to_string());
                failure = Some(e);
            }
        }
    });
    let v = &summary.vehicles[k];
    let ending = Ending { outcome: v.outcome.to_string(), contact: v.contact.is_some(), stop: v.stop_reason.clone() };
    worker.finish(&ending, failure.is_some());
    (summary, failure)
}

/// What vehicle `k` observes now: its own pose and speeds, its goal, and every obstacle and
/// every other vehicle where it is and as it moves.
fn observe(fleet: &Fleet, control: &FleetControl, k: usize, wheel_base: f64) -> Observation {
    let t = fleet.time();
    let world = fleet.world(k);
    let pose = world.pose();
    let [left, right] = world.wheel_speeds();
    let body = |position: flowgate_sim::Point, velocity: flowgate_sim::Point, radius: f64| ObstacleObservation {
        x: position.re,
        y: position.im,
        vx: velocity.re,
        vy: velocity.im,
        radius,
    };
    let obstacles = (0..world.obstacle_count())
        .map(|o| body(world.obstacle_position(o, t), world.obstacle_velocity(o, t), world.obstacle_radius(o)));
    let vehicles = (0..fleet.len())
        .filter(|&j| j != k)
        .map(|j| body(fleet.world(j).pose().position, fleet.velocity(j), fleet.world(j).robot_radius()));
    let goal = control.goal(k);
    Observation {
        t,
        robot: RobotObservation {
            x: pose.position.re,
            y: pose.position.im,
            heading: pose.heading,
            v: 0.5 * (left + right),
            w: (right - left) / wheel_base,
        },
        goal: [goal.re, goal.im],
        obstacles: obstacles.chain(vehicles).collect(),
    }
}
