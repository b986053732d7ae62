//! `flowgate plan`: the offline scenario runner.

use crate::cli::say;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use flowgate::lab::planner_only::Mode;
use flowgate::lab::{outputs, plots, Scenario};
use flowgate::lab::{people_benchmark, policy, swarm, sweep};

#[derive(Args, Debug)]
pub struct PlanArgs {
    /// The scenario file (TOML).
    #[arg(long, value_name = "FILE", conflicts_with = "all")]
    scenario: Option<PathBuf>,
    /// The scenario file, positionally (for `--sweep N FILE`).
    #[arg(value_name = "FILE", conflicts_with_all = ["all", "scenario"])]
    file: Option<PathBuf>,
    /// Run every `*.toml` in this folder and print a table.
    #[arg(long, value_name = "DIR")]
    all: Option<PathBuf>,
    /// Run the people benchmark on the scenarios of this folder (scenarios/people): every
    /// method on every row, --sweep episodes each (default 500); writes benchmark.json,
    /// benchmark.svg and the episodes as Parquet into --out (default out/benchmark).
    #[arg(long, value_name = "DIR", conflicts_with_all = ["all", "scenario", "file", "swarm", "policy", "merge", "compare", "shard", "unsupervised"])]
    benchmark: Option<PathBuf>,
    /// Run a Monte-Carlo sweep of this many episodes around the scenario.
    #[arg(long, value_name = "N", conflicts_with = "all")]
    sweep: Option<usize>,
    /// Seed of the sweep.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run only this shard of the sweep, `i/n`: the episodes whose index is i modulo n
    /// (writes shard.json and episodes.parquet for `--merge`; a batch system runs i = 0..n-1
    /// anywhere). `auto/n`
    /// takes i from the array job's index: SLURM_ARRAY_TASK_ID (less SLURM_ARRAY_TASK_MIN),
    /// JOB_COMPLETION_INDEX (Kubernetes) or AWS_BATCH_JOB_ARRAY_INDEX.
    #[arg(long, value_name = "I/N")]
    shard: Option<sweep::ShardSpec>,
    /// Run the sweep twice, the second time with this setting changed (`KEY=VALUE`, e.g.
    /// `planner.lane_residual=1e-8`), and say whether the outcomes stay the same in
    /// distribution (each rate inside the other's 95% interval, the minimum clearances
    /// alike by a Kolmogorov-Smirnov test at 1%); fails when they do not.
    #[arg(long, value_name = "KEY=VALUE", requires = "sweep", conflicts_with = "shard")]
    compare: Option<String>,
    /// Run a fault swarm of this many episodes around the scenario: random overlapping
    /// faults on both links and in the world, through the whole stack, an operator
    /// resetting, arming and starting after each stop, every episode judged by invariants.
    /// Of a fleet: a vehicle's lost link, the operator's stop of one vehicle and the fleet's
    /// e-stop, at the planner level, judged by the fleet's invariants.
    #[arg(long, value_name = "N", conflicts_with_all = ["all", "sweep", "planner_only"])]
    swarm: Option<u64>,
    /// Run one episode of the swarm or the sweep alone, keeping its outputs in --out: for the
    /// swarm its cycles.csv, can.log and truth (the command a broken invariant prints), for
    /// the sweep what a single run writes (summary.json, the plots, and through the whole
    /// stack cycles.csv and can.log).
    #[arg(long, value_name = "K", conflicts_with_all = ["shard", "compare"])]
    episode: Option<u64>,
    /// Merge sweep shards (each DIR holding a shard.json and its episodes.parquet) into one
    /// sweep: sweep.json and episodes.parquet in --out.
    #[arg(long, value_name = "DIR", num_args = 1.., conflicts_with_all = ["all", "scenario", "file", "sweep"])]
    merge: Vec<PathBuf>,
    /// Worker threads for the sweep or the swarm, from 1 to 1024 [default: the CPUs this
    /// process may use, as its affinity and cgroup quota allow (a batch system's allocation)].
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=sweep::MAX_THREADS as i64))]
    threads: Option<u16>,
    /// Run the planner alone against a modelled sensing chain (faster), instead of the whole
    /// stack (the gateway core, the firmware and the wire protocols) in virtual time.
    #[arg(long)]
    planner_only: bool,
    /// A fleet through the whole stack (the gateway core driving every vehicle, navigating
    /// or scripted, against the simulator's firmware, in virtual time) rather than at the
    /// planner level: one run, `--sweep N`, `--sweep N --compare-obstacles` or `--swarm N`.
    #[arg(long, conflicts_with_all = ["planner_only", "policy", "compare", "shard"])]
    whole_stack: bool,
    /// Let the planner drive without the safety supervisor (for before-and-after
    /// comparisons; the gateway always runs it).
    #[arg(long)]
    unsupervised: bool,
    /// Let a planner outside flowgate drive: CMD (run by `sh -c`) speaks JSON lines with the
    /// whole stack in virtual time, its commands supervised (docs/policies.md); with
    /// --sweep or --swarm, one process a worker.
    #[arg(long, value_name = "CMD", conflicts_with_all = ["all", "planner_only", "unsupervised", "compare", "merge"])]
    policy: Option<String>,
    /// How long the policy may take to answer one observation, host time, ms.
    #[arg(long, value_name = "MS", default_value_t = 1000, requires = "policy",
          value_parser = clap::value_parser!(u64).range(1..=60_000))]
    policy_budget_ms: u64,
    /// With --policy on a fleet's scenario: the navigating vehicle the policy drives (its
    /// name; default the robot), the others as the scenario says, at the planner level.
    #[arg(long, value_name = "NAME", requires = "policy")]
    vehicle: Option<String>,
    /// With --sweep of a fleet: run every episode twice, the scripted vehicles as vehicles
    /// and as obstacles on the same scripts, and compare the robot's outcomes.
    #[arg(long, requires = "sweep")]
    compare_obstacles: bool,
    /// Where to write summary.json and the plots (default: out/plan/<scenario>).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

