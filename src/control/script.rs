//! A scripted vehicle's script: where it should be each moment after it set off, a path of
//! straight legs at one speed (standing, a line, or waypoints, once or over and over), and
//! the limits a vehicle must meet to follow it within [`PRECISION`]. The gateway's script
//! follower ([`super::fleet::follow`]) steers onto it; the rig's loader checks it against
//! the vehicle's wheels and cuts it where it would leave the room's free region.

use crate::Point;
pub use flowgate_protocol::plane::script::{Unfollowable, Wheels, DEFAULT_TOLERANCE, PRECISION};

/// One straight leg: set off at `at` (s after the start) from `from` at `velocity`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Leg {
    at: f64,
    from: Point,
    velocity: Point,
}

/// A script: from its start through its points at its speed, then standing at the last
/// (or, repeating, back to the start and round again).
#[derive(Debug, Clone, PartialEq)]
pub struct Script {
    start: Point,
    legs: Vec<Leg>,
    /// When the last leg ends, s (a standing script: 0).
    end: f64,
    repeat: bool,
    speed: f64,
}

impl Script {
    /// Standing at `at`.
    pub fn standing(at: Point) -> Self {
        Self { start: at, legs: Vec::new(), end: 0.0, repeat: false, speed: 0.0 }
    }

    /// From `start` through each of `points` at `speed` (m/s); `repeat`: then back to the
    /// start and round again.
    pub fn through(start: Point, points: &[Point], speed: f64, repeat: bool) -> Self {
        let mut legs = Vec::with_capacity(points.len() + 1);
        let (mut t, mut from) = (0.0, start);
        for &p in points.iter().chain(repeat.then_some(&start)) {
            let d = p - from;
            if d.norm() > 0.0 && speed > 0.0 {
                legs.push(Leg { at: t, from, velocity: d / d.norm() * speed });
                t += d.norm() / speed;
            }
            from = p;
        }
        let repeat = repeat && t > 0.0;
        Self { start, legs, end: t, repeat, speed: if t > 0.0 { speed } else { 0.0 } }
    }

    pub fn start(&self) -> Point {
        self.start
    }

    /// Its speed on every leg, m/s (0: standing).
    pub fn speed(&self) -> f64 {
        self.speed
    }

    pub fn repeats(&self) -> bool {
        self.repeat
    }

    /// When it comes to rest at its last point, s after the start; `None` for one that
    /// repeats.
    pub fn end_time(&self) -> Option<f64> {
        (!self.repeat).then_some(self.end)
    }

    /// Where it comes to rest (a repeating script: its start, where each round ends).
    pub fn last_point(&self) -> Point {
        self.legs.last().filter(|_| !self.repeat).map_or(self.start, |l| l.from + l.velocity * (self.end - l.at))
    }

    /// The leg it is on at `t` s after the start, and `t` within the round.
    fn leg(&self, t: f64) -> Option<(&Leg, f64)> {
        let t = if self.repeat { t.rem_euclid(self.end) } else { t };
        if t >= self.end {
            return None;
        }
        self.legs.iter().rev().find(|l| l.at <= t).map(|l| (l, t))
    }

    /// Where it is `t` s after the start.
    pub fn position(&self, t: f64) -> Point {
        match self.leg(t.max(0.0)) {
            Some((l, t)) => l.from + l.velocity * (t - l.at),
            None => self.last_point(),
        }
    }

    /// How it moves `t` s after the start, m/s.
    pub fn velocity(&self, t: f64) -> Point {
        self.leg(t.max(0.0)).map_or(Point::default(), |(l, _)| l.velocity)
    }

    /// The same script up to where it first leaves the places `free` allows (asked with the
    /// script's position and velocity there), stopping there (walked in millimetre steps);
    /// `None` when it never leaves. The cut script's end, and when it comes there.
    pub fn cut(&self, free: impl Fn(Point, Point) -> bool) -> Option<(Script, Point, f64)> {
        if self.speed == 0.0 {
            return None;
        }
        let dt = 0.001 / self.speed;
        let round = self.end;
        let mut t = 0.0;
        // One round of a repeating script covers all of it.
        while t < round {
            if !free(self.position(t + dt), self.velocity(t + dt)) {
                let end = self.position(t);
                let corners: Vec<Point> =
                    self.legs.iter().skip(1).take_while(|l| l.at < t).map(|l| l.from).chain([end]).collect();
                return Some((Script::through(self.start, &corners, self.speed, false), end, t));
            }
            t += dt;
        }
        None
    }

