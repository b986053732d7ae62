//! The whole stack in deterministic virtual time, on one thread.
//!
//! The real gateway [`Core`] is wired to the simulator's firmware (the PSD controller, an
//! SLCAN USB-CAN adapter and the motor board on its bus) and its world, through the real
//! encoders and decoders: COBS + CRC frames on the serial line, SLCAN lines to the adapter,
//! CAN frames on the bus. Each direction of each line is a `Wire` that delivers its bytes
//! in order after their transmission time (10 bits a byte). Time jumps from one event to the
//! next: the core's deadline, a firmware event, a delivery, a fault. Every random choice is
//! seeded by the scenario, so one seed gives one run, byte for byte (`cycles.csv` and
//! `can.log` included): a failure is replayed exactly from its seed.
//!
//! The harness plays the rig shell's part the way [`crate::gateway::shell`] does: it arms on
//! the controller's first stream, reopens a lost serial line every 200 ms, and hands every
//! output of the core to its line.

use std::collections::VecDeque;
use std::path::Path;

use bytes::BytesMut;
use flowgate_protocol::codec::{PsdCodec, SlcanAdapterCodec, SlcanHostCodec};
use flowgate_protocol::slcan::Command;
use flowgate_protocol::CanFrame;
use flowgate_sim::camera::CameraModel;
use flowgate_sim::faults::{CanFaults, FaultPlan, SerialFaults};
use flowgate_sim::motors::FleetMotors;
use flowgate_sim::psd_controller::{LedMap, Outgoing, PsdController, SerialQueue};
use flowgate_sim::truth::TruthRecord;
use flowgate_sim::world::fleet::Fleet;
use flowgate_sim::world::World;

use super::{Outcome, Scenario};
use crate::gateway::core::input::{InputRecord, RecordedInput};
use crate::gateway::core::operator::{Refusal, Request, Status};
use crate::gateway::core::{Answer, Core, Input, NoClock, SetupError, StageClock, State};
use crate::gateway::shell::telemetry::{CycleRecord, Timing, WrittenFiles};
use crate::gateway::shell::Report;
use crate::time::HostTime;

mod events;
mod wiring;

use wiring::{fault_plan, firmware_spec, fleet_motors, gateway_rig};

/// The PSD line's and the SLCAN adapter's serial rate, baud.
pub const SERIAL_BAUD: f64 = 921_600.0;
/// The longest the world advances without an event (so its truth is sampled finely).
const MAX_STEP_NS: u64 = 5_000_000;
/// How long the world keeps running after the gateway stopped, s (its truth then shows
/// the robot at rest).
pub const LINGER: f64 = 0.8;

/// What to keep of a run.
#[derive(Debug, Clone, Copy, Default)]
pub struct Options {
    /// Truth samples every 20 ms (for plots and stop-time checks); the summary is always kept.
    pub truth_samples: bool,
    /// `cycles.csv` and `can.log`, in memory.
    pub telemetry: bool,
    /// End the run at the first contact (sweeps need no more).
    pub stop_at_contact: bool,
    /// Start idle and wait for operator requests ([`VirtualRig::request`]), as the rig's
    /// gateway does without `--arm`. By default the run arms and starts towards the
    /// scenario's goal when the controller first streams.
    pub wait_for_operator: bool,
    /// How the gateway reaches the CAN bus.
    pub can: CanTransport,
    /// Settings of the gateway's rig beyond what the scenario implies (a test's watchdogs).
    pub adjust_rig: Option<fn(&mut crate::config::Rig)>,
    /// Keep every input handed to the core, as a recording's input channels keep them
    /// ([`VirtualRun::inputs`]): replayed into a fresh core, they give the same outputs.
    pub record_inputs: bool,
    /// Rehearse the cycle ([`Core::rehearse`], the low-latency mode's warm-up) at every
    /// event of the run, far more often than a rig does: it must change nothing.
    pub rehearse: bool,
    /// The motors are two CiA 402 drives (nodes 1 and 2, `[cia402]` at its defaults), not
    /// the PCL-80K-like board. They do not play the board's own faults
    /// ([`Motors::unplayed`](flowgate_sim::motors::Motors::unplayed)).
    pub cia402: bool,
    /// The PSD controller drives this many LEDs (up to the protocol's 64), not the
    /// simulated one's 16: a fleet past it, for the benchmark.
    pub controller_leds: Option<u8>,
    /// Time, on the host's clock, each handling of the controller's bytes that ran a
    /// cycle ([`VirtualRig::cycle_ns`]).
    pub time_cycles: bool,
    /// The robot's own CAN link fails at this time, s, as a vehicle's `link_lost_at` does
    /// (the fleet's swarm): its motors neither hear the bus nor are heard on it.
    pub robot_link_lost_at: Option<f64>,
}

