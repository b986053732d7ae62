//! What the tests of a running gateway process share: `flowgate run --arm` on E1, its PSD
//! controller and SLCAN adapter the simulator's ptys, the config as a test adjusts it.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use flowgate::config::RigFile;
use flowgate::lab::Scenario;
use flowgate_sim::rig::{RigConfig, RigHandle};

/// A gateway process driving the simulated rig.
pub struct RunningGateway {
    pub process: Child,
    pub rig: RigHandle,
    dir: PathBuf,
}

/// A free loopback address (the OS's pick, released for the gateway to take).
pub fn free_loopback_addr() -> std::net::SocketAddr {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap()
}

/// Start the simulator and `flowgate run --arm` on it, its config adjusted by `configure`.
pub async fn run_on_sim(name: &str, configure: impl FnOnce(&mut RigFile)) -> RunningGateway {
    let dir = std::env::temp_dir().join(format!("flowgate-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let s = Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml")).unwrap();
    let rig = flowgate_sim::rig::start(RigConfig::new(s.sim.clone())).await.unwrap();
    let can = format!("slcan:{}?bitrate=1000000", rig.can_path.as_ref().unwrap().display());
    let mut cfg = s.rig_file(&rig.psd_path, &can, None);
    configure(&mut cfg);
    let config = dir.join("rig.toml");
    std::fs::write(&config, cfg.to_toml()).unwrap();
    let process = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["run", "--arm", "--config"])
        .arg(&config)
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    RunningGateway { process, rig, dir }
}

impl RunningGateway {
    /// Kill the gateway, stop the simulator, remove the files.
    pub async fn stop(mut self) {
        let _ = self.process.kill();
        let _ = self.process.wait();
        self.rig.stop().await;
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}
