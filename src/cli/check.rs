//! `flowgate check --config rig.toml`: the preflight. Moves nothing; prints a PASS/FAIL
//! table and exits non-zero when any line failed.

use crate::cli::say;
use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

#[derive(Args, Debug)]
pub struct CheckArgs {
    /// The rig configuration to check (see rig.example.toml).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
}

/// Runs the check; `Ok(false)` when any line failed.
pub fn run(args: CheckArgs) -> Result<bool> {
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let report = runtime.block_on(flowgate::setup::check::check(&args.config));
    say!("flowgate check: {}", args.config.display());
    say!("{report}");
    Ok(report.failures() == 0)
}