/// The gateway's CAN link in the virtual rig.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum CanTransport {
    /// An SLCAN adapter on a serial line (the lines at 921600 baud, the adapter's firmware).
    #[default]
    Slcan,
    /// A SocketCAN interface: frames straight onto the bus at 1 Mbit/s; the host's own
    /// controller going bus-off arrives as an error frame.
    SocketCan,
}

impl CanTransport {
    /// The interface name candump lines carry.
    fn interface(self) -> &'static str {
        match self {
            Self::Slcan => "slcan0",
            Self::SocketCan => "vcan0",
        }
    }
}

/// Frames on a CAN bus at 1 Mbit/s, one after another, each after its transmission time.
#[derive(Debug, Default)]
struct FrameWire {
    frames: VecDeque<(u64, CanFrame)>,
    free_at: u64,
}

impl FrameWire {
    /// Send `frame` at `at`; returns when it has crossed the bus.
    fn send(&mut self, at: u64, frame: CanFrame) -> u64 {
        // Header, CRC and trailer about 47 bits, 8 a data byte; 1 µs a bit.
        let bits = 47 + 8 * frame.data().len() as u64;
        let arrive = at.max(self.free_at) + bits * 1000;
        self.free_at = arrive;
        self.frames.push_back((arrive, frame));
        arrive
    }

    fn next(&self) -> u64 {
        self.frames.front().map_or(u64::MAX, |f| f.0)
    }

    fn take(&mut self, t: u64) -> Option<CanFrame> {
        self.frames.front().is_some_and(|f| f.0 <= t).then(|| self.frames.pop_front().map(|f| f.1)).flatten()
    }
}

/// One direction of a serial line: bytes in order, each chunk arriving after its
/// transmission time and no earlier than the chunk before it. Chunks are taken whole and in
/// order, so the buffer empties (and rewinds) whenever the line goes idle.
#[derive(Debug)]
struct Wire {
    bytes: Vec<u8>,
    head: usize,
    chunks: VecDeque<(u64, usize)>,
    free_at: u64,
    byte_ns: u64,
}

impl Wire {
    fn new(baud: f64) -> Self {
        Self {
            bytes: Vec::with_capacity(4096),
            head: 0,
            chunks: VecDeque::with_capacity(64),
            free_at: 0,
            byte_ns: (10.0 / baud * 1e9).round() as u64,
        }
    }

    /// Send `data` at `at`; returns when its last byte arrives.
    fn send(&mut self, at: u64, data: &[u8]) -> u64 {
        let arrive = at.max(self.free_at) + data.len() as u64 * self.byte_ns;
        self.free_at = arrive;
        self.bytes.extend_from_slice(data);
        self.chunks.push_back((arrive, data.len()));
        arrive
    }

    fn next(&self) -> u64 {
        self.chunks.front().map_or(u64::MAX, |c| c.0)
    }

    /// The next chunk due by `t` into `buf`.
    fn take(&mut self, t: u64, buf: &mut Vec<u8>) -> bool {
        match self.chunks.front() {
            Some(&(at, len)) if at <= t => {
                self.chunks.pop_front();
                buf.clear();
                buf.extend_from_slice(&self.bytes[self.head..self.head + len]);
                self.head += len;
                if self.chunks.is_empty() {
                    self.clear();
                }
                true
            }
            _ => false,
        }
    }

