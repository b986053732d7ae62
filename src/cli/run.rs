//! `flowgate run --config rig.toml`: the gateway service.
//!
//! SIGINT/SIGTERM stop the robot in order and end the run; SIGUSR1 re-arms after a stop or
//! fault (there is no automatic restart). State changes are printed as `state: NAME`.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use flowgate::config::GatewayConfig;
use flowgate::gateway::{self, Controls, Progress};
use tokio::signal::unix::{signal, SignalKind};
use tokio::sync::{mpsc, watch};

#[derive(Args, Debug)]
pub struct RunArgs {
    /// The rig configuration (see rig.example.toml).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
}

pub fn run(args: RunArgs) -> Result<()> {
    let rig = GatewayConfig::load(&args.config)?;
    // The gateway is one loop: a single-threaded runtime keeps its wake-ups on one thread
    // (the telemetry writer has its own blocking thread).
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    runtime.block_on(async move {
        let mut interrupt = signal(SignalKind::interrupt())?;
        let mut terminate = signal(SignalKind::terminate())?;
        let mut user1 = signal(SignalKind::user_defined1())?;
        let (stop_tx, stop_rx) = watch::channel(false);
        let (arm_tx, arm_rx) = mpsc::channel(4);
        let (progress_tx, mut progress_rx) = watch::channel(Progress::default());
        let mut gateway =
            tokio::spawn(gateway::run(rig, Controls { shutdown: stop_rx, arm: arm_rx }, Some(progress_tx)));
        let mut last_state = None;
        let report = loop {
            tokio::select! {
                r = &mut gateway => break r??,
                _ = interrupt.recv() => { let _ = stop_tx.send(true); }
                _ = terminate.recv() => { let _ = stop_tx.send(true); }
                _ = user1.recv() => { let _ = arm_tx.try_send(()); }
                changed = progress_rx.changed() => {
                    if changed.is_ok() {
                        let state = progress_rx.borrow().state;
                        if last_state != Some(state) {
                            say(&format!("state: {state}"));
                            last_state = Some(state);
                        }
                    }
                }
            }
        };
        say(&report.to_string());
        if let Some(csv) = &report.files.cycles_csv {
            say(&format!("telemetry in {}", csv.parent().map_or_else(String::new, |p| p.display().to_string())));
        }
        Ok(())
    })
}

/// Print a line; a closed stdout must never take the gateway down with it.
fn say(line: &str) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stdout().lock(), "{line}");
}
