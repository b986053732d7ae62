//! The simulated rig in real time: the world, the PSD controller on a serial endpoint and
//! the motor board on a CAN endpoint, in one process. A fleet's scenario puts every
//! vehicle's LEDs under the one camera and its motors on the one bus
//! ([`RigConfig::vehicles`]).
//!
//! One task owns the world and both firmware state machines and advances them by the
//! wall clock; small I/O tasks move bytes between them and the endpoints:
//! - PSD serial: a fresh pty (its path printed; optionally a stable symlink), or a real
//!   serial device;
//! - CAN: `slcan-pty` (the simulator plays a USB-CAN adapter in SLCAN mode on a pty, with
//!   the bus and the board behind it), or `socketcan:IFACE` (the board on a real or virtual
//!   CAN interface).
//!
//! The controller's outgoing bytes pass through a bounded queue to the serial writer, like a
//! UART's FIFO: when nobody reads the line, bytes are dropped and counted, never blocking
//! the simulation.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use bytes::BytesMut;
use flowgate_protocol::codec::{PsdCodec, SlcanAdapterCodec, StreamError};
use flowgate_protocol::motor::NodeId;
use flowgate_protocol::psd::{self, Packet};
use flowgate_protocol::slcan::{Command, Line, Response, MAX_LINE_LEN};
use flowgate_protocol::CanFrame;
use futures_util::StreamExt;
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_serial::SerialPort as _;
use tokio_util::codec::{Encoder, FramedRead};

use crate::camera::CameraModel;
use crate::faults::{CanFaults, FaultPlan, SerialFaults};
use crate::motors::{FleetMotors, MotorKind, Motors};
use crate::psd_controller::{BadRequest, LedMap, Outgoing, PsdController, SerialQueue};
use crate::scenario::SimScenario;
use crate::slcan_adapter::SlcanAdapter;
use crate::truth::{TruthRecord, SAMPLE_PERIOD};
use crate::world::fleet::Fleet;

/// Where the PSD controller's serial line is.
#[derive(Debug, Clone, PartialEq)]
pub enum SerialEndpoint {
    /// A new pty; `link` makes a stable symlink to its path.
    Pty { link: Option<PathBuf> },
    /// A real serial device.
    Device { path: PathBuf, baud: u32 },
}

/// Where the motor board's CAN bus is.
#[derive(Debug, Clone, PartialEq)]
pub enum CanEndpoint {
    /// The simulator plays an SLCAN adapter on a new pty; `link` makes a symlink to it.
    SlcanPty { link: Option<PathBuf> },
    /// A SocketCAN interface (`can0`, `vcan0`).
    SocketCan { interface: String },
}

impl FromStr for CanEndpoint {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.split_once(':') {
            None if s == "slcan-pty" => Ok(Self::SlcanPty { link: None }),
            Some(("socketcan", iface)) if !iface.is_empty() => Ok(Self::SocketCan { interface: iface.to_string() }),
            _ => Err(format!("CAN endpoint `{s}`: expected `slcan-pty` or `socketcan:IFACE` (e.g. socketcan:vcan0)")),
        }
    }
}

/// Everything the rig is made of.
#[derive(Debug, Clone)]
pub struct RigConfig {
    pub scenario: SimScenario,
    pub camera: CameraModel,
    pub leds: LedMap,
    pub psd: SerialEndpoint,
    pub can: CanEndpoint,
    pub node: NodeId,
    /// CiA 402 drives at these nodes (left, right) in place of the board at `node`.
    pub cia402: Option<[flowgate_protocol::canopen::NodeId; 2]>,
    pub faults: FaultPlan,
    /// PSD position noise, counts (σ).
    pub noise_counts: f64,
    pub seed: u64,
}

