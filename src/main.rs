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
    /// Run the simulator and the gateway together (no hardware needed).
    Demo,
    /// Run scenarios offline in virtual time: one, all in a folder, or a Monte-Carlo sweep.
    Plan(cli::plan::PlanArgs),
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Demo => cli::demo::run(),
        Command::Plan(args) => cli::plan::run(args),
    }
}
