//! The fault swarm through the command a user runs (`flowgate plan --swarm N`): random
//! overlapping faults on both links and in the world, the whole stack in virtual time, an
//! operator who resets, arms and starts after each stop, every episode judged by the
//! invariants of `flowgate::lab::swarm` against the simulator's world truth. The judge
//! itself, and the draw, are unit-tested in `src/lab/swarm.rs`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn flowgate() -> Command {
    Command::new(env!("CARGO_BIN_EXE_flowgate"))
}

fn scenario(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)
}

fn run(args: &[&str]) -> Output {
    flowgate().args(args).output().expect("flowgate runs")
}

/// A fresh directory for one test's files.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("flowgate-swarm-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// The episodes CI runs around each scenario (docs/faults.md gives the 10,000-episode figures).
const EPISODES: &str = "300";

/// A swarm around E2 (the lane) and E5 (free space, two obstacles), in two shards as a batch
/// system would run it: zero broken invariants; every kind of fault and every backend drawn;
/// faults that stop the robot, and every episode without a lasting cause back at its goal.
#[test]
fn the_swarm_breaks_no_invariant_around_e2_and_e5() {
    let dir = scratch("invariants");
    for name in ["e2-lane-head-on.toml", "e5-moving-and-standing.toml"] {
        let (mut episodes, mut kinds, mut stops, mut backends) = (0, std::collections::BTreeSet::new(), 0, 0);
        for shard in ["0/2", "1/2"] {
            let out = dir.join(format!("{name}-{}", shard.replace('/', "of")));
            let o = run(&[
                "plan",
                "--swarm",
                EPISODES,
                "--shard",
                shard,
                scenario(name).to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ]);
            assert!(o.status.success(), "{name} shard {shard}:\n{}", text(&o));
            let report: Value =
                serde_json::from_str(&std::fs::read_to_string(out.join("swarm.json")).unwrap()).unwrap();
            assert_eq!(report["violated"], 0, "{}", text(&o));
            let n = report["episodes"].as_u64().unwrap();
            let (reached, lasting) = (report["reached_goal"].as_u64().unwrap(), report["lasting"].as_u64().unwrap());
            assert_eq!(reached + lasting, n, "every episode without a lasting cause reaches its goal");
            episodes += n;
            stops += report["stops"].as_u64().unwrap();
            kinds.extend(report["by_kind"].as_object().unwrap().keys().cloned());
            backends = backends.max(report["by_backend"].as_object().unwrap().len());
            assert!(text(&o).contains("invariants broken: 0 episodes"), "{}", text(&o));
        }
        assert_eq!(episodes, 300, "{name}: the two shards hold every episode once");
        assert_eq!(kinds.len(), flowgate::lab::swarm::Kind::ALL.len(), "{name}: {kinds:?}");
        assert_eq!(backends, 3);
        assert!(stops > 200, "{name}: {stops} fault states");
    }
}

