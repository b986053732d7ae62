//! What a step of people walking costs (`cargo bench --bench people`; docs/performance.md,
//! "People"): 100 people on ORCA's circle test (a circle of 50 body radii, each bound for
//! its antipode), by ORCA and by social forces, beside 100 straight walkers, whose step is
//! where each is now. Timed: one [`Crowd::step`] on one thread, every step until the last
//! person arrives (or twice the straight-line time); the straight walkers' row times the
//! same number of steps of 100 positions from their scripted ways. The crowd has room for
//! its legs reserved, as `people::ways` reserves it for a scenario's walk. Then a sweep of
//! five ORCA people against the same sweep of straight walkers ([`sweeps`]).

use std::time::Instant;

use flowgate::lab::planner_only::Mode;
use flowgate::lab::scenario::Scenario;
use flowgate::lab::sweep::sweep;
use flowgate_sim::scenario::{Behaviour, Motion, ObstacleSpec};
use flowgate_sim::world::people::Crowd;
use flowgate_sim::world::{ObstaclePath, Room};
use flowgate_sim::Point;
use hdrhistogram::Histogram;

const PEOPLE: u32 = 100;
const RADIUS: f64 = 0.07;
const SPEED: f64 = 0.06;

fn circle() -> Vec<(Point, Point)> {
    (0..PEOPLE)
        .map(|k| {
            let at = Point::from_polar(50.0 * RADIUS, std::f64::consts::TAU * f64::from(k) / f64::from(PEOPLE));
            (at, -at)
        })
        .collect()
}

fn row(name: &str, histogram: &Histogram<u64>) {
    let us = |q: f64| histogram.value_at_quantile(q) as f64 / 1e3;
    println!(
        "{name:<32} {:>6} steps  p50 {:>6.1} µs  p99 {:>6.1} µs  p99.9 {:>6.1} µs  max {:>6.1} µs",
        histogram.len(),
        us(0.5),
        us(0.99),
        us(0.999),
        histogram.max() as f64 / 1e3
    );
}

fn main() {
    let straight_time = 2.0 * 50.0 * RADIUS / SPEED;
    let mut steps = 0;
    for behaviour in [Behaviour::Orca, Behaviour::SocialForce] {
        let people: Vec<ObstacleSpec> = circle()
            .into_iter()
            .map(|(start, goal)| ObstacleSpec {
                behaviour,
                goal: Some([goal.re, goal.im]),
                preferred_speed: Some(SPEED),
                ..ObstacleSpec::scripted(RADIUS, [start.re, start.im], Motion::Stationary)
            })
            .collect();
        let goals: Vec<Point> = circle().into_iter().map(|(_, g)| g).collect();
        let mut crowd = Crowd::new(&people, Room::default(), 1);
        crowd.reserve((2.0 * straight_time / flowgate_sim::world::people::STEP).ceil() as usize + 1);
        let mut histogram = Histogram::<u64>::new(3).expect("histogram");
        while crowd.time() < 2.0 * straight_time
            && crowd.positions().zip(&goals).any(|(p, &g)| (p - g).norm() >= RADIUS)
        {
            let start = Instant::now();
            crowd.step();
            let _ = histogram.record(start.elapsed().as_nanos() as u64);
        }
        steps = steps.max(histogram.len());
        row(&format!("{PEOPLE} people by {behaviour:?}, a step"), &histogram);
    }
    let walkers: Vec<ObstaclePath> = circle()
        .into_iter()
        .map(|(start, goal)| {
            let velocity = (goal - start) / (goal - start).norm() * SPEED;
            ObstaclePath::new(&ObstacleSpec::scripted(
                RADIUS,
                [start.re, start.im],
                Motion::Constant { velocity: [velocity.re, velocity.im] },
            ))
        })
        .collect();
    let mut histogram = Histogram::<u64>::new(3).expect("histogram");
    let mut sum = Point::default();
    for n in 0..steps {
        let t = n as f64 * flowgate_sim::world::people::STEP;
        let start = Instant::now();
        for w in &walkers {
            sum += w.position(t);
        }
        let _ = histogram.record(start.elapsed().as_nanos() as u64);
    }
    std::hint::black_box(sum);
    row(&format!("{PEOPLE} straight walkers, a step"), &histogram);
    sweeps();
}

/// A sweep among people against the same sweep among straight walkers: 200 episodes of
/// `scenarios/people/circle-crossing-5.toml`, the planner alone, on one thread, the median
/// of three runs each. The ORCA people walked ahead (the default) and as needed
/// (`people_walk = "as_needed"`), each as a share of the straight walkers' pace.
fn sweeps() {
    const EPISODES: usize = 200;
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/people/circle-crossing-5.toml");
    let text = std::fs::read_to_string(path).expect("scenarios/people/circle-crossing-5.toml");
    let with = |from: &str, to: &str| {
        assert!(text.contains(from), "circle-crossing-5.toml has no `{from}`");
        text.replacen(from, to, 1)
    };
    let variants = [
        ("ORCA people, walked ahead", text.clone()),
        ("ORCA people, walked as needed", with("time_limit = 40", "time_limit = 40\npeople_walk = \"as_needed\"")),
        ("straight walkers", with("behaviour = \"orca\"", "behaviour = \"straight\"")),
    ];
    let mut medians = Vec::new();
    for (name, text) in &variants {
        let scenario = Scenario::from_toml(text, name).expect("the variant loads");
        let mut times: Vec<f64> = (0..3)
            .map(|_| {
                let start = Instant::now();
                let report = sweep(&scenario, EPISODES, 1, 1, Mode::PlannerOnly).expect("the sweep runs");
                std::hint::black_box(report);
                start.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        medians.push(times[1]);
    }
    let straight = medians[2];
    for ((name, _), time) in variants.iter().zip(&medians) {
        println!(
            "{EPISODES} episodes among {name:<30} {time:>6.2} s  {:>4.0}% of the straight walkers' pace",
            100.0 * straight / time
        );
    }
}