impl RigConfig {
    /// A rig for `scenario` with the standard camera and LEDs, SLCAN on a pty, node 1, and
    /// the scenario's faults.
    pub fn new(scenario: SimScenario) -> Self {
        let leds = LedMap::standard(scenario.robot.radius);
        let seed = scenario.sensing.seed;
        let faults = scenario.faults.clone();
        Self {
            camera: scenario.camera,
            scenario,
            leds,
            psd: SerialEndpoint::Pty { link: None },
            can: CanEndpoint::SlcanPty { link: None },
            node: NodeId::new(1).expect("node 1"),
            cia402: None,
            faults,
            noise_counts: 1.0,
            seed,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error("cannot create a pty: {0}")]
    Pty(#[source] tokio_serial::Error),
    #[error("cannot open serial device {path}: {source}")]
    Device { path: PathBuf, source: tokio_serial::Error },
    #[error("cannot create link {path}: {source}")]
    Link { path: PathBuf, source: std::io::Error },
    #[error("cannot open CAN interface {interface}: {source} (does it exist and is it up? `ip link add dev vcan0 type vcan; ip link set up vcan0`)")]
    SocketCan { interface: String, source: std::io::Error },
    #[error("cannot start the simulator's thread: {0}")]
    Thread(std::io::Error),
    #[error("{0}")]
    Unplayed(String),
}

impl RigConfig {
    /// The motor firmware's kind.
    pub fn motor_kind(&self) -> MotorKind {
        match self.cia402 {
            Some([left, right]) => MotorKind::Cia402 { left, right },
            None => MotorKind::Board(self.node),
        }
    }

    /// Every vehicle as the rig wires it, the robot first: its name, its LEDs (front, rear)
    /// and its motors. The other vehicles' LEDs follow the obstacles' ([`LedMap::vehicle_leds`])
    /// and their motors the robot's ([`MotorKind::for_vehicle`]); refused, naming the vehicle,
    /// past the LED ids the controller drives or the protocol's node ids.
    pub fn vehicles(&self) -> Result<Vec<WiredVehicle>, RigError> {
        let s = &self.scenario;
        let mut wired = Vec::with_capacity(1 + s.vehicles.len());
        for (k, (name, body, _)) in s.fleet().enumerate() {
            let leds = match k {
                0 => Some((self.leds.robot_front, self.leds.robot_rear, self.leds.robot_led_offset)),
                _ => self.leds.vehicle_leds(s.obstacles.len(), k, body.radius),
            };
            let leds = leds.filter(|&(_, rear, _)| rear <= self.leds.driven).ok_or_else(|| {
                RigError::Unplayed(format!(
                    "vehicle {name}: its LEDs would be past LED {}, the last the simulated controller drives",
                    self.leds.driven
                ))
            })?;
            let motors = self.motor_kind().for_vehicle(k).ok_or_else(|| {
                RigError::Unplayed(format!(
                    "vehicle {name}: counting on from the robot's {}, its motors would be past the protocol's \
                     node ids (boards 1-15, drives 1-127)",
                    self.motor_kind().describe()
                ))
            })?;
            wired.push(WiredVehicle { name: name.to_string(), front_led: leds.0, rear_led: leds.1, motors });
        }
        Ok(wired)
    }
}

/// A vehicle as the simulated rig wires it.
#[derive(Debug, Clone, PartialEq)]
pub struct WiredVehicle {
    pub name: String,
    pub front_led: u8,
    pub rear_led: u8,
    pub motors: MotorKind,
}

/// A rig running on a thread of its own, with its own runtime: its firmware keeps the pace
/// of its deadlines whatever the process around it does (a gateway, a live view and a
/// browser sharing a loaded machine's CPUs).
#[derive(Debug)]
pub struct RigThread {
    /// The path a host opens for the PSD controller.
    pub psd_path: PathBuf,
    /// The SLCAN adapter's path (with `slcan-pty`).
    pub can_path: Option<PathBuf>,
    stop: oneshot::Sender<()>,
    truth: oneshot::Receiver<TruthRecord>,
    thread: std::thread::JoinHandle<()>,
}

impl RigThread {
    /// Stop the rig; returns the world's truth.
    pub async fn stop(self) -> TruthRecord {
        let _ = self.stop.send(());
        let truth = self.truth.await.unwrap_or_default();
        let _ = self.thread.join();
        truth
    }
}

/// Start a rig on a thread of its own (see [`RigThread`]).
pub async fn spawn(config: RigConfig) -> Result<RigThread, RigError> {
    let (ready_tx, ready_rx) = oneshot::channel();
    let (stop_tx, stop_rx) = oneshot::channel::<()>();
    let (truth_tx, truth_rx) = oneshot::channel();
    let thread = std::thread::Builder::new()
        .name("flowgate-sim".into())
        .spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(r) => r,
                Err(e) => {
                    let _ = ready_tx.send(Err(RigError::Thread(e)));
                    return;
                }
            };
            runtime.block_on(async move {
                match start(config).await {
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                    }
                    Ok(handle) => {
                        let _ = ready_tx.send(Ok((handle.psd_path.clone(), handle.can_path.clone())));
                        let _ = stop_rx.await;
                        let _ = truth_tx.send(handle.stop().await);
                    }
                }
            });
        })
        .map_err(RigError::Thread)?;
    let (psd_path, can_path) = ready_rx
        .await
        .map_err(|_| RigError::Thread(std::io::Error::other("the simulator's thread ended at start")))??;
    Ok(RigThread { psd_path, can_path, stop: stop_tx, truth: truth_rx, thread })
}

