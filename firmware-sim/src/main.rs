//! `flowgate-sim`: the simulated rig as a program. It prints the paths of its endpoints,
//! runs until SIGINT/SIGTERM, then writes the world's truth and removes its links.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use flowgate_protocol::motor::NodeId;
use flowgate_sim::camera::CameraModel;
use flowgate_sim::faults::FaultPlan;
use flowgate_sim::rig::{self, CanEndpoint, RigConfig, SerialEndpoint};
use flowgate_sim::scenario::SimScenario;

#[derive(Parser, Debug)]
#[command(
    name = "flowgate-sim",
    version,
    about = "The simulated flowgate rig: PSD controller on a serial line, motor boards or drives on CAN"
)]
struct Args {
    /// The world: a scenario file (robot, obstacles, lane; a fleet's `[[vehicles]]` each get
    /// their LEDs after the obstacles' and their motors after the robot's, printed at start).
    #[arg(long, value_name = "FILE")]
    scenario: PathBuf,
    /// Make a stable symlink to the PSD controller's pty.
    #[arg(long, value_name = "PATH", conflicts_with = "psd_device")]
    psd_link: Option<PathBuf>,
    /// Serve the PSD controller on this serial device instead of a new pty.
    #[arg(long, value_name = "DEVICE")]
    psd_device: Option<PathBuf>,
    /// Baud rate for --psd-device.
    #[arg(long, default_value_t = 921_600)]
    baud: u32,
    /// The motor board's CAN endpoint: `slcan-pty` or `socketcan:IFACE`.
    #[arg(long, default_value = "slcan-pty")]
    can: String,
    /// Make a stable symlink to the SLCAN adapter's pty.
    #[arg(long, value_name = "PATH")]
    can_link: Option<PathBuf>,
    /// The motor board's node id (1-15).
    #[arg(long, default_value_t = 1)]
    node: u8,
    /// The motors: one PCL-80K-like board (`pcl80k`, at --node) or one CiA 402 drive a
    /// wheel (`cia402`, the left at node 1, the right at node 2).
    #[arg(long, default_value = "pcl80k", value_parser = ["pcl80k", "cia402"])]
    drive: String,
    /// A camera model (TOML: homography, k1, counts); default: the standard one.
    #[arg(long, value_name = "FILE")]
    camera: Option<PathBuf>,
    /// PSD position noise, counts (σ).
    #[arg(long, default_value_t = 1.0)]
    noise: f64,
    /// Faults from a TOML file (the keys of `[faults]`), instead of the scenario's.
    #[arg(long, value_name = "FILE")]
    faults: Option<PathBuf>,
    /// One fault setting, `key=value` (repeatable), e.g. `--fault serial_drop=0.01`.
    #[arg(long = "fault", value_name = "KEY=VALUE")]
    fault: Vec<String>,
    /// Hold this LED as a calibration wand: each line on stdin, `X Y` (floor metres), puts it
    /// there; `off` takes it out of sight (for `flowgate calibrate`).
    #[arg(long, value_name = "LED")]
    wand: Option<u8>,
    /// Write the world's truth here at exit (`.json`, or CSV otherwise).
    #[arg(long, value_name = "FILE")]
    truth: Option<PathBuf>,
}

