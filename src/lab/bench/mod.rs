//! The gateway benchmark (`flowgate bench`): the gateway as a separate process between a
//! scripted PSD controller (a pty) and a scripted CAN bus (an SLCAN adapter on a pty, or a
//! SocketCAN interface), both played here so that every time is taken at the wire.
//!
//! Gateway-added latency of a cycle: from the moment the last byte of the cycle's frames
//! (its `FrameEnd`) has been written into the PSD pty, to the moment the resulting velocity
//! command is readable on the bus. It includes the pty and the CAN transport, so each rate
//! is first run through a null gateway ([`peers::NullGateway`]: the same endpoints, no
//! work) to measure the floor those impose on this machine. Both are stated beside the wire
//! time of the same traffic, so a user can read off whether flowgate, the host or the wire
//! is the bottleneck.

mod pace;
mod peers;

use std::path::Path;
use std::time::{Duration, Instant};

use flowgate_protocol::motor::{BoardState, FaultBits, MotorMessage, NodeId};
use flowgate_protocol::psd;
use hdrhistogram::Histogram;
use serde::Serialize;
use tokio::io::AsyncReadExt;

use pace::Pacer;
use peers::{CanSide, Controller, NullGateway, Stamped, ToBus};

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
    /// The same rate through the null gateway (same endpoints, no work): what the pty, the
    /// scheduler and the CAN transport cost on this machine. `None` for phases run for
    /// memory only.
    pub floor: Option<Floor>,
    /// Gateway CPU over the phase, percent of one core.
    pub cpu_percent: f64,
    /// Gateway resident set size: at the start, peak and at the end of the phase, MB.
    pub rss_mb: [f64; 3],
}

/// The null gateway's figures at one rate.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Floor {
    pub commands_received: u64,
    pub late_percent: f64,
    pub latency_us: Percentiles,
    /// The null gateway's thread, percent of one core: the I/O alone.
    pub cpu_percent: f64,
}

/// One phase to run: a frame rate (two LEDs a frame) for a number of cycles.
#[derive(Debug, Clone, Copy)]
pub struct PhaseSpec {
    pub name: &'static str,
    pub frame_rate_hz: f64,
    pub cycles: u64,
    /// Also run it through the null gateway first.
    pub floor: bool,
}

/// Where the gateway's CAN commands go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transport {
    /// A scripted SLCAN adapter on a pty.
    SlcanPty,
    /// A SocketCAN interface (vcan0 in the VM, or a real bus).
    SocketCan { interface: String },
}

impl Transport {
    fn describe(&self) -> String {
        match self {
            Self::SlcanPty => "pty (PSD, 921600 baud) + SLCAN on a pty (CAN)".into(),
            Self::SocketCan { interface } => format!("pty (PSD, 921600 baud) + SocketCAN {interface} (CAN)"),
        }
    }
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
    /// One whole time-division frame as the bench sends it (two samples and the frame end)
    /// at `BAUD`, µs, and the sample rate the PSD line can carry at most that way.
    pub psd_frame_us: f64,
    pub psd_max_samples_per_s: f64,
}

