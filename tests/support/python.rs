//! The Python interpreter the tests run their peers with, and where the peers are: one
//! lookup for every test of the workspace (each crate's tests include this file by path).
//!
//! `FLOWGATE_PYTHON` when set (`scripts/test` sets it to its venv, `target/py`, with the peer
//! tools installed); otherwise that venv if it exists. Anything else is a clear failure: the
//! system's Python has none of the peers' packages, and a test must not pass or fail by which
//! of them a machine happens to have.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The interpreter with the peers' packages.
pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("FLOWGATE_PYTHON") {
        return PathBuf::from(p);
    }
    // The workspace's venv, above whichever crate's tests run.
    let venv =
        Path::new(env!("CARGO_MANIFEST_DIR")).ancestors().map(|d| d.join("target/py/bin/python")).find(|p| p.exists());
    venv.expect(
        "no Python for the peer tools: run the tests through scripts/test (it makes the venv target/py), \
         or set FLOWGATE_PYTHON",
    )
}

/// The peer of the test `name`, in the calling crate's `tests/peers/`.
pub fn peer(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/peers").join(format!("{name}.py"))
}

/// `program` run at a lower scheduling priority (`nice -n 10`), for a peer that shares the
/// machine with a gateway running in real time: a browser starting up on a two-core machine
/// must not starve the gateway's watchdogs, as it would not on a rig whose gateway has a
/// core to itself.
pub fn niced(program: &Path) -> std::process::Command {
    let mut command = std::process::Command::new("nice");
    command.args(["-n", "10"]).arg(program);
    command
}
