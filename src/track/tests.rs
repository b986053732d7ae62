use super::*;

#[test]
fn pose_from_leds_round_trips() {
    let g = LedGeometry { front: 0.04, rear: 0.02 };
    let pose = Pose { position: Point::new(0.1, -0.2), heading: 2.0 };
    let (f, r) = g.leds(pose.position, Point::from_polar(1.0, pose.heading));
    let back = g.pose(f, r).unwrap();
    assert!((back.position - pose.position).length() < 1e-12);
    assert!((back.heading - pose.heading).abs() < 1e-12);
    assert!(g.pose(f, f).is_none());
}

/// A noiseless constant-velocity target: the filter learns its velocity and predicts
/// ahead of the measurements.
#[test]
fn kalman_tracks_constant_velocity() {
    let v = Point::new(0.141, -0.05);
    let at = |t: f64| Point::new(-0.3, 0.2) + v * t;
    let mut kf = ConstantVelocityKf::new(KalmanConfig::default(), 0.0, at(0.0));
    for k in 1..=100 {
        let t = f64::from(k) * 0.02;
        assert!(kf.update(t, at(t)));
    }
    let (p, est_v) = kf.predict(2.0 + 0.6);
    assert!((est_v - v).length() < 2e-3, "{est_v}");
    assert!((p - at(2.6)).length() < 2e-3, "{p}");
    assert!(!kf.update(1.0, at(1.0)), "an older measurement is refused");
}

/// The per-axis filter is the textbook 4×4 one: run side by side on noisy, unevenly
/// timed measurements of a manoeuvring point, state and covariance agree to rounding.
#[test]
fn the_per_axis_filter_is_the_full_one() {
    use nalgebra::{Matrix2, Matrix2x4, Matrix4, Vector2, Vector4};
    let config = KalmanConfig::default();
    let (q, r) = (config.process_noise, config.measurement_noise.powi(2));
    let at = |t: f64| Point::new(0.3 * (0.7 * t).sin() - 0.1 * t, 0.2 * (1.1 * t).cos());
    let mut kf = ConstantVelocityKf::new(config, 0.0, at(0.0));
    let mut x = Vector4::new(at(0.0).re, at(0.0).im, 0.0, 0.0);
    let mut p = Matrix4::from_diagonal(&Vector4::new(r, r, 0.25, 0.25));
    let h = Matrix2x4::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0);
    let mut t = 0.0;
    for k in 1..=300 {
        let dt = 0.017 + 0.004 * f64::from(k % 5);
        t += dt;
        let wobble = 0.002 * (f64::from(k) * 2.3).sin();
        let z = at(t) + Point::new(wobble, -wobble);
        assert!(kf.update(t, z));
        let mut f = Matrix4::identity();
        f[(0, 2)] = dt;
        f[(1, 3)] = dt;
        let (a, b, c) = (dt.powi(3) / 3.0 * q, dt.powi(2) / 2.0 * q, dt * q);
        let process = Matrix4::new(a, 0.0, b, 0.0, 0.0, a, 0.0, b, b, 0.0, c, 0.0, 0.0, b, 0.0, c);
        x = f * x;
        p = f * p * f.transpose() + process;
        let s = h * p * h.transpose() + Matrix2::identity() * r;
        let gain = p * h.transpose() * s.try_inverse().unwrap();
        x += gain * (Vector2::new(z.re, z.im) - h * x);
        p = (Matrix4::identity() - gain * h) * p;
        let (position, velocity) = kf.predict(t);
        assert!((position - Point::new(x[0], x[1])).norm() < 1e-12, "{k}");
        assert!((velocity - Point::new(x[2], x[3])).norm() < 1e-10, "{k}");
        let cov = kf.position_covariance(t);
        assert!((cov[0] - p[(0, 0)]).abs() < 1e-12 * p[(0, 0)] && (cov[2] - p[(1, 1)]).abs() < 1e-12 * p[(1, 1)]);
        assert!(p[(0, 1)].abs() < 1e-18 && p[(0, 3)].abs() < 1e-18, "nothing between the axes");
        let (_, velocity_sd) = kf.uncertainty(t);
        assert!((velocity_sd - p[(2, 2)].sqrt()).abs() < 1e-12 * p[(2, 2)].sqrt(), "{k}");
    }
}

#[test]
fn low_pass_lags_a_ramp_by_its_time_constant() {
    // A first-order filter lags a ramp by τ = 1/(2π fc): 0.159 s at 1 Hz.
    let mut lp = LowPass::new(1.0);
    let dt = 0.001;
    let mut y = Point::default();
    for k in 0..20_000 {
        y = lp.filter(Point::new(f64::from(k) * dt, 0.0), dt);
    }
    let lag = 19_999.0 * dt - y.re;
    assert!((lag - 1.0 / std::f64::consts::TAU).abs() < 2e-3, "{lag}");
}

