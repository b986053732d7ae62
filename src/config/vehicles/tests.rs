use super::super::{ConfigError, Rig, RigFile};
use super::VehicleMotors;

const EXAMPLE: &str = include_str!("../../../rig.example.toml");

/// The example rig (robot LEDs 1 and 2, obstacles 3 and 4, the board at node 1) with
/// `extra` appended: `[[vehicles]]` entries, or a section.
fn rig(extra: &str) -> Result<Rig, ConfigError> {
    RigFile::from_toml(&format!("{EXAMPLE}\n{extra}"), "rig.toml")?.rig("rig.toml")
}

/// The example driving CiA 402 drives at nodes 1 and 2 (gateway node 127).
fn drives_rig(extra: &str) -> Result<Rig, ConfigError> {
    let text = EXAMPLE.replace("protocol = \"pcl80k\"", "protocol = \"cia402\"");
    RigFile::from_toml(&format!("{text}\n[cia402]\nleft_node = 1\nright_node = 2\n{extra}"), "rig.toml")?
        .rig("rig.toml")
}

fn refused(result: Result<Rig, ConfigError>) -> (String, String) {
    match result {
        Err(ConfigError::Invalid { invalid, .. }) => (invalid.key, invalid.why),
        Err(other) => panic!("refused, but not as invalid: {other}"),
        Ok(_) => panic!("accepted"),
    }
}

const TWO: &str = "
[[vehicles]]
name = \"oncoming\"
front_led = 5
rear_led = 6
node = 2

[[vehicles]]
name = \"b\"
front_led = 7
rear_led = 8
node = 3
radius = 0.05
max_speed = 0.12
";

#[test]
fn vehicles_join_the_schedule_with_the_robots_body_by_default() {
    let r = rig(TWO).unwrap();
    let leds: Vec<u8> = r.schedule.slots().iter().map(|s| s.led).collect();
    assert_eq!(leds, [1, 2, 3, 4, 5, 6, 7, 8], "the robot's, the obstacles', then each vehicle's pair");
    assert_eq!(r.sample_period.as_micros(), 8 * 4000 + 1000);
    let [a, b] = &r.vehicles[..] else { panic!("two vehicles") };
    assert_eq!((a.name.as_str(), a.front_led, a.rear_led), ("oncoming", 5, 6));
    assert_eq!(a.motors, VehicleMotors::Board(flowgate_protocol::motor::NodeId::new(2).unwrap()));
    assert_eq!((a.robot.radius, a.robot.max_speed, a.drive.wheel_base), (0.07, 0.15, 0.108), "the robot's");
    assert_eq!((a.led_geometry.front, a.led_geometry.rear), (0.035, 0.035), "[leds]' offsets");
    assert_eq!((b.robot.radius, b.robot.max_speed), (0.05, 0.12), "its own");
    // A single-robot config is as it was.
    let one = rig("").unwrap();
    assert!(one.vehicles.is_empty());
    assert_eq!(one.schedule.slots().len(), 4);
}

#[test]
fn drives_of_several_vehicles_share_the_bus_when_their_identifiers_keep_apart() {
    let r =
        drives_rig("[[vehicles]]\nname = \"b\"\nfront_led = 5\nrear_led = 6\nleft_node = 3\nright_node = 4\n").unwrap();
    assert!(matches!(r.vehicles[0].motors, VehicleMotors::Drives { .. }));
}

#[test]
fn a_vehicle_on_anothers_led_or_name_is_refused_naming_both() {
    let one = |body: &str| rig(&format!("[[vehicles]]\n{body}"));
    let cases = [
        (
            "name = \"a\"\nfront_led = 1\nrear_led = 6\nnode = 2",
            "vehicles[0].front_led",
            "LED 1 is the robot's (leds.robot_front)",
        ),
        (
            "name = \"a\"\nfront_led = 5\nrear_led = 4\nnode = 2",
            "vehicles[0].rear_led",
            "LED 4 is an obstacle's (leds.obstacles[1].led)",
        ),
        (
            "name = \"a\"\nfront_led = 5\nrear_led = 5\nnode = 2",
            "vehicles[0].rear_led",
            "is 5, the vehicle's front LED too",
        ),
        (
            "name = \"robot\"\nfront_led = 5\nrear_led = 6\nnode = 2",
            "vehicles[0].name",
            "\"robot\" is the first vehicle's",
        ),
        ("name = \"Car-1\"\nfront_led = 5\nrear_led = 6\nnode = 2", "vehicles[0].name", "is not a name"),
    ];
    for (body, key, why) in cases {
        let (k, w) = refused(one(body));
        assert_eq!(k, key, "{body}");
        assert!(w.contains(why), "{body}: {w}");
    }
    let twice = "[[vehicles]]\nname = \"a\"\nfront_led = 5\nrear_led = 6\nnode = 2\n\
                 [[vehicles]]\nname = \"a\"\nfront_led = 7\nrear_led = 6\nnode = 3\n";
    assert_eq!(refused(rig(twice)), ("vehicles[1].name".into(), "\"a\" is vehicles[0]'s name too".into()));
    let (k, w) = refused(rig(&twice.replacen("name = \"a\"\nfront_led = 7", "name = \"b\"\nfront_led = 7", 1)));
    assert_eq!((k.as_str(), w.as_str()), ("vehicles[1].rear_led", "LED 6 is vehicles[0] (a)'s"));
}

