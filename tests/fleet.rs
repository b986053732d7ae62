//! Several vehicles under one camera (`[[vehicles]]`, `[swap]`), at the planner level:
//! antipodal swaps of 2, 4 and 8 navigating vehicles bring every vehicle home with no
//! contact and within 1.5 times the slowest one's time alone; E2, E5 and E6 with their
//! moving obstacles as scripted vehicles leave the robot as well off as the obstacles do,
//! each script kept within 1 cm; a script driven into a vehicle is held by its supervisor;
//! `plan` names every vehicle in summary.json; a fleet that cannot run is refused at load,
//! naming the key.

use std::path::{Path, PathBuf};
use std::process::Command;

use flowgate::lab::fleet::sweep::{compare_scripts, place, sweep};
use flowgate::lab::fleet::{run, FleetOptions};
use flowgate::lab::{Outcome, Scenario};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn scenario(name: &str) -> Scenario {
    Scenario::load(&root().join("scenarios/fleet").join(name)).unwrap()
}

/// Every swap, 40 episodes each (the docs' 10,000 are printed by `flowgate plan --sweep
/// 10000 scenarios/fleet/swap-N.toml`).
#[test]
fn swaps_bring_every_vehicle_home_without_contact() {
    for (file, episodes) in [("swap-2.toml", 40), ("swap-4.toml", 40), ("swap-8.toml", 40)] {
        let s = scenario(file);
        let (report, _) = sweep(&s, episodes, 1, 2, FleetOptions::default()).unwrap();
        assert_eq!(report.all_home.count, episodes as usize, "{file}: {report}");
        assert_eq!(report.vehicle_contact_episodes, 0, "{file}: {report}");
        assert!(report.makespan_ratio_max <= 1.5, "{file}: {report}");
        assert!(report.makespan_ratio_p50 >= 1.0, "no vehicle beats its own time alone: {report}");
    }
}

/// The 8-vehicle swap's episodes in which a vehicle, its way out past another that had
/// stopped at its goal, sat on the edge of the other's spacing and crawled for seconds
/// after every other vehicle was home (2.30, 2.39 and 2.28 times the slowest vehicle's time
/// alone): a vehicle gives up another's spacing once the other is behind it, and each
/// episode ends within 1.5 times.
#[test]
fn a_vehicle_leaving_another_does_not_crawl_on_its_spacing() {
    use flowgate::lab::fleet::sweep::episode;
    let swap = scenario("swap-8.toml");
    for index in [9115, 8627, 3344] {
        let e = episode(&swap, 1, index, FleetOptions::default());
        assert_eq!((e.home, e.contacts), (8, 0), "episode {index}: {e:?}");
        let ratio = e.makespan_ratio().expect("every vehicle home");
        assert!(ratio < 1.5, "episode {index}: makespan {ratio:.2} times the slowest alone");
    }
}

/// E2, E5 and E6 with their moving obstacles as scripted vehicles, 100 episodes each, each
/// episode run twice: the robot reaches its goal as often and keeps as far off as with
/// the obstacles, and every script is followed within 1 cm where nothing held it.
#[test]
fn scripted_vehicles_keep_to_their_scripts() {
    for file in ["e2-scripted.toml", "e5-scripted.toml", "e6-scripted.toml"] {
        let c = compare_scripts(&scenario(file), 100, 1, 2, FleetOptions::default()).unwrap();
        assert!(c.as_vehicles.count >= c.as_obstacles.count, "{file}: {c}");
        assert!(c.clearance_as_vehicles[0] >= c.clearance_as_obstacles[0], "{file}: {c}");
        assert!(c.script_error_max <= 0.01 && c.script_error_max > 0.0, "{file}: {c}");
        assert_eq!((c.script_error_over_1cm, c.scripts_lost), (0, 0), "{file}: {c}");
        assert!(c.failed_as_vehicles.is_empty() && c.failed_as_obstacles.is_empty(), "{file}: {c}");
    }
}

