//! From a velocity command to wheel speeds (eq. 30) and stepper pulse rates.
//!
//! `v_{l,r} = v ∓ K_c l_w Δθ / (2T)`, `Δθ = wrap(arg(u + i v) − θ)`: the angle from the
//! heading's unit vector to the command, so `wrap` is never needed.
//! Beyond the paper: the forward speed is `|u + i v| · max(cos Δθ, 0)`, so a robot facing
//! away from the command turns before it drives (the paper's robot started roughly aligned);
//! and both wheels are scaled by one factor when either exceeds the wheel limit, which
//! keeps the path's curvature while slowing down.

use crate::Point;

use crate::geometry::angle;

/// The drive's geometry and the steering gain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveConfig {
    /// `l_w`, m.
    pub wheel_base: f64,
    pub wheel_radius: f64,
    pub steps_per_rev: u32,
    pub microsteps: u32,
    /// Wheel rim speed limit, m/s.
    pub max_wheel_speed: f64,
    /// `K_c`.
    pub steering_gain: f64,
    /// `T`, s.
    pub sample_time: f64,
}

impl DriveConfig {
    /// Step pulses per metre of rim travel.
    pub fn pulses_per_metre(&self) -> f64 {
        f64::from(self.steps_per_rev) * f64::from(self.microsteps) / (std::f64::consts::TAU * self.wheel_radius)
    }
}

/// Wheel rim speeds, m/s (positive drives the robot forward).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WheelSpeeds {
    pub left: f64,
    pub right: f64,
}

/// Eq. 30 with the heading gate and wheel limits described in the module docs; `facing`
/// is the heading as a unit vector.
pub fn wheel_speeds(command: Point, facing: Point, cfg: &DriveConfig) -> WheelSpeeds {
    // (Its square: the length itself is not needed, and is zero or NaN exactly when it is.)
    let speed_sqr = command.norm_sqr();
    if speed_sqr.is_nan() || speed_sqr <= 0.0 || !(facing.re.is_finite() && facing.im.is_finite()) {
        return WheelSpeeds::default();
    }
    // The command seen from the heading: its angle is Δθ, its x is |u + i v| cos Δθ.
    let relative = command * facing.conj();
    let dtheta = angle(relative);
    let v = relative.re.max(0.0);
    let turn = cfg.steering_gain * cfg.wheel_base * dtheta / (2.0 * cfg.sample_time);
    let (left, right) = (v - turn, v + turn);
    let scale = (left.abs().max(right.abs()) / cfg.max_wheel_speed).max(1.0);
    WheelSpeeds { left: left / scale, right: right / scale }
}

/// Wheel speeds to signed pulse rates (pulses/s), rounded to the nearest pulse.
pub fn pulse_rates(w: WheelSpeeds, cfg: &DriveConfig) -> [i32; 2] {
    let ppm = cfg.pulses_per_metre();
    let max = f64::from(flowgate_protocol::motor::MAX_PULSE_RATE);
    [w.left, w.right].map(|v| (v * ppm).round().clamp(-max, max) as i32)
}

/// The pulse rates that stop a robot as the supervisor's brake does, from its wheels' rim
/// speeds now: both wheels lowered together until the centre stands (the boards' ramps take
/// both at one rate to targets equally far, so the turn holds and the centre keeps its arc),
/// then both to zero, turning on the spot. Zero at once would ramp each wheel down alone, the
/// slower first, and pivot the robot off the arc the supervisor certified, further by
/// `(v_r - v_l)² / 8a` along its path. Called each cycle of a stop; within a pulse a second
/// of standing it asks for zero.
pub fn braking_pulse_rates(wheels: [f64; 2], cfg: &DriveConfig) -> [i32; 2] {
    let centre = 0.5 * (wheels[0] + wheels[1]);
    if !centre.is_finite() || (centre * cfg.pulses_per_metre()).abs() <= 1.0 {
        return [0, 0];
    }
    pulse_rates(WheelSpeeds { left: wheels[0] - centre, right: wheels[1] - centre }, cfg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wrap_angle;
    use proptest::prelude::*;

    fn cfg() -> DriveConfig {
        DriveConfig {
            wheel_base: 0.108,
            wheel_radius: 0.02,
            steps_per_rev: 200,
            microsteps: 8,
            max_wheel_speed: 0.25,
            steering_gain: 0.06,
            sample_time: 0.02,
        }
    }

    #[test]
    fn equation_30() {
        let c = cfg();
        // Aligned: both wheels at the commanded speed.
        let w = wheel_speeds(Point::new(0.1, 0.0), Point::new(1.0, 0.0), &c);
        assert!((w.left - 0.1).abs() < 1e-12 && (w.right - 0.1).abs() < 1e-12);
        // Δθ = 0.2 rad to the left: right wheel faster by K_c l_w Δθ / T.
        let w = wheel_speeds(Point::from_polar(0.1, 0.2), Point::new(1.0, 0.0), &c);
        let turn = 0.06 * 0.108 * 0.2 / (2.0 * 0.02);
        assert!((w.right - w.left - 2.0 * turn).abs() < 1e-12);
        assert!((0.5 * (w.left + w.right) - 0.1 * 0.2f64.cos()).abs() < 1e-12);
    }

    #[test]
    fn pulse_rate_conversion() {
        // 200 steps x 8 microsteps per rev of a 2 cm wheel: 12732.4 pulses/m.
        let p = pulse_rates(WheelSpeeds { left: 0.1, right: -0.05 }, &cfg());
        assert_eq!(p, [1273, -637]);
    }

    #[test]
    fn braking_holds_the_turn_until_the_centre_stands() {
        let c = cfg();
        let ppm = c.pulses_per_metre();
        // Turning left at 0.1 m/s: both wheels go 0.1 m/s lower, the right one still forward.
        let [l, r] = braking_pulse_rates([0.08, 0.12], &c);
        assert_eq!([l, r], pulse_rates(WheelSpeeds { left: -0.02, right: 0.02 }, &c));
        assert!((f64::from(l + r)).abs() <= 1.0, "the centre's target is standing: {l} {r}");
        // Standing (within a pulse a second), turning on the spot: both to zero.
        assert_eq!(braking_pulse_rates([-0.02, 0.02 + 0.5 / ppm], &c), [0, 0]);
        // Backing up, straight: zero.
        assert_eq!(braking_pulse_rates([-0.1, -0.1], &c), [0, 0]);
        assert_eq!(braking_pulse_rates([f64::NAN, 0.1], &c), [0, 0]);
    }

    proptest! {
        #[test]
        fn wheel_limits_hold_and_curvature_is_kept(speed in 0.0..2.0f64, arg in -4.0..4.0f64, heading in -4.0..4.0f64) {
            let c = cfg();
            let w = wheel_speeds(Point::from_polar(speed, arg), Point::from_polar(1.0, heading), &c);
            prop_assert!(w.left.abs() <= c.max_wheel_speed + 1e-12 && w.right.abs() <= c.max_wheel_speed + 1e-12);
            prop_assert!(w.left.is_finite() && w.right.is_finite());
            // Turning toward the command: the sign of (right - left) follows Δθ.
            let dtheta = wrap_angle(arg - heading);
            if speed > 0.0 && dtheta.abs() > 1e-6 {
                prop_assert_eq!((w.right - w.left).signum(), dtheta.signum());
            }
        }
    }
}
