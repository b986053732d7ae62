//! What a vehicle's wheels must allow for it to follow a script (straight legs at one speed)
//! within [`PRECISION`]. The gateway's rig loader and the simulator's scenario loader both
//! refuse a script by these rules, in these words.

use core::fmt;

use super::Point;

/// How closely a scripted vehicle follows its script where nothing holds it, m: a script
/// that asks for more (a corner its wheels cannot turn, a start its ramps cannot reach) is
/// refused at load.
pub const PRECISION: f64 = 0.01;

/// Beyond this distance from its script (unless set per vehicle) a scripted vehicle is
/// stopped and the stop named, m.
pub const DEFAULT_TOLERANCE: f64 = 0.05;

/// What a vehicle's wheels allow: its speed limit, its wheels' speed and ramp, its track.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wheels {
    pub max_speed: f64,
    pub max_wheel_speed: f64,
    pub wheel_accel: f64,
    pub wheel_base: f64,
}

/// Why a vehicle cannot follow a script within [`PRECISION`], with the numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Unfollowable {
    /// Faster than the vehicle's speed limit.
    TooFast { speed: f64, max_speed: f64 },
    /// From rest, its wheels' ramp leaves it `lag` m behind, more than half the precision.
    FallsBehind { speed: f64, wheel_accel: f64, lag: f64 },
    /// At the script's point `index` (its first point is 0) it turns `angle` rad; the
    /// tightest arc its wheels allow at the script's speed leaves it `error` m off.
    Corner { index: usize, angle: f64, speed: f64, arc: f64, error: f64 },
}

impl fmt::Display for Unfollowable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::TooFast { speed, max_speed } => {
                write!(f, "moves at {speed} m/s: faster than the vehicle's max_speed, {max_speed} m/s")
            }
            Self::FallsBehind { speed, wheel_accel, lag } => write!(
                f,
                "starts at {speed} m/s: from rest on its wheel_accel of {wheel_accel} m/s² the vehicle falls {:.1} mm \
                 behind, more than half of {} mm",
                lag * 1e3,
                PRECISION * 1e3
            ),
            Self::Corner { index, angle, speed, arc, error } => write!(
                f,
                "turns {:.0}° at point {index} at {speed} m/s: the tightest arc the wheels allow ({:.1} cm) leaves the \
                 vehicle {:.1} cm off its script, more than {} cm",
                angle.to_degrees(),
                arc * 100.0,
                error * 100.0,
                PRECISION * 100.0
            ),
        }
    }
}

/// Whether a vehicle with `wheels` can follow, within [`PRECISION`], a script at `speed`
/// (m/s) whose legs run, in order, along `directions` (each leg's velocity, or any vector
/// along it; a repeating script's first leg again after its last): no faster than its speed
/// limit, a start its ramps reach, each corner between two legs one its wheels can turn.
pub fn followable(speed: f64, directions: &[Point], wheels: &Wheels) -> Result<(), Unfollowable> {
    if speed > wheels.max_speed {
        return Err(Unfollowable::TooFast { speed, max_speed: wheels.max_speed });
    }
    // From rest to the script's speed on the wheels' ramp, the vehicle falls behind by v²/2a.
    let lag = speed * speed / (2.0 * wheels.wheel_accel);
    if lag > 0.5 * PRECISION {
        return Err(Unfollowable::FallsBehind { speed, wheel_accel: wheels.wheel_accel, lag });
    }
    // Turning at the script's speed, the wheels' headroom sets the tightest arc.
    let turn_rate = 2.0 * (wheels.max_wheel_speed.min(wheels.max_speed) - speed) / wheels.wheel_base;
    for (index, pair) in directions.windows(2).enumerate() {
        let angle = (pair[1] / pair[0]).arg().abs();
        if angle < 1e-9 {
            continue; // straight on
        }
        let arc = if turn_rate > 0.0 { speed / turn_rate } else { f64::INFINITY };
        // Cutting the corner on the arc, and falling behind the script along it.
        let half = 0.5 * angle;
        let error = arc * (1.0 / half.cos() - 1.0) + arc * (half.tan() - half);
        if error.is_nan() || error > PRECISION {
            return Err(Unfollowable::Corner { index, angle, speed, arc, error });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const WHEELS: Wheels = Wheels { max_speed: 0.15, max_wheel_speed: 0.25, wheel_accel: 1.0, wheel_base: 0.108 };

    #[test]
    fn a_script_the_wheels_cannot_follow_is_refused_with_the_numbers() {
        let east = Point::new(1.0, 0.0);
        assert_eq!(followable(0.07, &[east, east], &WHEELS), Ok(()));
        assert_eq!(followable(0.2, &[east], &WHEELS), Err(Unfollowable::TooFast { speed: 0.2, max_speed: 0.15 }));
        let slow = Wheels { wheel_accel: 0.1, ..WHEELS };
        let behind = followable(0.07, &[east], &slow).unwrap_err();
        assert!(behind.to_string().contains("falls 24.5 mm behind, more than half of 10 mm"), "{behind}");
        let corner = followable(0.08, &[east, Point::new(0.0, 1.0)], &WHEELS).unwrap_err();
        assert!(matches!(corner, Unfollowable::Corner { index: 0, .. }));
        assert!(corner.to_string().starts_with("turns 90° at point 0 at 0.08 m/s"), "{corner}");
        // A gentle turn at a crawl is followed.
        assert_eq!(followable(0.02, &[east, Point::new(1.0, 0.2)], &WHEELS), Ok(()));
    }
}
