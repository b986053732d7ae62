//! The paper's experiments, closed loop against the simulator's world, judged by its truth
//! (contact and clearance against the true radii), plus the pinned bad cases.

use std::path::{Path, PathBuf};
use std::process::Command;

use flowgate::lab::planner_only::{self, Mode, Outcome};
use flowgate::lab::sweep;
use flowgate::lab::Scenario;

fn scenario(name: &str) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name);
    Scenario::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

fn assert_goal_without_contact(name: &str) {
    let run = planner_only::run(&scenario(name), false);
    let s = &run.summary;
    assert_eq!(s.outcome, Outcome::Goal, "{name}: {s:?}");
    assert!(s.first_contact.is_none(), "{name}: contact at {:?}", s.first_contact);
    assert!(s.min_obstacle_clearance.unwrap_or(1.0) > 0.0, "{name}: {s:?}");
    assert!(s.min_wall_clearance.unwrap_or(1.0) > 0.0, "{name}: {s:?}");
}

#[test]
fn e1_standing_obstacle_reaches_goal() {
    assert_goal_without_contact("e1-standing-obstacle.toml");
}

#[test]
fn e2_lane_head_on_reaches_goal() {
    assert_goal_without_contact("e2-lane-head-on.toml");
}

/// E2's obstacle touches the wall, so its circle is closed against it (centred on the wall)
/// except while that closure would take in the goal: its first second (51 cycles at 20 ms),
/// until the obstacle, coming head-on, has moved far enough from the goal. Counted, not
/// hidden; docs/simulation.md quotes the figure.
#[test]
fn e2_leaves_its_circle_unclosed_only_while_the_closure_would_take_in_the_goal() {
    let s = planner_only::run(&scenario("e2-lane-head-on.toml"), false).summary;
    assert_eq!(s.unclosed_at_a_wall_cycles, 51, "{s:?}");
    assert_eq!(s.cycles, 411, "{s:?}");
    // Free space never leaves a circle unclosed: there is no wall.
    let e1 = planner_only::run(&scenario("e1-standing-obstacle.toml"), false).summary;
    assert_eq!(e1.unclosed_at_a_wall_cycles, 0);
}

#[test]
fn e4_lowpass_lag_reaches_goal() {
    assert_goal_without_contact("e4-lowpass-lag.toml");
}

#[test]
fn e5_moving_and_standing_reaches_goal() {
    assert_goal_without_contact("e5-moving-and-standing.toml");
}

#[test]
fn e6_two_moving_reaches_goal() {
    assert_goal_without_contact("e6-two-moving.toml");
}

/// Paper Fig. 3: with a 0.6 s delay the robot collides at R = R_0 and succeeds at 1.1 R_0.
#[test]
fn e3_delay_collides_without_margin_and_succeeds_with_it() {
    let a = planner_only::run(&scenario("e3a-delay-no-margin.toml"), false).summary;
    assert_eq!(a.outcome, Outcome::Collision, "{a:?}");
    assert!(a.first_contact.is_some());
    let b = planner_only::run(&scenario("e3b-delay-margin.toml"), false).summary;
    assert_eq!(b.outcome, Outcome::Goal, "{b:?}");
    assert!(b.min_obstacle_clearance.unwrap() > 0.0);
    // The 1.1 R0 margin and the prediction's uncertainty take in the robot as the obstacle
    // passes: 90 of its 700 cycles plan with that circle shrunk short of the robot instead
    // of freezing it, and summary.json says so. Without a margin nothing is shrunk.
    assert_eq!((b.margin_shrunk_cycles, b.cycles), (90, 700), "{b:?}");
    assert_eq!(a.margin_shrunk_cycles, 0, "{a:?}");
}

