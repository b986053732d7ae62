use super::faults::MAX_FAULTS;
use super::judge::Seen;
use super::*;
use std::path::Path;

fn e2() -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e2-lane-head-on.toml")).unwrap()
}

/// A schedule is a function of (seed, episode) alone, and the draws cover every kind
/// and backend over a modest number of episodes.
#[test]
fn schedules_are_reproducible_and_cover_every_kind() {
    let base = e2();
    let mut kinds = std::collections::BTreeSet::new();
    let mut backends = std::collections::BTreeSet::new();
    for i in 0..400 {
        let a = schedule(&base, 7, i);
        let b = schedule(&base, 7, i);
        assert_eq!(a.faults, b.faults);
        assert_eq!(a.scenario.faults, b.scenario.faults);
        assert!(a.scenario.faults.validate().is_ok(), "{:?}", a.scenario.faults.validate());
        assert!((1..=MAX_FAULTS).contains(&a.faults.len()));
        for f in &a.faults {
            assert!(f.kind.applies(a.backend));
        }
        kinds.extend(a.faults.iter().map(|f| f.kind));
        backends.insert(a.backend);
    }
    assert_eq!(kinds.len(), Kind::ALL.len(), "kinds never drawn");
    assert_eq!(backends.len(), 3);
    assert_ne!(schedule(&base, 7, 1).faults, schedule(&base, 8, 1).faults);
}

fn settings() -> Settings {
    let rig = e2().rig_with("slcan:/dev/null", false);
    Settings { period: 0.02, safety: rig.safety, board_timeout: 0.2, backend: Backend::BoardSlcan }
}

fn with(faults: Vec<Injected>) -> FaultSchedule {
    FaultSchedule { backend: Backend::BoardSlcan, faults, scenario: e2() }
}

fn silence(from: f64, to: f64) -> Injected {
    Injected { kind: Kind::SerialSilence, from, to, led: None }
}

/// The judge finds what it is for: a stop named for no fault present, a watchdog late,
/// wheels late to rest or turning in a fault, an arm nobody asked for, a goal missed.
#[test]
fn the_judge_finds_each_broken_invariant() {
    let s = settings();
    let started = vec![(0.0, State::Idle), (0.1, State::Armed), (0.12, State::Running)];
    let fault = |at: f64, reason| {
        let mut h = started.clone();
        h.push((at, State::Fault(reason)));
        h
    };
    let seen = |at: f64, reason, rest: Option<f64>| EpisodeLog {
        faults: vec![Seen { at, reason, rest }],
        ..EpisodeLog::default()
    };
    // Named and stopped in budget, then back to the goal: nothing to say.
    let good = with(vec![silence(2.0, 2.3)]);
    let h = fault(2.1, StopReason::SamplesStopped);
    let (v, stops) = judge(&good, &s, &h, &seen(2.1, StopReason::SamplesStopped, Some(2.1001)), true, State::Idle);
    assert!(v.is_empty(), "{v:?}");
    assert_eq!(stops[0].named_for, Some(Kind::SerialSilence));
    // Named for something no fault explains (the line quiet, named as the pose).
    let (v, _) = judge(
        &good,
        &s,
        &fault(2.1, StopReason::PoseLost),
        &seen(2.1, StopReason::PoseLost, Some(2.1)),
        true,
        State::Idle,
    );
    assert!(v[0].contains("no fault present names it"), "{v:?}");
    // The watchdog late: the pose watchdog (150 ms, the later of the two that may find
    // a silent line) and a cycle after the silence began is the latest.
    let (v, _) = judge(&good, &s, &h, &seen(2.2, StopReason::SamplesStopped, Some(2.2)), true, State::Idle);
    assert!(v[0].contains("200.0 ms after its cause, beyond the 150 ms watchdog"), "{v:?}");
    // The wheels at rest later than a cycle after the fault.
    let (v, _) = judge(&good, &s, &h, &seen(2.1, StopReason::SamplesStopped, Some(2.15)), true, State::Idle);
    assert!(v[0].contains("wheels at rest 50.0 ms after it"), "{v:?}");
    // Turning again in the fault.
    let mut w = seen(2.1, StopReason::SamplesStopped, Some(2.1));
    w.turned_in_fault = Some(2.5);
    let (v, _) = judge(&good, &s, &h, &w, true, State::Idle);
    assert!(v[0].contains("turned in a fault"), "{v:?}");
    // Armed again with no operator's arm.
    let mut h2 = h.clone();
    h2.extend([(2.7, State::Idle), (2.8, State::Armed)]);
    let (v, _) = judge(&good, &s, &h2, &seen(2.1, StopReason::SamplesStopped, Some(2.1)), true, State::Idle);
    assert!(v[0].contains("armed at 2.800 s without the operator's arm"), "{v:?}");
    // The goal not reached after the last fault.
    let (v, _) = judge(&good, &s, &h, &seen(2.1, StopReason::SamplesStopped, Some(2.1)), false, State::Idle);
    assert!(v[0].contains("goal was not reached"), "{v:?}");
}

/// The occlusion watchdog watches only a running robot: an obstacle hidden while the
/// robot stood armed (its goal refused, say) is found as the robot starts, however long
/// after the occlusion began; one hidden while it ran, within the watchdog and a cycle.
#[test]
fn a_watchdog_of_a_running_robot_fires_as_it_starts() {
    let s = settings();
    let hidden = with(vec![Injected { kind: Kind::ObstacleOccluded, from: 5.3, to: 7.6, led: Some(3) }]);
    let reason = StopReason::ObstacleOccluded { led: 3, at_edge: false };
    let seen = |at: f64| EpisodeLog { faults: vec![Seen { at, reason, rest: Some(at) }], ..EpisodeLog::default() };
    let armed = vec![(0.0, State::Idle), (4.36, State::Armed)];
    let ran_at = |t: f64| {
        let mut h = armed.clone();
        h.extend([(t, State::Running), (t, State::Fault(reason))]);
        h
    };
    let (v, _) = judge(&hidden, &s, &ran_at(7.45), &seen(7.45), true, State::Idle);
    assert!(v.is_empty(), "{v:?}");
    // Running since before the occlusion: late beyond the watchdog and a cycle.
    let mut h = vec![(0.0, State::Idle), (4.36, State::Armed), (4.4, State::Running)];
    h.push((7.45, State::Fault(reason)));
    let (v, _) = judge(&hidden, &s, &h, &seen(7.45), true, State::Idle);
    assert!(v[0].contains("beyond the 1000 ms watchdog"), "{v:?}");
}
