//! Monte-Carlo sweeps around a scenario: the evidence for the safety envelope.
//!
//! Each episode perturbs the base scenario, reproducibly from `(seed, episode)` (a crowd
//! scenario instead places its crowd afresh: [`flowgate_sim::scenario::Scenario::crowd_episode`]):
//! - every moving obstacle's speed × U(0.5, 1.5), its heading ± U(20°);
//! - the robot's start ± U(3 cm) in x and y (kept inside the lane);
//! - the sensing delay U(0, max(2 × base delay, 0.3 s));
//! - the noise seed.
//!
//! The report gives outcome rates, the distribution of minimum clearance, and success
//! against obstacle speed / robot speed limit and against delay.
//!
//! A sweep splits into shards (`--shard i/n`: the episodes whose index is `i` modulo `n`)
//! that run anywhere, each writing its episodes with their indices ([`ShardFile`]);
//! [`merge`] checks that the shards belong to one sweep and hold every episode exactly
//! once, and gives the same report as the sweep run in one piece.

use flowgate_sim::scenario::Motion;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::planner_only::Mode;
use super::Outcome;
use crate::lab::Scenario;

/// One episode's perturbation and result.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Episode {
    /// Its index in the sweep (its perturbation is drawn from the seed and this).
    pub index: u64,
    pub outcome: Outcome,
    pub min_clearance: Option<f64>,
    /// Fastest obstacle speed over the robot's speed limit.
    pub speed_ratio: f64,
    pub delay: f64,
    /// A collision in which the robot drove into what it touched (above 1 cm/s toward it);
    /// a collision without it was passive (the robot stopped or moving away, and hit).
    #[serde(default)]
    pub active_contact: bool,
}

impl Episode {
    fn passive_contact(&self) -> bool {
        self.outcome == Outcome::Collision && !self.active_contact
    }
}

/// Success rate in one bin of a parameter.
#[derive(Debug, Clone, Serialize)]
pub struct Bin {
    pub from: f64,
    pub to: f64,
    pub episodes: usize,
    pub goal_rate: f64,
    pub collision_rate: f64,
    pub active_contact_rate: f64,
}

/// The sweep's report (printed as a table, written as JSON).
#[derive(Debug, Clone, Serialize)]
pub struct SweepReport {
    pub scenario: String,
    /// Which runner made it: the full stack or the planner alone.
    pub mode: Mode,
    /// Whether the safety supervisor checked the commands (`--unsupervised`: not).
    pub supervised: bool,
    pub episodes: usize,
    pub seed: u64,
    pub goal_rate: f64,
    /// Every collision, active and passive.
    pub collision_rate: f64,
    /// Collisions in which the robot drove into what it touched.
    pub active_contact_rate: f64,
    /// Collisions in which the robot was stopped or moving away.
    pub passive_contact_rate: f64,
    /// Active contacts in episodes whose obstacles are all slower than the robot's limit
    /// (where the supervisor promises none).
    pub active_contacts_slower_obstacles: usize,
    /// Episodes whose obstacles are all slower than the robot's limit.
    pub slower_obstacle_episodes: usize,
    pub timeout_rate: f64,
    pub stall_rate: f64,
    pub fault_rate: f64,
    /// Orderly stops other than at the goal (e.g. the goal blocked).
    pub stopped_rate: f64,
    /// Minimum clearance percentiles over the episodes, m: min, p5, p25, p50.
    pub clearance_min: f64,
    pub clearance_p5: f64,
    pub clearance_p25: f64,
    pub clearance_p50: f64,
    pub by_speed_ratio: Vec<Bin>,
    pub by_delay: Vec<Bin>,
}

