//! Monte-Carlo sweeps around a scenario: the evidence for the safety envelope.
//!
//! Each episode perturbs the base scenario, reproducibly from `(seed, episode)` (a crowd
//! scenario instead places its crowd afresh: [`flowgate_sim::scenario::SimScenario::crowd_episode`]):
//! - every moving obstacle's speed × U(0.5, 1.5), its heading ± U(20°);
//! - the robot's start ± U(3 cm) in x and y (kept inside the lane);
//! - the sensing delay U(0, max(2 × base delay, 0.3 s));
//! - the noise seed.
//!
//! The report gives outcome rates, the distribution of minimum clearance, and success
//! against obstacle speed / robot speed limit and against delay.
//!
//! A sweep splits into shards (`--shard i/n`: the episodes whose index is `i` modulo `n`)
//! that run anywhere, each writing its [`Manifest`] (`shard.json`) beside its episodes as
//! Parquet ([`episodes_file`]); [`merge`] checks that the shards belong to one sweep and hold
//! every episode exactly once, and gives the same episodes and report as the sweep run in one
//! piece.

pub mod compare;
pub mod episodes_file;
mod shard;

pub use shard::{available_threads, MAX_THREADS};
pub use shard::{
    merge, read_shard, write_shard, AutoShardError, BadShard, Manifest, MergeError, Shard, ShardData, ShardDirError,
    ShardSpec, TooLarge, BATCH_INDEX_VARIABLES, EPISODES_FILE, MANIFEST_FILE, MAX_EPISODES,
};

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
    /// Smallest true clearance to a wall or static obstacle, m (None: the room has none).
    #[serde(default)]
    pub min_wall_clearance: Option<f64>,
    /// When the episode ended (at the goal, a stop or the time limit), s of virtual time.
    #[serde(default)]
    pub duration: f64,
    /// The robot's path length, m.
    #[serde(default)]
    pub path_length: f64,
    /// The share of the episode a person was uncomfortably near the robot
    /// ([`DISCOMFORT_RADII`](super::planner_only::DISCOMFORT_RADII) of its radius).
    #[serde(default)]
    pub discomfort: f64,
}

impl Episode {
    /// A collision the robot did not drive into.
    pub fn passive_contact(&self) -> bool {
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
        if let Some(speed) = &mut o.preferred_speed {
            *speed *= scale;
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
    s.obstacles.iter().map(|o| o.top_speed()).fold(0.0, f64::max)
}

/// Run `n` episodes around `base` on `threads` threads.
pub fn sweep(base: &Scenario, n: usize, seed: u64, threads: usize, mode: Mode) -> Result<SweepReport, TooLarge> {
    let episodes = run_shard(base, n as u64, seed, threads, mode, Shard::WHOLE)?;
    Ok(report(&base.name, seed, mode, base.supervised, &episodes))
}

/// Run one shard of an `n`-episode sweep around `base` on `threads` threads: its episodes,
/// in index order.
pub fn run_shard(
    base: &Scenario,
    n: u64,
    seed: u64,
    threads: usize,
    mode: Mode,
    shard: Shard,
) -> Result<Vec<Episode>, TooLarge> {
    let mut episodes = shard.run(n, threads, |i| {
        let s = perturb(base, seed, i);
        Episode::of(i, &s, &mode.episode(&s))
    })?;
    episodes.sort_by_key(|e| e.index);
    Ok(episodes)
}

/// The same through the whole stack with an outside policy as the planner (`plan --policy
/// CMD --sweep N`): one policy process a worker. An episode the policy fails ends stopped,
/// its reason logged.
pub fn run_policy_shard(
    base: &Scenario,
    n: u64,
    seed: u64,
    threads: usize,
    shard: Shard,
    command: &str,
    budget: std::time::Duration,
) -> Result<Vec<Episode>, TooLarge> {
    let worker = || super::policy::Worker::new(command, budget);
    let mut episodes = shard.run_with(n, threads, worker, |policy, i| {
        let s = perturb(base, seed, i);
        let options = super::virtual_rig::Options { stop_at_contact: true, ..Default::default() };
        let (run, failure) = policy.episode(&s, options);
        if let Some(e) = failure {
            tracing::warn!("episode {i}: {e}");
        }
        Episode::of(i, &s, &super::planner_only::EpisodeResult::of(&s, &run))
    })?;
    episodes.sort_by_key(|e| e.index);
    Ok(episodes)
}

impl Episode {
    /// Episode `index`, scenario `s`, ended as `r` says.
    fn of(index: u64, s: &Scenario, r: &super::planner_only::EpisodeResult) -> Self {
        Self {
            index,
            outcome: r.outcome,
            min_clearance: r.min_obstacle_clearance,
            speed_ratio: fastest_obstacle(s) / s.robot.max_speed,
            delay: s.sensing.delay,
            active_contact: r.outcome == Outcome::Collision && r.contact.is_some_and(|c| c.active),
            min_wall_clearance: r.min_wall_clearance,
            duration: r.duration,
            path_length: r.path_length,
            discomfort: r.discomfort,
        }
    }
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