/// Pinned: robot, obstacle and goal collinear. Without the tie-break the robot runs into
/// the rear stagnation point and stalls; with it, it goes round (keeping right). The pin
/// is the paper's field in free space: the camera's view is no boundary here (its edges,
/// not quite symmetric about the axis, would break the tie by themselves).
#[test]
fn rear_stagnation_stalls_without_tie_break_and_passes_with_it() {
    let mut s = scenario("e1s-standing-obstacle-symmetric.toml");
    s.room.view_boundary = Some(false);
    s.planner.tie_break = false;
    let stuck = planner_only::run(&s, true);
    assert_eq!(stuck.summary.outcome, Outcome::Stall, "{:?}", stuck.summary);
    let last = stuck.trace.last().unwrap().pose.position;
    assert!(last.im.abs() < 1e-3, "stalled on the axis, at {last}");
    assert!((last.re + 0.14).abs() < 0.02, "at the rear stagnation point x = -R, got {last}");

    s.planner.tie_break = true;
    let run = planner_only::run(&s, true);
    assert_eq!(run.summary.outcome, Outcome::Goal, "{:?}", run.summary);
    assert!(run.summary.tie_break_cycles > 0);
    // Keep right: heading +x, the robot passes the obstacle on the -y side.
    let passing = run.trace.iter().find(|r| r.pose.position.re > 0.0).unwrap();
    assert!(passing.pose.position.im < 0.0, "{}", passing.pose.position);
}

/// Pinned: a symmetric head-on approach in free space. Without the tie-break every term is
/// real on the axis and the field pushes the robot straight back; a differential-drive
/// robot has to turn round to obey (Δθ = π), and the obstacle runs into it. With the
/// tie-break it passes.
#[test]
fn head_on_deadlock_is_broken_by_the_tie_break() {
    let mut s = scenario("e1s-standing-obstacle-symmetric.toml");
    s.obstacles[0].start = [0.3, 0.0];
    s.obstacles[0].motion = flowgate_sim::scenario::Motion::Constant { velocity: [-0.06, 0.0] };
    s.goal.position = [0.6, 0.0];
    s.time_limit = 20.0;
    // The paper's planner alone (no allowance for uncertainty, no room for a supervisor,
    // none): a noisy estimate's wider circle can break the symmetry by luck, and the pin is
    // about the field.
    let defaults = (s.planner.uncertainty_sigmas, s.planner.clearance);
    (s.planner.uncertainty_sigmas, s.planner.clearance, s.supervised) = (0.0, 0.0, false);
    (s.planner.tie_break, s.room.view_boundary) = (false, Some(false));
    let plain = planner_only::run(&s, true);
    // It cannot pick a side, turns round to retreat, and the obstacle catches it.
    assert_eq!(plain.summary.outcome, Outcome::Collision, "{:?}", plain.summary);
    assert_eq!(plain.summary.tie_break_cycles, 0);

    s.planner.tie_break = true;
    let broken = planner_only::run(&s, false).summary;
    assert_eq!(broken.outcome, Outcome::Goal, "{broken:?}");
    // And with the defaults, supervised (the view's edge a boundary, evasion on): evasion
    // backs away before the slow obstacle rather than slip past it, and the robot reaches
    // the goal only once it has gone round, at 29.3 s against 10.2 s without evasion
    // (docs/supervisor.md, "Evasion").
    (s.planner.uncertainty_sigmas, s.planner.clearance, s.supervised) = (defaults.0, defaults.1, true);
    (s.room.view_boundary, s.time_limit) = (None, 60.0);
    let broken = planner_only::run(&s, false).summary;
    assert_eq!(broken.outcome, Outcome::Goal, "{broken:?}");
    assert!(broken.first_contact.is_none());
    assert!((broken.end_time - 29.29).abs() < 0.05, "{broken:?}");
    s.planner.evasion = Some(false);
    let unevaded = planner_only::run(&s, false).summary;
    assert!(unevaded.outcome == Outcome::Goal && (unevaded.end_time - 10.2).abs() < 0.05, "{unevaded:?}");
}

/// E7: an obstacle faster than the robot's limit is flagged; whatever happens is reported.
/// E1's standing one and E5's slow one are not.
#[test]
fn e7_flags_an_obstacle_faster_than_the_robot() {
    let s = planner_only::run(&scenario("e7-obstacle-faster-than-robot.toml"), false).summary;
    assert!(s.obstacle_faster_than_robot, "{s:?}");
    let e1 = planner_only::run(&scenario("e1-standing-obstacle.toml"), false).summary;
    assert!(!e1.obstacle_faster_than_robot);
    // E5's obstacle at 7 cm/s against 15 cm/s, its estimate with 1 mm of noise: not
    // flagged (the speed alone, OR'd over every cycle, flagged it).
    let e5 = planner_only::run(&scenario("e5-moving-and-standing.toml"), false).summary;
    assert!(!e5.obstacle_faster_than_robot, "{e5:?}");
}

