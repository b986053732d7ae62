//! The checks of the planner's mathematics (docs/planner.md, "The checks that prove the
//! terms"), as properties over random configurations.

use super::lane_series;
use super::*;
use proptest::prelude::*;
use std::f64::consts::PI;

fn sink(goal: Point) -> Sink {
    Sink { goal, strength: 0.1 * 0.14, c1: 20.0, reference_radius: 0.14 }
}

fn pt() -> impl Strategy<Value = Point> {
    (-1.0..1.0f64, -1.0..1.0f64).prop_map(|(x, y)| Point::new(x, y))
}

fn vel() -> impl Strategy<Value = Point> {
    (-0.3..0.3f64, -0.3..0.3f64).prop_map(|(x, y)| Point::new(x, y))
}

/// The normal speed of the flow at angle θ on obstacle `o`'s circle, minus the
/// obstacle's own normal speed: zero when the boundary condition holds.
fn boundary_residual(field: &Field, o: &PlanObstacle, theta: f64) -> f64 {
    let n = Point::from_polar(1.0, theta);
    let z = o.center + n * o.radius * (1.0 + 1e-11);
    let v = field.velocity(z).unwrap();
    (v * n.conj()).re - (o.velocity * n.conj()).re
}

/// Up to `n` non-overlapping obstacles with the goal outside all of them.
fn scene(n: usize) -> impl Strategy<Value = (Point, Vec<PlanObstacle>)> {
    (pt(), proptest::collection::vec((pt(), vel(), 0.05..0.25f64), n)).prop_filter_map(
        "overlapping obstacles or goal inside one",
        |(goal, raw)| {
            let obs: Vec<PlanObstacle> =
                raw.into_iter().map(|(center, velocity, radius)| PlanObstacle { center, velocity, radius }).collect();
            let apart = obs.iter().enumerate().all(|(i, a)| {
                (goal - a.center).norm() > a.radius * 1.05
                    && obs[..i].iter().all(|b| (a.center - b.center).norm() > (a.radius + b.radius) * 1.05)
            });
            apart.then_some((goal, obs))
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, max_global_rejects: 1 << 20, ..ProptestConfig::default() })]

    /// Check 1: single obstacle in free space, any K: the flow's normal speed on the circle
    /// equals the obstacle's.
    #[test]
    fn single_obstacle_boundary_condition((goal, obs) in scene(1), theta in 0.0..2.0 * PI, c1 in 1.0..100.0f64) {
        let field = Field::new(Space::Free, Sink { c1, ..sink(goal) }, &obs).unwrap();
        let scale = field.velocity(obs[0].center + obs[0].radius * 3.0).unwrap().norm() + obs[0].velocity.norm() + 1e-3;
        let r = boundary_residual(&field, &obs[0], theta);
        prop_assert!(r.abs() < 1e-6 * scale, "residual {r} (scale {scale})");
    }

    /// Check 1, blended: two to five obstacles with gap weights: exact on every circle.
    #[test]
    fn blended_boundary_condition_on_every_circle((goal, obs) in (2usize..=5).prop_flat_map(scene), theta in 0.0..2.0 * PI) {
        let field = Field::new(Space::Free, sink(goal), &obs).unwrap();
        for o in &obs {
            let r = boundary_residual(&field, o, theta);
            prop_assert!(r.abs() < 1e-5, "residual {r} on {o:?}");
        }
    }

    /// Check 2: the walls are streamlines of every lane term (v = 0 on y = ±h).
    #[test]
    fn walls_are_streamlines(h in 0.1..1.0f64, a in pt(), mu in vel(), x in -3.0..3.0f64) {
        let space = Space::Lane { half_width: h };
        let a = Point::new(a.re, a.im * h * 0.9);
        for y in [h, -h] {
            let z = Point::new(x, y);
            let s = space.sink(z, a);
            let d = space.doublet(z, a, mu);
            // F = u - i v: v = -Im F.
            prop_assert!(s.im.abs() < 1e-9 * (1.0 + s.norm()), "sink v = {}", s.im);
            prop_assert!(d.im.abs() < 1e-9 * (1.0 + d.norm()), "doublet v = {}", d.im);
        }
    }

    /// Check 2 on the whole lane field with two obstacles anywhere in the lane (near or across
    /// a wall too, with their series): the walls are streamlines to rounding, asserted at
    /// 2e-12 of the speed (2.7e-13 is the worst seen in 20,000 cases).
    #[test]
    fn lane_field_walls((a, r) in lane_circle(0.4), (b, rb) in lane_circle(0.4), (va, vb) in (vel(), vel()), x in -4.0..5.0f64) {
        let h = 0.4;
        let obs = [
            PlanObstacle { center: a, velocity: va, radius: r },
            PlanObstacle { center: b + 1.0, velocity: vb, radius: rb },
        ];
        prop_assume!((obs[0].center - obs[1].center).norm() > 1.3 * (r + rb) + 0.05);
        let goal = Point::new(4.5, 0.0);
        prop_assume!(obs.iter().all(|o| (goal - o.center).norm() > 1.5 * o.radius));
        let field = Field::new(Space::Lane { half_width: h }, sink(goal), &obs).unwrap();
        // 1e-15 h inside the wall (the field is not defined on it): the normal flow there
        // is at most that times its gradient, far below the bound.
        for y in [h * (1.0 - 1e-15), -h * (1.0 - 1e-15)] {
            let z = Point::new(x, y);
            if field.obstacles().iter().all(|o| (z - o.center).norm() > o.radius + 0.01) {
                let f = field.eval(z).unwrap();
                prop_assert!(f.im.abs() <= 2e-12 * f.norm().max(0.1), "v = {:e} at {z} (|F| = {})", f.im, f.norm());
            }
        }
    }

    /// Check 3: the closed forms equal truncated sums of wall images (period 4ih).
    #[test]
    fn closed_forms_match_image_sums(h in 0.2..0.6f64, a in pt(), z in pt(), mu in vel()) {
        let a = Point::new(a.re, a.im * h * 0.9);
        let z = Point::new(z.re, z.im * h * 0.9);
        prop_assume!((z - a).norm() > 0.05);
        let lane = Space::Lane { half_width: h };
        let n = 20_000;
        let (mut sink_sum, mut doublet_sum) = (Point::default(), Point::default());
        for k in -n..=n {
            let shift = Point::new(0.0, 4.0 * h * f64::from(k));
            let direct = a + shift; // the source and its translates
            let mirror = a.conj() + Point::new(0.0, 2.0 * h) + shift; // its mirror images
            sink_sum += -(z - direct).inv() - (z - mirror).inv();
            doublet_sum += mu / ((z - direct) * (z - direct)) + mu.conj() / ((z - mirror) * (z - mirror));
        }
        let s = lane.sink(z, a);
        let d = lane.doublet(z, a, mu);
        prop_assert!((s - sink_sum).norm() < 1e-3 * s.norm().max(1.0), "sink {s} vs sum {sink_sum}");
        prop_assert!((d - doublet_sum).norm() < 1e-3 * d.norm().max(1.0), "doublet {d} vs sum {doublet_sum}");
    }

    /// Check 4: far away the free-space speed with K tends to m/R.
    #[test]
    fn far_field_speed(((goal, obs), dir) in (scene(1), 0.0..2.0 * PI)) {
        let s = sink(goal);
        let field = Field::new(Space::Free, s, &obs).unwrap();
        let z = goal + Point::from_polar(1e4, dir);
        let speed = field.velocity(z).unwrap().norm();
        let expect = s.strength / s.reference_radius;
        prop_assert!((speed - expect).abs() < 1e-3 * expect, "{speed} vs {expect}");
    }

    /// No configuration the planner accepts gives a NaN or infinite command.
    #[test]
    fn commands_are_always_finite((goal, obs) in (0usize..=4).prop_flat_map(scene), z in pt(), lane in proptest::option::of(1.0..3.0f64)) {
        let space = lane.map_or(Space::Free, |half_width| Space::Lane { half_width });
        if let Ok(field) = Field::new(space, sink(goal), &obs) {
            if let Ok(v) = field.velocity(z) {
                prop_assert!(v.re.is_finite() && v.im.is_finite(), "{v} at {z}");
            }
        }
    }
}