/// An episode replays alone, to the same bytes: the digest of every byte the gateway sent
/// is the swarm's, and two replays write the same cycles.csv and can.log.
#[test]
fn a_swarm_episode_replays_alone_to_the_same_bytes() {
    let dir = scratch("replay");
    let e2 = scenario("e2-lane-head-on.toml");
    let swarm = dir.join("swarm");
    let o = run(&["plan", "--swarm", "24", e2.to_str().unwrap(), "--out", swarm.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let report: Value = serde_json::from_str(&std::fs::read_to_string(swarm.join("swarm.json")).unwrap()).unwrap();
    // The first episode that stopped, and whose gateway was reset and started again.
    let line = report["episode_lines"].as_array().unwrap().iter().find(|l| l["stops"].as_u64() > Some(1)).unwrap();
    let k = line["index"].as_u64().unwrap().to_string();
    let replay = |n: &str| {
        let out = dir.join(n);
        let o = run(&["plan", "--swarm", "24", "--episode", &k, e2.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        assert!(o.status.success(), "{}", text(&o));
        (text(&o), std::fs::read(out.join("cycles.csv")).unwrap(), std::fs::read(out.join("can.log")).unwrap())
    };
    let (said, cycles, can) = replay("a");
    assert!(said.contains(&format!("digest {}", line["digest"].as_str().unwrap())), "{said}");
    let (_, cycles_again, can_again) = replay("b");
    assert!(cycles.len() > 10_000 && can.len() > 10_000);
    assert!(cycles == cycles_again && can == can_again, "a replay differs");
}

/// A broken invariant is reported with its seed and episode and the one-line command that
/// replays it, and the swarm fails. The scenario here is E2 given one second after its last
/// fault (its robot needs about nine to reach the goal): every episode breaks the invariant
/// that the goal is reached once the faults have ended.
#[test]
fn a_broken_invariant_names_its_episode_and_the_command_that_replays_it() {
    let dir = scratch("broken");
    let e2 = std::fs::read_to_string(scenario("e2-lane-head-on.toml")).unwrap();
    assert!(e2.contains("time_limit = 30"));
    let hurried = dir.join("e2-hurried.toml");
    std::fs::write(&hurried, e2.replace("time_limit = 30", "time_limit = 1")).unwrap();
    let out = dir.join("shard");
    // The shard of one episode: 8804 of the 10,000.
    let o = run(&[
        "plan",
        "--swarm",
        "10000",
        "--shard",
        "8804/10000",
        hurried.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let said = text(&o);
    assert!(said.contains("episode 8804 (CiA 402 drives over SLCAN) broke:"), "{said}");
    assert!(said.contains("the goal was not reached after the last fault ended at 2.683 s"), "{said}");
    let command = said.lines().find_map(|l| l.trim().strip_prefix("replay: ")).expect("a replay line").to_string();
    assert_eq!(command, format!("flowgate plan --swarm 10000 --seed 1 --episode 8804 {}", hurried.display()));
    let report: Value = serde_json::from_str(&std::fs::read_to_string(out.join("swarm.json")).unwrap()).unwrap();
    let digest = report["failures"][0]["digest"].as_str().unwrap().to_string();
    // The printed command, run as printed (with an --out of our own), reproduces it.
    let args: Vec<&str> = command.split(' ').skip(1).collect();
    let replay_out = dir.join("replay");
    let o = flowgate().args(&args).args(["--out", replay_out.to_str().unwrap()]).output().unwrap();
    assert!(!o.status.success());
    let said = text(&o);
    assert!(said.contains(&format!("digest {digest}")) && said.contains("broke 1 invariants"), "{said}");
    // The replay lists the gateway's states, each with its time.
    assert!(said.contains("states: 0.000 s idle, 0.001 s armed"), "{said}");
}

/// Episodes of the 10,000-episode swarms around E2 and E5 that take the rarer ways of
/// naming a stop, replayed alone, each clean: a handshake after a reset whose answer was
/// cut short, discarded for its sequence number or late for held time syncs; garbage
/// before an arm; a clock that stepped back just after a handshake, or before a reboot; an
/// obstacle hidden while the robot stood armed.
#[test]
fn the_episodes_the_swarm_found_are_clean() {
    let found: [(&str, &[u64]); 2] = [
        ("e2-lane-head-on.toml", &[1931, 3843, 4022, 4469, 5053, 5889, 7569, 8135, 8615, 8804]),
        ("e5-moving-and-standing.toml", &[4190, 4469, 4538, 5889, 6092, 7569, 8615]),
    ];
    let dir = scratch("found");
    for (file, episodes) in found {
        for k in episodes {
            let path = scenario(file);
            let k = k.to_string();
            let out = dir.join(&k);
            let o = run(&[
                "plan",
                "--swarm",
                "10000",
                "--episode",
                &k,
                path.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ]);
            assert!(o.status.success(), "{file} episode {k}:\n{}", text(&o));
        }
    }
}
