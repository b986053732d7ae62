//! Rooms: walls and static obstacles from the scenario file to the world's truth. A room is
//! refused at load naming the key and the reason; the field and the supervisor keep the
//! robot off the shelves of a warehouse aisle, planner-only and through the whole stack; the
//! supervisor slows a command into a wall and passes one along it.

use std::path::Path;

use flowgate::control::drive::WheelSpeeds;
use flowgate::control::supervisor::{supervise, Supervision, SupervisorConfig};
use flowgate::gateway::core::operator::{Goal, Refusal, Request};
use flowgate::lab::planner_only::{self, Mode, Outcome};
use flowgate::lab::sweep;
use flowgate::lab::virtual_rig::{self, Options, VirtualRig};
use flowgate::lab::Scenario;
use flowgate::planner::room::{Room, RoomShape};
use flowgate::planner::{PlanInput, Planner};
use flowgate::track::Estimate;
use flowgate::Point;

fn scenario_text(path: &str) -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(path)).unwrap()
}

fn aisle_text() -> String {
    scenario_text("scenarios/rooms/warehouse-aisle.toml")
}

/// E2's text, its lane as the scenario gives it, and the walls' faces at `±y` that bound
/// the robot's centre where the lane's lines are, once grown by the robot and clearance.
fn e2_lane() -> (String, Scenario, f64) {
    let e2 = scenario_text("scenarios/e2-lane-head-on.toml");
    let lane = Scenario::from_toml(&e2, "lane").unwrap();
    let y = 0.2 + lane.robot.radius + lane.rig().config.planner.clearance;
    (e2, lane, y)
}

fn refused(text: &str) -> String {
    Scenario::from_toml(text, "room").map(|_| ()).unwrap_err().to_string()
}

/// Every bad room is refused at load, naming the key (and the item's index) and the reason.
#[test]
fn a_bad_room_is_refused_naming_the_key() {
    let aisle = aisle_text();
    // A shelf whose outline crosses itself.
    let e = refused(&aisle.replacen(
        "[[-0.75, 0.2], [-0.15, 0.2], [-0.15, 0.45], [-0.75, 0.45]]",
        "[[-0.75, 0.2], [-0.15, 0.45], [-0.15, 0.2], [-0.75, 0.45]]",
        1,
    ));
    assert!(e.contains("`static_obstacles[0].points` the polygon is not simple: two of its edges cross"), "{e}");
    // A wall with an edge of no length.
    let e = refused(&format!("{aisle}\n[[walls]]\npoints = [[1.0, 1.0], [1.0, 1.0], [1.2, 1.0]]\n"));
    assert!(e.contains("walls[0].points") && e.contains("the edge from point 0 to point 1 has no length"), "{e}");
    // The goal on a shelf.
    let e = refused(&aisle.replace("position = [0.6, 0.0]", "position = [0.5, 0.3]"));
    assert!(e.contains("goal.position") && e.contains("static_obstacles[1]"), "{e}");
    // The goal beside a shelf: clear of it by the robot's radius (7 cm), not by that and the
    // supervisor's room (`planner.clearance`, 6 mm).
    let e = refused(&aisle.replace("position = [0.6, 0.0]", "position = [0.6, 0.127]"));
    assert!(e.contains("goal.position") && e.contains("from static_obstacles[1]"), "{e}");
    // The start against a shelf.
    let e = refused(&aisle.replace("start = [-0.6, 0.0]", "start = [-0.6, 0.15]"));
    assert!(e.contains("robot.start") && e.contains("static_obstacles[0]"), "{e}");
    // With the camera's view as the room's edge, a wall across it: the goal is out of reach.
    let e = refused(&format!("{aisle}\n[room]\nview_boundary = true\n[[walls]]\npoints = [[0.4, -2.0], [0.4, 2.0]]\n"));
    assert!(e.contains("goal.position") && e.contains("out of the robot's reach from robot.start"), "{e}");
    // A [room] key it does not know.
    let e = refused(&format!("{aisle}\n[room]\nview_edge = true\n"));
    assert!(e.contains("[room]") && e.contains("view_edge"), "{e}");
    // Corners' panels asked to turn by more than half a radian.
    let e = refused(&format!("{aisle}\n[room]\ncorner_turn = 0.8\n"));
    assert!(e.contains("room.corner_turn") && e.contains("must be 0 (off) or 0.01-0.5 rad, is 0.8"), "{e}");
    // Asked well, it loads.
    Scenario::from_toml(&format!("{aisle}\n[room]\ncorner_turn = 0.03\n"), "aisle").unwrap();
}

