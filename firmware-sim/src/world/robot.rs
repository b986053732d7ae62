//! Differential-drive kinematics: wheel speeds over time in, pose out.

use crate::{wrap_angle, Point};

/// The robot's pose: centre and heading (rad, from +x, counter-clockwise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub position: Point,
    pub heading: f64,
}

/// A differential-drive base.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiffDrive {
    pub wheel_base: f64,
    /// Step pulses per metre of wheel rim travel.
    pub pulses_per_metre: f64,
}

impl DiffDrive {
    /// The centre's speed at wheel rim speeds `w` (left, right), m/s.
    fn speed(w: [f64; 2]) -> f64 {
        0.5 * (w[0] + w[1])
    }

    /// The turn rate at wheel rim speeds `w` (left, right), rad/s.
    fn turn_rate(&self, w: [f64; 2]) -> f64 {
        (w[1] - w[0]) / self.wheel_base
    }

    /// The robot's motion in its own frame over `span` seconds while its wheels' rim speeds
    /// (m/s; left, right) go linearly from `from` to `to`, as they do on the boards' ramps.
    /// At constant speeds it is the exact arc; through a ramp the heading changes
    /// quadratically and the displacement is integrated by three-point Gauss-Legendre
    /// quadrature over pieces turning at most `QUADRATURE_TURN` each (exact to about
    /// 1e-15 of the travel).
    pub fn motion(&self, from: [f64; 2], to: [f64; 2], span: f64) -> Motion {
        let (v0, v1) = (Self::speed(from), Self::speed(to));
        let (w0, w1) = (self.turn_rate(from), self.turn_rate(to));
        let turned = 0.5 * (w0 + w1) * span;
        let length = travel(v0, v1, span);
        if from == to {
            if v0 == 0.0 {
                return Motion { displacement: Point::new(0.0, 0.0), turned, length };
            }
            // Chord of the arc: ds · sinc(dθ/2) along the mean heading.
            let (ds, half) = (v0 * span, 0.5 * turned);
            let half_turn = turn(half);
            let chord = if half.abs() < 1e-9 { ds } else { ds * half_turn.im / half };
            return Motion { displacement: half_turn * chord, turned, length };
        }
        let pieces = (w0.abs().max(w1.abs()) * span / QUADRATURE_TURN).ceil().max(1.0);
        let piece = span / pieces;
        // The heading `t` into the span, from the start's.
        // The rates of change, divided once: three nodes a piece would take six divisions.
        let (turn_change, speed_change) = (0.5 * (w1 - w0) / span, (v1 - v0) / span);
        let heading = |t: f64| w0 * t + turn_change * t * t;
        let velocity = |t: f64| turn(heading(t)) * (v0 + speed_change * t);
        const NODE: f64 = 0.774_596_669_241_483_4; // sqrt(3/5)
        let mut displacement = Point::new(0.0, 0.0);
        for k in 0..pieces as usize {
            let mid = (k as f64 + 0.5) * piece;
            let half = 0.5 * piece;
            displacement += (velocity(mid - NODE * half) * (5.0 / 9.0)
                + velocity(mid) * (8.0 / 9.0)
                + velocity(mid + NODE * half) * (5.0 / 9.0))
                * half;
        }
        Motion { displacement, turned, length }
    }

    /// How far the centre may stray, over a motion of `span` seconds with the wheels'
    /// speeds going linearly from `from` to `to`, from its chord traversed at constant
    /// speed, m: `M span² / 8` for an acceleration bounded by `M`, here the speed's rate
    /// of change plus the largest speed times the largest turn rate (both linear in time,
    /// so extreme at the ends).
    pub fn bow(&self, from: [f64; 2], to: [f64; 2], span: f64) -> f64 {
        self.swerve(from, to, span) * span * span / 8.0
    }

    /// The most the centre's acceleration can be over such a motion, m/s²: the speed's
    /// rate of change plus the largest speed times the largest turn rate.
    pub fn swerve(&self, from: [f64; 2], to: [f64; 2], span: f64) -> f64 {
        let (v0, v1) = (Self::speed(from), Self::speed(to));
        let tangential = (v1 - v0).abs() / span;
        let normal = v0.abs().max(v1.abs()) * self.turn_rate(from).abs().max(self.turn_rate(to).abs());
        tangential + normal
    }
}

/// The most a quadrature piece turns, rad: three-point Gauss-Legendre integrates
/// `e^{iθ}` over it to about θ⁶/2·10⁶, below 1e-15.
const QUADRATURE_TURN: f64 = 0.05;

/// Distance travelled in `span` at a speed going linearly from `v0` to `v1`, m (the
/// speed may pass through zero: distance, not displacement).
fn travel(v0: f64, v1: f64, span: f64) -> f64 {
    if (v0 >= 0.0) == (v1 >= 0.0) {
        0.5 * (v0 + v1).abs() * span
    } else {
        0.5 * (v0 * v0 + v1 * v1) / (v1 - v0).abs() * span
    }
}

