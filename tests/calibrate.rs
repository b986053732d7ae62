//! `flowgate calibrate` against the simulator over a real pty: the simulated camera has a
//! known homography, lens distortion (k1 = 0.03) and a count of noise; a wand LED is put at
//! each floor point when the tool asks. The calibration written into rig.toml must recover
//! the camera to under 1 mm RMS over the arena, keep the user's comments, and refuse a
//! point the PSD cannot see and a set of points that cannot be fitted.

use std::path::{Path, PathBuf};
use std::process::Stdio;

use flowgate::config::RigFile;
use flowgate::lab::Scenario;
use flowgate::Point;
use flowgate_sim::camera::CameraModel;
use flowgate_sim::rig::{RigConfig, RigHandle};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

const WAND: u8 = 9;

fn camera() -> CameraModel {
    CameraModel { k1: 0.03, ..CameraModel::default() }
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("flowgate-calibrate-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The simulator with the distorted camera, and a rig.toml for it whose calibration is a
/// rough guess, with the user's comments in it.
async fn rig(dir: &Path) -> (RigHandle, PathBuf, String) {
    let s = Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let mut sim = RigConfig::new(s.sim.clone());
    sim.camera = camera();
    sim.noise_counts = 1.0;
    let handle = flowgate_sim::rig::start(sim).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().unwrap().display());
    let mut cfg: RigFile = s.rig_file(&handle.psd_path, &can, None);
    cfg.calibration.homography = Some([[2000.0, 0.0, 0.0], [0.0, 2000.0, 0.0], [0.0, 0.0, 1.0]]);
    cfg.calibration.points.clear();
    cfg.calibration.k1 = 0.0;
    let text = format!("# Lab rig B, north bench.\n{}", cfg.to_toml())
        .replace("[serial]\n", "[serial]\n# The controller's USB adapter.\n")
        .replace("[calibration]\n", "[calibration]\n# A guess until calibrated.\n");
    let path = dir.join("rig.toml");
    std::fs::write(&path, &text).unwrap();
    (handle, path, text)
}

/// Run `flowgate calibrate` with `args`, answering its prompts: each "Put LED" prompt
/// moves the wand to the point it names (the first time to `first_at` instead, if given)
/// and presses Enter; each "point N:" prompt types the next of `typed`. Returns the exit
/// status and everything printed.
async fn calibrate(
    handle: &RigHandle,
    config: &Path,
    args: &[&str],
    first_at: Option<Option<Point>>,
    typed: &[&str],
) -> (bool, String) {
    let mut child = tokio::process::Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["calibrate", "--config"])
        .arg(config)
        .args(["--led", &WAND.to_string()])
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut out = String::new();
    let mut first = first_at;
    let mut typed = typed.iter();
    let mut last_point = None;
    while let Some(line) = lines.next_line().await.unwrap() {
        out.push_str(&line);
        out.push('\n');
        if let Some(rest) = line.strip_prefix(&format!("Put LED {WAND} at (")) {
            let (xy, _) = rest.split_once(')').unwrap();
            let (x, y) = xy.split_once(", ").unwrap();
            let p = Point::new(x.parse().unwrap(), y.parse().unwrap());
            last_point = Some(p);
            handle.place_wand(WAND, first.take().unwrap_or(Some(p)));
            stdin.write_all(b"\n").await.unwrap();
        } else if line.starts_with("Enter to measure it again") {
            handle.place_wand(WAND, last_point);
            stdin.write_all(b"\n").await.unwrap();
        } else if line.starts_with("point ") && line.contains("floor position") {
            let answer = typed.next().map_or(String::from("\n"), |t| format!("{t}\n"));
            stdin.write_all(answer.as_bytes()).await.unwrap();
        }
    }
    let status = child.wait_with_output().await.unwrap();
    out.push_str(&String::from_utf8_lossy(&status.stderr));
    (status.status.success(), out)
}

/// The calibration in `config` against the true camera: RMS floor error over a 21x21 grid
/// of the square `half` m about the origin, m.
fn error_against_truth(config: &Path, half: f64) -> f64 {
    let rig = RigFile::load(config).unwrap();
    let cam = camera();
    let n = 21;
    let mut sq = 0.0;
    for i in 0..n {
        for j in 0..n {
            let p = Point::new(
                -half + 2.0 * half * f64::from(i) / f64::from(n - 1),
                -half + 2.0 * half * f64::from(j) / f64::from(n - 1),
            );
            let (x, y) = cam.project(p).unwrap();
            sq += (rig.calibration.to_floor(x, y).unwrap() - p).norm_sqr();
        }
    }
    (sq / f64::from(n * n)).sqrt()
}

fn grid(n: i32, half: f64) -> Vec<[f64; 2]> {
    let step = 2.0 * half / f64::from(n - 1);
    (0..n).flat_map(|i| (0..n).map(move |j| [-half + step * f64::from(i), -half + step * f64::from(j)])).collect()
}

