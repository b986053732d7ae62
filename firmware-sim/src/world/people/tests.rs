use super::*;
use crate::scenario::Motion;

fn person(behaviour: Behaviour, start: Point, goal: Point, radius: f64, speed: f64) -> ObstacleSpec {
    ObstacleSpec {
        behaviour,
        goal: Some([goal.re, goal.im]),
        preferred_speed: Some(speed),
        ..ObstacleSpec::scripted(radius, [start.re, start.im], Motion::Stationary)
    }
}

/// The smallest gap between two people walking their ways from `t0` to `t1`: each leg is
/// one velocity, so the gap's least is found in closed form between the legs' changes.
fn least_gap(a: &ObstaclePath, b: &ObstaclePath, ra: f64, rb: f64, end: f64) -> f64 {
    let mut least = f64::INFINITY;
    let mut t = 0.0;
    while t < end {
        let next = [a.change_between(t, end), b.change_between(t, end)].into_iter().flatten().fold(end, f64::min);
        let (dp, dv) = (b.position(t) - a.position(t), b.velocity(t) - a.velocity(t));
        let s = if dv.norm_sqr() > 0.0 {
            (-(dp.re * dv.re + dp.im * dv.im) / dv.norm_sqr()).clamp(0.0, next - t)
        } else {
            0.0
        };
        least = least.min((dp + dv * s).norm() - ra - rb);
        t = next;
    }
    least
}

/// ORCA's own circle test: 100 people on a circle of 50 body radii, each to its antipode.
/// All arrive within twice the straight-line time, and no two ever overlap (three seeds of
/// the people's sway; `--nocapture` prints each).
#[test]
fn orca_people_pass_the_circle_test() {
    for seed in 1..=3 {
        let (last, straight, least) = circle_test(seed);
        println!(
            "circle test, seed {seed}: all 100 arrived by {last:.1} s ({:.2} times the straight line), \
             least gap {:.1} mm",
            last / straight,
            least * 1e3
        );
        assert!(last < 2.0 * straight, "seed {seed}: {last} s against {straight} s straight");
        assert!(least >= -1e-9, "seed {seed}: two people overlapped by {} mm", -least * 1e3);
    }
}

/// The circle test at `seed`: when the last person arrived, the straight-line time, and
/// the least gap between any two people all through.
fn circle_test(seed: u64) -> (f64, f64, f64) {
    let (n, r, speed) = (100, 0.07, 0.06);
    let radius = 50.0 * r;
    let people: Vec<ObstacleSpec> = (0..n)
        .map(|k| {
            let at = Point::from_polar(radius, std::f64::consts::TAU * f64::from(k) / f64::from(n));
            person(Behaviour::Orca, at, -at, r, speed)
        })
        .collect();
    let straight = 2.0 * radius / speed;
    let mut crowd = Crowd::new(&people, Room::default(), seed);
    let mut arrived = vec![None; people.len()];
    while crowd.time() < 2.0 * straight && arrived.iter().any(Option::is_none) {
        crowd.step();
        let t = crowd.time();
        for ((p, spec), seen) in crowd.positions().zip(&people).zip(&mut arrived) {
            if seen.is_none() && (p - crate::scenario::point(spec.goal.unwrap())).norm() < r {
                *seen = Some(t);
            }
        }
    }
    let last = arrived.iter().map(|a| a.unwrap_or(f64::INFINITY)).fold(0.0, f64::max);
    let end = crowd.time();
    let ways = crowd.into_ways();
    let mut least = f64::INFINITY;
    for i in 0..ways.len() {
        for j in i + 1..ways.len() {
            least = least.min(least_gap(&ways[i], &ways[j], r, r, end));
        }
    }
    (last, straight, least)
}

