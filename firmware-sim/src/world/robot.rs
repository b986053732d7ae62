//! Differential-drive kinematics: wheel travel in, pose out.

use crate::Point;

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
    /// The pose after the wheels emitted `pulses` (left, right) from `pose`. Exact for
    /// constant wheel speeds over the step (the centre moves on an arc).
    pub fn advance(&self, pose: Pose, pulses: [f64; 2]) -> Pose {
        self.motion(pulses).apply(pose, Point::from_polar(1.0, pose.heading)).0
    }

    /// The robot's motion in its own frame while the wheels emit `pulses` (left, right).
    pub fn motion(&self, pulses: [f64; 2]) -> Arc {
        if pulses == [0.0, 0.0] {
            return Arc::REST;
        }
        let [dl, dr] = pulses.map(|p| p / self.pulses_per_metre);
        let ds = 0.5 * (dl + dr);
        let turned = (dr - dl) / self.wheel_base;
        // Chord of the arc: ds · sinc(dθ/2) along the mean heading.
        let half = 0.5 * turned;
        let (sin, cos) = half.sin_cos();
        let chord = if half.abs() < 1e-9 { ds } else { ds * sin / half };
        let half_turn = Point::new(cos, sin);
        Arc { chord: half_turn * chord, rotation: half_turn * half_turn, turned, length: chord.abs() }
    }
}

/// A step of the robot along an arc, in its own frame at the start: the chord, the
/// rotation (a unit complex number) and the angle turned. The world's wheels hold one
/// speed for most of a run, so most of its 1 ms steps are the same arc: it keeps the last
/// one, and a step costs no trigonometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arc {
    pub chord: Point,
    pub rotation: Point,
    pub turned: f64,
    /// The chord's length, m: what the step adds to the path travelled.
    pub length: f64,
}

impl Arc {
    /// No motion.
    pub const REST: Arc = Arc { chord: Point::new(0.0, 0.0), rotation: Point::new(1.0, 0.0), turned: 0.0, length: 0.0 };

    /// `pose` moved along this arc, given the unit vector `facing` along its heading; and
    /// the new one.
    pub fn apply(&self, pose: Pose, facing: Point) -> (Pose, Point) {
        if self.turned == 0.0 && self.chord == Point::new(0.0, 0.0) {
            return (pose, facing);
        }
        let position = pose.position + facing * self.chord;
        (Pose { position, heading: wrap_angle(pose.heading + self.turned) }, facing * self.rotation)
    }
}

/// An angle in `(-π, π]`.
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    if a > -PI && a <= PI {
        return a; // the common case, every millisecond of a run: no division
    }
    let w = (a + PI).rem_euclid(TAU) - PI;
    if w <= -PI {
        w + TAU
    } else {
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn straight_and_turn_in_place() {
        let d = DiffDrive { wheel_base: 0.1, pulses_per_metre: 1000.0 };
        let p = d.advance(Pose { position: Point::new(0.0, 0.0), heading: 0.0 }, [100.0, 100.0]);
        assert!((p.position - Point::new(0.1, 0.0)).norm() < 1e-12);
        // Opposite wheels, each travelling a quarter of the wheel circle: half a turn.
        let quarter = PI * 0.1 / 4.0 * 1000.0;
        let p = d.advance(p, [-quarter, quarter]);
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
            p = d.advance(p, [2.0 * PI * 0.15 * 1000.0 / n as f64, 2.0 * PI * 0.25 * 1000.0 / n as f64]);
        }
        assert!(p.position.norm() < 1e-9, "{:?}", p.position);
    }

    #[test]
    fn wraps_angles() {
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(0.5) - 0.5).abs() < 1e-12);
    }
}
