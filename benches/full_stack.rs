//! The whole stack in virtual time: what one episode costs, how fast sweeps go, and where
//! a cycle's time goes. `cargo bench --bench full_stack` (docs/performance.md "The whole stack in
//! virtual time"). Times are thread CPU time, so a busy neighbour does not inflate them.

use std::path::Path;
use std::time::Instant;

use flowgate::gateway::core::StageClock;
use flowgate::gateway::shell::telemetry::CycleRecord;
use flowgate::lab::planner_only::{self, Mode};
use flowgate::lab::sweep;
use flowgate::lab::virtual_rig::{self, Options, VirtualRig};
use flowgate::lab::Scenario;
use rustix::time::{clock_gettime, ClockId};

/// This thread's CPU time, ns.
fn cpu_ns() -> u64 {
    let t = clock_gettime(ClockId::ThreadCPUTime);
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

/// The core's stages timed on the thread's CPU clock.
#[derive(Debug, Clone, Copy)]
struct ThreadCpu;

impl StageClock for ThreadCpu {
    fn now_ns(&mut self) -> u64 {
        cpu_ns()
    }
}

fn scenario(name: &str) -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)).expect("scenario")
}

fn main() {
    let e2 = scenario("e2-lane-head-on.toml");
    let runs = 200;

    // One E2 episode through the whole stack, as a sweep runs it.
    let _ = virtual_rig::run(&e2, Options::default());
    let mut per_episode = Vec::with_capacity(runs);
    let mut simulated = 0.0;
    for _ in 0..runs {
        let start = cpu_ns();
        let e = virtual_rig::run(&e2, Options::default());
        per_episode.push(cpu_ns() - start);
        simulated = e.truth.summary.duration;
    }
    per_episode.sort_unstable();
    let median = per_episode[runs / 2] as f64 / 1e6;
    println!("E2 episode, full stack: {simulated:.1} s simulated in {median:.2} ms of CPU (median of {runs}; min {:.2}, max {:.2}): {:.0} times faster than real time",
        per_episode[0] as f64 / 1e6, per_episode[runs - 1] as f64 / 1e6, simulated * 1e3 / median);

    // Where the time goes: the core's stages on the CPU clock, and the rest. The world is
    // computed where the firmware asks it (a sample, a command), so it is in the rest;
    // `scripts/sweep-instructions --full-stack` counts its share.
    let start = cpu_ns();
    let rig = VirtualRig::with_clock(&e2, ThreadCpu, Options { telemetry: true, ..Options::default() });
    let e = rig.run(e2.time_limit, e2.goal.position, e2.goal.tolerance);
    let total = (cpu_ns() - start) as f64;
    let csv = String::from_utf8(e.telemetry.expect("telemetry").cycles_csv).expect("utf-8");
    let mut stages = [0f64; 3];
    let mut cycles = 0;
    let columns = ["decode_ns", "track_ns", "plan_ns"].map(|c| CycleRecord::column(c).expect("a cycles.csv column"));
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        for (k, col) in columns.into_iter().enumerate() {
            stages[k] += f[col].parse::<f64>().expect("ns");
        }
        cycles += 1;
    }
    let per = |ns: f64| ns / f64::from(cycles) / 1e3;
    let rest = total - stages.iter().sum::<f64>();
    println!("one cycle ({cycles} cycles, with telemetry): {:.2} µs in all", per(total));
    for (name, ns) in [
        ("decode (COBS, CRC, packets)", stages[0]),
        ("track (calibration, pose, Kalman)", stages[1]),
        ("plan (control step)", stages[2]),
        ("firmware, world, encoders, SLCAN, wires, telemetry", rest),
    ] {
        println!("  {name:<45} {:>6.2} µs  {:>4.0}%", per(ns), 100.0 * ns / total);
    }

    // The whole stack's sweeps against their targets, 1,000 episodes/s around E2 (the lane)
    // and 3,000 around E1 (free space), on this machine's two cores; wall time, as a sweep's
    // user sees it, the median of three (a busy neighbour slows one run).
    let e1 = scenario("e1-standing-obstacle.toml");
    for (name, base, n, target) in [("E2", &e2, 1000, 1000.0), ("E1", &e1, 3000, 3000.0)] {
        let (rates, report) = sweep_rates(base, n, 3, 2, Mode::FullStack);
        println!(
            "full-stack sweep around {name}, {n} episodes on 2 threads: {:.0} episodes/s (median of {}; min {:.0}, \
             max {:.0}): {}; goal {:.1}%",
            rates[rates.len() / 2],
            rates.len(),
            rates[0],
            rates[rates.len() - 1],
            against(rates[rates.len() / 2], target),
            100.0 * report.goal_rate
        );
    }
    scaling(&e1, 1500, Mode::FullStack, "full-stack");
    let (rates, report) = sweep_rates(&e2, 2000, 1, 2, Mode::PlannerOnly);
    println!(
        "planner-only sweep around E2, 2000 episodes on 2 threads: {:.0} episodes/s; goal {:.1}%",
        rates[0],
        100.0 * report.goal_rate
    );

    // The bound the planner sets on a planner-only sweep: two threads over (one command's
    // cost × the commands an episode takes), both from a sample of the sweep's own episodes
    // on one thread; then how close the sweep itself comes to it.
    for (name, base, n) in [("E2 (lane)", &e2, 2000), ("E3b (free space)", &scenario("e3b-delay-margin.toml"), 20000)] {
        let sample = 200;
        let (mut plan_ns, mut commands) = (0.0, 0u64);
        let mut cost = planner_only::CycleCost::default();
        for i in 0..sample {
            let s = sweep::perturb(base, 1, i);
            let run = planner_only::run(&s, false);
            plan_ns += run.summary.planner_compute.p50_us * 1e3 * run.summary.cycles as f64;
            commands += run.summary.cycles;
            cost.sense_and_track_ns += run.cost.sense_and_track_ns;
            cost.control_ns += run.cost.control_ns;
            cost.world_ns += run.cost.world_ns;
        }
        let per_command_ns = plan_ns / commands as f64;
        let per_episode = commands as f64 / sample as f64;
        let bound = 2.0 / (per_command_ns * 1e-9 * per_episode);
        let started = Instant::now();
        sweep::sweep(base, n, 1, 2, Mode::PlannerOnly).expect("a sweep this small fits");
        let rate = n as f64 / started.elapsed().as_secs_f64();
        println!(
            "planner-only sweep around {name}: one command {:.2} µs (p50) x {per_episode:.0} commands an episode \
             bounds it at {bound:.0} episodes/s on 2 threads; the sweep runs {rate:.0} ({:.0}% of the bound)",
            per_command_ns / 1e3,
            100.0 * rate / bound
        );
        // Where a cycle of the sweep goes: the stages timed in the sample, and the whole
        // cycle as the sweep ran it (two threads over its rate and the cycles an episode).
        let per_cycle = |ns: u64| ns as f64 / commands as f64 / 1e3;
        let whole = 2.0 / rate / per_episode * 1e6;
        println!(
            "  a cycle of it: sensing and tracking {:.2} µs, control step {:.2} µs, world {:.2} µs (means, each \
             timed with a clock read); the sweep's cycle {whole:.2} µs on each thread",
            per_cycle(cost.sense_and_track_ns),
            per_cycle(cost.control_ns),
            per_cycle(cost.world_ns),
        );
    }

    // The planner-only targets: a sweep of 10^4 episodes on two threads, as `flowgate plan
    // --planner-only --sweep 10000 --seed 1 FILE` runs it, at 10,000 episodes/s or more around
    // E1 and 5,000 around each other free-space experiment (median of five, wall time).
    const EPISODES: usize = 10_000;
    const REPEATS: usize = 5;
    for (name, file, target) in [
        ("E1", "e1-standing-obstacle.toml", 10_000.0),
        ("E3b", "e3b-delay-margin.toml", 5000.0),
        ("E5", "e5-moving-and-standing.toml", 5000.0),
        ("E6", "e6-two-moving.toml", 5000.0),
    ] {
        let (rates, _) = sweep_rates(&scenario(file), EPISODES, REPEATS, 2, Mode::PlannerOnly);
        let median = rates[REPEATS / 2];
        println!(
            "planner-only sweep around {name}, {EPISODES} episodes on 2 threads: {median:.0} episodes/s (median of \
             {REPEATS}; min {:.0}, max {:.0}): {}",
            rates[0],
            rates[REPEATS - 1],
            against(median, target),
        );
    }
    scaling(&scenario("e1-standing-obstacle.toml"), 5000, Mode::PlannerOnly, "planner-only");
}