/// Counters of the rig's links, readable while it runs.
#[derive(Debug, Default)]
pub struct RigStats {
    /// Bytes the controller sent that the serial writer could not take (line not read).
    pub serial_overflow_bytes: AtomicU64,
    pub serial_bytes_dropped: AtomicU64,
    pub serial_bytes_corrupted: AtomicU64,
    pub can_frames_lost: AtomicU64,
    pub psd_requests: AtomicU64,
    pub psd_bad_requests: AtomicU64,
    pub can_frames_in: AtomicU64,
    pub can_frames_out: AtomicU64,
}

/// A running rig.
#[derive(Debug)]
pub struct RigHandle {
    /// The path a host opens for the PSD controller.
    pub psd_path: PathBuf,
    /// The SLCAN adapter's path (with `slcan-pty`).
    pub can_path: Option<PathBuf>,
    pub stats: Arc<RigStats>,
    /// Every vehicle as wired: its LEDs and motors (one, the robot, without a fleet).
    pub vehicles: Vec<WiredVehicle>,
    wand: tokio::sync::watch::Sender<Option<(u8, Option<crate::Point>)>>,
    stop: Option<oneshot::Sender<()>>,
    task: JoinHandle<TruthRecord>,
    links: Vec<PathBuf>,
}

impl RigHandle {
    /// Hold LED `led` as a calibration wand at floor point `at` (`None`: out of sight). The
    /// controller reports that LED there from its next slot on.
    pub fn place_wand(&self, led: u8, at: Option<crate::Point>) {
        self.wand.send_replace(Some((led, at)));
    }

    /// Stop the rig; returns the world's truth. Removes the links it made.
    pub async fn stop(mut self) -> TruthRecord {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        let truth = (&mut self.task).await.unwrap_or_default();
        for link in &self.links {
            let _ = std::fs::remove_file(link);
        }
        truth
    }
}

fn make_link(link: &Path, target: &Path) -> Result<(), RigError> {
    if link.symlink_metadata().is_ok_and(|m| m.file_type().is_symlink()) {
        let _ = std::fs::remove_file(link);
    }
    std::os::unix::fs::symlink(target, link).map_err(|source| RigError::Link { path: link.to_path_buf(), source })
}

/// A pty pair: the master for the simulator (or any scripted peer), an open descriptor
/// on the slave, and the slave's path for the host.
///
/// The simulator keeps a plain descriptor on the slave so that a host can close and reopen
/// it without the line hanging up. It is not serialport's handle: serialport locks every
/// tty it opens (`flock`), which would lock the host out.
pub fn pty() -> Result<(tokio_serial::SerialStream, std::fs::File, PathBuf), RigError> {
    use std::os::unix::fs::OpenOptionsExt;
    let (master, slave) = tokio_serial::SerialStream::pair().map_err(RigError::Pty)?;
    let path = slave.name().map(PathBuf::from).ok_or_else(|| {
        RigError::Pty(tokio_serial::Error::new(tokio_serial::ErrorKind::Unknown, "pty without a name"))
    })?;
    let keep = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOCTTY)
        .open(&path)
        .map_err(|e| RigError::Pty(e.into()))?;
    drop(slave);
    Ok((master, keep, path))
}

