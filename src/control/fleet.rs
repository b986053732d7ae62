//! Several vehicles under one camera: what each vehicle's control step is given of the
//! others, and how a scripted vehicle follows its script.
//!
//! - **The others as moving obstacles.** Each vehicle's field and supervisor see every
//!   other vehicle as an obstacle of its own radius, moving at the velocity it was
//!   *commanded*: known, not estimated. Vehicles plan in a fixed order (their priority: the
//!   robot first, then `[[vehicles]]` in the file's order), so a vehicle sees this cycle's
//!   command of every vehicle ahead of it and the last cycle's of those behind; a vehicle that
//!   is stopped, or braking, is seen moving as it moves.
//! - **No deadlock, no mirroring.** Every vehicle keeps right of every other (the planner's
//!   tie-break shifts a vehicle dead ahead to the left, the same rule in every vehicle's
//!   frame), so two vehicles meeting head-on both pass on their right instead of swerving
//!   into each other; a vehicle whose goal another still stands on heads for the point
//!   beside it on its right ([`FleetRule::aim`]) rather than wait for it, which would
//!   deadlock a swap. Together the vehicles turn one way round, as at a roundabout. Each
//!   keeps [`FleetRule::spacing`] from the others, as a margin the field gives up before it
//!   would freeze a vehicle.
//! - **The supervisor certifies every pair**: each vehicle's own supervisor checks its
//!   command against every other vehicle, whatever its planner (the field, a script, an
//!   outside planner) asked. It sees each other vehicle going on at the velocity its wheels
//!   ramp toward (its command; standing, once it is stopped), its footprint grown by how far
//!   behind that way the ramps may still leave it: a vehicle setting off, or braking, is not
//!   yet, or no longer, where its command would put it, and one following it must not run
//!   into it there. And anywhere short of that way: it may stop dead (its link lost, its
//!   motors timing out) before anyone knows ([`crate::control::supervisor`]).

use crate::planner::ObstacleEstimate;
use crate::Point;

/// What a vehicle's control step sees of another vehicle this cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleView {
    pub position: Point,
    /// What it was commanded (or, stopped, how it moves), m/s: what the fields plan on.
    pub velocity: Point,
    /// What its wheels ramp toward, m/s: its command, or standing once it is stopped.
    pub toward: Point,
    /// How far behind the way `toward` would take it its wheels' ramps may leave it, m:
    /// the gap between how it moves now and `toward`, times the longer of its wheels' ramps
    /// (the centre's speed moves monotonically between the two meanwhile).
    pub lag: f64,
    pub radius: f64,
    /// It navigates on: where it stands now it will leave.
    pub moving_on: bool,
    /// How far it may still move, m, beyond where it is, out of control (its link lost, its
    /// motors holding their last command until they stop): 0 for one under control.
    pub reach: f64,
}

impl VehicleView {
    /// A vehicle of `radius` standing at `position`, under control, going nowhere.
    pub fn standing(position: Point, radius: f64) -> Self {
        let still = Point::default();
        Self { position, velocity: still, toward: still, lag: 0.0, radius, moving_on: false, reach: 0.0 }
    }
}

/// The rule the vehicles share.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FleetRule {
    /// The room a vehicle's field keeps from every other vehicle beyond their footprints,
    /// m: a margin, given up before it would freeze a vehicle or cover its goal.
    pub spacing: f64,
}

/// The spacing of [`FleetRule::default`], m: the middle of the range (3-5 cm) in which the
/// 8-vehicle swap's makespan is least (docs/fleet.md).
pub const SPACING: f64 = 0.04;

impl Default for FleetRule {
    fn default() -> Self {
        Self { spacing: SPACING }
    }
}

impl FleetRule {
    /// Vehicle `me`'s obstacles: the other `vehicles` (every vehicle, `me` among them, in
    /// priority order) appended to `out` after what is already there.
    pub fn others_as_obstacles(&self, me: usize, vehicles: &[VehicleView], out: &mut Vec<ObstacleEstimate>) {
        for (_, v) in vehicles.iter().enumerate().filter(|&(k, _)| k != me) {
            out.push(self.as_obstacle(v));
        }
    }

    /// Another vehicle as a field plans on it.
    pub fn as_obstacle(&self, v: &VehicleView) -> ObstacleEstimate {
        self.out_of_control_or(v, v.velocity, 0.0)
    }

    /// Another vehicle as a supervisor checks a command against it.
    pub fn as_supervised(&self, v: &VehicleView) -> ObstacleEstimate {
        self.out_of_control_or(v, v.toward, v.lag)
    }

    /// The same for vehicle `me`'s supervisor: each vehicle under control going on at the
    /// velocity its wheels ramp toward, its footprint grown by its ramps' lag behind that way.
    pub fn others_as_supervised(&self, me: usize, vehicles: &[VehicleView], out: &mut Vec<ObstacleEstimate>) {
        for (_, v) in vehicles.iter().enumerate().filter(|&(k, _)| k != me) {
            out.push(self.as_supervised(v));
        }
    }

