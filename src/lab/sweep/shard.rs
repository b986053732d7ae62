//! Shards of a sweep: which episodes a shard runs ([`Shard`], [`ShardSpec`] with the batch
//! system's index), what it writes (a [`Manifest`] as `shard.json` beside its episodes as
//! Parquet, [`episodes_file`](super::episodes_file)), and how shards merge back into the
//! sweep ([`merge`]), refusing what belongs to another sweep by the field that differs.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use serde::{Deserialize, Serialize};

use super::{report, Episode, SweepReport};
use crate::lab::planner_only::Mode;

/// Which part of a sweep to run: the episodes whose index is `index` modulo `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: u64,
    pub count: u64,
}

impl Shard {
    /// The whole sweep.
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// How many of a sweep's `n` episodes are this shard's.
    pub fn episodes_of(self, n: u64) -> u64 {
        match n.checked_sub(self.index) {
            Some(left) if left > 0 && self.count > 0 => (left - 1) / self.count + 1,
            _ => 0,
        }
    }

    /// `episode(i)` for this shard's episodes of `n` (i modulo the count is the index), on
    /// `threads` threads (no more than the shard has episodes); in no particular order.
    /// A worker the system will not start (a process or cgroup limit on threads) has its
    /// episodes run on the calling thread instead: slower, nothing lost. Refused before any
    /// episode runs if this process cannot allocate the space for all of them.
    pub fn run<T: Send>(self, n: u64, threads: usize, episode: impl Fn(u64) -> T + Sync) -> Result<Vec<T>, TooLarge> {
        self.run_with(n, threads, || (), |(), i| episode(i))
    }

    /// The same, each worker keeping what `worker` makes for all its episodes (an outside
    /// policy's process: one a worker).
    pub fn run_with<W, T: Send>(
        self,
        n: u64,
        threads: usize,
        worker: impl Fn() -> W + Sync,
        episode: impl Fn(&mut W, u64) -> T + Sync,
    ) -> Result<Vec<T>, TooLarge> {
        let too_large = || TooLarge::of::<T>(self.episodes_of(n));
        let mine = usize::try_from(self.episodes_of(n)).map_err(|_| too_large())?;
        let mut out = Vec::new();
        out.try_reserve_exact(mine).map_err(|_| too_large())?;
        let threads = threads.clamp(1, mine.max(1));
        let count = usize::try_from(self.count.max(1)).unwrap_or(usize::MAX);
        let (episode, worker) = (&episode, &worker);
        // Each worker takes the space for its episodes before the first, and the others stop
        // at their next episode when one cannot: a sweep too large fails at once, not after
        // hours.
        let refused = AtomicBool::new(false);
        let refused = &refused;
        let run_share = move |w: usize| {
            let indices = (self.index..n).step_by(count).skip(w).step_by(threads);
            let mut done = Vec::new();
            if done.try_reserve_exact(indices.size_hint().0).is_err() {
                refused.store(true, Ordering::Relaxed);
                return None;
            }
            let mut state = worker();
            for i in indices {
                if refused.load(Ordering::Relaxed) {
                    return None;
                }
                done.push(episode(&mut state, i));
            }
            Some(done)
        };
        std::thread::scope(|scope| {
            let workers: Vec<_> = (0..threads)
                .map(|w| std::thread::Builder::new().spawn_scoped(scope, move || run_share(w)).map_err(|_| w))
                .collect();
            for worker in workers {
                let done = match worker {
                    Ok(handle) => handle.join().expect("a worker panicked"),
                    Err(w) => {
                        tracing::warn!(
                            "could not start sweep worker {w} of {threads}; its episodes run on this thread"
                        );
                        run_share(w)
                    }
                };
                out.extend(done.ok_or_else(too_large)?);
            }
            Ok(out)
        })
    }
}

/// A shard with more episodes than this process can hold.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "{episodes} episodes take {gib:.1} GiB to hold, more than this process can allocate: run them in shards \
     (--shard i/n), each small enough for one machine",
    gib = *bytes as f64 / f64::from(1u32 << 30)
)]
pub struct TooLarge {
    pub episodes: u64,
    /// What their records alone take, bytes.
    pub bytes: u64,
}

