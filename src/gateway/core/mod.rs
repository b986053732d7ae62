//! The gateway core: everything the gateway decides, with no I/O and no clock.
//!
//! The core is a state machine in the manner of quinn-proto's `Connection`. There is one way
//! in and two ways out:
//!
//! - [`Core::handle`]`(now, input)`: every [`Input`] (PSD bytes as read, CAN events as
//!   received, the links opening and failing, an operator's request, a shutdown, a tick)
//!   with the host time at which it happened. An operator's request gets its [`Answer`].
//! - [`Core::poll`], after every `handle`, until it returns `None`: the [`Output`]s to carry
//!   out, in order (packets for the PSD controller, CAN frames, each cycle's command with its
//!   timing record, state changes). A PSD read is decoded as its outputs are drained, so
//!   what the caller asks of the core while it carries out a cycle's command is that
//!   cycle's, even when one read carried two frames.
//! - [`Core::next_deadline`], after draining: when to hand the core [`Input::Tick`] if
//!   nothing else happens first. Watchdogs, heartbeats and retries live there, so they fire
//!   however the I/O around the core behaves.
//!
//! The rig's tokio shell ([`crate::gateway::shell`]), replay of a recording
//! ([`crate::replay`]), the virtual rig of the deterministic simulation and the fuzz target
//! all drive it this way and no other, so a recording of the inputs of any of them replays
//! every decision, byte for byte. The queries ([`Core::state`], [`Core::counters`],
//! [`Core::scene`], ...) change nothing.
//!
//! ```
//! use flowgate::config::RigFile;
//! use flowgate::gateway::core::{Core, Input, NoClock, Output};
//! use flowgate::time::HostTime;
//!
//! let config = RigFile::from_toml(include_str!("../../../rig.example.toml"), "rig.toml").unwrap();
//! let mut core = Core::new(config.rig("rig.toml").unwrap(), NoClock);
//! let mut now = HostTime::ZERO;
//! core.handle(now, Input::PsdConnected);
//! let mut to_controller = 0;
//! for _ in 0..10 {
//!     // Carry out what the core asks: here, count the packets for the controller.
//!     while let Some(output) = core.poll() {
//!         if let Output::Psd(_packet) = output {
//!             to_controller += 1; // the shell encodes and writes it to the serial line
//!         }
//!     }
//!     // Nothing was read: sleep until the core's deadline and tick it.
//!     now = core.next_deadline();
//!     core.handle(now, Input::Tick);
//! }
//! // The handshake's request, asked again while the controller stays silent.
//! assert!(to_controller >= 2);
//! ```
//!
//! Per cycle (one PSD time-division frame, closed by its `FrameEnd`): decode -> floor
//! coordinates (calibration) -> tracks (each vehicle's [`PoseTrack`], the [`ObstacleTracks`])
//! -> each vehicle's control step, in the fleet's order -> its CAN velocity frame. The same core runs on the rig, in deterministic virtual time against the
//! simulator's firmware, in replay and in the benchmarks: that is what makes a
//! virtual-time test evidence about the rig.
//!
//! The core is a dispatcher over its machines, each in its own module, in the order a
//! sample travels: [`psd_session`] (the controller's handshake, sequence and clock) and
//! [`frame`] (one time-division frame) on the PSD link ([`psd_link`]); the obstacles' tracks
//! and the control step (`cycle`); each vehicle the core drives, the robot first (`vehicle`:
//! its pose track, [`safety`] state machine, control step, motors and goals) and what each
//! sees of the others (`fleet`), their motors behind one type ([`motors`]: a board or CiA 402
//! drives) on the CAN link (`can_link`); the operator's requests (`requests`), each for one
//! vehicle or for the fleet; and one timer table ([`timers`]), the rig's entries and each
//! vehicle's, that both gives the next deadline and fires what is due.

use std::time::Duration;

use crate::config::Rig;
use crate::time::HostTime;
use crate::track::ObstacleTracks;
#[cfg(doc)]
use crate::track::PoseTrack;

mod budget;
mod can_link;
pub mod counter_window;
mod counters;
mod cycle;
mod fleet;
pub mod frame;
pub mod input;
mod mission;
pub mod motors;
pub mod notice;
pub mod operator;
mod output;
pub mod psd_link;
pub mod psd_session;
mod requests;
pub mod safety;
pub mod scene;
mod script_run;
pub mod timers;
pub mod timing;
mod vehicle;
mod watch;

