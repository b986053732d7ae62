//! Outside policies in the simulator (`flowgate plan --policy CMD`): the twenty-line Python
//! policy printed in docs/policies.md reaches E1's goal, the same bytes over two runs, and
//! a sweep of it runs one policy process a worker; a policy that sleeps, dies, prints
//! garbage or sends NaN ends its episode with its name.

#[path = "support/python.rs"]
mod python;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn e1() -> PathBuf {
    root().join("scenarios/e1-standing-obstacle.toml")
}

fn plan(args: &[&str], out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flowgate")).arg("plan").args(args).arg("--out").arg(out).output().unwrap()
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("flowgate-policies-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The policy docs/policies.md prints (its second Python block), written to `dir`.
fn documented_policy(dir: &Path) -> PathBuf {
    let page = std::fs::read_to_string(root().join("docs/policies.md")).unwrap();
    let block = page.split("```python\n").nth(2).expect("docs/policies.md prints the policy");
    let code = &block[..block.find("```").unwrap()];
    assert!(code.lines().count() <= 20, "the documented policy is {} lines", code.lines().count());
    let file = dir.join("policy.py");
    std::fs::write(&file, code).unwrap();
    file
}

fn command(policy: &Path) -> String {
    format!("{} {}", python::python().display(), policy.display())
}

#[test]
fn the_documented_policy_reaches_e1s_goal_the_same_bytes_twice() {
    let dir = temp("e1");
    let policy = command(&documented_policy(&dir));
    let runs: Vec<PathBuf> = (0..2).map(|k| dir.join(format!("run{k}"))).collect();
    for out in &runs {
        let o = plan(&["--policy", &policy, e1().to_str().unwrap()], out);
        assert!(o.status.success(), "{}", text(&o));
        assert!(text(&o).contains("goal ") && text(&o).contains("stop: stopped: goal reached"), "{}", text(&o));
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(runs[0].join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["outcome"], "goal", "{summary}");
    assert!(summary["contact"].is_null() && summary["min_obstacle_clearance"].as_f64().unwrap() > 0.02, "{summary}");
    for file in ["cycles.csv", "can.log", "summary.json", "trajectory.svg"] {
        let (a, b) = (std::fs::read(runs[0].join(file)).unwrap(), std::fs::read(runs[1].join(file)).unwrap());
        assert!(a == b, "{file} differs between two runs of the same policy");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A sweep of the documented policy, one process a worker: each process notes its id.
#[test]
fn a_sweep_of_a_policy_runs_one_process_a_worker() {
    let dir = temp("sweep");
    let policy = documented_policy(&dir);
    let pids = dir.join("pids");
    std::fs::create_dir_all(&pids).unwrap();
    let noted = format!("touch {}/$$; exec {}", pids.display(), command(&policy));
    let out = dir.join("sweep");
    let o = plan(&["--policy", &noted, "--sweep", "1000", "--threads", "2", e1().to_str().unwrap()], &out);
    assert!(o.status.success(), "{}", text(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("sweep.json")).unwrap()).unwrap();
    assert_eq!(report["episodes"], 1000, "{report}");
    assert!(report["goal_rate"].as_f64().unwrap() > 0.99, "{report}");
    assert_eq!(report["active_contact_rate"].as_f64(), Some(0.0), "{report}");
    assert_eq!(std::fs::read_dir(&pids).unwrap().count(), 2, "one policy process a worker");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Each way a policy can fail ends its episode, the robot stopped, the failure named.
#[test]
fn a_policy_that_sleeps_dies_babbles_or_sends_nan_ends_its_episode_by_name() {
    let dir = temp("bad");
    let python = python::python();
    let answer_nan = format!(
        "{} -c 'import sys\nfor line in sys.stdin:\n    print(\"{{\\\"v\\\": NaN, \\\"w\\\": 0}}\", flush=True)'",
        python.display()
    );
    let cases = [
        ("sleep 5", "policy: no answer within 200 ms"),
        ("head -c 1 >/dev/null; exit 3", "policy: exited (exit status: 3)"),
        ("while read -r line; do echo 'turn left'; done", "policy: answered `turn left`, not"),
        (answer_nan.as_str(), "policy: answered a command not finite (NaN or infinite)"),
    ];
    for (k, (policy, named)) in cases.iter().enumerate() {
        let out = dir.join(k.to_string());
        let o = plan(&["--policy", policy, "--policy-budget-ms", "200", e1().to_str().unwrap()], &out);
        assert!(o.status.success(), "{policy}: {}", text(&o));
        assert!(text(&o).contains(named), "{policy}: {}", text(&o));
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
        assert!(summary["stop_reason"].as_str().unwrap().starts_with(named), "{summary}");
        assert_ne!(summary["outcome"], "goal", "{summary}");
        assert!(summary["contact"].is_null(), "{summary}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A policy written with the package's helper (`flowgate_policy.serve`) drives through
/// `--policy` to E3b's goal (free space, its obstacle crossing late).
#[test]
fn a_policy_written_with_the_python_package_reaches_its_goal() {
    let dir = temp("helper");
    let policy = format!("{} {} helper", python::python().display(), python::peer("policies").display());
    let scenario = root().join("scenarios/e3b-delay-margin.toml");
    let o = plan(&["--policy", &policy, scenario.to_str().unwrap()], &dir);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("stop: stopped: goal reached"), "{}", text(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The package's Gymnasium environment: `check_env` passes; the same seed gives the same
/// first observation; an episode steered at the goal reaches it, rewarded and named.
#[test]
fn the_gymnasium_environment_passes_check_env_and_runs_an_episode() {
    let scenario = root().join("scenarios/e3b-delay-margin.toml");
    let o = Command::new(python::python())
        .arg(python::peer("policies"))
        .args(["gym", scenario.to_str().unwrap(), env!("CARGO_BIN_EXE_flowgate")])
        .output()
        .unwrap();
    let seen: serde_json::Value =
        serde_json::from_slice(&o.stdout).unwrap_or_else(|_| panic!("{}", String::from_utf8_lossy(&o.stderr)));
    assert_eq!(seen["checked"], true, "{seen}");
    assert_eq!(seen["same_on_same_seed"], true, "{seen}");
    assert_eq!(seen["info"]["outcome"], "goal", "{seen}");
    assert_eq!(seen["info"]["contact"], false, "{seen}");
    // The goal's 1, the way's progress (positive), less 0.001 a step.
    let (reward, steps) = (seen["reward"].as_f64().unwrap(), seen["steps"].as_f64().unwrap());
    assert!(reward > 1.0 - 0.001 * steps && reward < 2.0 - 0.001 * steps, "{seen}");
    assert_eq!(seen["observation"], 8 + 6 * 4, "{seen}");
}

/// A swarm with a policy driving: the documented policy meets every invariant and reaches
/// its goal after the last fault; an adversary driving at the nearest obstacle at top speed
/// meets every invariant too (no active contact, every stop named, no motion while faulted).
#[test]
fn a_swarm_driven_by_a_policy_or_an_adversary_breaks_no_invariant() {
    let dir = temp("swarm");
    let documented = command(&documented_policy(&dir));
    let adversary = format!("{} {} push", python::python().display(), python::peer("policies").display());
    for (name, policy, n) in [("documented", documented.as_str(), "200"), ("adversary", adversary.as_str(), "300")] {
        let out = dir.join(name);
        let o = plan(&["--policy", policy, "--swarm", n, "--threads", "2", e1().to_str().unwrap()], &out);
        assert!(o.status.success(), "{name}: {}", text(&o));
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("swarm.json")).unwrap()).unwrap();
        assert_eq!(report["violated"], 0, "{name}: {}", text(&o));
        let (episodes, lasting) = (report["episodes"].as_u64().unwrap(), report["lasting"].as_u64().unwrap());
        let reached = report["reached_goal"].as_u64().unwrap();
        if name == "documented" {
            assert_eq!(reached, episodes - lasting, "{name}: {}", text(&o));
        } else {
            assert_eq!(reached, 0, "the adversary never heads for the goal: {}", text(&o));
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The adversary's episodes of the 10,000-episode swarm (seed 1) that once ended in an active
/// contact, each after a reflection of a robot LED onto the far side of the other: taken as
/// a pose with its heading turned about once the time since the last pose put it in reach,
/// while the robot stood or after the operator armed again. Each now keeps every invariant.
#[test]
fn the_swarm_episodes_a_reflection_once_drove_into_the_obstacle_keep_every_invariant() {
    let dir = temp("reflections");
    let adversary = format!("{} {} push", python::python().display(), python::peer("policies").display());
    for episode in ["853", "2499", "3115", "3220", "8594", "9687"] {
        let out = dir.join(episode);
        let args = ["--policy", &adversary, "--swarm", "10000", "--seed", "1", "--episode", episode];
        let o = plan(&[&args[..], &[e1().to_str().unwrap()]].concat(), &out);
        assert!(o.status.success(), "episode {episode}: {}", text(&o));
        assert!(text(&o).contains("fault Reflection"), "episode {episode} draws a reflection: {}", text(&o));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A policy drives one vehicle of a fleet (`--vehicle NAME`, at the planner level): the
/// package's helper steering `v2` of the 4-vehicle swap brings every vehicle home, the same
/// bytes over two runs; an adversary driving `v2` at the nearest body makes no active
/// contact in 20 episodes, its commands held by `v2`'s supervisor; a policy that dies stops
/// its vehicle, named, and the others go home but the robot, whose goal it stands on; a vehicle that is not there, or on a
/// scenario without vehicles, is refused by name.
#[test]
fn a_policy_drives_a_vehicle_of_a_fleet() {
    let dir = temp("fleet");
    let swap = root().join("scenarios/fleet/swap-4.toml");
    let swap = swap.to_str().unwrap();
    let peer = |mode: &str| {
        format!("{} {} {mode}", python::python().display(), root().join("tests/peers/policies.py").display())
    };
    let summary = |out: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
    };
    let runs: Vec<PathBuf> = (0..2).map(|k| dir.join(format!("helper{k}"))).collect();
    for out in &runs {
        let o = plan(&["--policy", &peer("helper"), "--vehicle", "v2", swap], out);
        assert!(o.status.success(), "{}", text(&o));
    }
    let s = summary(&runs[0]);
    assert_eq!((s["outcome"].as_str(), s["vehicles"][2]["name"].as_str()), (Some("goal"), Some("v2")), "{s}");
    assert_eq!(
        std::fs::read(runs[0].join("summary.json")).unwrap(),
        std::fs::read(runs[1].join("summary.json")).unwrap()
    );

    let out = dir.join("push");
    let o = plan(&["--policy", &peer("push"), "--vehicle", "v2", "--sweep", "20", "--threads", "2", swap], &out);
    assert!(o.status.success(), "{}", text(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("fleet_sweep.json")).unwrap()).unwrap();
    assert_eq!(
        (
            report["episodes"].as_u64(),
            report["vehicle_contact_episodes"].as_u64(),
            report["active_contact_episodes"].as_u64()
        ),
        (Some(20), Some(0), Some(0)),
        "{report}"
    );

    let out = dir.join("dies");
    let o = plan(&["--policy", "head -c 1 >/dev/null; exit 3", "--vehicle", "v2", swap], &out);
    assert!(o.status.success(), "{}", text(&o));
    let s = summary(&out);
    let v2 = &s["vehicles"][2];
    assert_eq!(v2["outcome"], "stopped", "{s}");
    assert!(v2["stop_reason"].as_str().unwrap().starts_with("policy: exited (exit status: 3)"), "{s}");
    // It stopped where it started, on the robot's goal: the robot waits, then gives it up.
    assert_eq!(s["vehicles"][0]["stop_reason"], "goal blocked by vehicle v2", "{s}");
    for k in [1, 3] {
        assert_eq!(s["vehicles"][k]["outcome"], "goal", "{s}");
    }

    let o = plan(&["--policy", &peer("helper"), "--vehicle", "v9", swap], &dir.join("v9"));
    assert!(
        !o.status.success() && text(&o).contains("--vehicle v9: Swap 4 has vehicles robot, v1, v2, v3"),
        "{}",
        text(&o)
    );
    let o = plan(&["--policy", &peer("helper"), "--vehicle", "v2", e1().to_str().unwrap()], &dir.join("e1"));
    assert!(
        !o.status.success() && text(&o).contains("--vehicle v2:") && text(&o).contains("has no vehicles"),
        "{}",
        text(&o)
    );
    let _ = std::fs::remove_dir_all(&dir);
}