    /// Vehicle `v` as an obstacle: out of control, a region (the planner leaves this
    /// vehicle and its goal outside it; the supervisor keeps clear of all of it), as an
    /// unseen obstacle is; else going on at `velocity`, its footprint grown by `grown`.
    fn out_of_control_or(&self, v: &VehicleView, velocity: Point, grown: f64) -> ObstacleEstimate {
        if v.reach > 0.0 {
            let exact = ObstacleEstimate::exact(v.position, v.velocity, v.radius + v.reach);
            return ObstacleEstimate { keep: self.spacing, spread: v.velocity.norm().max(f64::MIN_POSITIVE), ..exact };
        }
        ObstacleEstimate { keep: self.spacing, ..ObstacleEstimate::exact(v.position, velocity, v.radius + grown) }
    }
}

impl FleetRule {
    /// Where vehicle `me` at `position` should head for `goal` while another vehicle that
    /// navigates on still stands on it (`None`: the goal itself). Waiting for it to leave
    /// would deadlock a swap, each waiting on the other; heading for the near side of it
    /// would bring the two face to face. Instead the vehicle heads for the point beside its
    /// goal on its right, clear of the other: the other, doing the same, passes on its own
    /// right, and the goal is taken once it is free. The aim it `held` last cycle is kept
    /// while it is free and within [`AIM_HOLD`] of where it would be now: a field in a room
    /// is solved afresh for each new point it heads for.
    pub fn aim(
        &self,
        me: usize,
        position: Point,
        goal: Point,
        vehicles: &[VehicleView],
        held: Option<Point>,
    ) -> Option<Point> {
        self.aim_within(me, position, goal, vehicles, held, |_| true)
    }

    /// The same, the aim taken only where `allowed` (the room's free region: a point beside
    /// the goal may lie in a wall, in the furniture or beyond the view, where no field can
    /// lead).
    pub fn aim_within(
        &self,
        me: usize,
        position: Point,
        goal: Point,
        vehicles: &[VehicleView],
        held: Option<Point>,
        allowed: impl Fn(Point) -> bool,
    ) -> Option<Point> {
        let my_radius = vehicles[me].radius;
        let way = goal - position;
        if way.norm() == 0.0 {
            return None;
        }
        let right = -Point::i() * way / way.norm();
        let on_goal = |v: &VehicleView| (goal - v.position).norm() < v.radius + my_radius + self.spacing;
        let blocker = vehicles.iter().enumerate().find(|&(k, v)| k != me && v.moving_on && on_goal(v))?;
        let clear = blocker.1.radius + my_radius + self.spacing + AIM_CLEARANCE;
        // The point on the right, or the nearest free one round the blocker toward this
        // vehicle: another vehicle may stand there.
        let free = |p: Point| {
            allowed(p)
                && vehicles
                    .iter()
                    .enumerate()
                    .all(|(k, v)| k == me || (p - v.position).norm() >= v.radius + my_radius + self.spacing)
        };
        let fresh = (0..=6)
            .map(|step| blocker.1.position + right * Point::from_polar(clear, -f64::from(step) * AIM_TURN))
            .find(|&p| free(p))?;
        Some(held.filter(|&p| free(p) && (p - fresh).norm() < AIM_HOLD).unwrap_or(fresh))
    }
}

/// How far the aim may lag where it would be before it is moved, m.
pub const AIM_HOLD: f64 = 0.01;
/// How far outside the blocking vehicle's circle a vehicle aims, m.
const AIM_CLEARANCE: f64 = 0.03;
/// The steps, radians, by which the aim turns round the blocker toward the vehicle when
/// the point on the right is taken: six of them, a quarter turn at most.
const AIM_TURN: f64 = std::f64::consts::PI / 12.0;

/// Gains of the script follower: a tracking controller on the unicycle (after Kanayama et
/// al., 1990), its error in the vehicle's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FollowerGains {
    /// Along the heading, 1/s.
    pub along: f64,
    /// Across it, 1/m².
    pub across: f64,
    /// Heading, 1/m.
    pub heading: f64,
}

impl Default for FollowerGains {
    fn default() -> Self {
        Self { along: 3.0, across: 400.0, heading: 40.0 }
    }
}