pub use counters::{Counters, Progress};
pub use input::{Answer, CanEvent, Input};
pub use notice::{Level, Notice};
pub use output::Output;
pub use psd_session::{SerialBytes, SetupError};
pub use safety::{RobotMotion, State, StopReason};
pub use script_run::ScriptStatus;

use can_link::CanLinkHealth;
use frame::FrameAssembler;
use motors::MotorCounters;
use output::Outbox;
use psd_link::PsdLinkHealth;
use psd_session::PsdSession;
use safety::{Action, Safety};
use vehicle::DrivenVehicle;
use watch::{SampleWatch, StampWatch};

/// The robot's index among the vehicles the core drives: the first.
const ROBOT: usize = 0;

/// How often the gateway sends its heartbeat.
pub const HEARTBEAT_PERIOD: Duration = Duration::from_millis(100);
/// How long an orderly stop may take before the gateway calls the axes at rest.
pub const STOP_GRACE: Duration = Duration::from_secs(1);
/// How often a lost serial line or CAN link is asked to be opened again.
pub const REOPEN_EVERY: Duration = Duration::from_millis(200);

/// Measures how long each stage of a cycle takes. The core reads no clock of its own: the
/// rig's shell hands it a monotonic one, the deterministic simulation [`NoClock`] (every
/// stage then takes zero time, and the outputs depend on the inputs alone).
pub trait StageClock {
    /// Nanoseconds from an arbitrary origin.
    fn now_ns(&mut self) -> u64;
}

/// A stage clock that always says zero.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoClock;

impl StageClock for NoClock {
    fn now_ns(&mut self) -> u64 {
        0
    }
}

/// Stage times gathered before a frame's cycle runs, ns.
#[derive(Debug, Default)]
struct StageTimes {
    /// Decode time, and check time (sequence, time mapping, schedule, frame assembly),
    /// since the last cycle.
    decode_ns: u64,
    checks_ns: u64,
    /// When the packet being handled was decoded (stage clock): its checks run from here.
    checks_from: Option<u64>,
}

impl StageTimes {
    /// A packet took `ns` to decode.
    fn decoded(&mut self, ns: u64) {
        self.decode_ns += ns;
    }

    /// A packet's checks begin at `at` (stage clock).
    fn checks_begin(&mut self, at: u64) {
        self.checks_from = Some(at);
    }

    /// The checks under way, if any (a cycle may have taken them), end at `now()`.
    fn checks_end(&mut self, now: impl FnOnce() -> u64) {
        if let Some(from) = self.checks_from.take() {
            self.checks_ns += now().saturating_sub(from);
        }
    }

    /// This frame's decode and checks, for its cycle; the next frame's count from zero.
    fn take_for_cycle(&mut self) -> (u64, u64) {
        (std::mem::take(&mut self.decode_ns), std::mem::take(&mut self.checks_ns))
    }
}

/// The gateway core. `K` times the stages of a cycle.
#[derive(Debug)]
pub struct Core<K: StageClock> {
    rig: Rig,
    clock: K,
    out: Outbox,
    psd: PsdSession,
    frame: FrameAssembler,
    /// Every obstacle LED's track.
    obstacles: ObstacleTracks,
    /// What each vehicle sees of the others.
    fleet: fleet::FleetViews,
    /// Every vehicle the core drives, the robot first ([`ROBOT`]): each one's pose track,
    /// safety state, control step, motors and goals.
    vehicles: Vec<DrivenVehicle>,
    motor_counters: MotorCounters,
    /// The two links' health.
    psd_link: PsdLinkHealth,
    can_link: CanLinkHealth,
    /// What the watchdogs and the core's own timers count from.
    samples: SampleWatch,
    stamps: StampWatch,
    stages: StageTimes,
    counters: Counters,
    progress: Progress,
    shutdown: bool,
}