/// Serial line I/O: decoded input (mapped by `map`) to the returned receiver, bytes from
/// the returned sender out.
fn spawn_serial<S, D, O>(
    port: S,
    codec: D,
    map: fn(D::Item, &D) -> O,
) -> (mpsc::Receiver<O>, mpsc::Sender<Vec<u8>>, JoinHandle<()>)
where
    S: AsyncRead + AsyncWrite + Send + 'static,
    D: tokio_util::codec::Decoder<Error = std::io::Error> + Send + 'static,
    D::Item: Send,
    O: Send + 'static,
{
    let (read, mut write) = tokio::io::split(port);
    let (in_tx, in_rx) = mpsc::channel(256);
    let (out_tx, mut out_rx) = mpsc::channel::<Vec<u8>>(256);
    let task = tokio::spawn(async move {
        let mut frames = FramedRead::new(read, codec);
        loop {
            tokio::select! {
                item = frames.next() => match item {
                    Some(Ok(item)) => { if in_tx.send(map(item, frames.decoder())).await.is_err() { break } }
                    Some(Err(_)) | None => break,
                },
                bytes = out_rx.recv() => match bytes {
                    Some(b) => { if write.write_all(&b).await.is_err() { break } }
                    None => break,
                },
            }
        }
    });
    (in_rx, out_tx, task)
}

/// A PSD frame as the controller takes it: the packet, or why it did not decode.
fn psd_item(item: Result<Packet, StreamError<psd::Error>>, codec: &PsdCodec) -> Result<Packet, BadRequest> {
    item.map_err(|e| BadRequest::from_stream(e, codec))
}

/// An SLCAN line as the adapter takes it: `None` for a line that did not parse.
fn slcan_item(
    item: Result<Command, StreamError<flowgate_protocol::slcan::SlcanError>>,
    _: &SlcanAdapterCodec,
) -> Option<Command> {
    item.ok()
}

/// The CAN side as the rig loop sees it.
enum Bus {
    Slcan { adapter: SlcanAdapter, rx: mpsc::Receiver<Option<Command>>, tx: mpsc::Sender<Vec<u8>> },
    Socket { rx: mpsc::Receiver<CanFrame>, tx: mpsc::Sender<CanFrame> },
}

/// A SocketCAN interface as the loop's bus: frames read into one queue, written from
/// another, by a task of its own.
fn socketcan_bus(interface: &str) -> Result<(Bus, tokio::task::JoinHandle<()>), RigError> {
    let socket = socketcan::tokio::CanSocket::open(interface)
        .map_err(|source| RigError::SocketCan { interface: interface.to_string(), source })?;
    let (in_tx, rx) = mpsc::channel(256);
    let (tx, mut out_rx) = mpsc::channel::<CanFrame>(256);
    let task = tokio::spawn(async move {
        let mut socket = socket;
        loop {
            tokio::select! {
                frame = socket.next() => match frame {
                    Some(Ok(f)) => {
                        if let Ok(f) = CanFrame::try_from(&f) {
                            if in_tx.send(f).await.is_err() { break }
                        }
                    }
                    Some(Err(e)) => tracing::warn!("CAN read: {e}"),
                    None => break,
                },
                out = out_rx.recv() => match out {
                    Some(f) => { if let Err(e) = socket.write_frame(f.into()).await { tracing::warn!("CAN write: {e}") } }
                    None => break,
                },
            }
        }
    });
    Ok((Bus::Socket { rx, tx }, task))
}

