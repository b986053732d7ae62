//! `flowgate bench`: gateway-added latency against the wire, sustained rate, CPU and memory.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Short phases (a smoke run of a minute) instead of the full set (about six minutes).
    #[arg(long)]
    quick: bool,
    /// Where to write bench.json.
    #[arg(long, value_name = "DIR", default_value = "out/bench")]
    out: PathBuf,
}

pub fn run(args: BenchArgs) -> Result<()> {
    // (name, frame rate Hz, cycles); two LEDs per frame, so samples/s = 2 x frames/s.
    // One hour at the paper's T = 17 ms is 211,765 cycles.
    let full: &[(&str, f64, u64)] = &[
        ("T=17ms (paper)", 1000.0 / 17.0, 3_000),
        ("1 kHz", 1_000.0, 100_000),
        ("2.5 kHz", 2_500.0, 25_000),
        ("5 kHz", 5_000.0, 50_000),
        ("10 kHz", 10_000.0, 50_000),
        ("12.5 kHz", 12_500.0, 50_000),
        ("1 hour at T=17ms", 5_000.0, 211_765),
    ];
    let quick: &[(&str, f64, u64)] = &[
        ("T=17ms (paper)", 1000.0 / 17.0, 300),
        ("1 kHz", 1_000.0, 10_000),
        ("5 kHz", 5_000.0, 10_000),
        ("10 kHz", 10_000.0, 10_000),
    ];
    let phases = if args.quick { quick } else { full };
    let exe = std::env::current_exe().context("locating the flowgate binary")?;
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let report = runtime.block_on(flowgate::bench::run(&exe, phases, &args.out))?;
    println!("{report}");
    let path = args.out.join("bench.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)?)?;
    println!("wrote {}", path.display());
    Ok(())
}