impl<K: StageClock> Core<K> {
    pub fn new(rig: Rig, clock: K) -> Self {
        let radii: Vec<f64> = rig.obstacles.iter().map(|o| o.radius).collect();
        let budget = rig.safety.bad_frames_per_s;
        Self {
            psd: PsdSession::new(rig.schedule, rig.psd_counts),
            frame: FrameAssembler::new(budget),
            obstacles: ObstacleTracks::new(rig.tracking, &radii),
            fleet: fleet::FleetViews::new(1 + rig.vehicles.len()),
            vehicles: std::iter::once(DrivenVehicle::robot(&rig))
                .chain(rig.vehicles.iter().map(DrivenVehicle::vehicle))
                .collect(),
            motor_counters: MotorCounters::default(),
            out: Outbox::new(),
            psd_link: PsdLinkHealth::new(budget),
            can_link: CanLinkHealth::new(),
            samples: SampleWatch::default(),
            stamps: StampWatch::default(),
            stages: StageTimes::default(),
            counters: Counters::default(),
            progress: Progress::default(),
            shutdown: false,
            clock,
            rig,
        }
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }
    pub fn state(&self) -> State {
        self.vehicles[ROBOT].state()
    }
    /// Vehicle `k`'s name (0: `robot`; then the `[[vehicles]]` in order).
    pub fn vehicle_name(&self, k: usize) -> &str {
        self.vehicles.get(k).map_or("?", |v| v.name.as_str())
    }
    /// The index of the vehicle named `name` (`robot`, or a `[[vehicles]]` name), as
    /// [`Input::VehicleRequest`] takes it.
    pub fn vehicle_index(&self, name: &str) -> Option<u8> {
        self.vehicles.iter().position(|v| v.name == name).and_then(|k| u8::try_from(k).ok())
    }
    /// Vehicle `k`'s safety state.
    pub fn vehicle_state(&self, k: usize) -> Option<State> {
        self.vehicles.get(k).map(|v| v.state())
    }
    /// Vehicle `k`'s states since it started, each with when it was entered, s.
    pub fn vehicle_history(&self, k: usize) -> &[(f64, State)] {
        self.vehicles.get(k).map_or(&[], |v| &v.safety.history)
    }
    /// Scripted vehicle `k`'s distance from its script (`None`: not scripted).
    pub fn vehicle_script(&self, k: usize) -> Option<ScriptStatus> {
        self.vehicles.get(k)?.script.as_ref().map(script_run::ScriptRun::status)
    }
    /// How many vehicles it drives, the robot included.
    pub fn vehicle_count(&self) -> usize {
        self.vehicles.len()
    }
    pub fn safety(&self) -> &Safety {
        &self.vehicles[ROBOT].safety
    }
    pub fn counters(&self) -> Counters {
        self.counters.with_motors(self.motor_counters)
    }
    /// Where the PSD line's bytes went (every one accounted for).
    pub fn serial_bytes(&self) -> SerialBytes {
        self.psd.bytes()
    }
    pub fn progress(&self) -> Progress {
        self.progress
    }
    /// Whether the controller has streamed at least once (a setup failure before that is a
    /// startup failure).
    pub fn has_streamed(&self) -> bool {
        self.psd_link.has_streamed()
    }
    /// Shutdown was asked for and the robot is at rest: the caller may end the run.
    pub fn finished(&self) -> bool {
        self.shutdown
            && self.vehicles.iter().all(|v| matches!(v.state(), State::Idle | State::Stopped(_) | State::Fault(_)))
    }
    /// What the core holds in its queues, in elements of capacity: the output queue, the
    /// budgets' windows, the goals. A soak asserts it stops growing once warm.
    pub fn footprint(&self) -> usize {
        self.out.capacity()
            + self.psd_link.footprint()
            + self.can_link.footprint()
            + self.vehicles[ROBOT].mission.capacity()
    }

    /// The PSD receive buffer's capacity, bytes: it rises and falls as frames are taken
    /// out of it, so a soak holds it to a bound rather than to its warm size.
    pub fn psd_buffer_capacity(&self) -> usize {
        self.psd.buffered_capacity()
    }

    /// The next output, if any. A PSD read is decoded here, up to its next output: a read
    /// that carried two frames gives the first cycle's command while the core is still in
    /// that cycle's state, so what the caller asks of it then ([`Core::scene`]) is that
    /// cycle's.
    pub fn poll(&mut self) -> Option<Output> {
        if self.out.is_empty() {
            self.decode_read(true);
        }
        self.out.pop()
    }

