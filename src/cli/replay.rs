//! `flowgate replay FILE.mcap`: a recorded run through the gateway core again, in virtual
//! time. With the recorded configuration it must ask for the same CAN frames, byte for byte
//! (exit status 1 if not, and for a recording cut short, whose prefix it replays); with `--config` or `--set` it is a what-if, and reports how the
//! commands and the paths they drive differ (and draws them).

use crate::cli::{say, say_raw};
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use flowgate::config::RigFile;
use flowgate::replay::{self, Recording};

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The recording (`flowgate run --record FILE.mcap`, `flowgate demo --record`).
    recording: PathBuf,
    /// A what-if: replay with this configuration instead of the recorded one.
    #[arg(long, value_name = "FILE", conflicts_with = "set")]
    config: Option<PathBuf>,
    /// A what-if: change one key of the recorded configuration (dotted, TOML value), e.g.
    /// `--set planner.kc=0.2`. Repeatable.
    #[arg(long, value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Where a what-if draws both paths (default: beside the recording, `NAME-whatif.svg`).
    #[arg(long, value_name = "FILE")]
    svg: Option<PathBuf>,
    /// Print the recorded configuration (TOML) and stop: the start of a `--config` what-if.
    #[arg(long)]
    print_config: bool,
}

/// `Ok(false)`: a replay with the recorded configuration did not reproduce the run.
pub fn run(args: ReplayArgs) -> Result<bool> {
    let recording = Recording::read(&args.recording)?;
    if args.print_config {
        say_raw!("{}", recording.config_toml);
        return Ok(true);
    }
    say!(
        "recording    {}: {} inputs over {:.1} s",
        args.recording.display(),
        recording.inputs.len(),
        recording.duration()
    );
    say!("             {}", completeness(&recording));
    if recording.inputs.is_empty() {
        say!("             no inputs: nothing to replay");
        return Ok(false);
    }
    let config = match &args.config {
        Some(path) => RigFile::read(path)?,
        None if args.set.is_empty() => return verify(&recording),
        None => {
            let text = replay::apply_sets(&recording.config_toml, &args.set)?;
            RigFile::from_toml(&text, "the recorded configuration with --set")?
        }
    };
    let title = match &args.config {
        Some(p) => format!("what-if: {}", p.display()),
        None => format!("what-if: {}", args.set.join(", ")),
    };
    let what_if = recording.what_if(config.rig("the what-if configuration")?, &title)?;
    say_replayed(&what_if.replayed, recording.duration());
    say_diff(&what_if.diff);
    let svg_path = args.svg.unwrap_or_else(|| {
        let stem = args.recording.file_stem().map_or("replay".into(), |s| s.to_string_lossy().into_owned());
        args.recording.with_file_name(format!("{stem}-whatif.svg"))
    });
    std::fs::write(&svg_path, &what_if.svg).with_context(|| format!("writing {}", svg_path.display()))?;
    say!("             drawn in {}", svg_path.display());
    Ok(true)
}

/// Whether the recording holds every input the gateway took.
fn completeness(recording: &Recording) -> String {
    match (&recording.end, &recording.truncated) {
        (_, Some(why)) => format!("cut short ({why}): replaying what was read"),
        (None, None) => "not closed (the gateway did not end it): replaying what was read".into(),
        (Some((taken, dropped)), None) if !recording.is_whole() => format!(
            "incomplete: the gateway took {taken} inputs, {} are here ({dropped} records dropped by a full queue)",
            recording.inputs.len()
        ),
        _ => "whole: every input the gateway took".into(),
    }
}

fn say_replayed(replayed: &replay::Replayed, duration: f64) {
    let speedup = if replayed.elapsed > 0.0 { duration / replayed.elapsed } else { f64::INFINITY };
    say!(
        "replayed     in {:.1} ms of CPU, {:.0}x real time; final state {}",
        replayed.elapsed * 1e3,
        speedup,
        replayed.final_state
    );
}

/// The replay with the recorded configuration: the same CAN frames, byte for byte?
fn verify(recording: &Recording) -> Result<bool> {
    let v = recording.verify()?;
    say_replayed(&v.replayed, recording.duration());
    let (n, common) = (v.recorded, v.compared);
    let unwritten = if v.written < n { format!(" ({} while the link was down)", n - v.written) } else { String::new() };
    if !v.whole {
        say!("             the recording is not whole: comparing the first {common} frames");
    }
    match &v.difference {
        None if !v.whole => say!(
            "CAN frames   the first {common} of {n} recorded{unwritten}: identical, byte for byte; \
             the rest of the run is not in the recording (exit status 1)"
        ),
        None => {
            say!("CAN frames   {n} recorded{unwritten}, {} replayed: identical, byte for byte", v.replayed.can.len())
        }
        Some(d) => say!(
            "CAN frames   {n} recorded, {} replayed: DIFFER at frame {}: recorded {}, replayed {}",
            v.replayed.can.len(),
            d.index,
            d.recorded.as_deref().unwrap_or("nothing"),
            d.replayed.as_deref().unwrap_or("nothing")
        ),
    }
    Ok(v.reproduced())
}

fn say_diff(diff: &replay::CommandDiff) {
    say!(
        "commands     {} recorded, {} what-if; {} differ{}",
        diff.recorded_commands,
        diff.replayed_commands,
        diff.differing,
        diff.first_differs_at.map_or(String::new(), |t| format!(", the first at {t:.3} s"))
    );
    say!("             largest wheel difference {} pulses/s", diff.max_pulse_difference);
    say!(
        "paths        dead-reckoned from the commands: {:.1} mm apart at most, {:.1} mm at the end",
        diff.max_path_gap * 1e3,
        diff.end_gap * 1e3
    );
}
