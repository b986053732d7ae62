//! Every subcommand with its standard output closed under it (`flowgate ... | head -1`,
//! `| true`): it ends with the status of a writer whose reader went away (141, as SIGPIPE
//! gives a shell) or its own, never a panic (101).

use std::path::Path;
use std::process::{Command, Stdio};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Run flowgate with a standard output whose reader is already closed; its exit code and
/// standard error.
fn with_closed_stdout(args: &[&str]) -> (Option<i32>, String) {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(args)
        .current_dir(root())
        .stdin(Stdio::null())
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
}

fn assert_no_panic(args: &[&str], expected: i32) {
    let (code, stderr) = with_closed_stdout(args);
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    assert_eq!(code, Some(expected), "{args:?}: {stderr}");
}

#[test]
fn commands_that_print_end_quietly_at_a_closed_stdout() {
    let e1 = root().join("scenarios/e1-standing-obstacle.toml");
    let out = std::env::temp_dir().join(format!("flowgate-closed-pipe-{}", std::process::id()));
    let out = out.to_str().unwrap();
    // Commands whose output is what they are for: 141 at the first line.
    assert_no_panic(&["plan", "--all", "scenarios", "--planner-only", "--out", out], 141);
    assert_no_panic(&["plan", "--planner-only", "--out", out, e1.to_str().unwrap()], 141);
    assert_no_panic(&["check", "--config", "rig.example.toml"], 141);
    assert_no_panic(&["bench", "--quick", "--out", out], 141);
    // Commands that fail before printing anything say so on stderr, with their own status.
    assert_no_panic(&["ctl", "--socket", "/nonexistent/flowgate.sock", "status"], 1);
    assert_no_panic(&["run", "--config", "/nonexistent/rig.toml"], 1);
    assert_no_panic(&["calibrate", "--config", "/nonexistent/rig.toml"], 1);
    assert_no_panic(&["replay", "/nonexistent/run.mcap"], 1);
    assert_no_panic(&["record", "info", "/nonexistent/run.mcap"], 1);
    // Help and version.
    for sub in ["demo", "check", "calibrate", "run", "replay", "record", "ctl", "bench", "plan"] {
        let (code, stderr) = with_closed_stdout(&[sub, "--help"]);
        assert!(!stderr.contains("panicked") && code != Some(101), "{sub} --help: {code:?} {stderr}");
    }
    let (code, stderr) = with_closed_stdout(&["--version"]);
    assert!(!stderr.contains("panicked") && code != Some(101), "--version: {code:?} {stderr}");
    let _ = std::fs::remove_dir_all(out);
}

/// The demo prints its result as it ends: a closed stdout then ends it with 141 too.
#[test]
fn the_demo_ends_quietly_at_a_closed_stdout() {
    let out = std::env::temp_dir().join(format!("flowgate-closed-pipe-demo-{}", std::process::id()));
    let e1 = root().join("scenarios/e1-standing-obstacle.toml");
    assert_no_panic(&["demo", "--scenario", e1.to_str().unwrap(), "--out", out.to_str().unwrap()], 141);
    let _ = std::fs::remove_dir_all(out);
}
