//! E2 driven between two walls of finite length against E2 in its lane: the outcome, the
//! time and how far the paths part (docs/planner.md, "Two walls and the lane").
//!
//! `cargo run --release --example two_walls [L]`: walls from `-L` to `L` m (default 2).

use flowgate::lab::{planner_only, Scenario};

fn main() {
    let l: f64 = match std::env::args().nth(1).map(|a| a.parse()) {
        None => 2.0,
        Some(Ok(l)) if l > 0.7 => l,
        Some(_) => {
            eprintln!("L: the walls' half-length in metres, more than 0.7 (E2's start and goal lie within)");
            std::process::exit(2);
        }
    };
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e2-lane-head-on.toml");
    let e2 = std::fs::read_to_string(&path).expect("scenarios/e2-lane-head-on.toml");
    let lane = Scenario::from_toml(&e2, "E2").expect("E2 loads");
    // The walls' faces where the lane's lines are, once grown by the robot and clearance.
    let y = 0.2 + lane.robot.radius + lane.rig().config.planner.clearance;
    let walls = format!(
        "[[walls]]\npoints = [[{a}, {y}], [{l}, {y}]]\n[[walls]]\npoints = [[{a}, -{y}], [{l}, -{y}]]\n\
         [room]\nview_boundary = false\nwalls_as_lane = false\n",
        a = -l
    );
    let room = match Scenario::from_toml(&e2.replace("[lane]\nhalf_width = 0.2\n", &walls), "E2 between two walls") {
        Ok(room) => room,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let (a, b) = (planner_only::run(&lane, true), planner_only::run(&room, true));
    let apart =
        a.trace.iter().zip(&b.trace).map(|(p, q)| (p.pose.position - q.pose.position).norm()).fold(0.0, f64::max);
    println!("E2 in its lane:            {} at {:.2} s", a.summary.outcome, a.summary.end_time);
    println!("E2 between walls of ±{l} m: {} at {:.2} s", b.summary.outcome, b.summary.end_time);
    println!("the paths part by {:.1} mm at most (cycle by cycle)", apart * 1e3);
}
