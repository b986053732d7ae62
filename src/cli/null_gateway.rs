//! `flowgate null-gateway` (hidden): the bench's floor as its own process, opened the same
//! way as the gateway (src/lab/bench/null_gateway.rs). Not for users.

use std::io::Write as _;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{anyhow, Result};
use clap::Args;
use flowgate::lab::bench::null_gateway::{serve, READY};
use flowgate::link::CanUrl;

#[derive(Args, Debug)]
pub struct NullGatewayArgs {
    /// The PSD line (a pty).
    #[arg(long, value_name = "PATH")]
    psd: PathBuf,
    /// The CAN endpoint, as in a rig config (`slcan:/dev/pts/N?bitrate=...`, `socketcan:vcan0`).
    #[arg(long, value_name = "ENDPOINT")]
    can: String,
    /// Poll for frames this long either side of when each is due, as the gateway's
    /// low-latency mode does (0: sleep between frames).
    #[arg(long, value_name = "US", default_value_t = 0)]
    spin_us: u64,
}

pub fn run(args: NullGatewayArgs) -> Result<()> {
    let can: CanUrl = args.can.parse().map_err(|e: String| anyhow!("--can {}: {e}", args.can))?;
    let spin = (args.spin_us > 0).then(|| Duration::from_micros(args.spin_us));
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    runtime.block_on(serve(&args.psd, &can, spin, || {
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "{READY}");
        let _ = out.flush();
    }))?;
    Ok(())
}
