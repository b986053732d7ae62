//! Planner cost per evaluation (criterion): `eval` is the field at one point for a built
//! geometry; `plan` is one whole command (images and weights from the current geometry,
//! margins, tie-break, evaluation, saturation), which is what a control cycle pays.
//!
//! cargo bench --bench planner

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion};
use flowgate::planner::{Field, Margin, ObstacleEstimate, PlanInput, Planner, PlannerConfig, Sink, Space, TieBreak};
use flowgate::Point;

fn obstacles(n: usize) -> Vec<ObstacleEstimate> {
    (0..n)
        .map(|k| {
            let a = k as f64 * 2.399; // golden-angle spiral, well apart
            ObstacleEstimate::exact(Point::from_polar(0.25 + 0.12 * k as f64, a), Point::from_polar(0.05, -a), 0.03)
        })
        .collect()
}

fn planner(space: Space) -> Planner {
    Planner::new(PlannerConfig {
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
    })
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