/// A pose is plausible only as far as the wheels could have moved and turned the robot
/// since the last one. A reflection of the front LED onto the far side of the rear one
/// keeps their spacing and moves the centre within the jump's reach a few frames on, but
/// turns the heading about: that is refused, and a true turn at the wheels' limit is not.
#[test]
fn a_pose_turned_further_than_the_wheels_can_turn_it_is_refused() {
    let Driving { geometry, mut tracker, reach, centre, front, rear, .. } = driving();
    // Driving, twelve frames later (0.2 s): the front LED read 13.3 cm back along x.
    let t = 1.2;
    let reflected = front - Point::new(0.133, 0.0);
    let moved = (geometry.locate(reflected, rear).unwrap().0 - centre).length();
    assert!(moved < reach.speed * 0.2 + reach.tolerance, "the centre alone is within reach ({moved} m)");
    match tracker.plausible(t, reflected, rear, reach) {
        Err(Implausible::Turn { turned, reach }) => assert!(turned > 2.5 && reach < 1.5, "{turned} {reach}"),
        other => panic!("the reflection was taken: {other:?}"),
    }
    // Both wheels at their limit, opposite ways, for 0.2 s: a true turn, taken.
    let turned = Point::from_polar(1.0, 0.18 + reach.turn_rate * 0.2);
    let (front, rear) = geometry.leds(centre, turned);
    assert_eq!(tracker.plausible(t, front, rear, reach), Ok(()));
}

/// A robot driving at 0.1 m/s, its pose seen at 1 s: the LEDs mounted 7 cm apart, the
/// rig's wheels (0.25 m/s, 10.8 cm apart), a pose tolerance of 2 cm.
struct Driving {
    geometry: LedGeometry,
    tracker: Tracker,
    reach: PoseReach,
    centre: Point,
    facing: Point,
    front: Point,
    rear: Point,
}

fn driving() -> Driving {
    let geometry = LedGeometry { front: 0.035, rear: 0.035 };
    let mut tracker = Tracker::new(settings(), geometry, &[]);
    let reach = PoseReach { speed: 0.25, turn_rate: 2.0 * 0.25 / 0.108, tolerance: 0.02 };
    let (centre, facing) = (Point::new(-0.2, -0.05), Point::from_polar(1.0, 0.18));
    let (front, rear) = geometry.leds(centre, facing);
    tracker.commanded(0.9, 0.1, 0.1);
    assert!(tracker.observe_robot(1.0, front, rear));
    Driving { geometry, tracker, reach, centre, facing, front, rear }
}

fn settings() -> TrackingSettings {
    TrackingSettings {
        predict_robot: true,
        wheel_accel: 1.0,
        predict_obstacles: true,
        kalman: KalmanConfig::default(),
        occluded_after: 0.15,
        max_obstacle_speed: 0.5,
    }
}

/// While the wheels are at rest a pose is checked against the last plausible one as far as
/// the wheels could have moved it before they stopped: however long the robot stands (its
/// pose forgotten at a stop, or not), a reflection is refused and the true pose taken. A
/// pose refused so that stands still for SETTLE is taken (the robot carried by hand).
#[test]
fn a_pose_seen_again_after_a_stop_is_where_the_wheels_left_it() {
    let Driving { geometry, mut tracker, reach, centre, facing, front, rear } = driving();
    tracker.halted(1.0);
    let reflected = front - Point::new(0.133, 0.0);
    for t in [1.5, 2.0, 2.9] {
        assert!(tracker.plausible(t, reflected, rear, reach).is_err(), "the reflection taken at {t} s");
    }
    tracker.forget_pose();
    assert!(tracker.plausible(2.95, reflected, rear, reach).is_err(), "the reflection taken with the pose forgotten");
    assert_eq!(tracker.plausible(3.0, front, rear, reach), Ok(()), "the true pose, where the wheels left it");
    // Carried 30 cm by hand and set down: refused until it has stood still for SETTLE.
    let carried = geometry.leds(centre + Point::new(0.3, 0.0), facing);
    assert!(matches!(tracker.plausible(3.1, carried.0, carried.1, reach), Err(Implausible::Jump { .. })));
    assert!(tracker.plausible(3.1 + SETTLE - 0.1, carried.0, carried.1, reach).is_err());
    assert_eq!(tracker.plausible(3.1 + SETTLE + 0.02, carried.0, carried.1, reach), Ok(()));
    // While the wheels drive, the reach grows with the time since the last pose.
    let mut moving = Tracker::new(settings(), geometry, &[]);
    assert!(moving.observe_robot(1.0, front, rear));
    moving.commanded(1.0, 0.25, 0.25);
    moving.forget_pose();
    let ahead = geometry.leds(centre + facing * 0.2, facing);
    assert_eq!(moving.plausible(2.0, ahead.0, ahead.1, reach), Ok(()));
}
