//! `flowgate record info FILE.mcap`: what a recording holds, as `mcap info` says it: its
//! size and duration, each channel's messages, its chunks' compression, the bytes a cycle
//! takes, and whether it was cut short. Any MCAP file, compressed or not.
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
    }
}