/// Down the aisle, with someone coming out of the cross aisle: the goal, no contact with a
/// shelf or the person, planner-only and through the whole stack.
#[test]
fn the_warehouse_aisle_is_driven_without_touching_a_shelf() {
    let s = Scenario::from_toml(&aisle_text(), "warehouse-aisle").unwrap();
    assert!(s.rig().control.room.is_some(), "the shelves make a room");
    let run = planner_only::run(&s, false).summary;
    assert_eq!(run.outcome, Outcome::Goal, "{run:?}");
    assert!(run.first_contact.is_none(), "{run:?}");
    let shelves = run.min_wall_clearance.unwrap();
    // Between shelves 40 cm apart a 7 cm robot has at most 13 cm each side.
    assert!(shelves > 0.0 && shelves <= 0.13, "it drove between the shelves, clear of them: {shelves}");
    let whole = virtual_rig::run(&s, Options::default());
    assert_eq!(whole.outcome, Outcome::Goal, "{}", whole.report);
    let t = &whole.truth.summary;
    assert!(t.contact.is_none() && t.min_wall_clearance.unwrap() > 0.0, "{t:?}");
}

/// The robot 1 mm from a wall (its footprint's gap): driving at it is slowed (the hazard a
/// line, not an obstacle), along it passes; and so at a static obstacle's corner, where
/// driving away passes.
#[test]
fn the_supervisor_keeps_the_robot_off_walls_and_static_obstacles() {
    let r = 0.07;
    let shape = RoomShape {
        walls: vec![vec![Point::new(-2.0, 0.3), Point::new(2.0, 0.3)]],
        obstacles: vec![vec![
            Point::new(0.5, -0.5),
            Point::new(0.9, -0.5),
            Point::new(0.9, -0.2),
            Point::new(0.5, -0.2),
        ]],
        view: None,
    };
    let room = Room::new(&shape, r, 0.03).unwrap().unwrap();
    let mut cfg = SupervisorConfig::new(1.0, 0.108, r, 0.017, None);
    cfg.room = Some(std::sync::Arc::new(room));
    let toward = WheelSpeeds { left: 0.15, right: 0.15 };
    let by_the_wall = Estimate {
        position: Point::new(0.0, 0.3 - r - 0.001),
        facing: Point::from_polar(1.0, 1.5),
        wheels: [0.0; 2],
        obstacles: &[],
        predicted: &[],
        delay: 0.0,
    };
    let (wheels, verdict) = supervise(&cfg, &by_the_wall, toward);
    assert!(matches!(verdict, Supervision::Slowed { hazard: None }), "{verdict:?}");
    assert!(wheels.left < 0.05, "{wheels:?}");
    let along = Estimate { facing: Point::new(1.0, 0.0), ..by_the_wall };
    assert_eq!(supervise(&cfg, &along, toward).1, Supervision::Passed);
    // Heading for the table's corner, diagonally, 1 mm from it.
    let corner = Point::new(0.5, -0.2);
    let heading = Point::from_polar(1.0, -std::f64::consts::FRAC_PI_4);
    let at_the_table = Estimate { position: corner - heading * (r + 0.001), facing: heading, ..by_the_wall };
    assert!(matches!(supervise(&cfg, &at_the_table, toward).1, Supervision::Slowed { hazard: None }));
    let away = Estimate { facing: -heading, ..at_the_table };
    assert_eq!(supervise(&cfg, &away, toward).1, Supervision::Passed);
}

/// `flowgate ctl goal` in a room: a goal on a shelf or beside one is refused naming the
/// shelf, a free one down the aisle is taken and reached.
#[test]
fn the_operator_goal_is_refused_in_furniture_and_taken_in_the_aisle() {
    let s = Scenario::from_toml(&aisle_text(), "warehouse-aisle").unwrap();
    let mut rig = VirtualRig::new(&s, Options::default());
    rig.run_until(0.5);
    let goal = |x: f64, y: f64| Request::Goal { goals: vec![Goal { position: [x, y], tolerance: 0.02 }] };
    for (at, says) in [([0.5, 0.3], "lies inside static_obstacles[1]"), ([0.5, 0.13], "from static_obstacles[1]")] {
        match rig.request(&goal(at[0], at[1])) {
            Err(Refusal::BadGoal { why, .. }) => assert!(why.contains(says), "{at:?}: {why}"),
            other => panic!("{at:?}: {other:?}"),
        }
    }
    rig.request(&goal(0.3, 0.0)).unwrap();
    let e = rig.run(s.time_limit, [0.3, 0.0], 0.02);
    assert_eq!(e.outcome, Outcome::Goal, "{}", e.report);
}

