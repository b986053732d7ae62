//! Every surface a file or a flag reaches, probed as a hostile user would (docs/hostile-input.md):
//! damaged recordings, endless and enormous config and scenario files, implausible
//! quantities, escape sequences. Each is refused or read to where it stops, with the key,
//! the limit or the byte named; nothing panics, aborts or exhausts memory. (The control
//! socket's probes are in tests/control_socket.rs.)

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use flowgate::replay::{Recording, RecordingInfo};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("flowgate-hostile-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Run flowgate; its exit code (`None`: killed by a signal, as an abort is) and its output.
fn flowgate(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowgate")).args(args).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.code(), text)
}

/// Exit 0 or 1 and no sign of a panic or an abort.
fn ended_in_words(code: Option<i32>, text: &str) {
    assert!(matches!(code, Some(0 | 1)), "exit {code:?}: {text}");
    for sign in ["panicked", "memory allocation", "backtrace", "RUST_BACKTRACE"] {
        assert!(!text.contains(sign), "{sign}: {text}");
    }
}

/// A real recording: the demo's, over real ptys.
fn demo_recording(dir: &Path) -> Vec<u8> {
    let mcap = dir.join("demo.mcap");
    let (code, text) =
        flowgate(&["demo", "--out", dir.join("demo").to_str().unwrap(), "--record", mcap.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{text}");
    std::fs::read(&mcap).unwrap()
}

#[test]
fn damaged_recordings_are_read_to_the_damage_and_never_crash_the_tools() {
    let dir = temp_dir("recordings");
    let whole = demo_recording(&dir);
    let len = whole.len();
    // 400 single flipped bytes spread over the file, 60 cuts, 20 files of noise.
    let mut damaged: Vec<(String, Vec<u8>)> = Vec::new();
    for i in 0..400 {
        let at = (i * 7919 + 13) % len;
        let mut bytes = whole.clone();
        bytes[at] ^= 1 << (i % 8);
        damaged.push((format!("byte {at} flipped"), bytes));
    }
    for i in 0..60 {
        let at = i * len / 60;
        damaged.push((format!("cut at byte {at}"), whole[..at].to_vec()));
    }
    let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
    for i in 0..20 {
        let mut noise = whole[..8.min(len)].to_vec(); // the magic, then noise
        noise.extend((0..(i + 1) * 997).map(|_| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed as u8
        }));
        damaged.push((format!("noise {i}"), noise));
    }
    let mut cut_short = 0;
    for (what, bytes) in &damaged {
        match Recording::from_reader(bytes.as_slice(), what) {
            Ok(r) => cut_short += usize::from(r.truncated.is_some()),
            Err(e) => assert!(!e.to_string().is_empty(), "{what}"),
        }
        if let Ok(info) = RecordingInfo::scan(|| Ok(bytes.as_slice()), bytes.len() as u64, what) {
            assert!(!info.to_string().is_empty(), "{what}");
        }
    }
    // Most flips land in a chunk: its CRC stops the reading there, and says so.
    assert!(cut_short > 300, "{cut_short} of {} read as cut short", damaged.len());

    // The tools, on a flip inside a compressed chunk (where a length is read from damage), a cut
    // and noise: each ends in words, and says the recording is cut short.
    let probes = [(60_000.min(len - 1), "flipped"), (len * 2 / 3, "cut"), (0, "noise")];
    for (at, kind) in probes {
        let bytes = match kind {
            "flipped" => {
                let mut b = whole.clone();
                b[at] ^= 0xff;
                b
            }
            "cut" => whole[..at].to_vec(),
            _ => damaged.last().unwrap().1.clone(),
        };
        let file = dir.join(format!("{kind}.mcap"));
        std::fs::write(&file, &bytes).unwrap();
        let f = file.to_str().unwrap();
        let (code, info) = flowgate(&["record", "info", f]);
        ended_in_words(code, &info);
        let (code, replay) = flowgate(&["replay", f]);
        ended_in_words(code, &replay);
        let bag = dir.join(format!("{kind}-bag"));
        let (code, export) = flowgate(&["record", "export", "--ros2", bag.to_str().unwrap(), f]);
        ended_in_words(code, &export);
        if kind != "noise" {
            assert_eq!(code, Some(1), "{export}");
            assert!(info.contains("cut short"), "{info}");
            assert!(export.contains("is cut short at ") && export.contains(" s of its run"), "{export}");
            assert!(bag.join("metadata.yaml").exists(), "the bag of what came before: {export}");
        } else {
            assert!(!bag.exists(), "a failed export leaves no folder: {export}");
        }
    }
    // No half-written bag is left anywhere.
    let debris: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().contains(".partial"))
        .collect();
    assert!(debris.is_empty(), "{debris:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_empty_file_is_not_a_whole_recording() {
    let dir = temp_dir("empty");
    let empty = dir.join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    let (code, text) = flowgate(&["record", "info", empty.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("is not an MCAP file: no MCAP header in its 0 bytes") && !text.contains("whole"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A scenario or config that no real one resembles is refused in under a second, with the
/// limit and the key named.
#[test]
fn enormous_and_endless_files_are_refused_quickly_naming_the_limit() {
    let dir = temp_dir("files");
    let e1 = std::fs::read_to_string(root().join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let walls: String = (0..10_000)
        .map(|i| format!("\n[[walls]]\npoints = [[{:.4}, -0.4], [{:.4}, -0.39]]\n", i as f64 * 1e-4, i as f64 * 1e-4))
        .collect();
    let points: String = (0..50_000).map(|i| format!("[{:.5}, -0.4],", i as f64 * 1e-5)).collect();
    let obstacles: String = (0..10_000)
        .map(|i| format!("\n[[obstacles]]\nradius = 0.01\nstart = [0.3, {:.3}]\n", i as f64 * 1e-3))
        .collect();
    let big = format!("{e1}\n# {}\n", "x".repeat(2 << 20));
    let cases: Vec<(String, &str)> = vec![
        (big, "longer than 1048576 bytes"),
        (format!("{e1}{walls}"), "`walls` has 10000 entries: at most 64"),
        (format!("{e1}\n[[walls]]\npoints = [{points}]\n"), "`walls[0].points` has 50000 entries: at most 256"),
        (format!("{e1}{obstacles}"), "`obstacles` has 10001 entries: at most 14"),
        (e1.replace("wheel_base = 0.108", "wheel_base = 1e308"), "`robot.wheel_base` must be at most 2 m, is 1e308"),
        (
            e1.replace("position_noise = 0.001", "position_noise = 1e308"),
            "`sensing.position_noise` must be at most 2 m",
        ),
        (e1.replace("lowpass_hz = 0.0", "lowpass_hz = 1e308"), "`sensing.lowpass_hz` must be at most 1000 Hz"),
        (e1.replace("[goal]", "[goal]\ntolerance = 1e300"), "`goal.tolerance` must be at most 1 m"),
        (e1.replace("name = \"", "name = \"\\u001b[2J"), "`name` holds the control character"),
    ];
    for (i, (text, says)) in cases.iter().enumerate() {
        assert_ne!(text, &e1, "case {i} changed nothing");
        let file = dir.join(format!("case-{i}.toml"));
        std::fs::write(&file, text).unwrap();
        let started = Instant::now();
        let (code, out) = flowgate(&["plan", "--scenario", file.to_str().unwrap()]);
        let took = started.elapsed();
        assert_eq!(code, Some(1), "case {i}: {out}");
        assert!(out.contains(says), "case {i}: {out}");
        assert!(took < Duration::from_secs(1), "case {i} took {took:?}: {out}");
    }
    // An endless file: /dev/zero, as a scenario and as a rig config.
    for args in [&["plan", "--scenario", "/dev/zero"][..], &["check", "--config", "/dev/zero"]] {
        let started = Instant::now();
        let (code, out) = flowgate(args);
        assert_eq!(code, Some(1), "{out}");
        assert!(out.contains("/dev/zero: longer than 1048576 bytes"), "{out}");
        assert!(started.elapsed() < Duration::from_secs(1), "{args:?} took {:?}", started.elapsed());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The rig config's quantities, bounded as the scenario's are, the key named.
#[test]
fn implausible_rig_quantities_are_refused_naming_the_key() {
    let rig = std::fs::read_to_string(root().join("rig.example.toml")).unwrap();
    let set = |key: &str, value: &str| {
        let mut doc: toml_edit::DocumentMut = rig.parse().unwrap();
        let (section, name) = key.split_once('.').unwrap();
        doc[section][name] = toml_edit::value(value.parse::<f64>().unwrap());
        doc.to_string()
    };
    for (key, value, says) in [
        ("drive.wheel_base", "1e308", "must be at most 2 m, is 1e308"),
        ("drive.max_wheel_speed", "1e9", "must be at most 10 m/s"),
        ("drive.wheel_accel", "1e9", "must be at most 100 m/s²"),
        ("goal.tolerance", "1e300", "must be at most 1 m"),
        ("planner.kc", "1e300", "must be at most 1000000"),
    ] {
        let err = flowgate::config::RigFile::from_toml(&set(key, value), "rig.toml")
            .and_then(|c| c.rig("rig.toml"))
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.contains(&format!("`{key}` {says}")), "{key}: {err}");
    }
}

/// A run that fails at start (its serial port and CAN adapter missing) leaves no empty run
/// folder, and `latest` still names the run before it.
#[test]
fn a_failed_run_leaves_no_folder_and_latest_as_it_was() {
    let dir = temp_dir("run");
    let out = dir.join("runs");
    std::fs::create_dir_all(out.join("20260101T000000Z")).unwrap();
    std::os::unix::fs::symlink("20260101T000000Z", out.join("latest")).unwrap();
    let mut doc: toml_edit::DocumentMut =
        std::fs::read_to_string(root().join("rig.example.toml")).unwrap().parse().unwrap();
    doc["serial"]["port"] = toml_edit::value(dir.join("no-such-tty").display().to_string());
    doc["can"]["endpoint"] = toml_edit::value(format!("slcan:{}?bitrate=1000000", dir.join("no-such-can").display()));
    doc["telemetry"]["out_dir"] = toml_edit::value(out.display().to_string());
    doc["operator"]["socket"] = toml_edit::value(dir.join("control.sock").display().to_string());
    let config = dir.join("rig.toml");
    std::fs::write(&config, doc.to_string()).unwrap();
    let (code, text) = flowgate(&["run", "--config", config.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("does not exist"), "{text}");
    let runs: Vec<String> =
        std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(runs.len(), 2, "{runs:?}");
    assert_eq!(std::fs::read_link(out.join("latest")).unwrap(), PathBuf::from("20260101T000000Z"));
    let _ = std::fs::remove_dir_all(&dir);
}