/// A comparison names the first episodes in which the robot did not get home, each way, to
/// replay with `--episode K`: here the robot is taken to have stalled with the scripts as
/// vehicles wherever its start was jittered to the right.
#[test]
fn a_comparison_names_the_episodes_the_robot_did_not_get_home() {
    use flowgate::lab::fleet::sweep::compare_scripts_with;
    let e5 = scenario("e5-scripted.toml");
    let right_of_start = |s: &Scenario| s.sim.robot.start[0] > e5.sim.robot.start[0];
    let c = compare_scripts_with(&e5, 40, 1, 2, |s| {
        let mut f = run(s, FleetOptions::default());
        if right_of_start(s) && !s.sim.vehicles.is_empty() {
            f.vehicles[0].outcome = Outcome::Stall;
        }
        f
    })
    .unwrap();
    let expected: Vec<u64> = (0..40).filter(|&i| right_of_start(&place(&e5, 1, i))).take(10).collect();
    assert!(expected.len() >= 5, "{expected:?}");
    assert_eq!(c.failed_as_vehicles, expected, "{c}");
    assert!(c.failed_as_obstacles.is_empty(), "{c}");
    assert!(c.to_string().contains(&format!("first episodes not home as vehicles: {expected:?}")), "{c}");
}

const DRIVEN_INTO: &str = r#"
name = "A script through a standing vehicle"
time_limit = 30

[robot]
start = [-0.3, 0.0]
radius = 0.07
wheel_base = 0.108
wheel_radius = 0.025
steps_per_rev = 200
microsteps = 8
max_wheel_speed = 0.25
wheel_accel = 1.0
max_speed = 0.15

[goal]
position = [0.0, 0.0]

[[vehicles]]
name = "ram"
role = "script"
start = [0.45, 0.0]
motion = { kind = "waypoints", points = [[-0.45, 0.0]], speed = 0.05 }

[sensing]
sample_time = 0.02

[planner]
cruise_speed = 0.1
c1 = 20
kc = 0.15
margin = { rule = "none" }
"#;

/// A script that runs through the robot standing at its goal: the scripted vehicle's
/// supervisor holds it short of the robot, nothing touches, and the vehicle is stopped,
/// named, once it is further than its tolerance from its script.
#[test]
fn a_script_into_a_vehicle_is_held_and_stopped() {
    let s = Scenario::from_toml(DRIVEN_INTO, "driven-into").unwrap();
    let f = run(&s, FleetOptions::default());
    let (robot, ram) = (&f.vehicles[0], &f.vehicles[1]);
    assert_eq!(robot.outcome, Outcome::Goal, "{f:?}");
    assert!(robot.contact.is_none() && ram.contact.is_none(), "{f:?}");
    assert_eq!(ram.outcome, Outcome::Stopped, "{f:?}");
    let why = ram.stop_reason.as_deref().unwrap();
    assert!(why.contains("mm off its script (tolerance 50.0 mm)"), "{why}");
    assert!(ram.script_error.unwrap() <= 0.01, "where its supervisor passed it: {f:?}");
    assert!(ram.script_error_held.unwrap() > 0.05, "held, it fell behind: {f:?}");
    assert!(ram.min_vehicle_gap > 0.0 && ram.supervised_cycles > 0, "{f:?}");
    assert_eq!(f.outcome, Outcome::Stopped);
}