/// `flowgate ctl goal` beyond the corridor's walls: clear of every wall, inside the view,
/// and out of the robot's reach; refused naming where the robot stands.
#[test]
fn the_operator_goal_beyond_the_walls_is_refused_as_out_of_reach() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/rooms/l-corridor.toml");
    let s = Scenario::load(&path).unwrap();
    let mut rig = VirtualRig::new(&s, Options::default());
    rig.run_until(0.5);
    let goal = Request::Goal { goals: vec![Goal { position: [-0.4, 0.4], tolerance: 0.02 }] };
    match rig.request(&goal) {
        Err(Refusal::BadGoal { why, .. }) => {
            assert!(why.contains("out of the robot's reach from (-0.55"), "{why}");
            assert!(why.contains("the walls, static obstacles or the view's edge close it off"), "{why}");
        }
        other => panic!("{other:?}"),
    }
}

/// E2's lane as two walls of finite length `±l`: the room's field between them is the
/// exact lane's in direction, and weaker to the left of the goal by the share of the goal's
/// flux that now comes round the nearer, right-hand ends (`0.6/l` for a goal 0.6 m along,
/// with the channels' resistance in proportion to their length). The lane is the limit of
/// walls without end, reached at that first-order rate.
#[test]
fn two_parallel_walls_tend_to_the_exact_lane_as_they_lengthen() {
    let (e2, lane, y) = e2_lane();
    let field = |s: &Scenario| {
        let c = s.rig().control;
        let input =
            PlanInput { position: s.robot_start(), goal: s.goal(), robot_radius: 0.07, obstacles: &[], delay: 0.02 };
        Planner::in_room(c.planner, c.room.clone()).field(&input).unwrap().0
    };
    let exact = field(&lane);
    let points = [Point::new(-0.5, 0.0), Point::new(-0.3, 0.1), Point::new(0.0, -0.15), Point::new(-0.5, 0.14)];
    let mut deficits = Vec::new();
    for l in [2.0, 4.0, 8.0] {
        let walls = format!(
            "[[walls]]\npoints = [[{a}, {y}], [{l}, {y}]]\n[[walls]]\npoints = [[{a}, -{y}], [{l}, -{y}]]\n\
             [room]\nview_boundary = false\npanel_spacing = 0.06\nwalls_as_lane = false\n",
            a = -l
        );
        let room = field(&Scenario::from_toml(&e2.replace("[lane]\nhalf_width = 0.2\n", &walls), "walls").unwrap());
        let deficit = |z: Point| {
            let (a, b) = (exact.velocity(z).unwrap(), room.velocity(z).unwrap());
            assert!((b / a).arg().abs() < 3e-3, "l = {l}: at {z:?} the lane's {a:?}, the walls' {b:?}");
            1.0 - b.norm() / a.norm()
        };
        let d = deficit(points[0]);
        for &z in &points[1..] {
            assert!((deficit(z) - d).abs() < 0.01, "l = {l}: at {z:?} {} against {d}", deficit(z));
        }
        assert!(d > 0.0 && d < 0.6 / l + 0.01, "l = {l}: {d}");
        deficits.push(d);
    }
    assert!(deficits[1] < 0.56 * deficits[0] && deficits[2] < 0.56 * deficits[1], "{deficits:?}");
    assert!(deficits[2] > 0.6 / 8.0 - 0.01, "{deficits:?}");
}