#[test]
fn can_identifiers_used_twice_on_the_bus_are_refused_naming_both_devices() {
    let vehicle = |can: &str| format!("[[vehicles]]\nname = \"b\"\nfront_led = 5\nrear_led = 6\n{can}\n");
    // Two boards at one node: the e-stop to one stops both.
    let (k, w) = refused(rig(&vehicle("node = 1")));
    assert_eq!(k, "vehicles");
    assert_eq!(
        w,
        "CAN id 0x001 is e-stop to the board (the robot) and e-stop to the board (vehicles[0] (b)): \
         on one bus each would take the other's frames"
    );
    // Drives on other node numbers than the boards', and still on the boards' identifiers:
    // the robot's left drive's TPDO1 is the board at node 1's config.
    let (_, w) = refused(rig(&vehicle("protocol = \"cia402\"\nleft_node = 1\nright_node = 4")));
    assert!(w.contains("the section is missing"), "a board's rig has no [cia402]: {w}");
    let (k, w) = refused(drives_rig(&vehicle("protocol = \"pcl80k\"\nnode = 3")));
    assert_eq!(k, "vehicles");
    assert_eq!(
        w,
        "CAN id 0x000 is e-stop to every board (the gateway, to the boards) and NMT to every drive (the gateway, to \
         the drives): on one bus each would take the other's frames"
    );
    let (_, w) = refused(drives_rig(&vehicle("protocol = \"pcl80k\"\nnode = 1")));
    assert!(w.starts_with("CAN id 0x081 is the drive's EMCY (the robot, left) and the board's emergency"), "{w}");
    // Drives: a node taken twice; the gateway's own heartbeat on a drive's.
    let (_, w) = refused(drives_rig(&vehicle("left_node = 2\nright_node = 3")));
    assert!(
        w.starts_with(
            "CAN id 0x082 is the drive's EMCY (the robot, right) and the drive's EMCY (vehicles[0] (b), left)"
        ),
        "{w}"
    );
    let (_, w) = refused(drives_rig(&vehicle("left_node = 126\nright_node = 127")));
    assert!(w.contains("0x77F is the drive's heartbeat (vehicles[0] (b), right) and the gateway's heartbeat"), "{w}");
}

