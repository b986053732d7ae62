//! `flowgate null-gateway` (hidden): the bench's floor as its own process, opened the same
//! way as the gateway (src/lab/bench/null_gateway.rs). Not for users.

use std::io::Write as _;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{anyhow, Result};
use clap::Args;
use flowgate::config::CanUrl;
use flowgate::gateway::shell::realtime::{self, RealtimeSettings};
use flowgate::lab::bench::null_gateway::{serve, READY};

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
    /// Run on this CPU (repeatable), as the gateway's `[realtime] cpus`.
    #[arg(long = "cpu", value_name = "N")]
    cpus: Vec<usize>,
    /// SCHED_FIFO at this priority, as the gateway's `[realtime] fifo_priority`.
    #[arg(long, value_name = "1-99", value_parser = clap::value_parser!(u8).range(1..=99))]
    fifo_priority: Option<u8>,
    /// Lock memory, as the gateway's `[realtime] lock_memory`.
    #[arg(long)]
    lock_memory: bool,
    /// Answer each frame with an RPDO1 to each of these two CiA 402 nodes (LEFT,RIGHT),
    /// as the gateway's CiA 402 backend does.
    #[arg(long, value_name = "LEFT,RIGHT", value_delimiter = ',')]
    cia402_drives: Option<Vec<u8>>,
}

pub fn run(args: NullGatewayArgs) -> Result<()> {
    let can: CanUrl = args.can.parse().map_err(|e: String| anyhow!("--can {}: {e}", args.can))?;
    let spin = (args.spin_us > 0).then(|| Duration::from_micros(args.spin_us));
    let realtime =
        RealtimeSettings { cpus: args.cpus, fifo_priority: args.fifo_priority, lock_memory: args.lock_memory };
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    // On the thread that runs the loop, before it starts, as the gateway does.
    realtime::apply(&realtime)?;
    let drives = match args.cia402_drives.as_deref() {
        None => None,
        Some(&[left, right]) => {
            let node = |n| {
                flowgate_protocol::canopen::NodeId::new(n).ok_or_else(|| anyhow!("--cia402-drives: {n} is not 1-127"))
            };
            Some([node(left)?, node(right)?])
        }
        Some(other) => return Err(anyhow!("--cia402-drives: two node ids, got {other:?}")),
    };
    runtime.block_on(serve(&args.psd, &can, spin, drives, || {
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "{READY}");
        let _ = out.flush();
    }))?;
    Ok(())
}
