//! The `flowgate` command. Library errors are typed (`thiserror`); this binary edge turns
//! them into messages with `anyhow`. One file per subcommand under `cli/`.

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "flowgate",
    version,
    about = "Steers a mobile robot around moving obstacles: PSD serial in, motor CAN out"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run the simulator and the gateway together over real ptys (no hardware needed).
    Demo(cli::demo::DemoArgs),
    /// Run the gateway on a rig (serial PSD controller, CAN motor boards).
    Run(cli::run::RunArgs),
    /// Measure the gateway: latency against the wire, sustained rate, CPU, memory.
    Bench(cli::bench::BenchArgs),
    /// Run scenarios offline in virtual time: one, all in a folder, or a Monte-Carlo sweep.
    Plan(cli::plan::PlanArgs),
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Command::Demo(args) => cli::demo::run(args),
        Command::Plan(args) => cli::plan::run(args),
        Command::Run(args) => cli::run::run(args),
        Command::Bench(args) => cli::bench::run(args),
    }
}