fn plan(args: &[&str], out: &Path) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_flowgate")).arg("plan").args(args).arg("--out").arg(out).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{text}");
    text
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("flowgate-fleet-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// `plan` on a fleet prints a line a vehicle and writes each into summary.json: name,
/// role, outcome, contact, and a scripted vehicle's script error; the fleet's outcome is
/// `goal` only with every navigating vehicle home.
#[test]
fn plan_names_every_vehicle() {
    let out = temp("e2");
    let e2 = root().join("scenarios/fleet/e2-scripted.toml");
    let text = plan(&[e2.to_str().unwrap()], &out);
    assert!(
        text.contains("note: vehicles[0] (oncoming): its script leaves the camera's view at (-0.815, 0.060)"),
        "{text}"
    );
    assert!(text.contains("oncoming     script   goal      script within"), "{text}");
    let summary: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["outcome"], "goal");
    let vehicles = summary["vehicles"].as_array().unwrap();
    assert_eq!(vehicles.iter().map(|v| v["name"].as_str().unwrap()).collect::<Vec<_>>(), ["robot", "oncoming"]);
    assert_eq!((vehicles[1]["role"].as_str(), vehicles[1]["outcome"].as_str()), (Some("script"), Some("goal")));
    assert!(vehicles[1]["contact"].is_null() && vehicles[1]["script_error"].as_f64().unwrap() < 0.01);
    assert!(vehicles[0]["script_error"].is_null());
    let plot = std::fs::read_to_string(out.join("trajectory.svg")).unwrap();
    assert!(plot.contains(">oncoming<") && plot.contains(">robot<") && plot.contains("outcome: goal"), "{plot}");

    // E5's plot draws its standing obstacle's footprint (a path of one point) in the
    // obstacles' red, and the robot's goal as a ring in the robot's blue.
    let out = temp("e5");
    plan(&[root().join("scenarios/fleet/e5-scripted.toml").to_str().unwrap()], &out);
    let plot = std::fs::read_to_string(out.join("trajectory.svg")).unwrap();
    let circles: Vec<&str> = plot.lines().filter(|l| l.starts_with("<circle")).collect();
    assert!(circles.iter().any(|c| c.contains(r##"fill="#d62728" fill-opacity="0.08""##)), "{plot}");
    assert!(circles.iter().any(|c| c.contains(r##"fill="#1f77b4" fill-opacity="0""##)), "{plot}");

    let out = temp("swap");
    let swap = root().join("scenarios/fleet/swap-4.toml");
    let text = plan(&[swap.to_str().unwrap(), "--sweep", "6"], &out);
    assert!(text.contains("every vehicle home, no contact: 100.00%"), "{text}");
    let lines = std::fs::read_to_string(out.join("fleet_episodes.jsonl")).unwrap();
    assert_eq!(lines.lines().count(), 6);
    let refused = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["plan", swap.to_str().unwrap(), "--sweep", "6", "--shard", "0/2"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && text.contains("--shard drives one robot"), "{text}");
}

/// What no fleet could run from is refused at load, naming the key and the numbers.
#[test]
fn a_fleet_that_cannot_run_is_refused_naming_the_key() {
    let base = DRIVEN_INTO;
    let vehicle = "[[vehicles]]\nname = \"ram\"\nrole = \"script\"\nstart = [0.45, 0.0]\nmotion = { kind = \"waypoints\", points = [[-0.45, 0.0]], speed = 0.05 }\n";
    let other = |extra: &str| base.replace(vehicle, &format!("{vehicle}\n{extra}\n"));
    let nav = |name: &str, start: &str, goal: &str| {
        format!("[[vehicles]]\nname = \"{name}\"\nrole = \"navigate\"\nstart = {start}\ngoal = {goal}\n")
    };
    let cases: Vec<(String, &str, &str)> = vec![
        (other(&nav("ram", "[0.0, 0.4]", "[0.0, -0.4]")), "`vehicles[1].name`", "is taken"),
        (other(&nav("Big One", "[0.0, 0.4]", "[0.0, -0.4]")), "`vehicles[1].name`", "lower-case letters"),
        (other(&nav("b", "[0.4, 0.05]", "[0.0, -0.4]")), "`vehicles[1].start`", "overlaps `vehicles[0].start`"),
        (other(&nav("b", "[0.0, 0.4]", "[0.05, 0.0]")), "`vehicles[1].goal`", "from the goal of `robot`"),
        (other(&nav("b", "[0.0, 0.4]", "[5.0, 0.0]")), "`vehicles[1].goal`", "outside the calibrated arena"),
        (
            other("[[vehicles]]\nname = \"b\"\nrole = \"navigate\"\nstart = [0.0, 0.4]\n"),
            "`vehicles[1].goal`",
            "needs a `goal`",
        ),
        (
            base.replace("speed = 0.05 }", "speed = 0.2 }"),
            "`vehicles[0].motion`",
            "faster than the vehicle's max_speed, 0.15 m/s",
        ),
        (
            base.replace("speed = 0.05 }", "speed = 0.12 }\nwheel_accel = 0.5"),
            "`vehicles[0].motion`",
            "falls 14.4 mm behind",
        ),
        (
            base.replace("points = [[-0.45, 0.0]], speed = 0.05", "points = [[0.0, 0.0], [0.0, 0.4]], speed = 0.08"),
            "`vehicles[0].motion.points`",
            "turns 90° at point 0 at 0.08 m/s",
        ),
        (
            base.replace("start = [0.45, 0.0]\n", "start = [0.45, 0.0]\nheading_deg = 90\n"),
            "`vehicles[0].heading_deg`",
            "off the script's first direction",
        ),
        (
            base.replace("start = [0.45, 0.0]\n", "start = [0.45, 0.0]\nradius = -1\n"),
            "`vehicles[0].radius`",
            "positive",
        ),
        (
            base.replace("start = [0.45, 0.0]\n", "start = [0.45, 0.0]\nheading_deg = nan\n"),
            "`vehicles[0].heading_deg`",
            "within ±360°, is NaN",
        ),
        (
            base.replace("start = [0.45, 0.0]\n", "start = [0.45, 0.0]\nlink_lost_at = -1\n"),
            "`vehicles[0].link_lost_at`",
            "must be 0 to time_limit (30 s)",
        ),
        (
            (0..7).fold(base.to_string(), |s, k| {
                s + &nav(
                    &format!("n{k}"),
                    &format!("[{:.2}, 0.5]", -0.6 + 0.2 * k as f64),
                    &format!("[{:.2}, -0.5]", -0.6 + 0.2 * k as f64),
                )
            }),
            "`vehicles`",
            "at most 7",
        ),
        (
            base.replace(vehicle, "")
                .replace("[sensing]", "[swap]\nvehicles = 8\ncircle_radius = 0.2\njitter = 0.01\n\n[sensing]"),
            "`swap.circle_radius`",
            "puts 8 vehicles 15.3 cm apart",
        ),
        (
            base.replace("[sensing]", "[swap]\nvehicles = 2\ncircle_radius = 0.3\n\n[sensing]"),
            "`vehicles`",
            "a swap places its own vehicles",
        ),
    ];
    for (text, key, why) in cases {
        let err = Scenario::from_toml(&text, "fleet").unwrap_err().to_string();
        assert!(err.contains(key) && err.contains(why), "{key} {why}: {err}");
    }
}

/// The bus load table in docs/fleet.md is what the whole stack measures: one vehicle's
/// frames over E1 (board, and CiA 402 drives), at their worst-case length, scaled to eight;
/// with boards, eight vehicles take under 40% of a 1 Mbit/s bus.
#[test]
fn the_bus_load_table_is_measured() {
    use flowgate::lab::bus_load::{measure, table};
    let e1 = Scenario::load(&root().join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let measured = table(&e1);
    println!("{measured}");
    let page = std::fs::read_to_string(root().join("docs/fleet.md")).unwrap();
    assert!(page.contains(&measured), "docs/fleet.md should carry, as measured:\n{measured}");
    let boards = measure(&e1, false).load(8);
    assert!(boards.bus < 0.40, "{boards:?}");
    assert!(boards.to_adapter < 1.0 && boards.from_adapter < 1.0, "{boards:?}");
}

/// A vehicle whose own link fails mid-crossing is stopped, named; its motors hold their last
/// command for their timeout and stop; the others treat it as a region until it stands, then
/// go round it to their goals, and nothing touches (60 episodes, each start moved by up to
/// 3 cm).
#[test]
fn a_vehicle_that_loses_its_link_stops_and_the_others_go_round() {
    let s = scenario("crossing-link-lost.toml");
    for i in 0..60 {
        let f = run(&place(&s, 1, i), FleetOptions::default());
        let b = &f.vehicles[2];
        assert_eq!((b.name.as_str(), b.outcome), ("b", Outcome::Fault), "episode {i}: {f:?}");
        let why = b.stop_reason.as_deref().unwrap();
        assert!(
            why.contains("its link failed at 2.50 s: its motors held their last command 200 ms, then stopped"),
            "{why}"
        );
        // 2.5 s at most 0.15 m/s and its hold after: it went no further.
        assert!(b.path_length < 0.15 * 2.7, "episode {i}: {f:?}");
        for v in f.vehicles.iter().filter(|v| v.name != "b") {
            assert_eq!(v.outcome, Outcome::Goal, "episode {i}: {} {f:?}", v.name);
        }
        assert!(f.vehicles.iter().all(|v| v.contact.is_none()), "episode {i}: {f:?}");
        assert_eq!(f.outcome, Outcome::Fault);
    }
}

/// A placement the scenario's checks would refuse at load (here a start jittered onto the
/// vehicle beside it) is not run: the episode runs the placement the file was loaded with.
#[test]
fn a_placement_the_checks_refuse_runs_as_loaded() {
    let side_by_side = DRIVEN_INTO
        .replace("start = [-0.3, 0.0]", "start = [-0.3, -0.0725]")
        .replace("position = [0.0, 0.0]", "position = [0.3, -0.0725]")
        .replace(
            "role = \"script\"\nstart = [0.45, 0.0]\nmotion = { kind = \"waypoints\", points = [[-0.45, 0.0]], speed = 0.05 }",
            "role = \"navigate\"\nstart = [-0.3, 0.0725]\ngoal = [0.3, 0.0725]",
        );
    let s = Scenario::from_toml(&side_by_side, "side-by-side").unwrap();
    let mut refused = 0;
    for i in 0..40 {
        let placed = place(&s, 1, i);
        let (a, b) = (placed.robot.start, placed.vehicles[0].start);
        let gap = (a[0] - b[0]).hypot(a[1] - b[1]) - 0.14;
        assert!(gap >= 0.0, "episode {i}: starts overlap by {:.1} mm", -gap * 1e3);
        refused += usize::from(a == s.robot.start && b == s.vehicles[0].start);
    }
    assert!(refused > 0 && refused < 40, "{refused} of 40 episodes fell back to the loaded placement");
}

/// The fleet's fault swarm: lost links, the operator's stops of one vehicle and the fleet's
/// e-stop drawn on the 4-vehicle swap (and on the crossing whose vehicle loses its link on
/// its own), judged by the fleet's invariants: none broken, every kind drawn and stopping
/// vehicles (docs/fleet.md, "The fleet's fault swarm", prints 10,000). The command says
/// so, keeps one episode's files, and refuses a policy.
#[test]
fn the_fleet_swarm_breaks_no_invariant() {
    use flowgate::lab::fleet::swarm;
    for (file, n) in [("swap-4.toml", 100), ("crossing-link-lost.toml", 40)] {
        let report = swarm::run(&scenario(file), n, 1, 2).unwrap();
        assert_eq!(report.broken_episodes, 0, "{file}: {report}\n{:?}", report.broken);
        assert!(report.faults.iter().chain(&report.stopped).all(|&k| k > 0), "{file}: {report}");
        assert!(report.unfaulted_home > 0 && report.unfaulted_home <= report.unfaulted, "{file}: {report}");
    }
    let out = temp("swarm");
    let file = root().join("scenarios/fleet/swap-4.toml");
    let said = plan(&["--swarm", "20", file.to_str().unwrap()], &out);
    assert!(said.contains("episodes that broke an invariant: 0 of 20"), "{said}");
    assert!(out.join("fleet_swarm.json").exists());
    let said = plan(&["--swarm", "20", "--episode", "3", file.to_str().unwrap()], &out);
    assert!(said.contains("episode 3 of the fleet swarm around Swap 4 (seed 1):"), "{said}");
    assert!(out.join("summary.json").exists() && out.join("trajectory.svg").exists());
    let refused = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["plan", "--swarm", "5", "--policy", "true"])
        .arg(&file)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && said.contains("leave --policy and --compare-obstacles out"), "{said}");
}

/// The 8-vehicle swap's swarm episodes that each of the fleet's rules holds (docs/fleet.md):
/// a stop while turning beside a standing vehicle (3140, 7661: a stop keeps the arc) and a
/// follower behind a vehicle its wheels have not yet taken where its command says (5540:
/// the ramps' lag). Each keeps every invariant, and in each the fault of its story comes.
/// And a stop after every vehicle has reached the end of its way is watched to rest.
#[test]
fn the_swarm_episodes_behind_the_fleets_rules_keep_every_invariant() {
    use flowgate::lab::fleet::swarm;
    let swap = scenario("swap-8.toml");
    for (index, stopped) in
        [(3140, "e-stop (every vehicle)"), (5540, "stopped by the operator"), (7661, "stopped by the operator")]
    {
        let (episode, summary) = swarm::episode(&swap, 1, index, None);
        assert!(episode.broken.is_empty(), "episode {index}: {:?}", episode.broken);
        assert!(
            summary.vehicles.iter().any(|v| v.stop_reason.as_deref() == Some(stopped)),
            "episode {index}: {summary:?}"
        );
        let active = summary.vehicles.iter().filter_map(|v| v.contact.as_ref()).filter(|c| c.active).count();
        assert_eq!(active, 0, "episode {index}: {summary:?}");
    }
    // E5's crossing vehicle, its script run out, stopped by the operator at 11.96 s: the run
    // goes on a second beyond the stop, long enough to see it at rest.
    let (episode, summary) = swarm::episode(&scenario("e5-scripted.toml"), 1, 102, None);
    assert!(episode.broken.is_empty(), "{:?}", episode.broken);
    let &(_, _, at) = episode.stopped.iter().find(|s| s.0 == 1).expect("the crossing vehicle stopped");
    assert!(at > 11.0 && summary.end_time >= at + 1.0, "stopped at {at} s, ended at {} s", summary.end_time);
}

/// A vehicle that waits neither creeps nor pivots into another. Episode 561 of the 4-vehicle
/// swap among people (`scenarios/people/swap-4.toml`, seed 1): `v3`, held by its supervisor
/// for some 390 cycles beside `v2` at its goal, its field pushing on, crept into it at the
/// robot's 2 mm/s tolerance; a vehicle now closes on nothing within its reach but as it
/// slows. Episode 92 of the 8-vehicle swap's swarm: `v2`, turning, finds its goal covered by
/// `v3` (whose link has failed) and waits; zero on each wheel pivoted it into `v5`, standing
/// beside it, at 3 cm/s, where the brake its supervisor certified keeps the arc.
#[test]
fn a_vehicle_that_waits_neither_creeps_nor_pivots_into_another() {
    use flowgate::lab::fleet::{swarm, sweep::episode};
    let people = Scenario::load(&root().join("scenarios/people/swap-4.toml")).unwrap();
    let e = episode(&people, 1, 561, FleetOptions::default());
    assert_eq!((e.vehicle_contacts, e.active_contacts), (0, 0), "{e:?}");
    let (episode, summary) = swarm::episode(&scenario("swap-8.toml"), 1, 92, None);
    assert!(episode.broken.is_empty(), "{:?}", episode.broken);
    let v2 = summary.vehicles.iter().find(|v| v.name == "v2").expect("v2");
    assert_eq!(v2.stop_reason.as_deref(), Some("goal blocked by vehicle v3"), "{summary:?}");
    assert!(summary.vehicles.iter().all(|v| v.contact.is_none()), "{summary:?}");
}
