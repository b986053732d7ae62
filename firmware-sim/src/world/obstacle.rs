//! Scripted obstacle motion, analytic in time so that the truth at any moment is exact.

use crate::scenario::{point, Motion, ObstacleSpec};
use crate::Point;
use std::sync::atomic::{AtomicUsize, Ordering};

/// An obstacle's path: a start and legs of constant velocity.
#[derive(Debug)]
pub struct ObstaclePath {
    start: Point,
    /// Legs as (start time, start point, velocity); after the last leg the obstacle rests
    /// (or, with `repeat`, the schedule starts again).
    legs: Vec<(f64, Point, Point)>,
    end: f64,
    repeat: bool,
    /// `Some((start, velocity))` for one velocity forever: the position in closed form,
    /// as the world asks it every step.
    uniform: Option<(Point, Point)>,
    /// The fastest of the legs, m/s (the world asks it every step; a walked way has
    /// thousands of legs).
    top: f64,
    /// Where the last lookup found its leg: the world asks about moments close together,
    /// so the next is most often the same leg or the one after.
    hint: AtomicUsize,
}

impl Clone for ObstaclePath {
    fn clone(&self) -> Self {
        Self {
            start: self.start,
            legs: self.legs.clone(),
            end: self.end,
            repeat: self.repeat,
            uniform: self.uniform,
            top: self.top,
            hint: AtomicUsize::new(self.hint.load(Ordering::Relaxed)),
        }
    }
}

impl ObstaclePath {
    pub fn new(spec: &ObstacleSpec) -> Self {
        Self::scripted(spec).with_top_speed()
    }

    fn with_top_speed(mut self) -> Self {
        self.top = self.legs.iter().map(|l| l.2.norm()).fold(0.0, f64::max);
        self
    }

    fn scripted(spec: &ObstacleSpec) -> Self {
        let start = point(spec.start);
        match &spec.motion {
            Motion::Stationary => Self {
                start,
                legs: Vec::new(),
                end: 0.0,
                repeat: false,
                uniform: None,
                top: 0.0,
                hint: AtomicUsize::new(0),
            },
            Motion::Constant { velocity } => Self {
                start,
                legs: vec![(0.0, start, point(*velocity))],
                end: f64::INFINITY,
                repeat: false,
                uniform: Some((start, point(*velocity))),
                top: 0.0,
                hint: AtomicUsize::new(0),
            },
            Motion::Waypoints { points, speed, repeat } => {
                let mut legs = Vec::new();
                let (mut t, mut from) = (0.0, start);
                for &p in points.iter().map(|p| point(*p)).collect::<Vec<_>>().iter().chain(repeat.then_some(&start)) {
                    let d = p - from;
                    if d.norm() > 0.0 {
                        legs.push((t, from, d / d.norm() * *speed));
                        t += d.norm() / speed;
                    }
                    from = p;
                }
                Self {
                    start,
                    legs,
                    end: t,
                    repeat: *repeat && t > 0.0,
                    uniform: None,
                    top: 0.0,
                    hint: AtomicUsize::new(0),
                }
            }
        }
    }

    /// A walked way: from `start`, legs of constant velocity `(start time, start point,
    /// velocity)` in time order, standing where the last leaves it from `end` on.
    pub fn walked(start: Point, legs: Vec<(f64, Point, Point)>, end: f64) -> Self {
        Self { start, legs, end, repeat: false, uniform: None, top: 0.0, hint: AtomicUsize::new(0) }.with_top_speed()
    }

    /// A way still to be walked, from `start`, at most `top` m/s: standing there until
    /// [`ObstaclePath::walk_on`] adds its legs.
    pub fn walking(start: Point, top: f64) -> Self {
        Self { start, legs: Vec::new(), end: 0.0, repeat: false, uniform: None, top, hint: AtomicUsize::new(0) }
    }

    /// A walking way goes on at `t` from `from` at velocity `v` until `until`, and stands
    /// where that leaves it after, until walked on again.
    pub fn walk_on(&mut self, t: f64, from: Point, v: Point, until: f64) {
        if self.legs.last().is_none_or(|&(_, _, last)| last != v) {
            self.legs.push((t, from, v));
        }
        self.end = until;
    }

    /// When the path ends (infinite for one velocity forever; one lap of a repeating one).
    pub fn end_time(&self) -> f64 {
        self.end
    }

    /// The points where the path turned before `t`, in order (a repeating path's every lap).
    pub fn corners_before(&self, t: f64) -> Vec<Point> {
        let mut corners = Vec::new();
        if self.uniform.is_some() || self.legs.is_empty() {
            return corners;
        }
        let mut lap = 0.0;
        while lap <= t {
            for &(t0, p0, _) in &self.legs {
                if lap + t0 > 0.0 && lap + t0 <= t {
                    corners.push(p0);
                }
            }
            if !self.repeat {
                break;
            }
            lap += self.end;
        }
        corners
    }

    fn leg_at(&self, t: f64) -> Option<(f64, Point, Point)> {
        let t = if self.repeat { self.lap_time(t) } else { t };
        if t >= self.end {
            return None;
        }
        let i = self.legs_begun(t).checked_sub(1)?;
        let (t0, p0, v) = self.legs[i];
        Some((t - t0, p0, v))
    }