/// Errors as one line on stderr, each cause once, with no backtrace block; log colours only
/// on a terminal.
fn main() -> std::process::ExitCode {
    use std::io::IsTerminal as _;
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .init();
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            let mut text = e.to_string();
            for cause in e.chain().skip(1).map(ToString::to_string) {
                if !text.contains(&cause) {
                    text = format!("{text}: {cause}");
                }
            }
            eprintln!("Error: {text}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> Result<()> {
    let args = Args::parse();
    let mut config = RigConfig::new(SimScenario::load(&args.scenario)?);
    config.psd = match args.psd_device {
        Some(path) => SerialEndpoint::Device { path, baud: args.baud },
        None => SerialEndpoint::Pty { link: args.psd_link },
    };
    config.can = args.can.parse::<CanEndpoint>().map_err(anyhow::Error::msg)?;
    if let (CanEndpoint::SlcanPty { link }, Some(l)) = (&mut config.can, args.can_link) {
        *link = Some(l);
    }
    config.node = NodeId::new(args.node).with_context(|| format!("--node {}: node ids are 1-15", args.node))?;
    if args.drive == "cia402" {
        let node = |n| flowgate_protocol::canopen::NodeId::new(n).context("node ids are 1-127");
        config.cia402 = Some([node(1)?, node(2)?]);
    }
    if let Some(path) = args.camera {
        let text = flowgate_sim::scenario::read_text(&path, flowgate_sim::scenario::MAX_FILE_BYTES)
            .with_context(|| format!("reading {}", path.display()))?;
        config.camera = toml::from_str::<CameraModel>(&text).with_context(|| format!("camera {}", path.display()))?;
    }
    config.noise_counts = args.noise;
    let base = match args.faults {
        Some(path) => {
            let text = flowgate_sim::scenario::read_text(&path, flowgate_sim::scenario::MAX_FILE_BYTES)
                .with_context(|| format!("reading {}", path.display()))?;
            toml::from_str::<FaultPlan>(&text).with_context(|| format!("faults {}", path.display()))?
        }
        None => config.faults.clone(),
    };
    config.faults = base.with_settings(&args.fault).map_err(anyhow::Error::msg)?;

    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    runtime.block_on(async move {
        // Handlers first: a supervisor may signal as soon as the endpoints are announced.
        use tokio::signal::unix::{signal, SignalKind};
        let mut interrupt = signal(SignalKind::interrupt())?;
        let mut term = signal(SignalKind::terminate())?;
        let handle = rig::start(config).await?;
        announce(&handle);
        let (wand_tx, mut wand_rx) = tokio::sync::mpsc::channel::<Option<flowgate_sim::Point>>(4);
        if let Some(led) = args.wand {
            handle.place_wand(led, None);
            std::thread::spawn(move || {
                for line in std::io::stdin().lines().map_while(Result::ok) {
                    match parse_wand(&line) {
                        Ok(at) => {
                            if wand_tx.blocking_send(at).is_err() {
                                break;
                            }
                        }
                        Err(why) => eprintln!("wand: {why}"),
                    }
                }
            });
        }
        loop {
            tokio::select! {
                _ = interrupt.recv() => break,
                _ = term.recv() => break,
                Some(at) = wand_rx.recv() => {
                    if let Some(led) = args.wand {
                        handle.place_wand(led, at);
                        println!("wand: LED {led} at {}", at.map_or("off".into(), |p| format!("{} {}", p.re, p.im)));
                    }
                }
            }
        }
        let truth = handle.stop().await;
        if let Some(path) = args.truth {
            truth.write(&path).with_context(|| format!("writing truth to {}", path.display()))?;
            eprintln!("truth written to {}", path.display());
        }
        Ok(())
    })
}

/// The endpoints, and a fleet's wiring: what a host opens and addresses.
fn announce(handle: &rig::RigHandle) {
    println!("psd: {}", handle.psd_path.display());
    if let Some(can) = &handle.can_path {
        println!("can: slcan {}", can.display());
    }
    if handle.vehicles.len() > 1 {
        for v in &handle.vehicles {
            println!("vehicle {}: LEDs {} and {}, {}", v.name, v.front_led, v.rear_led, v.motors.describe());
        }
    }
}

/// A wand line: `X Y` in metres, or `off`.
fn parse_wand(line: &str) -> Result<Option<flowgate_sim::Point>, String> {
    let line = line.trim();
    if line == "off" {
        return Ok(None);
    }
    let v: Vec<f64> =
        line.split_whitespace().map(str::parse).collect::<Result<_, _>>().map_err(|e| format!("`{line}`: {e}"))?;
    match v[..] {
        [x, y] if x.is_finite() && y.is_finite() => Ok(Some(flowgate_sim::Point::new(x, y))),
        _ => Err(format!("`{line}`: expected `X Y` (metres) or `off`")),
    }
}