/// The scenario of episode `i`.
pub fn perturb(base: &Scenario, seed: u64, i: u64) -> Scenario {
    if base.crowd.is_some() {
        let mut s = base.clone();
        // Placed at load for (sensing.seed, 0) with the same rules: it places again.
        match base.sim.crowd_episode(seed, i) {
            Ok(placed) => s.sim = placed,
            Err((key, why)) => tracing::warn!("episode {i}: `{key}` {why}: the episode runs the base crowd"),
        }
        return s;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let mut s = base.clone();
    for o in &mut s.obstacles {
        let scale = rng.random_range(0.5..1.5);
        let turn = rng.random_range(-20f64..20.0).to_radians();
        match &mut o.motion {
            Motion::Stationary => {}
            Motion::Constant { velocity } => {
                let v = num_complex::Complex64::new(velocity[0], velocity[1])
                    * scale
                    * num_complex::Complex64::from_polar(1.0, turn);
                *velocity = [v.re, v.im];
            }
            Motion::Waypoints { speed, .. } => *speed *= scale,
        }
    }
    s.robot.start[0] += rng.random_range(-0.03..0.03);
    s.robot.start[1] += rng.random_range(-0.03..0.03);
    if let Some(lane) = s.lane {
        let room = lane.half_width - s.robot.radius - 1e-3;
        s.robot.start[1] = s.robot.start[1].clamp(-room, room);
    }
    s.sensing.delay = rng.random_range(0.0..(2.0 * base.sensing.delay).max(0.3));
    s.sensing.seed = rng.random();
    s
}

fn fastest_obstacle(s: &Scenario) -> f64 {
    s.obstacles
        .iter()
        .map(|o| match &o.motion {
            Motion::Stationary => 0.0,
            Motion::Constant { velocity } => velocity[0].hypot(velocity[1]),
            Motion::Waypoints { speed, .. } => *speed,
        })
        .fold(0.0, f64::max)
}

/// Which part of a sweep to run: the episodes whose index is `index` modulo `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: u64,
    pub count: u64,
}

impl Shard {
    /// The whole sweep.
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// `episode(i)` for this shard's episodes of `n` (i modulo the count is the index), on
    /// `threads` threads; in no particular order.
    pub fn run<T: Send>(self, n: u64, threads: usize, episode: impl Fn(u64) -> T + Sync) -> Vec<T> {
        let threads = threads.max(1);
        let count = usize::try_from(self.count.max(1)).unwrap_or(usize::MAX);
        let episode = &episode;
        std::thread::scope(|scope| {
            let handles: Vec<_> = (0..threads)
                .map(|w| {
                    scope.spawn(move || {
                        (self.index..n).step_by(count).skip(w).step_by(threads).map(episode).collect::<Vec<_>>()
                    })
                })
                .collect();
            handles.into_iter().flat_map(|h| h.join().expect("a worker panicked")).collect()
        })
    }
}

/// A `--shard` that is not `i/n` with `0 <= i < n`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("shard {0:?}: expected i/n with 0 <= i < n (e.g. 0/4 .. 3/4), or auto/n (the index from a batch system)")]
pub struct BadShard(pub String);