#[test]
fn more_leds_than_the_schedule_holds_and_bad_limits_are_refused() {
    // Fourteen boards' vehicles and the example's two obstacles: 32 LEDs, as many circles
    // in each field as the planner takes (16).
    let boards = |n: usize| -> String {
        (0..n)
            .map(|k| {
                format!(
                    "[[vehicles]]\nname = \"v{k}\"\nfront_led = {}\nrear_led = {}\nnode = {}\n",
                    10 + 2 * k,
                    11 + 2 * k,
                    k + 2
                )
            })
            .collect()
    };
    let (k, _) = refused(rig(&boards(14)));
    assert_eq!(k, "safety.sample_timeout_ms", "at 4 ms a slot T = 129 ms: the robot's board would stop first");
    let short = |text: &str| text.replace("slot_us = 4000 ", "slot_us = 500 ");
    let r =
        RigFile::from_toml(&short(&format!("{EXAMPLE}\n{}", boards(14))), "rig.toml").unwrap().rig("rig.toml").unwrap();
    assert_eq!(r.schedule.slots().len(), 32);
    let three = short(EXAMPLE).replace("obstacles = [", "obstacles = [ { led = 60, radius = 0.05 },");
    let (k, w) =
        refused(RigFile::from_toml(&format!("{three}\n{}", boards(14)), "rig.toml").and_then(|f| f.rig("rig.toml")));
    assert_eq!(k, "vehicles");
    assert_eq!(w, "15 vehicles and 3 obstacles: each vehicle's field would take 17 circles, at most 16");
    // Drives: 31 vehicles, 66 LEDs, more than a schedule holds (the field's limit is a
    // planner's, the schedule's the protocol's: the LEDs are counted first).
    let drives: String = (0..31)
        .map(|k| {
            format!(
                "[[vehicles]]\nname = \"v{k}\"\nfront_led = {}\nrear_led = {}\nleft_node = {}\nright_node = {}\n",
                100 + 2 * k,
                101 + 2 * k,
                3 + 2 * k,
                4 + 2 * k
            )
        })
        .collect();
    let (k, w) = refused(drives_rig(&drives));
    assert_eq!(k, "vehicles");
    assert_eq!(w, "66 LEDs (the robot's 2, 2 obstacles', 2 for each of 31 vehicles): the schedule holds at most 64");
    let one = |extra: &str| rig(&format!("[[vehicles]]\nname = \"b\"\nfront_led = 5\nrear_led = 6\nnode = 2\n{extra}"));
    let cases = [
        ("max_speed = 0.3", "vehicles[0].max_speed"),
        ("radius = 0", "vehicles[0].radius"),
        ("command_timeout_ms = 10", "vehicles[0].command_timeout_ms"),
        ("command_timeout_ms = 100", "vehicles[0].command_timeout_ms"),
        ("left_node = 3", "vehicles[0].node"),
        ("front_offset = -0.01", "vehicles[0].front_offset"),
    ];
    for (extra, key) in cases {
        let (k, w) = refused(one(extra));
        assert_eq!(k, key, "{extra}: {w}");
    }
    let (_, w) = refused(one("command_timeout_ms = 100"));
    assert!(w.starts_with("is 100 ms: `safety."), "the watchdog it would outlast: {w}");
    let (k, w) = refused(rig("[[vehicles]]\nname = \"b\"\nfront_led = 5\nrear_led = 6\nnode = 16\n"));
    assert_eq!((k.as_str(), w.as_str()), ("vehicles[0].node", "must be 1-15, is 16"));
}

/// A vehicle's goal for `flowgate run --arm`: taken as the robot's `[goal]` is, and refused
/// at load where no vehicle could end (outside the view, inside the lane's walls or the
/// furniture, on another vehicle's goal), naming the key and the numbers.
#[test]
fn a_vehicles_goal_is_checked_as_the_robots() {
    let with_goal = |goal: &str| format!("{TWO}goal = {goal}\n");
    let r = rig(&with_goal("[0.3, 0.1]")).unwrap();
    let g = r.vehicles[1].goal.unwrap();
    assert_eq!((g.position, g.tolerance), ([0.3, 0.1], 0.02), "the default tolerance");
    assert!(r.vehicles[0].goal.is_none());

    let (k, w) = refused(rig(&with_goal("[9.0, 0.0]")));
    assert_eq!(k, "vehicles[1].goal");
    assert!(w.starts_with("[9.0, 0.0] lies outside the calibrated arena"), "{w}");
    // The robot's [goal] is (0.6, 0): vehicle b (radius 0.05) 0.1 m from it, the robot 0.07.
    let (k, w) = refused(rig(&with_goal("[0.5, 0.0]")));
    assert_eq!(k, "vehicles[1].goal");
    assert_eq!(
        w,
        "[0.5, 0.0] is 0.100 m from goal.position [0.6, 0.0]: two vehicles 0.120 m across could not both stand there"
    );
    let (k, w) = refused(rig(&format!("{TWO}goal_tolerance = 0.05\n")));
    assert_eq!((k.as_str(), w.as_str()), ("vehicles[1].goal_tolerance", "is set, but `goal` is not"));
    let room = "[[static_obstacles]]\npoints = [[0.25, 0.05], [0.35, 0.05], [0.35, 0.15], [0.25, 0.15]]\n";
    let (k, w) = refused(rig(&format!("{room}{}", with_goal("[0.3, 0.1]"))));
    assert_eq!(k, "vehicles[1].goal");
    assert!(w.starts_with("[0.3, 0.1]: "), "inside the furniture: {w}");
}

