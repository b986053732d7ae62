//! The `flowgate-sim` program: it prints its endpoints, makes the links it was asked for,
//! exits cleanly on SIGINT and SIGTERM, writes the truth and removes its links.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Run `flowgate-sim` on `scenario` until `signal`; the lines it printed after its
/// endpoints, and the truth it wrote.
fn run_until_signal(signal: i32, scenario: &str, truth: &str) -> (Vec<String>, String) {
    let tag = format!("{signal}-{}-{truth}", scenario.replace('/', "-"));
    let dir = std::env::temp_dir().join(format!("flowgate-sim-bin-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (psd_link, can_link, truth_path) = (dir.join("psd"), dir.join("can"), dir.join(truth));
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios").join(scenario);
    let mut child = Command::new(env!("CARGO_BIN_EXE_flowgate-sim"))
        .arg("--scenario")
        .arg(&scenario)
        .arg("--psd-link")
        .arg(&psd_link)
        .arg("--can-link")
        .arg(&can_link)
        .arg("--truth")
        .arg(&truth_path)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    // The endpoints are announced once they exist.
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let psd: PathBuf = lines.next().unwrap().unwrap().strip_prefix("psd: ").expect("psd line").into();
    let can: PathBuf = lines.next().unwrap().unwrap().strip_prefix("can: slcan ").expect("can line").into();
    assert_eq!(std::fs::read_link(&psd_link).unwrap(), psd);
    assert_eq!(std::fs::read_link(&can_link).unwrap(), can);
    assert!(psd.exists() && can.exists());

    #[allow(unsafe_code)]
    // SAFETY: kill(2) on our own child's pid, with a valid signal number.
    let rc = unsafe { libc::kill(child.id() as i32, signal) };
    assert_eq!(rc, 0);
    let status = child.wait().unwrap();
    assert!(status.success(), "exit status {status:?}");
    // A fleet's vehicles, a line each, were printed after the endpoints.
    let vehicles: Vec<String> = lines.map_while(Result::ok).collect();
    assert!(!psd_link.exists() && !can_link.exists(), "links removed");
    let text = std::fs::read_to_string(&truth_path).expect("truth written");
    if truth.ends_with(".json") {
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert!(v["summary"]["duration"].as_f64().unwrap() >= 0.0);
        assert!(!v["samples"].as_array().unwrap().is_empty());
    } else {
        assert!(text.starts_with("t,x,y,heading,v_left,v_right,min_clearance,wall_clearance,contact,o0x,o0y"));
        assert!(text.lines().count() >= 2);
    }
    let _ = std::fs::remove_dir_all(&dir);
    (vehicles, text)
}

#[test]
fn sigint_exits_cleanly_with_truth_json() {
    let (vehicles, _) = run_until_signal(libc::SIGINT, "e1-standing-obstacle.toml", "truth.json");
    assert!(vehicles.is_empty(), "the robot alone: {vehicles:?}");
}

#[test]
fn sigterm_exits_cleanly_with_truth_csv() {
    run_until_signal(libc::SIGTERM, "e1-standing-obstacle.toml", "truth.csv");
}

/// A fleet's scenario: each vehicle's LEDs and board are printed, and the truth names
/// every vehicle (JSON: each one's summary and pose at every sample; CSV: its columns).
#[test]
fn a_fleet_is_served_and_its_vehicles_named() {
    let (vehicles, text) = run_until_signal(libc::SIGINT, "fleet/e5-scripted.toml", "truth.json");
    assert_eq!(vehicles, ["vehicle robot: LEDs 1 and 2, board node 1", "vehicle crossing: LEDs 4 and 5, board node 2"]);
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let names: Vec<&str> =
        v["summary"]["vehicles"].as_array().unwrap().iter().map(|v| v["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["robot", "crossing"]);
    assert_eq!(v["samples"][0]["vehicles"][0]["name"], "crossing");
    let (_, csv) = run_until_signal(libc::SIGTERM, "fleet/e5-scripted.toml", "truth.csv");
    let header = csv.lines().next().unwrap();
    assert!(header.ends_with(",o0x,o0y,crossing_x,crossing_y,crossing_heading"), "{header}");
}

#[test]
fn a_bad_can_endpoint_is_refused_with_a_clear_message() {
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/e1-standing-obstacle.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_flowgate-sim"))
        .arg("--scenario")
        .arg(&scenario)
        .args(["--can", "vcan0"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("expected `slcan-pty` or `socketcan:IFACE`"));
    // This machine's kernel has no CAN: the error must say what to check.
    let out = Command::new(env!("CARGO_BIN_EXE_flowgate-sim"))
        .arg("--scenario")
        .arg(&scenario)
        .args(["--can", "socketcan:vcan9"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("cannot open CAN interface vcan9"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// An error printed to a pipe is one line: no colours, no backtrace block, whatever
/// RUST_BACKTRACE says.
#[test]
fn an_error_in_a_pipe_is_one_plain_line() {
    let out = Command::new(env!("CARGO_BIN_EXE_flowgate-sim"))
        .args(["--scenario", "/dev/zero"])
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("Error: cannot read scenario /dev/zero: longer than 1048576 bytes"), "{err}");
    assert!(!err.contains('\x1b') && !err.contains("backtrace"), "{err}");
}