/// A rate on two threads against its target: met, or short of it and the threads it would
/// take at the same rate a thread (a sweep's episodes are independent of one another, so
/// `--threads` and a batch system's `--shard` spread them; [`scaling`] shows how well).
fn against(rate: f64, target: f64) -> String {
    if rate >= target {
        format!("meets the {target:.0} asked")
    } else {
        let per_thread = rate / 2.0;
        format!(
            "short of the {target:.0} asked, which at {per_thread:.0} a thread takes {:.0} threads",
            (target / per_thread).ceil()
        )
    }
}

/// How a sweep's rate grows from one thread to two (median of three each): what the
/// threads [`against`] counts rest on.
fn scaling(base: &Scenario, n: usize, mode: Mode, what: &str) {
    let median = |threads| {
        let (rates, _) = sweep_rates(base, n, 3, threads, mode);
        rates[1]
    };
    let (one, two) = (median(1), median(2));
    println!(
        "{what} sweep around {}, {n} episodes: {one:.0} episodes/s on 1 thread, {two:.0} on 2 (x{:.2}; median of 3 each)",
        base.name,
        two / one
    );
}

/// The rates of `repeats` sweeps of `n` episodes around `base` on `threads` threads
/// (episodes/s of wall time, sorted), and the last sweep's report.
fn sweep_rates(
    base: &Scenario,
    n: usize,
    repeats: usize,
    threads: usize,
    mode: Mode,
) -> (Vec<f64>, sweep::SweepReport) {
    let mut rates = Vec::with_capacity(repeats);
    let mut report = None;
    for _ in 0..repeats {
        let started = Instant::now();
        report = Some(sweep::sweep(base, n, 1, threads, mode).expect("a sweep this small fits"));
        rates.push(n as f64 / started.elapsed().as_secs_f64());
    }
    rates.sort_by(f64::total_cmp);
    (rates, report.expect("at least one sweep"))
}