/// Check 5: goal far on +x, obstacle at the origin: the field vanishes at z = ±R.
#[test]
fn stagnation_points() {
    let r = 0.14;
    let obs = [PlanObstacle { center: Point::default(), velocity: Point::default(), radius: r }];
    let field = Field::new(Space::Free, sink(Point::new(1e7, 0.0)), &obs).unwrap();
    let scale = field.velocity(Point::new(0.0, 5.0 * r)).unwrap().norm();
    for x in [-r, r] {
        let v = field.velocity(Point::new(x * (1.0 + 1e-9), 0.0)).unwrap();
        assert!(v.norm() < 1e-6 * scale, "speed {} at {x}", v.norm());
    }
    // The rear point is a saddle: on the axis the flow runs into it, off the axis past it.
    let on_axis = field.velocity(Point::new(-3.0 * r, 0.0)).unwrap();
    assert!(on_axis.re > 0.0 && on_axis.im.abs() < 1e-12);
}

/// Check 6: goal within R of an obstacle centre is reported, never garbage.
#[test]
fn goal_inside_obstacle_is_an_error() {
    let obs = [PlanObstacle { center: Point::new(0.5, 0.0), velocity: Point::default(), radius: 0.14 }];
    let err = Field::new(Space::Free, sink(Point::new(0.6, 0.0)), &obs).unwrap_err();
    assert_eq!(err, FieldError::GoalInsideObstacle { index: 0 });
}

