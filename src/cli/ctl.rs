//! `flowgate ctl`: the operator's commands, sent to a running gateway's control socket.
//!
//! One JSON request per line, one reply per line (src/gateway/core/operator.rs). The exit status
//! is non-zero when the gateway refuses, with its reason.

use crate::cli::{say, say_raw};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use flowgate::config::GatewayConfig;
use flowgate::gateway::core::operator::{Goal, Request};
use flowgate::gateway::shell::telemetry::{write_stage_table, StageSummary};
use serde::Deserialize as _;

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
            let rig = GatewayConfig::load(c)?;
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
    let reply = exchange(&socket, &req)?;
    let value: serde_json::Value = serde_json::from_str(&reply).context("the gateway's reply is not JSON")?;
    if args.json {
        say!("{}", reply.trim_end());
    } else {
        print_reply(&value);
    }
    if value["ok"] != serde_json::Value::Bool(true) {
        bail!("refused: {}", value["error"].as_str().unwrap_or("(no reason given)"));
    }
    Ok(())
}

/// How long `ctl` waits for a reply: longer than the gateway's own answer deadline
/// (`control_socket::ANSWER_DEADLINE`), which answers every request it takes in time.
const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

/// One request, one reply line; every way it can fail said in words.
fn exchange(socket: &Path, req: &Request) -> Result<String> {
    let mut stream = UnixStream::connect(socket)
        .with_context(|| format!("control socket {} (is the gateway running? may you use it?)", socket.display()))?;
    stream.set_read_timeout(Some(REPLY_TIMEOUT))?;
    stream.set_write_timeout(Some(REPLY_TIMEOUT))?;
    let mut line = serde_json::to_string(req)?;
    line.push('\n');
    stream.write_all(line.as_bytes()).with_context(|| format!("sending the request to {}", socket.display()))?;
    let mut reply = String::new();
    match BufReader::new(&stream).read_line(&mut reply) {
        Ok(0) => bail!(
            "the gateway closed the connection without answering (shutting down, or it closed this connection to \
             make room for another): check with `flowgate ctl status`"
        ),
        Ok(_) => Ok(reply),
        Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
            let fate = if req.always_obeyed() {
                "a stop is obeyed whenever the gateway takes it"
            } else {
                "the request expires unanswered and is not carried out"
            };
            bail!(
                "no reply within {} s: the gateway is stalled or gone ({fate}); check with `flowgate ctl status`",
                REPLY_TIMEOUT.as_secs()
            )
        }
        Err(e) => Err(e).context("reading the gateway's reply"),
    }
}

fn print_reply(v: &serde_json::Value) {
    let Some(s) = v.get("status").filter(|s| !s.is_null()) else {
        if v["ok"] == serde_json::Value::Bool(true) {
            say!("ok");
        }
        return;
    };
    say!("state      {}", s["state"].as_str().unwrap_or("?"));
    say!("last stop  {}", s["last_stop"].as_str().unwrap_or("-"));
    let goals: Vec<String> = s["goals"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|g| format!("({}, {})", g["position"][0], g["position"][1]))
        .collect();
    say!("goals      {}", if goals.is_empty() { "-".into() } else { goals.join(" then ") });
    match s["pose"].as_array() {
        Some(p) => say!(
            "pose       x {:.3} m  y {:.3} m  heading {:.1}°",
            p[0].as_f64().unwrap_or(f64::NAN),
            p[1].as_f64().unwrap_or(f64::NAN),
            p[2].as_f64().unwrap_or(f64::NAN).to_degrees()
        ),
        None => say!("pose       -"),
    }
    for o in s["obstacles"].as_array().into_iter().flatten() {
        let seen = if o["occluded"].as_bool() == Some(true) { "occluded, last seen" } else { "at" };
        say!(
            "obstacle LED {} {seen} ({:.3}, {:.3}) m, velocity ({:.3}, {:.3}) m/s, planning radius {:.3} m",
            o["led"],
            o["position"][0].as_f64().unwrap_or(f64::NAN),
            o["position"][1].as_f64().unwrap_or(f64::NAN),
            o["velocity"][0].as_f64().unwrap_or(f64::NAN),
            o["velocity"][1].as_f64().unwrap_or(f64::NAN),
            o["planning_radius"].as_f64().unwrap_or(f64::NAN)
        );
    }
    let absent: Vec<String> = s["absent"].as_array().into_iter().flatten().map(|l| format!("LED {l}")).collect();
    if !absent.is_empty() {
        say!("not in view {}", absent.join(", "));
    }
    say!("cycles     {}", s["cycles"]);
    if let Some(l) = s.get("latency_us").filter(|l| !l.is_null()) {
        say!(
            "latency    p50 {:.0} µs  p99 {:.0} µs  max {:.0} µs   (serial read -> CAN write done)",
            l["p50_us"].as_f64().unwrap_or(f64::NAN),
            l["p99_us"].as_f64().unwrap_or(f64::NAN),
            l["max_us"].as_f64().unwrap_or(f64::NAN)
        );
    }
    let stages = s.get("stages").and_then(|v| Vec::<StageSummary>::deserialize(v).ok());
    if let Some(stages) = stages {
        let mut table = String::new();
        let _ = write_stage_table(&mut table, &stages, "stages (µs) ");
        say_raw!("{table}");
    }
}
