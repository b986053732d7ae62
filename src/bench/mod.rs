//! The gateway benchmark (`flowgate bench`): the gateway as a separate process between a
//! scripted PSD controller (a pty) and a scripted CAN bus (an SLCAN adapter on a pty, or a
//! SocketCAN interface), both played here so that every time is taken at the wire.
//!
//! Gateway-added latency of a cycle: from the moment the last byte of the cycle's frames
//! (its `FrameEnd`) has been written into the PSD pty, to the moment the resulting velocity
//! command is readable on the bus. It includes the pty and the CAN transport, and is stated
//! beside the wire time of the same traffic at the configured rates, so a user can read off
//! whether flowgate or the wire is the bottleneck.

use std::path::{Path, PathBuf};
use std::time::Duration;

use bytes::BytesMut;
use flowgate_protocol::codec::{PsdCodec, SlcanAdapterCodec};
use flowgate_protocol::motor::{BoardState, FaultBits, MotorMessage, NodeId};
use flowgate_protocol::psd::{self, Info, Message, Packet, Sample, SampleFlags};
use flowgate_protocol::slcan::{Command, Line, Response};
use flowgate_protocol::CanFrame;
use hdrhistogram::Histogram;
use serde::Serialize;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::Instant;
use tokio_util::codec::Decoder;

/// The PSD line's baud rate and the CAN bitrate the wire times are stated for.
pub const BAUD: u32 = 921_600;
pub const CAN_BITRATE: u32 = 1_000_000;

/// One measured phase.
#[derive(Debug, Clone, Serialize)]
pub struct Phase {
    pub name: String,
    /// Time-division frames per second the controller sent.
    pub frame_rate_hz: f64,
    pub samples_per_s: f64,
    pub cycles_sent: u64,
    pub commands_received: u64,
    /// Cycles whose command came back after the next frame was due (latency > period), %.
    pub late_percent: f64,
    pub latency_us: Percentiles,
    /// Gateway CPU over the phase, percent of one core.
    pub cpu_percent: f64,
    /// Gateway resident set size: at the start, peak and at the end of the phase, MB.
    pub rss_mb: [f64; 3],
}

#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Percentiles {
    pub p50: f64,
    pub p99: f64,
    pub p999: f64,
    pub max: f64,
}

/// The wire time of one cycle's traffic.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Wire {
    /// One sample frame (33 bytes, 10 bits each) at `BAUD`, µs.
    pub sample_frame_us: f64,
    /// One velocity command on CAN at `CAN_BITRATE` (11-bit id, DLC 7, no stuffing), µs.
    pub command_frame_us: f64,
    /// The same command as an SLCAN line over a `BAUD` serial link, µs.
    pub command_slcan_us: f64,
}

impl Wire {
    pub fn new() -> Self {
        let sample = psd::SAMPLE_WIRE_LEN as f64 * 10.0 / f64::from(BAUD) * 1e6;
        let can_bits = 1 + 11 + 3 + 4 + 8 * 7 + 15 + 3 + 7 + 3; // SOF id RTR/IDE/r0 DLC data CRC ACK EOF IFS
        let slcan_line = 1 + 3 + 1 + 14 + 1;
        Self {
            sample_frame_us: sample,
            command_frame_us: f64::from(can_bits) / f64::from(CAN_BITRATE) * 1e6,
            command_slcan_us: f64::from(slcan_line) * 10.0 / f64::from(BAUD) * 1e6,
        }
    }
}

impl Default for Wire {
    fn default() -> Self {
        Self::new()
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    pub transport: String,
    pub wire: Wire,
    pub phases: Vec<Phase>,
    /// The highest rate sustained with no lost command and under 1% late cycles, in
    /// samples/s (two LEDs per frame).
    pub sustained_samples_per_s: f64,
    pub planner_note: &'static str,
}

/// Gateway process statistics from /proc.
fn proc_stat(pid: u32) -> (f64, f64) {
    let ticks = 100.0; // USER_HZ on Linux
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let cpu = fields.get(11).and_then(|u| u.parse::<f64>().ok()).unwrap_or(0.0)
        + fields.get(12).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0);
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let rss_kb = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(0.0);
    (cpu / ticks, rss_kb / 1024.0)
}