#[test]
fn sweep_is_reproducible_and_accounts_for_every_episode() {
    let base = scenario("e2-lane-head-on.toml");
    let a = sweep::sweep(&base, 60, 7, 2, Mode::PlannerOnly).expect("a sweep this small fits");
    let b = sweep::sweep(&base, 60, 7, 1, Mode::PlannerOnly).expect("a sweep this small fits");
    assert_eq!(a.episodes, 60);
    let total = a.goal_rate + a.collision_rate + a.timeout_rate + a.stall_rate;
    assert!((total - 1.0).abs() < 1e-9, "{total}");
    assert_eq!(serde_json::to_string(&a).unwrap(), serde_json::to_string(&b).unwrap(), "same seed, same report");
    let c = sweep::sweep(&base, 60, 8, 2, Mode::PlannerOnly).expect("a sweep this small fits");
    assert_ne!(serde_json::to_string(&a).unwrap(), serde_json::to_string(&c).unwrap(), "another seed differs");
}

/// The baseline `planner.method = "straight"` (straight at the goal, the supervisor alone)
/// on the same 300 episodes of the five-obstacle circle crossing as the field: the
/// supervisor keeps it from driving into anyone, and it reaches the goal less often, walked
/// into where it is held (docs/simulation.md, "A baseline").
#[test]
fn the_straight_baseline_is_held_by_the_supervisor_and_trails_the_field() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/crowd/circle-crossing-5.toml");
    let field = Scenario::load(&path).unwrap();
    let straight = Scenario::load_with(&path, "planner.method=\"straight\"").unwrap();
    let a = sweep::sweep(&field, 300, 1, 2, Mode::PlannerOnly).unwrap();
    let b = sweep::sweep(&straight, 300, 1, 2, Mode::PlannerOnly).unwrap();
    assert_eq!((a.goal_rate, a.collision_rate), (1.0, 0.0), "{a:?}");
    assert_eq!(b.active_contact_rate, 0.0, "{b:?}");
    assert!((b.goal_rate - 0.96).abs() < 1e-9 && (b.passive_contact_rate - 0.04).abs() < 1e-9, "{b:?}");
}