/// The forward speed (m/s) and turn rate (rad/s) that bring a vehicle at `position`,
/// facing `facing` (a unit vector), onto a script that is at `reference` moving at
/// `velocity`. A script at rest is approached straight on, then held.
pub fn follow(gains: &FollowerGains, position: Point, facing: Point, reference: Point, velocity: Point) -> (f64, f64) {
    let speed = velocity.norm();
    let error = (reference - position) * facing.conj(); // in the vehicle's frame
    let (ex, ey) = (error.re, error.im);
    if speed == 0.0 {
        // Standing script: drive to it along the heading, turning toward it while away.
        let near = error.norm() < 1e-3;
        let w = if near { 0.0 } else { gains.heading * 0.05 * ey.atan2(ex.abs()) };
        return (gains.along * ex, w);
    }
    let e_heading = (velocity / speed * facing.conj()).arg();
    let v = speed * e_heading.cos() + gains.along * ex;
    let w = speed * (gains.across * ey + gains.heading * e_heading.sin());
    (v, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On its script, a vehicle is asked the script's own speed and no turn; to its left, it
    /// turns right back onto it.
    #[test]
    fn the_follower_holds_a_line_and_returns_to_it() {
        let g = FollowerGains::default();
        let east = Point::new(1.0, 0.0);
        let (v, w) = follow(&g, Point::new(0.0, 0.0), east, Point::new(0.0, 0.0), Point::new(0.05, 0.0));
        assert!((v - 0.05).abs() < 1e-12 && w.abs() < 1e-12, "{v} {w}");
        let (_, w) = follow(&g, Point::new(0.0, 0.01), east, Point::new(0.0, 0.0), Point::new(0.05, 0.0));
        assert!(w < 0.0, "left of the script: turn right, {w}");
        let (v, _) = follow(&g, Point::new(-0.01, 0.0), east, Point::new(0.0, 0.0), Point::new(0.05, 0.0));
        assert!(v > 0.05, "behind the script: catch up, {v}");
    }

    /// Every other vehicle is an obstacle of its own footprint, moving as commanded, with
    /// the fleet's spacing kept from it as a margin.
    #[test]
    fn the_others_are_obstacles_with_a_margin() {
        let rule = FleetRule { spacing: 0.04 };
        let views = [0.0, 1.0, 2.0].map(|x| VehicleView {
            position: Point::new(x, 0.0),
            velocity: Point::new(0.0, x),
            toward: Point::new(0.0, x),
            lag: 0.0,
            radius: 0.07,
            moving_on: true,
            reach: 0.0,
        });
        let mut seen = Vec::new();
        rule.others_as_obstacles(1, &views, &mut seen);
        assert_eq!(seen.iter().map(|o| o.center.re).collect::<Vec<_>>(), [0.0, 2.0]);
        assert_eq!(seen[1].velocity, Point::new(0.0, 2.0), "as commanded");
        assert!(seen.iter().all(|o| o.radius == 0.07 && o.keep == 0.04 && o.spread == 0.0));
        let mut lost = views;
        lost[2].reach = 0.05;
        seen.clear();
        rule.others_as_obstacles(1, &lost, &mut seen);
        assert!((seen[1].radius - 0.12).abs() < 1e-12 && seen[1].spread > 0.0, "a region: {:?}", seen[1]);
    }

    /// To a supervisor, a vehicle moving as commanded is the fields' obstacle; one setting
    /// off, or braking, goes on where its wheels are headed, grown by their lag.
    #[test]
    fn a_supervisor_sees_a_vehicle_where_its_wheels_are_headed() {
        let rule = FleetRule { spacing: 0.04 };
        let mut views = [0.0, 1.0].map(|x| VehicleView {
            position: Point::new(x, 0.0),
            velocity: Point::new(0.1, 0.0),
            toward: Point::new(0.1, 0.0),
            lag: 0.0,
            radius: 0.07,
            moving_on: true,
            reach: 0.0,
        });
        let (mut fields, mut supervised) = (Vec::new(), Vec::new());
        rule.others_as_obstacles(0, &views, &mut fields);
        rule.others_as_supervised(0, &views, &mut supervised);
        assert_eq!(fields, supervised, "steady: the same obstacle");
        // Stopped at 0.1 m/s, braking on 1 m/s² ramps: standing, grown by 0.1 m/s x 0.1 s.
        (views[1].toward, views[1].lag) = (Point::default(), 0.01);
        supervised.clear();
        rule.others_as_supervised(0, &views, &mut supervised);
        let o = supervised[0];
        assert_eq!((o.velocity, o.spread), (Point::default(), 0.0), "{o:?}");
        assert!((o.radius - 0.08).abs() < 1e-12, "{o:?}");
    }

    /// A vehicle standing on another's goal sends the other to the point beside it on the
    /// other's right; one that stays there for good (at its own goal) does not.
    #[test]
    fn a_goal_still_taken_is_approached_on_the_right() {
        let rule = FleetRule { spacing: 0.04 };
        let mut views = [(0.0, -0.5), (0.0, 0.5)].map(|(x, y)| VehicleView {
            position: Point::new(x, y),
            velocity: Point::default(),
            toward: Point::default(),
            lag: 0.0,
            radius: 0.07,
            moving_on: true,
            reach: 0.0,
        });
        let aim = rule.aim(0, views[0].position, Point::new(0.0, 0.5), &views, None).unwrap();
        assert!(aim.re > 0.17 && (aim.im - 0.5).abs() < 1e-9, "east of the goal, heading north: {aim}");
        let kept = aim + Point::new(0.005, 0.0);
        assert_eq!(rule.aim(0, views[0].position, Point::new(0.0, 0.5), &views, Some(kept)), Some(kept), "held");
        let stale = aim + Point::new(0.02, 0.0);
        assert_eq!(rule.aim(0, views[0].position, Point::new(0.0, 0.5), &views, Some(stale)), Some(aim), "moved");
        views[1].moving_on = false;
        assert_eq!(rule.aim(0, views[0].position, Point::new(0.0, 0.5), &views, None), None);
    }
}
