//! `flowgate record info FILE.mcap`: what a recording holds, as `mcap info` says it: its
//! size and duration, each channel's messages, its chunks' compression, the bytes a cycle
//! takes, and whether it was cut short. Any MCAP file, compressed or not.

use crate::cli::say;
use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, Subcommand};
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
    }
}