/// Start the rig. Returns once its endpoints exist, so a host can open them at once.
pub async fn start(config: RigConfig) -> Result<RigHandle, RigError> {
    if let Some(key) = Motors::unplayed(config.motor_kind(), &config.faults) {
        return Err(RigError::Unplayed(format!("{key}: played by the PCL-80K-like board only, not by CiA 402 drives")));
    }
    let wired = config.vehicles()?;
    let vehicles = wired.clone();
    let mut links = Vec::new();
    let mut keep_alive: Vec<std::fs::File> = Vec::new();
    let mut psd_keep = None;
    let (psd_port, psd_path) = match &config.psd {
        SerialEndpoint::Pty { link } => {
            let (master, slave, path) = pty()?;
            psd_keep = Some(slave);
            if let Some(link) = link {
                make_link(link, &path)?;
                links.push(link.clone());
            }
            (master, path)
        }
        SerialEndpoint::Device { path, baud } => {
            let port = tokio_serial::SerialStream::open(&tokio_serial::new(path.to_string_lossy(), *baud))
                .map_err(|source| RigError::Device { path: path.clone(), source })?;
            (port, path.clone())
        }
    };
    let (psd_rx, psd_tx, psd_task) = spawn_serial(psd_port, PsdCodec::controller(), psd_item);
    let psd = PsdIo { rx: psd_rx, tx: psd_tx, task: psd_task, keep: psd_keep };

    let mut can_path = None;
    let (bus, can_task) = match &config.can {
        CanEndpoint::SlcanPty { link } => {
            let (master, slave, path) = pty()?;
            keep_alive.push(slave);
            if let Some(link) = link {
                make_link(link, &path)?;
                links.push(link.clone());
            }
            can_path = Some(path);
            let (rx, tx, task) = spawn_serial(master, SlcanAdapterCodec::new(), slcan_item);
            (Bus::Slcan { adapter: SlcanAdapter::default(), rx, tx }, task)
        }
        CanEndpoint::SocketCan { interface } => socketcan_bus(interface)?,
    };

    let stats = Arc::new(RigStats::default());
    let (stop_tx, stop_rx) = oneshot::channel();
    let (wand, wand_rx) = tokio::sync::watch::channel(None);
    let loop_stats = stats.clone();
    let task = tokio::spawn(async move {
        let (truth, psd) = run(config, wired, psd, bus, stop_rx, wand_rx, loop_stats).await;
        psd.task.abort();
        can_task.abort();
        drop(keep_alive);
        truth
    });
    Ok(RigHandle { psd_path, can_path, stats, vehicles, wand, stop: Some(stop_tx), task, links })
}

/// The PSD controller's serial endpoint as the loop holds it (replaceable: it can vanish).
struct PsdIo {
    rx: mpsc::Receiver<Result<Packet, BadRequest>>,
    tx: mpsc::Sender<Vec<u8>>,
    task: JoinHandle<()>,
    /// Our descriptor on the pty's slave, keeping the line up.
    keep: Option<std::fs::File>,
}

impl PsdIo {
    /// A new pty behind `link`.
    fn reopen(link: &Path) -> Result<Self, RigError> {
        let (master, keep, path) = pty()?;
        make_link(link, &path)?;
        let (rx, tx, task) = spawn_serial(master, PsdCodec::controller(), psd_item);
        Ok(Self { rx, tx, task, keep: Some(keep) })
    }
}

/// Frames from elsewhere on the bus (the `foreign_frames` fault).
pub fn foreign_frames(node: NodeId) -> [CanFrame; 3] {
    use flowgate_protocol::motor::{BoardState, FaultBits, MotorMessage};
    let other = MotorMessage::Status {
        node: NodeId::new(9).expect("9"),
        state: BoardState::Enabled,
        faults: FaultBits::default(),
        last_seq: 0,
        seq_errors: 0,
    };
    let std = |id: u16, data: &[u8]| CanFrame::new(flowgate_protocol::CanId::Standard(id), data).expect("valid");
    [
        other.to_frame().expect("valid"),
        std(0x123, &[0xDE, 0xAD]),
        std(0x200 | u16::from(node.get()), &[2]), // our status id, one byte: does not decode
    ]
}

