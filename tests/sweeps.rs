//! Sweeps in shards, as a batch system runs them: each shard's manifest and Parquet episodes,
//! merged back into exactly the sweep run in one piece, read by pyarrow as a user's analysis
//! would; shards of another sweep refused by the field that differs. A setting compared over
//! the same episodes (`--compare`), judged by its outcomes in distribution.

#[path = "support/python.rs"]
mod python;

use std::path::{Path, PathBuf};
use std::process::Command;

use flowgate::lab::planner_only::Mode;
use flowgate::lab::sweep::{self, Manifest, Shard, ShardData};
use flowgate::lab::Scenario;

const E1: &str = "scenarios/e1-standing-obstacle.toml";

fn e1() -> (Scenario, Vec<u8>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(E1);
    (Scenario::load(&path).unwrap_or_else(|e| panic!("{e}")), std::fs::read(&path).unwrap())
}

fn flowgate() -> Command {
    Command::new(env!("CARGO_BIN_EXE_flowgate"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("flowgate-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A sweep in shards merges into exactly the episodes and report of the sweep run in one
/// piece; shards of another sweep, an episode twice or a shard missing are refused, naming
/// what is wrong.
#[test]
fn sweep_shards_merge_into_the_whole_sweep() {
    let (base, bytes) = e1();
    let whole = sweep::sweep(&base, 24, 3, 2, Mode::PlannerOnly).expect("a sweep this small fits");
    let shard = |i: u64, seed: u64| {
        let shard = Shard { index: i, count: 3 };
        ShardData {
            manifest: Manifest::new(&base, &bytes, Mode::PlannerOnly, seed, 24, shard),
            episodes: sweep::run_shard(&base, 24, seed, 1, Mode::PlannerOnly, shard).expect("a sweep this small fits"),
        }
    };
    let shards = [shard(2, 3), shard(0, 3), shard(1, 3)];
    assert_eq!(shards.iter().map(|s| s.episodes.len()).sum::<usize>(), 24);
    assert!(shards.iter().all(|s| s.manifest.episodes == 8));
    let (manifest, episodes, merged) = sweep::merge(&shards).unwrap();
    assert_eq!(serde_json::to_value(&merged).unwrap(), serde_json::to_value(&whole).unwrap());
    assert_eq!(
        episodes,
        sweep::run_shard(&base, 24, 3, 2, Mode::PlannerOnly, Shard::WHOLE).expect("a sweep this small fits")
    );
    assert_eq!(manifest, Manifest::new(&base, &bytes, Mode::PlannerOnly, 3, 24, Shard::WHOLE));

    let err = |shards: &[ShardData]| sweep::merge(shards).unwrap_err().to_string();
    let e = err(&shards[..2]);
    assert!(e.contains("8 of the sweep's 24 episodes are missing") && e.contains("shard 1/3"), "{e}");
    let e = err(&[shards[0].clone(), shards[1].clone(), shards[0].clone()]);
    assert!(e.contains("in more than one shard") && e.contains("2/3"), "{e}");
    let e = err(&[shards[0].clone(), shard(0, 4)]);
    assert!(e.contains("seed is 4") && e.contains("first shard's is 3"), "{e}");
    let with = |edit: fn(&mut Manifest)| {
        let mut s = shards[1].clone();
        edit(&mut s.manifest);
        err(&[shards[0].clone(), s])
    };
    let e = with(|m| m.supervised = false);
    assert!(e.contains("shard 0/3 is of another sweep: supervised is false"), "{e}");
    let e = with(|m| m.scenario_sha256 = "00".repeat(32));
    assert!(e.contains("scenario_sha256 is 0000") && e.contains(&shards[0].manifest.scenario_sha256), "{e}");
    let e = with(|m| m.flowgate_version = "0.0.9".into());
    assert!(e.contains("flowgate_version is 0.0.9, the first shard's is 0.1.0"), "{e}");
    let e = with(|m| m.episodes = 7);
    assert!(e.contains("holds 8 episodes, its manifest says 7"), "{e}");
    let mut broken = shards[0].clone();
    broken.manifest.shard = Shard { index: 0, count: 0 }; // a hand-edited shard.json
    let e = err(&[broken]);
    assert!(e.contains("shard 0/0 is not i/n"), "{e}");
    assert_eq!("1/3".parse::<Shard>().unwrap(), Shard { index: 1, count: 3 });
    for bad in ["3/3", "1/0", "1", "a/b", "-1/2"] {
        assert!(bad.parse::<Shard>().is_err(), "{bad}");
    }
    assert_eq!([0, 1, 2].map(|i| Shard { index: i, count: 3 }.episodes_of(8)), [3, 3, 2]);
    assert_eq!(Shard { index: 5, count: 8 }.episodes_of(5), 0);
}

/// The episodes file keeps every field of every episode, gaps (no wall, no clearance) as
/// nulls, and its manifest; a file that is not one is refused by what is wrong with it.
#[test]
fn episodes_round_trip_through_parquet() {
    let (base, bytes) = e1();
    let dir = temp_dir("episodes-file");
    std::fs::create_dir_all(&dir).unwrap();
    let mut episodes =
        sweep::run_shard(&base, 6, 9, 1, Mode::PlannerOnly, Shard::WHOLE).expect("a sweep this small fits");
    episodes[2].min_clearance = None;
    episodes[3].min_wall_clearance = Some(0.25);
    episodes[4].active_contact = true;
    let manifest = Manifest::new(&base, &bytes, Mode::PlannerOnly, 9, 6, Shard::WHOLE);
    let path = dir.join("episodes.parquet");
    sweep::episodes_file::write(&path, &manifest, &episodes).unwrap();
    let (read_manifest, read) = sweep::episodes_file::read(&path).unwrap();
    assert_eq!((read_manifest, read), (manifest.clone(), episodes.clone()));

    std::fs::write(dir.join("shard.json"), serde_json::to_string(&manifest).unwrap()).unwrap();
    assert!(sweep::read_shard(&dir).is_ok());
    let other = Manifest { seed: 10, ..manifest };
    std::fs::write(dir.join("shard.json"), serde_json::to_string(&other).unwrap()).unwrap();
    let e = sweep::read_shard(&dir).unwrap_err().to_string();
    assert!(e.contains("episodes.parquet is not of the shard") && e.contains("shard.json"), "{e}");
    std::fs::write(&path, b"PAR1 not really").unwrap();
    let e = sweep::episodes_file::read(&path).unwrap_err().to_string();
    assert!(e.contains("episodes.parquet"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Through the command line: `--shard i/n` writes shard.json and episodes.parquet,
/// `--merge` reads them into sweep.json and episodes.parquet, equal to the unsharded
/// sweep's; pyarrow reads the merged episodes row for row as the whole sweep's and finds
/// the report's rates in them. A bad shard or a missing one is refused.
#[test]
fn plan_command_shards_and_merges_a_sweep() {
    let dir = temp_dir("shards");
    let e1 = Path::new(env!("CARGO_MANIFEST_DIR")).join(E1);
    let run = |args: &[&str]| {
        let out = flowgate().arg("plan").args(args).output().unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr),
        )
    };
    let e1s = e1.to_str().unwrap();
    let d = |name: &str| dir.join(name).to_str().unwrap().to_owned();
    let (ok, text) = run(&["--planner-only", "--sweep", "10", "--seed", "5", e1s, "--out", &d("whole")]);
    assert!(ok, "{text}");
    for i in 0..2 {
        let shard = format!("{i}/2");
        let out = d(&format!("s{i}"));
        let (ok, text) =
            run(&["--planner-only", "--sweep", "10", "--seed", "5", "--shard", &shard, e1s, "--out", &out]);
        assert!(ok && text.contains(&format!("shard {i}/2 of the sweep of 10")), "{text}");
    }
    let (ok, text) = run(&["--merge", &d("s0"), &d("s1"), "--out", &d("merged")]);
    assert!(ok && text.contains("merged from 2 shards"), "{text}");
    let read = |p: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join(p)).unwrap()).unwrap()
    };
    assert_eq!(read("merged/sweep.json"), read("whole/sweep.json"));
    let bytes = |p: &str| std::fs::read(dir.join(p)).unwrap();
    assert!(bytes("merged/episodes.parquet") == bytes("whole/episodes.parquet"), "the episodes differ in bytes");
    let peer = Command::new(python::python())
        .arg(python::peer("sweeps"))
        .args([d("merged"), d("whole"), d("s0"), d("s1")])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&peer.stdout).into_owned() + &String::from_utf8_lossy(&peer.stderr);
    assert!(peer.status.success() && said.contains("pyarrow read 10 episodes"), "{said}");

    let (ok, text) = run(&["--merge", &d("s0"), "--out", &d("merged")]);
    assert!(!ok && text.contains("5 of the sweep's 10 episodes are missing") && text.contains("shard 1/2"), "{text}");
    let (ok, text) = run(&["--planner-only", "--sweep", "10", "--seed", "6", "--shard", "1/2", e1s, "--out", &d("s6")]);
    assert!(ok, "{text}");
    let (ok, text) = run(&["--merge", &d("s0"), &d("s6"), "--out", &d("merged")]);
    assert!(!ok && text.contains("shard 1/2 is of another sweep: seed is 6, the first shard's is 5"), "{text}");
    let (ok, text) = run(&["--merge", &d("whole"), "--out", &d("merged")]);
    assert!(!ok && text.contains("shard.json: No such file"), "{text}");
    let (ok, text) = run(&["--planner-only", "--sweep", "10", "--shard", "2/2", e1s]);
    assert!(!ok && text.contains("expected i/n with 0 <= i < n"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--shard auto/n` takes its index from a batch system's array job (a Slurm array counted
/// from 1 here): the same shard as `1/2`; refused, naming the variables, outside one.
#[test]
fn an_automatic_shard_takes_its_index_from_the_batch_system() {
    let dir = temp_dir("auto-shard");
    let e1 = Path::new(env!("CARGO_MANIFEST_DIR")).join(E1);
    let e1s = e1.to_str().unwrap();
    let d = |name: &str| dir.join(name).to_str().unwrap().to_owned();
    let sweep = |shard: &str, env: &[(&str, &str)], out: &str| {
        let mut cmd = flowgate();
        cmd.arg("plan").args(["--planner-only", "--sweep", "10", "--seed", "5", "--shard", shard, e1s]);
        cmd.args(["--out", out]);
        for v in sweep::BATCH_INDEX_VARIABLES.into_iter().chain(["SLURM_ARRAY_TASK_MIN"]) {
            cmd.env_remove(v);
        }
        let out = cmd.envs(env.iter().copied()).output().unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr),
        )
    };
    let (ok, text) = sweep("1/2", &[], &d("fixed"));
    assert!(ok, "{text}");
    let (ok, text) = sweep("auto/2", &[("SLURM_ARRAY_TASK_ID", "2"), ("SLURM_ARRAY_TASK_MIN", "1")], &d("auto"));
    assert!(ok && text.contains("shard 1/2 of the sweep of 10"), "{text}");
    let read = |p: &str| std::fs::read(dir.join(p)).unwrap();
    assert_eq!(read("auto/shard.json"), read("fixed/shard.json"));
    assert_eq!(read("auto/episodes.parquet"), read("fixed/episodes.parquet"));
    let (ok, text) = sweep("auto/2", &[], &d("none"));
    assert!(!ok && text.contains("--shard auto/2: no batch index in the environment"), "{text}");
    assert!(text.contains("SLURM_ARRAY_TASK_ID, JOB_COMPLETION_INDEX, AWS_BATCH_JOB_ARRAY_INDEX"), "{text}");
    let (ok, text) = sweep("auto/2", &[("JOB_COMPLETION_INDEX", "2")], &d("beyond"));
    assert!(!ok && text.contains("JOB_COMPLETION_INDEX gives task 2, beyond the 2 shards"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--threads` changes how fast a sweep runs, not its episodes: one thread, five and the
/// default (the CPUs this process may use) write the same episodes, byte for byte. A count
/// outside 1 to 1024, or a swarm of more episodes than a sweep may have, is refused before
/// anything runs, naming the flag.
#[test]
fn threads_change_a_sweeps_pace_not_its_episodes() {
    let dir = temp_dir("threads");
    let e1 = Path::new(env!("CARGO_MANIFEST_DIR")).join(E1);
    let sweep = |threads: Option<&str>, out: &str| {
        let mut cmd = flowgate();
        cmd.arg("plan").args(["--planner-only", "--sweep", "12", "--seed", "3"]).arg(&e1);
        cmd.arg("--out").arg(dir.join(out));
        cmd.args(threads.map(|t| ["--threads", t]).into_iter().flatten());
        let out = cmd.output().unwrap();
        (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    for (threads, out) in [(None, "default"), (Some("1"), "one"), (Some("5"), "five")] {
        let (code, stderr) = sweep(threads, out);
        assert_eq!(code, Some(0), "{threads:?}: {stderr}");
    }
    let read = |out: &str| std::fs::read(dir.join(out).join("episodes.parquet")).unwrap();
    assert_eq!(read("one"), read("default"));
    assert_eq!(read("five"), read("default"));
    // A swarm beyond the episodes a sweep may have is refused the same way.
    let out = flowgate()
        .args(["plan", "--swarm", "18446744073709551615", "--out"])
        .arg(dir.join("bad"))
        .arg(&e1)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("--swarm 18446744073709551615: at most 1000000000 episodes"), "{stderr}");
    for bad in ["0", "1025", "many"] {
        let (code, stderr) = sweep(Some(bad), "bad");
        assert_eq!(code, Some(2), "--threads {bad}: {stderr}");
        assert!(stderr.contains(&format!("invalid value '{bad}' for '--threads <THREADS>'")), "{stderr}");
        assert!(!dir.join("bad").exists(), "--threads {bad} wrote its output");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// deploy/k8s/sweep-job.yaml, read as Kubernetes reads it (PyYAML), is an Indexed Job of
/// as many completions as its command has shards; its command, run for every index as the
/// Job's pods would (JOB_COMPLETION_INDEX set, a smaller sweep, the volume and the image's
/// scenarios mapped to folders here), writes shards that merge into the sweep.
#[test]
fn the_kubernetes_job_runs_one_shard_per_index() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let peer = Command::new(python::python())
        .arg(python::peer("sweeps"))
        .args(["--k8s", root.join("deploy/k8s/sweep-job.yaml").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(peer.status.success(), "{}", String::from_utf8_lossy(&peer.stderr));
    let job: serde_json::Value = serde_json::from_slice(&peer.stdout).unwrap();
    assert_eq!(job["completion_mode"], "Indexed");
    assert_eq!(job["restart_policy"], "Never");
    let completions = job["completions"].as_u64().unwrap();
    assert_eq!(job["parallelism"].as_u64(), Some(completions));
    let command: Vec<String> = serde_json::from_value(job["command"].clone()).unwrap();
    assert_eq!(command[..2], ["sh", "-c"]);
    let script = &command[2];
    assert!(script.contains(&format!("--shard auto/{completions} ")), "{script}");
    assert!(script.contains("/results/shard-$JOB_COMPLETION_INDEX"), "{script}");
    assert_eq!(job["mounts"], serde_json::json!(["/results"]));

    let dir = temp_dir("k8s");
    let results = dir.join("results");
    let here = script
        .replace("exec flowgate ", &format!("exec {} ", env!("CARGO_BIN_EXE_flowgate")))
        .replace("--sweep 100000 ", "--sweep 12 ")
        .replace("/results", results.to_str().unwrap())
        .replace("/scenarios/", root.join("scenarios/").to_str().unwrap());
    assert!(here.contains("--sweep 12 "), "the Job's sweep size moved: {script}");
    for index in 0..completions {
        let out =
            Command::new("sh").args(["-c", &here]).env("JOB_COMPLETION_INDEX", index.to_string()).output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success() && text.contains(&format!("shard {index}/{completions} of the sweep of 12")),
            "{text}"
        );
    }
    let shards: Vec<_> = (0..completions).map(|i| results.join(format!("shard-{i}"))).collect();
    let read: Vec<ShardData> = shards.iter().map(|d| sweep::read_shard(d).unwrap()).collect();
    let (manifest, episodes, _) = sweep::merge(&read).unwrap();
    assert_eq!((manifest.sweep_episodes, episodes.len()), (12, 12));
    assert_eq!(manifest.scenario, "E2 lane head-on");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--compare KEY=VALUE` runs the same episodes twice. E2's lane at the default residual
/// (`planner.lane_residual = 1e-4`) and at 1e-8 has the same outcomes in distribution, as
/// has a room's far field by runs' expansions and by every panel's log (`room.far_field`);
/// planning circles grown by 5 cm (`planner.clearance`) keep every rate but move every
/// minimum clearance, and the command fails, naming the setting.
#[test]
fn a_compared_setting_is_judged_by_its_outcomes_in_distribution() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let compare = |episodes: &str, setting: &str, scenario: &str, dir: &Path| {
        let out = flowgate()
            .args(["plan", "--planner-only", "--sweep", episodes, "--compare", setting, "--out"])
            .arg(dir)
            .arg(root.join(scenario))
            .output()
            .unwrap();
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("compare.json")).unwrap()).unwrap();
        (out, json)
    };
    let dir = temp_dir("compare-lane");
    let (out, json) = compare("100", "planner.lane_residual=1e-8", "scenarios/e2-lane-head-on.toml", &dir);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("the same in distribution: yes"), "{text}");
    assert_eq!(json["same"], true, "{json}");
    assert_eq!(json["rates"].as_array().unwrap().len(), 7);
    assert!(json["clearance"]["p_value"].as_f64().unwrap() >= 0.01, "{json}");
    assert_eq!(json["clearance"]["before"], 100);

    // The room's far panels by runs' expansions (the default) and by their log: the same
    // (docs/simulation.md has the 10,000-episode sweeps of every scenario).
    let dir = temp_dir("compare-far-field");
    let (out, json) = compare("100", "room.far_field=\"exact\"", "scenarios/rooms/table-and-crowd.toml", &dir);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("the same in distribution: yes"), "{text}");
    assert!(json["clearance"]["p_value"].as_f64().unwrap() >= 0.01, "{json}");

    let dir = temp_dir("compare-clearance");
    let (out, json) = compare("50", "planner.clearance=0.05", E1, &dir);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{}", String::from_utf8_lossy(&out.stdout));
    assert!(err.contains("with planner.clearance=0.05 the outcomes are not the same in distribution"), "{err}");
    assert!(json["rates"].as_array().unwrap().iter().all(|r| r["same"] == true), "{json}");
    assert!(json["clearance"]["p_value"].as_f64().unwrap() < 0.01 && json["same"] == false, "{json}");

    // A setting the scenario cannot take is refused before anything runs, naming the key.
    let out = flowgate()
        .args(["plan", "--planner-only", "--sweep", "5", "--compare", "planner.lane_residual=1e-2"])
        .arg(root.join(E1))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("planner.lane_residual"), "{err}");
    let out = flowgate()
        .args(["plan", "--planner-only", "--sweep", "5", "--compare", "room.far_field=\"fast\""])
        .arg(root.join(E1))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("unknown variant `fast`") && err.contains("far_field"), "{err}");
}

/// `--sweep N --episode K` runs episode K of the sweep alone and ends as it did in the
/// sweep: its outcome, and its time and minimum clearance to a nanosecond and a nanometre
/// (the single run sums them from its records), planner-only and through the whole
/// stack, with a single run's outputs; an episode beyond the sweep is refused.
#[test]
fn one_episode_of_a_sweep_runs_alone_as_in_the_sweep() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scenario = root.join("scenarios/e5-moving-and-standing.toml");
    for (mode, n, picks) in [("--planner-only", "12", [0u64, 7, 11]), ("--full-stack", "3", [0, 2, 2])] {
        let mode_args: &[&str] = if mode == "--planner-only" { &[mode] } else { &[] };
        let dir = temp_dir(&format!("episode-sweep{mode}"));
        let ok = flowgate().args(["plan", "--sweep", n, "--out"]).arg(&dir).args(mode_args).arg(&scenario).status();
        assert!(ok.unwrap().success());
        let (_, episodes) = sweep::episodes_file::read(&dir.join(sweep::EPISODES_FILE)).unwrap();
        for k in picks {
            let one = temp_dir(&format!("episode-{k}{mode}"));
            let out = flowgate()
                .args(["plan", "--sweep", n, "--episode", &k.to_string(), "--out"])
                .arg(&one)
                .args(mode_args)
                .arg(&scenario)
                .output()
                .unwrap();
            let text = String::from_utf8_lossy(&out.stdout);
            assert!(out.status.success() && text.contains(&format!("episode {k} of the sweep of {n}")), "{text}");
            let summary: serde_json::Value =
                serde_json::from_slice(&std::fs::read(one.join("summary.json")).unwrap()).unwrap();
            let e = &episodes[k as usize];
            assert_eq!(summary["outcome"], e.outcome.to_string(), "{mode} episode {k}");
            let end = summary["end_time"].as_f64().unwrap();
            assert!((end - e.duration).abs() < 1e-9, "{mode} episode {k}: {end} against {}", e.duration);
            let clearance = summary["min_obstacle_clearance"].as_f64().unwrap();
            assert!((clearance - e.min_clearance.unwrap()).abs() < 1e-9, "{mode} episode {k}");
            let _ = std::fs::remove_dir_all(&one);
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
    let out = flowgate().args(["plan", "--sweep", "3", "--episode", "3"]).arg(&scenario).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--episode 3: the sweep has episodes 0 to 2"), "{err}");
}