impl PlanArgs {
    /// `--threads`, or the CPUs this process may use.
    fn threads(&self) -> usize {
        self.threads.map_or_else(sweep::available_threads, usize::from)
    }

    fn policy_budget(&self) -> std::time::Duration {
        std::time::Duration::from_millis(self.policy_budget_ms)
    }
}

pub fn run(args: PlanArgs) -> Result<()> {
    let mode = if args.planner_only { Mode::PlannerOnly } else { Mode::FullStack };
    if !args.merge.is_empty() {
        return merge(&args.merge, args.out.as_deref());
    }
    if let Some(dir) = &args.all {
        return run_all(dir, args.out.as_deref(), mode, !args.unsupervised);
    }
    if let Some(dir) = &args.benchmark {
        let out = args.out.clone().unwrap_or_else(|| PathBuf::from("out/benchmark"));
        let n = args.sweep.unwrap_or(500);
        let b = people_benchmark::run(dir, &out, n, args.seed, args.threads(), mode)?;
        say!("{b}");
        say!(
            "wrote {}/{{benchmark.json,benchmark.svg}} and episodes/ (Parquet, Hive-partitioned by row and method)",
            out.display()
        );
        return Ok(());
    }
    let Some(file) = args.scenario.as_ref().or(args.file.as_ref()) else {
        bail!("name a scenario: --scenario FILE, or --all DIR");
    };
    let mut scenario = Scenario::load(file)?;
    scenario.supervised = !args.unsupervised;
    for note in &scenario.notes {
        say!("note: {note}");
    }
    let out = args.out.clone().unwrap_or_else(|| Path::new("out/plan").join(stem(file)));
    if scenario.is_fleet() || scenario.swap.is_some() {
        return fleet_command(&args, file, &scenario, &out);
    }
    fleet_flags_refused(&args, file)?;
    if args.shard.is_some() && args.sweep.is_none() && args.swarm.is_none() {
        bail!("--shard splits a --sweep or a --swarm");
    }
    if args.episode.is_some() && args.sweep.is_none() && args.swarm.is_none() {
        bail!("--episode picks one episode of a --sweep or a --swarm");
    }
    if let Some(n) = args.sweep {
        return sweep_command(&args, file, &scenario, n, &out, mode);
    }
    if let Some(n) = args.swarm {
        return swarm_command(&args, file, &scenario, n, &out);
    }
    let run = match &args.policy {
        Some(command) => outputs::run_policy(&scenario, command, args.policy_budget(), Some(&out))?,
        None => outputs::run_one(&scenario, mode, Some(&out))?,
    };
    say!("{}  ({mode})", plots::one_line(&run));
    if let Some(stop) = run.summary.stop_reason.as_deref().filter(|s| s.starts_with("policy:")) {
        say!("  {stop}");
    }
    outputs::write_run(&out, &scenario, &run)?;
    say_run_files(&out, mode);
    Ok(())
}