/// The scripted rig the gateway talks to. The CAN side (an SLCAN adapter with a board
/// behind it) runs in its own tasks: a reader that stamps each velocity command the moment
/// its line is read and answers the gateway's lines, and a writer.
struct Rig {
    psd: tokio_serial::SerialStream,
    psd_buf: BytesMut,
    psd_codec: PsdCodec,
    can_tx: tokio::sync::mpsc::UnboundedSender<Vec<u8>>,
    seq: u16,
    frame: u32,
}

/// The CAN side: an SLCAN adapter on a new pty, served by its own thread and runtime so
/// that each velocity command is stamped the moment its line is readable, whatever the
/// pacing thread is doing. Returns the pty's path, a sender for lines to the gateway, and
/// the commands as (when read, seq).
fn spawn_can() -> (PathBuf, tokio::sync::mpsc::UnboundedSender<Vec<u8>>, std::sync::mpsc::Receiver<(Instant, u8)>) {
    let (setup_tx, setup_rx) = std::sync::mpsc::channel();
    let (cmd_tx, cmd_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
        rt.block_on(async move {
            let (can, path, _keep) = pty();
            let (mut rd, mut wr) = tokio::io::split(can);
            let (out_tx, mut out_rx) = tokio::sync::mpsc::unbounded_channel::<Vec<u8>>();
            setup_tx.send((path, out_tx.clone())).expect("bench alive");
            let writer = tokio::spawn(async move {
                while let Some(bytes) = out_rx.recv().await {
                    if wr.write_all(&bytes).await.is_err() {
                        break;
                    }
                }
            });
            let mut buf = BytesMut::new();
            let mut codec = SlcanAdapterCodec::new();
            let mut chunk = [0u8; 4096];
            while let Ok(n) = rd.read(&mut chunk).await {
                if n == 0 {
                    break;
                }
                let now = Instant::now();
                buf.extend_from_slice(&chunk[..n]);
                while let Ok(Some(item)) = codec.decode(&mut buf) {
                    let reply: &[u8] = match item {
                        Ok(Command::Transmit(f)) => {
                            if let Ok(MotorMessage::Velocity { seq, .. }) = MotorMessage::parse(&f) {
                                if cmd_tx.send((now, seq)).is_err() {
                                    return;
                                }
                            }
                            b"z\r"
                        }
                        Ok(_) => b"\r",
                        Err(_) => b"\x07",
                    };
                    let _ = out_tx.send(reply.to_vec());
                }
            }
            writer.abort();
        });
    });
    let (path, out) = setup_rx.recv().expect("CAN thread starts");
    (path, out, cmd_rx)
}

impl Rig {
    async fn send_psd(&mut self, m: Message) {
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let n = Packet::new(self.seq, m).encode(&mut wire).expect("fits");
        self.seq = self.seq.wrapping_add(1);
        self.psd.write_all(&wire[..n]).await.expect("psd write");
    }

    fn send_can(&mut self, m: MotorMessage) {
        let mut line = [0u8; flowgate_protocol::slcan::MAX_LINE_LEN];
        let frame: CanFrame = m.to_frame().expect("valid");
        let n = Response::Frame { frame, timestamp_ms: None }.emit(&mut line).expect("fits");
        let _ = self.can_tx.send(line[..n].to_vec());
    }

    /// Answer the gateway's requests on the PSD line.
    async fn serve_psd(&mut self, psd_bytes: &[u8]) {
        self.psd_buf.extend_from_slice(psd_bytes);
        while let Ok(Some(item)) = self.psd_codec.decode(&mut self.psd_buf) {
            let Ok(p) = item else { continue };
            let reply = match p.message {
                Message::GetInfo => Message::Info(Info {
                    firmware: [0, 9, 0],
                    psd_counts: [4096; 2],
                    max_leds: 16,
                    clock_hz: 1_000_000,
                }),
                Message::TimeSync { host_time_us } => Message::TimeSyncReply { host_time_us, t_ctrl_us: self.clock() },
                m => Message::Ack { seq: p.seq, msg_type: m.msg_type() as u8 },
            };
            self.send_psd(reply).await;
        }
    }