#[test]
fn invalid_inputs_are_typed_errors() {
    let o = PlanObstacle { center: Point::new(0.5, 0.0), velocity: Point::default(), radius: 0.14 };
    let goal = Point::new(1.0, 0.0);
    assert_eq!(Field::new(Space::Lane { half_width: 0.0 }, sink(goal), &[o]).unwrap_err(), FieldError::BadLane(0.0));
    let nan = PlanObstacle { center: Point::new(f64::NAN, 0.0), ..o };
    assert_eq!(Field::new(Space::Free, sink(goal), &[nan]).unwrap_err(), FieldError::NonFinite);
    let field = Field::new(Space::Free, sink(goal), &[o]).unwrap();
    assert_eq!(field.eval(Point::new(0.45, 0.0)).unwrap_err(), FieldError::InsideObstacle { index: 0 });
    assert_eq!(field.eval(Point::new(f64::INFINITY, 0.0)).unwrap_err(), FieldError::NonFinite);
    assert_eq!(field.eval(goal).unwrap(), Point::default());
    let lane = Field::new(Space::Lane { half_width: 0.2 }, sink(goal * 0.1), &[]).unwrap();
    assert_eq!(lane.eval(Point::new(0.0, 0.3)).unwrap_err(), FieldError::OutsideLane);
    let too_many = [o; MAX_OBSTACLES + 1];
    assert_eq!(Field::new(Space::Free, sink(goal), &too_many).unwrap_err(), FieldError::TooManyObstacles);
    // A lane's aim out of range is refused, not clamped, and the field keeps its own.
    let mut lane = Field::empty(Space::Lane { half_width: 0.2 }, sink(goal * 0.1));
    assert_eq!(lane.set_lane_aim(1e-3).unwrap_err(), FieldError::BadLaneAim(1e-3));
    assert!(matches!(lane.set_lane_aim(f64::NAN), Err(FieldError::BadLaneAim(a)) if a.is_nan()));
    assert_eq!(FieldError::BadLaneAim(1e-3).to_string(), "the lane's aim 1e-3 is outside 1e-10 to 1e-4");
    let obs = [PlanObstacle { center: Point::new(-0.3, 0.0), velocity: Point::new(-0.05, 0.0), radius: 0.14 }];
    lane.rebuild(Space::Lane { half_width: 0.2 }, sink(goal * 0.1), &obs).unwrap();
    let exact = Field::new(Space::Lane { half_width: 0.2 }, sink(goal * 0.1), &obs).unwrap();
    assert_eq!(lane.lane_orders(0), exact.lane_orders(0), "the refused aims left the exact one");
    lane.set_lane_aim(1e-4).unwrap();
}

/// The worst normal-flow residual on obstacle `o`'s circle (its part inside the lane),
/// over 720 points, relative to the largest flow speed met on the circle.
fn worst_residual(field: &Field, o: &PlanObstacle) -> f64 {
    let h = match field.space() {
        Space::Lane { half_width } => half_width,
        Space::Free => f64::INFINITY,
    };
    let (mut worst, mut scale) = (0.0f64, 0.0f64);
    for d in 0..720 {
        let theta = f64::from(d) * PI / 360.0;
        let z = o.center + Point::from_polar(o.radius * (1.0 + 1e-11), theta);
        if z.im.abs() < h * (1.0 - 1e-9) {
            worst = worst.max(boundary_residual(field, o, theta).abs());
            scale = scale.max(field.velocity(z).unwrap().norm());
        }
    }
    worst / scale.max(o.velocity.norm()).max(1e-12)
}

/// E2's geometry (R = 14 cm in h = 20 cm, a 70% blockage), a centred 90% blockage standing
/// and moving, and a small circle near a wall, each against [`lane_sink`].
fn lane_circles() -> [PlanObstacle; 4] {
    [
        (Point::new(0.0, 0.0), 0.14, Point::new(-0.056, 0.0)),
        (Point::new(0.2, 0.0), 0.18, Point::default()),
        (Point::new(0.2, 0.0), 0.18, Point::new(-0.05, 0.03)),
        (Point::new(0.0, 0.03), 0.03, Point::new(0.1, 0.0)),
    ]
    .map(|(center, radius, velocity)| PlanObstacle { center, velocity, radius })
}

/// The goal sink 0.8 m along the lane, at E2's strength.
fn lane_sink() -> Sink {
    Sink { goal: Point::new(0.8, 0.0), strength: 0.1 * 0.14, c1: 20.0, reference_radius: 0.14 }
}

/// `planner.lane_residual`: the same circles, fitted to the loosest aim (a rig's default),
/// stay within it with at most two thirds of the orders (a cheaper cycle).
#[test]
fn a_looser_lane_aim_holds_its_residual_with_fewer_orders() {
    let lane = Space::Lane { half_width: 0.2 };
    for obs in lane_circles() {
        let (centre, radius, s) = (obs.center, obs.radius, lane_sink());
        let mut field = Field::empty(lane, s);
        field.set_lane_aim(1e-4).unwrap();
        field.rebuild(lane, s, &[obs]).unwrap();
        let worst = worst_residual(&field, &obs);
        let exact = Field::new(lane, s, &[obs]).unwrap();
        let (loose, tight) = (field.lane_orders(0).unwrap(), exact.lane_orders(0).unwrap());
        eprintln!("R = {radius} m at {centre}: {worst:.1e} of the local speed with {loose} orders ({tight} at 1e-8)");
        assert!(worst < 1e-4, "R = {radius} at {centre}: {worst:.2e}");
        assert!(3 * loose <= 2 * tight, "{loose} orders, {tight} at 1e-8");
    }
}