/// `--sweep N`: the episodes around the scenario, or one shard of them (`--shard i/n`): a
/// shard's manifest and episodes for `--merge`, or the whole sweep's report and episodes.
fn sweep_command(args: &PlanArgs, file: &Path, scenario: &Scenario, n: usize, out: &Path, mode: Mode) -> Result<()> {
    if n == 0 {
        bail!("--sweep needs at least one episode");
    }
    if n as u64 > sweep::MAX_EPISODES {
        bail!("--sweep {n}: at most {} episodes (shard a larger envelope into several sweeps)", sweep::MAX_EPISODES);
    }
    if let Some(setting) = &args.compare {
        return compare_command(args, file, scenario, n, setting, out, mode);
    }
    if let Some(k) = args.episode {
        return sweep_episode(args.seed, scenario, n as u64, k, out, mode);
    }
    let started = std::time::Instant::now();
    let bytes = flowgate_sim::scenario::read_text(file, flowgate_sim::scenario::MAX_FILE_BYTES)
        .with_context(|| format!("reading {}", file.display()))?
        .into_bytes();
    outputs::folder(out)?;
    let shard = args.shard.map(|s| s.resolve(|name| std::env::var(name).ok())).transpose()?;
    let whole = shard.unwrap_or(sweep::Shard::WHOLE);
    let episodes = match &args.policy {
        Some(command) => sweep::run_policy_shard(
            scenario,
            n as u64,
            args.seed,
            args.threads(),
            whole,
            command,
            args.policy_budget(),
        )?,
        None => sweep::run_shard(scenario, n as u64, args.seed, args.threads(), mode, whole)?,
    };
    let manifest =
        sweep::Manifest::new(scenario, &bytes, mode, args.seed, n as u64, shard.unwrap_or(sweep::Shard::WHOLE));
    let report = sweep::report(&scenario.name, args.seed, mode, scenario.supervised, &episodes);
    if let Some(shard) = shard {
        say!("shard {shard} of the sweep of {n}:");
    }
    say!("{report}");
    say!("  ({} episodes in {:.1} s)", episodes.len(), started.elapsed().as_secs_f64());
    if shard.is_some() {
        sweep::write_shard(out, &manifest, &episodes)?;
        say!("  wrote {}/{{{},{}}}", out.display(), sweep::MANIFEST_FILE, sweep::EPISODES_FILE);
    } else {
        outputs::write_sweep(out, &manifest, &episodes, &report)?;
        say!("  wrote {}/{{sweep.json,{}}}", out.display(), sweep::EPISODES_FILE);
    }
    Ok(())
}

/// `--sweep N --episode K`: episode K of the sweep alone, as a single run (its outcome, and
/// through the whole stack the state it ended in), with a single run's outputs.
fn sweep_episode(seed: u64, scenario: &Scenario, n: u64, k: u64, out: &Path, mode: Mode) -> Result<()> {
    if k >= n {
        bail!("--episode {k}: the sweep has episodes 0 to {}", n - 1);
    }
    let s = sweep::perturb(scenario, seed, k);
    let run = outputs::run_one(&s, mode, Some(out))?;
    say!("episode {k} of the sweep of {n} around {} (seed {seed}, {mode}):", scenario.name);
    say!("{}", plots::one_line(&run));
    outputs::write_run(out, &s, &run)?;
    say_run_files(out, mode);
    Ok(())
}

