use super::*;

fn swap_4() -> Scenario {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/fleet/swap-4.toml");
    Scenario::load(&path).unwrap()
}

/// Judge a run of `s` with `faults`, after `tamper` has changed what the judge reads.
fn tampered(
    s: &Scenario,
    faults: &[FleetFault],
    tamper: impl FnOnce(&mut FleetSummary, &mut WheelLog),
) -> (SwarmEpisode, FleetSummary) {
    let (mut summary, stopped, mut log) = play(s, faults, None);
    tamper(&mut summary, &mut log);
    (judged(s, 0, faults.to_vec(), &summary, stopped, &log, Level::Planner), summary)
}

/// Each episode's faults come from the seed and its index alone, in time order within the
/// window, one to three of them, every kind drawn.
#[test]
fn faults_are_drawn_from_the_seed_and_the_index_alone() {
    let s = swap_4();
    let mut kinds = [0; 3];
    for i in 0..300 {
        let f = faults(&s, 1, i);
        assert_eq!(f, faults(&s, 1, i));
        assert!((1..=3).contains(&f.len()), "{f:?}");
        assert!(f.windows(2).all(|w| w[0].at() <= w[1].at()), "{f:?}");
        assert!(f.iter().all(|x| (0.0..FAULT_WINDOW_S).contains(&x.at())), "{f:?}");
        f.iter().for_each(|&x| kinds[kind(x)] += 1);
    }
    assert!(kinds.iter().all(|&k| k > 30), "{kinds:?}");
    assert_ne!(faults(&s, 1, 0), faults(&s, 2, 0));
}

/// The fleet's e-stop three seconds in stops every vehicle, each named, at rest within its
/// wheels' ramp, and none turns a wheel again; a vehicle that did would be named.
#[test]
fn an_e_stop_stops_every_vehicle_for_good() {
    let s = swap_4();
    let estop = [FleetFault::EStop { at: 3.0 }];
    let (e, summary) = tampered(&s, &estop, |_, _| {});
    assert!(e.broken.is_empty(), "{:?}", e.broken);
    assert_eq!(e.stopped.len(), 4);
    assert!(e.stopped.iter().all(|&(_, _, at)| (3.0..3.0 + s.sensing.sample_time).contains(&at)), "{:?}", e.stopped);
    for v in &summary.vehicles {
        assert_eq!((v.outcome, v.stop_reason.as_deref()), (Outcome::Stopped, Some(E_STOP)), "{v:?}");
    }
    let (e, _) = tampered(&s, &estop, |_, log| {
        let last = log.wheels.len() - 4 + 2;
        log.wheels[last] = [0.01, 0.01];
    });
    assert_eq!(e.broken.len(), 1, "{:?}", e.broken);
    assert!(e.broken[0].starts_with("v2, stopped by e_stop at 3.00 s, still turns its wheels at "), "{:?}", e.broken);
}

/// A vehicle whose link fails is named by it and stands once its motors' timeout runs out;
/// the operator's stop of another is named too; the others drive on. A stop reason that
/// does not name its fault, and a contact driven into by a vehicle in control, are named.
#[test]
fn a_lost_link_and_an_operators_stop_are_each_named() {
    let s = swap_4();
    let two = [FleetFault::LinkLost { vehicle: 1, at: 2.0 }, FleetFault::Stop { vehicle: 3, at: 2.5 }];
    let (e, summary) = tampered(&s, &two, |_, _| {});
    assert!(e.broken.is_empty(), "{:?}", e.broken);
    let reasons: Vec<Option<&str>> = summary.vehicles.iter().map(|v| v.stop_reason.as_deref()).collect();
    assert!(reasons[1].is_some_and(|r| r.starts_with("its link failed at 2.00 s")), "{reasons:?}");
    assert_eq!(reasons[3], Some(STOPPED_BY_THE_OPERATOR));
    assert_eq!((e.unfaulted, summary.vehicles[1].outcome), (2, Outcome::Fault));
    let (e, _) = tampered(&s, &two, |summary, _| {
        summary.vehicles[3].stop_reason = Some("stalled".into());
        summary.vehicles[0].contact = Some(crate::lab::fleet::VehicleContactReport {
            at: 4.0,
            with: "vehicle v2".into(),
            approach_speed: 0.05,
            active: true,
        });
    });
    assert_eq!(
        e.broken,
        ["robot drove into vehicle v2 at 4.00 s", "v3, stopped by stop, names its stop Some(\"stalled\")"],
    );
}