/// The lane's exact boundaries: E2's geometry (R = 14 cm in h = 20 cm, a 70% blockage)
/// and a centred 90% blockage, standing and moving: the residual is at the fit's level.
#[test]
fn lane_circle_residual_is_at_the_fit_level() {
    let lane = Space::Lane { half_width: 0.2 };
    for obs in lane_circles() {
        let (centre, radius, s) = (obs.center, obs.radius, lane_sink());
        let field = Field::new(lane, s, &[obs]).unwrap();
        let worst = worst_residual(&field, &obs);
        eprintln!("lane circle residual, R = {radius} m at {centre}, h = 0.2 m: {worst:.1e} of the local speed");
        assert!(worst < 1e-6, "R = {radius} at {centre}: {worst:.2e}");
        // The field's own measure (what `examples/lane_residuals.rs` prints) agrees.
        let own = field.circle_residual(0, 720).unwrap();
        assert!(own < 1e-6 && own > 0.1 * worst, "circle_residual {own:.2e} vs {worst:.2e}");
        assert!(field.circle_residual(1, 720).is_none());
    }
}

fn planner(tie_break: Option<TieBreak>) -> Planner {
    Planner::new(PlannerConfig {
        space: Space::Free,
        cruise_speed: 0.1,
        c1: 20.0,
        reference_radius: 0.14,
        max_speed: 0.15,
        margin: Margin::None,
        uncertainty_sigmas: 1.0,
        clearance: 0.0,
        tie_break,
        anticipation: 0.0,
        lane_residual: crate::planner::lane_series::EXACT_AIM,
    })
}

/// The symmetric head-on case: without the tie-break every term is real on the axis and
/// the command has no lateral part; with it, the command turns the robot to its right
/// (keep right), deterministically.
#[test]
fn tie_break_breaks_the_symmetric_case() {
    let obstacles = [ObstacleEstimate::exact(Point::new(0.0, 0.0), Point::new(-0.05, 0.0), 0.07)];
    let input = PlanInput {
        position: Point::new(-0.4, 0.0),
        goal: Point::new(0.6, 0.0),
        robot_radius: 0.07,
        obstacles: &obstacles,
        delay: 0.0,
    };
    let plain = planner(None).plan(&input).unwrap();
    assert_eq!(plain.velocity.im, 0.0);
    let broken = planner(Some(TieBreak::default())).plan(&input).unwrap();
    assert!(broken.flags.tie_break);
    assert!(broken.velocity.im < -1e-4, "expected a push to the right (−y), got {}", broken.velocity);
    // Off the axis, outside the cone, the tie-break leaves the field alone.
    let off = PlanInput { position: Point::new(-0.4, 0.2), ..input };
    let tb = planner(Some(TieBreak::default())).plan(&off).unwrap();
    assert!(!tb.flags.tie_break);
    assert_eq!(tb.velocity, planner(None).plan(&off).unwrap().velocity);
}

/// In a lane, an obstacle coming head-on and drifting to one side is passed on the side it
/// leaves: the robot is steered toward that side while still far off, where the field on
/// the obstacle as it stands (anticipation off) keeps right whatever the drift. With no
/// drift, anticipation changes nothing and the tie-break keeps right; in free space it is
/// not used.
#[test]
fn a_drifting_obstacle_in_a_lane_is_passed_on_the_side_it_leaves() {
    let lane = |anticipation| {
        Planner::new(PlannerConfig {
            space: Space::Lane { half_width: 0.2 },
            anticipation,
            ..*planner(Some(TieBreak::default())).config()
        })
    };
    let plan = |planner: &Planner, drift_y: f64| {
        let obstacles = [ObstacleEstimate::exact(Point::new(0.3, 0.02), Point::new(-0.056, drift_y), 0.07)];
        let input = PlanInput {
            position: Point::new(-0.3, 0.0),
            goal: Point::new(0.6, 0.0),
            robot_radius: 0.07,
            obstacles: &obstacles,
            delay: 0.0,
        };
        planner.plan(&input).unwrap().velocity
    };
    let (on, off) = (lane(3.0), lane(0.0));
    // Drifting toward the robot's right (−y): passed on its left (+y), though it starts a
    // little left of the robot's way.
    assert!(plan(&off, -0.02).im < 0.0, "{}", plan(&off, -0.02));
    assert!(plan(&on, -0.02).im > 0.0, "{}", plan(&on, -0.02));
    // Drifting toward the left: passed on the right, turning harder than on the obstacle
    // as it stands.
    assert!(plan(&on, 0.02).im < 2.0 * plan(&off, 0.02).im, "{} {}", plan(&on, 0.02), plan(&off, 0.02));
    // No drift: as without anticipation.
    assert_eq!(plan(&on, 0.0), plan(&off, 0.0));
    // Free space: not used.
    let free =
        |anticipation| Planner::new(PlannerConfig { anticipation, ..*planner(Some(TieBreak::default())).config() });
    assert_eq!(plan(&free(3.0), -0.02), plan(&free(0.0), -0.02));
}

#[test]
fn margins() {
    assert_eq!(Margin::None.radius(0.14, 0.1, 0.6), 0.14);
    assert!((Margin::Factor { factor: 1.1 }.radius(0.14, 0.1, 0.6) - 0.154).abs() < 1e-12);
    assert!((Margin::Fixed { metres: 0.02 }.radius(0.14, 0.1, 0.6) - 0.16).abs() < 1e-12);
    assert!((Margin::Delay { extra_speed: 0.0 }.radius(0.14, 0.141, 0.6) - (0.14 + 0.141 * 0.6)).abs() < 1e-12);
}

