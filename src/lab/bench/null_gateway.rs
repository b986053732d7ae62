//! The floor: a "gateway" that does no work, run as its own process (`flowgate
//! null-gateway`, hidden) so that it pays the same process wake-ups as the gateway.
//!
//! It opens the same two endpoints the same way as the gateway (tokio-serial on the PSD pty;
//! SLCAN on a pty or a SocketCAN socket, through `link`), on the same single-threaded
//! runtime, and answers every frame end with a fixed velocity command at once. What it
//! measures is the pty, the scheduler and the CAN transport on this machine, with
//! flowgate's work taken out. With `spin` it polls for frames as the gateway's low-latency
//! mode does ([`SpinWindow`]), so that mode has a floor too; with real-time settings it
//! applies them as the gateway does, so those have one as well.

use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

use bytes::BytesMut;
use flowgate_protocol::canopen;
use flowgate_protocol::codec::PsdCodec;
use flowgate_protocol::motor::{MotorMessage, NodeId};
use flowgate_protocol::psd::{Message, Packet};
use tokio::io::{AsyncBufReadExt, AsyncReadExt as _};
use tokio_util::codec::Decoder;

use crate::config::CanUrl;
use crate::gateway::shell::link::{open_can, open_serial};
use crate::gateway::shell::low_latency::{SpinWindow, Wait};
use crate::gateway::shell::realtime::RealtimeSettings;

/// What the process prints once both endpoints are open.
pub const READY: &str = "null gateway ready";

/// Serve until the PSD line or the CAN link closes; `ready` is called once both are open.
/// With `cia402`, each frame end is answered with an RPDO1 to each of the two drives instead
/// of one velocity frame, as the gateway's CiA 402 backend sends.
pub async fn serve(
    psd_path: &Path,
    can: &CanUrl,
    spin: Option<Duration>,
    cia402: Option<[canopen::NodeId; 2]>,
    ready: impl FnOnce(),
) -> std::io::Result<()> {
    let mut psd = open_serial(psd_path, super::BAUD).map_err(std::io::Error::other)?;
    let mut can = open_can(can).await.map_err(std::io::Error::other)?;
    ready();
    // Node 2: on a shared SocketCAN bus the gateway (node 1) must not take the null
    // gateway's commands for a second master on its own board's id.
    let node = NodeId::new(2).expect("2");
    let mut rx = BytesMut::with_capacity(4096);
    let mut codec = PsdCodec::new();
    let mut seq = 0u8;
    let mut window = spin.map(SpinWindow::new);
    loop {
        let wait = window.as_ref().map_or(Wait::Sleep, |w| w.wait(std::time::Instant::now()));
        tokio::select! {
            n = psd.read_buf(&mut rx) => {
                if !matches!(n, Ok(n) if n > 0) {
                    return Ok(());
                }
                while let Ok(Some(item)) = codec.decode(&mut rx) {
                    if let Ok(Packet { message: Message::FrameEnd { .. }, .. }) = item {
                        if let Some(w) = &mut window {
                            w.frame(std::time::Instant::now());
                        }
                        match cia402 {
                            None => {
                                let m = MotorMessage::Velocity { node, left: 0, right: 0, seq };
                                seq = seq.wrapping_add(1);
                                can.send(m.to_frame().expect("valid")).await.map_err(std::io::Error::other)?;
                            }
                            Some(drives) => {
                                for drive in drives {
                                    let data = canopen::VelocityCommand { controlword: 0x000F, target_velocity: 0 }.data();
                                    let m = canopen::CanOpenMessage::Pdo {
                                        direction: canopen::PdoDirection::Receive,
                                        number: 1,
                                        node: drive,
                                        data,
                                    };
                                    can.send(m.to_frame().expect("valid")).await.map_err(std::io::Error::other)?;
                                }
                            }
                        }
                    }
                }
            }
            // Drain what the bus says (SLCAN acks) so its buffer never fills.
            e = can.recv() => {
                e.map_err(std::io::Error::other)?;
            }
            () = wait.pause() => {}
        }
    }
}

/// The null gateway's process, seen from the bench.
#[derive(Debug)]
pub struct NullGatewayProcess {
    child: tokio::process::Child,
    pub pid: u32,
}

impl NullGatewayProcess {
    /// Start `exe null-gateway` on the two endpoints; return once it says both are open
    /// (within 5 s), or with what it said when it could not.
    pub async fn start(
        exe: &Path,
        psd_path: &Path,
        can_endpoint: &str,
        spin: Option<Duration>,
        realtime: &RealtimeSettings,
        cia402: Option<[canopen::NodeId; 2]>,
    ) -> std::io::Result<Self> {
        let mut cmd = tokio::process::Command::new(exe);
        cmd.arg("null-gateway").arg("--psd").arg(psd_path).args(["--can", can_endpoint]);
        if let Some(s) = spin {
            cmd.args(["--spin-us", &s.as_micros().to_string()]);
        }
        for cpu in &realtime.cpus {
            cmd.args(["--cpu", &cpu.to_string()]);
        }
        if let Some(p) = realtime.fifo_priority {
            cmd.args(["--fifo-priority", &p.to_string()]);
        }
        if realtime.lock_memory {
            cmd.arg("--lock-memory");
        }
        if let Some([left, right]) = cia402 {
            cmd.args(["--cia402-drives", &format!("{},{}", left.get(), right.get())]);
        }
        // Its errors go to the bench's stderr, where the user sees them.
        let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::inherit()).kill_on_drop(true).spawn()?;
        let pid = child.id().unwrap_or(0);
        let stdout = child.stdout.take().expect("piped");
        let mut lines = tokio::io::BufReader::new(stdout).lines();
        match tokio::time::timeout(Duration::from_secs(5), lines.next_line()).await {
            Ok(Ok(Some(line))) if line == READY => Ok(Self { child, pid }),
            said => {
                let _ = child.start_kill();
                let why = match said {
                    Err(_) => "no word within 5 s".to_string(),
                    Ok(Ok(Some(line))) => format!("it said `{line}`"),
                    Ok(Ok(None)) => "it exited (its error above)".to_string(),
                    Ok(Err(e)) => e.to_string(),
                };
                Err(std::io::Error::other(format!("the null gateway did not start: {why}")))
            }
        }
    }

    /// Its /proc directory, for CPU time and memory.
    pub fn proc_dir(&self) -> String {
        format!("/proc/{}", self.pid)
    }

    /// Stop it and wait, so its ports are closed.
    pub async fn stop(mut self) {
        let _ = self.child.kill().await;
    }
}