    fn clear(&mut self) {
        self.bytes.clear();
        self.head = 0;
        self.chunks.clear();
    }
}

/// The simulated rig's firmware side: what rebuilding the controller needs.
#[derive(Debug, Clone)]
struct ControllerSpec {
    camera: CameraModel,
    leds: LedMap,
    noise_counts: f64,
    seed: u64,
    faults: FaultPlan,
}

impl ControllerSpec {
    /// The controller, booted at `t`.
    fn build(&self, t: f64) -> PsdController {
        PsdController::new(self.camera, self.leds, self.noise_counts, self.seed, self.faults.booted_at(t))
    }
}

/// A stage clock on the host's monotonic clock: the core's stages take their real compute
/// time (virtual time itself is unaffected, but `cycles.csv` then differs run to run).
#[derive(Debug, Clone, Copy)]
pub struct HostClock(std::time::Instant);

impl Default for HostClock {
    fn default() -> Self {
        Self(std::time::Instant::now())
    }
}

impl StageClock for HostClock {
    fn now_ns(&mut self) -> u64 {
        self.0.elapsed().as_nanos() as u64
    }
}

/// `cycles.csv` and `can.log` of a virtual run.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Telemetry {
    pub cycles_csv: Vec<u8>,
    pub can_log: Vec<u8>,
}

impl Telemetry {
    /// The planner's compute time per cycle (the `plan_ns` column): p50, p99, max, µs.
    pub fn plan_us(&self) -> [f64; 3] {
        let text = String::from_utf8_lossy(&self.cycles_csv);
        let plan = CycleRecord::column("plan_ns").expect("a column of cycles.csv");
        let mut ns: Vec<u64> =
            text.lines().skip(1).filter_map(|l| l.split(',').nth(plan).and_then(|v| v.parse().ok())).collect();
        ns.sort_unstable();
        let q = |p: f64| ns.get(((ns.len().max(1) - 1) as f64 * p).round() as usize).map_or(0.0, |&v| v as f64 / 1e3);
        [q(0.5), q(0.99), q(1.0)]
    }

    /// Write both files into `dir`.
    pub fn write(&self, dir: &Path) -> std::io::Result<()> {
        std::fs::create_dir_all(dir)?;
        std::fs::write(dir.join("cycles.csv"), &self.cycles_csv)?;
        std::fs::write(dir.join("can.log"), &self.can_log)
    }
}

/// A finished virtual run.
#[derive(Debug, Clone)]
pub struct VirtualRun {
    pub report: Report,
    pub truth: TruthRecord,
    pub outcome: Outcome,
    /// The robot ended within the goal tolerance (+1 cm for the stop ramp).
    pub reached_goal: bool,
    pub contact: bool,
    /// Since when the wheels have stood still, s (None: still turning at the end).
    pub at_rest_since: Option<f64>,
    pub telemetry: Option<Telemetry>,
    /// The PSD controller could not be configured (the run never started).
    pub setup_error: Option<SetupError>,
    /// Velocity commands that were not zero, given outside Running (the invariant: none).
    pub motion_outside_running: u64,
    /// What the simulator injected on the serial line: packets duplicated, packets
    /// replayed, bytes dropped, bytes corrupted.
    pub injected: [u64; 4],
    /// Every input the core took, in order, and every CAN frame it asked for, with
    /// [`Options::record_inputs`].
    pub inputs: Vec<InputRecord>,
    pub can_sent: Vec<CanFrame>,
}