#[test]
fn saturation_keeps_direction() {
    let obstacles = [ObstacleEstimate::exact(Point::new(0.3, 0.3), Point::new(0.0, -0.2), 0.07)];
    let input = PlanInput {
        position: Point::new(-2.0, 0.0),
        goal: Point::new(2.0, 0.0),
        robot_radius: 0.07,
        obstacles: &obstacles,
        delay: 0.0,
    };
    let p = Planner::new(PlannerConfig { cruise_speed: 0.5, ..*planner(None).config() }).plan(&input).unwrap();
    assert!(p.flags.saturated);
    assert!((p.velocity.norm() - 0.15).abs() < 1e-12);
    assert!((p.velocity.arg() - p.field.arg()).abs() < 1e-12);
}

/// A circle in a lane of half-width `h`: (centre, radius) with the centre anywhere inside
/// the lane and `R` up to 90% of `h`.
fn lane_circle(h: f64) -> impl Strategy<Value = (Point, f64)> {
    (-3.0..3.0f64, -1.0..1.0f64, 0.02..0.9f64).prop_map(move |(x, y, r)| (Point::new(x, y * h * 0.999), r * h))
}

/// The gap to the nearer wall over the radius below which a circle is closed against the
/// wall (see `field::in_lane`): 1/10.
const CLOSED_BELOW: f64 = super::field::WALL_CLOSE;

/// A circle near a wall, closed against it: the gap to the nearer wall anywhere from R/10
/// down to minus R (the centre on the wall).
fn near_wall_circle(h: f64) -> impl Strategy<Value = (Point, f64)> {
    (-3.0..3.0f64, 0.0..1.0f64, any::<bool>(), 0.02..0.9f64).prop_map(move |(x, u, up, r)| {
        let y = (1.0 - u * r * (1.0 + CLOSED_BELOW)).max(0.0) * h;
        (Point::new(x, if up { y } else { -y } * 0.99999), r * h)
    })
}

/// A circle clear of the walls in a lane of half-width `h`: a gap to the walls of R/10 or
/// more, up to a 90% blockage of the lane.
fn clear_lane_circle(h: f64) -> impl Strategy<Value = (Point, f64)> {
    (-3.0..3.0f64, -1.0..1.0f64, 0.02..0.9f64)
        .prop_map(move |(x, y, r)| (Point::new(x, y * (1.0 - r * (1.0 + CLOSED_BELOW)) * h), r * h))
}

/// The band where the lane series is held to 1e-6: a convergence rate (see
/// [`lane_series::convergence_rate`]) up to 0.65. It holds every circle clear of the walls
/// (a wall at least 1.1 R away, rate 0.64; a 90% blockage of the lane has 0.63) whose
/// goal and neighbours' wall images lie beyond R/0.65 = 1.54 R of its centre.
const CONVERGENT: f64 = 0.65;

