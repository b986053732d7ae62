//! A fleet through the whole stack: one gateway core drives every vehicle of a scenario
//! against the simulator's firmware (one PSD controller lighting every vehicle's LEDs, one
//! CAN bus with every vehicle's board), in deterministic virtual time. Each vehicle is armed,
//! given its goal and started as an operator would (`Input::VehicleRequest`), is seen by the
//! camera, plans with the others as moving obstacles at their commanded velocities, and is
//! stopped and e-stopped on its own or with the fleet.

use std::path::Path;

use flowgate::control::script::Script;
use flowgate::gateway::core::operator::{Goal, Refusal, Request};
use flowgate::gateway::core::{State, StopReason};
use flowgate::lab::fleet::sweep::place;
use flowgate::lab::virtual_rig::{Options, VirtualRig};
use flowgate::lab::Scenario;

fn scenario(name: &str) -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/fleet").join(name)).unwrap()
}

/// Vehicle `k`'s goal and how far from it counts as there (its tolerance, and a centimetre
/// for the stop's ramp).
fn goal(s: &Scenario, k: usize) -> ([f64; 2], f64) {
    let g = s.vehicle(k).sim.goal;
    (g.position, g.tolerance + 0.01)
}

/// Every vehicle of the 2- and 4-vehicle swaps (the loaded placement and jittered ones)
/// reaches its goal through the whole stack, stopped there by the gateway; nothing touches
/// and no motion is commanded outside Running.
#[test]
fn every_vehicle_of_a_swap_reaches_its_goal_through_the_whole_stack() {
    for (name, episodes) in [("swap-2.toml", 4), ("swap-4.toml", 6)] {
        let loaded = scenario(name);
        for i in 0..episodes {
            let s = if i == 0 { loaded.clone() } else { place(&loaded, 7, i) };
            let mut rig = VirtualRig::new(&s, Options::default());
            rig.run_until(s.time_limit.min(30.0));
            let core = rig.core();
            let n = core.vehicle_count();
            assert_eq!(n, 1 + s.vehicles.len());
            for k in 0..n {
                let state = core.vehicle_state(k).unwrap();
                assert_eq!(state, State::Stopped(StopReason::GoalReached), "{name} episode {i}: vehicle {k}");
                let (at, within) = goal(&s, k);
                let p = rig.fleet().world(k).pose().position;
                let off = (p.re - at[0]).hypot(p.im - at[1]);
                assert!(off <= within, "{name} episode {i}: vehicle {k} ends {off:.3} m from its goal");
                assert!(rig.fleet().world(k).first_contact().is_none(), "{name} episode {i}: vehicle {k}");
                assert!(rig.fleet().vehicle_contact(k).is_none(), "{name} episode {i}: vehicle {k}");
            }
            assert_eq!(rig.motion_outside_running(), 0, "{name} episode {i}");
        }
    }
}