/// The stack in virtual time. `K` times the core's stages ([`NoClock`] for determinism).
#[derive(Debug)]
pub struct VirtualRig<K: StageClock = NoClock> {
    t: u64,
    /// Every vehicle's world (the robot's alone, without `[[vehicles]]`), and their names.
    fleet: Fleet,
    names: Vec<String>,
    spec: ControllerSpec,
    controller: PsdController,
    /// Every vehicle's motors on the one bus, and the board node each vehicle's answers at.
    motors: FleetMotors,
    board_nodes: Vec<Option<u8>>,
    adapter: flowgate_sim::slcan_adapter::SlcanAdapter,
    core: Core<K>,
    /// The core's next deadline, asked for once after each input rather than at each of the
    /// dozen or so events of a cycle (see [`feed`]).
    core_deadline: HostTime,
    /// The inputs handed to the core, and the CAN frames it asked for, when kept.
    inputs: Option<Vec<InputRecord>>,
    can_sent: Vec<CanFrame>,
    plan: FaultPlan,
    serial_faults: SerialFaults,
    can_faults: CanFaults,
    bursts: VecDeque<f64>,
    vanish: Option<(f64, f64)>,
    psd_gone: bool,
    next_foreign: f64,
    /// When the second master next speaks.
    next_master: f64,
    psd_out: Vec<Outgoing>,
    pending: SerialQueue,
    to_host: Wire,
    to_controller: Wire,
    controller_rx: BytesMut,
    controller_codec: PsdCodec,
    can_up: Wire,
    can_down: Wire,
    host_rx: BytesMut,
    host_codec: SlcanHostCodec,
    adapter_rx: BytesMut,
    adapter_codec: SlcanAdapterCodec,
    can_out: Vec<CanFrame>,
    adapter_replies: Vec<flowgate_protocol::slcan::Response>,
    to_bus: Vec<CanFrame>,
    /// SocketCAN: frames from the gateway onto the bus, and from the bus to the gateway.
    host_tx: FrameWire,
    host_rx_frames: FrameWire,
    /// SocketCAN: the host controller's bus-off was reported (once a bus-off window).
    host_bus_off: bool,
    scratch: Vec<u8>,
    setup_error: Option<SetupError>,
    options: Options,
    truth: TruthRecord,
    next_truth: f64,
    at_rest_since: Option<f64>,
    telemetry: Option<Telemetry>,
    /// Latency and period histograms (with telemetry only: they are large to allocate).
    timing: Option<Timing>,
    /// The state the core last announced for each vehicle, and the motion commands it gave
    /// outside Running (there must be none: every test's invariant).
    announced: Vec<State>,
    /// When each vehicle's gateway began its stop at the goal, s.
    reached_at: Vec<Option<f64>>,
    motion_outside_running: u64,
    lines: LineTruth,
    cycle_ns: Option<Vec<u64>>,
}

/// The world's truth of the lines.
#[derive(Debug)]
struct LineTruth {
    /// Bytes the PSD line delivered to the gateway, and CAN frames the bus delivered to it
    /// (each must be accounted for by the core).
    psd_delivered: u64,
    can_delivered: u64,
    /// FNV-1a over every byte the gateway sent (PSD packets, CAN frames' ids and data): two
    /// runs that agree on it sent the same bytes.
    sent_digest: u64,
}

impl Default for LineTruth {
    fn default() -> Self {
        Self { psd_delivered: 0, can_delivered: 0, sent_digest: FNV_OFFSET }
    }
}

/// FNV-1a's offset basis and prime (64 bits).
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

fn fnv(mut hash: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        hash = (hash ^ u64::from(b)).wrapping_mul(FNV_PRIME);
    }
    hash
}

impl VirtualRig<NoClock> {
    /// The scenario's rig, deterministic.
    pub fn new(scenario: &Scenario, options: Options) -> Self {
        Self::with_clock(scenario, NoClock, options)
    }
}