proptest! {
    // 256 cases unless PROPTEST_CASES says otherwise.
    #![proptest_config(ProptestConfig { max_global_rejects: 1 << 20, ..ProptestConfig::default() })]

    /// Point 2 of the planner issue: clear of the walls, every circle is a streamline of
    /// the lane field to 1e-6 of the flow's speed, standing or moving, with the goal
    /// anywhere in the lane outside it, alone or with a second obstacle.
    #[test]
    fn lane_circles_are_exact_clear_of_the_walls(
        h in 0.1..1.0f64,
        (a, b) in (clear_lane_circle(1.0), clear_lane_circle(1.0)),
        (va, vb) in (vel(), vel()),
        goal in pt(),
        two in any::<bool>(),
    ) {
        let (a, b) = ((a.0 * h, a.1 * h), (b.0 * h, b.1 * h));
        let goal = Point::new(goal.re * 3.0 * h, goal.im * h * 0.99);
        let mut obs = vec![PlanObstacle { center: a.0, velocity: va, radius: a.1 }];
        if two {
            obs.push(PlanObstacle { center: b.0, velocity: vb, radius: b.1 });
            prop_assume!((a.0 - b.0).norm() > 1.05 * (a.1 + b.1));
        }
        prop_assume!(obs.iter().all(|o| (goal - o.center).norm() > 1.05 * o.radius));
        for (k, o) in obs.iter().enumerate() {
            let others = obs.iter().enumerate().filter(|&(j, _)| j != k).map(|(_, p)| p.center).chain([goal]);
            prop_assume!(lane_series::convergence_rate(h, o.center, o.radius, others) <= CONVERGENT);
        }
        let field = Field::new(Space::Lane { half_width: h }, sink(goal), &obs).unwrap();
        for o in field.obstacles() {
            let worst = worst_residual(&field, o);
            prop_assert!(worst < 1e-6, "residual {worst:.2e} on {o:?} (h = {h})");
        }
    }

    /// Points 1 and 2: near a wall (a gap under R/10, touching, or across it) the circle is
    /// closed against the wall: centred on it, covering the true circle, sliding along it
    /// with the obstacle. It meets the wall at right angles, so the corner is no
    /// singularity: reflected in the wall the circle is whole, in a lane twice as wide,
    /// where its series converges as a circle's clear of the walls does. Every such circle,
    /// up to a true blockage of 90% right at a wall (a closed one of 95%), with the goal far
    /// downstream or near it in the band of [`CONVERGENT`], is a streamline to 1e-6 (the
    /// worst seen in 20,000 cases is 6.4e-8; 3.7e-7 across the grid of the planner's
    /// documentation). A closure that crossed the wall at an angle would leave a corner no
    /// series converges at (residuals of 2e-2), one that ignored the wall a field pointing
    /// into the obstacle.
    #[test]
    fn lane_circles_near_a_wall_are_exact(
        h in 0.1..1.0f64,
        (a, r) in near_wall_circle(1.0),
        v in vel(),
        goal in pt(),
        far in any::<bool>(),
    ) {
        let (a, r) = (a * h, r * h);
        prop_assume!(h - a.im.abs() - r < CLOSED_BELOW * r); // what is closed
        // The goal anywhere in the lane near the circle (or downstream, far from it).
        let goal = if far { Point::new(a.re + 3.0 * h, 0.0) } else { Point::new(a.re + goal.re * 3.0 * h, goal.im * h * 0.99) };
        prop_assume!((goal - a).norm() > 1.3 * r);
        let obs = [PlanObstacle { center: a, velocity: v, radius: r }];
        let field = Field::new(Space::Lane { half_width: h }, sink(goal), &obs).unwrap();
        let planned = field.obstacles()[0];
        prop_assume!(!field.unclosed_at_a_wall()); // the closure would take in the goal
        // A goal near the circle: within the band where the series is held to 1e-6 (its
        // image in the far wall beyond 1.54 R; its image in this wall is in the flow the
        // series corrects). Far from it, every closed circle, up to a 95% closed blockage.
        let rate = lane_series::convergence_rate(h, planned.center, planned.radius, [goal].into_iter());
        prop_assume!(far || rate <= CONVERGENT);
        prop_assert!((planned.center - a).norm() + r <= planned.radius + 1e-12, "the planned circle covers the true one");
        prop_assert_eq!(planned.center.im.abs(), h, "centred on the wall");
        prop_assert_eq!(planned.velocity, Point::new(v.re, 0.0), "sliding along it");
        let worst = worst_residual(&field, &planned);
        prop_assert!(worst < 1e-6, "residual {worst:.2e} on {planned:?} (h = {h})");
    }

    /// Point 1: a standing obstacle anywhere in the lane is never entered by a robot that
    /// follows the field (at up to 15 cm/s, 20 ms steps) from anywhere upstream. Planning
    /// circles are at least 2 cm (a robot's radius alone is more): seven steps across, so a
    /// step cannot jump a tangent path over a circle's edge; entering by more than 0.1 mm
    /// fails.
    #[test]
    fn standing_obstacles_are_never_entered(h in 0.1..0.5f64, (a, r) in lane_circle(1.0), y0 in -1.0..1.0f64) {
        let (a, r) = (Point::new(0.0, a.im * h), (r * h).max(0.02));
        prop_assume!(r < 0.9 * h);
        let goal = Point::new(a.re + 3.0 * h + r, 0.0);
        let obs = [PlanObstacle { center: a, velocity: Point::default(), radius: r }];
        let field = Field::new(Space::Lane { half_width: h }, sink(goal), &obs).unwrap();
        let planned = field.obstacles()[0];
        let mut z = Point::new(a.re - r - 2.0 * h, y0 * h * 0.95);
        prop_assume!((z - planned.center).norm() > planned.radius);
        for _ in 0..3000 {
            let v = match field.velocity(z) {
                Ok(v) => v,
                // Within the tolerance below, at the stagnation point: it went no further.
                Err(FieldError::InsideObstacle { .. }) if (z - a).norm() > r - 1e-4 => break,
                Err(e) => return Err(TestCaseError::fail(format!("{e} at {z} (planned {planned:?}, h = {h})"))),
            };
            let v = if v.norm() > 0.15 { v * (0.15 / v.norm()) } else { v };
            z += v * 0.02;
            // A robot that converges on the front stagnation point can step past it by
            // micrometres (where the lane flow is fast, the command there, rate × distance,
            // has rate × step above 1): 0.1 mm is the tolerance for that, not for the field.
            prop_assert!((z - a).norm() > r - 1e-4, "entered the obstacle at {z}");
            if (z - goal).norm() < 0.01 {
                break;
            }
        }
    }
}