/// A second master's command to our board (the `second_master_at` fault): both the board
/// and the host see it.
pub fn second_master_command(node: NodeId) -> CanFrame {
    use flowgate_protocol::motor::MotorMessage;
    MotorMessage::Velocity { node, left: 50, right: 50, seq: 0 }.to_frame().expect("in range")
}

/// Period of the second master's commands, s.
pub const SECOND_MASTER_PERIOD: f64 = 0.02;

/// The rig's loop in real time: the world, the PSD controller and the motors stepped to
/// the host's clock, their output put on the serial line and the bus with the faults the
/// config injects, and what comes back handed to them.
struct Realtime {
    config: RigConfig,
    psd: PsdIo,
    bus: Bus,
    stats: Arc<RigStats>,
    fleet: Fleet,
    /// The vehicles' names, the robot first (the truth names them).
    names: Vec<String>,
    controller: PsdController,
    motors: FleetMotors,
    serial_faults: SerialFaults,
    can_faults: CanFaults,
    bursts: VecDeque<f64>,
    truth: TruthRecord,
    next_truth: f64,
    psd_link: Option<PathBuf>,
    /// (vanish at, back at), while pending.
    vanish: Option<(f64, f64)>,
    psd_gone: bool,
    next_foreign: f64,
    next_master: f64,
    origin: Instant,
    psd_out: Vec<Outgoing>,
    pending: SerialQueue,
    can_out: Vec<CanFrame>,
    to_host: Vec<Response>,
    to_bus: Vec<CanFrame>,
}

impl Realtime {
    fn new(config: RigConfig, wired: &[WiredVehicle], psd: PsdIo, bus: Bus, stats: Arc<RigStats>) -> Self {
        let mut fleet = Fleet::for_rig(&config.scenario);
        let mut controller =
            PsdController::new(config.camera, config.leds, config.noise_counts, config.seed, config.faults.clone());
        let kinds: Vec<MotorKind> = wired.iter().map(|v| v.motors).collect();
        let link_lost_at = std::iter::once(f64::INFINITY)
            .chain(config.scenario.vehicles.iter().map(|v| v.link_lost_at.unwrap_or(f64::INFINITY)))
            .collect();
        let mut motors = FleetMotors::new(&kinds, &config.faults, link_lost_at);
        let psd_link = match &config.psd {
            SerialEndpoint::Pty { link } => link.clone(),
            SerialEndpoint::Device { .. } => None,
        };
        let f = &config.faults;
        let (mut psd_out, mut can_out) = (Vec::new(), Vec::new());
        controller.boot(0.0, &mut psd_out);
        motors.boot(0.0, &mut fleet, &mut can_out);
        Self {
            serial_faults: SerialFaults::new(f),
            can_faults: CanFaults::new(f),
            bursts: f.serial_burst_at.iter().copied().collect(),
            vanish: f.serial_vanish_at.map(|at| (at, at + f.serial_vanish_s)),
            next_foreign: if f.foreign_frames { 0.0 } else { f64::INFINITY },
            next_master: f.second_master_at.unwrap_or(f64::INFINITY),
            truth: TruthRecord::default(),
            next_truth: 0.0,
            psd_gone: false,
            origin: Instant::now(),
            pending: SerialQueue::default(),
            to_host: Vec::new(),
            to_bus: Vec::new(),
            config,
            psd,
            bus,
            stats,
            fleet,
            names: wired.iter().map(|v| v.name.clone()).collect(),
            controller,
            motors,
            psd_link,
            psd_out,
            can_out,
        }
    }

    fn now(&self) -> f64 {
        self.origin.elapsed().as_secs_f64()
    }

