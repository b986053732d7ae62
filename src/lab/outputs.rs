//! What `flowgate plan` leaves in its output folder, each file named here and nowhere else:
//! a single run's (`summary.json`, the plots, through the whole stack `cycles.csv` and
//! `can.log`), a sweep's (`sweep.json` and its episodes), a comparison's (`compare.json`),
//! a swarm's (`swarm.json`) and one swarm episode's. The CLI calls these and prints what
//! they wrote.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::planner_only::{self, Mode};
use super::swarm::{self, SwarmReport};
use super::sweep::{self, compare::Comparison, Manifest, SweepReport};
use super::{plots, virtual_rig, Scenario};

/// A single run's files, as `{...}` lists them.
pub const RUN_FILES: &str = "summary.json,trajectory.svg,history.svg";
/// A full-stack run's files besides.
pub const TELEMETRY_FILES: &str = "cycles.csv,can.log";
/// A swarm episode's files.
pub const SWARM_EPISODE_FILES: &str = "episode.json,faults.toml,cycles.csv,can.log,truth.csv";

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("writing {path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{0}")]
    Episodes(#[from] sweep::episodes_file::EpisodesFileError),
    #[error("{scenario}: the simulated PSD controller could not be configured: {error}")]
    Setup { scenario: String, error: String },
    #[error("{scenario}: a fleet of {vehicles} vehicles, run by `flowgate plan` at the planner level (docs/fleet.md)")]
    Fleet { scenario: String, vehicles: usize },
}

fn io_at(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io { path: path.display().to_string(), source }
}

fn write(path: &Path, bytes: impl AsRef<[u8]>) -> Result<(), OutputError> {
    std::fs::write(path, bytes).map_err(io_at(path))
}