/// A stopped vehicle brakes as its supervisor certified: both wheels come down together
/// until its centre stands (its turn held, so it keeps its arc), then both to zero on the
/// spot. A link that fails while it brakes leaves its motors on the brake's last command
/// until their timeout; the judge waits for that, and no longer.
#[test]
fn a_stop_keeps_the_arc_and_a_link_lost_while_braking_is_waited_for() {
    let s = swap_4();
    let estop = [FleetFault::EStop { at: 3.0 }];
    let (_, _, log) = play(&s, &estop, None);
    let from = log.t.iter().position(|&t| t >= 3.0).unwrap();
    let ppm = s.vehicle(0).rig().control.drive.pulses_per_metre();
    let mut turning = 0;
    for k in 0..4 {
        let wheels: Vec<[f64; 2]> = log.wheels.chunks_exact(4).skip(from).map(|w| w[k]).collect();
        turning += usize::from((wheels[0][1] - wheels[0][0]).abs() > 0.01);
        for pair in wheels.windows(2) {
            let (was, now) = (pair[0], pair[1]);
            let centre = 0.5 * (was[0] + was[1]);
            if (centre * ppm).abs() > 1.0 {
                let (dl, dr) = (now[0] - was[0], now[1] - was[1]);
                assert!((dl - dr).abs() <= 1.5 / ppm, "vehicle {k}: the wheels came down apart: {was:?} -> {now:?}");
            }
        }
        assert_eq!(wheels.last(), Some(&[0.0; 2]));
    }
    assert!(turning > 0, "a vehicle was turning at the stop");
    // The link of a braking vehicle fails a cycle into its stop.
    let dt = s.sensing.sample_time;
    let faults = [FleetFault::Stop { vehicle: 2, at: 3.0 }, FleetFault::LinkLost { vehicle: 2, at: 3.0 + dt }];
    let (e, _) = tampered(&s, &faults, |_, _| {});
    assert!(e.broken.is_empty(), "{:?}", e.broken);
    let body = s.vehicle(2).sim.robot;
    let rest_by = (3.0 + body.max_wheel_speed / body.wheel_accel).max(3.0 + dt + motors_hold(&s, 2)) + 2.0 * dt;
    let (e, _) = tampered(&s, &faults, |_, log| {
        let at = log.t.iter().position(|&t| t > rest_by).unwrap();
        log.wheels[at * 4 + 2] = [-0.01, 0.01];
    });
    assert_eq!(e.broken.len(), 1, "{:?}", e.broken);
    assert!(e.broken[0].starts_with("v2, stopped by stop at 3.00 s, still turns its wheels at "), "{:?}", e.broken);
}

/// The report lists the first episodes in which a vehicle no fault stopped missed its goal,
/// and those with a contact while coasting, for `--episode K`.
#[test]
fn the_report_lists_the_episodes_to_look_at() {
    let s = swap_4();
    let episode = |index, unfaulted_home, coasting_contacts| SwarmEpisode {
        index,
        faults: Vec::new(),
        outcome: Outcome::Goal,
        stopped: Vec::new(),
        unfaulted: 4,
        unfaulted_home,
        coasting_contacts,
        broken: Vec::new(),
    };
    let episodes = [episode(0, 4, 0), episode(1, 3, 0), episode(2, 4, 1), episode(3, 2, 0)];
    let report = report(&s, 1, &episodes, Level::Planner);
    assert_eq!(
        (report.unfaulted_short_episodes.as_slice(), report.coasting_episodes.as_slice()),
        (&[1, 3][..], &[2][..])
    );
    let said = report.to_string();
    assert!(said.contains("13 of 16 at their goal (81.2%) (episode 1, 3)\n"), "{said}");
    assert!(said.contains("after a lost link: 1 (episode 2)\n"), "{said}");
}
