//! `flowgate bench`: gateway-added latency against the wire, sustained rate, CPU and memory.

use crate::cli::say;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use flowgate::gateway::shell::realtime::RealtimeSettings;
use flowgate::lab::bench::{Mode, PhaseSpec, Transport};

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Short phases (a smoke run of a minute) instead of the full set (about seven minutes).
    #[arg(long)]
    quick: bool,
    /// The CAN side: an SLCAN adapter on a pty (`slcan-pty`, the default) or a SocketCAN
    /// interface (`socketcan:vcan0`; see scripts/vcan-vm on machines without CAN).
    #[arg(long, value_name = "ENDPOINT", default_value = "slcan-pty")]
    can: String,
    /// Cycles of the paper's T = 17 ms phase (3000 by default, 51 s; 100000 takes 28 minutes,
    /// twice that with its floor).
    #[arg(long, value_name = "N")]
    paper_cycles: Option<u64>,
    /// The low-latency window for the paper's rate (`[realtime] spin_us`): that phase also
    /// runs through a gateway in that mode, in the same seconds (0: not).
    #[arg(long, value_name = "US", default_value_t = 1000)]
    spin_us: u32,
    /// The real-time row at the paper's rate: a gateway (and its null gateway) on this CPU
    /// with SCHED_FIFO at --fifo-priority and locked memory, in the same seconds.
    #[arg(long, value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u16).range(0..rustix::thread::CpuSet::MAX_CPU as i64))]
    rt_cpu: u16,
    /// SCHED_FIFO priority of the real-time row (0: no real-time row).
    #[arg(long, value_name = "0-99", default_value_t = 50, value_parser = clap::value_parser!(u8).range(0..=99))]
    fifo_priority: u8,
    /// Leave out the rows with an MCAP recording on (`--record`: at the paper's rate and at
    /// 1 kHz, where its CPU shows), and with the live view served too (`--view`).
    #[arg(long)]
    no_recording_row: bool,
    /// Leave out the rows with CiA 402 drives (two RPDOs a cycle, at the paper's rate and
    /// at 1 kHz: the latency to the second RPDO beside the board's velocity frame).
    #[arg(long)]
    no_cia402_row: bool,
    /// Leave out the row with the ROS 2 node on (at the paper's rate and at 1 kHz).
    #[arg(long)]
    no_ros2_row: bool,
    /// Where to write bench.json.
    #[arg(long, value_name = "DIR", default_value = "out/bench")]
    out: PathBuf,
}

fn phase(name: &'static str, frame_rate_hz: f64, cycles: u64) -> PhaseSpec {
    PhaseSpec { name, frame_rate_hz, cycles, floor: true, also: Vec::new() }
}

/// Two LEDs a frame, so samples/s = 2 x frames/s. The latency phases above the paper's rate
/// have 10^5 cycles; the last phase is one hour's worth of the paper's T = 17 ms cycles (211,765),
/// played at 5 kHz, for memory.
fn full() -> Vec<PhaseSpec> {
    vec![
        phase("T=17ms (paper)", 1000.0 / 17.0, 3_000),
        phase("1 kHz", 1_000.0, 100_000),
        phase("5 kHz", 5_000.0, 100_000),
        phase("10 kHz", 10_000.0, 100_000),
        phase("12.5 kHz", 12_500.0, 100_000),
        phase("20 kHz", 20_000.0, 100_000),
        PhaseSpec { floor: false, ..phase("1 hour at T=17ms", 5_000.0, 211_765) },
    ]
}

fn quick() -> Vec<PhaseSpec> {
    vec![
        phase("T=17ms (paper)", 1000.0 / 17.0, 300),
        phase("1 kHz", 1_000.0, 10_000),
        phase("5 kHz", 5_000.0, 10_000),
        phase("10 kHz", 10_000.0, 10_000),
    ]
}

pub fn run(args: BenchArgs) -> Result<()> {
    let transport = match args.can.as_str() {
        "slcan-pty" => Transport::SlcanPty,
        other => match other.strip_prefix("socketcan:") {
            Some(interface) if !interface.is_empty() => Transport::SocketCan { interface: interface.to_string() },
            _ => bail!("--can {other}: expected slcan-pty or socketcan:IFACE"),
        },
    };
    let mut phases = if args.quick { quick() } else { full() };
    if let Some(n) = args.paper_cycles {
        if n == 0 {
            bail!("--paper-cycles must be positive");
        }
        phases[0].cycles = n;
    }
    if args.spin_us > 30_000 {
        bail!("--spin-us {}: at most 30000 µs (the window, twice it, must fit in a frame)", args.spin_us);
    }
    // The paper's rate, with the low-latency mode and the real-time settings beside it.
    if args.spin_us > 0 {
        phases[0].also.push(Mode { spin_us: args.spin_us, ..Mode::default() });
        phases[0].also.push(Mode { spin_us: args.spin_us, warm_up: true, ..Mode::default() });
    }
    if args.fifo_priority > 0 {
        let realtime = RealtimeSettings {
            cpus: vec![usize::from(args.rt_cpu)],
            fifo_priority: Some(args.fifo_priority),
            lock_memory: true,
        };
        phases[0].also.push(Mode { realtime, ..Mode::default() });
    }
    if !args.no_recording_row {
        phases[0].also.push(Mode { record: true, ..Mode::default() });
        phases[0].also.push(Mode { record: true, view: true, ..Mode::default() });
        phases[1].also.push(Mode { record: true, ..Mode::default() });
    }
    if !args.no_cia402_row {
        phases[0].also.push(Mode { cia402: true, ..Mode::default() });
        phases[1].also.push(Mode { cia402: true, ..Mode::default() });
    }
    if !args.no_ros2_row && cfg!(feature = "ros2") {
        phases[0].also.push(Mode { ros2: true, ..Mode::default() });
        phases[1].also.push(Mode { ros2: true, ..Mode::default() });
    }
    let names: Vec<&str> = phases.iter().map(|p| p.name).collect();
    say!("bench: phases {} ({}), bench.json to {}", names.join(", "), args.can, args.out.display());
    let exe = std::env::current_exe().context("locating the flowgate binary")?;
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let report = runtime.block_on(flowgate::lab::bench::run(&exe, &transport, &phases, &args.out))?;
    say!("{report}");
    let path = args.out.join("bench.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)?)?;
    say!("wrote {}", path.display());
    Ok(())
}