fn json(value: &impl Serialize) -> String {
    // The reports are plain structs of numbers and strings: they always serialise.
    serde_json::to_string_pretty(value).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

/// The output folder, made if missing.
pub fn folder(dir: &Path) -> Result<(), OutputError> {
    std::fs::create_dir_all(dir).map_err(io_at(dir))
}

/// One run of `scenario` in `mode`; through the whole stack its `cycles.csv` and `can.log`
/// go into `out`, when given.
pub fn run_one(scenario: &Scenario, mode: Mode, out: Option<&Path>) -> Result<planner_only::Run, OutputError> {
    if scenario.is_fleet() {
        return Err(OutputError::Fleet { scenario: scenario.name.clone(), vehicles: 1 + scenario.vehicles.len() });
    }
    Ok(match mode {
        Mode::PlannerOnly => planner_only::run(scenario, out.is_some()),
        Mode::FullStack => {
            let options = virtual_rig::Options { truth_samples: out.is_some(), telemetry: true, ..Default::default() };
            let episode = virtual_rig::run_timed(scenario, options);
            if let Some(e) = episode.setup_error {
                return Err(OutputError::Setup { scenario: scenario.name.clone(), error: e.to_string() });
            }
            let mut run = planner_only::Run::from_episode(scenario, &episode);
            if let Some(t) = &episode.telemetry {
                let [p50_us, p99_us, max_us] = t.plan_us();
                run.summary.planner_compute = planner_only::ComputeTime { p50_us, p99_us, max_us };
                if let Some(out) = out {
                    t.write(out).map_err(io_at(out))?;
                }
            }
            run
        }
    })
}

/// One run of `scenario` through the whole stack with an outside policy (`command`) as its
/// planner, in virtual time on no host clock: the same policy gives the same bytes. Its
/// `cycles.csv` and `can.log` go into `out`, when given; a policy's failure is the run's
/// stop (`policy: ...`).
pub fn run_policy(
    scenario: &Scenario,
    command: &str,
    budget: std::time::Duration,
    out: Option<&Path>,
) -> Result<planner_only::Run, OutputError> {
    let options = virtual_rig::Options { truth_samples: out.is_some(), telemetry: true, ..Default::default() };
    let mut worker = super::policy::Worker::new(command, budget);
    let (episode, failure) = worker.episode(scenario, options);
    worker.close();
    if let Some(e) = episode.setup_error {
        return Err(OutputError::Setup { scenario: scenario.name.clone(), error: e.to_string() });
    }
    let mut run = planner_only::Run::from_episode(scenario, &episode);
    if let Some(e) = failure {
        run.summary.stop_reason = Some(e.to_string());
    }
    if let (Some(t), Some(out)) = (&episode.telemetry, out) {
        t.write(out).map_err(io_at(out))?;
    }
    Ok(run)
}

/// A single run's summary and plots ([`RUN_FILES`]).
pub fn write_run(dir: &Path, scenario: &Scenario, run: &planner_only::Run) -> Result<(), OutputError> {
    folder(dir)?;
    write(&dir.join("summary.json"), json(&run.summary))?;
    write(&dir.join("trajectory.svg"), plots::trajectory_svg(scenario, &run.trace, (&run.summary).into()))?;
    write(&dir.join("history.svg"), plots::history_svg(scenario, run))
}

/// A whole sweep: its report (`sweep.json`) and its episodes ([`sweep::EPISODES_FILE`]).
pub fn write_sweep(
    dir: &Path,
    manifest: &Manifest,
    episodes: &[sweep::Episode],
    report: &SweepReport,
) -> Result<(), OutputError> {
    folder(dir)?;
    sweep::episodes_file::write(&dir.join(sweep::EPISODES_FILE), manifest, episodes)?;
    write(&dir.join("sweep.json"), json(report))
}

/// A comparison of two sweeps (`compare.json`); its path.
pub fn write_comparison(dir: &Path, comparison: &Comparison) -> Result<PathBuf, OutputError> {
    folder(dir)?;
    let path = dir.join("compare.json");
    write(&path, json(comparison))?;
    Ok(path)
}

/// A swarm's report (`swarm.json`); its path.
pub fn write_swarm(dir: &Path, report: &SwarmReport) -> Result<PathBuf, OutputError> {
    folder(dir)?;
    let path = dir.join("swarm.json");
    write(&path, json(report))?;
    Ok(path)
}

/// One swarm episode, kept to be looked into ([`SWARM_EPISODE_FILES`]).
pub fn write_swarm_episode(
    dir: &Path,
    outcome: &swarm::JudgedEpisode,
    episode: &virtual_rig::VirtualRun,
    schedule: &swarm::FaultSchedule,
) -> Result<(), OutputError> {
    folder(dir)?;
    if let Some(t) = &episode.telemetry {
        t.write(dir).map_err(io_at(dir))?;
    }
    let truth = dir.join("truth.csv");
    episode.truth.write(&truth).map_err(io_at(&truth))?;
    let faults_path = dir.join("faults.toml");
    let faults = toml::to_string(&schedule.scenario.faults)
        .map_err(|e| OutputError::Io { path: faults_path.display().to_string(), source: std::io::Error::other(e) })?;
    write(&faults_path, faults)?;
    write(&dir.join("episode.json"), json(outcome))
}

/// A fleet run: its `summary.json` (the fleet's outcome and each vehicle's) and its
/// `trajectory.svg`.
pub fn write_fleet_run(
    dir: &Path,
    scenario: &Scenario,
    summary: &super::fleet::FleetSummary,
    trace: &super::fleet::FleetTrace,
) -> Result<(), OutputError> {
    folder(dir)?;
    write(&dir.join("summary.json"), json(summary))?;
    write(&dir.join("trajectory.svg"), plots::fleet_svg(scenario, &plots::FleetEnding::of(summary), trace))
}

/// A fleet sweep: its report (`fleet_sweep.json`) and one JSON line an episode
/// (`fleet_episodes.jsonl`).
pub fn write_fleet_sweep(
    dir: &Path,
    report: &super::fleet::sweep::FleetSweepReport,
    episodes: &[super::fleet::sweep::FleetEpisode],
) -> Result<(), OutputError> {
    folder(dir)?;
    write(&dir.join("fleet_sweep.json"), json(report))?;
    let lines: String = episodes.iter().map(|e| serde_json::to_string(e).unwrap_or_default() + "\n").collect();
    write(&dir.join("fleet_episodes.jsonl"), lines)
}

/// Any report as pretty JSON at `path` (its folder made if missing).
pub fn write_json(path: &Path, value: &impl Serialize) -> Result<(), OutputError> {
    if let Some(dir) = path.parent() {
        folder(dir)?;
    }
    write(path, json(value))
}