    /// The world, the controller and the motors brought to `t`, the injected events due.
    fn advance(&mut self, t: f64, wand: Option<(u8, Option<crate::Point>)>) {
        if t > self.fleet.time() {
            self.fleet.step(t - self.fleet.time());
        }
        if let Some((led, at)) = wand {
            self.fleet.world_mut(0).place_wand(led, at);
        }
        self.controller.poll(t, &self.fleet, &mut self.psd_out);
        self.motors.poll(t, &mut self.fleet, &mut self.can_out);
        self.vanish(t);
        if t >= self.next_foreign {
            self.next_foreign = t + 0.1;
            self.can_out.extend(foreign_frames(self.config.node));
        }
        if t >= self.next_master {
            self.next_master = t + SECOND_MASTER_PERIOD;
            let frame = second_master_command(self.config.node);
            self.motors.robot().handle(t, &frame, self.fleet.world_mut(0), &mut self.can_out);
            self.can_out.push(frame);
        }
    }

    /// The serial device vanishing (the pty closes; the host's reads fail) and coming back.
    fn vanish(&mut self, t: f64) {
        let Some((gone_at, back_at)) = self.vanish else { return };
        if !self.psd_gone && t >= gone_at {
            self.psd.task.abort();
            self.psd.keep = None;
            self.psd_gone = true;
            self.pending.clear();
            self.psd_out.clear();
        } else if self.psd_gone && t >= back_at {
            self.vanish = None;
            match self.psd_link.as_deref().map(PsdIo::reopen) {
                Some(Ok(io)) => {
                    self.psd = io;
                    self.psd_gone = false;
                    let c = &self.config;
                    self.controller =
                        PsdController::new(c.camera, c.leds, c.noise_counts, c.seed, c.faults.booted_at(t));
                    self.controller.boot(t, &mut self.psd_out);
                }
                Some(Err(e)) => tracing::error!("serial device cannot come back: {e}"),
                None => tracing::error!("serial_vanish_at needs a pty endpoint with a link"),
            }
        }
    }

    /// Serial out: in order, each message no earlier than its time (injected delay), with
    /// the line's faults.
    fn serial_out(&mut self, t: f64) {
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        for o in self.psd_out.drain(..) {
            self.pending.push(o);
        }
        let mut bytes = Vec::new();
        while let Some(packet) = self.pending.pop_due(t) {
            self.serial_faults.packets(t, packet, &mut |p| {
                if let Ok(n) = p.encode(&mut wire) {
                    bytes.extend_from_slice(&wire[..n]);
                }
            });
        }
        while self.bursts.front().is_some_and(|&at| at <= t) {
            self.bursts.pop_front();
            bytes.extend(self.serial_faults.burst(self.config.faults.serial_burst_len));
        }
        if !bytes.is_empty() {
            self.serial_faults.apply(t, &mut bytes);
            self.stats.serial_bytes_dropped.store(self.serial_faults.dropped, Ordering::Relaxed);
            self.stats.serial_bytes_corrupted.store(self.serial_faults.corrupted, Ordering::Relaxed);
            let n = bytes.len() as u64;
            if self.psd_gone || self.psd.tx.try_send(bytes).is_err() {
                self.stats.serial_overflow_bytes.fetch_add(n, Ordering::Relaxed);
            }
        }
    }

    /// CAN out: the board's frames onto the bus (unless bus-off or lost).
    fn can_out(&mut self, t: f64) {
        let bus_off = self.config.faults.bus_off(t);
        for f in self.can_out.drain(..) {
            if bus_off || self.can_faults.lose(t) {
                continue;
            }
            self.stats.can_frames_out.fetch_add(1, Ordering::Relaxed);
            match &mut self.bus {
                Bus::Slcan { adapter, tx, .. } => {
                    adapter.bus_off = self.config.faults.adapter_bus_off(t);
                    if let Some(r) = adapter.from_bus(f, t) {
                        send_line(tx, &r);
                    }
                }
                Bus::Socket { tx, .. } => {
                    let _ = tx.try_send(f);
                }
            }
        }
        self.stats.can_frames_lost.store(self.can_faults.lost, Ordering::Relaxed);
    }

