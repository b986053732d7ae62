//! `flowgate ctl`: the operator's commands, sent to a running gateway's control socket.
//!
//! One JSON request per line, one reply per line (src/gateway/core/operator.rs). The exit status
//! is non-zero when the gateway refuses, with its reason.

use crate::cli::{say, say_raw};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use flowgate::config::RigFile;
use flowgate::gateway::core::operator::{Goal, Reply, Request};
use flowgate::gateway::shell::control_client::ControlClient;
use flowgate::gateway::shell::telemetry::write_stage_table;

#[derive(Args, Debug)]
pub struct CtlArgs {
    /// The control socket (default: `[operator] socket` of --config, else the installed
    /// service's, /run/flowgate/control.sock).
    #[arg(long, value_name = "PATH", conflicts_with = "config")]
    socket: Option<PathBuf>,
    /// The rig config naming the socket.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Print the gateway's raw JSON reply.
    #[arg(long)]
    json: bool,
    /// The vehicle the command is for (`robot`, or a `[[vehicles]]` name). Without it,
    /// `estop`, `stop` and `cancel` are every vehicle's, the rest the robot's.
    #[arg(long, value_name = "NAME")]
    vehicle: Option<String>,
    #[command(subcommand)]
    command: CtlCommand,
}

#[derive(Subcommand, Debug)]
enum CtlCommand {
    /// State, last stop, goals, pose, obstacles.
    Status,
    /// Enable the board (nothing moves yet).
    Arm,
    /// Drive to the goal.
    Start,
    /// Stop in order (ramp down, disable).
    Stop,
    /// Emergency stop, at once, whatever the state.
    Estop,
    /// Leave a fault, once its cause is gone.
    Reset,
    /// Set the goal: `goal X Y [--tolerance M]`, or a queue: `goal --queue X,Y X,Y ...`.
    Goal {
        /// x y, m.
        #[arg(num_args = 2, value_names = ["X", "Y"], allow_negative_numbers = true, required_unless_present = "queue")]
        xy: Vec<f64>,
        /// Goals driven in order, each `X,Y`.
        #[arg(long, num_args = 1.., value_name = "X,Y", allow_hyphen_values = true, conflicts_with = "xy")]
        queue: Vec<String>,
        /// m.
        #[arg(long, default_value_t = 0.02)]
        tolerance: f64,
    },
    /// Drop the goals; a running robot stops in order.
    Cancel,
    /// The cycle latency and each stage's min, p50, p99, max, mean and jitter (σ), since
    /// the gateway started or the last `stats --reset`.
    Stats {
        /// Start a new window after this answer.
        #[arg(long)]
        reset: bool,
    },
}

fn request(command: &CtlCommand) -> Result<Request> {
    Ok(match command {
        CtlCommand::Status => Request::Status,
        CtlCommand::Arm => Request::Arm,
        CtlCommand::Start => Request::Start,
        CtlCommand::Stop => Request::Stop,
        CtlCommand::Estop => Request::EStop,
        CtlCommand::Reset => Request::Reset,
        CtlCommand::Cancel => Request::Cancel,
        CtlCommand::Stats { reset } => Request::Stats { reset: *reset },
        CtlCommand::Goal { xy, queue, tolerance } => {
            let goals = if queue.is_empty() {
                vec![Goal { position: [xy[0], xy[1]], tolerance: *tolerance }]
            } else {
                queue
                    .iter()
                    .map(|p| {
                        let (x, y) = p.split_once(',').with_context(|| format!("--queue {p}: expected X,Y"))?;
                        let v = |s: &str| {
                            s.trim().parse::<f64>().with_context(|| format!("--queue {p}: `{s}` is not a number"))
                        };
                        Ok(Goal { position: [v(x)?, v(y)?], tolerance: *tolerance })
                    })
                    .collect::<Result<_>>()?
            };
            Request::Goal { goals }
        }
    })
}

/// Where the packaged service's control socket is.
const INSTALLED_SOCKET: &str = "/run/flowgate/control.sock";