    /// Whether the obstacle keeps one velocity from `t0` to `t1` (no turn at a waypoint,
    /// no stop, no restart of a repeating schedule between them).
    pub fn one_velocity_between(&self, t0: f64, t1: f64) -> bool {
        if self.legs.is_empty() || self.uniform.is_some() {
            return true; // stationary, or one velocity forever
        }
        if self.repeat {
            // Which lap, and which leg of it.
            let lap = |t: f64| (t.max(0.0) / self.end).floor();
            return lap(t0) == lap(t1) && self.leg_index(t0) == self.leg_index(t1);
        }
        self.leg_index(t0) == self.leg_index(t1)
    }

    /// The leg in force at `t` (`legs.len()`: resting after the last).
    /// The first instant strictly between `a` and `b` at which the velocity changes (a
    /// leg ends), if there is one.
    pub fn change_between(&self, a: f64, b: f64) -> Option<f64> {
        if self.legs.is_empty() || self.uniform.is_some() || b <= a || self.one_velocity_between(a, b) {
            return None;
        }
        let from = a.max(0.0);
        let (lap, begun) = if self.repeat {
            let lap = (from / self.end).floor() * self.end;
            (lap, self.legs.partition_point(|l| lap + l.0 <= a))
        } else {
            (0.0, self.legs_begun(a))
        };
        let at = lap + self.legs.get(begun).map_or(self.end, |l| l.0);
        (at > a && at < b).then_some(at)
    }

    /// The fastest the obstacle ever moves, m/s.
    pub fn top_speed(&self) -> f64 {
        self.top
    }

    fn leg_index(&self, t: f64) -> usize {
        let t = t.max(0.0);
        let t = if self.repeat { self.lap_time(t) } else { t };
        if t >= self.end {
            return self.legs.len();
        }
        self.legs_begun(t).saturating_sub(1)
    }

    /// How many legs have begun by `t` (within a lap). Legs are in time order, and a walked
    /// way has thousands: the last answer's leg and those either side are tried before a
    /// search (the judge asks about the two ends of an interval in turn).
    fn legs_begun(&self, t: f64) -> usize {
        let begun = |n: usize| n == 0 || self.legs[n - 1].0 <= t;
        let not_yet = |n: usize| n == self.legs.len() || self.legs[n].0 > t;
        let hint = self.hint.load(Ordering::Relaxed);
        let n = if hint <= self.legs.len() && begun(hint) && not_yet(hint) {
            hint
        } else if hint < self.legs.len() && begun(hint + 1) && not_yet(hint + 1) {
            hint + 1
        } else if (1..=self.legs.len()).contains(&hint) && begun(hint - 1) && not_yet(hint - 1) {
            hint - 1
        } else {
            self.legs.partition_point(|l| l.0 <= t)
        };
        self.hint.store(n, Ordering::Relaxed);
        n
    }

    /// `t` within the repeating schedule's lap. Out of line: inlined, the compiler
    /// computed the remainder (a library call) on every path, repeating or not.
    #[inline(never)]
    fn lap_time(&self, t: f64) -> f64 {
        t.rem_euclid(self.end)
    }

    pub fn position(&self, t: f64) -> Point {
        if let Some((start, velocity)) = self.uniform {
            return start + velocity * t.max(0.0);
        }
        if self.legs.is_empty() {
            return self.start; // standing
        }
        match self.leg_at(t.max(0.0)) {
            Some((dt, p0, v)) => p0 + v * dt,
            None => self.rest_point(),
        }
    }

    pub fn velocity(&self, t: f64) -> Point {
        self.leg_at(t.max(0.0)).map_or(Point::new(0.0, 0.0), |(_, _, v)| v)
    }

    fn rest_point(&self) -> Point {
        match self.legs.last() {
            Some(&(t0, p0, v)) if self.end.is_finite() => p0 + v * (self.end - t0),
            _ => self.start,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(motion: Motion) -> ObstacleSpec {
        ObstacleSpec::scripted(0.1, [0.0, 0.0], motion)
    }

    #[test]
    fn waypoints_then_rest() {
        let p = ObstaclePath::new(&spec(Motion::Waypoints {
            points: vec![[1.0, 0.0], [1.0, 1.0]],
            speed: 0.5,
            repeat: false,
        }));
        assert!((p.position(1.0) - Point::new(0.5, 0.0)).norm() < 1e-12);
        assert!((p.position(3.0) - Point::new(1.0, 0.5)).norm() < 1e-12);
        assert!((p.velocity(3.0) - Point::new(0.0, 0.5)).norm() < 1e-12);
        assert!((p.position(10.0) - Point::new(1.0, 1.0)).norm() < 1e-12);
        assert_eq!(p.velocity(10.0), Point::new(0.0, 0.0));
    }

    #[test]
    fn repeating_waypoints_loop() {
        let p = ObstaclePath::new(&spec(Motion::Waypoints { points: vec![[1.0, 0.0]], speed: 1.0, repeat: true }));
        assert!((p.position(1.5) - Point::new(0.5, 0.0)).norm() < 1e-12);
        assert!((p.position(2.25) - Point::new(0.25, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn constant_velocity() {
        let p = ObstaclePath::new(&spec(Motion::Constant { velocity: [-0.1, 0.2] }));
        assert!((p.position(2.0) - Point::new(-0.2, 0.4)).norm() < 1e-12);
    }
}