impl TooLarge {
    fn of<T>(episodes: u64) -> Self {
        Self { episodes, bytes: episodes.saturating_mul(std::mem::size_of::<T>() as u64) }
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

/// What a sweep is, written beside its episodes (`shard.json` of a shard, and inside every
/// `episodes.parquet`): enough to check that shards belong to one sweep, and to rebuild the
/// whole sweep's report exactly from them.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Manifest {
    /// The scenario's name.
    pub scenario: String,
    /// SHA-256 of the scenario file's bytes, in hex (`sha256sum FILE` prints the same).
    pub scenario_sha256: String,
    /// The flowgate that ran it: episodes of two versions may differ.
    pub flowgate_version: String,
    pub mode: Mode,
    /// Whether the safety supervisor checked the commands.
    pub supervised: bool,
    pub seed: u64,
    /// Episodes in the whole sweep.
    pub sweep_episodes: u64,
    pub shard: Shard,
    /// Episodes in this shard (the rows of its `episodes.parquet`).
    pub episodes: u64,
}

impl Manifest {
    /// The manifest of `shard` of an `n`-episode sweep around `scenario`, whose file held
    /// `scenario_bytes`.
    pub fn new(
        scenario: &crate::lab::Scenario,
        scenario_bytes: &[u8],
        mode: Mode,
        seed: u64,
        n: u64,
        shard: Shard,
    ) -> Self {
        use sha2::Digest;
        let digest = sha2::Sha256::digest(scenario_bytes);
        Manifest {
            scenario: scenario.name.clone(),
            scenario_sha256: digest.iter().map(|b| format!("{b:02x}")).collect(),
            flowgate_version: env!("CARGO_PKG_VERSION").to_owned(),
            mode,
            supervised: scenario.supervised,
            seed,
            sweep_episodes: n,
            shard,
            episodes: shard.episodes_of(n),
        }
    }

    /// The fields two shards of one sweep share, by name, as text: the first that differs
    /// names the mismatch.
    fn sweep_fields(&self) -> [(&'static str, String); 8] {
        [
            ("scenario", self.scenario.clone()),
            ("scenario_sha256", self.scenario_sha256.clone()),
            ("flowgate_version", self.flowgate_version.clone()),
            ("mode", self.mode.to_string()),
            ("supervised", self.supervised.to_string()),
            ("seed", self.seed.to_string()),
            ("sweep_episodes", self.sweep_episodes.to_string()),
            ("shard count", self.shard.count.to_string()),
        ]
    }
}

/// One shard as read back: its manifest and its episodes.
#[derive(Debug, Clone, PartialEq)]
pub struct ShardData {
    pub manifest: Manifest,
    pub episodes: Vec<Episode>,
}

/// The most episodes a sweep may have (10^9: a merge holds one flag per episode).
pub const MAX_EPISODES: u64 = 1_000_000_000;
/// The most worker threads a sweep or a swarm runs on (`--threads`).
pub const MAX_THREADS: usize = 1024;

/// The threads a sweep runs on by default: the CPUs this process may use (its affinity
/// and cgroup quota: a batch system's allocation), at most [`MAX_THREADS`].
pub fn available_threads() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get).min(MAX_THREADS)
}

/// Why shards cannot be merged into one sweep.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MergeError {
    #[error("no shards to merge")]
    Empty,
    #[error("shard {shard} says the sweep has {total} episodes: more than {MAX_EPISODES}")]
    TooLarge { shard: String, total: u64 },
    #[error("shard {shard} is of another sweep: {key} is {theirs}, the first shard's is {ours}")]
    Mismatch { shard: String, key: &'static str, ours: String, theirs: String },
    #[error("shard {shard} holds {rows} episodes, its manifest says {manifest}")]
    Count { shard: String, rows: u64, manifest: u64 },
    #[error("shard {shard} is not i/n with 0 <= i < n")]
    BadShard { shard: String },
    #[error("episode {index} is in more than one shard (shard {shard} given twice?)")]
    Duplicate { index: u64, shard: String },
    #[error("shard {shard} holds episode {index}, which is not its own")]
    Foreign { index: u64, shard: String },
    #[error("{missing} of the sweep's {total} episodes are missing (the first is {first}: shard {first_shard} not given or incomplete)")]
    Missing { missing: u64, total: u64, first: u64, first_shard: String },
}

