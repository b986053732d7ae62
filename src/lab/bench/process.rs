//! The gateway under test: its rig config, its process, and the CPU time it spent.

use super::pace::Pacer;
use super::peers::{CanSide, Commands, Controller};
use super::{board_alive, can_side, BenchMotors, Mode, Transport};
use crate::gateway::shell::control_client::{ClientError, ControlClient};
use crate::gateway::shell::telemetry::StageSummary;
use std::path::Path;
use std::time::{Duration, Instant};

/// CPU seconds used and resident set size (MB) of a process or thread, from its /proc
/// directory (`/proc/PID` or `/proc/self/task/TID`).
pub(super) fn proc_stat(dir: &str) -> (f64, f64) {
    let ticks = 100.0; // USER_HZ on Linux
    let stat = std::fs::read_to_string(format!("{dir}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let cpu = fields.get(11).and_then(|u| u.parse::<f64>().ok()).unwrap_or(0.0)
        + fields.get(12).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0);
    let status = std::fs::read_to_string(format!("{dir}/status")).unwrap_or_default();
    let rss_kb = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(0.0);
    (cpu / ticks, rss_kb / 1024.0)
}

/// The gateway's configuration for the bench. Its watchdogs are set long (30 s, the board's
/// timeout beyond them as the config requires): it idles while the null gateway has its
/// turn, and under emulation (vcan in the VM) a turn can stretch; the watchdogs themselves
/// are tested in tests/fault_table.rs. So is its stall check, set to an hour here: the
/// bench's robot swings to and fro whatever the gateway commands, and after an idle turn it
/// may be back within a centimetre of where it was, which a rig's robot would not be.
/// Its control socket answers the bench's `stats`.
pub(super) fn rig_toml(psd: &Path, can_endpoint: &str, motors: &BenchMotors, socket: &Path, mode: &Mode) -> String {
    let h = flowgate_sim::camera::CameraModel::default().homography;
    // The schedule's period only bounds the low-latency window (twice it must fit in T);
    // the bench streams at its own rates.
    let spin_us = mode.spin_us;
    let slot_us = 500.max(spin_us + 100);
    let rt = &mode.realtime;
    let view = if mode.view { "view = \"127.0.0.1:0\"\n" } else { "" };
    // A domain of its own, on loopback: the node publishes with no one to hear it.
    let ros2 =
        if mode.ros2 { "[ros2]\nenabled = true\ndomain_id = 231\ndiscovery_range = \"localhost\"\n" } else { "" };
    // CiA 402 drives: the bench answers their configuration at once, but under emulation
    // (vcan in the VM) a turn of the null gateway may hold it up.
    let (node, protocol, cia402) = match *motors {
        BenchMotors::Board(node) => (node.get(), "pcl80k", String::new()),
        BenchMotors::Cia402 { left, right, gateway } => (
            1,
            "cia402",
            format!(
                "[cia402]\nleft_node = {}\nright_node = {}\ngateway_node = {}\nsdo_timeout_ms = 5000\nenable_timeout_ms = 30000\n",
                left.get(),
                right.get(),
                gateway.get()
            ),
        ),
    };
    let record = if mode.record {
        format!("[telemetry]\nrecord = \"{}\"\n", socket.with_extension("mcap").display())
    } else {
        String::new()
    };
    format!(
        "[serial]\nport = \"{}\"\n[leds]\nrobot_front = 1\nrobot_rear = 2\nfront_offset = 0.035\nrear_offset = 0.035\n\
         [schedule]\nslot_us = {slot_us}\n[calibration]\nhomography = {h:?}\n[can]\nendpoint = \"{can_endpoint}\"\nprotocol = \"{protocol}\"\nnode = {node}\n{cia402}\
         [drive]\nwheel_radius = 0.025\nsteps_per_rev = 200\nmicrosteps = 8\nwheel_base = 0.108\nmax_wheel_speed = 0.25\nwheel_accel = 1.0\ncommand_timeout_ms = 31000\n\
         [robot]\nradius = 0.07\nmax_speed = 0.15\n[goal]\nposition = [0.75, 0.0]\n[planner]\ncruise_speed = 0.1\nc1 = 20\nkc = 0.1\n\
         [safety]\nsample_timeout_ms = 30000\npose_timeout_ms = 30000\nocclusion_timeout_ms = 31000\nheartbeat_timeout_ms = 30000\nbad_frames_per_s = 1000\nstall_window_ms = 3600000\n\
         [operator]\nsocket = \"{}\"\n{view}[realtime]\nspin_us = {spin_us}\nwarm_up = {}\ncpus = {:?}\nfifo_priority = {}\nlock_memory = {}\n{record}{ros2}",
        psd.display(),
        socket.display(),
        mode.warm_up,
        rt.cpus,
        rt.fifo_priority.unwrap_or(0),
        rt.lock_memory,
    )
}

/// A gateway process (`flowgate run --arm`), as the bench drives it.
pub(super) struct GatewayProcess {
    child: tokio::process::Child,
    log: std::path::PathBuf,
    socket: std::path::PathBuf,
}

impl GatewayProcess {
    /// Start it on `target`'s endpoints and bring it up: answer its requests, be a live
    /// board, stream at 50 Hz until it commands.
    pub(super) async fn start(
        exe: &Path,
        target: &mut Target,
        workdir: &Path,
        name: &str,
        motors: BenchMotors,
        mode: &Mode,
    ) -> std::io::Result<Self> {
        let config = workdir.join(format!("{name}.toml"));
        // Sockets in the temporary directory: the output folder may be on a file system
        // without them (the VM's 9p share, where scripts/vcan-vm runs the bench).
        let sockets = std::env::temp_dir().join(format!("flowgate-bench-{}", std::process::id()));
        std::fs::create_dir_all(&sockets)?;
        let socket = sockets.join(format!("{name}.sock"));
        std::fs::write(&config, rig_toml(&target.controller.path, &target.can.endpoint, &motors, &socket, mode))?;
        let log = workdir.join(format!("{name}.log"));
        let mut child = tokio::process::Command::new(exe)
            .args(["run", "--arm", "--config"])
            .arg(&config)
            .stdout(std::fs::File::create(&log)?)
            .kill_on_drop(true)
            .spawn()?;
        target.proc_dir = format!("/proc/{}", child.id().unwrap_or(0));
        let board = (target.can.board(), motors);
        let started = Instant::now();
        let mut pacer = Pacer::new(Duration::from_millis(20));
        let mut commands = 0;
        while commands < 20 {
            if started.elapsed() > Duration::from_secs(15) {
                let _ = child.kill().await;
                return Err(std::io::Error::other(format!("{name} did not start commanding within 15 s")));
            }
            if let Some(status) = child.try_wait()? {
                let said = std::fs::read_to_string(&log).unwrap_or_default();
                return Err(std::io::Error::other(format!("{name} exited ({status}) while starting: {}", said.trim())));
            }
            pacer.wait();
            board_alive(&board);
            target.controller.frame()?;
            commands += target.can.commands.try_iter().count();
        }
        Ok(Self { child, log, socket })
    }

    /// Its stage statistics since the last call (`flowgate ctl stats --reset` over its
    /// control socket), within 2 s.
    pub(super) async fn stages(&self) -> std::io::Result<Vec<StageSummary>> {
        let socket = self.socket.clone();
        let ask = move || {
            let status = ControlClient::connect_with(&socket, Duration::from_secs(2))?.stats(true)?;
            status.stages.ok_or(ClientError::NoStatus("stats"))
        };
        tokio::task::spawn_blocking(ask)
            .await
            .map_err(std::io::Error::other)?
            .map_err(|e| std::io::Error::other(format!("{}: {e}", self.socket.display())))
    }

    /// Stop it; its state lines ("state: running", ...) say why it stopped commanding, if it did.
    pub(super) async fn stop(mut self) -> Vec<String> {
        // In order (SIGTERM: a recording is closed), killed if it takes over 5 s.
        let term = self
            .child
            .id()
            .and_then(|id| rustix::process::Pid::from_raw(id as i32))
            .map(|pid| rustix::process::kill_process(pid, rustix::process::Signal::TERM));
        let ended = matches!(term, Some(Ok(())))
            && tokio::time::timeout(Duration::from_secs(5), self.child.wait()).await.is_ok();
        if !ended {
            let _ = self.child.kill().await;
        }
        std::fs::read_to_string(&self.log)
            .unwrap_or_default()
            .lines()
            .filter_map(|l| l.strip_prefix("state: ").map(str::to_string))
            .collect()
    }
}

/// One side of the comparison: a PSD pty and a CAN side, and the /proc entry of the process
/// whose CPU time counts.
pub(super) struct Target {
    pub(super) controller: Controller,
    pub(super) can: CanSide,
    pub(super) proc_dir: String,
    /// The bench's CAN reader polls during this target's blocks (the low-latency rows).
    pub(super) poll_can: bool,
}

impl Target {
    pub(super) fn new(transport: &Transport, poll_can: bool, commands: Commands) -> std::io::Result<Self> {
        let can = can_side(transport, commands)?;
        Ok(Self { controller: Controller::new()?, can, proc_dir: String::new(), poll_can })
    }
}