impl<K: StageClock> VirtualRig<K> {
    /// The scenario's rig, the core's stages timed by `clock`. The scenario's sensing chain
    /// is played by the firmware: its delay as the controller's sample delay, its position
    /// noise as PSD noise in counts (a low-pass filter is not part of the real chain).
    pub fn with_clock(scenario: &Scenario, clock: K, options: Options) -> Self {
        let plan = fault_plan(scenario);
        let (spec, wired) = firmware_spec(scenario, &options, &plan);
        let mut fleet = Fleet::for_rig(&scenario.sim);
        let mut controller = spec.build(0.0);
        let (mut motors, board_nodes) = fleet_motors(scenario, &wired, &plan, &options);
        let (mut psd_out, mut can_out) = (Vec::with_capacity(32), Vec::with_capacity(32));
        controller.boot(0.0, &mut psd_out);
        motors.boot(0.0, &mut fleet, &mut can_out);
        let (gateway_rig, adapter_bitrate) = gateway_rig(scenario, &options);
        let mut rig = Self {
            t: 0,
            core: Core::new(gateway_rig, clock),
            core_deadline: HostTime::ZERO,
            inputs: options.record_inputs.then(Vec::new),
            can_sent: Vec::new(),
            serial_faults: SerialFaults::new(&plan),
            can_faults: CanFaults::new(&plan),
            bursts: plan.serial_burst_at.iter().copied().collect(),
            vanish: plan.serial_vanish_at.map(|at| (at, at + plan.serial_vanish_s)),
            psd_gone: false,
            next_foreign: if plan.foreign_frames { 0.0 } else { f64::INFINITY },
            next_master: plan.second_master_at.unwrap_or(f64::INFINITY),
            plan,
            fleet,
            names: wired.iter().map(|v| v.name.clone()).collect(),
            spec,
            controller,
            motors,
            board_nodes,
            adapter: Default::default(),
            psd_out,
            pending: SerialQueue::default(),
            to_host: Wire::new(SERIAL_BAUD),
            to_controller: Wire::new(SERIAL_BAUD),
            controller_rx: BytesMut::with_capacity(1024),
            controller_codec: PsdCodec::controller(),
            can_up: Wire::new(SERIAL_BAUD),
            can_down: Wire::new(SERIAL_BAUD),
            host_rx: BytesMut::with_capacity(1024),
            host_codec: SlcanHostCodec::new(),
            adapter_rx: BytesMut::with_capacity(1024),
            adapter_codec: SlcanAdapterCodec::new(),
            can_out,
            adapter_replies: Vec::with_capacity(8),
            to_bus: Vec::with_capacity(8),
            host_tx: FrameWire::default(),
            host_rx_frames: FrameWire::default(),
            host_bus_off: false,
            scratch: Vec::with_capacity(1024),
            setup_error: None,
            options,
            truth: TruthRecord::default(),
            next_truth: if options.truth_samples { 0.0 } else { f64::INFINITY },
            at_rest_since: Some(0.0),
            telemetry: options.telemetry.then(|| Telemetry {
                cycles_csv: format!("{}\n", CycleRecord::CSV_HEADER).into_bytes(),
                can_log: Vec::new(),
            }),
            timing: options.telemetry.then(Timing::default),
            announced: vec![State::Idle; wired.len()],
            reached_at: vec![None; wired.len()],
            motion_outside_running: 0,
            lines: LineTruth::default(),
            cycle_ns: options.time_cycles.then(Vec::new),
        };
        rig.core_deadline = rig.core.next_deadline();
        // The shell opens the adapter (close, bitrate, open) and the PSD line at start.
        if options.can == CanTransport::Slcan {
            for cmd in [Command::Close, Command::SetBitrate(adapter_bitrate), Command::Open] {
                rig.host_line(cmd);
            }
        }
        if !options.wait_for_operator {
            rig.feed(Input::ArmAtStart);
        }
        rig.feed(Input::PsdConnected);
        rig.firmware_out();
        rig
    }

    pub fn core(&self) -> &Core<K> {
        &self.core
    }
    /// The robot's world.
    pub fn world(&self) -> &World {
        self.fleet.world(0)
    }
    /// Every vehicle's world.
    pub fn fleet(&self) -> &Fleet {
        &self.fleet
    }
    /// When vehicle `k`'s gateway began its stop at its goal, s.
    pub fn reached_at(&self, k: usize) -> Option<f64> {
        self.reached_at.get(k).copied().flatten()
    }
    /// The CAN frames the core asked for so far, with [`Options::record_inputs`].
    pub fn can_sent(&self) -> &[CanFrame] {
        &self.can_sent
    }
    /// Virtual time, s.
    pub fn time(&self) -> f64 {
        secs(self.t)
    }
    /// Since when the wheels have stood still, s (`None`: turning now).
    pub fn at_rest_since(&self) -> Option<f64> {
        self.at_rest_since
    }
    /// Bytes the PSD line delivered to the gateway, and CAN frames the bus delivered to it.
    pub fn delivered(&self) -> (u64, u64) {
        (self.lines.psd_delivered, self.lines.can_delivered)
    }
    /// A digest of every byte the gateway sent so far (FNV-1a, 64 bits).
    pub fn sent_digest(&self) -> u64 {
        self.lines.sent_digest
    }