/// A scripted vehicle in rig.toml: its `start` and `motion` as a scenario's; a constant
/// motion laid out until it would leave the arena, cut there and said; followed through its
/// supervisor as an outside planner's commands. The keys of the other role, a start out of
/// view, a script its wheels cannot follow: refused, named.
#[test]
fn a_scripted_vehicle_follows_its_motion_cut_at_the_arenas_edge() {
    let scripted = |keys: &str| format!("{TWO}role = \"script\"\n{keys}\n");
    let r = rig(&scripted("start = [0.3, 0.1]\nmotion = { kind = \"constant\", velocity = [-0.05, 0.0] }")).unwrap();
    let s = r.vehicles[1].script.as_ref().unwrap();
    assert_eq!((s.tolerance, s.script.speed()), (0.05, 0.05));
    let note = s.cut.as_deref().unwrap();
    let at = "at (-0.773, 0.100) after 21.46 s: the vehicle stops there";
    assert_eq!(note, format!("vehicles[1] (b): its script leaves the room's free region {at}"), "docs/fleet.md");
    let end = s.script.last_point();
    assert!(end.re < 0.0 && (end.im - 0.1).abs() < 1e-9, "westward along y = 0.1 to the arena's edge: {end}");
    assert!(r.vehicles[1].goal.is_none() && r.vehicles[0].script.is_none());
    let outside = matches!(r.vehicles[1].driven.control.source, crate::control::CommandSource::Outside { .. });
    assert!(outside, "the follower's commands go through its supervisor");

    let waypoints = "start = [0.3, 0.1]\nmotion = { kind = \"waypoints\", points = [[0.0, 0.1]], speed = 0.05 }";
    let r = rig(&scripted(waypoints)).unwrap();
    let s = r.vehicles[1].script.as_ref().unwrap();
    assert!(s.cut.is_none(), "inside the arena: as written");
    assert!((s.script.end_time().unwrap() - 6.0).abs() < 1e-9, "{:?}", s.script.end_time());

    let cases = [
        (format!("{TWO}start = [0.3, 0.1]\n"), "vehicles[1].start", "is a scripted vehicle's"),
        (
            scripted("start = [0.3, 0.1]\ngoal = [0.0, 0.0]\nmotion = { kind = \"stationary\" }"),
            "vehicles[1].goal",
            "is a navigating vehicle's",
        ),
        (scripted("start = [0.3, 0.1]"), "vehicles[1].motion", "is missing"),
        (
            scripted("start = [9.0, 0.1]\nmotion = { kind = \"stationary\" }"),
            "vehicles[1].start",
            "[9.0, 0.1] lies outside the calibrated arena",
        ),
        (
            scripted("start = [0.3, 0.1]\nmotion = { kind = \"constant\", velocity = [-0.2, 0.0] }"),
            "vehicles[1].motion",
            "moves at 0.2 m/s: faster than the vehicle's max_speed, 0.12 m/s",
        ),
        (
            scripted("start = [0.35, 0.1]\nmotion = { kind = \"stationary\" }").replacen(
                "node = 2\n",
                "node = 2\nrole = \"script\"\nstart = [0.3, 0.1]\nmotion = { kind = \"stationary\" }\n",
                1,
            ),
            "vehicles[1].start",
            "[0.35, 0.1] is 0.050 m from vehicles[0].start [0.3, 0.1]: two vehicles 0.120 m across",
        ),
        (
            scripted("start = [0.3, 0.1]\nscript_tolerance = 0.001\nmotion = { kind = \"stationary\" }"),
            "vehicles[1].script_tolerance",
            "must be 0.01 to 2 m",
        ),
    ];
    for (text, key, why) in cases {
        let (k, w) = refused(rig(&text));
        assert_eq!(k, key, "{w}");
        assert!(w.starts_with(why), "{key}: {w}");
    }
}

/// A rig with vehicles brakes its stops on the arc by default; a single robot's stop is as
/// it was (zero to each wheel) unless `safety.stop_brake` asks for the arc; a brake the
/// gateway does not know is refused, naming it.
#[test]
fn a_fleet_stops_on_the_arc_and_a_single_robot_as_configured() {
    use crate::config::StopBrake;
    assert_eq!(rig(TWO).unwrap().safety.stop_brake, StopBrake::Arc);
    assert_eq!(rig("").unwrap().safety.stop_brake, StopBrake::EachWheel);
    let arc = EXAMPLE.replace("[safety]\n", "[safety]\nstop_brake = \"arc\"\n");
    let r = RigFile::from_toml(&arc, "rig.toml").unwrap().rig("rig.toml").unwrap();
    assert_eq!(r.safety.stop_brake, StopBrake::Arc);
    let each = format!("{}\n{TWO}", EXAMPLE.replace("[safety]\n", "[safety]\nstop_brake = \"each-wheel\"\n"));
    assert_eq!(
        RigFile::from_toml(&each, "rig.toml").unwrap().rig("rig.toml").unwrap().safety.stop_brake,
        StopBrake::EachWheel
    );
    let bad = EXAMPLE.replace("[safety]\n", "[safety]\nstop_brake = \"coast\"\n");
    let Err(e) = RigFile::from_toml(&bad, "rig.toml") else { panic!("an unknown brake was taken") };
    let said = e.to_string();
    assert!(said.contains("stop_brake") && said.contains("coast"), "{said}");
}
