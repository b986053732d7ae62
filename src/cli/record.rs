//! `flowgate record info FILE.mcap`: what a recording holds, as `mcap info` says it: its
//! size and duration, each channel's messages, its chunks' compression, the bytes a cycle
//! takes, and whether it was cut short. Any MCAP file, compressed or not.
//!
//! `flowgate record export --ros2 DIR FILE.mcap`: a recording as a ROS 2 bag.
//!
//! `flowgate record events DIR`: a run's durable event log (`events.jsonl`): state changes,
//! operator requests and the gateway's notices, its warnings and errors among them.

use crate::cli::say;
use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, Subcommand};
use flowgate::gateway::shell::telemetry::read_events;
use flowgate::replay::RecordingInfo;

#[derive(Args, Debug)]
pub struct RecordArgs {
    #[command(subcommand)]
    command: RecordCommand,
}

#[derive(Subcommand, Debug)]
enum RecordCommand {
    /// Summarise a recording: channels, messages, duration, compression, bytes a cycle.
    Info {
        /// The recording.
        file: PathBuf,
        /// Print it as JSON.
        #[arg(long)]
        json: bool,
    },
    /// A run's events (its telemetry directory, or its events.jsonl): state changes,
    /// requests, warnings and errors, each with its time.
    Events {
        /// The run's telemetry directory, or its events.jsonl.
        path: PathBuf,
        /// Only events at this level or above.
        #[arg(long, value_enum, default_value = "info")]
        level: EventLevel,
        /// Print them as JSON lines, fields and all.
        #[arg(long)]
        json: bool,
    },
    /// Turn a recording into a ROS 2 bag (rosbag2: MCAP storage, CDR, metadata.yaml) with
    /// the topics the ROS 2 node publishes: /odom and /tf every cycle, ~/obstacles and
    /// ~/path at [ros2] publish_hz, /diagnostics once a second.
    Export {
        /// The recording.
        file: PathBuf,
        /// The bag's folder (new): `ros2 bag play DIR` plays it.
        #[arg(long, value_name = "DIR")]
        ros2: PathBuf,
    },
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum EventLevel {
    Info,
    Warning,
    Error,
}

pub fn run(args: RecordArgs) -> Result<bool> {
    match args.command {
        RecordCommand::Info { file, json } => {
            let info = RecordingInfo::read(&file)?;
            if json {
                say!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                say!("recording    {}", file.display());
                say!("{info}");
            }
            Ok(info.truncated.is_none())
        }
        RecordCommand::Events { path, level, json } => {
            let events = read_events(&path)?;
            let least = level as u8;
            for e in events.iter().filter(|e| e.rank() >= least) {
                if json {
                    say!("{}", serde_json::to_string(e)?);
                } else {
                    say!("{:>10.3} s  {:<7}  {:<21}  {}", e.t_s, e.level, e.kind, e.text);
                }
            }
            Ok(true)
        }
        RecordCommand::Export { file, ros2 } => export_ros2(&file, &ros2),
    }
}

#[cfg(feature = "ros2")]
fn export_ros2(file: &std::path::Path, dir: &std::path::Path) -> Result<bool> {
    let recording = flowgate::replay::Recording::read(file)?;
    let bag = flowgate::replay::ros2_bag::export(&recording, dir)?;
    if let Some(why) = &recording.truncated {
        say!(
            "{} is cut short at {:.3} s of its run ({why}): the bag holds what came before",
            file.display(),
            recording.duration()
        );
    }
    let total: u64 = bag.messages.values().sum();
    let seconds = (bag.end_ns - bag.start_ns) as f64 * 1e-9;
    say!("rosbag2 {} ({total} messages over {seconds:.1} s, MCAP storage, CDR):", bag.dir.display());
    for (topic, n) in &bag.messages {
        say!("  {topic:<24} {n:>7}");
    }
    say!("  ros2 bag play {} plays it", bag.dir.display());
    Ok(recording.truncated.is_none())
}

#[cfg(not(feature = "ros2"))]
fn export_ros2(_: &std::path::Path, _: &std::path::Path) -> Result<bool> {
    anyhow::bail!("this flowgate was built without ROS 2 (the `ros2` feature): it cannot write a ROS 2 bag")
}