/// `--sweep N --compare KEY=VALUE`: the same episodes as given and with the setting
/// changed, side by side (`compare.json`).
fn compare_command(
    args: &PlanArgs,
    file: &Path,
    scenario: &Scenario,
    n: usize,
    setting: &str,
    out: &Path,
    mode: Mode,
) -> Result<()> {
    let mut changed = Scenario::load_with(file, setting)?;
    changed.supervised = scenario.supervised;
    let started = std::time::Instant::now();
    let before = sweep::run_shard(scenario, n as u64, args.seed, args.threads(), mode, sweep::Shard::WHOLE)?;
    let after = sweep::run_shard(&changed, n as u64, args.seed, args.threads(), mode, sweep::Shard::WHOLE)?;
    let comparison = sweep::compare::compare(&before, &after);
    say!("{n} episodes around {} (seed {}, {mode}), as given and with {setting}:", scenario.name, args.seed);
    say!("{comparison}");
    say!("  ({} episodes in {:.1} s)", 2 * n, started.elapsed().as_secs_f64());
    let path = outputs::write_comparison(out, &comparison)?;
    say!("  wrote {}", path.display());
    if !comparison.same {
        bail!("with {setting} the outcomes are not the same in distribution");
    }
    Ok(())
}

/// `--swarm N`: the fault swarm, or one shard of it, or one episode (`--episode K`).
fn swarm_command(args: &PlanArgs, file: &Path, scenario: &Scenario, n: u64, out: &Path) -> Result<()> {
    if n == 0 {
        bail!("--swarm needs at least one episode");
    }
    if n > sweep::MAX_EPISODES {
        bail!("--swarm {n}: at most {} episodes (shard a larger swarm into several)", sweep::MAX_EPISODES);
    }
    outputs::folder(out)?;
    let replay = |k: u64| {
        let unsupervised = if scenario.supervised { "" } else { " --unsupervised" };
        let policy = args.policy.as_ref().map_or(String::new(), |p| format!(" --policy '{p}'"));
        format!("flowgate plan --swarm {n} --seed {} --episode {k}{unsupervised}{policy} {}", args.seed, file.display())
    };
    if let Some(k) = args.episode {
        return swarm_episode(args, scenario, n, k, out);
    }
    let started = std::time::Instant::now();
    let shard =
        args.shard.map(|s| s.resolve(|name| std::env::var(name).ok())).transpose()?.unwrap_or(sweep::Shard::WHOLE);
    let policy = args.policy.as_deref().map(|command| (command, args.policy_budget()));
    let outcomes = swarm::run(scenario, n, args.seed, args.threads(), shard, policy)?;
    let report = swarm::report(scenario, args.seed, shard, &outcomes);
    say!("{report}");
    say!(
        "  ({} episodes, {:.0} s of virtual time, in {:.1} s)",
        outcomes.len(),
        report.virtual_s,
        started.elapsed().as_secs_f64()
    );
    let path = outputs::write_swarm(out, &report)?;
    say!("  wrote {}", path.display());
    for o in &report.failures {
        say!("episode {} ({}) broke:", o.index, o.backend.name());
        for v in &o.violations {
            say!("  {v}");
        }
        say!("  replay: {}", replay(o.index));
    }
    if report.violated > 0 {
        bail!("{} of {} episodes broke an invariant", report.violated, report.episodes);
    }
    Ok(())
}