/// Two straight walls along x at `y = ±w`, across the whole view, are the paper's lane
/// (`room.walls_as_lane`): E2 between them ends as E2 in its `[lane]`, its path within a
/// millimetre of the lane's, planner-only and through the whole stack; the drawings show the
/// walls. Walls that stop inside the view, or a lane asked to be solved as walls, are a room.
#[test]
fn two_walls_across_the_view_are_the_lane() {
    let (e2, lane, y) = e2_lane();
    let walls = |from: f64| {
        let walls = format!(
            "[[walls]]\npoints = [[{from}, {y}], [3.0, {y}]]\n[[walls]]\npoints = [[3.0, -{y}], [{from}, -{y}]]\n"
        );
        Scenario::from_toml(&e2.replace("[lane]\nhalf_width = 0.2\n", &walls), "walls").unwrap()
    };
    let across = walls(-3.0);
    assert!(across.rig().control.room.is_none(), "the lane's exact field, no panels");
    let drawn = across.rig().room_outline().expect("the walls are drawn");
    assert_eq!((drawn.walls.len(), drawn.obstacles.len(), drawn.view.is_none()), (2, 0, true));
    assert!(lane.rig().room_outline().is_none());
    assert!(walls(-0.6).rig().control.room.is_some(), "walls that stop inside the view are a room");
    let own =
        e2.replace("[lane]\nhalf_width = 0.2\n", "").replace("[planner]", "[room]\nwalls_as_lane = false\n[planner]");
    let own = format!(
        "{own}[[walls]]\npoints = [[-3.0, {y}], [3.0, {y}]]\n[[walls]]\npoints = [[-3.0, -{y}], [3.0, -{y}]]\n"
    );
    assert!(Scenario::from_toml(&own, "own").unwrap().rig().control.room.is_some(), "walls_as_lane = false");

    let (a, b) = (planner_only::run(&lane, true), planner_only::run(&across, true));
    assert_eq!(a.summary.outcome, Outcome::Goal);
    assert_eq!((b.summary.outcome, b.summary.end_time), (a.summary.outcome, a.summary.end_time));
    assert_eq!(a.trace.len(), b.trace.len());
    let apart = a.trace.iter().zip(&b.trace).map(|(p, q)| (p.pose.position - q.pose.position).norm());
    assert!(apart.fold(0.0, f64::max) <= 1e-3, "planner-only paths more than 1 mm apart");

    let options = Options { truth_samples: true, ..Options::default() };
    let (a, b) = (virtual_rig::run(&lane, options), virtual_rig::run(&across, options));
    assert_eq!(a.outcome, Outcome::Goal, "{}", a.report);
    assert_eq!(b.outcome, a.outcome, "{}", b.report);
    let (a, b) = (&a.truth.samples, &b.truth.samples);
    assert_eq!(a.len(), b.len());
    let apart = a.iter().zip(b).map(|(p, q)| (p.x - q.x).hypot(p.y - q.y));
    assert!(apart.fold(0.0, f64::max) <= 1e-3, "full-stack paths more than 1 mm apart");
}

/// Round the corner of an L-shaped corridor with someone coming the other way, and through
/// a doorway someone has just come through: the goal, touching nothing, planner-only and
/// through the whole stack.
#[test]
fn the_corridor_and_the_doorway_are_driven_without_contact() {
    for name in ["l-corridor.toml", "doorway.toml"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/rooms").join(name);
        let s = Scenario::load(&path).unwrap();
        let run = planner_only::run(&s, false).summary;
        assert_eq!(run.outcome, Outcome::Goal, "{name}: {run:?}");
        assert!(run.first_contact.is_none() && run.min_wall_clearance.unwrap() > 0.0, "{name}: {run:?}");
        let whole = virtual_rig::run(&s, Options::default());
        assert_eq!(whole.outcome, Outcome::Goal, "{name}: {}", whole.report);
        assert!(whole.truth.summary.contact.is_none(), "{name}: {:?}", whole.truth.summary);
    }
}

/// The rooms' sweeps, 1000 episodes each (seed 1), planner-only and through the whole
/// stack: goal, active and passive contact, stall and fault rates, exact for the seed
/// (docs/simulation.md prints them). No episode ends in an active contact, with a person,
/// a wall or a shelf. The narrow rooms' passive contacts are people on courses the sweep
/// turned, walking into a robot with nowhere to go.
#[test]
fn the_rooms_sweeps_end_as_measured() {
    // (scenario, mode, goal, passive contact, stall, fault)
    let rows = [
        ("warehouse-aisle.toml", Mode::PlannerOnly, 0.840, 0.160, 0.0, 0.0),
        ("warehouse-aisle.toml", Mode::FullStack, 0.791, 0.206, 0.0, 0.003),
        ("l-corridor.toml", Mode::PlannerOnly, 0.904, 0.096, 0.0, 0.0),
        ("l-corridor.toml", Mode::FullStack, 0.921, 0.078, 0.0, 0.001),
        ("doorway.toml", Mode::PlannerOnly, 0.993, 0.0, 0.007, 0.0),
        ("doorway.toml", Mode::FullStack, 0.995, 0.0, 0.005, 0.0),
        ("table-and-crowd.toml", Mode::PlannerOnly, 0.959, 0.019, 0.022, 0.0),
        ("table-and-crowd.toml", Mode::FullStack, 0.962, 0.008, 0.030, 0.0),
    ];
    for (name, mode, goal, passive, stall, fault) in rows {
        let s = Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/rooms").join(name)).unwrap();
        let r = sweep::sweep(&s, 1000, 1, 2, mode).expect("a sweep this small fits");
        assert_eq!(r.active_contact_rate, 0.0, "{name} {mode}: {r}");
        let measured = [r.goal_rate, r.passive_contact_rate, r.stall_rate, r.fault_rate];
        let expected = [goal, passive, stall, fault];
        assert!(measured.iter().zip(expected).all(|(m, e)| (m - e).abs() < 1e-9), "{name} {mode}: {r}");
    }
}
