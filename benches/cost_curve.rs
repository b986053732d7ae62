//! The cost curve: how a cycle's cost and a sweep's rate grow with the number of obstacles,
//! in free space and in a lane, planner only and through the whole stack.
//! `cargo bench --bench cost_curve` (docs/performance.md "The cost curve").
//!
//! The scene is the crowd benchmark's circle crossing (scenarios/crowd/): the robot crosses
//! a circle of 0.65 m while n obstacles cross it from random points to their antipodes, each
//! episode placed afresh. In the lane the same crowd crosses between walls at ±0.75 m (the
//! camera's view), so the two columns differ only by the lane's field. n runs 1, 2, 4, 8
//! and 14: a controller addresses 16 LEDs, two of them the robot's.
//!
//! Each row runs the sweep's episodes one after another on this thread, for about 3 s of CPU
//! (200 episodes at most, 4 at least): a cycle's cost is the CPU time over their cycles, and
//! the sweep's rate is episodes per CPU second, what each of a sweep's threads runs
//! (`flowgate plan --sweep N --threads K` runs about K times that).

use flowgate::lab::planner_only::{self, Mode, Outcome};
use flowgate::lab::sweep;
use flowgate::lab::virtual_rig::{self, Options};
use flowgate::lab::Scenario;
use rustix::time::{clock_gettime, ClockId};
use std::path::Path;

/// This thread's CPU time, ns.
fn cpu_ns() -> u64 {
    let t = clock_gettime(ClockId::ThreadCPUTime);
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

const COUNTS: [usize; 5] = [1, 2, 4, 8, 14];

/// The crowd scenario with `n` obstacles, in a lane or not.
fn crowd(n: usize, lane: bool) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/crowd/circle-crossing-5.toml");
    let text = std::fs::read_to_string(&path).expect("the crowd scenario");
    let mut text = text
        .replace("obstacles = 5\n", &format!("obstacles = {n}\n"))
        .replace("circle_radius = 0.6\n", "circle_radius = 0.65\n");
    if lane {
        text.push_str("\n[lane]\nhalf_width = 0.75\n");
    }
    let name = format!("crowd of {n}{}", if lane { " in a lane" } else { "" });
    Scenario::from_toml(&text, &name).expect("a valid crowd scenario")
}

/// One episode of `mode` around `base`: its cycles, and whether it reached the goal.
fn episode(base: &Scenario, i: u64, mode: Mode) -> (u64, bool) {
    let s = sweep::perturb(base, 1, i);
    match mode {
        Mode::PlannerOnly => {
            let run = planner_only::run(&s, false);
            (run.summary.cycles, run.summary.outcome == Outcome::Goal)
        }
        Mode::FullStack => {
            let e = virtual_rig::run(&s, Options::default());
            ((e.truth.summary.duration / s.sim.sensing.sample_time).round() as u64, e.outcome == Outcome::Goal)
        }
    }
}

/// Each row runs episodes until it has taken this much CPU (at least [`MIN_EPISODES`]).
const BUDGET_NS: u64 = 3_000_000_000;
const MIN_EPISODES: u64 = 4;
const MAX_EPISODES: u64 = 200;

fn main() {
    println!(
        "{:<12} {:<5} {:>3} {:>9} {:>10} {:>8} {:>14} {:>7}",
        "mode", "space", "n", "episodes", "cycle µs", "cycles", "episodes/CPU s", "goal %"
    );
    for mode in [Mode::PlannerOnly, Mode::FullStack] {
        for lane in [false, true] {
            for n in COUNTS {
                let base = crowd(n, lane);
                let start = cpu_ns();
                let (mut episodes, mut cycles, mut goals) = (0u64, 0u64, 0u64);
                while episodes < MAX_EPISODES && (episodes < MIN_EPISODES || cpu_ns() - start < BUDGET_NS) {
                    let (c, goal) = episode(&base, episodes, mode);
                    episodes += 1;
                    cycles += c;
                    goals += u64::from(goal);
                }
                let cpu_s = (cpu_ns() - start) as f64 * 1e-9;
                println!(
                    "{:<12} {:<5} {n:>3} {episodes:>9} {:>10.2} {:>8.0} {:>14.1} {:>7.1}",
                    mode.to_string(),
                    if lane { "lane" } else { "free" },
                    cpu_s * 1e6 / cycles as f64,
                    cycles as f64 / episodes as f64,
                    episodes as f64 / cpu_s,
                    100.0 * goals as f64 / episodes as f64
                );
            }
        }
    }
}
