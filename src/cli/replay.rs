//! `flowgate replay FILE.mcap`: a recorded run through the gateway core again, in virtual
//! time. With the recorded configuration it must ask for the same CAN frames, byte for byte
//! (exit status 1 if not, and for a recording cut short, whose prefix it replays); with `--config` or `--set` it is a what-if, and reports how the
//! commands and the paths they drive differ (and draws them).

use crate::cli::{say, say_raw};
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use flowgate::config::GatewayConfig;
use flowgate::replay::{self, Recording};
use flowgate::Point;

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
    let duration = recording.duration();
    say!("recording    {}: {} inputs over {:.1} s", args.recording.display(), recording.inputs.len(), duration);
    match (&recording.end, &recording.truncated) {
        (_, Some(why)) => say!("             cut short ({why}): replaying what was read"),
        (None, None) => say!("             not closed (the gateway did not end it): replaying what was read"),
        (Some((taken, dropped)), None) if !recording.is_whole() => say!(
            "             incomplete: the gateway took {taken} inputs, {} are here ({dropped} records dropped by a full queue)",
            recording.inputs.len()
        ),
        _ => say!("             whole: every input the gateway took"),
    }
    if recording.inputs.is_empty() {
        say!("             no inputs: nothing to replay");
        return Ok(false);
    }
    let what_if = args.config.is_some() || !args.set.is_empty();
    let config = match &args.config {
        Some(path) => GatewayConfig::read(path)?,
        None if args.set.is_empty() => recording.config()?,
        None => {
            let text = replay::apply_sets(&recording.config_toml, &args.set)?;
            GatewayConfig::from_toml(&text, "the recorded configuration with --set")?
        }
    };
    let origin = if what_if { "the what-if configuration" } else { "the recorded configuration" };
    let rig = config.rig(origin)?;
    let (pulses_per_metre, wheel_base, space) =
        (rig.control.drive.pulses_per_metre(), rig.control.drive.wheel_base, rig.control.planner.space);
    let recorded = replay::run(recording.config()?.rig("the recorded configuration")?, &recording.inputs);
    let replayed = if what_if { replay::run(rig, &recording.inputs) } else { recorded.clone() };
    let speedup = if replayed.elapsed > 0.0 { duration / replayed.elapsed } else { f64::INFINITY };
    say!(
        "replayed     in {:.1} ms of CPU, {:.0}x real time; final state {}",
        replayed.elapsed * 1e3,
        speedup,
        replayed.final_state
    );
    if !what_if {
        let written = recording.can_sent.iter().filter(|f| f.written).count();
        let n = recording.can_sent.len();
        let unwritten = if written < n { format!(" ({} while the link was down)", n - written) } else { String::new() };
        // A recording that is not whole ends at an arbitrary point: its last inputs' frames
        // may be missing, so only the common prefix can be compared.
        let whole = recording.is_whole();
        let common = recording.can_sent.len().min(replayed.can.len());
        let (sent, again) = if whole {
            (&recording.can_sent[..], &replayed.can[..])
        } else {
            say!("             the recording is not whole: comparing the first {common} frames");
            (&recording.can_sent[..common], &replayed.can[..common])
        };
        return Ok(match replay::first_difference(sent, again) {
            None if !whole => {
                say!(
                    "CAN frames   the first {common} of {n} recorded{unwritten}: identical, byte for byte; \
                     the rest of the run is not in the recording (exit status 1)"
                );
                false
            }
            None => {
                say!("CAN frames   {n} recorded{unwritten}, {} replayed: identical, byte for byte", replayed.can.len());
                true
            }
            Some(d) => {
                say!(
                    "CAN frames   {n} recorded, {} replayed: DIFFER at frame {}: recorded {}, replayed {}",
                    replayed.can.len(),
                    d.index,
                    d.recorded.as_deref().unwrap_or("nothing"),
                    d.replayed.as_deref().unwrap_or("nothing")
                );
                false
            }
        });
    }
    // The what-if: both command streams dead-reckoned from the first measured pose.
    let first =
        recorded.commands.first().copied().context("the recorded run gave no velocity command: nothing to compare")?;
    let start = Point::new(first.x, first.y);
    let heading = first.heading;
    let path_a = replay::dead_reckon(&recorded.commands, start, heading, pulses_per_metre, wheel_base);
    let path_b = replay::dead_reckon(&replayed.commands, start, heading, pulses_per_metre, wheel_base);
    let diff = replay::diff_commands(&recorded.commands, &replayed.commands, (&path_a, &path_b), first.t);
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
    let measured: Vec<Point> = recorded.commands.iter().map(|c| Point::new(c.x, c.y)).collect();
    let title = match &args.config {
        Some(p) => format!("what-if: {}", p.display()),
        None => format!("what-if: {}", args.set.join(", ")),
    };
    let svg = replay::paths_svg(&measured, &path_a, &path_b, space, &title);
    let svg_path = args.svg.unwrap_or_else(|| {
        let stem = args.recording.file_stem().map_or("replay".into(), |s| s.to_string_lossy().into_owned());
        args.recording.with_file_name(format!("{stem}-whatif.svg"))
    });
    std::fs::write(&svg_path, svg).with_context(|| format!("writing {}", svg_path.display()))?;
    say!("             drawn in {}", svg_path.display());
    Ok(true)
}
