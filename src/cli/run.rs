//! `flowgate run --config rig.toml`: the gateway service.
//!
//! It starts idle and moves nothing until an operator arms and starts it over the control
//! socket (`flowgate ctl`); `--arm` arms and starts towards the config's `[goal]` at once
//! (the demo and tests; never a service). SIGINT/SIGTERM stop the robot in order and end
//! the run. There is no automatic restart. State changes are printed as `state: ...`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use flowgate::config::RigFile;
use flowgate::gateway;
use flowgate::gateway::core::Progress;
use flowgate::gateway::shell::{telemetry, Controls};
use tokio::signal::unix::{signal, SignalKind};
use tokio::sync::watch;

#[derive(Args, Debug)]
pub struct RunArgs {
    /// The rig configuration (see rig.example.toml).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Arm and start towards the config's [goal] as soon as the PSD controller streams,
    /// without an operator. For the demo and tests only: a service never uses it.
    #[arg(long)]
    arm: bool,
    /// Record the run to this MCAP file (every input the core takes, what it sends, each
    /// cycle's scene and timing; `flowgate replay FILE` plays it back). Overrides the
    /// config's `telemetry.record`.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Serve the live view here (read-only; `--view` alone: 127.0.0.1:8080). Overrides the
    /// config's `operator.view`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8080")]
    view: Option<std::net::SocketAddr>,
}

pub fn run(args: RunArgs) -> Result<()> {
    let mut config = RigFile::read(&args.config)?;
    if let Some(path) = &args.record {
        config.telemetry.record = Some(path.clone());
    }
    if let Some(addr) = args.view {
        config.operator.view = Some(addr);
    }
    let mut rig = config.rig(&args.config.display().to_string())?;
    // A script cut where it would leave the arena is said before anything moves.
    for note in rig.vehicles.iter().filter_map(|v| v.script.as_ref()?.cut.as_deref()) {
        eprintln!("note: {note}");
    }
    if args.arm && rig.goal.is_none() {
        anyhow::bail!("--arm needs a [goal] in {}", args.config.display());
    }
    let Some(out_dir) = rig.telemetry.out_dir.clone() else { return serve(rig, args.arm) };
    let previous = std::fs::read_link(out_dir.join("latest")).ok();
    let dir = telemetry::run_directory(&out_dir, std::time::SystemTime::now())
        .with_context(|| format!("telemetry.out_dir = {}: making this run's directory", out_dir.display()))?;
    rig.telemetry.out_dir = Some(dir.clone());
    let served = serve(rig, args.arm);
    if served.is_err() {
        // A run that failed before writing leaves no empty folder, and `latest` as it was.
        telemetry::abandon_run_directory(&out_dir, &dir, previous.as_deref());
    }
    served
}

/// Run the gateway until a signal or its end, printing its states and its report.
fn serve(rig: flowgate::config::Rig, arm: bool) -> Result<()> {
    // The gateway is one loop: a single-threaded runtime keeps its wake-ups on one thread
    // (the telemetry writer has its own blocking thread).
    let telemetry_dir = rig.telemetry.out_dir.clone();
    let recording = rig.telemetry.record.clone();
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    runtime.block_on(async move {
        let mut interrupt = signal(SignalKind::interrupt())?;
        let mut terminate = signal(SignalKind::terminate())?;
        let (stop_tx, stop_rx) = watch::channel(false);
        let (progress_tx, mut progress_rx) = watch::channel(Progress::default());
        let mut gateway = tokio::spawn(gateway::shell::run(rig, Controls::new(stop_rx, arm), Some(progress_tx)));
        let mut last_state = None;
        let report = loop {
            tokio::select! {
                r = &mut gateway => break r??,
                _ = interrupt.recv() => { let _ = stop_tx.send(true); }
                _ = terminate.recv() => { let _ = stop_tx.send(true); }
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
        if let Some(dir) = &telemetry_dir {
            report.write_json(dir).with_context(|| format!("writing {}/report.json", dir.display()))?;
            say(&format!("telemetry and report.json in {}", dir.display()));
        }
        if let Some(path) = &recording {
            say(&format!("recording in {} (flowgate replay {} plays it back)", path.display(), path.display()));
        }
        Ok(())
    })
}

/// Print a line; a closed stdout must never take the gateway down with it (unlike the
/// other commands' `say!`, which end at a closed stdout).
fn say(line: &str) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stdout().lock(), "{line}");
}
