//! The `flowgate` command. Library errors are typed (`thiserror`); this binary edge turns
//! them into messages with `anyhow`. One file per subcommand under `cli/`.

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "flowgate",
    version = concat!(env!("CARGO_PKG_VERSION"), " (", env!("FLOWGATE_COMMIT"), ")"),
    about = "Steers a mobile robot around moving obstacles: PSD serial in, motor CAN out"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run the simulator and the gateway together over real ptys (no hardware needed).
    #[cfg(feature = "lab")]
    Demo(cli::demo::DemoArgs),
    /// Preflight: check the config, the PSD controller and the motor board without moving
    /// anything. Exits non-zero when any check fails.
    Check(cli::check::CheckArgs),
    /// Calibrate the camera: an LED at known floor points, the fit written into rig.toml.
    Calibrate(cli::calibrate::CalibrateArgs),
    /// Run the gateway on a rig (serial PSD controller, CAN motor boards). Starts idle.
    Run(cli::run::RunArgs),
    /// Play a recording back through the gateway core: the same CAN frames, byte for byte;
    /// or a what-if with another configuration (--config, --set KEY=VALUE).
    Replay(cli::replay::ReplayArgs),
    /// Look into a recording: `flowgate record info FILE.mcap`.
    Record(cli::record::RecordArgs),
    /// Operate a running gateway: status, arm, start, stop, estop, reset, goal, cancel.
    Ctl(cli::ctl::CtlArgs),
    /// Measure the gateway: latency against the wire, sustained rate, CPU, memory.
    #[cfg(feature = "lab")]
    Bench(cli::bench::BenchArgs),
    /// Run scenarios in virtual time (the whole stack, or --planner-only): one, all in a
    /// folder, or a Monte-Carlo sweep.
    #[cfg(feature = "lab")]
    Plan(cli::plan::PlanArgs),
    /// The bench's floor: a gateway that does no work, as its own process.
    #[cfg(feature = "lab")]
    #[command(hide = true)]
    NullGateway(cli::null_gateway::NullGatewayArgs),
}

/// An error as one line: each cause once (the library's messages already name theirs).
fn one_line(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !text.contains(&c) {
            text.push_str(": ");
            text.push_str(&c);
        }
    }
    text
}

fn main() -> std::process::ExitCode {
    match run() {
        Ok(true) => std::process::ExitCode::SUCCESS,
        // The command ran and said why (a failed preflight): no error line to add.
        Ok(false) => std::process::ExitCode::FAILURE,
        Err(e) => {
            eprintln!("Error: {}", one_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// `Ok(false)`: the command ran and reported a failure itself.
fn run() -> Result<bool> {
    cli::logging::init();
    let cli = Cli::parse();
    let done = |r: Result<()>| r.map(|()| true);
    match cli.command {
        Command::Check(args) => cli::check::run(args),
        Command::Calibrate(args) => done(cli::calibrate::run(args)),
        Command::Replay(args) => cli::replay::run(args),
        Command::Record(args) => cli::record::run(args),
        #[cfg(feature = "lab")]
        Command::Demo(args) => done(cli::demo::run(args)),
        #[cfg(feature = "lab")]
        Command::Plan(args) => done(cli::plan::run(args)),
        Command::Run(args) => done(cli::run::run(args)),
        Command::Ctl(args) => done(cli::ctl::run(args)),
        #[cfg(feature = "lab")]
        Command::Bench(args) => done(cli::bench::run(args)),
        #[cfg(feature = "lab")]
        Command::NullGateway(args) => done(cli::null_gateway::run(args)),
    }
}