    /// Run the scenario: until the gateway has stopped (goal, stall, fault) and the world
    /// has run [`LINGER`] more, or the scenario's time limit.
    pub fn run(mut self, time_limit: f64, goal: [f64; 2], tolerance: f64) -> VirtualRun {
        let mut end = time_limit;
        while self.time() < end && self.setup_error.is_none() {
            self.step();
            if self.options.stop_at_contact && self.touched() {
                break;
            }
            if self.at_rest_all() && end == time_limit {
                end = (self.time() + LINGER).min(time_limit);
            }
        }
        self.finish(goal, tolerance)
    }

    /// Run as [`run`](Self::run), handing the rig to `drive` once every `period` s of virtual
    /// time from the start (an outside planner's turn: it looks, and asks). An error from
    /// `drive` ends its turns: the robot is stopped in order, the world runs [`LINGER`] more,
    /// and the error comes back beside the run.
    pub fn run_driven<E>(
        mut self,
        time_limit: f64,
        goal: [f64; 2],
        tolerance: f64,
        period: f64,
        mut drive: impl FnMut(&mut Self) -> Result<(), E>,
    ) -> (VirtualRun, Option<E>) {
        let mut end = time_limit;
        let mut turn = 0.0;
        let mut failure = None;
        while self.time() < end && self.setup_error.is_none() {
            if failure.is_none() && self.time() >= turn {
                turn += period;
                if let Err(e) = drive(&mut self) {
                    failure = Some(e);
                    let _ = self.request(&Request::Stop);
                    end = (self.time() + LINGER).min(time_limit);
                    continue;
                }
            }
            self.step();
            if self.options.stop_at_contact && self.touched() {
                break;
            }
            if self.at_rest_all() && end == time_limit {
                end = (self.time() + LINGER).min(time_limit);
            }
        }
        (self.finish(goal, tolerance), failure)
    }

    /// Run until virtual time `t` (s).
    pub fn run_until(&mut self, t: f64) {
        while self.time() < t && self.setup_error.is_none() {
            self.step();
        }
    }

    /// Hand the core one input now: the one way into it, as the shell's.
    fn feed(&mut self, input: Input<'_>) -> Option<Answer> {
        feed(&mut self.core, &mut self.inputs, &mut self.core_deadline, HostTime::from_nanos(self.t), input)
    }

    /// An operator's request now, and the core's answer.
    fn ask(&mut self, request: &Request) -> Answer {
        let answer = self.feed(Input::Request(request)).expect("the core answers every request");
        self.drain_core();
        self.firmware_out();
        answer
    }

    /// An operator's request now.
    pub fn request(&mut self, request: &Request) -> Result<(), Refusal> {
        self.ask(request).result
    }

    /// An operator's request for vehicle `vehicle` now (0: the robot).
    pub fn vehicle_request(&mut self, vehicle: u8, request: &Request) -> Result<(), Refusal> {
        let answer = self.feed(Input::VehicleRequest { vehicle, request }).expect("the core answers every request");
        self.drain_core();
        self.firmware_out();
        answer.result
    }

    /// What the gateway believes now (its last cycle's pose and speeds, its obstacles).
    pub fn scene(&self) -> crate::gateway::core::scene::SceneRecord {
        self.core.scene(HostTime::from_nanos(self.t))
    }

    /// The operator's status view now.
    pub fn status(&mut self) -> Status {
        self.ask(&Request::Status).status.expect("a status request is answered with the status")
    }

