//! `[crowd]`: CrowdNav's circle crossing scaled to the rig, placed afresh each episode.

use serde::Deserialize;

use super::{point, Behaviour, Motion, ObstacleSpec, SimScenario, MAX_OBSTACLES};
use crate::Point;

/// The robot and `obstacles` obstacles on a circle of `circle_radius` about the origin,
/// each crossing to the opposite side: the robot from (0, -r) to (0, r), each obstacle from
/// a random point of the circle to its antipode (both jittered), at `speed_ratio` of the
/// robot's speed limit, then standing there (or, with `walk_on`, walking on).
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CrowdSpec {
    pub obstacles: usize,
    pub circle_radius: f64,
    pub obstacle_radius: f64,
    pub speed_ratio: f64,
    /// The largest offset of each start and each goal from the circle, m, either axis.
    #[serde(default = "default_jitter")]
    pub jitter: f64,
    /// The obstacles walk on past their antipodes, another diameter, instead of standing
    /// there (people crossing a room do not stop on the far side of the robot's way).
    #[serde(default)]
    pub walk_on: bool,
    /// How they walk: straight through each other (the default), or as people avoiding
    /// each other (`orca`, CrowdNav's humans; `social_force`), at `speed_ratio` of the
    /// robot's top speed as their preferred speed.
    #[serde(default)]
    pub behaviour: Behaviour,
    /// People who see the robot and avoid it (with `behaviour` a person's).
    #[serde(default)]
    pub sees_robot: bool,
}

fn default_jitter() -> f64 {
    0.05
}

/// How many placements a crowd tries before it gives up on one obstacle's place.
const CROWD_TRIES: usize = 10_000;

impl SimScenario {
    pub(super) fn validate_crowd(&self) -> Result<(), (String, String)> {
        let Some(c) = self.crowd else { return Ok(()) };
        let bad = |key: &str, why: String| Err((format!("crowd.{key}"), why));
        if !(1..=MAX_OBSTACLES).contains(&c.obstacles) {
            return bad("obstacles", format!("must be 1-{MAX_OBSTACLES}, is {}", c.obstacles));
        }
        for (key, v) in
            [("circle_radius", c.circle_radius), ("obstacle_radius", c.obstacle_radius), ("speed_ratio", c.speed_ratio)]
        {
            if !(v.is_finite() && v > 0.0) {
                return bad(key, format!("must be a positive number, is {v}"));
            }
        }
        if !(c.jitter.is_finite() && c.jitter >= 0.0 && c.jitter < c.circle_radius) {
            return bad("jitter", format!("must be 0 or more, under circle_radius, is {}", c.jitter));
        }
        if !self.obstacles.is_empty() {
            return Err(("obstacles".into(), "a crowd places its own obstacles: leave [[obstacles]] out".into()));
        }
        if c.sees_robot && !c.behaviour.walks() {
            return bad("sees_robot", "is for people who walk: set behaviour = \"orca\" or \"social_force\"".into());
        }
        Ok(())
    }

    /// This scenario with its crowd placed for episode `i` of seed `seed` (reproducibly from
    /// the two), or as it is without a crowd. A crowd that cannot be placed without overlap
    /// in `CROWD_TRIES` tries an obstacle is refused, naming the key.
    pub fn crowd_episode(&self, seed: u64, i: u64) -> Result<SimScenario, (String, String)> {
        use rand::{Rng, SeedableRng};
        let Some(c) = self.crowd else { return Ok(self.clone()) };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xC20D);
        let mut s = self.clone();
        s.obstacles.clear();
        let r = c.circle_radius;
        s.robot.start = [0.0, -r];
        s.robot.heading_deg = 90.0;
        s.goal.position = [0.0, r];
        let (start, goal) = (point(s.robot.start), point(s.goal.position));
        let body = c.obstacle_radius + s.robot.radius + 0.05;
        let apart = 2.0 * c.obstacle_radius + 0.02;
        let speed = c.speed_ratio * s.robot.max_speed;
        let mut placed: Vec<(Point, Point)> = Vec::with_capacity(c.obstacles);
        for k in 0..c.obstacles {
            let mut found = None;
            for _ in 0..CROWD_TRIES {
                let theta = rng.random_range(0.0..std::f64::consts::TAU);
                let mut jitter =
                    || Point::new(rng.random_range(-c.jitter..=c.jitter), rng.random_range(-c.jitter..=c.jitter));
                let from = Point::from_polar(r, theta) + jitter();
                let to = -Point::from_polar(r, theta) + jitter();
                let clear = (from - start).norm() >= body
                    && (from - goal).norm() >= body
                    && (to - goal).norm() >= body
                    && (to - start).norm() >= body
                    && placed.iter().all(|&(f, t)| (from - f).norm() >= apart && (to - t).norm() >= apart);
                if clear {
                    found = Some((from, to));
                    break;
                }
            }
            let Some((from, to)) = found else {
                return Err((
                    "crowd.obstacles".into(),
                    format!("obstacle {k} finds no place on a circle of {r} m clear of the others"),
                ));
            };
            placed.push((from, to));
            let beyond = to + (to - from);
            let goals = if c.walk_on { vec![[to.re, to.im], [beyond.re, beyond.im]] } else { vec![[to.re, to.im]] };
            let start = [from.re, from.im];
            s.obstacles.push(if c.behaviour.walks() {
                ObstacleSpec {
                    behaviour: c.behaviour,
                    goals,
                    preferred_speed: Some(speed),
                    sees_robot: c.sees_robot,
                    ..ObstacleSpec::scripted(c.obstacle_radius, start, Motion::Stationary)
                }
            } else {
                ObstacleSpec::scripted(
                    c.obstacle_radius,
                    start,
                    Motion::Waypoints { points: goals, speed, repeat: false },
                )
            });
        }
        s.sensing.seed = rng.random();
        Ok(s)
    }
}
