//! Several vehicles in one world: each a [`World`] of its own (its wheels and ramps, the
//! scenario's obstacles, walls and room, judged exactly as the robot's), and every pair of
//! vehicles judged against each other.
//!
//! Between vehicles the judge samples: while a pair could meet within the step, the step is
//! cut so that neither vehicle moves more than [`PAIR_RESOLUTION`] between samples, and a
//! contact is dated to the first sample at which the footprints touch. Active or passive is
//! judged per vehicle, as for the robot: a vehicle moving toward the other faster than
//! [`ACTIVE_CONTACT_SPEED`] drove into it.

use super::{World, ACTIVE_CONTACT_SPEED};
use crate::scenario::SimScenario;
use crate::Point;

/// The most a vehicle moves between two samples of the pair judge, m.
pub const PAIR_RESOLUTION: f64 = 5e-4;

/// A vehicle's first contact with another vehicle.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VehicleContact {
    /// When, s.
    pub at: f64,
    /// The other vehicle's index (0: the robot).
    pub with: usize,
    /// This vehicle's velocity toward the other, m/s (negative: away).
    pub approach_speed: f64,
    /// This vehicle drove into the other.
    pub active: bool,
}

/// Every vehicle's world, and the judge between them.
#[derive(Debug, Clone)]
pub struct Fleet {
    worlds: Vec<World>,
    /// Each vehicle's top speed, m/s (its wheels' limit).
    top_speed: Vec<f64>,
    contact: Vec<Option<VehicleContact>>,
    /// Each vehicle's smallest gap to any other's footprint, m.
    min_gap: Vec<f64>,
}

impl Fleet {
    /// The fleet of a scenario at time 0, the robot first.
    pub fn new(s: &SimScenario) -> Self {
        let n = 1 + s.vehicles.len();
        let worlds: Vec<World> = (0..n).map(|k| World::new(&s.vehicle_alone(k))).collect();
        let top_speed = s.fleet().map(|(_, body, _)| body.max_wheel_speed).collect();
        let mut fleet = Self { worlds, top_speed, contact: vec![None; n], min_gap: vec![f64::INFINITY; n] };
        fleet.judge_pairs();
        fleet
    }

    pub fn len(&self) -> usize {
        self.worlds.len()
    }
    pub fn is_empty(&self) -> bool {
        self.worlds.is_empty()
    }
    pub fn time(&self) -> f64 {
        self.worlds[0].time()
    }
    /// Vehicle `k`'s world (0: the robot's).
    pub fn world(&self, k: usize) -> &World {
        &self.worlds[k]
    }
    pub fn world_mut(&mut self, k: usize) -> &mut World {
        &mut self.worlds[k]
    }
    /// Vehicle `k`'s first contact with another vehicle.
    pub fn vehicle_contact(&self, k: usize) -> Option<VehicleContact> {
        self.contact[k]
    }
    /// Vehicle `k`'s smallest gap to another vehicle so far, m.
    pub fn min_vehicle_gap(&self, k: usize) -> f64 {
        self.min_gap[k]
    }

    /// Advance every vehicle by `dt`, judging every pair on the way.
    pub fn step(&mut self, dt: f64) {
        if dt.is_nan() || dt <= 0.0 {
            return;
        }
        let pieces = self.pieces(dt);
        let h = dt / pieces as f64;
        for _ in 0..pieces {
            self.worlds.iter_mut().for_each(|w| w.step(h));
            self.judge_pairs();
        }
    }

    /// Into how many pieces to cut a step of `dt`: one while no pair can meet within it.
    fn pieces(&self, dt: f64) -> usize {
        let n = self.worlds.len();
        let fastest = self.top_speed.iter().copied().fold(0.0, f64::max);
        let mut near = false;
        for i in 0..n {
            for j in 0..i {
                let reach = (self.top_speed[i] + self.top_speed[j]) * dt;
                near |= self.gap(i, j) <= reach + PAIR_RESOLUTION;
            }
        }
        if near {
            ((fastest * dt / PAIR_RESOLUTION).ceil() as usize).clamp(1, 10_000)
        } else {
            1
        }
    }

    fn radius(&self, k: usize) -> f64 {
        self.worlds[k].robot_radius()
    }

    fn gap(&self, i: usize, j: usize) -> f64 {
        (self.worlds[i].pose().position - self.worlds[j].pose().position).norm() - self.radius(i) - self.radius(j)
    }

    /// Vehicle `k`'s velocity now, m/s.
    pub fn velocity(&self, k: usize) -> Point {
        let w = &self.worlds[k];
        let [l, r] = w.wheel_speeds();
        w.facing() * (0.5 * (l + r))
    }

    fn judge_pairs(&mut self) {
        let n = self.worlds.len();
        let t = self.time();
        for i in 0..n {
            for j in 0..i {
                let gap = self.gap(i, j);
                self.min_gap[i] = self.min_gap[i].min(gap);
                self.min_gap[j] = self.min_gap[j].min(gap);
                if gap > 0.0 {
                    continue;
                }
                let toward = self.worlds[j].pose().position - self.worlds[i].pose().position;
                let unit = if toward.norm() > 0.0 { toward / toward.norm() } else { Point::new(1.0, 0.0) };
                for (a, b, u) in [(i, j, unit), (j, i, -unit)] {
                    if self.contact[a].is_none() {
                        let v = self.velocity(a);
                        let approach_speed = v.re * u.re + v.im * u.im;
                        let active = approach_speed > ACTIVE_CONTACT_SPEED;
                        self.contact[a] = Some(VehicleContact { at: t, with: b, approach_speed, active });
                    }
                }
            }
        }
    }
}