    fn clock(&self) -> u64 {
        (std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default().as_micros() % (1 << 40))
            as u64
    }

    /// One time-division frame: the robot's two LEDs, then the frame end. Returns when the
    /// last byte is written. The robot swings along x so the planner never stalls.
    async fn cycle(&mut self, t: f64) {
        let x = 0.2 * (t * 1.5).sin();
        let cal = flowgate_sim::calibration::CameraModel::default();
        let mut out = Vec::with_capacity(3 * psd::MAX_WIRE_LEN);
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let stamp = self.clock();
        for (slot, led, dx) in [(0u8, 1u8, 0.035), (1, 2, -0.035)] {
            let (rx, ry) = cal.project(crate::Point::new(x + dx, 0.0)).expect("in view");
            let s = Sample {
                frame: self.frame,
                slot,
                led,
                t_ctrl_us: stamp,
                x: rx.round() as i32,
                y: ry.round() as i32,
                intensity: 3000,
                flags: SampleFlags(0),
            };
            let n = Packet::new(self.seq, Message::Sample(s)).encode(&mut wire).expect("fits");
            self.seq = self.seq.wrapping_add(1);
            out.extend_from_slice(&wire[..n]);
        }
        let n = Packet::new(self.seq, Message::FrameEnd { frame: self.frame, t_ctrl_us: stamp, samples: 2 })
            .encode(&mut wire)
            .expect("fits");
        self.seq = self.seq.wrapping_add(1);
        out.extend_from_slice(&wire[..n]);
        self.frame = self.frame.wrapping_add(1);
        self.psd.write_all(&out).await.expect("psd write");
    }
}

fn pty() -> (tokio_serial::SerialStream, PathBuf, std::fs::File) {
    use std::os::unix::fs::OpenOptionsExt;
    use tokio_serial::SerialPort as _;
    let (master, slave) = tokio_serial::SerialStream::pair().expect("pty");
    let path = PathBuf::from(slave.name().expect("pty name"));
    let keep =
        std::fs::OpenOptions::new().read(true).write(true).custom_flags(libc::O_NOCTTY).open(&path).expect("pty slave");
    drop(slave);
    (master, path, keep)
}

fn rig_toml(psd: &Path, can: &Path, slot_us: u32) -> String {
    let h = flowgate_sim::calibration::CameraModel::default().homography;
    format!(
        "[serial]\nport = \"{}\"\n[leds]\nrobot_front = 1\nrobot_rear = 2\nfront_offset = 0.035\nrear_offset = 0.035\n\
         [schedule]\nslot_us = {slot_us}\n[calibration]\nhomography = {h:?}\n[can]\nendpoint = \"slcan:{}?bitrate=1000000\"\n\
         [drive]\nwheel_radius = 0.025\nsteps_per_rev = 200\nmicrosteps = 8\nwheel_base = 0.108\nmax_wheel_speed = 0.25\nwheel_accel = 1.0\ncommand_timeout_ms = 1000\n\
         [robot]\nradius = 0.07\nmax_speed = 0.15\n[planner]\ngoal = [0.75, 0.0]\ncruise_speed = 0.1\nc1 = 20\nkc = 0.1\n\
         [safety]\nsample_timeout_ms = 2000\npose_timeout_ms = 2000\nheartbeat_timeout_ms = 2000\nbad_frames_per_s = 1000\n",
        psd.display(),
        can.display()
    )
}