/// Arm, goal and start each vehicle; `estop` for one vehicle stops that one only; `estop`
/// without a vehicle stops every vehicle; each is reset on its own and driven again to
/// Running, without a restart.
#[test]
fn one_vehicles_estop_stops_it_and_the_fleets_stops_every_vehicle() {
    let s = scenario("swap-4.toml");
    let mut rig = VirtualRig::new(&s, Options { wait_for_operator: true, ..Default::default() });
    rig.run_until(0.5);
    let start = |rig: &mut VirtualRig, k: u8| {
        let (at, _) = goal(&s, usize::from(k));
        rig.vehicle_request(k, &Request::Arm).unwrap();
        rig.vehicle_request(k, &Request::Goal { goals: vec![Goal { position: at, tolerance: 0.02 }] }).unwrap();
        rig.vehicle_request(k, &Request::Start).unwrap();
    };
    for k in 0..4 {
        start(&mut rig, k);
    }
    rig.run_until(1.5);
    let states = |rig: &VirtualRig| (0..4).map(|k| rig.core().vehicle_state(k).unwrap()).collect::<Vec<_>>();
    assert_eq!(states(&rig), [State::Running; 4]);
    assert_eq!(rig.vehicle_request(9, &Request::Arm), Err(Refusal::NoVehicle { index: 9, count: 4 }), "no vehicle 9");

    rig.vehicle_request(2, &Request::EStop).unwrap();
    rig.run_until(2.0);
    let after_one = states(&rig);
    assert_eq!(after_one[2], State::Fault(StopReason::OperatorEStop));
    assert_eq!([after_one[0], after_one[1], after_one[3]], [State::Running; 3], "the others drive on");
    assert_eq!(rig.fleet().world(2).wheel_speeds(), [0.0; 2], "vehicle 2 at rest");

    rig.request(&Request::EStop).unwrap();
    rig.run_until(2.5);
    assert_eq!(states(&rig), [State::Fault(StopReason::OperatorEStop); 4]);
    for k in 0..4 {
        assert_eq!(rig.fleet().world(k).wheel_speeds(), [0.0; 2], "vehicle {k} at rest");
    }
    let path = |rig: &VirtualRig| (0..4).map(|k| rig.fleet().world(k).truth().path_length).collect::<Vec<_>>();
    let stood = path(&rig);
    rig.run_until(3.5);
    assert_eq!(path(&rig), stood, "nothing moves after the fleet's e-stop");
    assert_eq!(rig.motion_outside_running(), 0);

    // The way back: each vehicle reset on its own, then armed and started again.
    rig.vehicle_request(1, &Request::Reset).unwrap();
    assert_eq!(rig.core().vehicle_state(1), Some(State::Idle));
    assert_eq!(rig.core().vehicle_state(3), Some(State::Fault(StopReason::OperatorEStop)), "reset is per vehicle");
    for k in [0, 2, 3] {
        rig.vehicle_request(k, &Request::Reset).unwrap();
    }
    for k in 0..4 {
        start(&mut rig, k);
    }
    rig.run_until(4.5);
    assert_eq!(states(&rig), [State::Running; 4]);
    assert!((0..4).all(|k| rig.fleet().world(k).truth().path_length > stood[k] + 0.02), "every vehicle drives again");
}

/// A vehicle whose own CAN link fails mid-crossing (its board no longer heard, nor hearing)
/// is stopped by the gateway, named by its board's heartbeat; the others keep clear of where
/// it could still go while its board holds its last command, and reach their goals untouched.
#[test]
fn a_vehicle_that_loses_its_link_is_stopped_named_and_the_others_go_round() {
    let s = scenario("crossing-link-lost.toml");
    for i in 0..4 {
        let placed = if i == 0 { s.clone() } else { place(&s, 1, i) };
        let mut rig = VirtualRig::new(&placed, Options::default());
        rig.run_until(placed.time_limit.min(30.0));
        let core = rig.core();
        assert_eq!(core.vehicle_name(2), "b");
        // b's board is node 3 (the robot's 1, a's 2).
        assert_eq!(core.vehicle_state(2), Some(State::Fault(StopReason::HeartbeatLost { node: 3 })), "episode {i}");
        for k in [0, 1, 3] {
            assert_eq!(
                core.vehicle_state(k),
                Some(State::Stopped(StopReason::GoalReached)),
                "episode {i}: vehicle {k}"
            );
        }
        for k in 0..4 {
            assert!(rig.fleet().vehicle_contact(k).is_none(), "episode {i}: vehicle {k}");
            assert!(rig.fleet().world(k).first_contact().is_none(), "episode {i}: vehicle {k}");
        }
        assert_eq!(rig.fleet().world(2).wheel_speeds(), [0.0; 2], "b's board stopped itself");
    }
}

