//! The people benchmark (`flowgate plan --benchmark DIR`): CrowdNav's protocol scaled to
//! the rig and two rooms, every method on the same episodes, each figure with its 95%
//! interval.
//!
//! The rows are scenarios of `DIR` (the repository's `scenarios/people/`): the circle
//! crossing (five ORCA people on a circle of 0.65 m, each to its antipode at the robot's
//! cruise speed) with people who do not see the robot and with people who do, the hallway
//! and the furnished room. The methods are the field and the baselines behind the same
//! supervisor (`planner.method`). For each, success, active and passive contact and timeout
//! (Wilson's intervals), and time to goal and path length over the straight line (over the
//! episodes that reached the goal) and discomfort (over all; see
//! [`DISCOMFORT_RADII`](super::planner_only::DISCOMFORT_RADII)), each a mean with its normal
//! interval.

use std::path::Path;

use serde::Serialize;

use super::planner_only::Mode;
use super::sweep::compare::Interval;
use super::sweep::{self, Episode, Manifest, Shard};
use super::{Outcome, Scenario};
use crate::svg::Svg;

/// The methods, as `planner.method` names them.
pub const METHODS: [&str; 4] = ["field", "straight", "orca", "social_force"];

/// A row: a scenario file of the benchmark's folder, its people seeing the robot or not.
#[derive(Debug, Clone, Copy)]
pub struct Row {
    /// As the table and the Parquet partitions name it.
    pub name: &'static str,
    pub file: &'static str,
    pub sees_robot: bool,
}

pub const ROWS: [Row; 4] = [
    Row { name: "circle, unseen", file: "circle-crossing-5.toml", sees_robot: false },
    Row { name: "circle, seen", file: "circle-crossing-5.toml", sees_robot: true },
    Row { name: "hallway", file: "hallway.toml", sees_robot: false },
    Row { name: "furnished room", file: "furnished-room.toml", sees_robot: false },
];

/// A mean and its 95% interval (normal), over `n` values.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct Mean {
    pub n: usize,
    pub mean: f64,
    pub low: f64,
    pub high: f64,
}

impl Mean {
    pub fn of(values: &[f64]) -> Self {
        let n = values.len();
        if n == 0 {
            return Self { n, mean: f64::NAN, low: f64::NAN, high: f64::NAN };
        }
        let mean = values.iter().sum::<f64>() / n as f64;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n.max(2) - 1) as f64;
        let half = 1.96 * (var / n as f64).sqrt();
        Self { n, mean, low: mean - half, high: mean + half }
    }
}

/// One method on one row.
#[derive(Debug, Clone, Serialize)]
pub struct Cell {
    pub row: &'static str,
    pub method: &'static str,
    pub success: Interval,
    pub active_contact: Interval,
    pub passive_contact: Interval,
    pub timeout: Interval,
    /// Over the episodes that reached the goal, s.
    pub time_to_goal: Mean,
    pub path_length_ratio: Mean,
    /// The share of each episode a person was uncomfortably near, over every episode.
    pub discomfort: Mean,
}

/// The field's failures on a row, and how many of them the best baseline there failed too
/// (the same episodes: each method runs every episode index of the row).
#[derive(Debug, Clone, Serialize)]
pub struct Failures {
    pub row: &'static str,
    pub field_failed: usize,
    /// The baseline that reached the goal most often on the row.
    pub best_baseline: &'static str,
    pub also_failed: usize,
}

/// The benchmark's table.
#[derive(Debug, Clone, Serialize)]
pub struct Benchmark {
    pub episodes: usize,
    pub seed: u64,
    pub mode: Mode,
    pub cells: Vec<Cell>,
    pub failures: Vec<Failures>,
}