impl std::str::FromStr for Shard {
    type Err = BadShard;
    fn from_str(text: &str) -> Result<Self, BadShard> {
        let bad = || BadShard(text.to_owned());
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let (index, count) = (i.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

/// A `--shard` as given: `i/n`, or `auto/n`, the index taken from the batch system's
/// environment when the shard runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardSpec {
    Fixed(Shard),
    Auto { count: u64 },
}

/// The environment variables a batch system's array job gives each task its index in:
/// Slurm's (less `SLURM_ARRAY_TASK_MIN`, as `--array=1-4` counts from 1), a Kubernetes
/// Indexed Job's, AWS Batch's.
pub const BATCH_INDEX_VARIABLES: [&str; 3] =
    ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX", "AWS_BATCH_JOB_ARRAY_INDEX"];

/// Why `auto/n` has no shard here.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AutoShardError {
    #[error("--shard auto/{count}: no batch index in the environment (none of {})", BATCH_INDEX_VARIABLES.join(", "))]
    Unset { count: u64 },
    #[error("--shard auto/{count}: {variable}={value} is not a task index")]
    NotAnIndex { count: u64, variable: &'static str, value: String },
    #[error("--shard auto/{count}: {variable} gives task {index}, beyond the {count} shards (0..{count})")]
    Beyond { count: u64, variable: &'static str, index: u64 },
}

impl ShardSpec {
    /// The shard to run, `env` the environment (`|name| std::env::var(name).ok()`).
    pub fn resolve(self, env: impl Fn(&str) -> Option<String>) -> Result<Shard, AutoShardError> {
        let count = match self {
            Self::Fixed(shard) => return Ok(shard),
            Self::Auto { count } => count,
        };
        let (variable, value) = BATCH_INDEX_VARIABLES
            .iter()
            .find_map(|&v| env(v).map(|value| (v, value)))
            .ok_or(AutoShardError::Unset { count })?;
        let number = |text: &str| text.trim().parse::<u64>().ok();
        let not_an_index = || AutoShardError::NotAnIndex { count, variable, value: value.clone() };
        let id = number(&value).ok_or_else(not_an_index)?;
        let first = if variable == "SLURM_ARRAY_TASK_ID" {
            env("SLURM_ARRAY_TASK_MIN").and_then(|m| number(&m)).unwrap_or(0)
        } else {
            0
        };
        let index = id.checked_sub(first).ok_or_else(not_an_index)?;
        if index >= count {
            return Err(AutoShardError::Beyond { count, variable, index });
        }
        Ok(Shard { index, count })
    }
}

impl std::str::FromStr for ShardSpec {
    type Err = BadShard;
    fn from_str(text: &str) -> Result<Self, BadShard> {
        match text.split_once('/') {
            Some((auto, n)) if auto.trim() == "auto" => match n.trim().parse() {
                Ok(count) if count > 0 => Ok(Self::Auto { count }),
                _ => Err(BadShard(text.to_owned())),
            },
            _ => text.parse().map(Self::Fixed),
        }
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// What one shard of a sweep writes (`shard.json`): enough to check it belongs with the
/// others and to rebuild the whole sweep's report exactly.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardFile {
    pub scenario: String,
    pub mode: Mode,
    /// Whether the safety supervisor checked the commands.
    #[serde(default = "supervised_by_default")]
    pub supervised: bool,
    pub seed: u64,
    /// Episodes in the whole sweep.
    pub sweep_episodes: u64,
    pub shard: Shard,
    pub episodes: Vec<Episode>,
}

fn supervised_by_default() -> bool {
    true
}

/// Run `n` episodes around `base` on `threads` threads.
pub fn sweep(base: &Scenario, n: usize, seed: u64, threads: usize, mode: Mode) -> SweepReport {
    let episodes = run_shard(base, n as u64, seed, threads, mode, Shard::WHOLE);
    report(&base.name, seed, mode, base.supervised, &episodes)
}

/// Run one shard of an `n`-episode sweep around `base` on `threads` threads: its episodes,
/// in index order.
pub fn run_shard(base: &Scenario, n: u64, seed: u64, threads: usize, mode: Mode, shard: Shard) -> Vec<Episode> {
    let mut episodes = shard.run(n, threads, |i| {
        let s = perturb(base, seed, i);
        let (outcome, min_clearance, contact) = mode.episode(&s);
        Episode {
            index: i,
            outcome,
            min_clearance,
            speed_ratio: fastest_obstacle(&s) / s.robot.max_speed,
            delay: s.sensing.delay,
            active_contact: outcome == Outcome::Collision && contact.is_some_and(|c| c.active),
        }
    });
    episodes.sort_by_key(|e| e.index);
    episodes
}

/// The most episodes a sweep may have (10^9: a merge holds one flag per episode).
pub const MAX_EPISODES: u64 = 1_000_000_000;

/// Why shards cannot be merged into one sweep.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MergeError {
    #[error("no shards to merge")]
    Empty,
    #[error("shard {shard} says the sweep has {total} episodes: more than {MAX_EPISODES}")]
    TooLarge { shard: String, total: u64 },
    #[error("shard {shard} is of another sweep: {key} is {theirs}, the first shard's is {ours}")]
    Mismatch { shard: String, key: &'static str, ours: String, theirs: String },
    #[error("shard {shard} is not i/n with 0 <= i < n")]
    BadShard { shard: String },
    #[error("episode {index} is in more than one shard (shard {shard} given twice?)")]
    Duplicate { index: u64, shard: String },
    #[error("shard {shard} holds episode {index}, which is not its own")]
    Foreign { index: u64, shard: String },
    #[error("{missing} of the sweep's {total} episodes are missing (the first is {first}: shard {first_shard} not given or incomplete)")]
    Missing { missing: u64, total: u64, first: u64, first_shard: String },
}

/// Merge the shards of one sweep into its report, refusing shards of different sweeps, an
/// episode twice, or any episode missing.
pub fn merge(shards: &[ShardFile]) -> Result<SweepReport, MergeError> {
    let first = shards.first().ok_or(MergeError::Empty)?;
    let total = first.sweep_episodes;
    if total > MAX_EPISODES {
        return Err(MergeError::TooLarge { shard: first.shard.to_string(), total });
    }
    let mut seen = vec![false; total as usize];
    let mut episodes = Vec::with_capacity(total as usize);
    for s in shards {
        let mismatch = |key: &'static str, ours: String, theirs: String| MergeError::Mismatch {
            shard: s.shard.to_string(),
            key,
            ours,
            theirs,
        };
        if s.scenario != first.scenario {
            return Err(mismatch("scenario", first.scenario.clone(), s.scenario.clone()));
        }
        if s.mode != first.mode {
            return Err(mismatch("mode", first.mode.to_string(), s.mode.to_string()));
        }
        if s.supervised != first.supervised {
            return Err(mismatch("supervised", first.supervised.to_string(), s.supervised.to_string()));
        }
        if s.seed != first.seed {
            return Err(mismatch("seed", first.seed.to_string(), s.seed.to_string()));
        }
        if s.sweep_episodes != total {
            return Err(mismatch("sweep_episodes", total.to_string(), s.sweep_episodes.to_string()));
        }
        if s.shard.count == 0 || s.shard.index >= s.shard.count {
            return Err(MergeError::BadShard { shard: s.shard.to_string() });
        }
        if s.shard.count != first.shard.count {
            return Err(mismatch("shard count", first.shard.count.to_string(), s.shard.count.to_string()));
        }
        for e in &s.episodes {
            if e.index >= total || e.index % s.shard.count != s.shard.index {
                return Err(MergeError::Foreign { index: e.index, shard: s.shard.to_string() });
            }
            if std::mem::replace(&mut seen[e.index as usize], true) {
                return Err(MergeError::Duplicate { index: e.index, shard: s.shard.to_string() });
            }
            episodes.push(*e);
        }
    }
    let missing = seen.iter().filter(|&&s| !s).count() as u64;
    if let Some(first_missing) = seen.iter().position(|&s| !s) {
        let count = first.shard.count;
        return Err(MergeError::Missing {
            missing,
            total,
            first: first_missing as u64,
            first_shard: Shard { index: first_missing as u64 % count, count }.to_string(),
        });
    }
    episodes.sort_by_key(|e| e.index);
    Ok(report(&first.scenario, first.seed, first.mode, first.supervised, &episodes))
}

/// The report over `episodes` (of a whole sweep, or of one shard).
pub fn report(scenario: &str, seed: u64, mode: Mode, supervised: bool, episodes: &[Episode]) -> SweepReport {
    let n = episodes.len().max(1) as f64;
    let rate = |o: Outcome| episodes.iter().filter(|e| e.outcome == o).count() as f64 / n;
    let mut clearances: Vec<f64> = episodes.iter().filter_map(|e| e.min_clearance).collect();
    clearances.sort_by(f64::total_cmp);
    let pct = |q: f64| {
        if clearances.is_empty() {
            f64::NAN
        } else {
            clearances[((clearances.len() - 1) as f64 * q).round() as usize]
        }
    };
    let bins = |edges: &[f64], key: fn(&Episode) -> f64| -> Vec<Bin> {
        edges
            .windows(2)
            .map(|w| {
                let inside: Vec<&Episode> = episodes.iter().filter(|e| key(e) >= w[0] && key(e) < w[1]).collect();
                let m = inside.len().max(1) as f64;
                Bin {
                    from: w[0],
                    to: w[1],
                    episodes: inside.len(),
                    goal_rate: inside.iter().filter(|e| e.outcome == Outcome::Goal).count() as f64 / m,
                    collision_rate: inside.iter().filter(|e| e.outcome == Outcome::Collision).count() as f64 / m,
                    active_contact_rate: inside.iter().filter(|e| e.active_contact).count() as f64 / m,
                }
            })
            .filter(|b| b.episodes > 0)
            .collect()
    };
    SweepReport {
        scenario: scenario.to_owned(),
        mode,
        supervised,
        episodes: episodes.len(),
        seed,
        goal_rate: rate(Outcome::Goal),
        collision_rate: rate(Outcome::Collision),
        active_contact_rate: episodes.iter().filter(|e| e.active_contact).count() as f64 / n,
        passive_contact_rate: episodes.iter().filter(|e| e.passive_contact()).count() as f64 / n,
        active_contacts_slower_obstacles: episodes.iter().filter(|e| e.active_contact && e.speed_ratio < 1.0).count(),
        slower_obstacle_episodes: episodes.iter().filter(|e| e.speed_ratio < 1.0).count(),
        timeout_rate: rate(Outcome::Timeout),
        stall_rate: rate(Outcome::Stall),
        fault_rate: rate(Outcome::Fault),
        stopped_rate: rate(Outcome::Stopped),
        clearance_min: pct(0.0),
        clearance_p5: pct(0.05),
        clearance_p25: pct(0.25),
        clearance_p50: pct(0.5),
        by_speed_ratio: bins(&[0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, f64::INFINITY], |e| e.speed_ratio),
        by_delay: bins(&[0.0, 0.1, 0.2, 0.3, 0.45, 0.6, 0.9, 1.2, f64::INFINITY], |e| e.delay),
    }
}

impl std::fmt::Display for SweepReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pc = |x: f64| 100.0 * x;
        writeln!(
            f,
            "sweep of {} episodes around {} (seed {}, {}{})",
            self.episodes,
            self.scenario,
            self.seed,
            self.mode,
            if self.supervised { "" } else { ", unsupervised" }
        )?;
        writeln!(
            f,
            "  goal {:.1}%  collision {:.1}% (active {:.1}%, passive {:.1}%)  timeout {:.1}%  stall {:.1}%  fault {:.1}%  stopped {:.1}%",
            pc(self.goal_rate),
            pc(self.collision_rate),
            pc(self.active_contact_rate),
            pc(self.passive_contact_rate),
            pc(self.timeout_rate),
            pc(self.stall_rate),
            pc(self.fault_rate),
            pc(self.stopped_rate)
        )?;
        writeln!(
            f,
            "  active contacts with every obstacle slower than the robot: {} of {} episodes",
            self.active_contacts_slower_obstacles, self.slower_obstacle_episodes
        )?;
        writeln!(
            f,
            "  min clearance (m): min {:.4}  p5 {:.4}  p25 {:.4}  p50 {:.4}",
            self.clearance_min, self.clearance_p5, self.clearance_p25, self.clearance_p50
        )?;
        for (title, bins) in
            [("obstacle speed / robot limit", &self.by_speed_ratio), ("sensing delay (s)", &self.by_delay)]
        {
            writeln!(f, "  {title:<30} {:>9} {:>8} {:>10} {:>8}", "episodes", "goal", "collision", "active")?;
            for b in bins {
                let range =
                    if b.to.is_finite() { format!("{:.2} - {:.2}", b.from, b.to) } else { format!(">= {:.2}", b.from) };
                writeln!(
                    f,
                    "  {range:<30} {:>9} {:>7.1}% {:>9.1}% {:>7.1}%",
                    b.episodes,
                    pc(b.goal_rate),
                    pc(b.collision_rate),
                    pc(b.active_contact_rate)
                )?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env<'a>(vars: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |name| vars.iter().find(|(k, _)| *k == name).map(|(_, v)| v.to_string())
    }

    /// `auto/n` takes its index from whichever batch system set one, a Slurm array from
    /// its first task; `i/n` ignores the environment.
    #[test]
    fn an_automatic_shard_takes_the_batch_systems_index() {
        let auto: ShardSpec = "auto/4".parse().unwrap();
        assert_eq!(auto, ShardSpec::Auto { count: 4 });
        let slurm = [("SLURM_ARRAY_TASK_ID", "3"), ("SLURM_ARRAY_TASK_MIN", "1")];
        assert_eq!(auto.resolve(env(&slurm)), Ok(Shard { index: 2, count: 4 }));
        assert_eq!(auto.resolve(env(&[("JOB_COMPLETION_INDEX", "0")])), Ok(Shard { index: 0, count: 4 }));
        assert_eq!(auto.resolve(env(&[("AWS_BATCH_JOB_ARRAY_INDEX", "3")])), Ok(Shard { index: 3, count: 4 }));
        assert_eq!(auto.resolve(env(&[])), Err(AutoShardError::Unset { count: 4 }));
        let beyond = auto.resolve(env(&[("JOB_COMPLETION_INDEX", "4")])).unwrap_err();
        assert_eq!(beyond.to_string(), "--shard auto/4: JOB_COMPLETION_INDEX gives task 4, beyond the 4 shards (0..4)");
        let junk = auto.resolve(env(&[("SLURM_ARRAY_TASK_ID", "x")])).unwrap_err();
        assert_eq!(junk.to_string(), "--shard auto/4: SLURM_ARRAY_TASK_ID=x is not a task index");
        let fixed: ShardSpec = "1/4".parse().unwrap();
        assert_eq!(fixed.resolve(env(&slurm)), Ok(Shard { index: 1, count: 4 }));
        assert!("auto/0".parse::<ShardSpec>().is_err() && "auto".parse::<ShardSpec>().is_err());
    }
}