impl Wire {
    pub fn new() -> Self {
        let sample = psd::SAMPLE_WIRE_LEN as f64 * 10.0 / f64::from(BAUD) * 1e6;
        let can_bits = 1 + 11 + 3 + 4 + 8 * 7 + 15 + 3 + 7 + 3; // SOF id RTR/IDE/r0 DLC data CRC ACK EOF IFS
        let slcan_line = 1 + 3 + 1 + 14 + 1;
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let frame_end = psd::Packet::new(0, psd::Message::FrameEnd { frame: 0, t_ctrl_us: 0, samples: 2 })
            .encode(&mut wire)
            .expect("fits");
        let psd_frame_us = (2 * psd::SAMPLE_WIRE_LEN + frame_end) as f64 * 10.0 / f64::from(BAUD) * 1e6;
        Self {
            sample_frame_us: sample,
            command_frame_us: f64::from(can_bits) / f64::from(CAN_BITRATE) * 1e6,
            command_slcan_us: f64::from(slcan_line) * 10.0 / f64::from(BAUD) * 1e6,
            psd_frame_us,
            psd_max_samples_per_s: 2.0 * 1e6 / psd_frame_us,
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
    /// The wire time the latency is compared with: one sample frame plus one command on this
    /// transport (an SLCAN line, or a CAN frame), µs.
    pub wire_per_cycle_us: f64,
    pub wire: Wire,
    pub phases: Vec<Phase>,
    /// The highest rate sustained, with every slower phase, with no lost command and under
    /// 1% late cycles, in samples/s (two LEDs per frame).
    pub sustained_samples_per_s: f64,
    /// The same, but late no more often than the null gateway plus one point: the rates at
    /// which flowgate itself is not the bottleneck.
    pub sustained_vs_floor_samples_per_s: f64,
    /// The gateway's states over the run, in order (from its output).
    pub gateway_states: Vec<String>,
    pub planner_note: &'static str,
}

/// CPU seconds used and resident set size (MB) of a process or thread, from its /proc
/// directory (`/proc/PID` or `/proc/self/task/TID`).
fn proc_stat(dir: &str) -> (f64, f64) {
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
/// are tested in tests/fault_table.rs.
fn rig_toml(psd: &Path, can_endpoint: &str, slot_us: u32) -> String {
    let h = flowgate_sim::calibration::CameraModel::default().homography;
    format!(
        "[serial]\nport = \"{}\"\n[leds]\nrobot_front = 1\nrobot_rear = 2\nfront_offset = 0.035\nrear_offset = 0.035\n\
         [schedule]\nslot_us = {slot_us}\n[calibration]\nhomography = {h:?}\n[can]\nendpoint = \"{can_endpoint}\"\n\
         [drive]\nwheel_radius = 0.025\nsteps_per_rev = 200\nmicrosteps = 8\nwheel_base = 0.108\nmax_wheel_speed = 0.25\nwheel_accel = 1.0\ncommand_timeout_ms = 31000\n\
         [robot]\nradius = 0.07\nmax_speed = 0.15\n[goal]\nposition = [0.75, 0.0]\n[planner]\ncruise_speed = 0.1\nc1 = 20\nkc = 0.1\n\
         [safety]\nsample_timeout_ms = 30000\npose_timeout_ms = 30000\nheartbeat_timeout_ms = 30000\nbad_frames_per_s = 1000\n",
        psd.display(),
    )
}

/// One side of the comparison: a PSD pty and a CAN side, and the /proc entry whose CPU
/// time counts (the gateway process, or the null gateway's thread).
struct Target {
    controller: Controller,
    can: CanSide,
    proc_dir: String,
}

/// What the blocks of one phase measured on one target.
struct Tally {
    latency: Histogram<u64>,
    sent: u64,
    received: u64,
    late: u64,
    elapsed_s: f64,
    cpu_s: f64,
    rss_peak_mb: f64,
}

impl Tally {
    fn new() -> Self {
        Self {
            latency: Histogram::new_with_bounds(1, 10_000_000_000, 3).expect("bounds"),
            sent: 0,
            received: 0,
            late: 0,
            elapsed_s: 0.0,
            cpu_s: 0.0,
            rss_peak_mb: 0.0,
        }
    }

    fn percentiles(&self) -> Percentiles {
        let q = |p: f64| self.latency.value_at_quantile(p) as f64 / 1e3;
        Percentiles { p50: q(0.5), p99: q(0.99), p999: q(0.999), max: self.latency.max() as f64 / 1e3 }
    }

    fn late_percent(&self) -> f64 {
        100.0 * self.late as f64 / self.sent.max(1) as f64
    }
}

/// Send `cycles` frames, one per `period`, to one target, and match the k-th command to the
/// k-th frame (one command per frame, in order). The gateway's board (`board`) says it is
/// alive at the start and about once a second, whichever target runs.
async fn block(
    target: &mut Target,
    period: Duration,
    cycles: u64,
    tally: &mut Tally,
    board: &ToBus,
) -> std::io::Result<()> {
    target.can.drain();
    board_alive(board);
    let cpu0 = proc_stat(&target.proc_dir).0;
    let mut written: Vec<Instant> = Vec::with_capacity(cycles as usize);
    let mut commands: Vec<Stamped> = Vec::with_capacity(cycles as usize);
    let start = Instant::now();
    let mut next_second = start + Duration::from_secs(1);
    let mut pacer = Pacer::new(period);
    for _ in 0..cycles {
        pacer.wait();
        target.controller.frame().await?;
        let now = Instant::now();
        written.push(now);
        if now >= next_second {
            next_second += Duration::from_secs(1);
            board_alive(board);
        }
        commands.extend(target.can.commands.try_iter());
    }
    // The last commands: wait for them, but not forever (a lost command stays lost).
    let drain_end = Instant::now() + Duration::from_millis(500);
    while commands.len() < written.len() && Instant::now() < drain_end {
        if let Ok(c) = target.can.commands.recv_timeout(Duration::from_millis(10)) {
            commands.push(c);
        }
    }
    let (cpu1, rss) = proc_stat(&target.proc_dir);
    // Paced time: first deadline to the last frame, plus the period that frame owns.
    tally.elapsed_s += written.last().map_or(0.0, |t| t.duration_since(start).as_secs_f64()) + period.as_secs_f64();
    tally.cpu_s += cpu1 - cpu0;
    tally.rss_peak_mb = tally.rss_peak_mb.max(rss);
    tally.sent += written.len() as u64;
    tally.received += commands.len().min(written.len()) as u64;
    for (w, (r, _)) in written.iter().zip(&commands) {
        let latency = r.saturating_duration_since(*w);
        tally.late += u64::from(latency > period);
        let _ = tally.latency.record(latency.as_nanos().max(1) as u64);
    }
    Ok(())
}

/// Heartbeats and an Enabled status, as a live board sends them.
fn board_alive(can: &ToBus) {
    let node = NodeId::new(1).expect("1");
    can.send(MotorMessage::Heartbeat { node, state: BoardState::Enabled });
    can.send(MotorMessage::Status {
        node,
        state: BoardState::Enabled,
        faults: FaultBits(0),
        last_seq: 0,
        seq_errors: 0,
    });
}

fn can_side(transport: &Transport) -> std::io::Result<CanSide> {
    match transport {
        Transport::SlcanPty => Ok(CanSide::slcan()),
        Transport::SocketCan { interface } => CanSide::socketcan(interface),
    }
}

/// How long each target runs before the other takes over: short enough that both see the
/// same moments of a noisy host, and far inside the idle gateway's watchdogs.
const BLOCK: Duration = Duration::from_millis(500);

/// Run the benchmark. The gateway (`gateway_exe run`) and the null gateway each get their
/// own PSD pty and CAN side; every phase alternates between them in blocks of [`BLOCK`],
/// so the floor is measured over the same seconds as the gateway.
pub async fn run(
    gateway_exe: &Path,
    transport: &Transport,
    phases: &[PhaseSpec],
    workdir: &Path,
) -> std::io::Result<BenchReport> {
    std::fs::create_dir_all(workdir)?;
    let mut gateway = Target { controller: Controller::new(), can: can_side(transport)?, proc_dir: String::new() };
    let mut floor = Target { controller: Controller::new(), can: can_side(transport)?, proc_dir: String::new() };
    let null = NullGateway::start(floor.controller.path.clone(), &floor.can.endpoint)?;
    floor.proc_dir = format!("/proc/self/task/{}", null.tid);

    let config = workdir.join("bench-rig.toml");
    std::fs::write(&config, rig_toml(&gateway.controller.path, &gateway.can.endpoint, 500))?;
    let gateway_log = workdir.join("gateway.log");
    let mut child = tokio::process::Command::new(gateway_exe)
        .args(["run", "--arm", "--config"])
        .arg(&config)
        .stdout(std::fs::File::create(&gateway_log)?)
        .kill_on_drop(true)
        .spawn()?;
    gateway.proc_dir = format!("/proc/{}", child.id().unwrap_or(0));
    let board = gateway.can.board();

    // Bring-up: answer its requests, be a live board, stream at 50 Hz until it commands.
    let mut next_frame = Instant::now();
    let bring_up_end = next_frame + Duration::from_secs(15);
    let mut commands = 0;
    let mut psd_in = [0u8; 4096];
    while commands < 20 {
        if Instant::now() > bring_up_end {
            let _ = child.kill().await;
            return Err(std::io::Error::other("the gateway did not start commanding within 15 s"));
        }
        if let Some(status) = child.try_wait()? {
            let log = std::fs::read_to_string(&gateway_log).unwrap_or_default();
            return Err(std::io::Error::other(format!("the gateway exited ({status}) while starting: {}", log.trim())));
        }
        if Instant::now() >= next_frame {
            next_frame += Duration::from_millis(20);
            board_alive(&board);
            gateway.controller.frame().await?;
        }
        commands += gateway.can.commands.try_iter().count();
        let wait = tokio::time::Instant::from_std(next_frame.min(Instant::now() + Duration::from_millis(5)));
        tokio::select! {
            n = gateway.controller.port.read(&mut psd_in) => {
                let n = n?;
                let b = psd_in[..n].to_vec();
                gateway.controller.serve(&b).await;
            }
            _ = tokio::time::sleep_until(wait) => {}
        }
    }

    let mut report_phases = Vec::new();
    for spec in phases {
        let period = Duration::from_secs_f64(1.0 / spec.frame_rate_hz);
        let per_block = ((BLOCK.as_secs_f64() * spec.frame_rate_hz) as u64).clamp(1, spec.cycles);
        let (mut g, mut f) = (Tally::new(), Tally::new());
        let rss0 = proc_stat(&gateway.proc_dir).1;
        let mut left = spec.cycles;
        while left > 0 {
            let n = per_block.min(left);
            left -= n;
            if spec.floor {
                block(&mut floor, period, n, &mut f, &board).await?;
            }
            block(&mut gateway, period, n, &mut g, &board).await?;
            floor.can.drain(); // on a shared bus (vcan) it heard the gateway's commands too
        }
        let rss1 = proc_stat(&gateway.proc_dir).1;
        report_phases.push(Phase {
            name: spec.name.to_string(),
            frame_rate_hz: g.sent as f64 / g.elapsed_s,
            samples_per_s: 2.0 * g.sent as f64 / g.elapsed_s,
            cycles_sent: g.sent,
            commands_received: g.received,
            late_percent: g.late_percent(),
            latency_us: g.percentiles(),
            floor: spec.floor.then(|| Floor {
                commands_received: f.received,
                late_percent: f.late_percent(),
                latency_us: f.percentiles(),
                cpu_percent: 100.0 * f.cpu_s / f.elapsed_s.max(1e-9),
            }),
            cpu_percent: 100.0 * g.cpu_s / g.elapsed_s.max(1e-9),
            rss_mb: [rss0, g.rss_peak_mb.max(rss1), rss1],
        });
    }
    drop(null);
    let _ = child.kill().await;
    // Its state lines ("state: running", ...): a gateway that stopped commanding says why.
    let gateway_states: Vec<String> = std::fs::read_to_string(&gateway_log)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| l.strip_prefix("state: ").map(str::to_string))
        .collect();
    // Sustained: the highest rate that passes with every slower latency phase passing too.
    let sustained_by = |passes: &dyn Fn(&Phase) -> bool| {
        let mut latency_phases: Vec<&Phase> = report_phases.iter().filter(|p| p.floor.is_some()).collect();
        latency_phases.sort_by(|a, b| a.samples_per_s.total_cmp(&b.samples_per_s));
        latency_phases
            .iter()
            .take_while(|p| p.commands_received == p.cycles_sent && passes(p))
            .last()
            .map_or(0.0, |p| p.samples_per_s)
    };
    let sustained = sustained_by(&|p| p.late_percent < 1.0);
    let sustained_vs_floor = sustained_by(&|p| p.floor.is_some_and(|f| p.late_percent <= f.late_percent + 1.0));
    let wire = Wire::new();
    Ok(BenchReport {
        transport: transport.describe(),
        wire_per_cycle_us: wire.sample_frame_us
            + match transport {
                Transport::SlcanPty => wire.command_slcan_us,
                Transport::SocketCan { .. } => wire.command_frame_us,
            },
        wire,
        phases: report_phases,
        sustained_samples_per_s: sustained,
        sustained_vs_floor_samples_per_s: sustained_vs_floor,
        gateway_states,
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
            "wire capacity: a frame of two samples and its end takes {:.0} µs, so the PSD line carries at most {:.0} samples/s; faster phases test flowgate beyond the wire",
            w.psd_frame_us, w.psd_max_samples_per_s
        )?;
        writeln!(
            f,
            "{:<17} {:>9} {:>9} {:>7} {:>7} {:>7} {:>7} {:>8} {:>7} {:>6} {:>13} {:>26} {:>5} {:>9}",
            "phase",
            "samples/s",
            "cycles",
            "lost",
            "late %",
            "p50 µs",
            "p99 µs",
            "p99.9 µs",
            "max µs",
            "CPU %",
            "RSS MB s/p/e",
            "floor p50/p99/late/CPU %",
            "lost",
            "p50/wire"
        )?;
        for p in &self.phases {
            let floor = match &p.floor {
                Some(fl) => {
                    format!(
                        "{:.0}/{:.0}/{:.2}/{:.1}",
                        fl.latency_us.p50, fl.latency_us.p99, fl.late_percent, fl.cpu_percent
                    )
                }
                None => "-".into(),
            };
            let floor_lost =
                p.floor.map_or("-".into(), |fl| (p.cycles_sent - fl.commands_received.min(p.cycles_sent)).to_string());
            writeln!(
                f,
                "{:<17} {:>9.0} {:>9} {:>7} {:>7.2} {:>7.0} {:>7.0} {:>8.0} {:>7.0} {:>6.1} {:>4.1}/{:>4.1}/{:>4.1} {:>26} {:>5} {:>9.2}",
                p.name,
                p.samples_per_s,
                p.cycles_sent,
                p.cycles_sent - p.commands_received.min(p.cycles_sent),
                p.late_percent,
                p.latency_us.p50,
                p.latency_us.p99,
                p.latency_us.p999,
                p.latency_us.max,
                p.cpu_percent,
                p.rss_mb[0],
                p.rss_mb[1],
                p.rss_mb[2],
                floor,
                floor_lost,
                p.latency_us.p50 / self.wire_per_cycle_us
            )?;
        }
        writeln!(f, "lost: frames with no command; late: command after the next frame was due")?;
        writeln!(f, "floor: the same rate through a null gateway (same endpoints, no work): the pty, scheduler and CAN transport alone")?;
        writeln!(
            f,
            "p50/wire: median gateway-added latency over the wire time of one sample frame plus one command ({:.0} µs)",
            self.wire_per_cycle_us
        )?;
        writeln!(f, "gateway states: {}", self.gateway_states.join(" -> "))?;
        writeln!(
            f,
            "sustained (with every slower phase): {:.0} samples/s with nothing lost and under 1% late; {:.0} samples/s with nothing lost and late no more than the floor + 1 point",
            self.sustained_samples_per_s, self.sustained_vs_floor_samples_per_s
        )
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
        // Two 33-byte samples and a 21-byte frame end (13-byte payload, protocol/README.md).
        assert!((w.psd_frame_us - 870.0 / 0.9216).abs() < 1e-9);
        assert!((w.psd_max_samples_per_s - 2.0 * 92_160.0 / 87.0).abs() < 1e-6);
    }
}
