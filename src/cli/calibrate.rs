//! `flowgate calibrate --config rig.toml`: place an LED at known floor points, one at a time;
//! the tool measures each, fits the homography and the lens distortion, prints the
//! residuals, draws them (SVG) and writes `[calibration]` back into rig.toml, keeping the
//! file's comments and layout (the previous file is kept as `rig.toml.bak`).
//!
//! The floor points come from `--points FILE` (`points = [[x, y], ...]`, metres) or are
//! typed one by one. Before each measurement the tool asks for Enter; `s` skips the point,
//! `q` ends the session without writing anything.

use std::io::{BufRead, Write};
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use flowgate::calib::{span, Calibration, MIN_POINTS_WITH_DISTORTION};
use flowgate::config::GatewayConfig;
use flowgate::setup::calibrate::{self, Reading};
use flowgate::setup::psd_client::PsdClient;

#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// The rig configuration: its serial port and schedule are used, and its
    /// `[calibration]` rewritten.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// The LED to place (default: the robot's front LED, `leds.robot_front`).
    #[arg(long)]
    led: Option<u8>,
    /// Floor points, `points = [[x, y], ...]` in metres; without it, each is typed.
    #[arg(long, value_name = "FILE")]
    points: Option<PathBuf>,
    /// Samples averaged per point.
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u16).range(5..=10_000))]
    samples: u16,
    /// Where the residual plot goes (default: beside the config, `<name>-residuals.svg`).
    #[arg(long, value_name = "FILE")]
    svg: Option<PathBuf>,
    /// Fit and report, but leave the config as it is.
    #[arg(long)]
    dry_run: bool,
}

/// A line from the user (`None` at end of input).
fn ask(prompt: &str) -> Result<Option<String>> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{prompt}")?;
    out.flush()?;
    let mut line = String::new();
    Ok((std::io::stdin().lock().read_line(&mut line)? > 0).then(|| line.trim().to_string()))
}