    /// The world's truth, sampled every [`SAMPLE_PERIOD`] up to `t`.
    fn record_truth(&mut self, t: f64) {
        while self.next_truth <= t {
            self.truth.record_fleet(&self.fleet, &self.names);
            self.next_truth += SAMPLE_PERIOD;
        }
    }

    /// When the loop next has something to do, s.
    fn next_wake(&self, t: f64) -> f64 {
        let mut next = self.controller.next_event().min(self.motors.next_event()).min(self.next_truth).min(t + 0.005);
        next = next.min(self.pending.next_at());
        if let Some(&b) = self.bursts.front() {
            next = next.min(b);
        }
        if let Some((gone_at, back_at)) = self.vanish {
            next = next.min(if self.psd_gone { back_at } else { gone_at });
        }
        next.min(self.next_foreign).min(self.next_master)
    }

    /// Frames the host sent onto the bus, to the motors (unless bus-off or lost).
    fn frames_in(&mut self) {
        let t = self.now();
        for f in self.to_bus.drain(..) {
            self.stats.can_frames_in.fetch_add(1, Ordering::Relaxed);
            if !self.config.faults.bus_off(t) && !self.can_faults.lose(t) {
                self.motors.handle(t, &f, &mut self.fleet, &mut self.can_out);
            }
        }
    }
}

async fn run(
    config: RigConfig,
    wired: Vec<WiredVehicle>,
    psd: PsdIo,
    bus: Bus,
    mut stop: oneshot::Receiver<()>,
    wand: tokio::sync::watch::Receiver<Option<(u8, Option<crate::Point>)>>,
    stats: Arc<RigStats>,
) -> (TruthRecord, PsdIo) {
    let mut rig = Realtime::new(config, &wired, psd, bus, stats);
    loop {
        let t = rig.now();
        rig.advance(t, *wand.borrow());
        rig.serial_out(t);
        rig.can_out(t);
        rig.record_truth(t);
        let deadline = rig.origin + Duration::from_secs_f64(rig.next_wake(t).max(t));
        let Realtime { psd, bus, controller, config, stats, to_host, to_bus, psd_out, psd_gone, origin, .. } = &mut rig;
        let now = || origin.elapsed().as_secs_f64();
        let (slcan_rx, socket_rx) = match bus {
            Bus::Slcan { rx, .. } => (Some(rx), None),
            Bus::Socket { rx, .. } => (None, Some(rx)),
        };
        tokio::select! {
            _ = &mut stop => break,
            _ = tokio::time::sleep_until(deadline) => {}
            Some(request) = psd.rx.recv(), if !*psd_gone => {
                stats.psd_requests.fetch_add(1, Ordering::Relaxed);
                if request.is_err() {
                    stats.psd_bad_requests.fetch_add(1, Ordering::Relaxed);
                }
                controller.handle(now(), request, psd_out);
            }
            Some(line) = async { match slcan_rx { Some(rx) => rx.recv().await, None => std::future::pending().await } } => {
                if let Bus::Slcan { adapter, tx, .. } = bus {
                    adapter.bus_off = config.faults.adapter_bus_off(now());
                    adapter.handle(line, to_host, to_bus);
                    for r in to_host.drain(..) {
                        send_line(tx, &r);
                    }
                }
            }
            Some(frame) = async { match socket_rx { Some(rx) => rx.recv().await, None => std::future::pending().await } } => {
                to_bus.push(frame);
            }
        }
        rig.frames_in();
    }
    rig.truth.record_fleet(&rig.fleet, &rig.names);
    (rig.truth, rig.psd)
}

fn send_line(tx: &mpsc::Sender<Vec<u8>>, r: &Response) {
    let mut buf = [0u8; MAX_LINE_LEN];
    if let Ok(n) = r.emit(&mut buf) {
        let _ = tx.try_send(buf[..n].to_vec());
    }
}

/// Encode a PSD packet into bytes (for tools and tests that write to the simulator).
pub fn encode_packet(p: Packet) -> Vec<u8> {
    let mut buf = BytesMut::new();
    PsdCodec::new().encode(p, &mut buf).expect("packets fit");
    buf.to_vec()
}