    /// One input at `now`: every input the core takes goes through here on the rig, so a
    /// recording of them replays the run (see [`input`]). An operator's request gets its
    /// answer back.
    pub fn handle(&mut self, now: HostTime, input: Input<'_>) -> Option<Answer> {
        // Inputs are taken in order: what is left of an earlier read is decoded first.
        self.decode_read(false);
        match input {
            Input::PsdConnected => self.psd_connected(now),
            Input::PsdLost => self.psd_lost(now),
            Input::PsdBytes(bytes) => self.psd_bytes(now, bytes),
            Input::Can(event) => self.can_event(now, event),
            Input::CanFailed => self.can_failed(now),
            Input::CanReopened => self.can_reopened(),
            Input::Request(request) => return Some(self.answer(now, None, request)),
            Input::VehicleRequest { vehicle, request } => {
                return Some(self.answer(now, Some(usize::from(vehicle)), request));
            }
            Input::ArmAtStart => self.vehicles[ROBOT].mission.arm_at_start(),
            Input::Shutdown => self.shutdown(now),
            Input::Tick => self.tick(now),
        }
        None
    }

    /// Stop every vehicle in order and end the run once they are at rest.
    fn shutdown(&mut self, now: HostTime) {
        self.shutdown = true;
        for k in 0..self.vehicles.len() {
            if !matches!(self.vehicles[k].state(), State::Stopping(_)) {
                self.stop_vehicle(k, now, StopReason::Shutdown);
            }
        }
    }

    /// Stop every vehicle for `reason`: the rig's own (the camera, the bus, the operator's
    /// e-stop, a shutdown).
    fn stop(&mut self, now: HostTime, reason: StopReason) {
        for k in 0..self.vehicles.len() {
            self.stop_vehicle(k, now, reason);
        }
    }

    /// Stop vehicle `k` for `reason`: its own (its pose, its motors, its goal, its planner).
    fn stop_vehicle(&mut self, k: usize, now: HostTime, reason: StopReason) {
        let action = self.vehicles[k].safety.stop(now.secs(), reason);
        self.act(k, now, action);
    }

    /// Something for the operator's log, at `now` (the shell logs it and keeps it).
    fn notice(&mut self, now: HostTime, notice: Notice) {
        self.out.push(Output::Notice { at: now, notice });
    }

    /// Something of vehicle `k`'s for the operator's log: named for it, unless it is the
    /// robot's.
    fn vehicle_notice(&mut self, k: usize, now: HostTime, notice: Notice) {
        let notice = match k {
            ROBOT => notice,
            _ => Notice::OfVehicle { vehicle: self.vehicles[k].name.clone(), notice: Box::new(notice) },
        };
        self.notice(now, notice);
    }

    /// Stop every vehicle whose watchdogs are armed for `reason` (a budget exceeded while
    /// idle is counted, not a fault).
    fn stop_if_active(&mut self, now: HostTime, reason: StopReason) {
        for k in 0..self.vehicles.len() {
            if self.vehicles[k].state().is_active() {
                self.stop_vehicle(k, now, reason);
            }
        }
    }

    /// Whether any vehicle is armed, running or stopping.
    fn any_active(&self) -> bool {
        self.vehicles.iter().any(|v| v.state().is_active())
    }

    /// Carry out on vehicle `k`'s motors what a transition asks.
    fn act(&mut self, k: usize, now: HostTime, action: Action) {
        if self.vehicles[k].act(now, action, &mut self.out.can()) {
            let state = self.vehicles[k].state();
            self.vehicle_notice(k, now, Notice::EmergencyStop { state });
        }
        self.state_changed(k, now);
    }

    /// Vehicle `k`'s orderly stop ends once its motors are at rest, or its grace has passed.
    fn check_at_rest(&mut self, k: usize, now: HostTime) {
        if self.vehicles[k].settle(now, self.shutdown, &mut self.out.can()) {
            self.state_changed(k, now);
        }
    }

    fn state_changed(&mut self, k: usize, now: HostTime) {
        let state = self.vehicles[k].state();
        if self.vehicles[k].announced != state {
            self.vehicles[k].announced = state;
            if k == ROBOT {
                self.progress.state = state;
            } else {
                let others = self.vehicles[ROBOT + 1..].iter().filter(|v| v.state().is_active()).count();
                self.progress.others_active = others as u32;
            }
            self.out.push(Output::State { at: now, vehicle: k, state });
        }
    }
}

#[cfg(test)]
mod tests;