/// `flowgate run` on a fleet the simulator serves over ptys: `flowgate ctl --vehicle NAME`
/// arms each vehicle, sets its goal and starts it; in the world's truth every vehicle reaches
/// its goal and nothing touches. A vehicle the rig does not have is refused, naming the rig's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn flowgate_run_drives_a_fleet_from_ctl() {
    use flowgate::gateway::core::operator::StateName;
    use flowgate::gateway::shell::control_client::ControlClient;
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};

    let s = scenario("swap-2.toml");
    let handle = flowgate_sim::rig::start(flowgate_sim::rig::RigConfig::new(s.sim.clone())).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
    let dir = std::env::temp_dir().join(format!("flowgate-fleet-run-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let socket = dir.join("control.sock");
    let mut cfg = s.rig_file(&handle.psd_path, &can, None);
    cfg.operator.socket = Some(socket.clone());
    std::fs::write(dir.join("rig.toml"), cfg.to_toml()).unwrap();
    /// The gateway process, killed however the test ends.
    struct Gateway(std::process::Child);
    impl Drop for Gateway {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let gateway = Gateway(
        Command::new(env!("CARGO_BIN_EXE_flowgate"))
            .args(["run", "--config"])
            .arg(dir.join("rig.toml"))
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.join("gateway.log")).unwrap())
            .spawn()
            .unwrap(),
    );
    let ctl = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_flowgate"))
            .arg("ctl")
            .arg("--socket")
            .arg(&socket)
            .args(args)
            .output()
            .unwrap()
    };
    // Await the event: the gateway answers on its socket and sees every vehicle's pose.
    let seen = Instant::now() + Duration::from_secs(10);
    loop {
        let status = ControlClient::connect(&socket).and_then(|mut c| c.status());
        if status.is_ok_and(|st| st.pose.is_some() && st.vehicles.iter().all(|v| v.pose.is_some())) {
            break;
        }
        assert!(Instant::now() < seen, "the gateway sees every vehicle within 10 s");
        tokio::time::sleep(Duration::from_millis(50)).await; // polling the socket until it answers
    }
    // Each armed and given its goal, then both started: neither waits on the other's goal
    // for a vehicle that is not yet under way.
    for (name, k) in [("robot", 0), ("v1", 1)] {
        let ([x, y], _) = goal(&s, k);
        for args in [vec!["arm"], vec!["goal", &x.to_string(), &y.to_string()]] {
            let out = ctl(&[&["--vehicle", name][..], &args].concat());
            assert!(out.status.success(), "{name} {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        }
    }
    let mut client = ControlClient::connect(&socket).unwrap();
    for name in ["robot", "v1"] {
        let reply = client.ask_for(Some(name), &Request::Start).unwrap();
        assert!(reply.ok, "{name}: {reply:?}");
    }
    let nobody = ctl(&["--vehicle", "nobody", "arm"]);
    assert!(!nobody.status.success());
    let text = String::from_utf8_lossy(&nobody.stderr);
    assert!(text.contains("no vehicle \"nobody\": the rig's are robot, v1"), "{text}");
    // Await the event: both vehicles stopped at their goals.
    let home = Instant::now() + Duration::from_secs(30);
    let arrived = |st: &flowgate::gateway::core::operator::Status| {
        let at_goal =
            |name: StateName, reason: Option<&str>| name == StateName::Stopped && reason == Some("goal reached");
        at_goal(st.state.name, st.state.reason.as_deref())
            && st.vehicles.iter().all(|v| at_goal(v.state.name, v.state.reason.as_deref()))
    };
    loop {
        let status = ControlClient::connect(&socket).unwrap().status().unwrap();
        if arrived(&status) {
            break;
        }
        assert!(Instant::now() < home, "both vehicles home within 30 s: {status:?}");
        tokio::time::sleep(Duration::from_millis(100)).await; // polling the socket for the states
    }
    let shown = String::from_utf8_lossy(&ctl(&["status"]).stdout).into_owned();
    assert!(shown.contains("vehicle v1") && shown.contains("stopped: goal reached"), "{shown}");
    drop(gateway);
    let truth = handle.stop().await;
    for (k, v) in truth.summary.vehicles.iter().enumerate() {
        let (at, within) = goal(&s, k);
        let off = (v.final_position[0] - at[0]).hypot(v.final_position[1] - at[1]);
        assert!(off <= within, "{} ends {off:.3} m from its goal", v.name);
        assert!(v.contact.is_none() && v.vehicle_contact.is_none(), "{v:?}");
    }
    assert_eq!(truth.summary.vehicles.len(), 2);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `flowgate demo --scenario` of a fleet: the simulator and the gateway over ptys, every
/// navigating vehicle armed and started at the first stream (its `[[vehicles]] goal`), all
/// home with no contact in the world's truth; a scripted vehicle (E5's crossing one) is
/// driven along its script by the gateway to its end.
#[test]
fn the_demo_drives_a_fleet_and_a_script() {
    use std::process::Command;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = std::env::temp_dir().join(format!("flowgate-demo-fleet-{}", std::process::id()));
    let demo = |file: &str| {
        let run = Command::new(env!("CARGO_BIN_EXE_flowgate"))
            .args(["demo", "--scenario"])
            .arg(root.join("scenarios/fleet").join(file))
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&run.stdout).to_string();
        assert!(run.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&run.stderr));
        assert!(stdout.contains("outcome          goal reached, no contact"), "{stdout}");
        stdout
    };
    let stdout = demo("swap-2.toml");
    assert!(stdout.contains("vehicle v1       at its goal, no contact"), "{stdout}");
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("truth.json")).unwrap()).unwrap();
    let names: Vec<&str> =
        truth["summary"]["vehicles"].as_array().unwrap().iter().map(|v| v["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["robot", "v1"]);
    // The plot draws every vehicle's true path, each named at its start.
    let plot = |out: &Path| std::fs::read_to_string(out.join("trajectory.svg")).unwrap();
    let svg = plot(&out);
    assert!(svg.contains("| 2 vehicles | outcome: goal |") && svg.contains(">v1</text>"), "{svg}");
    let stdout = demo("e5-scripted.toml");
    assert!(stdout.contains("vehicle crossing at its script's end, no contact"), "{stdout}");
    assert!(plot(&out).contains(">crossing</text>"));
    let _ = std::fs::remove_dir_all(&out);
}

/// A scripted vehicle through the gateway: it takes no goal; it is guarded as every vehicle
/// is; stopped, it is started again along its script from the start; it is not started away
/// from its script's start. E2's oncoming vehicle, its
/// script running head-on into the robot standing idle in the lane, is held by its
/// supervisor short of the robot (no contact), and once its script has run more than its
/// tolerance ahead of it, it is stopped, named with the numbers.
#[test]
fn a_scripted_vehicle_is_held_short_of_a_standing_robot_and_stopped_off_its_script() {
    let s = scenario("e2-scripted.toml");
    let mut rig = VirtualRig::new(&s, Options { wait_for_operator: true, ..Default::default() });
    rig.run_until(0.5);
    let goal = Request::Goal { goals: vec![Goal { position: [0.0, 0.0], tolerance: 0.02 }] };
    assert_eq!(rig.vehicle_request(1, &goal), Err(Refusal::Scripted { name: "oncoming".into() }));
    let go = |rig: &mut VirtualRig| {
        rig.vehicle_request(1, &Request::Arm).unwrap();
        rig.vehicle_request(1, &Request::Start).unwrap();
    };
    go(&mut rig);
    rig.run_until(25.0);
    let core = rig.core();
    let Some(State::Stopped(StopReason::OffScript { error_mm, tolerance_mm })) = core.vehicle_state(1) else {
        panic!("{:?}", core.vehicle_state(1));
    };
    assert_eq!(tolerance_mm, 50);
    assert!((50..60).contains(&error_mm), "stopped as it passed its tolerance: {error_mm} mm");
    assert_eq!(core.vehicle_state(0), Some(State::Idle), "the robot was never started");
    let script = core.vehicle_script(1).unwrap();
    assert!(script.largest <= 0.01, "within 1 cm wherever its supervisor passed it: {script:?}");
    assert!(script.largest_held > 0.05, "{script:?}");
    for k in 0..2 {
        assert!(rig.fleet().world(k).first_contact().is_none(), "vehicle {k}");
        assert!(rig.fleet().vehicle_contact(k).is_none(), "vehicle {k}");
    }
    let gap = rig.fleet().min_vehicle_gap(1);
    assert!(gap > 0.0 && gap < 0.06, "held short of the robot, not far off: {gap:.3} m");
    assert_eq!(rig.motion_outside_running(), 0);

    // Stopped a little way along and started again, without a restart: its script from the
    // start, which the vehicle, a few centimetres past it, waits for and follows again.
    let mut rig = VirtualRig::new(&s, Options { wait_for_operator: true, ..Default::default() });
    rig.run_until(0.5);
    go(&mut rig);
    rig.run_until(1.0);
    assert_eq!(rig.core().vehicle_state(1), Some(State::Running));
    rig.vehicle_request(1, &Request::Stop).unwrap();
    rig.run_until(1.5);
    assert_eq!(rig.core().vehicle_state(1), Some(State::Stopped(StopReason::Operator)));
    let (at, start) = (rig.fleet().world(1).pose().position, s.vehicles[0].start);
    let off = (at.re - start[0]).hypot(at.im - start[1]);
    assert!((0.01..0.05).contains(&off), "it had gone {off:.3} m along");
    go(&mut rig);
    rig.run_until(4.0);
    assert_eq!(rig.core().vehicle_state(1), Some(State::Running), "back to Running");
    let again = rig.core().vehicle_script(1).unwrap();
    assert!(again.along > 2.0 && again.error < 0.01, "on its script again: {again:?}");

    // Its script moved 10 cm from where the vehicle stands: the start is refused, named.
    fn moved(rig: &mut flowgate::config::Rig) {
        let script = rig.vehicles[0].script.as_mut().unwrap();
        script.script = Script::standing(script.script.start() + flowgate::Point::new(0.0, -0.1));
    }
    let options = Options { wait_for_operator: true, adjust_rig: Some(moved), ..Default::default() };
    let mut rig = VirtualRig::new(&s, options);
    rig.run_until(0.5);
    rig.vehicle_request(1, &Request::Arm).unwrap();
    let Err(refused) = rig.vehicle_request(1, &Request::Start) else { panic!("started away from its script") };
    let text = refused.to_string();
    assert!(text.starts_with("oncoming stands 0.10"), "{text}");
    assert!(text.ends_with("beyond its script_tolerance (0.05 m): bring it there first"), "{text}");
}

/// E2, E5 and E6 with their obstacles as scripted vehicles through the whole stack, as
/// `flowgate plan --whole-stack --sweep N --compare-obstacles` runs them (docs/fleet.md's
/// figures come from 1,000 episodes each): the robot at its goal with no contact in every
/// episode, with the scripts as vehicles as with them as obstacles; its clearance from
/// scripted vehicles no less; every script within 1 cm where its supervisor did not hold it,
/// and none lost.
#[test]
fn scripted_vehicles_through_the_whole_stack_keep_their_scripts() {
    use flowgate::lab::fleet::{stack, sweep};
    for name in ["e2-scripted.toml", "e5-scripted.toml", "e6-scripted.toml"] {
        let c = sweep::compare_scripts_with(&scenario(name), 40, 1, 2, stack::run).unwrap();
        assert_eq!((c.as_vehicles.rate, c.as_obstacles.rate), (1.0, 1.0), "{name}: {c}");
        assert!(c.clearance_as_vehicles[0] >= c.clearance_as_obstacles[0], "{name}: {c}");
        assert!(c.script_error_max <= 0.01 && c.script_error_over_1cm == 0, "{name}: {c}");
        assert_eq!(c.scripts_lost, 0, "{name}: {c}");
    }
}

/// The antipodal swaps through the whole stack, as `flowgate plan --whole-stack --sweep N`
/// runs them (docs/fleet.md's figures come from 10,000 episodes each): every vehicle home
/// with no contact in every episode, and the makespan within 1.5 times the slowest
/// vehicle's time alone (each alone through the whole stack too).
#[test]
fn swaps_through_the_whole_stack_bring_every_vehicle_home() {
    use flowgate::lab::fleet::stack;
    for (name, n) in [("swap-2.toml", 40), ("swap-4.toml", 40), ("swap-8.toml", 12)] {
        let (report, episodes) = stack::sweep(&scenario(name), n, 1, 2).unwrap();
        assert_eq!(episodes.len(), n as usize);
        assert_eq!(report.all_home.rate, 1.0, "{name}: {report}");
        assert_eq!((report.vehicle_contact_episodes, report.active_contact_episodes), (0, 0), "{name}: {report}");
        assert!(report.makespan_ratio_max <= 1.5, "{name}: {report}");
    }
}

/// A fleet's inputs (every vehicle's requests among them, with their vehicle) replayed into
/// a fresh core, as `flowgate replay` replays a recording, give every CAN frame of every
/// vehicle again, byte for byte.
#[test]
fn a_fleets_inputs_replay_to_the_same_frames() {
    let s = scenario("swap-4.toml");
    let mut rig = VirtualRig::new(&s, Options { record_inputs: true, wait_for_operator: true, ..Options::default() });
    let gateway_rig = rig.core().rig().clone();
    rig.run_until(0.5);
    for k in 0..4u8 {
        let (at, _) = goal(&s, usize::from(k));
        rig.vehicle_request(k, &Request::Arm).unwrap();
        rig.vehicle_request(k, &Request::Goal { goals: vec![Goal { position: at, tolerance: 0.02 }] }).unwrap();
        rig.vehicle_request(k, &Request::Start).unwrap();
    }
    rig.run_until(4.0);
    rig.vehicle_request(3, &Request::EStop).unwrap();
    let e = rig.run(s.time_limit, s.goal.position, s.goal.tolerance);
    assert!(e.inputs.iter().filter(|r| r.input.as_input().kind() == "vehicle_request").count() == 13);
    let replayed = flowgate::replay::run(gateway_rig, &e.inputs);
    assert_eq!(replayed.can.len(), e.can_sent.len());
    assert!(replayed.can == e.can_sent, "the replay's frames differ from the run's");
}

/// The fleet's fault swarm through the whole stack, as `flowgate plan --whole-stack --swarm
/// N` runs it (docs/fleet.md's figures come from 10,000 episodes each): lost links on the
/// simulated bus, the operator's stops and the fleet's e-stops through the gateway; no
/// episode breaks an invariant, and no vehicle coasting after its link failed touches
/// anything. Every kind of fault is drawn and stops vehicles.
#[test]
fn the_fleets_swarm_through_the_whole_stack_breaks_no_invariant() {
    use flowgate::lab::fleet::swarm::stack;
    for (name, n) in [("swap-4.toml", 100), ("e5-scripted.toml", 40)] {
        let report = stack::run(&scenario(name), n, 1, 2).unwrap();
        assert_eq!(report.episodes, n as usize);
        assert_eq!(report.broken_episodes, 0, "{name}: {report}\n{:?}", report.broken);
        assert_eq!(report.coasting_contacts, 0, "{name}: {report}");
        assert!(report.stopped.iter().all(|&k| k > 0), "{name}: every kind stops vehicles: {report}");
        assert!(report.unfaulted_home > 0, "{name}: {report}");
    }
}

/// The fleet's e-stop before the first stream has armed the fleet latches every vehicle,
/// and the swarm's judge counts each as stopped by it, not as a vehicle no fault stopped
/// that missed its goal (episode 2350 of E5's swarm); faults before the first stream that
/// stop nobody do not end the run before the fleet has started.
#[test]
fn faults_before_the_first_arm_are_judged_by_what_they_did() {
    use flowgate::lab::fleet::swarm::{stack, FleetFault};
    let (e, summary) = stack::episode(&scenario("e5-scripted.toml"), 1, 2350);
    assert!(e.broken.is_empty(), "{:?}", e.broken);
    assert_eq!(e.stopped.len(), 2, "{:?}", e.stopped);
    assert!(e.stopped.iter().all(|&(_, f, _)| matches!(f, FleetFault::EStop { .. })), "{:?}", e.stopped);
    assert_eq!(e.unfaulted, 0);
    for v in &summary.vehicles {
        assert_eq!(v.path_length, 0.0, "{} never moved", v.name);
        assert!(v.stop_reason.as_deref().is_some_and(|r| r.contains("operator emergency stop")), "{v:?}");
    }
    // Episode 2782's faults all come before the first stream and end nothing (a stop
    // refused, a vehicle not yet armed): the run goes on until the fleet is done, and the
    // robot reaches its goal.
    let (e, summary) = stack::episode(&scenario("e5-scripted.toml"), 1, 2782);
    assert!(e.broken.is_empty() && e.stopped.is_empty(), "{:?} {:?}", e.broken, e.stopped);
    assert_eq!((e.unfaulted, e.unfaulted_home), (1, 1), "{summary:?}");
}

/// A vehicle stopped while it turns hard is braked on its arc: both wheels come down
/// together until its centre stands, then both to zero. From the fastest its centre goes
/// once the stop is asked (`v`), it travels no further than a straight stop would (`v²/2a`,
/// and `v` for the cycle the stop waits for), where zero to each wheel would carry it up to
/// `(v_r - v_l)²/8a` further.
#[test]
fn a_vehicle_stopped_while_it_turns_keeps_its_arc() {
    let s = scenario("swap-4.toml");
    let accel = s.robot.wheel_accel;
    let mut rig = VirtualRig::new(&s, Options::default());
    let turning = |w: [f64; 2]| (w[1] - w[0]).abs() >= 0.15 && (w[0] + w[1]).abs() / 2.0 >= 0.03;
    while !turning(rig.fleet().world(1).wheel_speeds()) {
        assert!(rig.time() < 10.0, "vehicle 1 never turned hard");
        rig.step();
    }
    let from = rig.fleet().world(1).truth().path_length;
    rig.vehicle_request(1, &Request::Stop).unwrap();
    let (mut fastest, mut spread) = (0.0f64, 0.0f64);
    loop {
        let w = rig.fleet().world(1).wheel_speeds();
        if w == [0.0; 2] {
            break;
        }
        (fastest, spread) = (fastest.max(((w[0] + w[1]) / 2.0).abs()), spread.max((w[1] - w[0]).abs()));
        assert!(rig.time() < 12.0, "vehicle 1 never stood");
        rig.step();
    }
    let travelled = rig.fleet().world(1).truth().path_length - from;
    let straight = fastest * fastest / (2.0 * accel) + fastest * s.sensing.sample_time;
    let pivot = spread * spread / (8.0 * accel);
    assert!(travelled <= straight, "{travelled:.4} m on the brake, a straight stop {straight:.4} m");
    assert!(pivot > 2.0 * straight, "zero to each wheel could go {pivot:.4} m further");
    rig.run_until(rig.time() + 0.2);
    assert_eq!(rig.core().vehicle_state(1), Some(State::Stopped(StopReason::Operator)));
}

/// A vehicle whose link fails is stopped dead by its motors' timeout before the gateway
/// hears of it (the heartbeat). A follower's supervisor judges each other vehicle anywhere
/// between where it stands and where its command would take it, so it keeps its stop's
/// length behind where that vehicle stands: in episode 3397 of the 8-vehicle swap's swarm,
/// `v4`'s link fails at 4.98 s as `v5` follows it a centimetre clear, and `v5` stops short
/// of it (judged as a supervisor seeing `v4` only going on, it drove into `v4` at 5.32 s).
#[test]
fn a_follower_stops_short_of_a_vehicle_its_motors_stopped_dead() {
    use flowgate::lab::fleet::swarm::stack;
    let (e, summary) = stack::episode(&scenario("swap-8.toml"), 1, 3397);
    assert!(e.broken.is_empty(), "{:?}", e.broken);
    let v5 = summary.vehicles.iter().find(|v| v.name == "v5").unwrap();
    assert!(v5.contact.is_none(), "{v5:?}");
}
