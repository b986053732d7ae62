use super::evasion::{evasion_candidates, nearest_clear, EVASION_SPARE};
use super::*;
use proptest::prelude::*;

/// A robot among one to three obstacles within a stop's reach, moving and uncertain, in
/// free space or near a lane's line.
#[derive(Debug, Clone)]
struct Scene {
    cfg: SupervisorConfig,
    position: Point,
    facing: Point,
    wheels: [f64; 2],
    predicted: Vec<ObstacleEstimate>,
}

impl Scene {
    fn judge<T>(&self, verdict: impl FnOnce(&Context<'_>) -> T) -> T {
        let mut hazards = ArrayVec::new();
        fill_hazards(&mut hazards, self.position, &self.cfg, &self.predicted);
        let ctx = Context {
            cfg: &self.cfg,
            position: self.position,
            facing: self.facing,
            wheels: self.wheels,
            hazards: &hazards,
        };
        verdict(&ctx)
    }
}

fn scene() -> impl Strategy<Value = Scene> {
    (
        -3.2f64..3.2,
        -0.15f64..0.15,
        prop::array::uniform2(-0.05f64..0.25),
        0.3f64..3.0,
        prop::option::of(0.0f64..0.04),
        prop::collection::vec(
            (
                0.0f64..0.12,
                // From the heading: anywhere, or about abeam, where only a turn brings
                // the robot toward it.
                prop_oneof![-3.2f64..3.2, 1.2f64..1.9, -1.9f64..-1.2],
                0.0f64..0.2,
                -3.2f64..3.2,
                0.02f64..0.1,
                0.0f64..0.01,
                0.0f64..0.02,
                // Another vehicle of a fleet (judged anywhere on its way), or not.
                prop::sample::select(vec![0.0, 0.04]),
            ),
            1..=3,
        ),
    )
        .prop_map(|(heading, y, wheels, accel, wall_gap, obstacles)| {
            // In a lane, its nearer line `wall_gap` from the robot's centre.
            let cfg = SupervisorConfig::new(accel, 0.108, 0.07, 0.017, wall_gap.map(|gap| y.abs() + gap));
            let position = Point::new(0.0, y);
            let predicted = obstacles
                .iter()
                .map(|&(distance, bearing, speed, course, radius, position_sd, velocity_sd, keep)| ObstacleEstimate {
                    center: position + Point::from_polar(distance + 0.07 + radius, heading + bearing),
                    velocity: Point::from_polar(speed, course),
                    radius,
                    position_sd,
                    velocity_sd,
                    drift: Point::from_polar(speed, course),
                    spread: 0.0,
                    keep,
                })
                .collect();
            Scene { cfg, position, facing: Point::from_polar(1.0, heading), wheels, predicted }
        })
}

/// A verdict as the hazard it names: its index, and for a line its side.
fn named(h: Option<Hazard>) -> Option<(Option<usize>, bool)> {
    h.map(|h| (h.index(), matches!(h, Hazard::Line { normal, .. } if normal.im > 0.0)))
}

/// The wheels' speeds at each step toward `command`, as the path ramps them.
fn ramped(scene: &Scene, command: WheelSpeeds, h: f64) -> Vec<[f64; 2]> {
    let (mut wheels, mut s, mut all) = (scene.wheels, 0.0, Vec::new());
    while s < scene.cfg.reaction_time {
        let step = scene.cfg.wheel_accel * h;
        wheels = [ramp(wheels[0], command.left, step), ramp(wheels[1], command.right, step)];
        all.push(wheels);
        s += h;
    }
    all
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// The shortcuts (nothing within reach; never moving toward anything, from the
    /// start or from a step of the brake on) decide every verdict as walking the whole
    /// path to the stop does.
    #[test]
    fn the_shortcuts_never_change_a_verdict(
        scene in scene(),
        command in prop::array::uniform2(-0.05f64..0.25),
        spare in prop::sample::select(vec![0.0, ROBUSTNESS]),
    ) {
        let command = WheelSpeeds { left: command[0], right: command[1] };
        let (taken, untaken) = scene.judge(|ctx| {
            (
                ctx.first_driven_into_by(command, spare, Shortcuts::Taken),
                ctx.first_driven_into_by(command, spare, Shortcuts::Untaken),
            )
        });
        prop_assert_eq!(named(taken), named(untaken));
    }

    /// Two commands [`BeyondRamp`] finds beyond the ramp's reach in the same sense on
    /// each wheel ramp the wheels alike, bit for bit, at every step, and so get the same
    /// verdict, each its whole path walked: what lets it give one verdict for them all.
    /// And it finds them so: a command more than the ramp can bring within the reaction
    /// time (and the step that crosses it), down or up on each wheel, is found beyond
    /// it. Some commands are within reach (`beyond` below zero): a sense too ready to
    /// find them beyond would pair them with others.
    #[test]
    fn commands_beyond_the_ramp_walk_one_path(
        scene in scene(),
        up in prop::array::uniform2(prop::bool::ANY),
        beyond in prop::array::uniform2(prop::array::uniform2(-0.05f64..0.1)),
    ) {
        // What the ramp reaches: the steps before `τ` and the one crossing it.
        let h = scene.judge(|ctx| BeyondRamp::new(ctx).h);
        let ramp = scene.cfg.wheel_accel * (scene.cfg.reaction_time + h);
        let command = |b: [f64; 2]| {
            let target = |k: usize| scene.wheels[k] + if up[k] { ramp + b[k] } else { -ramp - b[k] };
            WheelSpeeds { left: target(0), right: target(1) }
        };
        let commands = [command(beyond[0]), command(beyond[1])];
        let (senses, same_step, verdicts) = scene.judge(|ctx| {
            let found = BeyondRamp::new(ctx);
            (
                commands.map(|c| found.sense(ctx, c)),
                // A fast command on a slow ramp gets a longer step (and a walk of its own).
                commands.map(|c| ctx.path_step(ctx.fastest(c)) == found.h),
                commands.map(|c| named(ctx.first_driven_into_by(c, ROBUSTNESS, Shortcuts::Untaken))),
            )
        });
        let expected = [usize::from(up[0]), usize::from(up[1])];
        for k in 0..2 {
            if beyond[k].iter().all(|&b| b > 0.0) {
                prop_assert_eq!(senses[k], same_step[k].then_some(expected));
            }
        }
        if senses[0].is_some() && senses[0] == senses[1] {
            prop_assert_eq!(ramped(&scene, commands[0], h), ramped(&scene, commands[1], h));
            prop_assert_eq!(verdicts[0], verdicts[1]);
        }
    }

    /// Evasion's search from the least cost up, stopping at the first clear candidate,
    /// chooses what judging every candidate over the whole look-ahead chooses; and a margin
    /// cut short where it stops mattering is the whole margin wherever it still matters.
    #[test]
    fn evasions_shortcuts_choose_as_judging_every_candidate_whole(
        scene in scene(),
        proposed in prop::array::uniform2(-0.05f64..0.25),
        matters in -0.05f64..0.0,
    ) {
        let proposed = WheelSpeeds { left: proposed[0], right: proposed[1] };
        let top = 0.25;
        let (searched, whole, margins) = scene.judge(|ctx| {
            let whole_margin = |c| ctx.least_margin_ahead(c, Ahead::All, EVASION_HORIZON, f64::NEG_INFINITY);
            let mut nearest: Option<(f64, WheelSpeeds)> = None;
            for c in evasion_candidates(top) {
                if ctx.first_driven_into(c, EVASION_SPARE).is_some() || ctx.approaches_a_near_obstacle(c) {
                    continue;
                }
                let cost = (c.left - proposed.left).hypot(c.right - proposed.right) - (c.left + c.right);
                if whole_margin(c) >= 0.0 && nearest.is_none_or(|(d, _)| cost < d) {
                    nearest = Some((cost, c));
                }
            }
            let margins: Vec<(f64, f64)> = evasion_candidates(top)
                .map(|c| (whole_margin(c), ctx.least_margin_ahead(c, Ahead::All, EVASION_HORIZON, matters)))
                .collect();
            (nearest_clear(ctx, proposed, top).ok(), nearest.map(|(_, c)| c), margins)
        });
        prop_assert_eq!(searched, whole);
        for (whole, cut) in margins {
            if whole >= matters {
                prop_assert_eq!(whole.to_bits(), cut.to_bits());
            } else {
                prop_assert!(cut < matters, "{} {}", whole, cut);
            }
        }
    }
}

/// Passing beside a body with a millimetre a second of closing speed, held steady: a robot
/// may (a stop's sliver of speed is judged so); a fleet's vehicle may not close on another
/// vehicle so, which would creep into it, but may on anything else.
#[test]
fn a_vehicle_closes_on_another_only_as_it_slows() {
    let mut cfg = SupervisorConfig::new(0.25, 0.108, 0.07, 0.02, None);
    // Abeam, 1 mm clear, 3 mm ahead: driving on at 5 cm/s closes on it at about 1 mm/s.
    let beside =
        |keep| ObstacleEstimate { keep, ..ObstacleEstimate::exact(Point::new(0.003, 0.141), Point::default(), 0.07) };
    let steady = WheelSpeeds { left: 0.05, right: 0.05 };
    let verdict = |cfg: &SupervisorConfig, keep| {
        let scene = Scene {
            cfg: cfg.clone(),
            position: Point::default(),
            facing: Point::new(1.0, 0.0),
            wheels: [0.05; 2],
            predicted: vec![beside(keep)],
        };
        scene.judge(|ctx| ctx.first_driven_into(steady, 0.0)).map(|h| h.is_vehicle())
    };
    assert_eq!((verdict(&cfg, 0.0), verdict(&cfg, 0.04)), (None, None), "the robot's tolerance");
    cfg.vehicle_approach_tolerance = 0.0;
    assert_eq!(verdict(&cfg, 0.0), None, "an obstacle that is not a vehicle");
    assert_eq!(verdict(&cfg, 0.04), Some(true), "another vehicle");
    // Slowing to a stop, the last sliver of speed is judged by the robot's tolerance.
    let scene = Scene {
        cfg,
        position: Point::default(),
        facing: Point::new(1.0, 0.0),
        wheels: [0.0015; 2],
        predicted: vec![beside(0.04)],
    };
    assert_eq!(scene.judge(|ctx| ctx.first_driven_into(WheelSpeeds::default(), 0.0)).map(|h| h.is_vehicle()), None);
}

/// A follower keeps its stop's length behind where the vehicle ahead stands, not where it
/// is going: that vehicle may stop dead (its link lost, its motors' timeout) before anyone
/// knows. An obstacle that is not a vehicle is judged going on.
#[test]
fn a_follower_keeps_its_stop_behind_where_the_vehicle_ahead_stands() {
    let cfg = SupervisorConfig::new(1.0, 0.108, 0.07, 0.02, None);
    let (speed, contact) = (0.15, 0.14);
    let steady = WheelSpeeds { left: speed, right: speed };
    let verdict = |gap: f64, keep: f64| {
        let ahead = ObstacleEstimate {
            keep,
            ..ObstacleEstimate::exact(Point::new(contact + gap, 0.0), Point::new(speed, 0.0), 0.07)
        };
        let scene = Scene {
            cfg: cfg.clone(),
            position: Point::default(),
            facing: Point::new(1.0, 0.0),
            wheels: [speed; 2],
            predicted: vec![ahead],
        };
        scene.judge(|ctx| ctx.first_driven_into(steady, ROBUSTNESS).is_none())
    };
    // Its stop: the reaction time at speed, then v²/2a (11 mm), and the margins.
    let stop = speed * cfg.reaction_time + speed * speed / (2.0 * cfg.wheel_accel);
    assert!(verdict(0.008, 0.0), "an obstacle going on as fast");
    assert!(!verdict(0.008, 0.04), "a vehicle {:.1} mm ahead, inside the follower's stop", 8.0);
    assert!(!verdict(stop, 0.04), "the stop alone, without the margins");
    assert!(verdict(stop + 0.01, 0.04), "a stop and a centimetre behind");
}
