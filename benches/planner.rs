//! Planner cost per evaluation (criterion): `eval` is the field at one point for a built
//! geometry; `plan` is one whole command (images and weights from the current geometry,
//! margins, tie-break, evaluation, saturation), which is what a control cycle pays.
//!
//! `room/plan_32_5` is a whole command in a room of four walls and four heptagonal static
//! obstacles (32 edges in all) with five moving circles; beside criterion's median it prints
//! the distribution of 20,000 single commands (p50, p99, p99.9, max).
//!
//! cargo bench --bench planner

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion};
use flowgate::planner::room::{FarField, Panels, Room, RoomShape};
use flowgate::planner::{Field, Margin, ObstacleEstimate, PlanInput, Planner, PlannerConfig, Sink, Space, TieBreak};
use flowgate::Point;
use std::sync::Arc;

fn obstacles(n: usize) -> Vec<ObstacleEstimate> {
    (0..n)
        .map(|k| {
            let a = k as f64 * 2.399; // golden-angle spiral, well apart
            ObstacleEstimate::exact(Point::from_polar(0.25 + 0.12 * k as f64, a), Point::from_polar(0.05, -a), 0.03)
        })
        .collect()
}

fn config(space: Space) -> PlannerConfig {
    PlannerConfig {
        space,
        cruise_speed: 0.1,
        c1: 20.0,
        reference_radius: 0.14,
        max_speed: 0.15,
        margin: Margin::Factor { factor: 1.1 },
        uncertainty_sigmas: 1.0,
        clearance: 0.006,
        tie_break: Some(TieBreak::default()),
        anticipation: 0.0,
        lane_residual: flowgate::planner::lane_series::EXACT_AIM,
    }
}

fn planner(space: Space) -> Planner {
    Planner::new(config(space))
}

/// A 2 m square room walled by four walls, a heptagonal static obstacle (24 cm across) in
/// each quarter, grown by a 7 cm robot and the 6 mm clearance, panels of 3 cm (the default),
/// their far field taken as `far_field` says.
fn room(far_field: FarField) -> Arc<Room> {
    let p = Point::new;
    let walls = vec![
        vec![p(-1.0, -1.0), p(1.0, -1.0)],
        vec![p(1.0, -1.0), p(1.0, 1.0)],
        vec![p(1.0, 1.0), p(-1.0, 1.0)],
        vec![p(-1.0, 1.0), p(-1.0, -1.0)],
    ];
    let heptagon =
        |c: Point| (0..7).map(|k| c + Point::from_polar(0.12, std::f64::consts::TAU * k as f64 / 7.0)).collect();
    let obstacles = [p(-0.55, 0.6), p(0.55, 0.6), p(-0.55, -0.6), p(0.55, -0.6)].into_iter().map(heptagon).collect();
    let shape = RoomShape { walls, obstacles, view: None };
    let panels = Panels { spacing: 0.03, corner_turn: None, far_field };
    Arc::new(Room::with_panels(&shape, 0.076, panels).unwrap().unwrap())
}

/// The moving circles of the room case: five crossing its middle.
fn room_obstacles() -> Vec<ObstacleEstimate> {
    (0..5)
        .map(|k| {
            let x = -0.4 + 0.2 * k as f64;
            let y = if k % 2 == 0 { 0.15 } else { -0.15 };
            ObstacleEstimate::exact(Point::new(x, y), Point::new(0.0, if k % 2 == 0 { -0.06 } else { 0.06 }), 0.05)
        })
        .collect()
}

/// The distribution of `n` single calls of `f`, ns: p50, p99, p99.9, max.
fn distribution(n: usize, mut f: impl FnMut()) -> [f64; 4] {
    let mut times: Vec<f64> = (0..n)
        .map(|_| {
            let t = std::time::Instant::now();
            f();
            t.elapsed().as_nanos() as f64
        })
        .collect();
    times.sort_by(f64::total_cmp);
    let at = |q: f64| times[((n as f64 * q) as usize).min(n - 1)];
    [at(0.5), at(0.99), at(0.999), times[n - 1]]
}

fn bench(c: &mut Criterion) {
    let robot = Point::new(-1.6, 0.02);
    let goal = Point::new(1.8, -0.03);
    let cases: [(&str, Space, usize); 5] = [
        ("free_1", Space::Free, 1),
        ("lane_1", Space::Lane { half_width: 0.6 }, 1),
        ("free_2", Space::Free, 2),
        ("lane_2", Space::Lane { half_width: 0.6 }, 2),
        ("free_10", Space::Free, 10),
    ];
    let mut eval = c.benchmark_group("eval");
    for (name, space, n) in cases {
        let obs = obstacles(n);
        let input = PlanInput { position: robot, goal, robot_radius: 0.07, obstacles: &obs, delay: 0.02 };
        let (field, _) = planner(space).field(&input).unwrap();
        eval.bench_function(BenchmarkId::from_parameter(name), |b| b.iter(|| field.eval(black_box(robot)).unwrap()));
    }
    eval.finish();
    let mut plan = c.benchmark_group("plan");
    for (name, space, n) in cases {
        let obs = obstacles(n);
        let p = planner(space);
        plan.bench_function(BenchmarkId::from_parameter(name), |b| {
            b.iter(|| {
                let input =
                    PlanInput { position: black_box(robot), goal, robot_radius: 0.07, obstacles: &obs, delay: 0.02 };
                p.plan(&input).unwrap()
            })
        });
    }
    plan.finish();
    let room_obs = room_obstacles();
    let (robot_in, goal_in) = (Point::new(-0.8, 0.02), Point::new(0.8, -0.03));
    let command = |p: &Planner, field: &mut Field| {
        let input = PlanInput {
            position: black_box(robot_in),
            goal: goal_in,
            robot_radius: 0.07,
            obstacles: &room_obs,
            delay: 0.02,
        };
        p.plan_in(&input, field).unwrap()
    };
    for (name, far_field) in [("room/plan_32_5", FarField::Multipole), ("room/plan_32_5_series", FarField::Series)] {
        let p = Planner::in_room(config(Space::Free), Some(room(far_field)));
        let mut field = Field::empty(Space::Free, p.sink(goal_in));
        c.bench_function(name, |b| b.iter(|| command(&p, &mut field)));
        let [p50, p99, p999, max] = distribution(20_000, || {
            black_box(command(&p, &mut field));
        });
        println!(
            "{name}: {} panels; single commands p50 {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs",
            p.room().map_or(0, |r| r.panels().len()),
            p50 / 1e3,
            p99 / 1e3,
            p999 / 1e3,
            max / 1e3
        );
    }
    // Field construction alone, for the record.
    let obs: Vec<_> = obstacles(2)
        .iter()
        .map(|o| flowgate::planner::PlanObstacle { center: o.center, velocity: o.velocity, radius: 0.11 })
        .collect();
    let sink = Sink { goal, strength: 0.014, c1: 20.0, reference_radius: 0.14 };
    c.bench_function("build/lane_2", |b| {
        b.iter(|| Field::new(Space::Lane { half_width: 0.6 }, black_box(sink), &obs).unwrap())
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