/// `--swarm N --episode K`: one episode of the swarm, alone, its files kept in `out`.
fn swarm_episode(args: &PlanArgs, scenario: &Scenario, n: u64, k: u64, out: &Path) -> Result<()> {
    if k >= n {
        bail!("--episode {k}: the swarm has episodes 0 to {}", n - 1);
    }
    let mut worker = args.policy.as_deref().map(|command| policy::Worker::new(command, args.policy_budget()));
    let (outcome, run) = swarm::run_episode(scenario, args.seed, k, true, worker.as_mut());
    let schedule = swarm::schedule(scenario, args.seed, k);
    say!("episode {k} of the swarm around {} (seed {}), {}:", scenario.name, args.seed, outcome.backend.name());
    for f in &outcome.faults {
        let led = f.led.map(|l| format!(" (LED {l})")).unwrap_or_default();
        say!("  fault {:?}{led}: {:.3} s to {:.3} s", f.kind, f.from, f.to);
    }
    for s in &outcome.stops {
        let rest = s.rest_after.map_or("never".into(), |r| format!("{:.1} ms", r * 1e3));
        say!("  {:>8.3} s  fault: {}  (wheels at rest after {rest})", s.at, s.reason);
    }
    let states = outcome.states.iter().map(|(t, state)| format!("{t:.3} s {state}"));
    say!("  states: {}", states.collect::<Vec<_>>().join(", "));
    say!(
        "  goal reached: {}; {} requests refused; {:.1} s virtual",
        outcome.reached_goal,
        outcome.refusals,
        outcome.duration
    );
    say!("  bytes sent: digest {}", outcome.digest);
    outputs::write_swarm_episode(out, &outcome, &run, &schedule)?;
    say!("  wrote {}/{{{}}}", out.display(), outputs::SWARM_EPISODE_FILES);
    if !outcome.violations.is_empty() {
        bail!("episode {k} broke {} invariants:\n  {}", outcome.violations.len(), outcome.violations.join("\n  "));
    }
    Ok(())
}

/// `--merge`: the shards as one sweep, its report and episodes in `out`.
fn merge(dirs: &[PathBuf], out: Option<&Path>) -> Result<()> {
    let shards = dirs.iter().map(|dir| sweep::read_shard(dir)).collect::<Result<Vec<_>, _>>()?;
    let (manifest, episodes, report) = sweep::merge(&shards)?;
    say!("{report}");
    say!("  (merged from {} shards)", shards.len());
    let out = out.map_or_else(|| Path::new("out/plan").join("merged"), Path::to_path_buf);
    outputs::write_sweep(&out, &manifest, &episodes, &report)?;
    say!("  wrote {}/{{sweep.json,{}}}", out.display(), sweep::EPISODES_FILE);
    Ok(())
}

fn stem(path: &Path) -> String {
    path.file_stem().map_or_else(|| "scenario".into(), |s| s.to_string_lossy().into_owned())
}

/// What a single run wrote.
fn say_run_files(out: &Path, mode: Mode) {
    let extra = if mode == Mode::FullStack { format!(",{}", outputs::TELEMETRY_FILES) } else { String::new() };
    say!("  wrote {}/{{{}{extra}}}", out.display(), outputs::RUN_FILES);
}

/// A fleet's row of `--all`'s table: its outcome, any contact, and its makespan.
fn fleet_row(file: &Path, scenario: &Scenario) -> String {
    let f = flowgate::lab::fleet::run(scenario, flowgate::lab::fleet::FleetOptions::default());
    let contact = f.vehicles.iter().filter_map(|v| v.contact.as_ref()).map(|c| c.active).reduce(|a, b| a || b);
    let contact = contact.map_or("-", |active| if active { "active" } else { "passive" });
    let time = f.makespan.unwrap_or(f.end_time);
    let n = f.vehicles.len();
    format!(
        "{:<26} {:<9} {:<8} {:>7.1}  (fleet of {n}, planner level)",
        stem(file),
        f.outcome.to_string(),
        contact,
        time
    )
}

fn run_all(dir: &Path, out: Option<&Path>, mode: Mode, supervised: bool) -> Result<()> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("no *.toml scenarios in {}", dir.display());
    }
    say!("{mode}{}", if supervised { "" } else { ", unsupervised" });
    say!(
        "{:<26} {:<9} {:<8} {:>7} {:>11} {:>9} {:>6} {:>10} {:>10}",
        "scenario",
        "outcome",
        "contact",
        "time s",
        "clear. mm",
        "wall mm",
        "path×",
        "wheel mm/s",
        "plan p99µs"
    );
    for file in files {
        let mut scenario = Scenario::load(&file)?;
        scenario.supervised = supervised;
        let dir = out.map(|o| o.join(stem(&file)));
        if scenario.is_fleet() {
            say!("{}", fleet_row(&file, &scenario));
            continue;
        }
        let run = outputs::run_one(&scenario, mode, dir.as_deref())?;
        let s = &run.summary;
        say!(
            "{:<26} {:<9} {:<8} {:>7.1} {:>11} {:>9} {:>6.2} {:>10.0} {:>10}",
            stem(&file),
            s.outcome.to_string(),
            s.contact.map_or("-", |c| if c.active { "active" } else { "passive" }),
            s.time_to_goal.unwrap_or(s.end_time),
            s.min_obstacle_clearance.map_or("-".into(), |c| format!("{:.1}", c * 1e3)),
            s.min_wall_clearance.map_or("-".into(), |c| format!("{:.1}", c * 1e3)),
            s.path_length_ratio,
            s.peak_wheel_speed[0].max(s.peak_wheel_speed[1]) * 1e3,
            format!("{:.1}", s.planner_compute.p99_us)
        );
        if let Some(dir) = dir {
            outputs::write_run(&dir, &scenario, &run)?;
        }
    }
    Ok(())
}