/// Two people head on in a hallway, both ways: neither walks through the other or the
/// walls, and both arrive; by social forces likewise.
#[test]
fn people_pass_each_other_in_a_hallway() {
    for behaviour in [Behaviour::Orca, Behaviour::SocialForce] {
        let (r, speed) = (0.07, 0.06);
        let a = person(behaviour, Point::new(-0.6, 0.01), Point::new(0.6, 0.01), r, speed);
        let b = person(behaviour, Point::new(0.6, -0.01), Point::new(-0.6, -0.01), r, speed);
        let walls = |y: f64| vec![Point::new(-1.0, y), Point::new(1.0, y)];
        let room = Room::from_parts(vec![walls(0.25), walls(-0.25)], Vec::new());
        let mut crowd = Crowd::new(&[a.clone(), b.clone()], room.clone(), 1);
        while crowd.time() < 60.0 {
            crowd.step();
        }
        let ends: Vec<Point> = crowd.positions().collect();
        let end = crowd.time();
        let ways = crowd.into_ways();
        assert!(least_gap(&ways[0], &ways[1], r, r, end) > -1e-9, "{behaviour:?}: they overlapped");
        assert!((ends[0] - Point::new(0.6, 0.01)).norm() < r, "{behaviour:?}: {}", ends[0]);
        assert!((ends[1] - Point::new(-0.6, -0.01)).norm() < r, "{behaviour:?}: {}", ends[1]);
        for w in &ways {
            for k in 0..1200 {
                let p = w.position(f64::from(k) * 0.05);
                assert!(room.gap(p, r).is_some_and(|g| g.gap > -1e-3), "{behaviour:?}: into a wall at {p}");
            }
        }
    }
}

/// Straight walkers are avoided, not avoiding: a person crossing a scripted obstacle's way
/// takes the whole change, and the way is the same on every run.
#[test]
fn a_person_avoids_a_scripted_obstacle_and_walks_the_same_way_each_time() {
    let (r, speed) = (0.07, 0.06);
    let crossing = ObstacleSpec::scripted(r, [0.0, -0.6], Motion::Constant { velocity: [0.0, 0.06] });
    let walker = person(Behaviour::Orca, Point::new(-0.6, 0.0), Point::new(0.6, 0.0), r, speed);
    let walk = || {
        let mut crowd = Crowd::new(&[crossing.clone(), walker.clone()], Room::default(), 7);
        while crowd.time() < 40.0 {
            crowd.step();
        }
        let end = crowd.time();
        (crowd.into_ways(), end)
    };
    let (ways, end) = walk();
    assert!(least_gap(&ways[0], &ways[1], r, r, end) > -1e-9);
    let (again, _) = walk();
    for k in 0..800 {
        let t = f64::from(k) * 0.05;
        assert_eq!(ways[1].position(t), again[1].position(t));
    }
}

/// A person walking head on at the standing robot: one who does not see it walks into it
/// (a passive contact); one who sees it walks round it, as round a scripted obstacle, and
/// the world that walks it step by step as it runs is the same on every run.
#[test]
fn a_person_who_sees_the_robot_walks_round_it() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/people/hallway.toml");
    let mut s = SimScenario::load(&path).unwrap();
    s.robot.start = [0.0, 0.0];
    let run = |sees_robot: bool| {
        let walker = ObstacleSpec {
            sees_robot,
            ..person(Behaviour::Orca, Point::new(0.5, 0.005), Point::new(-0.7, 0.005), 0.07, 0.06)
        };
        let s = SimScenario { obstacles: vec![walker], ..s.clone() };
        let mut world = crate::world::World::new(&s);
        for _ in 0..1000 {
            world.step(0.02);
        }
        (world.truth(), world.obstacle_position(0, 20.0))
    };
    let (blind, _) = run(false);
    assert!(blind.contact.is_some_and(|c| !c.active), "walks into the robot: {blind:?}");
    let (seeing, at) = run(true);
    assert_eq!(seeing.contact, None, "{seeing:?}");
    assert!(seeing.min_obstacle_clearance > 0.0, "{seeing:?}");
    assert!(at.re < -0.5, "and walks on past it to its goal: {at}");
    assert_eq!(run(true).1, at);
}