/// Run the benchmark: `phases` as (name, frame rate Hz, cycles).
pub async fn run(gateway_exe: &Path, phases: &[(&str, f64, u64)], workdir: &Path) -> std::io::Result<BenchReport> {
    std::fs::create_dir_all(workdir)?;
    let (psd, psd_path, _keep_psd) = pty();
    let (can_path, can_tx, cmd_rx) = spawn_can();
    let node = NodeId::new(1).expect("1");
    let mut rig = Rig { psd, psd_buf: BytesMut::new(), psd_codec: PsdCodec::new(), can_tx, seq: 0, frame: 0 };
    let config = workdir.join("bench-rig.toml");
    std::fs::write(&config, rig_toml(&psd_path, &can_path, 500))?;
    let mut child = tokio::process::Command::new(gateway_exe)
        .args(["run", "--config"])
        .arg(&config)
        .stdout(std::process::Stdio::null())
        .kill_on_drop(true)
        .spawn()?;
    let pid = child.id().unwrap_or(0);
    let mut psd_in = [0u8; 4096];
    let mut commands: Vec<(Instant, u8)> = Vec::new();
    let origin = Instant::now();

    // Bring-up: serve requests, send heartbeats and Enabled status, stream at 50 Hz until
    // the gateway commands (it is Running or Armed).
    let mut next_hb = Instant::now();
    let bring_up_end = Instant::now() + Duration::from_secs(15);
    while commands.len() < 20 {
        if Instant::now() > bring_up_end {
            let _ = child.kill().await;
            return Err(std::io::Error::other("the gateway did not start commanding within 15 s"));
        }
        if Instant::now() >= next_hb {
            next_hb += Duration::from_millis(20);
            rig.send_can(MotorMessage::Heartbeat { node, state: BoardState::Enabled });
            rig.send_can(MotorMessage::Status {
                node,
                state: BoardState::Enabled,
                faults: FaultBits(0),
                last_seq: 0,
                seq_errors: 0,
            });
            rig.cycle(origin.elapsed().as_secs_f64()).await;
        }
        while let Ok(c) = cmd_rx.try_recv() {
            commands.push(c);
        }
        tokio::select! {
            n = rig.psd.read(&mut psd_in) => { let n = n?; let b = psd_in[..n].to_vec(); rig.serve_psd(&b).await; }
            _ = tokio::time::sleep_until(next_hb.min(Instant::now() + Duration::from_millis(5))) => {}
        }
    }

    let mut report_phases = Vec::new();
    let mut sustained: f64 = 0.0;
    for &(name, rate, cycles) in phases {
        while cmd_rx.try_recv().is_ok() {}
        commands.clear();
        let mut hist = Histogram::<u64>::new_with_bounds(1, 10_000_000_000, 3).expect("bounds");
        let (cpu0, rss0) = proc_stat(pid);
        let mut rss_peak = rss0;
        let start = Instant::now();
        let period = Duration::from_secs_f64(1.0 / rate);
        let mut next = start;
        let mut written: Vec<Instant> = Vec::with_capacity(cycles as usize);
        let mut next_hb = start;
        let mut next_rss = start;
        for k in 0..cycles {
            // Keep the board alive and the gateway happy.
            let now = Instant::now();
            if now >= next_hb {
                next_hb = now + Duration::from_millis(100);
                rig.send_can(MotorMessage::Heartbeat { node, state: BoardState::Enabled });
            }
            if now >= next_rss {
                next_rss = now + Duration::from_secs(1);
                rss_peak = rss_peak.max(proc_stat(pid).1);
            }
            // Pace: sleep most of the way, spin the last 100-200 µs (this thread does nothing else).
            loop {
                let now = Instant::now();
                if now >= next {
                    break;
                }
                if next - now > Duration::from_micros(200) {
                    std::thread::sleep(next - now - Duration::from_micros(100));
                } else {
                    std::hint::spin_loop();
                }
            }
            next += period;
            rig.cycle(start.elapsed().as_secs_f64()).await;
            written.push(Instant::now());
            let _ = k;
            while let Ok(c) = cmd_rx.try_recv() {
                commands.push(c);
            }
        }
        // Drain the last commands.
        let drain_end = std::time::Instant::now() + Duration::from_millis(300);
        while commands.len() < written.len() && std::time::Instant::now() < drain_end {
            if let Ok(c) = cmd_rx.recv_timeout(Duration::from_millis(10)) {
                commands.push(c);
            }
        }
        let elapsed = start.elapsed().as_secs_f64();
        let (cpu1, rss1) = proc_stat(pid);
        // The k-th command answers the k-th frame (one command per cycle, in order).
        let mut late = 0u64;
        for (w, (r, _)) in written.iter().zip(&commands) {
            let latency = r.saturating_duration_since(*w);
            late += u64::from(latency > period);
            let _ = hist.record(latency.as_nanos().max(1) as u64);
        }
        let q = |p: f64| hist.value_at_quantile(p) as f64 / 1e3;
        let phase = Phase {
            name: name.to_string(),
            frame_rate_hz: written.len() as f64 / elapsed,
            samples_per_s: 2.0 * written.len() as f64 / elapsed,
            cycles_sent: written.len() as u64,
            commands_received: commands.len() as u64,
            late_percent: 100.0 * late as f64 / written.len().max(1) as f64,
            latency_us: Percentiles { p50: q(0.5), p99: q(0.99), p999: q(0.999), max: hist.max() as f64 / 1e3 },
            cpu_percent: 100.0 * (cpu1 - cpu0) / elapsed,
            rss_mb: [rss0, rss_peak.max(rss1), rss1],
        };
        let kept_up = phase.commands_received == phase.cycles_sent && phase.late_percent < 1.0;
        if kept_up {
            sustained = sustained.max(phase.samples_per_s);
        }
        report_phases.push(phase);
    }
    let _ = child.kill().await;
    Ok(BenchReport {
        transport: "pty (PSD, 921600 baud) + SLCAN on a pty (CAN)".into(),
        wire: Wire::new(),
        phases: report_phases,
        sustained_samples_per_s: sustained,
        planner_note: "planner per-evaluation figures: cargo bench --bench planner (README)",
    })
}