pub fn run(args: CtlArgs) -> Result<()> {
    let socket = match (&args.socket, &args.config) {
        (Some(s), _) => s.clone(),
        (None, Some(c)) => {
            let rig = RigFile::load(c)?;
            rig.operator.socket.with_context(|| format!("{} has no [operator] socket", c.display()))?
        }
        // The installed service's socket (its unit's RuntimeDirectory, the packaged config's
        // `[operator] socket`).
        (None, None) if Path::new(INSTALLED_SOCKET).exists() => PathBuf::from(INSTALLED_SOCKET),
        (None, None) => bail!(
            "no gateway at {INSTALLED_SOCKET} (the installed service's socket): name one with --socket PATH \
             or --config rig.toml"
        ),
    };
    let req = request(&args.command)?;
    let reply = ControlClient::connect(&socket)?.ask_for(args.vehicle.as_deref(), &req)?;
    if args.json {
        say!("{}", serde_json::to_string(&reply)?);
    } else {
        print_reply(&reply);
    }
    if !reply.ok {
        bail!("refused: {}", reply.error.as_deref().unwrap_or("(no reason given)"));
    }
    Ok(())
}

fn print_reply(reply: &Reply) {
    let Some(s) = &reply.status else {
        if reply.ok {
            say!("ok");
        }
        return;
    };
    say!("state      {}", s.state);
    say!("last stop  {}", s.last_stop.as_deref().unwrap_or("-"));
    let goals: Vec<String> = s.goals.iter().map(|g| format!("({}, {})", g.position[0], g.position[1])).collect();
    say!("goals      {}", if goals.is_empty() { "-".into() } else { goals.join(" then ") });
    match s.pose {
        Some([x, y, heading]) => say!("pose       x {x:.3} m  y {y:.3} m  heading {:.1}°", heading.to_degrees()),
        None => say!("pose       -"),
    }
    for o in &s.obstacles {
        let seen = if o.occluded { "occluded, last seen" } else { "at" };
        say!(
            "obstacle LED {} {seen} ({:.3}, {:.3}) m, velocity ({:.3}, {:.3}) m/s, planning radius {:.3} m",
            o.led,
            o.position[0],
            o.position[1],
            o.velocity[0],
            o.velocity[1],
            o.planning_radius
        );
    }
    let absent: Vec<String> = s.absent.iter().map(|l| format!("LED {l}")).collect();
    if !absent.is_empty() {
        say!("not in view {}", absent.join(", "));
    }
    for v in &s.vehicles {
        say!("{}", vehicle_line(v));
    }
    say!("cycles     {}", s.cycles);
    if let Some(l) = &s.latency_us {
        say!(
            "latency    p50 {:.0} µs  p99 {:.0} µs  max {:.0} µs   (serial read -> CAN write done)",
            l.p50_us,
            l.p99_us,
            l.max_us
        );
    }
    if let Some(stages) = &s.stages {
        let mut table = String::new();
        let _ = write_stage_table(&mut table, stages, "stages (µs) ");
        say_raw!("{table}");
    }
}

/// A vehicle's line of `status`: its state, last stop, goal (or its script) and pose.
fn vehicle_line(v: &flowgate::gateway::core::operator::VehicleStatus) -> String {
    let pose = v.pose.map_or("-".into(), |[x, y, h]| format!("({x:.3}, {y:.3}) m, heading {:.1}°", h.to_degrees()));
    let mut goal = v.goals.first().map_or("-".into(), |g| format!("({}, {})", g.position[0], g.position[1]));
    if let Some(sc) = v.script {
        goal = format!(
            "its script, {:.1} s along, {:.1} mm off (at most {:.1} mm where not held)",
            sc.along,
            sc.error * 1e3,
            sc.largest * 1e3
        );
    }
    format!(
        "vehicle {:<12} {}  last stop {}  goal {goal}  pose {pose}",
        v.name,
        v.state,
        v.last_stop.as_deref().unwrap_or("-")
    )
}
