//! `flowgate calibrate --config rig.toml`: place an LED at known floor points, one at a time;
//! the tool measures each, fits the homography and the lens distortion, prints the
//! residuals, draws them (SVG) and writes `[calibration]` back into rig.toml, keeping the
//! file's comments and layout (the previous file is kept as `rig.toml.bak`).
//!
//! The floor points come from `--points FILE` (`points = [[x, y], ...]`, metres) or are
//! typed one by one. Before each measurement the tool asks for Enter; `s` skips the point,
//! `q` ends the session without writing anything.

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use flowgate::calibration::MIN_POINTS_WITH_DISTORTION;
use flowgate::config::RigFile;
use flowgate::setup::calibrate::{self, Calibrated, CalibrationPlan, Prompt};
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

/// The terminal: questions and answers on standard output and input.
struct Terminal;

impl Prompt for Terminal {
    fn ask(&mut self, question: &str) -> std::io::Result<Option<String>> {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{question}")?;
        out.flush()?;
        let mut line = String::new();
        Ok((std::io::stdin().lock().read_line(&mut line)? > 0).then(|| line.trim().to_string()))
    }

    fn say(&mut self, line: &str) {
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "{line}");
        let _ = out.flush();
    }
}

pub fn run(args: CalibrateArgs) -> Result<()> {
    let origin = args.config.display().to_string();
    let text = flowgate::config::read_text(&args.config, flowgate::config::MAX_FILE_BYTES)
        .with_context(|| format!("reading {origin}"))?;
    let config = RigFile::from_toml(&text, &origin)?;
    let rig = config.rig(&origin)?;
    let led = args.led.unwrap_or(rig.robot_front);
    let schedule = config.schedule_for(&[led]).map_err(|invalid| anyhow::anyhow!("{origin}: {invalid}"))?;
    let period = std::time::Duration::from_micros(u64::from(schedule.frame_period_us()));
    let points = args.points.as_deref().map(planned_points).transpose()?;
    let plan = CalibrationPlan { led, samples: usize::from(args.samples), period, points };
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let measured = runtime.block_on(async {
        let mut client = PsdClient::open(&rig.serial, schedule, rig.psd_counts)?;
        let i = client.configure().await?.info;
        client.pause().await?;
        let [a, b, c] = i.firmware;
        let port = rig.serial.port.display();
        Terminal.say(&format!(
            "PSD controller on {port}: firmware {a}.{b}.{c}; calibrating with LED {led}, {} samples a point",
            args.samples
        ));
        let measured = calibrate::measure_points(&mut client, &plan, &mut Terminal).await;
        client.stop().await;
        Ok::<_, anyhow::Error>(measured?)
    })?;
    let calibrated = Calibrated::fit(measured, rig.psd_counts).context("the fit")?;
    Terminal.say("");
    for line in calibrated.report() {
        Terminal.say(&line);
    }
    let svg_path = args.svg.clone().unwrap_or_else(|| residuals_beside(&args.config));
    std::fs::write(&svg_path, calibrated.residual_svg()).with_context(|| format!("writing {}", svg_path.display()))?;
    Terminal.say(&format!("residual plot: {}", svg_path.display()));
    if args.dry_run {
        Terminal.say("--dry-run: the config is unchanged");
        return Ok(());
    }
    let backup = calibrated.save(&args.config, &text, led)?;
    Terminal.say(&format!("[calibration] written to {origin} (the previous file is {})", backup.display()));
    Ok(())
}

/// The points file's floor points, enough of them for the fit.
fn planned_points(path: &Path) -> Result<Vec<[f64; 2]>> {
    let points = calibrate::load_points(path)?;
    if points.len() < MIN_POINTS_WITH_DISTORTION {
        bail!(
            "{}: {} points; the fit needs at least {MIN_POINTS_WITH_DISTORTION} (9 or more, spread over the arena, are better)",
            path.display(),
            points.len()
        );
    }
    Ok(points)
}

/// `<config name>-residuals.svg` beside the config.
fn residuals_beside(config: &Path) -> PathBuf {
    let stem = config.file_stem().map_or("rig".into(), |s| s.to_string_lossy().into_owned());
    config.with_file_name(format!("{stem}-residuals.svg"))
}