    /// Whether a vehicle with these wheels can follow it within [`PRECISION`]: no faster
    /// than its speed limit, a start its ramps reach, corners its wheels can turn
    /// ([`flowgate_protocol::plane::script::followable`], the simulator's rule too).
    pub fn followable(&self, wheels: &Wheels) -> Result<(), Unfollowable> {
        let mut directions: Vec<Point> = self.legs.iter().map(|l| l.velocity).collect();
        if self.repeat {
            directions.extend(self.legs.first().map(|l| l.velocity));
        }
        flowgate_protocol::plane::script::followable(self.speed, &directions, wheels)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f64, y: f64) -> Point {
        Point::new(x, y)
    }

    /// Along its legs at its speed, then standing at the last point; round again when it
    /// repeats.
    #[test]
    fn a_script_is_where_its_legs_put_it() {
        let s = Script::through(p(0.0, 0.0), &[p(0.1, 0.0), p(0.1, 0.1)], 0.05, false);
        assert_eq!(s.end_time(), Some(4.0));
        assert!((s.position(1.0) - p(0.05, 0.0)).norm() < 1e-12);
        assert!((s.position(3.0) - p(0.1, 0.05)).norm() < 1e-12);
        assert_eq!(s.velocity(3.0), p(0.0, 0.05));
        assert!((s.position(9.0) - p(0.1, 0.1)).norm() < 1e-12);
        assert_eq!(s.velocity(9.0), Point::default());
        let round = Script::through(p(0.0, 0.0), &[p(0.1, 0.0)], 0.05, true);
        assert_eq!(round.end_time(), None);
        assert!((round.position(5.0) - p(0.05, 0.0)).norm() < 1e-12, "{}", round.position(5.0));
        let still = Script::standing(p(0.2, 0.1));
        assert_eq!((still.position(3.0), still.velocity(3.0), still.end_time()), (p(0.2, 0.1), p(0.0, 0.0), Some(0.0)));
    }

    /// A line leaving the free region ends at its last free point, within a millimetre.
    #[test]
    fn a_script_is_cut_where_it_leaves() {
        let s = Script::through(p(0.0, 0.0), &[p(0.2, 0.0), p(0.2, 0.5)], 0.05, false);
        let (cut, end, t) = s.cut(|q, _| q.im < 0.3).unwrap();
        assert!((end - p(0.2, 0.3)).norm() < 0.0011, "{end}");
        assert!((t - 10.0).abs() < 0.03, "{t}");
        assert_eq!(cut.end_time().map(|e| (e - t).abs() < 1e-9), Some(true));
        assert!((cut.position(3.0) - s.position(3.0)).norm() < 1e-12);
        assert!(s.cut(|_, _| true).is_none());
    }

    /// Too fast, too sudden a start, too sharp a corner: each refused with its numbers.
    #[test]
    fn a_script_the_wheels_cannot_follow_is_refused() {
        let w = Wheels { max_speed: 0.15, max_wheel_speed: 0.25, wheel_accel: 1.0, wheel_base: 0.108 };
        let line = |speed| Script::through(p(0.0, 0.0), &[p(0.5, 0.0)], speed, false);
        assert!(line(0.07).followable(&w).is_ok());
        assert!(line(0.2).followable(&w).unwrap_err().to_string().contains("faster than the vehicle's max_speed"));
        let slow = Wheels { wheel_accel: 0.1, ..w };
        assert!(line(0.07).followable(&slow).unwrap_err().to_string().contains("falls 24.5 mm behind"));
        let corner = Script::through(p(0.0, 0.0), &[p(0.3, 0.0), p(0.3, 0.3)], 0.09, false);
        let turn = corner.followable(&w).unwrap_err().to_string();
        assert!(turn.starts_with("turns 90° at point 0"), "{turn}");
    }
}
