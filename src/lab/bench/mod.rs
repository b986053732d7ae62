//! The gateway benchmark (`flowgate bench`): the gateway as a separate process between a
//! scripted PSD controller (a pty) and a scripted CAN bus (an SLCAN adapter on a pty, or a
//! SocketCAN interface), both played here so that every time is taken at the wire.
//!
//! Gateway-added latency of a cycle: from the moment the last byte of the cycle's frames
//! (its `FrameEnd`) has been written into the PSD pty, to the moment the resulting velocity
//! command is readable on the bus. It includes the pty and the CAN transport, so each rate
//! is first run through a null gateway (`peers::NullGateway`: the same endpoints, no
//! work) to measure the floor those impose on this machine. Both are stated beside the wire
//! time of the same traffic, so a user can read off whether flowgate, the host or the wire
//! is the bottleneck.

pub mod null_gateway;
mod pace;
mod peers;
mod process;
mod report;
use process::{proc_stat, GatewayProcess, Target};

use std::path::Path;
use std::time::{Duration, Instant};

use flowgate_protocol::canopen;
use flowgate_protocol::motor::{BoardState, FaultBits, MotorMessage, NodeId};
use flowgate_protocol::psd;
use hdrhistogram::Histogram;
use serde::Serialize;

use null_gateway::NullGatewayProcess;
use pace::Pacer;
use peers::{CanSide, Commands, Stamped, ToBus};

use crate::gateway::shell::realtime::RealtimeSettings;
use crate::gateway::shell::telemetry::StageSummary;

/// The PSD line's baud rate and the CAN bitrate the wire times are stated for.
pub const BAUD: u32 = 921_600;
pub const CAN_BITRATE: u32 = 1_000_000;

/// One measured phase.
#[derive(Debug, Clone, Serialize)]
pub struct Phase {
    pub name: String,
    /// The gateway's low-latency window (`[realtime] spin_us`) in this phase, if it was on;
    /// its null gateway then polls the same way.
    pub spin_us: Option<u32>,
    /// The gateway's real-time settings in this phase (CPU affinity, SCHED_FIFO, locked
    /// memory), if any; its null gateway then runs with them too.
    pub realtime: Option<String>,
    /// The gateway rehearsed its cycle as each low-latency window opened (`[realtime]
    /// warm_up`; its null gateway has no cycle to rehearse).
    #[serde(default)]
    pub warm_up: bool,
    /// The gateway recorded the run to MCAP in this phase (its null gateway records nothing).
    #[serde(default)]
    pub recording: bool,
    /// The gateway served the live view in this phase.
    #[serde(default)]
    pub view: bool,
    /// The gateway commanded CiA 402 drives (two RPDOs a cycle) in this phase.
    #[serde(default)]
    pub cia402: bool,
    /// The gateway ran its ROS 2 node (on loopback, in a domain no subscriber listens in).
    #[serde(default)]
    pub ros2: bool,
    /// Time-division frames per second the controller sent.
    pub frame_rate_hz: f64,
    pub samples_per_s: f64,
    pub cycles_sent: u64,
    pub commands_received: u64,
    /// Cycles whose command came back after the next frame was due (latency > period), %.
    pub late_percent: f64,
    pub latency_us: Percentiles,
    /// The same rate through the null gateway (same endpoints, no work, its own process):
    /// what the pty, the scheduler and the CAN transport cost on this machine. `None` for
    /// phases run for memory only.
    pub floor: Option<Floor>,
    /// The gateway's latency minus the floor's, quantile by quantile: what flowgate adds.
    pub added_us: Option<Percentiles>,
    /// Gateway CPU over the phase, percent of one core.
    pub cpu_percent: f64,
    /// Gateway resident set size: at the start, peak and at the end of the phase, MB.
    pub rss_mb: [f64; 3],
    /// Each stage of the gateway's cycles in this phase, as its loop measured them
    /// (`flowgate ctl stats`).
    pub stages: Vec<StageSummary>,
}

/// The null gateway's figures at one rate.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Floor {
    pub commands_received: u64,
    pub late_percent: f64,
    pub latency_us: Percentiles,
    /// The null gateway's process, percent of one core: the I/O alone.
    pub cpu_percent: f64,
}