/// Merge the shards of one sweep: its episodes in index order and its report. Refuses shards
/// of different sweeps (naming the field), an episode twice, or any episode missing.
pub fn merge(shards: &[ShardData]) -> Result<(Manifest, Vec<Episode>, SweepReport), MergeError> {
    let first = &shards.first().ok_or(MergeError::Empty)?.manifest;
    let total = first.sweep_episodes;
    if total > MAX_EPISODES {
        return Err(MergeError::TooLarge { shard: first.shard.to_string(), total });
    }
    let mut seen = vec![false; total as usize];
    let mut episodes = Vec::with_capacity(total as usize);
    for ShardData { manifest: m, episodes: theirs } in shards {
        let shard = m.shard.to_string();
        if let Some(((key, ours), (_, other))) =
            first.sweep_fields().into_iter().zip(m.sweep_fields()).find(|((_, a), (_, b))| a != b)
        {
            return Err(MergeError::Mismatch { shard, key, ours, theirs: other });
        }
        if m.shard.count == 0 || m.shard.index >= m.shard.count {
            return Err(MergeError::BadShard { shard });
        }
        if theirs.len() as u64 != m.episodes {
            return Err(MergeError::Count { shard, rows: theirs.len() as u64, manifest: m.episodes });
        }
        for e in theirs {
            if e.index >= total || e.index % m.shard.count != m.shard.index {
                return Err(MergeError::Foreign { index: e.index, shard });
            }
            if std::mem::replace(&mut seen[e.index as usize], true) {
                return Err(MergeError::Duplicate { index: e.index, shard });
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
    let whole = Manifest { shard: Shard::WHOLE, episodes: total, ..first.clone() };
    let report = report(&whole.scenario, whole.seed, whole.mode, whole.supervised, &episodes);
    Ok((whole, episodes, report))
}

/// A shard's manifest, in its folder.
pub const MANIFEST_FILE: &str = "shard.json";
/// A sweep's or a shard's episodes, in its folder.
pub const EPISODES_FILE: &str = "episodes.parquet";

/// Why a shard's folder could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum ShardDirError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not a sweep shard's manifest: {source}")]
    NotAManifest { path: String, source: serde_json::Error },
    #[error(transparent)]
    Episodes(#[from] super::episodes_file::EpisodesFileError),
    #[error("{episodes} is not of the shard {manifest} describes: its manifest differs")]
    Mixed { manifest: String, episodes: String },
}

/// Write a shard into `dir`: its manifest ([`MANIFEST_FILE`]) and its episodes
/// ([`EPISODES_FILE`]). The episodes are written first: a manifest promises them.
pub fn write_shard(dir: &Path, manifest: &Manifest, episodes: &[Episode]) -> Result<(), ShardDirError> {
    super::episodes_file::write(&dir.join(EPISODES_FILE), manifest, episodes)?;
    let path = dir.join(MANIFEST_FILE);
    let json = serde_json::to_string_pretty(manifest).expect("a manifest serialises");
    std::fs::write(&path, json).map_err(|source| ShardDirError::Io { path: path.display().to_string(), source })
}

/// Read the shard in `dir`, refusing episodes whose own manifest is not the folder's.
pub fn read_shard(dir: &Path) -> Result<ShardData, ShardDirError> {
    let path = dir.join(MANIFEST_FILE);
    let at = path.display().to_string();
    let text = crate::config::read_text(&path, crate::config::MAX_FILE_BYTES)
        .map_err(|source| ShardDirError::Io { path: at.clone(), source })?;
    let manifest: Manifest =
        serde_json::from_str(&text).map_err(|source| ShardDirError::NotAManifest { path: at.clone(), source })?;
    let episodes_path = dir.join(EPISODES_FILE);
    let (theirs, episodes) = super::episodes_file::read(&episodes_path)?;
    if theirs != manifest {
        return Err(ShardDirError::Mixed { manifest: at, episodes: episodes_path.display().to_string() });
    }
    Ok(ShardData { manifest, episodes })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env<'a>(vars: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |name| vars.iter().find(|(k, _)| *k == name).map(|(_, v)| v.to_string())
    }

    /// A shard runs each of its episodes once, whatever the threads asked for: fewer than
    /// its episodes, as many, more (no idle workers are started), or none.
    #[test]
    fn a_shard_runs_each_of_its_episodes_once_on_any_number_of_threads() {
        let shard = Shard { index: 1, count: 3 };
        let expected: Vec<u64> = (1..20).step_by(3).collect();
        for threads in [0, 1, 2, 7, 64] {
            let started = std::sync::atomic::AtomicUsize::new(0);
            let mut got = shard
                .run(20, threads, |i| {
                    started.fetch_add(1, Ordering::Relaxed);
                    i
                })
                .unwrap();
            got.sort_unstable();
            assert_eq!(got, expected, "{threads} threads");
            assert_eq!(started.into_inner(), expected.len(), "{threads} threads");
        }
        assert!(Shard { index: 2, count: 3 }.run(2, 4, |i| i).unwrap().is_empty());
    }

    /// A shard this process cannot hold is refused before any episode runs, saying how
    /// much memory its episodes take.
    #[test]
    fn a_shard_too_large_to_hold_is_refused_before_it_runs() {
        let ran = AtomicBool::new(false);
        let huge = Shard::WHOLE.run(u64::MAX, 2, |i| {
            ran.store(true, Ordering::Relaxed);
            [i; 8]
        });
        let e = huge.unwrap_err();
        assert_eq!(e, TooLarge { episodes: u64::MAX, bytes: u64::MAX });
        assert!(e.to_string().contains("run them in shards (--shard i/n)"), "{e}");
        assert!(!ran.into_inner());
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
