//! What an outside policy costs a cycle (`cargo bench --bench policy`; docs/performance.md,
//! "Outside policies"): E1 through the whole stack in virtual time, the field driving
//! against a policy process that answers each observation at once (a Python loop that
//! does not parse it), the same episodes. The difference a cycle is the protocol's own cost:
//! the observation built and written as JSON, the pipe both ways, the answer read and
//! parsed, and the two context switches. Wall time: the policy runs in another process.

use std::path::Path;
use std::time::{Duration, Instant};

use flowgate::lab::policy::Worker;
use flowgate::lab::virtual_rig::{self, Options};
use flowgate::lab::{sweep, Scenario};

const EPISODES: u64 = 40;

/// Answers every observation with a constant command, reading nothing but the line.
const ECHO: &str = "import sys\nfor line in sys.stdin:\n    if line.startswith('{\"t\"'):\n        sys.stdout.write('{\"v\": 0.1, \"w\": 0.0}\\n'); sys.stdout.flush()";

fn python() -> String {
    std::env::var("FLOWGATE_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn main() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml");
    let base = Scenario::load(&path).expect("scenario");
    let scenarios: Vec<Scenario> = (0..EPISODES).map(|i| sweep::perturb(&base, 1, i)).collect();
    let command = format!("{} -c \"{}\"", python(), ECHO.replace('"', "\\\""));
    let mut worker = Worker::new(&command, Duration::from_secs(5));
    // Warm: the process started, the caches filled.
    let _ = worker.episode(&scenarios[0], Options::default());
    let _ = virtual_rig::run(&scenarios[0], Options::default());

    let (mut field_ns, mut policy_ns, mut turns) = (Vec::new(), Vec::new(), 0u64);
    for s in &scenarios {
        let start = Instant::now();
        let field = virtual_rig::run(s, Options::default());
        let field_time = start.elapsed();
        let start = Instant::now();
        let (run, failure) = worker.episode(s, Options::default());
        let policy_time = start.elapsed();
        assert!(failure.is_none(), "{failure:?}");
        // One observation a control period of the run.
        let periods = (run.truth.summary.duration / 0.017).ceil() as u64;
        turns += periods;
        field_ns.push(field_time.as_nanos() as f64 / (field.truth.summary.duration / 0.017).ceil());
        policy_ns.push(policy_time.as_nanos() as f64 / periods as f64);
    }
    worker.close();
    let quantile = |v: &mut Vec<f64>, q: f64| {
        v.sort_by(|a, b| a.total_cmp(b));
        v[((v.len() - 1) as f64 * q).round() as usize]
    };
    let (f50, p50) = (quantile(&mut field_ns, 0.5), quantile(&mut policy_ns, 0.5));
    let (f_max, p_max) = (quantile(&mut field_ns, 1.0), quantile(&mut policy_ns, 1.0));
    println!(
        "E1, {EPISODES} episodes through the whole stack, {turns} policy turns: a period costs {:.1} µs with the field, {:.1} µs with a policy that answers at once (medians of the episodes; max {:.1} and {:.1})",
        f50 / 1e3,
        p50 / 1e3,
        f_max / 1e3,
        p_max / 1e3
    );
    println!(
        "the protocol's own cost: {:.1} µs a period (the policy's answer, two pipes, JSON both ways)",
        (p50 - f50) / 1e3
    );
}
