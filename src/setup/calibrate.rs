//! `flowgate calibrate`: the camera calibration from an LED placed at known floor points.
//!
//! The pieces without I/O live here: averaging one point's samples (weak and saturated
//! ones rejected), the fit ([`crate::calibration::Calibration::fit_with_distortion`]), the residual plot, and
//! writing the `[calibration]` section back into the user's `rig.toml` with `toml_edit`,
//! so their comments and layout stay. [`measure_points`] runs the session over a
//! [`PsdClient`], asking the person at the rig through a [`Prompt`] (the CLI's terminal, or
//! a test's script); [`Calibrated`] reports the fit and writes it back.

use std::path::Path;
use std::time::Duration;

use crate::Point;
use flowgate_protocol::psd::{Sample, SampleFlags};
use tokio::time::Instant;

use super::psd_client::{PsdClient, PsdClientError};
use crate::calibration::{CalibrationError, Fit};
use crate::svg::{Axes, Svg};

/// Samples skipped after the stream starts (the LED's first frame).
const SETTLE_SAMPLES: usize = 2;
/// At least this share of a point's samples must be usable.
const MIN_USABLE_SHARE: f64 = 0.5;

/// One point's reading: the mean raw position of its usable samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    pub raw: [f64; 2],
    /// Standard deviation of the samples about the mean, counts (the larger axis).
    pub spread: f64,
    pub used: usize,
    pub weak: usize,
    pub saturated: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    #[error(
        "only {used} of {total} samples usable ({weak} weak, {saturated} saturated): is the LED in view, lit, not \
         glaring?"
    )]
    Unusable { used: usize, total: usize, weak: usize, saturated: usize },
    #[error("no samples of LED {led} within {} ms", .within.as_millis())]
    NoSamples { led: u8, within: Duration },
    #[error(transparent)]
    Psd(#[from] PsdClientError),
    #[error(transparent)]
    Fit(#[from] CalibrationError),
    #[error("points file {path}: {why}")]
    Points { path: String, why: String },
    #[error("{path}: cannot write the calibration back: {why}")]
    WriteBack { path: String, why: String },
    #[error("calibration ended before the fit: nothing written")]
    Ended,
    #[error("the prompt: {0}")]
    Prompt(#[from] std::io::Error),
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
}

/// Average the samples of one point, rejecting weak and saturated ones.
pub fn average(samples: &[Sample]) -> Result<Reading, CalibrateError> {
    let total = samples.len();
    let weak = samples.iter().filter(|s| s.flags.contains(SampleFlags::WEAK_SIGNAL)).count();
    let saturated = samples.iter().filter(|s| s.flags.contains(SampleFlags::SATURATED)).count();
    let good: Vec<[f64; 2]> = samples
        .iter()
        .filter(|s| !s.flags.contains(SampleFlags::WEAK_SIGNAL) && !s.flags.contains(SampleFlags::SATURATED))
        .map(|s| [f64::from(s.x), f64::from(s.y)])
        .collect();
    let used = good.len();
    if used < 3 || (used as f64) < MIN_USABLE_SHARE * total as f64 {
        return Err(CalibrateError::Unusable { used, total, weak, saturated });
    }
    let n = used as f64;
    let mean = [good.iter().map(|g| g[0]).sum::<f64>() / n, good.iter().map(|g| g[1]).sum::<f64>() / n];
    let var = |a: usize| good.iter().map(|g| (g[a] - mean[a]).powi(2)).sum::<f64>() / (n - 1.0);
    Ok(Reading { raw: mean, spread: var(0).max(var(1)).sqrt(), used, weak, saturated })
}

/// Stream `n` samples of `led` (after the settling ones) and average them. The stream must
/// be running; every wait has a deadline of a second beyond the frames asked for.
pub async fn measure(client: &mut PsdClient, led: u8, n: usize, period: Duration) -> Result<Reading, CalibrateError> {
    let within = period * (n + SETTLE_SAMPLES) as u32 + Duration::from_secs(1);
    let deadline = Instant::now() + within;
    let mut samples = Vec::with_capacity(n + SETTLE_SAMPLES);
    while samples.len() < n + SETTLE_SAMPLES {
        match client.next_sample(deadline).await? {
            Some(s) if s.led == led => samples.push(s),
            Some(_) => {}
            None if samples.is_empty() => return Err(CalibrateError::NoSamples { led, within }),
            None => break,
        }
    }
    average(samples.get(SETTLE_SAMPLES..).unwrap_or_default())
}

/// A points file: `points = [[x, y], ...]`, floor metres.
pub fn load_points(path: &Path) -> Result<Vec<[f64; 2]>, CalibrateError> {
    let bad = |why: String| CalibrateError::Points { path: path.display().to_string(), why };
    let text = crate::config::read_text(path, crate::config::MAX_FILE_BYTES).map_err(|e| bad(e.to_string()))?;
    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct File {
        points: Vec<[f64; 2]>,
    }
    let file: File = toml::from_str(&text).map_err(|e| bad(e.message().to_string()))?;
    for (i, p) in file.points.iter().enumerate() {
        if !p.iter().all(|v| v.is_finite() && v.abs() < 100.0) {
            return Err(bad(format!("points[{i}] = {p:?}: floor metres, finite and within 100 m")));
        }
        if let Some(j) = file.points[..i].iter().position(|q| q == p) {
            return Err(bad(format!("points[{i}] repeats points[{j}] ({p:?})")));
        }
    }
    Ok(file.points)
}

/// The config text with its `[calibration]` set to `fit` (homography and k1; `points`
/// removed, since the two exclude each other), everything else as the user wrote it. A
/// comment above the homography says where it came from.
pub fn write_back(text: &str, fit: &Fit, note: &str) -> Result<String, String> {
    use toml_edit::{Array, DocumentMut, Item, Table, Value};
    let mut doc: DocumentMut = text.parse().map_err(|e: toml_edit::TomlError| e.to_string())?;
    if !doc.contains_key("calibration") {
        doc["calibration"] = Item::Table(Table::new());
    }
    let table = doc["calibration"].as_table_mut().ok_or("`calibration` is not a table")?;
    // The points give way to the homography; their comment moves with them.
    let points_comment = table
        .key("points")
        .and_then(|k| k.leaf_decor().prefix().and_then(|p| p.as_str()).map(str::to_string))
        .unwrap_or_default();
    table.remove("points");
    let mut rows = Array::new();
    for row in &fit.homography {
        let mut r = Array::new();
        for v in row {
            r.push(*v);
        }
        rows.push(r);
    }
    // A key rewritten keeps its own comments (a trailing `# ...` after the value too).
    let mut set = |key: &str, new: Value| match table.get_mut(key).and_then(Item::as_value_mut) {
        Some(old) => {
            let decor = old.decor().clone();
            *old = new;
            *old.decor_mut() = decor;
        }
        None => table[key] = Item::Value(new),
    };
    set("homography", Value::Array(rows));
    set("k1", Value::from(fit.k1));
    if let Some(mut key) = table.key_mut("homography") {
        // Keep the user's comments above the key; replace an earlier run's note.
        let decor = key.leaf_decor_mut();
        let before = decor.prefix().and_then(|p| p.as_str()).unwrap_or("").to_string();
        let kept: String =
            before.split_inclusive('\n').filter(|l| !l.starts_with("# fitted by flowgate calibrate")).collect();
        decor.set_prefix(format!("{points_comment}{kept}# {note}\n"));
    }
    Ok(doc.to_string())
}

/// The residual plot: each point, and an arrow to where the calibration puts its reading,
/// magnified so a millimetre shows.
pub fn residual_svg(floor: &[[f64; 2]], fit: &Fit) -> String {
    let mut svg = Svg::new(640.0, 600.0);
    let (lo, hi) =
        floor.iter().fold((Point::new(f64::MAX, f64::MAX), Point::new(f64::MIN, f64::MIN)), |(lo, hi), p| {
            (Point::new(lo.re.min(p[0]), lo.im.min(p[1])), Point::new(hi.re.max(p[0]), hi.im.max(p[1])))
        });
    let pad = Point::new(0.1, 0.1) * ((hi - lo).norm().max(0.1));
    let axes = Axes::equal(&svg, lo - pad, hi + pad, (70.0, 50.0, 50.0, 20.0));
    axes.frame(&mut svg, "floor x (m)", "floor y (m)");
    let max_res = fit.residuals.iter().map(|r| r[0].hypot(r[1])).fold(0.0, f64::max).max(1e-6);
    // The largest residual drawn as a tenth of the span.
    let magnify = (0.1 * (hi - lo).norm().max(0.1) / max_res).round().max(1.0);
    for (p, r) in floor.iter().zip(&fit.residuals) {
        let at = Point::new(p[0], p[1]);
        axes.circle(&mut svg, at, 0.004 * (hi - lo).norm().max(0.1), "#1f77b4", 1.0, 1.0);
        axes.polyline(&mut svg, &[at, at + Point::new(r[0], r[1]) * magnify], "#d62728", 2.0, None);
        axes.label(&mut svg, at, &format!("{:.2} mm", 1e3 * r[0].hypot(r[1])), "#333");
    }
    svg.text(
        320.0,
        24.0,
        &format!(
            "calibration residuals: {} points, RMS {:.3} mm, k1 = {:.4}; arrows x{magnify}",
            floor.len(),
            1e3 * fit.rms_m,
            fit.k1
        ),
        "middle",
        13.0,
        "#000",
    );
    svg.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::Calibration;

    fn sample(x: i32, y: i32, flags: u8) -> Sample {
        Sample { frame: 0, slot: 0, led: 9, t_ctrl_us: 0, x, y, intensity: 3000, flags: SampleFlags(flags) }
    }

    #[test]
    fn weak_and_saturated_samples_are_rejected() {
        let mut s: Vec<Sample> = (0..10).map(|i| sample(100 + i % 2, -50, 0)).collect();
        s.push(sample(2000, 2000, SampleFlags::SATURATED));
        s.push(sample(0, 0, SampleFlags::WEAK_SIGNAL));
        let r = average(&s).unwrap();
        assert_eq!((r.used, r.weak, r.saturated), (10, 1, 1));
        assert_eq!(r.raw, [100.5, -50.0]);
        let dark: Vec<Sample> = (0..10).map(|_| sample(0, 0, SampleFlags::WEAK_SIGNAL)).collect();
        assert!(matches!(average(&dark), Err(CalibrateError::Unusable { used: 0, total: 10, weak: 10, .. })));
    }

    #[test]
    fn the_section_is_replaced_and_the_rest_kept() {
        let text = "# my rig\n[serial]\nport = \"/dev/x\" # the USB one\n\n[calibration]\ncounts = 4096\n\
                    # measured 2026-01-01\nhomography = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] # pixels to m\n\
                    k1 = 0.0    # lens distortion\n\n[can]\nendpoint = \"x\"\n";
        let points: Vec<([f64; 2], [f64; 2])> = (0..9)
            .map(|i| {
                let f = [0.2 * f64::from(i % 3) - 0.2, 0.2 * f64::from(i / 3) - 0.2];
                ([f[0] * 2000.0, f[1] * 2000.0], f)
            })
            .collect();
        let fit = Calibration::fit_with_distortion(&points, 4096).unwrap();
        let out = write_back(text, &fit, "fitted by flowgate calibrate: first").unwrap();
        assert!(out.starts_with("# my rig\n[serial]\nport = \"/dev/x\" # the USB one\n"), "{out}");
        assert!(out.contains("# measured 2026-01-01\n# fitted by flowgate calibrate: first\nhomography = [["), "{out}");
        // The values' own trailing comments stay too.
        assert!(out.contains("]] # pixels to m\n") && out.contains("    # lens distortion\n"), "{out}");
        assert!(!out.contains("k1 = 0.0 "), "{out}");
        // A second run replaces its note; the user's comment stays.
        let again = write_back(&out, &fit, "fitted by flowgate calibrate: second").unwrap();
        assert!(again.contains("# measured 2026-01-01\n# fitted by flowgate calibrate: second\nhomography"), "{again}");
        assert!(!again.contains("first"), "{again}");
        let points = "[calibration]\n# was points\npoints = [{ raw = [0.0, 0.0], floor = [0.0, 0.0] }]\n";
        let replaced = write_back(points, &fit, "note").unwrap();
        assert!(replaced.contains("# was points\n# note\nhomography") && !replaced.contains("points ="), "{replaced}");
        assert!(out.contains("counts = 4096") && out.contains("[can]\nendpoint = \"x\""), "{out}");
        let back: toml::Table = toml::from_str(&out).unwrap();
        assert_eq!(back["calibration"]["homography"][0][0].as_float().unwrap(), fit.homography[0][0]);
    }
}

/// The person at the rig, as the session asks them.
pub trait Prompt {
    /// Show `question` and read one line of answer (`None` at the end of input).
    fn ask(&mut self, question: &str) -> std::io::Result<Option<String>>;
    /// Tell them something.
    fn say(&mut self, line: &str);
}

/// What to measure: which LED, how many samples a point, one frame's period, and the floor
/// points (`None`: typed one by one).
#[derive(Debug, Clone)]
pub struct CalibrationPlan {
    pub led: u8,
    pub samples: usize,
    pub period: Duration,
    pub points: Option<Vec<[f64; 2]>>,
}

/// Measure each floor point: before each, the person places the LED and presses Enter
/// (`s` skips the point, `q` or the end of input ends the session: [`CalibrateError::Ended`]).
/// A point whose samples are unusable is offered again.
pub async fn measure_points(
    client: &mut PsdClient,
    plan: &CalibrationPlan,
    prompt: &mut impl Prompt,
) -> Result<Vec<([f64; 2], Reading)>, CalibrateError> {
    let mut measured = Vec::new();
    let mut k = 0;
    while let Some(floor) = next_point(plan, k, prompt)? {
        k += 1;
        if let Some(reading) = measure_point(client, plan, floor, prompt).await? {
            measured.push((floor, reading));
        }
    }
    Ok(measured)
}

/// The `k`th floor point: planned, or typed (an empty line: done).
fn next_point(plan: &CalibrationPlan, k: usize, prompt: &mut impl Prompt) -> Result<Option<[f64; 2]>, CalibrateError> {
    if let Some(points) = &plan.points {
        return Ok(points.get(k).copied());
    }
    loop {
        let question = format!("point {}: floor position `X Y` in metres (empty line: done)", k + 1);
        let Some(line) = prompt.ask(&question)? else { return Ok(None) };
        if line.is_empty() {
            return Ok(None);
        }
        match parse_point(&line) {
            Ok(p) => return Ok(Some(p)),
            Err(why) => prompt.say(&why),
        }
    }
}

/// One point, asked for until measured or skipped (`None`).
async fn measure_point(
    client: &mut PsdClient,
    plan: &CalibrationPlan,
    floor: [f64; 2],
    prompt: &mut impl Prompt,
) -> Result<Option<Reading>, CalibrateError> {
    let led = plan.led;
    let mut question =
        format!("Put LED {led} at ({:.3}, {:.3}) m, then press Enter (s: skip, q: quit)", floor[0], floor[1]);
    loop {
        match prompt.ask(&question)?.as_deref() {
            None | Some("q") => return Err(CalibrateError::Ended),
            Some("s") => {
                prompt.say(&format!("point ({:.3}, {:.3}) skipped", floor[0], floor[1]));
                return Ok(None);
            }
            Some(_) => {}
        }
        client.configure().await?;
        let result = measure(client, led, plan.samples, plan.period).await;
        client.pause().await?;
        match result {
            Ok(r) => {
                prompt.say(&format!(
                    "point ({:.3}, {:.3}): raw ({:.1}, {:.1}) counts, spread {:.2}, {} samples used ({} weak, {} saturated)",
                    floor[0], floor[1], r.raw[0], r.raw[1], r.spread, r.used, r.weak, r.saturated
                ));
                return Ok(Some(r));
            }
            Err(e @ (CalibrateError::Unusable { .. } | CalibrateError::NoSamples { .. })) => {
                prompt.say(&format!("point ({:.3}, {:.3}) rejected: {e}", floor[0], floor[1]));
                question = "Enter to measure it again (s: skip, q: quit)".to_string();
            }
            Err(e) => return Err(e),
        }
    }
}

/// A typed floor point, `X Y` in metres.
pub fn parse_point(line: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> =
        line.split_whitespace().map(str::parse).collect::<Result<_, _>>().map_err(|e| format!("`{line}`: {e}"))?;
    match v[..] {
        [x, y] if x.is_finite() && y.is_finite() && x.abs() < 100.0 && y.abs() < 100.0 => Ok([x, y]),
        _ => Err(format!("`{line}`: expected two numbers, `X Y`, in metres")),
    }
}

/// The measured points and the fit through them.
#[derive(Debug, Clone)]
pub struct Calibrated {
    pub measured: Vec<([f64; 2], Reading)>,
    pub fit: Fit,
}

impl Calibrated {
    /// Fit the homography and the lens distortion through the measured points.
    pub fn fit(measured: Vec<([f64; 2], Reading)>, counts: u16) -> Result<Self, CalibrateError> {
        let fit = crate::calibration::Calibration::fit_with_distortion(&self_pairs(&measured), counts)?;
        Ok(Self { measured, fit })
    }

    /// The report: each point's floor and raw position and residual, then the summary.
    pub fn report(&self) -> Vec<String> {
        let mut lines = vec!["point  floor x (m)  floor y (m)  raw x  raw y  residual (mm)".to_string()];
        for (i, ((floor, r), res)) in self.measured.iter().zip(&self.fit.residuals).enumerate() {
            let mm = 1e3 * res[0].hypot(res[1]);
            lines.push(format!(
                "{:>5}  {:>11.3}  {:>11.3}  {:>5.0}  {:>5.0}  {mm:>13.3}",
                i + 1,
                floor[0],
                floor[1],
                r.raw[0],
                r.raw[1]
            ));
        }
        let (centre, side) = crate::calibration::span(&self_pairs(&self.measured));
        let f = &self.fit;
        lines.push(format!(
            "RMS residual {:.3} mm over {} points ({:.2} counts); k1 = {:.5}; noise gain {:.2}; calibrated square {:.2} m about ({:.2}, {:.2})",
            1e3 * f.rms_m,
            self.measured.len(),
            f.rms_counts,
            f.k1,
            f.noise_gain,
            side,
            centre[0],
            centre[1]
        ));
        lines
    }

    /// The residual plot (SVG).
    pub fn residual_svg(&self) -> String {
        let floors: Vec<[f64; 2]> = self.measured.iter().map(|(f, _)| *f).collect();
        residual_svg(&floors, &self.fit)
    }

    /// Write `[calibration]` into the config at `path` (whose text is `text`), keeping its
    /// comments and layout; the previous file is kept beside it as `.toml.bak`, which is
    /// returned. What is written must load as a rig before it replaces the user's file.
    pub fn save(&self, path: &Path, text: &str, led: u8) -> Result<std::path::PathBuf, CalibrateError> {
        let origin = path.display().to_string();
        let f = &self.fit;
        let note = format!(
            "fitted by flowgate calibrate: {} points, LED {led}, RMS {:.3} mm, k1 {:.5}",
            self.measured.len(),
            1e3 * f.rms_m,
            f.k1
        );
        let write_back_error = |why: String| CalibrateError::WriteBack { path: origin.clone(), why };
        let new_text = write_back(text, f, &note).map_err(write_back_error)?;
        crate::config::RigFile::from_toml(&new_text, &origin)?.rig(&origin)?;
        let io = |what: &str, e: std::io::Error| write_back_error(format!("{what}: {e}"));
        let backup = path.with_extension("toml.bak");
        std::fs::copy(path, &backup).map_err(|e| io("keeping the previous file", e))?;
        let tmp = path.with_extension("toml.new");
        std::fs::write(&tmp, &new_text).map_err(|e| io("writing", e))?;
        std::fs::rename(&tmp, path).map_err(|e| io("replacing", e))?;
        Ok(backup)
    }
}

/// (raw, floor) pairs, as the fit takes them.
fn self_pairs(measured: &[([f64; 2], Reading)]) -> Vec<([f64; 2], [f64; 2])> {
    measured.iter().map(|(floor, r)| (r.raw, *floor)).collect()
}