    /// A shutdown request now (as SIGINT gives the rig's gateway).
    pub fn shutdown(&mut self) {
        self.feed(Input::Shutdown);
        self.drain_core();
        self.firmware_out();
    }

    /// Advance to the next event and handle everything due then.
    pub fn step(&mut self) {
        let next = self.next_event().max(self.t + 1);
        let dt = secs(next) - self.fleet.time();
        if dt > 0.0 {
            self.fleet.step(dt);
        }
        self.t = next;
        if self.options.rehearse {
            self.core.rehearse(HostTime::from_nanos(self.t));
            self.core_deadline = self.core.next_deadline();
        }
        self.faults_due();
        self.firmware_poll();
        self.deliver();
        // The core's deadline is read once its outputs are drained: a read is decoded as they are.
        self.drain_core();
        let now = HostTime::from_nanos(self.t);
        if now >= self.core_deadline() {
            self.feed(Input::Tick);
            self.drain_core();
        }
        self.firmware_out();
        self.observe();
    }

    /// End the run here: the episode as it stands.
    pub fn finish(mut self, goal: [f64; 2], tolerance: f64) -> VirtualRun {
        self.record_truth();
        let summary = &self.truth.summary;
        let end = summary.final_position;
        let reached_goal = (end[0] - goal[0]).hypot(end[1] - goal[1]) <= tolerance + 0.01;
        let contact = summary.first_contact.is_some();
        let outcome = match self.core.state() {
            _ if contact => Outcome::Collision,
            State::Stopped(crate::gateway::core::StopReason::GoalReached) if reached_goal => Outcome::Goal,
            State::Stopped(crate::gateway::core::StopReason::Stalled) => Outcome::Stall,
            State::Fault(_) => Outcome::Fault,
            State::Stopped(_) | State::Stopping(_) => Outcome::Stopped,
            _ => Outcome::Timeout,
        };
        VirtualRun {
            report: Report::new(&self.core, self.timing.as_ref(), self.core.counters(), WrittenFiles::default()),
            truth: self.truth,
            outcome,
            reached_goal,
            contact,
            at_rest_since: self.at_rest_since,
            telemetry: self.telemetry,
            setup_error: self.setup_error,
            motion_outside_running: self.motion_outside_running,
            injected: [
                self.serial_faults.duplicated,
                self.serial_faults.replayed,
                self.serial_faults.dropped,
                self.serial_faults.corrupted,
            ],
            inputs: self.inputs.unwrap_or_default(),
            can_sent: self.can_sent,
        }
    }
}

/// Hand `core` one input at `now`, keeping a copy in `log` when there is one.
fn feed<K: StageClock>(
    core: &mut Core<K>,
    log: &mut Option<Vec<InputRecord>>,
    deadline: &mut HostTime,
    now: HostTime,
    input: Input<'_>,
) -> Option<Answer> {
    if let Some(log) = log {
        log.push(InputRecord { seq: log.len() as u64, at: now, input: RecordedInput::of(input) });
    }
    let answer = core.handle(now, input);
    *deadline = core.next_deadline();
    answer
}

/// Run `scenario` through the whole stack in virtual time, deterministically.
pub fn run(scenario: &Scenario, options: Options) -> VirtualRun {
    VirtualRig::new(scenario, options).run(scenario.time_limit, scenario.goal.position, scenario.goal.tolerance)
}

/// The same, with the core's stages timed on the host's clock (for reports, not for
/// byte-for-byte comparisons).
pub fn run_timed(scenario: &Scenario, options: Options) -> VirtualRun {
    VirtualRig::with_clock(scenario, HostClock::default(), options).run(
        scenario.time_limit,
        scenario.goal.position,
        scenario.goal.tolerance,
    )
}

fn secs(ns: u64) -> f64 {
    ns as f64 * 1e-9
}

/// Seconds to whole nanoseconds, rounded up so an event is never handled before it is due.
fn ns(s: f64) -> u64 {
    if s.is_finite() {
        (s * 1e9).ceil().clamp(0.0, u64::MAX as f64) as u64
    } else {
        u64::MAX
    }
}