/// Why the benchmark could not run or be written.
#[derive(Debug, thiserror::Error)]
pub enum BenchmarkError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error(transparent)]
    Scenario(#[from] super::scenario::ScenarioError),
    #[error(transparent)]
    TooLarge(#[from] sweep::TooLarge),
    #[error(transparent)]
    Episodes(#[from] sweep::episodes_file::EpisodesFileError),
}

/// Row `row` of the folder `dir` with `method` planning.
pub fn scenario(dir: &Path, row: Row, method: &str) -> Result<Scenario, BenchmarkError> {
    let mut s = Scenario::load_with(&dir.join(row.file), &format!("planner.method=\"{method}\""))?;
    if row.sees_robot {
        if let Some(crowd) = &mut s.sim.crowd {
            crowd.sees_robot = true;
        }
        for o in s.sim.obstacles.iter_mut().filter(|o| o.behaviour.walks()) {
            o.sees_robot = true;
        }
    }
    Ok(s)
}

/// Run every row with every method, `episodes` each, writing each cell's episodes to
/// `out/episodes/row=<row>/method=<method>/episodes.parquet` (a Hive-partitioned dataset), the table
/// to `out/benchmark.json` and its plot to `out/benchmark.svg`.
pub fn run(
    dir: &Path,
    out: &Path,
    episodes: usize,
    seed: u64,
    threads: usize,
    mode: Mode,
) -> Result<Benchmark, BenchmarkError> {
    let (mut cells, mut failures) = (Vec::new(), Vec::new());
    for row in ROWS {
        let bytes = std::fs::read(dir.join(row.file)).map_err(|source| io(&dir.join(row.file), source))?;
        let mut reached: Vec<Vec<bool>> = Vec::new();
        for method in METHODS {
            let s = scenario(dir, row, method)?;
            let n = episodes as u64;
            let run = sweep::run_shard(&s, n, seed, threads, mode, Shard::WHOLE)?;
            let part = out
                .join("episodes")
                .join(format!("row={}", row.name.replace([' ', ','], "_")))
                .join(format!("method={method}"));
            std::fs::create_dir_all(&part).map_err(|source| io(&part, source))?;
            let manifest = Manifest::new(&s, &bytes, mode, seed, n, Shard::WHOLE);
            sweep::episodes_file::write(&part.join("episodes.parquet"), &manifest, &run)?;
            cells.push(cell(&s, row, method, seed, &run));
            reached.push(run.iter().map(|e| e.outcome == Outcome::Goal).collect());
        }
        failures.push(failures_of(row, &reached));
    }
    let benchmark = Benchmark { episodes, seed, mode, cells, failures };
    let json = serde_json::to_string_pretty(&benchmark).expect("a benchmark serialises");
    write(&out.join("benchmark.json"), &json)?;
    write(&out.join("benchmark.svg"), &plot(&benchmark))?;
    Ok(benchmark)
}

/// The field's failures on `row` against the best baseline's, from each method's
/// reached-the-goal per episode (in [`METHODS`] order, the field first).
fn failures_of(row: Row, reached: &[Vec<bool>]) -> Failures {
    let successes = |k: usize| reached[k].iter().filter(|&&r| r).count();
    let best = (1..reached.len()).max_by_key(|&k| (successes(k), std::cmp::Reverse(k))).unwrap_or(0);
    let field_failed = reached[0].iter().filter(|&&r| !r).count();
    let also_failed = reached[0].iter().zip(&reached[best]).filter(|&(&f, &b)| !f && !b).count();
    Failures { row: row.name, field_failed, best_baseline: METHODS[best], also_failed }
}

fn io(path: &Path, source: std::io::Error) -> BenchmarkError {
    BenchmarkError::Io { path: path.display().to_string(), source }
}

fn write(path: &Path, text: &str) -> Result<(), BenchmarkError> {
    std::fs::write(path, text).map_err(|source| io(path, source))
}

/// A cell's figures from its episodes (`s` the row's scenario, each episode's start and
/// goal drawn again from `seed` for its straight line).
fn cell(s: &Scenario, row: Row, method: &'static str, seed: u64, run: &[Episode]) -> Cell {
    let n = run.len();
    let count = |f: &dyn Fn(&Episode) -> bool| Interval::wilson(run.iter().filter(|e| f(e)).count(), n);
    let reached: Vec<&Episode> = run.iter().filter(|e| e.outcome == Outcome::Goal).collect();
    let ratios: Vec<f64> = reached
        .iter()
        .map(|e| {
            let episode = sweep::perturb(s, seed, e.index);
            e.path_length / (episode.goal() - episode.robot_start()).norm()
        })
        .collect();
    Cell {
        row: row.name,
        method,
        success: count(&|e| e.outcome == Outcome::Goal),
        active_contact: count(&|e| e.active_contact),
        passive_contact: count(&|e| e.passive_contact()),
        timeout: count(&|e| e.outcome == Outcome::Timeout),
        time_to_goal: Mean::of(&reached.iter().map(|e| e.duration).collect::<Vec<_>>()),
        path_length_ratio: Mean::of(&ratios),
        discomfort: Mean::of(&run.iter().map(|e| e.discomfort).collect::<Vec<_>>()),
    }
}

impl std::fmt::Display for Benchmark {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pct = |i: &Interval| format!("{:.1} [{:.1}, {:.1}]", 100.0 * i.rate, 100.0 * i.low, 100.0 * i.high);
        let mean = |m: &Mean, k: f64| match m.n {
            0 => "-".to_string(),
            _ => format!("{:.2} [{:.2}, {:.2}]", k * m.mean, k * m.low, k * m.high),
        };
        writeln!(
            f,
            "| row | method | success % | active % | passive % | timeout % | time to goal s | path / straight | discomfort % |"
        )?;
        writeln!(f, "| --- | --- | --- | --- | --- | --- | --- | --- | --- |")?;
        for c in &self.cells {
            writeln!(
                f,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                c.row,
                c.method,
                pct(&c.success),
                pct(&c.active_contact),
                pct(&c.passive_contact),
                pct(&c.timeout),
                mean(&c.time_to_goal, 1.0),
                mean(&c.path_length_ratio, 1.0),
                mean(&c.discomfort, 100.0)
            )?;
        }
        for x in &self.failures {
            writeln!(
                f,
                "{}: the field failed {} episodes; {}, the best baseline there, failed {} of them too",
                x.row, x.field_failed, x.best_baseline, x.also_failed
            )?;
        }
        write!(f, "({} episodes a cell, seed {}, {})", self.episodes, self.seed, self.mode)
    }
}

/// The success of each method on each row, bars with their intervals.
fn plot(b: &Benchmark) -> String {
    const COLOURS: [&str; 4] = ["#1f77b4", "#7f7f7f", "#2ca02c", "#d62728"];
    let (left, top, height, group) = (60.0, 30.0, 240.0, 150.0);
    let mut svg = Svg::new(left + group * ROWS.len() as f64 + 20.0, top + height + 80.0);
    svg.text(left, 18.0, "success, with 95% intervals", "start", 13.0, "black");
    for k in 0..=4 {
        let y = top + height * (1.0 - f64::from(k) / 4.0);
        svg.rect(left, y, group * ROWS.len() as f64, 0.5, "#cccccc");
        svg.text(left - 6.0, y + 4.0, &format!("{}%", 25 * k), "end", 11.0, "black");
    }
    for (r, row) in ROWS.iter().enumerate() {
        let x0 = left + group * r as f64 + 15.0;
        for (m, method) in METHODS.iter().enumerate() {
            let Some(c) = b.cells.iter().find(|c| c.row == row.name && c.method == *method) else { continue };
            let x = x0 + 30.0 * m as f64;
            let y = |p: f64| top + height * (1.0 - p);
            svg.rect(x, y(c.success.rate), 24.0, height * c.success.rate, COLOURS[m]);
            svg.rect(x + 11.0, y(c.success.high), 2.0, height * (c.success.high - c.success.low), "black");
        }
        svg.text(x0 + 60.0, top + height + 18.0, row.name, "middle", 12.0, "black");
    }
    for (m, method) in METHODS.iter().enumerate() {
        let x = left + 130.0 * m as f64;
        svg.rect(x, top + height + 40.0, 12.0, 12.0, COLOURS[m]);
        svg.text(x + 16.0, top + height + 50.0, method, "start", 12.0, "black");
    }
    svg.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The mean's interval is the normal one: 1.96 standard errors either side.
    #[test]
    fn a_mean_has_its_normal_interval() {
        let m = Mean::of(&[1.0, 2.0, 3.0, 4.0]);
        let half = 1.96 * (5.0f64 / 3.0 / 4.0).sqrt();
        assert_eq!((m.n, m.mean), (4, 2.5));
        assert!((m.low - (2.5 - half)).abs() < 1e-12 && (m.high - (2.5 + half)).abs() < 1e-12);
        assert!(Mean::of(&[]).mean.is_nan());
    }
}