/// The flags for a fleet, refused for a robot alone.
fn fleet_flags_refused(args: &PlanArgs, file: &Path) -> Result<()> {
    if let Some(name) = &args.vehicle {
        bail!("--vehicle {name}: {} has no vehicles beside the robot ([[vehicles]] or [swap])", file.display());
    }
    if args.whole_stack {
        bail!("--whole-stack runs a fleet: {} drives the robot alone, through the whole stack already", file.display());
    }
    Ok(())
}

/// A scenario of several vehicles: one run, `--sweep N`, or `--sweep N --episode K`. The
/// fleet runs at the planner level (`flowgate::lab::fleet`); the rest of `plan`'s modes
/// drive one robot.
fn fleet_command(args: &PlanArgs, file: &Path, scenario: &Scenario, out: &Path) -> Result<()> {
    use flowgate::lab::fleet::{self, sweep as fleet_sweep, FleetOptions};
    let driven = fleet_driven(args, scenario)?;
    if let Some(n) = args.swarm {
        return fleet_swarm_command(args, file, scenario, n, out);
    }
    if args.whole_stack {
        return fleet_stack_command(args, scenario, out);
    }
    let options = FleetOptions::default();
    let run_traced = |s: &Scenario| fleet_run_traced(args, s, options, driven);
    let Some(n) = args.sweep else {
        let (summary, trace) = run_traced(scenario);
        fleet::lines(&summary).iter().for_each(|l| say!("{l}"));
        outputs::write_fleet_run(out, scenario, &summary, &trace)?;
        say!("  wrote {}/{{summary.json,trajectory.svg}}  (fleet, planner level)", out.display());
        return Ok(());
    };
    if n == 0 || n as u64 > sweep::MAX_EPISODES {
        bail!("--sweep {n}: 1 to {} episodes", sweep::MAX_EPISODES);
    }
    if let Some(k) = args.episode {
        if k >= n as u64 {
            bail!("--episode {k}: the sweep has episodes 0 to {}", n - 1);
        }
        let s = fleet_sweep::place(scenario, args.seed, k);
        let (summary, trace) = run_traced(&s);
        say!("episode {k} of the sweep of {n} around {} (seed {}):", scenario.name, args.seed);
        fleet::lines(&summary).iter().for_each(|l| say!("{l}"));
        outputs::write_fleet_run(out, &s, &summary, &trace)?;
        return Ok(());
    }
    let started = std::time::Instant::now();
    if args.compare_obstacles {
        let comparison = fleet_sweep::compare_scripts(scenario, n as u64, args.seed, args.threads(), options)?;
        say!("{comparison}");
        say!("  ({} episodes twice in {:.1} s, fleet, planner level)", n, started.elapsed().as_secs_f64());
        outputs::write_json(&out.join("scripts_compared.json"), &comparison)?;
        say!("  wrote {}/scripts_compared.json", out.display());
        return Ok(());
    }
    let (report, episodes) = match driven {
        Some((k, command)) => {
            let (seed, threads, budget) = (args.seed, args.threads(), args.policy_budget());
            fleet_sweep::sweep_policy(scenario, n as u64, seed, threads, options, k, command, budget)?
        }
        None => fleet_sweep::sweep(scenario, n as u64, args.seed, args.threads(), options)?,
    };
    say!("{report}");
    say!("  ({} episodes in {:.1} s, fleet, planner level)", episodes.len(), started.elapsed().as_secs_f64());
    outputs::write_fleet_sweep(out, &report, &episodes)?;
    say!("  wrote {}/{{fleet_sweep.json,fleet_episodes.jsonl}}", out.display());
    Ok(())
}