/// A motion of the robot in its own frame at the start: where its centre ends up, the
/// angle turned, and the distance its centre travelled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motion {
    pub displacement: Point,
    pub turned: f64,
    pub length: f64,
}

impl Motion {
    /// `pose` moved by this motion, given the unit vector `facing` along its heading; and
    /// the new one.
    pub fn apply(&self, pose: Pose, facing: Point) -> (Pose, Point) {
        if self.turned == 0.0 && self.displacement == Point::new(0.0, 0.0) {
            return (pose, facing);
        }
        let heading = wrap_angle(pose.heading + self.turned);
        (Pose { position: pose.position + facing * self.displacement, heading }, facing * turn(self.turned))
    }
}

/// `e^{iθ}`; for the small angles of a step (|θ| ≤ 0.1 rad) by its series, exact to
/// rounding there and a fifth of a `sin_cos`. (The gateway has its own: the simulator
/// shares no code with what it judges.)
pub fn turn(theta: f64) -> Point {
    if theta.abs() > 0.1 {
        return Point::from_polar(1.0, theta);
    }
    let t2 = theta * theta;
    // Horner's form, the factorials' reciprocals as constants.
    let cos = 1.0 + t2 * (-1.0 / 2.0 + t2 * (1.0 / 24.0 + t2 * (-1.0 / 720.0 + t2 * (1.0 / 40_320.0))));
    let sin = theta * (1.0 + t2 * (-1.0 / 6.0 + t2 * (1.0 / 120.0 + t2 * (-1.0 / 5040.0 + t2 * (1.0 / 362_880.0)))));
    Point::new(cos, sin)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// The pose after the wheels emitted `pulses` (left, right) from `pose` at constant
    /// speeds (one second of them): the centre moves on an arc.
    fn advance(d: &DiffDrive, pose: Pose, pulses: [f64; 2]) -> Pose {
        let speeds = pulses.map(|p| p / d.pulses_per_metre);
        d.motion(speeds, speeds, 1.0).apply(pose, Point::from_polar(1.0, pose.heading)).0
    }

    #[test]
    fn straight_and_turn_in_place() {
        let d = DiffDrive { wheel_base: 0.1, pulses_per_metre: 1000.0 };
        let p = advance(&d, Pose { position: Point::new(0.0, 0.0), heading: 0.0 }, [100.0, 100.0]);
        assert!((p.position - Point::new(0.1, 0.0)).norm() < 1e-12);
        // Opposite wheels, each travelling a quarter of the wheel circle: half a turn.
        let quarter = PI * 0.1 / 4.0 * 1000.0;
        let p = advance(&d, p, [-quarter, quarter]);
        assert!((p.position - Point::new(0.1, 0.0)).norm() < 1e-12);
        assert!((p.heading - PI / 2.0).abs() < 1e-12);
    }

    #[test]
    fn a_full_circle_in_small_steps_closes() {
        let d = DiffDrive { wheel_base: 0.1, pulses_per_metre: 1000.0 };
        let mut p = Pose { position: Point::new(0.0, 0.0), heading: 0.0 };
        // Left wheel on radius 0.15, right on 0.25: the centre circles at radius 0.2.
        let n = 1000;
        for _ in 0..n {
            p = advance(&d, p, [2.0 * PI * 0.15 * 1000.0 / n as f64, 2.0 * PI * 0.25 * 1000.0 / n as f64]);
        }
        assert!(p.position.norm() < 1e-9, "{:?}", p.position);
    }

    #[test]
    fn a_ramp_is_integrated_as_finely_stepped() {
        let d = DiffDrive { wheel_base: 0.108, pulses_per_metre: 10_000.0 };
        let start = Pose { position: Point::new(0.1, -0.2), heading: 0.3 };
        // Both wheels ramp, at different rates, one through zero, over 20 ms.
        let (from, to) = ([0.05, -0.02], [0.12, 0.2]);
        let span = 0.02;
        let (whole, _) = d.motion(from, to, span).apply(start, Point::from_polar(1.0, start.heading));
        let n = 20_000;
        let mut fine = start;
        for k in 0..n {
            let at = |f: f64| [0, 1].map(|w| from[w] + (to[w] - from[w]) * f);
            let (a, b) = (at(k as f64 / n as f64), at((k + 1) as f64 / n as f64));
            let mean = [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
            fine = d.motion(mean, mean, span / n as f64).apply(fine, Point::from_polar(1.0, fine.heading)).0;
        }
        assert!((whole.position - fine.position).norm() < 1e-11, "{:?} {:?}", whole, fine);
        assert!((whole.heading - fine.heading).abs() < 1e-12);
        assert!((d.motion(from, to, span).length - travel(0.015, 0.16, span)).abs() < 1e-15);
    }

    #[test]
    fn small_turns_by_their_series() {
        for k in -1000..=1000 {
            let theta = f64::from(k) * 1e-4;
            assert!((turn(theta) - Point::from_polar(1.0, theta)).norm() < 2e-16, "{theta}");
        }
        assert_eq!(turn(0.7), Point::from_polar(1.0, 0.7));
    }
}