fn say(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

pub fn run(args: CalibrateArgs) -> Result<()> {
    let origin = args.config.display().to_string();
    let text = std::fs::read_to_string(&args.config).with_context(|| format!("reading {origin}"))?;
    let config = GatewayConfig::from_toml(&text, &origin)?;
    let rig = config.rig(&origin)?;
    let led = args.led.unwrap_or(rig.robot_front);
    let schedule = config.schedule_for(&[led]).map_err(|invalid| anyhow::anyhow!("{origin}: {invalid}"))?;
    let period = std::time::Duration::from_micros(u64::from(schedule.frame_period_us()));
    let planned = args.points.as_deref().map(calibrate::load_points).transpose()?;
    if let Some(p) = &planned {
        if p.len() < MIN_POINTS_WITH_DISTORTION {
            bail!(
                "{}: {} points; the fit needs at least {MIN_POINTS_WITH_DISTORTION} (9 or more, spread over the arena, are better)",
                args.points.as_ref().map_or(String::new(), |p| p.display().to_string()),
                p.len()
            );
        }
    }

    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let measured: Vec<([f64; 2], Reading)> = runtime.block_on(async {
        let mut client = PsdClient::open(&rig.serial, schedule, rig.psd_counts)?;
        let handshake = client.configure().await?;
        client.pause().await?;
        let i = handshake.info;
        say(&format!(
            "PSD controller on {}: firmware {}.{}.{}; calibrating with LED {led}, {} samples a point",
            rig.serial.port.display(),
            i.firmware[0],
            i.firmware[1],
            i.firmware[2],
            args.samples
        ));
        let mut measured = Vec::new();
        let mut k = 0;
        loop {
            let floor = match &planned {
                Some(points) => match points.get(k) {
                    Some(p) => *p,
                    None => break,
                },
                None => {
                    let Some(line) =
                        ask(&format!("point {}: floor position `X Y` in metres (empty line: done)", k + 1))?
                    else {
                        break;
                    };
                    if line.is_empty() {
                        break;
                    }
                    match parse_point(&line) {
                        Ok(p) => p,
                        Err(why) => {
                            say(&why);
                            continue;
                        }
                    }
                }
            };
            k += 1;
            let mut prompt = format!("Put LED {led} at ({:.3}, {:.3}) m, then press Enter (s: skip, q: quit)", floor[0], floor[1]);
            loop {
                match ask(&prompt)?.as_deref() {
                    None | Some("q") => bail!("calibration ended before the fit: nothing written"),
                    Some("s") => {
                        say(&format!("point ({:.3}, {:.3}) skipped", floor[0], floor[1]));
                        break;
                    }
                    Some(_) => {}
                }
                client.configure().await?;
                let result = calibrate::measure(&mut client, led, usize::from(args.samples), period).await;
                client.pause().await?;
                match result {
                    Ok(r) => {
                        say(&format!(
                            "point ({:.3}, {:.3}): raw ({:.1}, {:.1}) counts, spread {:.2}, {} samples used ({} weak, {} saturated)",
                            floor[0], floor[1], r.raw[0], r.raw[1], r.spread, r.used, r.weak, r.saturated
                        ));
                        measured.push((floor, r));
                        break;
                    }
                    Err(e @ (calibrate::CalibrateError::Unusable { .. } | calibrate::CalibrateError::NoSamples { .. })) => {
                        say(&format!("point ({:.3}, {:.3}) rejected: {e}", floor[0], floor[1]));
                        prompt = "Enter to measure it again (s: skip, q: quit)".to_string();
                    }
                    Err(e) => return Err(e.into()),
                }
            }
        }
        client.stop().await;
        Ok::<_, anyhow::Error>(measured)
    })?;

    let pairs: Vec<([f64; 2], [f64; 2])> = measured.iter().map(|(floor, r)| (r.raw, *floor)).collect();
    let fit = Calibration::fit_with_distortion(&pairs, rig.psd_counts).context("the fit")?;
    say("\npoint  floor x (m)  floor y (m)  raw x  raw y  residual (mm)");
    for (i, ((floor, r), res)) in measured.iter().zip(&fit.residuals).enumerate() {
        say(&format!(
            "{:>5}  {:>11.3}  {:>11.3}  {:>5.0}  {:>5.0}  {:>13.3}",
            i + 1,
            floor[0],
            floor[1],
            r.raw[0],
            r.raw[1],
            1e3 * res[0].hypot(res[1])
        ));
    }
    let (centre, side) = span(&pairs);
    say(&format!(
        "RMS residual {:.3} mm over {} points ({:.2} counts); k1 = {:.5}; noise gain {:.2}; calibrated square {:.2} m about ({:.2}, {:.2})",
        1e3 * fit.rms_m,
        measured.len(),
        fit.rms_counts,
        fit.k1,
        fit.noise_gain,
        side,
        centre[0],
        centre[1]
    ));
    let floors: Vec<[f64; 2]> = measured.iter().map(|(f, _)| *f).collect();
    let svg_path = args.svg.clone().unwrap_or_else(|| {
        let stem = args.config.file_stem().map_or("rig".into(), |s| s.to_string_lossy().into_owned());
        args.config.with_file_name(format!("{stem}-residuals.svg"))
    });
    std::fs::write(&svg_path, calibrate::residual_svg(&floors, &fit))
        .with_context(|| format!("writing {}", svg_path.display()))?;
    say(&format!("residual plot: {}", svg_path.display()));
    if args.dry_run {
        say("--dry-run: the config is unchanged");
        return Ok(());
    }
    let note = format!(
        "fitted by flowgate calibrate: {} points, LED {led}, RMS {:.3} mm, k1 {:.5}",
        measured.len(),
        1e3 * fit.rms_m,
        fit.k1
    );
    let new_text = calibrate::write_back(&text, &fit, &note).map_err(|why| anyhow::anyhow!("{origin}: {why}"))?;
    // What is written must load: check before replacing the user's file.
    GatewayConfig::from_toml(&new_text, &origin)?.rig(&origin)?;
    let backup = args.config.with_extension("toml.bak");
    std::fs::copy(&args.config, &backup).with_context(|| format!("keeping {}", backup.display()))?;
    let tmp = args.config.with_extension("toml.new");
    std::fs::write(&tmp, &new_text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &args.config).with_context(|| format!("replacing {origin}"))?;
    say(&format!("[calibration] written to {origin} (the previous file is {})", backup.display()));
    Ok(())
}

fn parse_point(line: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> =
        line.split_whitespace().map(str::parse).collect::<Result<_, _>>().map_err(|e| format!("`{line}`: {e}"))?;
    match v[..] {
        [x, y] if x.is_finite() && y.is_finite() && x.abs() < 100.0 && y.abs() < 100.0 => Ok([x, y]),
        _ => Err(format!("`{line}`: expected two numbers, `X Y`, in metres")),
    }
}
