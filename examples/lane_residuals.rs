//! The lane field's residual table for the README: how far each obstacle's circle is from
//! a streamline (the normal-flow residual relative to the flow's speed on the circle), and
//! what building the field costs, for the paper's geometries and across the lane.
//!
//! cargo run --release --example lane_residuals [AIM]
//!
//! AIM is `planner.lane_residual`, the truncation error the series aim at (default 1e-8).

use std::time::Instant;

use flowgate::planner::{Field, PlanObstacle, Sink, Space};
use num_complex::Complex64 as C;

fn sink(goal: C) -> Sink {
    Sink { goal, strength: 0.1 * 0.14, c1: 20.0, reference_radius: 0.14 }
}

/// The lane field at `aim` (`planner.lane_residual`).
fn build(aim: f64, h: f64, obstacles: &[PlanObstacle], goal: C) -> Field {
    let lane = Space::Lane { half_width: h };
    let mut field = Field::empty(lane, sink(goal));
    field.set_lane_aim(aim).expect("main checked the aim");
    field.rebuild(lane, sink(goal), obstacles).expect("a valid geometry");
    field
}

/// The residual on the first circle, and the field's build time in µs (median of 201).
fn measure(aim: f64, h: f64, obstacles: &[PlanObstacle], goal: C) -> (f64, f64) {
    let field = build(aim, h, obstacles, goal);
    let residual = (0..obstacles.len()).filter_map(|k| field.circle_residual(k, 720)).fold(0.0, f64::max);
    let mut times: Vec<f64> = (0..201)
        .map(|_| {
            let start = Instant::now();
            std::hint::black_box(build(aim, h, obstacles, goal));
            start.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    times.sort_by(f64::total_cmp);
    (residual, times[100])
}

fn refuse(why: &str) -> ! {
    eprintln!("lane_residuals: {why}");
    std::process::exit(2)
}

fn main() {
    let goal = C::new(0.8, 0.0);
    let aim = match std::env::args().nth(1).map(|a| (a.parse::<f64>(), a)) {
        None => flowgate::planner::lane_series::EXACT_AIM,
        Some((Ok(aim), _)) => aim,
        Some((Err(_), a)) => refuse(&format!("AIM is a number (1e-10 to 1e-4), not {a}")),
    };
    let lane = Space::Lane { half_width: 0.2 };
    if let Err(why) = Field::empty(lane, sink(goal)).set_lane_aim(aim) {
        refuse(&format!("AIM: {why}"));
    }
    println!("the series aim at {aim:e} (planner.lane_residual)");
    let one = |centre: C, radius: f64, velocity: C| [PlanObstacle { center: centre, velocity, radius }];
    println!("{:<58} {:>10} {:>10}", "geometry (h = 0.2 m unless given)", "residual", "build µs");
    let rows: [(&str, f64, Vec<PlanObstacle>); 7] = [
        ("R = 3 cm, centred, moving", 0.2, one(C::new(0.0, 0.0), 0.03, C::new(-0.056, 0.0)).to_vec()),
        ("R = 14 cm, centred (70% blockage), moving", 0.2, one(C::new(0.0, 0.0), 0.14, C::new(-0.056, 0.0)).to_vec()),
        ("R = 18 cm, centred (90% blockage), standing", 0.2, one(C::new(0.2, 0.0), 0.18, C::default()).to_vec()),
        ("R = 18 cm, centred (90% blockage), moving", 0.2, one(C::new(0.2, 0.0), 0.18, C::new(-0.05, 0.03)).to_vec()),
        (
            "E2: R = 14 cm at y = 6 cm (touching the wall), moving",
            0.2,
            one(C::new(0.0, 0.06), 0.14, C::new(-0.056, 0.0)).to_vec(),
        ),
        (
            "two obstacles, R = 11 cm, h = 0.6 m (the bench's lane_2)",
            0.6,
            vec![
                PlanObstacle { center: C::new(0.25, 0.0), velocity: C::new(0.05, 0.0), radius: 0.11 },
                PlanObstacle {
                    center: C::from_polar(0.37, 2.399),
                    velocity: C::from_polar(0.05, -2.399),
                    radius: 0.11,
                },
            ],
        ),
        ("R = 1 cm, 1 mm from the wall, standing", 0.2, one(C::new(0.0, 0.189), 0.01, C::default()).to_vec()),
    ];
    for (name, h, obstacles) in rows {
        let (residual, us) = measure(aim, h, &obstacles, goal);
        println!("{name:<58} {residual:>10.1e} {us:>10.1}");
    }

    // Across the lane: every centre and radius on a grid, standing and moving four ways.
    let h = 0.1;
    let (mut clear, mut near) = ([0usize; 8], [0usize; 8]);
    let (mut worst_clear, mut worst_near) = (0.0f64, 0.0f64);
    for iy in 0..100 {
        for ir in 0..40 {
            let y = (-0.999 + 1.998 * f64::from(iy) / 99.0) * h;
            let r = (0.02 + 0.88 * f64::from(ir) / 39.0) * h;
            // Closed against the wall below a gap of R/10.
            let is_clear = h - y.abs() - r >= flowgate::planner::field::WALL_CLOSE * r;
            for v in [C::default(), C::new(0.15, 0.0), C::new(-0.15, 0.0), C::new(0.0, 0.15), C::new(0.0, -0.15)] {
                let field = build(aim, h, &one(C::new(0.0, y), r, v), C::new(3.0 * h, 0.0));
                let w = field.circle_residual(0, 720).expect("one obstacle");
                let decade = (-w.log10()).floor().clamp(0.0, 7.0) as usize;
                if is_clear {
                    clear[decade] += 1;
                    worst_clear = worst_clear.max(w);
                } else {
                    near[decade] += 1;
                    worst_near = worst_near.max(w);
                }
            }
        }
    }
    println!();
    println!("across the lane (h = 0.1 m; centres over the whole band, R from 2% to 90% of h; standing and 15 cm/s four ways);\n each column counts the residuals from its bound up to the previous column's");
    println!(
        "{:<40} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>8}",
        "circles", "≥1e-1", "≥1e-2", "≥1e-3", "≥1e-4", "≥1e-5", "≥1e-6", "≥1e-7", "<1e-7", "worst"
    );
    for (name, hist, worst) in
        [("clear of the walls (gap >= R/10)", clear, worst_clear), ("near or across a wall (closed)", near, worst_near)]
    {
        print!("{name:<40}");
        for count in &hist {
            print!(" {count:>6}");
        }
        println!(" {worst:>8.1e}");
    }
}