/// `--whole-stack`: a fleet through the whole stack (navigating and scripted vehicles), one
/// run, `--sweep N` (`--episode K` of it) or `--sweep N --compare-obstacles`.
fn fleet_stack_command(args: &PlanArgs, scenario: &Scenario, out: &Path) -> Result<()> {
    use flowgate::lab::fleet::{self, stack, sweep as fleet_sweep};
    let placed = match (args.sweep, args.episode) {
        (Some(n), Some(k)) if k < n as u64 => Some(fleet_sweep::place(scenario, args.seed, k)),
        (Some(n), Some(k)) => bail!("--episode {k}: the sweep has episodes 0 to {}", n - 1),
        (None, Some(_)) => bail!("--episode picks one episode of a --sweep"),
        (None, None) => Some(scenario.clone()),
        (Some(_), None) => None,
    };
    if let Some(s) = placed {
        let summary = stack::run(&s);
        fleet::lines(&summary).iter().for_each(|l| say!("{l}"));
        outputs::folder(out)?;
        outputs::write_json(&out.join("summary.json"), &summary)?;
        say!("  wrote {}/summary.json  (fleet, whole stack)", out.display());
        return Ok(());
    }
    let n = args.sweep.unwrap_or(1);
    if n == 0 || n as u64 > sweep::MAX_EPISODES {
        bail!("--sweep {n}: 1 to {} episodes", sweep::MAX_EPISODES);
    }
    let started = std::time::Instant::now();
    if args.compare_obstacles {
        let comparison = fleet_sweep::compare_scripts_with(scenario, n as u64, args.seed, args.threads(), stack::run)?;
        say!("{comparison}");
        say!("  ({} episodes twice in {:.1} s, fleet, whole stack)", n, started.elapsed().as_secs_f64());
        outputs::write_json(&out.join("scripts_compared.json"), &comparison)?;
        say!("  wrote {}/scripts_compared.json", out.display());
        return Ok(());
    }
    let (report, episodes) = stack::sweep(scenario, n as u64, args.seed, args.threads())?;
    say!("{report}");
    say!("  ({} episodes in {:.1} s, fleet, whole stack)", episodes.len(), started.elapsed().as_secs_f64());
    outputs::write_fleet_sweep(out, &report, &episodes)?;
    say!("  wrote {}/{{fleet_sweep.json,fleet_episodes.jsonl}}", out.display());
    Ok(())
}