fn flowgate() -> Command {
    Command::new(env!("CARGO_BIN_EXE_flowgate"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("flowgate-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn plan_command_writes_summary_and_plots() {
    let out = temp_dir("plan");
    let status = flowgate()
        .args(["plan", "--scenario"])
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    assert!(String::from_utf8_lossy(&status.stdout).contains("goal"));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["outcome"], "goal");
    for key in ["min_obstacle_clearance", "time_to_goal", "path_length_ratio", "peak_wheel_speed", "planner_compute"] {
        assert!(!summary[key].is_null(), "summary.json lacks {key}");
    }
    assert!(summary["planner_compute"]["p99_us"].as_f64().unwrap() > 0.0);
    for plot in ["trajectory.svg", "history.svg"] {
        let svg = std::fs::read_to_string(out.join(plot)).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("<polyline"), "{plot}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// A full-stack run that ends in a fault says which, in summary.json and in its line: a
/// board fault at 2.5 s stops the robot, named by the board's node.
#[test]
fn a_full_stack_run_names_its_stop_reason() {
    let dir = temp_dir("stop-reason");
    std::fs::create_dir_all(&dir).unwrap();
    let e1 = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml"))
        .unwrap();
    std::fs::write(dir.join("faulted.toml"), format!("{e1}\n[faults]\nboard_fault_at = 2.5\n")).unwrap();
    let out =
        flowgate().args(["plan", "--scenario"]).arg(dir.join("faulted.toml")).arg("--out").arg(&dir).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("stop: fault: motor board 1 fault"), "{stdout}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["outcome"], "fault");
    assert_eq!(summary["stop_reason"], "fault: motor board 1 fault");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn plan_command_refuses_a_bad_scenario_naming_the_key() {
    let dir = temp_dir("bad");
    std::fs::create_dir_all(&dir).unwrap();
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml"))
            .unwrap()
            .replace("sample_time = 0.017", "sample_time = -1");
    std::fs::write(dir.join("bad.toml"), text).unwrap();
    let out = flowgate().args(["plan", "--scenario"]).arg(dir.join("bad.toml")).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("sensing.sample_time") && err.contains("positive"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// What no run could start from or end in is refused at load, naming the key, instead of
/// showing up as a collision at t = 0, a timeout, or a buffer the size of the delay.
#[test]
fn impossible_scenarios_are_refused_naming_the_key() {
    let e1 = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml"))
        .unwrap();
    let lane = |t: &str| t.replace("time_limit = 30", "time_limit = 30\n[lane]\nhalf_width = 0.2");
    let obstacles: String = (0..15)
        .map(|i| format!("\n[[obstacles]]\nradius = 0.02\nstart = [{}, 0.5]\n", 0.1 * f64::from(i) - 0.8))
        .collect();
    let cases: Vec<(String, &str, &str)> = vec![
        (e1.replace("start = [-0.35, -0.06]", "start = [-0.05, 0.0]"), "robot.start", "overlaps obstacles[0]"),
        (e1.replace("position = [0.35, 0.05]", "position = [0.01, 0.0]"), "goal.position", "standing obstacles[0]"),
        (lane(&e1).replace("start = [-0.35, -0.06]", "start = [-0.35, -0.3]"), "robot.start", "outside the lane"),
        (lane(&e1).replace("position = [0.35, 0.05]", "position = [0.35, 0.3]"), "goal.position", "outside the lane"),
        (lane(&e1).replace("start = [0.0, 0.0]", "start = [0.0, 0.5]"), "obstacles[0].start", "outside the lane"),
        (e1.replace("delay = 0.0", "delay = 1000.0"), "sensing.delay", "must be 0-10 s"),
        (e1.replace("time_limit = 30", "time_limit = 1e9"), "time_limit", "at most 3600 s"),
        (e1.replace("max_speed = 0.15", "max_speed = 0.30"), "robot.max_speed", "wheels cannot carry"),
        (format!("{e1}{obstacles}"), "obstacles", "has 16 entries: at most 14"),
        (e1.replace("sample_time = 0.017", "sample_time = 0.000003"), "schedule.frame_us", "shorter than 100 µs"),
        (e1.replace("microsteps = 8", "microsteps = 4000000000"), "robot.microsteps", "must be 1-256"),
    ];
    for (text, key, says) in cases {
        let err = Scenario::from_toml(&text, "s.toml").err().map(|e| e.to_string()).unwrap_or_default();
        assert!(err.contains(&format!("`{key}`")) && err.contains(says), "{key}: {err}");
    }
    assert!(Scenario::from_toml(&lane(&e1), "s.toml").is_ok(), "the unchanged scenario in a lane loads");
}

/// A command-line error is one line naming its cause once.
#[test]
fn errors_name_their_cause_once() {
    let out = flowgate().args(["run", "--config", "/nonexistent/rig.toml"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    let out = flowgate().args(["demo", "--can", "socketcna:vcan0"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("socketcna:vcan0"), "{err}");
}

/// Beside a standing obstacle with 1 mm of noise and 0.3 s of delay, 40 seeds: the
/// paper's planner alone (no allowance for the prediction's uncertainty, no supervisor)
/// grazes it in some; with the defaults (one standard deviation of the predicted centre in
/// the margin, room for the supervisor, the supervisor on) none does, and all 40 reach
/// the goal. Whether a run that skirts the margin for seconds stalls there instead, held
/// by its margins, turns on rounding: E1's sweep stalls in 0.9% of its episodes. A stall
/// here is not a graze; should one appear, it is the count below that moves. (A dead
/// reckoning that ignored the boards' ramp grazes in 22 of these 40.)
#[test]
fn noisy_delayed_estimates_do_not_graze_a_standing_obstacle() {
    let base = scenario("e1-standing-obstacle.toml");
    let runs = |paper: bool| {
        let base = &base;
        (0..40u64).map(move |seed| {
            let mut s = base.clone();
            if paper {
                (s.planner.uncertainty_sigmas, s.planner.clearance, s.supervised) = (0.0, 0.0, false);
                s.room.view_boundary = Some(false);
            }
            (s.sensing.position_noise, s.sensing.delay, s.sensing.seed) = (0.001, 0.3, seed);
            planner_only::run(&s, false).summary
        })
    };
    let grazed = runs(true).filter(|s| s.first_contact.is_some()).count();
    assert_eq!(grazed, 1, "the paper's planner");
    let after: Vec<_> = runs(false).collect();
    assert!(after.iter().all(|s| s.first_contact.is_none()), "{after:?}");
    let goals = after.iter().filter(|s| s.outcome == Outcome::Goal).count();
    assert_eq!(goals, 40, "{after:?}");
}

/// The paper's table ends the same way through the whole stack (the gateway core, the
/// firmware, the wire protocols, the camera's view) as planner-only: E3a collides as in the
/// paper, and every other experiment reaches its goal, E3b and E7 with their obstacles
/// walking out of the camera's view.
#[test]
fn the_papers_experiments_end_alike_through_the_whole_stack() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    assert_eq!(names.len(), 9, "{names:?}");
    for name in &names {
        let s = scenario(name);
        let planner_only = planner_only::run(&s, false).summary.outcome;
        let whole = flowgate::lab::virtual_rig::run(&s, flowgate::lab::virtual_rig::Options::default());
        let expected = if name.starts_with("e3a") { Outcome::Collision } else { Outcome::Goal };
        assert_eq!(planner_only, expected, "{name} planner-only");
        assert_eq!(whole.outcome, expected, "{name} whole stack: {}", whole.report);
    }
    let e3b = flowgate::lab::virtual_rig::run(
        &scenario("e3b-delay-margin.toml"),
        flowgate::lab::virtual_rig::Options::default(),
    );
    assert_eq!(e3b.report.counters.obstacles_left_view, 1, "{}", e3b.report);
}

/// The crowd benchmark, CrowdNav's circle crossing in the arena (scenarios/crowd/): the robot
/// and 5 (or 1) non-reactive obstacles at 2/3 of its speed cross a circle of 0.6 m, placed
/// afresh for each of 1000 episodes, planner-only and through the whole stack; in the
/// walk-on crowd, at the robot's cruise speed and on past the far side, with the planner's
/// defaults alone (evasion on outside a lane, the camera's view a boundary). The targets
/// hold: 5 obstacles stopping at the far side at least 95% success, the others at least
/// 99%; no active and at most 2% passive contact; and the walk-on crowd ends no episode in a
/// fault (the robot is never taken out of the camera's view). The rates are exact for the
/// seed (docs/supervisor.md quotes them). Without evasion the robot, held in the obstacles'
/// way, is hit in a fifth of the episodes.
#[test]
fn a_crossing_crowd_is_evaded() {
    let run = |name: &str, mode: Mode| {
        let s = scenario(&format!("crowd/{name}"));
        sweep::sweep(&s, 1000, 1, 2, mode).expect("a sweep this small fits")
    };
    for (name, mode, goal, passive) in [
        ("circle-crossing-5.toml", Mode::PlannerOnly, 0.996, 0.001),
        ("circle-crossing-5.toml", Mode::FullStack, 0.989, 0.0),
        ("circle-crossing-1.toml", Mode::PlannerOnly, 1.0, 0.0),
        ("circle-crossing-1.toml", Mode::FullStack, 0.999, 0.0),
        ("circle-crossing-5-walk-on.toml", Mode::PlannerOnly, 0.996, 0.003),
        ("circle-crossing-5-walk-on.toml", Mode::FullStack, 0.997, 0.002),
    ] {
        let r = run(name, mode);
        let target = if name.contains("-5.") { 0.95 } else { 0.99 };
        assert!(r.goal_rate >= target && r.passive_contact_rate <= 0.02, "{name} {mode}: {r}");
        assert_eq!(r.active_contact_rate, 0.0, "{name} {mode}: {r}");
        if name.contains("walk-on") {
            assert_eq!(r.fault_rate, 0.0, "{name} {mode}: {r}");
        }
        assert!(
            (r.goal_rate - goal).abs() < 1e-9 && (r.passive_contact_rate - passive).abs() < 1e-9,
            "{name} {mode}: {r}"
        );
    }
    let mut without = scenario("crowd/circle-crossing-5.toml");
    without.planner.evasion = Some(false);
    let r = sweep::sweep(&without, 1000, 1, 2, Mode::PlannerOnly).expect("a sweep this small fits");
    assert!((r.goal_rate - 0.784).abs() < 1e-9 && (r.passive_contact_rate - 0.215).abs() < 1e-9, "{r}");
}

/// Around E2 (a lane, the obstacle head-on, its course turned up to 20° and its speed
/// scaled 0.5-1.5), an obstacle drifting across the lane is passed on the side it leaves
/// (`planner.anticipation`, on by default in a lane): at most 1% passive contact, none
/// active, planner only and through the whole stack; planning on the obstacle as it stands
/// (anticipation 0) the robot takes the side the obstacle drifts into and is hit in 8% of
/// the episodes. The rates are exact for the seed (docs/supervisor.md quotes them).
#[test]
fn a_lane_obstacle_is_passed_on_the_side_it_leaves() {
    let base = scenario("e2-lane-head-on.toml");
    for (mode, goal, passive) in [(Mode::PlannerOnly, 0.996, 0.004), (Mode::FullStack, 0.996, 0.003)] {
        let r = sweep::sweep(&base, 1000, 1, 2, mode).expect("a sweep this small fits");
        assert!(r.passive_contact_rate <= 0.01 && r.active_contact_rate == 0.0, "{mode}: {r}");
        assert!((r.goal_rate - goal).abs() < 1e-9 && (r.passive_contact_rate - passive).abs() < 1e-9, "{mode}: {r}");
    }
    let mut standing = base.clone();
    standing.planner.anticipation = 0.0;
    let r = sweep::sweep(&standing, 1000, 1, 2, Mode::PlannerOnly).expect("a sweep this small fits");
    assert!((r.goal_rate - 0.917).abs() < 1e-9 && (r.passive_contact_rate - 0.083).abs() < 1e-9, "{r}");
}

/// An obstacle that walks into the robot stops it named for what happened, through the
/// whole stack: which obstacle, and whether the robot stood. E2's obstacle on the centre line
/// of a lane too narrow to pass reaches the robot standing where the supervisor held it;
/// one from behind, faster than the robot, reaches it driving ahead of it. Both contacts are
/// passive; `summary.json` and the state name the obstacle.
#[test]
fn an_obstacle_reaching_the_robot_is_named_for_it() {
    use flowgate::lab::virtual_rig::{self, Options};
    let e2 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e2-lane-head-on.toml")).unwrap();
    let narrow =
        e2.replace("half_width = 0.2", "half_width = 0.1").replace("start = [0.45, 0.06]", "start = [0.45, 0.0]");
    let behind = e2
        .replace("start = [0.45, 0.06]", "start = [-0.85, 0.0]")
        .replace("velocity = [-0.056, 0.0]", "velocity = [0.3, 0.0]");
    for (text, state) in [
        (narrow, "fault: obstacle LED 3 reached the standing robot"),
        (behind, "fault: obstacle LED 3 reached the robot driving, not towards it"),
    ] {
        assert_ne!(text, e2);
        let s = Scenario::from_toml(&text, "s.toml").unwrap();
        let run = virtual_rig::run(&s, Options::default());
        assert_eq!(run.report.final_state.to_string(), state);
        let contact = run.truth.summary.contact.unwrap_or_else(|| panic!("{state}: no contact"));
        assert!(!contact.active, "{state}: {contact:?}");
        let summary = planner_only::Run::from_episode(&s, &run).summary;
        assert_eq!(summary.stop_reason.as_deref(), Some(state));
    }
}
