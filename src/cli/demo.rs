//! `flowgate demo`: the simulator and the gateway together, no hardware.

use crate::cli::say;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use flowgate::gateway::core::Progress;
use flowgate::lab::Outcome;
use flowgate::lab::{demo, Scenario};

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// The scenario to run (default: E2, the lane head-on).
    #[arg(long, value_name = "FILE")]
    scenario: Option<PathBuf>,
    /// The CAN endpoint: `slcan-pty` (default), or `socketcan:vcan0` where vcan exists.
    #[arg(long, default_value = "slcan-pty")]
    can: String,
    /// The motors: one PCL-80K-like board (default), or one CiA 402 drive a wheel.
    #[arg(long, value_enum, default_value = "pcl80k")]
    drive: demo::DemoDrive,
    /// Where to write trajectory.svg, trace.json, cycles.csv, can.log, truth.json.
    #[arg(long, value_name = "DIR", default_value = "out/demo")]
    out: PathBuf,
    /// Record the run to this MCAP file (`flowgate replay FILE` plays it back).
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Serve the live view here while the demo runs (`--view` alone: 127.0.0.1:8080).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8080")]
    view: Option<std::net::SocketAddr>,
    /// Serve Foxglove live here while the demo runs (`--foxglove` alone: 127.0.0.1:8765,
    /// Foxglove's default): in Foxglove, "Open connection", Foxglove WebSocket.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    foxglove: Option<std::net::SocketAddr>,
    /// Serve a control socket here (`flowgate ctl --socket PATH status`).
    #[arg(long, value_name = "PATH")]
    socket: Option<PathBuf>,
    /// Join ROS 2 as node /flowgate (ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE
    /// honoured) and wait for a goal on /goal_pose and calls of ~/arm and ~/start, instead
    /// of driving to the scenario's goal at once.
    #[arg(long)]
    ros2: bool,
    /// With `--ros2` and the scenario's `planner.method = "ros2"`: take
    /// `geometry_msgs/msg/TwistStamped` on /cmd_vel (`[ros2] cmd_vel_stamped`) instead of
    /// Twist, as nav2's controllers publish it by default since Jazzy.
    #[arg(long, requires = "ros2")]
    cmd_vel_stamped: bool,
}

/// One line of the run's progress, about twice a second.
fn say_progress(p: &Progress) {
    say!(
        "  t={:>5.1}s  {:<8} goal {:>6.3} m  clearance {:>8}  cycle latency {:>6.0} µs  cycles {}",
        p.t,
        p.state.name(),
        p.goal_distance,
        p.clearance.map_or("-".into(), |c| format!("{:.3} m", c)),
        p.e2e_us,
        p.cycles
    );
}

/// What the demo runs, and where to watch it.
fn announce(args: &DemoArgs, scenario: &Scenario) {
    let motors = match args.drive {
        demo::DemoDrive::Pcl80k => "a PCL-80K-like board",
        demo::DemoDrive::Cia402 => "CiA 402 drives",
    };
    say!("flowgate demo: {} (simulator + gateway over ptys, CAN {}, {motors})", scenario.name, args.can);
    if let Some(addr) = args.view {
        say!("live view      http://{addr}/ (read-only; it ends with the run)");
    }
    if let Some(addr) = args.foxglove {
        say!("Foxglove live  ws://{addr} (read-only; it ends with the run)");
    }
    if args.ros2 {
        say!("ROS 2          node /flowgate: send a goal on /goal_pose, then call /flowgate/arm and /flowgate/start");
    }
}

/// What the demo's gateway writes and serves, as the flags ask.
fn outputs(args: &DemoArgs, out: &std::path::Path) -> demo::Outputs {
    demo::Outputs {
        dir: Some(out.to_path_buf()),
        record: args.record.clone(),
        view: args.view,
        foxglove: args.foxglove,
        socket: args.socket.clone(),
        ros2: args.ros2.then_some(flowgate::config::Ros2Section {
            enabled: true,
            cmd_vel_stamped: args.cmd_vel_stamped,
            ..Default::default()
        }),
    }
}

pub fn run(args: DemoArgs) -> Result<()> {
    let scenario = match &args.scenario {
        Some(path) => Scenario::load(path)?,
        None => Scenario::from_toml(demo::DEFAULT_SCENARIO, "E2 (built in)")?,
    };
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let out = std::fs::canonicalize(&args.out)?;
    announce(&args, &scenario);
    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    let run = runtime.block_on(demo::run(&scenario, &args.can, args.drive, outputs(&args, &out), say_progress))?;
    let t = &run.truth.summary;
    say!();
    say!(
        "outcome          {}",
        match run.outcome() {
            Outcome::Collision => "COLLISION",
            Outcome::Goal => "goal reached, no contact",
            _ => "goal not reached",
        }
    );
    say!(
        "world truth      min clearance {} , path {:.3} m, {:.1} s",
        t.min_obstacle_clearance.map_or("-".into(), |c| format!("{:.1} mm", c * 1e3)),
        t.path_length,
        t.duration
    );
    for ((v, (name, home)), spec) in t.vehicles.iter().skip(1).zip(&run.vehicles).zip(&scenario.vehicles) {
        let touched = v.contact.is_some() || v.vehicle_contact.is_some();
        let scripted = spec.role == flowgate_sim::scenario::vehicles::Role::Script;
        let how = match (home, touched, scripted) {
            (_, true, _) => "TOUCHED",
            (true, false, false) => "at its goal, no contact",
            (true, false, true) => "at its script's end, no contact",
            (false, false, false) => "not at its goal",
            (false, false, true) => "not at its script's end",
        };
        say!(
            "vehicle {name:<8} {how}, path {:.3} m, nearest vehicle {:.1} cm",
            v.path_length,
            v.min_vehicle_gap * 100.0
        );
    }
    say!("{}", run.report);
    run.write_files(&scenario, &out)?;
    say!("\nwrote {}/{}", out.display(), demo::DEMO_FILES);
    if let (Some(rec), Some(path)) = (&run.report.files.recording, &args.record) {
        let path = path.display();
        say!("recorded {path} ({} inputs, {} cycles): flowgate replay {path} plays it back", rec.inputs, rec.cycles);
    }
    // Driven from ROS 2, the goal is the operator's: the gateway's own stop says it was reached.
    let reached = if args.ros2 {
        run.report.stop_reason == Some(flowgate::gateway::core::StopReason::GoalReached) && !run.contact
    } else {
        run.outcome() == Outcome::Goal
    };
    if !reached {
        anyhow::bail!("the demo run did not reach the goal cleanly");
    }
    Ok(())
}