fn points_file(dir: &Path, points: &[[f64; 2]]) -> PathBuf {
    let path = dir.join("points.toml");
    let list: Vec<String> = points.iter().map(|p| format!("[{}, {}]", p[0], p[1])).collect();
    std::fs::write(&path, format!("# floor points, m\npoints = [{}]\n", list.join(", "))).unwrap();
    path
}

/// A 4x4 grid over the arena (±0.45 m) from a file; the wand is out of sight the first
/// time, so that point is rejected (all samples weak) and measured again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recovers_the_camera_to_under_a_millimetre() {
    let dir = dir("grid");
    let (handle, config, before) = rig(&dir).await;
    let points = points_file(&dir, &grid(4, 0.45));
    let guess = error_against_truth(&config, 0.45);
    let (ok, out) =
        calibrate(&handle, &config, &["--points", points.to_str().unwrap(), "--samples", "20"], Some(None), &[]).await;
    handle.stop().await;
    assert!(ok, "{out}");
    assert!(out.contains("rejected: only 0 of 20 samples usable (20 weak, 0 saturated)"), "{out}");
    assert_eq!(out.matches("samples used").count(), 16, "{out}");

    let after = std::fs::read_to_string(&config).unwrap();
    assert!(after.starts_with("# Lab rig B, north bench.\n"), "{after}");
    assert!(after.contains("[serial]\n# The controller's USB adapter.\n"), "{after}");
    assert!(after.contains("# A guess until calibrated.\n"), "{after}");
    assert!(after.contains("# fitted by flowgate calibrate: 16 points, LED 9, RMS "), "{after}");
    assert_eq!(std::fs::read_to_string(dir.join("rig.toml.bak")).unwrap(), before);

    let error = error_against_truth(&config, 0.45);
    println!(
        "floor error against the true camera over ±0.45 m: {:.3} mm RMS (the guess: {:.1} mm)",
        error * 1e3,
        guess * 1e3
    );
    assert!(error < 1e-3, "{error} m RMS");
    assert!(guess > 10e-3, "the starting guess was already right: {guess}");
    let rms_line = out.lines().find(|l| l.starts_with("RMS residual")).unwrap();
    let rms_mm: f64 = rms_line.split_whitespace().nth(2).unwrap().parse().unwrap();
    assert!(rms_mm < 1.0, "{rms_line}");
    let svg = std::fs::read_to_string(dir.join("rig-residuals.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.matches("<circle").count() == 16, "{svg}");
}

/// Points typed one by one (a 3x3 grid): the same fit, from the keyboard.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn points_can_be_typed() {
    let dir = dir("typed");
    let (handle, config, _) = rig(&dir).await;
    let typed: Vec<String> = grid(3, 0.4).iter().map(|p| format!("{} {}", p[0], p[1])).collect();
    let mut answers: Vec<&str> = vec!["0.1 nonsense"];
    answers.extend(typed.iter().map(String::as_str));
    let (ok, out) = calibrate(&handle, &config, &["--samples", "20"], None, &answers).await;
    handle.stop().await;
    assert!(ok, "{out}");
    assert!(out.contains("`0.1 nonsense`: invalid float literal"), "{out}");
    assert!(out.contains("fitted") || out.contains("[calibration] written"), "{out}");
    let error = error_against_truth(&config, 0.4);
    assert!(error < 1e-3, "{error} m RMS");
}

/// Points along a line cannot pin the mapping down: refused by name, nothing written.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refuses_points_along_a_line() {
    let dir = dir("line");
    let (handle, config, before) = rig(&dir).await;
    let line: Vec<[f64; 2]> = (0..7).map(|i| [0.1 * f64::from(i) - 0.3, 0.002 * f64::from(i % 2)]).collect();
    let points = points_file(&dir, &line);
    let (ok, out) =
        calibrate(&handle, &config, &["--points", points.to_str().unwrap(), "--samples", "10"], None, &[]).await;
    handle.stop().await;
    assert!(!ok, "{out}");
    assert!(out.contains("badly conditioned"), "{out}");
    assert!(out.contains("not along a line"), "{out}");
    assert_eq!(std::fs::read_to_string(&config).unwrap(), before);
    assert!(!dir.join("rig.toml.bak").exists());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_points_file_is_named() {
    let dir = dir("bad-points");
    let (handle, config, _) = rig(&dir).await;
    let path = dir.join("points.toml");
    for (text, says) in [
        ("points = [[0.0, 0.0], [0.1, 0.0], [0.0, 1e9]]\n", "points[2] = [0.0, 1000000000.0]: floor metres"),
        ("points = [[0.0, 0.0], [0.1, 0.0], [0.0, 0.0]]\n", "points[2] repeats points[0]"),
        ("points = [[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]]\n", "3 points; the fit needs at least 6"),
        ("pts = []\n", "unknown field `pts`"),
    ] {
        std::fs::write(&path, text).unwrap();
        let (ok, out) = calibrate(&handle, &config, &["--points", path.to_str().unwrap()], None, &[]).await;
        assert!(!ok && out.contains(says), "{text}: {out}");
        assert!(out.contains("points.toml"), "{out}");
    }
    handle.stop().await;
}
