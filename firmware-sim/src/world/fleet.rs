//! Several vehicles in one world: each a [`World`] of its own (its wheels and ramps, the
//! scenario's obstacles, walls and room, judged exactly as the robot's), and every pair of
//! vehicles judged against each other. People who walk as the world runs (those who see
//! the vehicles, `sees_robot`, or everyone under `people_walk = "as_needed"`) walk once for
//! the fleet, beside every vehicle, and each world is handed their ways.
//!
//! Between vehicles the judge samples: while a pair could meet within the step, the step is
//! cut so that neither vehicle moves more than [`PAIR_RESOLUTION`] between samples, and a
//! contact is dated to the first sample at which the footprints touch. Active or passive is
//! judged per vehicle, as for the robot: a vehicle moving toward the other faster than
//! [`ACTIVE_CONTACT_SPEED`] drove into it.

use super::people::Crowd;
use super::{ObstaclePath, World, ACTIVE_CONTACT_SPEED};
use crate::scenario::vehicles::Role;
use crate::scenario::{Motion, SimScenario};
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
    /// People who see the vehicles, walking as the fleet runs (`None`: none do).
    people: Option<Crowd>,
    /// Scratch: every vehicle as people see it.
    bodies: Vec<(Point, Point, f64)>,
}

impl Fleet {
    /// The fleet of a scenario at time 0, the robot first.
    pub fn new(s: &SimScenario) -> Self {
        let n = 1 + s.vehicles.len();
        let mut worlds: Vec<World> = (0..n).map(|k| World::new(&s.vehicle_alone(k))).collect();
        // Each world would walk its own people beside its own vehicle: one crowd walks for all.
        let people = worlds[0].take_people();
        for w in &mut worlds[1..] {
            w.take_people();
        }
        let top_speed = s.fleet().map(|(_, body, _)| body.max_wheel_speed).collect();
        let mut fleet = Self {
            worlds,
            top_speed,
            contact: vec![None; n],
            min_gap: vec![f64::INFINITY; n],
            people,
            bodies: Vec::with_capacity(n),
        };
        fleet.judge_pairs();
        fleet
    }

    /// The robot's world as a fleet of one: it walks its own people, exactly as it would
    /// alone (a scenario without vehicles, served by the simulated rig).
    pub fn of_one(world: World) -> Self {
        Self {
            worlds: vec![world],
            // Alone, no pair cuts a step: its speed is never asked.
            top_speed: vec![0.0],
            contact: vec![None],
            min_gap: vec![f64::INFINITY],
            people: None,
            bodies: Vec::new(),
        }
    }