impl std::fmt::Display for BenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let w = &self.wire;
        writeln!(f, "flowgate bench over {}", self.transport)?;
        writeln!(
            f,
            "wire: one sample frame {:.0} µs at {} baud; one command frame {:.0} µs on CAN at {} bit/s ({:.0} µs as an SLCAN line)",
            w.sample_frame_us, BAUD, w.command_frame_us, CAN_BITRATE, w.command_slcan_us
        )?;
        writeln!(
            f,
            "{:<18} {:>9} {:>10} {:>9} {:>9} {:>6} {:>8} {:>8} {:>9} {:>9} {:>6} {:>14} {:>9}",
            "phase",
            "frames/s",
            "samples/s",
            "cycles",
            "commands",
            "late %",
            "p50 µs",
            "p99 µs",
            "p99.9 µs",
            "max µs",
            "CPU %",
            "RSS MB s/p/e",
            "p50/wire"
        )?;
        for p in &self.phases {
            writeln!(
                f,
                "{:<18} {:>9.0} {:>10.0} {:>9} {:>9} {:>6.2} {:>8.0} {:>8.0} {:>9.0} {:>9.0} {:>6.1} {:>4.1}/{:>4.1}/{:>4.1} {:>9.2}",
                p.name,
                p.frame_rate_hz,
                p.samples_per_s,
                p.cycles_sent,
                p.commands_received,
                p.late_percent,
                p.latency_us.p50,
                p.latency_us.p99,
                p.latency_us.p999,
                p.latency_us.max,
                p.cpu_percent,
                p.rss_mb[0],
                p.rss_mb[1],
                p.rss_mb[2],
                p.latency_us.p50 / (w.sample_frame_us + w.command_slcan_us)
            )?;
        }
        writeln!(
            f,
            "p50/wire: median gateway-added latency over the wire time of one sample frame plus one command line"
        )?;
        write!(f, "sustained: {:.0} samples/s with every command answered and under 1% of cycles late (command after the next frame was due)", self.sustained_samples_per_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Wire times: 33 bytes x 10 bits at 921600 baud; a CAN 2.0A frame with 7 data bytes is
    /// 103 bits unstuffed; the SLCAN line `t1017` + 14 hex + CR is 20 bytes.
    #[test]
    fn wire_times() {
        let w = Wire::new();
        assert!((w.sample_frame_us - 330.0 / 0.9216).abs() < 1e-9);
        assert!((w.command_frame_us - 103.0).abs() < 1e-9);
        assert!((w.command_slcan_us - 200.0 / 0.9216).abs() < 1e-9);
    }
}