/// `--swarm N` of a fleet: faults on every vehicle and on the fleet, judged by invariants
/// (`flowgate::lab::fleet::swarm`); or one episode of it (`--episode K`), its files kept.
fn fleet_swarm_command(args: &PlanArgs, file: &Path, scenario: &Scenario, n: u64, out: &Path) -> Result<()> {
    use flowgate::lab::fleet::{self, swarm as fleet_swarm, FleetTrace};
    if n == 0 || n > sweep::MAX_EPISODES {
        bail!("--swarm {n}: 1 to {} episodes", sweep::MAX_EPISODES);
    }
    outputs::folder(out)?;
    if let Some(k) = args.episode {
        if k >= n {
            bail!("--episode {k}: the swarm has episodes 0 to {}", n - 1);
        }
        let mut trace = FleetTrace::default();
        let (episode, summary) = if args.whole_stack {
            fleet_swarm::stack::episode(scenario, args.seed, k)
        } else {
            fleet_swarm::episode(scenario, args.seed, k, Some(&mut trace))
        };
        say!("episode {k} of the fleet swarm around {} (seed {}):", scenario.name, args.seed);
        let names: Vec<&str> = scenario.fleet().map(|(name, _, _)| name).collect();
        for (v, fault, at) in &episode.stopped {
            say!("  {:>7.2} s  {} stopped by {}", at, names[*v], fault.name());
        }
        fleet::lines(&summary).iter().for_each(|l| say!("{l}"));
        episode.broken.iter().for_each(|b| say!("  broken: {b}"));
        let s = fleet::sweep::place(scenario, args.seed, k);
        if args.whole_stack {
            outputs::write_json(&out.join("summary.json"), &summary)?;
        } else {
            outputs::write_fleet_run(out, &s, &summary, &trace)?;
        }
        return Ok(());
    }
    let started = std::time::Instant::now();
    let report = if args.whole_stack {
        fleet_swarm::stack::run(scenario, n, args.seed, args.threads())?
    } else {
        fleet_swarm::run(scenario, n, args.seed, args.threads())?
    };
    say!("{report}");
    say!("  ({} episodes in {:.1} s)", report.episodes, started.elapsed().as_secs_f64());
    outputs::write_json(&out.join("fleet_swarm.json"), &report)?;
    say!("  wrote {}/fleet_swarm.json", out.display());
    for (k, broken) in &report.broken {
        say!("episode {k} broke:");
        broken.iter().for_each(|b| say!("  {b}"));
        let level = if args.whole_stack { " --whole-stack" } else { "" };
        say!("  replay: flowgate plan{level} --swarm {n} --seed {} --episode {k} {}", args.seed, file.display());
    }
    if report.broken_episodes > 0 {
        bail!("{} of {} episodes broke an invariant", report.broken_episodes, report.episodes);
    }
    Ok(())
}

/// What a fleet's run refuses; and the vehicle `--policy` drives, and its command.
fn fleet_driven<'a>(args: &'a PlanArgs, scenario: &Scenario) -> Result<Option<(usize, &'a str)>> {
    for (given, flag) in [(args.compare.is_some(), "--compare"), (args.shard.is_some(), "--shard")] {
        if given {
            bail!(
                "{flag} drives one robot: {} is a fleet of {} vehicles, run with --sweep N or alone",
                scenario.name,
                1 + scenario.vehicles.len()
            );
        }
    }
    if args.swarm.is_some() && (args.policy.is_some() || args.compare_obstacles) {
        bail!("--swarm of a fleet draws faults on the field's vehicles: leave --policy and --compare-obstacles out");
    }
    if args.policy.is_some() && args.compare_obstacles {
        bail!("--compare-obstacles compares the field's runs: leave --policy out");
    }
    match &args.policy {
        Some(command) => Ok(Some((driven_vehicle(scenario, args.vehicle.as_deref())?, command.as_str()))),
        None => Ok(None),
    }
}

/// One fleet run and its trace, vehicle `driven.0` driven by the policy `driven.1`.
fn fleet_run_traced(
    args: &PlanArgs,
    s: &Scenario,
    options: flowgate::lab::fleet::FleetOptions,
    driven: Option<(usize, &str)>,
) -> (flowgate::lab::fleet::FleetSummary, flowgate::lab::fleet::FleetTrace) {
    use flowgate::lab::fleet;
    let Some((k, command)) = driven else { return fleet::run_traced(s, options) };
    let mut worker = flowgate::lab::policy::Worker::new(command, args.policy_budget());
    let mut trace = fleet::FleetTrace::default();
    let (summary, _) = fleet::policy::run(s, options, k, &mut worker, Some(&mut trace));
    worker.close();
    (summary, trace)
}

/// The fleet's vehicle `--vehicle` names (default the robot), if it navigates.
fn driven_vehicle(scenario: &Scenario, name: Option<&str>) -> Result<usize> {
    use flowgate_sim::scenario::vehicles::Role;
    let name = name.unwrap_or("robot");
    let names: Vec<&str> = scenario.fleet().map(|(n, _, _)| n).collect();
    let Some(k) = names.iter().position(|n| *n == name) else {
        bail!("--vehicle {name}: {} has vehicles {}", scenario.name, names.join(", "));
    };
    match scenario.fleet().nth(k) {
        Some((_, _, Role::Navigate)) => Ok(k),
        _ => bail!("--vehicle {name}: a scripted vehicle follows its script; a policy drives a navigating one"),
    }
}