    /// The simulated rig's fleet for `s`: every vehicle, or the robot's world alone.
    pub fn for_rig(s: &SimScenario) -> Self {
        if s.is_fleet() {
            Self::new(s)
        } else {
            Self::of_one(World::new(s))
        }
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
            self.walk_people(self.time() + h);
            self.worlds.iter_mut().for_each(|w| w.step(h));
            self.judge_pairs();
        }
    }

    /// People who walk as the fleet runs walk each step that begins by `until`, those who
    /// see the vehicles seeing each where it is at the step's start, and every world learns
    /// their ways.
    fn walk_people(&mut self, until: f64) {
        let Some(crowd) = self.people.as_mut().filter(|_| until.is_finite()) else { return };
        while crowd.time() <= until {
            let t = crowd.time();
            self.bodies.clear();
            self.bodies.extend(self.worlds.iter().map(|w| w.body_seen_at(t)));
            crowd.step_beside(&self.bodies);
            // Known up to the crowd's time now: past `until`, whatever the rounding of
            // `t + STEP` (at `until` itself a way would otherwise read as standing).
            let walked = crowd.time();
            for (k, t0, from, v) in crowd.last_legs() {
                self.worlds.iter_mut().for_each(|w| w.walk_on(k, t0, from, v, walked));
            }
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

/// Cut vehicle `i`'s script at its last point for which `inside` (given a point and the
/// way the script moves there) holds, if it leaves it: the vehicle stops there. A note that
/// says where, `what` saying why (it "leaves the room").
pub fn cut_script(s: &mut SimScenario, i: usize, what: &str, inside: impl Fn(Point, Point) -> bool) -> Option<String> {
    let v = s.vehicles.get(i)?;
    let motion = v.motion.as_ref()?;
    if v.role != Role::Script || *motion == Motion::Stationary {
        return None;
    }
    let path = ObstaclePath::new(&v.script(v.body(&s.robot).radius));
    let speed = path.top_speed();
    let horizon = match motion {
        Motion::Waypoints { repeat: false, .. } => path.end_time().min(s.time_limit),
        _ => s.time_limit,
    };
    // Steps of a millimetre along the way.
    let dt = 0.001 / speed.max(1e-6);
    let mut t = 0.0;
    while t < horizon && inside(path.position(t + dt), path.velocity(t + dt)) {
        t += dt;
    }
    if t >= horizon {
        return None;
    }
    let end = path.position(t);
    let note = format!(
        "vehicles[{i}] ({}): its script {what} at ({:.3}, {:.3}) after {t:.2} s: the vehicle stops there",
        v.name, end.re, end.im
    );
    let points = path.corners_before(t).into_iter().chain(std::iter::once(end)).map(|p| [p.re, p.im]).collect();
    s.vehicles[i].motion = Some(Motion::Waypoints { points, speed, repeat: false });
    Some(note)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO: &str = r#"
        name = "two"
        time_limit = 10
        [robot]
        start = [-0.15, 0]
        radius = 0.07
        wheel_base = 0.108
        wheel_radius = 0.025
        steps_per_rev = 200
        microsteps = 8
        max_wheel_speed = 0.25
        wheel_accel = 1.0
        max_speed = 0.15
        [goal]
        position = [0.5, 0.5]
        [[vehicles]]
        name = "other"
        role = "navigate"
        start = [0.15, 0]
        heading_deg = 180
        goal = [-0.5, -0.5]
        [sensing]
        sample_time = 0.02
    "#;

    /// Drive the vehicles at these wheel speeds (m/s, both wheels) until one touches the
    /// other or `seconds` pass.
    fn drive(speeds: [f64; 2], seconds: f64) -> Fleet {
        let s = SimScenario::from_toml(TWO, "two").unwrap();
        let mut fleet = Fleet::new(&s);
        let ppm = s.robot.pulses_per_metre();
        for (k, v) in speeds.iter().enumerate() {
            let rate = (v * ppm).round() as i32;
            fleet.world_mut(k).command_pulse_rates([rate, rate]);
        }
        while fleet.time() < seconds && fleet.vehicle_contact(0).is_none() {
            fleet.step(0.02);
        }
        fleet
    }

    /// Head-on, both drove in; one standing and one driving, only the driver did; the gap
    /// closes to no more than the judge's resolution past touching.
    #[test]
    fn contact_between_vehicles_is_judged_per_vehicle() {
        let both = drive([0.1, 0.1], 5.0);
        let (a, b) = (both.vehicle_contact(0).unwrap(), both.vehicle_contact(1).unwrap());
        assert!(a.active && b.active && a.with == 1 && b.with == 0, "{a:?} {b:?}");
        // 16 cm apart to begin with, 15 cm once both have ramped up (0.1 s), closed at
        // 0.2 m/s: they touch at 0.85 s, dated within one sample (the fastest vehicle moves
        // PAIR_RESOLUTION in one: 2 ms).
        assert!(a.at >= 0.85 - 1e-9 && a.at <= 0.852 + 1e-9, "{a:?}");

        let one = drive([0.1, 0.0], 5.0);
        let (a, b) = (one.vehicle_contact(0).unwrap(), one.vehicle_contact(1).unwrap());
        assert!(a.active && !b.active, "{a:?} {b:?}");
        assert!(b.approach_speed.abs() < 1e-9, "{b:?}");

        let apart = drive([-0.1, -0.1], 3.0);
        assert!(
            apart.vehicle_contact(0).is_none() && (apart.min_vehicle_gap(0) - 0.16).abs() < 1e-9,
            "{}",
            apart.min_vehicle_gap(0)
        );
    }

    /// A person walking through where the second vehicle stands: one who sees the vehicles
    /// walks round it to their goal, untouched; one who does not walks into it. Every
    /// vehicle's world holds the same way for the person.
    #[test]
    fn people_who_see_the_vehicles_walk_round_every_one() {
        for sees in [true, false] {
            let person = format!(
                "[[obstacles]]\nradius = 0.07\nstart = [0.2, 0.5]\nbehaviour = \"orca\"\n\
                 goal = [0.2, -0.5]\npreferred_speed = 0.05\nsees_robot = {sees}\n"
            );
            let s = SimScenario::from_toml(&format!("{TWO}\n{person}"), "two").unwrap();
            let mut fleet = Fleet::new(&s);
            while fleet.time() < 30.0 {
                fleet.step(0.02);
            }
            let t = fleet.time();
            let (there, robots) = (fleet.world(1).obstacle_position(0, t), fleet.world(0).obstacle_position(0, t));
            assert_eq!(there, robots, "every world holds the same way");
            let touched = fleet.world(1).truth().contact;
            if sees {
                assert!(touched.is_none(), "{touched:?}");
                assert!((there - Point::new(0.2, -0.5)).norm() < 0.07, "{there}");
            } else {
                assert!(touched.is_some_and(|c| !c.active), "{touched:?}");
            }
        }
    }
}