/// How a row's gateway and its null gateway run: the low-latency window and the real-time
/// settings (both off: the gateway as installed).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Mode {
    pub spin_us: u32,
    /// With the low-latency window: rehearse the cycle as each window opens
    /// (`[realtime] warm_up`).
    pub warm_up: bool,
    pub realtime: RealtimeSettings,
    /// Record the run to MCAP (`[telemetry] record`): what recording costs the loop.
    pub record: bool,
    /// Serve the live view (`[operator] view`, a free loopback port): what it costs the loop.
    pub view: bool,
    /// Command two CiA 402 drives (an RPDO each a cycle) instead of a PCL-80K-like board;
    /// the latency is to the second RPDO, and the null gateway sends two frames too.
    pub cia402: bool,
    /// Run the ROS 2 node (`[ros2]`, on loopback, no subscriber): what publishing costs the loop.
    pub ros2: bool,
}

impl Mode {
    /// The row's suffix: `None` for the plain gateway.
    fn label(&self) -> Option<String> {
        let parts: Vec<&str> = [
            (self.spin_us > 0, "low-latency"),
            (self.warm_up, "warm-up"),
            (!self.realtime.is_empty(), "real-time"),
            (self.record, "recording"),
            (self.view, "view"),
            (self.cia402, "CiA 402"),
            (self.ros2, "ROS 2"),
        ]
        .into_iter()
        .filter_map(|(on, name)| on.then_some(name))
        .collect();
        (!parts.is_empty()).then(|| parts.join(" + "))
    }
}

/// One phase to run: a frame rate (two LEDs a frame) for a number of cycles.
#[derive(Debug, Clone)]
pub struct PhaseSpec {
    pub name: &'static str,
    pub frame_rate_hz: f64,
    pub cycles: u64,
    /// Also run it through the null gateway, block by block.
    pub floor: bool,
    /// Also run it, in the same seconds, through a gateway (and a null gateway) in each of
    /// these modes: a row each.
    pub also: Vec<Mode>,
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
    /// A cycle's command to CiA 402 drives: two RPDO1s (DLC 6) on CAN, and as two SLCAN
    /// lines, µs.
    pub cia402_frames_us: f64,
    pub cia402_slcan_us: f64,
    /// One whole time-division frame as the bench sends it (two samples and the frame end)
    /// at `BAUD`, µs, and the sample rate the PSD line can carry at most that way.
    pub psd_frame_us: f64,
    pub psd_max_samples_per_s: f64,
}