/// Three people side by side bound across a room at three speeds: walking alone they string
/// out along the way (one ends more than 0.5 m from the others' centre); as a group, at its
/// slowest member's pace, they keep together (each within four radii of the others' centre
/// all the way; the outer two start 3.2 radii from it) and every one arrives.
#[test]
fn a_group_walks_together() {
    let (r, end) = (0.07, 60.0);
    let people = |group: Option<&str>| -> Vec<ObstacleSpec> {
        [(-0.15, 0.04), (0.0, 0.06), (0.15, 0.08)]
            .into_iter()
            .map(|(y, speed)| ObstacleSpec {
                group: group.map(str::to_string),
                ..person(Behaviour::Orca, Point::new(-0.8, y), Point::new(0.8, y), r, speed)
            })
            .collect()
    };
    let spread = |group: Option<&str>| {
        let mut crowd = Crowd::new(&people(group), Room::default(), 3);
        let mut widest: f64 = 0.0;
        while crowd.time() < end {
            crowd.step();
            let at: Vec<Point> = crowd.positions().collect();
            for (i, p) in at.iter().enumerate() {
                let others = at.iter().enumerate().filter(|&(j, _)| j != i).map(|(_, q)| *q).sum::<Point>() / 2.0;
                widest = widest.max((others - p).norm());
            }
        }
        let arrived = crowd.positions().zip([-0.15, 0.0, 0.15]).all(|(p, y)| (p - Point::new(0.8, y)).norm() < r);
        (widest, arrived)
    };
    let (alone, arrived) = spread(None);
    assert!(alone > 0.5 && arrived, "alone they string out: {alone} m");
    let (together, arrived) = spread(Some("friends"));
    assert!(together < 4.0 * r && arrived, "a group keeps together: {together} m, arrived {arrived}");
}

/// Walked as needed (`people_walk = "as_needed"`), the people of a scenario walk the ways
/// they walk ahead, to the bit, while the world runs; only the judge's bound on a person's
/// speed differs (their cap, not their fastest leg, which is not yet walked).
#[test]
fn people_walked_as_needed_walk_the_ways_walked_ahead() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/people/concourse.toml");
    let ahead = SimScenario::load(&path).unwrap();
    assert_eq!(ahead.people_walk, PeopleWalk::Ahead);
    assert!(ahead.obstacles.iter().filter(|o| o.behaviour.walks()).count() >= 3);
    let as_needed = SimScenario { people_walk: PeopleWalk::AsNeeded, ..ahead.clone() };
    let (mut a, mut b) = (crate::world::World::new(&ahead), crate::world::World::new(&as_needed));
    for _ in 0..1500 {
        a.step(0.02);
        b.step(0.02);
        let t = a.time();
        for k in 0..ahead.obstacles.len() {
            assert_eq!(a.obstacle_position(k, t), b.obstacle_position(k, t), "person {k} at {t} s");
            assert_eq!(a.obstacle_velocity(k, t), b.obstacle_velocity(k, t), "person {k} at {t} s");
        }
    }
    // Walked as needed, nobody has walked yet when the world is made.
    let (_, crowd) = start(&as_needed);
    assert!(crowd.is_some_and(|c| c.time() == 0.0));
    assert!(start(&ahead).1.is_none());
}

/// When people walk is read from the scenario: ahead by default, as needed when asked, and
/// nothing else, refused naming the key.
#[test]
fn people_walk_ahead_or_as_needed() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/people/hallway.toml");
    let text = std::fs::read_to_string(path).unwrap();
    let with = |value: &str| text.replacen("time_limit = ", &format!("people_walk = {value}\ntime_limit = "), 1);
    assert_eq!(SimScenario::from_toml(&text, "t").unwrap().people_walk, PeopleWalk::Ahead);
    assert_eq!(SimScenario::from_toml(&with("\"as_needed\""), "t").unwrap().people_walk, PeopleWalk::AsNeeded);
    let err = SimScenario::from_toml(&with("\"later\""), "t").unwrap_err().to_string();
    assert!(err.contains("people_walk = \"later\"") && err.contains("expected `ahead` or `as_needed`"), "{err}");
}