/// Never freeze inside a margin: a robot inside an obstacle's planning circle but outside
/// the true one gets the circle shrunk to just short of it and a command; one inside the
/// true circle (a contact) is still refused. A goal inside a margin likewise.
#[test]
fn a_robot_inside_a_margin_is_steered_not_frozen() {
    let planner = Planner::new(PlannerConfig { margin: Margin::Factor { factor: 1.5 }, ..*planner(None).config() });
    let obstacles = [ObstacleEstimate::exact(Point::new(0.0, 0.0), Point::new(0.0, 0.05), 0.07)];
    // R_0 = 0.14, planned at 0.21; the robot at 0.17 from the centre, off the axis.
    let at = Point::from_polar(0.17, 2.5);
    let input =
        PlanInput { position: at, goal: Point::new(1.0, 0.0), robot_radius: 0.07, obstacles: &obstacles, delay: 0.0 };
    let mut planned = arrayvec::ArrayVec::new();
    let flags = planner.plan_obstacles(&input, &mut planned).unwrap();
    assert!(flags.margin_shrunk);
    assert!((planned[0].radius - (0.17 - SHRUNK_GAP)).abs() < 1e-12, "{}", planned[0].radius);
    let plan = planner.plan(&input).unwrap();
    assert!(plan.flags.margin_shrunk && plan.velocity.norm() > 0.0);
    // Relative to the obstacle the flow slides round the circle a millimetre away: its
    // normal part is under a tenth of it (it is zero on the circle itself).
    let relative = plan.field - obstacles[0].velocity;
    let normal = (relative * at.conj()).re / at.norm();
    assert!(normal.abs() < 0.1 * relative.norm(), "normal {normal} of {relative}");
    // Inside the true circle: refused.
    let inside = PlanInput { position: Point::from_polar(0.13, 2.5), ..input };
    assert_eq!(planner.plan(&inside).unwrap_err(), FieldError::InsideObstacle { index: 0 });
    // A goal inside the margin: shrunk likewise; inside the true circle: refused.
    let near_goal = PlanInput { position: Point::new(-1.0, 0.0), goal: Point::from_polar(0.18, 0.5), ..input };
    planner.plan_obstacles(&near_goal, &mut planned).unwrap();
    assert!((planned[0].radius - (0.18 - SHRUNK_GAP)).abs() < 1e-12, "{}", planned[0].radius);
    assert!(planner.plan(&near_goal).is_ok());
    let blocked = PlanInput { goal: Point::from_polar(0.12, 0.5), ..near_goal };
    assert_eq!(planner.plan(&blocked).unwrap_err(), FieldError::GoalInsideObstacle { index: 0 });
    // Outside the margin: untouched.
    let outside = PlanInput { position: Point::from_polar(0.3, 2.5), ..input };
    planner.plan_obstacles(&outside, &mut planned).unwrap();
    assert!((planned[0].radius - 0.21).abs() < 1e-12);
}

/// A vehicle inside another's spacing, the other behind it and its goal ahead, gives the
/// spacing up whole: shrunk to a millimetre short of it, as any margin, it would sit by the
/// still point of the circle's flow facing the goal and crawl. Ahead of the other, its
/// goal beyond it, the spacing is shrunk as before.
#[test]
fn a_vehicle_leaving_another_gives_up_its_spacing_rather_than_crawl() {
    let planner = planner(None);
    // The fleet's spacing round a vehicle of 7 cm standing at the origin; ours 17 cm off.
    let other = [ObstacleEstimate { keep: 0.04, ..ObstacleEstimate::exact(Point::default(), Point::default(), 0.07) }];
    let at = Point::new(0.17, 0.0);
    let leaving =
        PlanInput { position: at, goal: Point::new(0.6, 0.0), robot_radius: 0.07, obstacles: &other, delay: 0.0 };
    let mut planned = arrayvec::ArrayVec::new();
    assert!(planner.plan_obstacles(&leaving, &mut planned).unwrap().margin_shrunk);
    assert!((planned[0].radius - 0.14).abs() < 1e-12, "{}", planned[0].radius);
    let speed = planner.plan(&leaving).unwrap().velocity.norm();
    // Hugging the spacing's edge a millimetre off, the flow there is a few mm/s.
    let mut hugging = Field::empty(Space::Free, planner.sink(leaving.goal));
    let edge = PlanObstacle { center: Point::default(), velocity: Point::default(), radius: 0.17 - SHRUNK_GAP };
    hugging.rebuild_clear_of(Space::Free, planner.sink(leaving.goal), &[edge], Some(at)).unwrap();
    let crawl = hugging.velocity(at).unwrap().norm();
    assert!(crawl < 0.005 && speed > 0.03, "given up: {speed} m/s; hugging its edge: {crawl} m/s");
    // The other beside it (its goal square to the way from the other: the flow slides it
    // along the edge), or ahead of it: the spacing is kept, shrunk to just short of it.
    for goal in [Point::new(0.17, 0.6), Point::new(-0.6, 0.3)] {
        planner.plan_obstacles(&PlanInput { goal, ..leaving }, &mut planned).unwrap();
        assert!((planned[0].radius - (0.17 - SHRUNK_GAP)).abs() < 1e-12, "{goal}: {}", planned[0].radius);
    }
    // Within 60° of straight behind: given up.
    let goal = at + Point::from_polar(0.4, 0.9 * PI / 3.0);
    planner.plan_obstacles(&PlanInput { goal, ..leaving }, &mut planned).unwrap();
    assert!((planned[0].radius - 0.14).abs() < 1e-12, "{}", planned[0].radius);
    // An obstacle without a spacing (a single robot's) behind: shrunk as before.
    let obstacle = [ObstacleEstimate { keep: 0.0, ..other[0] }];
    let margin = Planner::new(PlannerConfig { margin: Margin::Factor { factor: 1.5 }, ..*planner.config() });
    margin.plan_obstacles(&PlanInput { obstacles: &obstacle, ..leaving }, &mut planned).unwrap();
    assert!((planned[0].radius - (0.17 - SHRUNK_GAP)).abs() < 1e-12, "{}", planned[0].radius);
}