impl Wire {
    pub fn new() -> Self {
        let sample = psd::SAMPLE_WIRE_LEN as f64 * 10.0 / f64::from(BAUD) * 1e6;
        // SOF id RTR/IDE/r0 DLC data CRC ACK EOF IFS, and `t` id DLC data CR.
        let can_bits = |data: u32| 1 + 11 + 3 + 4 + 8 * data + 15 + 3 + 7 + 3;
        let slcan_line = |data: u32| 1 + 3 + 1 + 2 * data + 1;
        let serial_us = |bytes: u32| f64::from(bytes) * 10.0 / f64::from(BAUD) * 1e6;
        let can_us = |bits: u32| f64::from(bits) / f64::from(CAN_BITRATE) * 1e6;
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let frame_end = psd::Packet::new(0, psd::Message::FrameEnd { frame: 0, t_ctrl_us: 0, samples: 2 })
            .encode(&mut wire)
            .expect("fits");
        let psd_frame_us = (2 * psd::SAMPLE_WIRE_LEN + frame_end) as f64 * 10.0 / f64::from(BAUD) * 1e6;
        Self {
            sample_frame_us: sample,
            command_frame_us: can_us(can_bits(7)),
            command_slcan_us: serial_us(slcan_line(7)),
            cia402_frames_us: 2.0 * can_us(can_bits(6)),
            cia402_slcan_us: 2.0 * serial_us(slcan_line(6)),
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
    /// The same with CiA 402 drives: one sample frame plus two RPDOs, µs.
    pub wire_per_cycle_cia402_us: f64,
    pub wire: Wire,
    pub phases: Vec<Phase>,
    /// The highest rate sustained, with every slower phase, with no lost command and under
    /// 1% late cycles, in samples/s (two LEDs per frame).
    pub sustained_samples_per_s: f64,
    /// The same, but late no more often than the null gateway plus one point: the rates at
    /// which flowgate itself is not the bottleneck.
    pub sustained_vs_floor_samples_per_s: f64,
    /// The gateway's states over the run, in order (from its output), and each other mode's
    /// gateway's over its phase (by row name).
    pub gateway_states: Vec<String>,
    pub other_states: Vec<(String, Vec<String>)>,
    pub planner_note: &'static str,
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

    fn cpu_percent(&self) -> f64 {
        100.0 * self.cpu_s / self.elapsed_s.max(1e-9)
    }

    fn floor(&self) -> Floor {
        Floor {
            commands_received: self.received,
            late_percent: self.late_percent(),
            latency_us: self.percentiles(),
            cpu_percent: self.cpu_percent(),
        }
    }
}

/// Send `cycles` frames, one per `period`, to one target, and match the k-th command to the
/// k-th frame (one command per frame, in order). Every gateway's board (`boards`) says it
/// is alive at the start and about once a second, whichever target runs.
async fn block(
    target: &mut Target,
    period: Duration,
    cycles: u64,
    tally: &mut Tally,
    boards: &[Board],
) -> std::io::Result<()> {
    target.can.drain();
    target.can.poll(target.poll_can);
    boards.iter().for_each(board_alive);
    let cpu0 = proc_stat(&target.proc_dir).0;
    let mut written: Vec<Instant> = Vec::with_capacity(cycles as usize);
    let mut commands: Vec<Stamped> = Vec::with_capacity(cycles as usize);
    let start = Instant::now();
    let mut next_second = start + Duration::from_secs(1);
    let mut pacer = Pacer::new(period);
    for _ in 0..cycles {
        pacer.wait();
        target.controller.frame()?;
        let now = Instant::now();
        written.push(now);
        if now >= next_second {
            next_second += Duration::from_secs(1);
            boards.iter().for_each(board_alive);
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
    target.can.poll(false);
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

/// A gateway's motors: a board at its node id, or two CiA 402 drives. On a shared bus (vcan)
/// each gateway has its own, or each would see the other commanding its motors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BenchMotors {
    Board(NodeId),
    Cia402 { left: canopen::NodeId, right: canopen::NodeId, gateway: canopen::NodeId },
}

impl BenchMotors {
    /// The motors of the gateway numbered `n` (1-15): the board at `n`, or drives at
    /// 0x20 + 2n and 0x21 + 2n with the gateway's heartbeat at 0x60 + n.
    fn of(n: u8, cia402: bool) -> Self {
        let node = |id| canopen::NodeId::new(id).expect("1-127");
        if cia402 {
            Self::Cia402 { left: node(0x20 + 2 * n), right: node(0x21 + 2 * n), gateway: node(0x60 + n) }
        } else {
            Self::Board(NodeId::new(n).expect("1-15"))
        }
    }

    /// What the bench reads as a cycle's command of these motors.
    fn commands(self) -> Commands {
        match self {
            Self::Board(_) => Commands::Board,
            Self::Cia402 { left, right, .. } => Commands::Cia402 { left, right },
        }
    }
}

/// A gateway's motors: the bus they are on, and which they are.
type Board = (ToBus, BenchMotors);

/// Heartbeats and an Enabled status, as a live board sends them; or each drive's heartbeat
/// and its statusword in operation enabled (TPDO1), at rest.
fn board_alive((can, motors): &Board) {
    match *motors {
        BenchMotors::Board(node) => {
            can.send(MotorMessage::Heartbeat { node, state: BoardState::Enabled });
            can.send(MotorMessage::Status {
                node,
                state: BoardState::Enabled,
                faults: FaultBits(0),
                last_seq: 0,
                seq_errors: 0,
            });
        }
        BenchMotors::Cia402 { left, right, .. } => {
            use canopen::{CanOpenMessage, DriveState, NmtState, PdoDirection, VelocityReport};
            let statusword = DriveState::OperationEnabled.statusword_bits() | canopen::statusword::REMOTE;
            for node in [left, right] {
                let data = VelocityReport { statusword, velocity_actual: 0 }.data();
                for m in [
                    CanOpenMessage::Heartbeat { node, state: NmtState::Operational },
                    CanOpenMessage::Pdo { direction: PdoDirection::Transmit, number: 1, node, data },
                ] {
                    can.send_frame(m.to_frame().expect("valid"));
                }
            }
        }
    }
}

fn can_side(transport: &Transport, commands: Commands) -> std::io::Result<CanSide> {
    match transport {
        Transport::SlcanPty => Ok(CanSide::slcan(commands)),
        Transport::SocketCan { interface } => CanSide::socketcan(interface, commands),
    }
}

/// The null gateway's drives when it plays a CiA 402 row's floor.
const NULL_DRIVES: [u8; 2] = [0x70, 0x71];

/// How long each target runs before the next takes over: short enough that all see the
/// same moments of a noisy host, and far inside the idle gateway's watchdogs.
const BLOCK: Duration = Duration::from_millis(500);

/// A gateway and its floor: two processes, each with its own PSD pty and CAN side.
struct Pair {
    gateway: Target,
    process: GatewayProcess,
    motors: BenchMotors,
    floor: Target,
    null: NullGatewayProcess,
}

impl Pair {
    async fn start(
        exe: &Path,
        transport: &Transport,
        workdir: &Path,
        name: &str,
        motors: BenchMotors,
        mode: &Mode,
    ) -> std::io::Result<Self> {
        let polls = mode.spin_us > 0;
        let null_drives = mode.cia402.then(|| NULL_DRIVES.map(|n| canopen::NodeId::new(n).expect("1-127")));
        let null_commands = null_drives.map_or(Commands::Board, |[left, right]| Commands::Cia402 { left, right });
        let mut floor = Target::new(transport, polls, null_commands)?;
        let spin = polls.then(|| Duration::from_micros(u64::from(mode.spin_us)));
        let (psd, can) = (&floor.controller.path, &floor.can.endpoint);
        let null = NullGatewayProcess::start(exe, psd, can, spin, &mode.realtime, null_drives).await?;
        floor.proc_dir = null.proc_dir();
        let mut gateway = Target::new(transport, polls, motors.commands())?;
        let process = GatewayProcess::start(exe, &mut gateway, workdir, name, motors, mode).await?;
        Ok(Self { gateway, process, motors, floor, null })
    }

    /// The gateway's states over its run.
    async fn stop(self) -> Vec<String> {
        self.null.stop().await;
        self.process.stop().await
    }
}

/// One pair's figures in one phase.
struct PairTally {
    gateway: Tally,
    floor: Tally,
    rss0: f64,
}

impl PairTally {
    fn new(pair: &Pair) -> Self {
        Self { gateway: Tally::new(), floor: Tally::new(), rss0: proc_stat(&pair.gateway.proc_dir).1 }
    }

    async fn phase(self, pair: &Pair, spec: &PhaseSpec, name: String, mode: &Mode) -> std::io::Result<Phase> {
        let (g, f) = (&self.gateway, &self.floor);
        let rss1 = proc_stat(&pair.gateway.proc_dir).1;
        let floor = spec.floor.then(|| f.floor());
        let (gp, fp) = (g.percentiles(), f.percentiles());
        Ok(Phase {
            name,
            spin_us: (mode.spin_us > 0).then_some(mode.spin_us),
            warm_up: mode.warm_up,
            realtime: (!mode.realtime.is_empty()).then(|| mode.realtime.to_string()),
            recording: mode.record,
            view: mode.view,
            cia402: mode.cia402,
            ros2: mode.ros2,
            frame_rate_hz: g.sent as f64 / g.elapsed_s,
            samples_per_s: 2.0 * g.sent as f64 / g.elapsed_s,
            cycles_sent: g.sent,
            commands_received: g.received,
            late_percent: g.late_percent(),
            latency_us: gp,
            added_us: floor.map(|_| Percentiles {
                p50: gp.p50 - fp.p50,
                p99: gp.p99 - fp.p99,
                p999: gp.p999 - fp.p999,
                max: gp.max - fp.max,
            }),
            floor,
            cpu_percent: g.cpu_percent(),
            rss_mb: [self.rss0, g.rss_peak_mb.max(rss1), rss1],
            stages: pair.process.stages().await?,
        })
    }
}

/// Run the benchmark. The gateway (`gateway_exe run`) and the null gateway (`gateway_exe
/// null-gateway`) are each their own process with their own PSD pty and CAN side; every
/// phase alternates between them in blocks of `BLOCK`, so the floor is measured over the
/// same seconds as the gateway. A phase with a low-latency window adds a second pair in
/// that mode to the rotation, started for that phase only.
pub async fn run(
    gateway_exe: &Path,
    transport: &Transport,
    phases: &[PhaseSpec],
    workdir: &Path,
) -> std::io::Result<BenchReport> {
    std::fs::create_dir_all(workdir)?;
    // The gateways' motors are numbered 1, then 3 on (`BenchMotors::of`); the null gateways
    // command node 2, or drives 0x70 and 0x71.
    let plain = Mode::default();
    let mut main = Pair::start(gateway_exe, transport, workdir, "gateway", BenchMotors::of(1, false), &plain).await?;
    let mut report_phases = Vec::new();
    let mut other_states = Vec::new();
    for spec in phases {
        // Each other mode's pair, started for this phase only, on its own board's node.
        let mut others: Vec<(Pair, &Mode, String)> = Vec::new();
        for (k, mode) in spec.also.iter().enumerate() {
            let label = mode.label().unwrap_or_else(|| "again".into());
            let file = format!("gateway-{}", label.replace([' ', '+'], "-"));
            let motors = BenchMotors::of(3 + k as u8, mode.cia402);
            let pair = Pair::start(gateway_exe, transport, workdir, &file, motors, mode).await?;
            others.push((pair, mode, format!("{}, {label}", spec.name)));
        }
        let boards: Vec<Board> = std::iter::once(&main)
            .chain(others.iter().map(|(p, ..)| p))
            .map(|p| (p.gateway.can.board(), p.motors))
            .collect();
        let period = Duration::from_secs_f64(1.0 / spec.frame_rate_hz);
        let per_block = ((BLOCK.as_secs_f64() * spec.frame_rate_hz) as u64).clamp(1, spec.cycles);
        // The stage statistics start with the phase.
        main.process.stages().await?;
        for (pair, ..) in &others {
            pair.process.stages().await?;
        }
        let mut m = PairTally::new(&main);
        let mut tallies: Vec<PairTally> = others.iter().map(|(p, ..)| PairTally::new(p)).collect();
        let mut left = spec.cycles;
        while left > 0 {
            let n = per_block.min(left);
            left -= n;
            if spec.floor {
                block(&mut main.floor, period, n, &mut m.floor, &boards).await?;
            }
            block(&mut main.gateway, period, n, &mut m.gateway, &boards).await?;
            for ((pair, ..), tally) in others.iter_mut().zip(&mut tallies) {
                block(&mut pair.floor, period, n, &mut tally.floor, &boards).await?;
                block(&mut pair.gateway, period, n, &mut tally.gateway, &boards).await?;
            }
            // On a shared bus (vcan) each side heard the others' commands too.
            main.floor.can.drain();
            for (pair, ..) in &others {
                pair.floor.can.drain();
                pair.gateway.can.drain();
            }
        }
        report_phases.push(m.phase(&main, spec, spec.name.to_string(), &plain).await?);
        for ((pair, mode, name), tally) in others.into_iter().zip(tallies) {
            report_phases.push(tally.phase(&pair, spec, name.clone(), mode).await?);
            other_states.push((name, pair.stop().await));
        }
    }
    let gateway_states = main.stop().await;
    Ok(BenchReport::new(transport, report_phases, gateway_states, other_states))
}

/// Sustained: the highest rate that passes with every slower latency phase passing too.
fn sustained(phases: &[Phase], passes: &dyn Fn(&Phase) -> bool) -> f64 {
    let mut latency_phases: Vec<&Phase> = phases
        .iter()
        .filter(|p| {
            p.floor.is_some()
                && p.spin_us.is_none()
                && p.realtime.is_none()
                && !p.recording
                && !p.view
                && !p.cia402
                && !p.ros2
        })
        .collect();
    latency_phases.sort_by(|a, b| a.samples_per_s.total_cmp(&b.samples_per_s));
    latency_phases
        .iter()
        .take_while(|p| p.commands_received == p.cycles_sent && passes(p))
        .last()
        .map_or(0.0, |p| p.samples_per_s)
}

#[cfg(test)]
mod tests;