/// The planning radius grows by the configured standard deviations of the predicted
/// centre, and by the supervisor's margin.
#[test]
fn the_margin_includes_the_prediction_uncertainty() {
    let planner = Planner::new(PlannerConfig { uncertainty_sigmas: 2.0, clearance: 0.006, ..*planner(None).config() });
    let obstacles = [ObstacleEstimate {
        position_sd: 0.01,
        ..ObstacleEstimate::exact(Point::new(0.0, 0.0), Point::default(), 0.07)
    }];
    let input = PlanInput {
        position: Point::new(-1.0, 0.0),
        goal: Point::new(1.0, 0.0),
        robot_radius: 0.07,
        obstacles: &obstacles,
        delay: 0.0,
    };
    let mut planned = arrayvec::ArrayVec::new();
    planner.plan_obstacles(&input, &mut planned).unwrap();
    assert!((planned[0].radius - (0.14 + 0.02 + 0.006)).abs() < 1e-12, "{}", planned[0].radius);
}

/// The field a report draws is the one the robot follows: a robot between an obstacle and
/// the wall it nearly touches keeps the circle unclosed in both (closing it against the
/// wall would take the robot in).
#[test]
fn the_drawn_field_is_the_planned_one() {
    let planner = Planner::new(PlannerConfig {
        space: Space::Lane { half_width: 0.2 },
        uncertainty_sigmas: 0.0,
        ..*planner(None).config()
    });
    // R_0 = 0.08 at y = 0.115: 5 mm from the wall, which closes the circle against it
    // unless that would take in the robot, 2 mm outside the circle by the wall.
    let obstacles = [ObstacleEstimate::exact(Point::new(0.0, 0.115), Point::default(), 0.05)];
    let input = PlanInput {
        position: Point::new(0.0, 0.197),
        goal: Point::new(1.0, 0.0),
        robot_radius: 0.03,
        obstacles: &obstacles,
        delay: 0.0,
    };
    let plan = planner.plan(&input).unwrap();
    let (field, _) = planner.field(&input).unwrap();
    assert_eq!(field.velocity(input.position).unwrap(), plan.field);
    assert!((field.obstacles()[0].radius - 0.08).abs() < 1e-12, "left as planned");
    assert!(plan.flags.unclosed_at_a_wall && field.unclosed_at_a_wall(), "and said so");
    // Elsewhere the same circle is closed against the wall, in both.
    let away = PlanInput { position: Point::new(-0.6, 0.0), ..input };
    let (field, _) = planner.field(&away).unwrap();
    assert!(field.obstacles()[0].radius > 0.08, "closed");
    assert!(!field.unclosed_at_a_wall() && !planner.plan(&away).unwrap().flags.unclosed_at_a_wall);
    assert_eq!(field.velocity(away.position).unwrap(), planner.plan(&away).unwrap().field);
}

/// A field rebuilt in place (its fit workspace kept from the build before, uncleared) is
/// the field built afresh, bit for bit, whatever the build before fitted: each of the
/// three kinds of series (a circle clear of the walls, one closed against a wall, one
/// left unclosed at a wall with its regularised arc fit) after each of the others.
#[test]
fn a_rebuilt_field_is_the_fresh_one() {
    let (h, goal) = (0.2, Point::new(1.0, 0.0));
    // By the wall, between it and a circle across it: closing that circle would take it in.
    let robot = Point::new(0.1, 0.19);
    let circle = |x: f64, y: f64, r: f64| PlanObstacle {
        center: Point::new(x, y),
        velocity: Point::new(-0.05, 0.01),
        radius: r,
    };
    let scenes: [&[PlanObstacle]; 4] = [
        &[circle(0.3, 0.0, 0.08)],                           // clear of the walls
        &[circle(0.6, 0.08, 0.11)],                          // closed against the wall
        &[circle(0.0, 0.15, 0.08)],                          // across the wall, left unclosed
        &[circle(0.3, -0.05, 0.06), circle(0.5, 0.1, 0.09)], // two at once
    ];
    let space = Space::Lane { half_width: h };
    let fresh = |obstacles: &[PlanObstacle]| {
        let mut field = Field::empty(space, sink(goal));
        field.rebuild_clear_of(space, sink(goal), obstacles, Some(robot)).unwrap();
        field
    };
    assert!(fresh(scenes[2]).unclosed_at_a_wall() && !fresh(scenes[1]).unclosed_at_a_wall());
    let probes = [Point::new(-0.3, 0.05), Point::new(0.3, 0.19), Point::new(0.7, -0.15), Point::new(0.1, -0.1)];
    for before in scenes {
        for after in scenes {
            let mut field = fresh(before);
            field.rebuild_clear_of(space, sink(goal), after, Some(robot)).unwrap();
            let expected = fresh(after);
            for z in probes {
                assert_eq!(field.eval(z), expected.eval(z), "{after:?} after {before:?} at {z}");
            }
        }
    }
}
