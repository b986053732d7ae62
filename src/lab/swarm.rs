//! The fault swarm (`flowgate plan --swarm N`): random schedules of overlapping faults on
//! both links and in the world, each run through the whole stack in virtual time with an
//! operator who resets, arms and starts after every stop, and judged against the
//! simulator's world truth.
//!
//! Each episode draws, from `(seed, episode)` alone, how the gateway reaches the wheels
//! (a board over SLCAN or SocketCAN, CiA 402 drives over SLCAN) and one to four faults of
//! the kinds in [`Kind`], at random times and overlapping. The invariants, checked on every
//! episode ([`run_episode`]):
//!
//! - never an active contact (the robot driving into what it touches);
//! - every fault state is named for a fault present then, with its LED or node;
//! - the wheels at rest within the budget of the fault table for that reason;
//! - no motion while faulted, Armed only when the operator armed, Running only when started;
//! - after the last fault ends, the operator's reset, arm and start bring the robot to its
//!   goal (a cause that never ends must end in a fault naming it);
//! - every byte the PSD line delivered is taken, dropped and counted, or still buffered,
//!   and every CAN frame the bus delivered is counted;
//! - the run advances.
//!
//! An episode is a pure function of the scenario, the seed and its index: a violation is
//! replayed alone, to the same bytes ([`JudgedEpisode::digest`]), with `--episode K`.

use std::collections::BTreeMap;

use flowgate_sim::faults::FaultPlan;
use flowgate_sim::scenario::{Motion, ObstacleSpec};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::sweep::{Shard, TooLarge};
use super::virtual_rig::{CanTransport, Options, VirtualRig};
use super::Scenario;
use crate::gateway::core::operator::{Goal, Request};
use crate::gateway::core::{State, StopReason};

/// How the gateway reaches the wheels in an episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Backend {
    /// The PCL-80K-like board, over an SLCAN adapter.
    BoardSlcan,
    /// The board, over SocketCAN.
    BoardSocketCan,
    /// Two CiA 402 drives, over an SLCAN adapter.
    DrivesSlcan,
}

impl Backend {
    const ALL: [Backend; 3] = [Backend::BoardSlcan, Backend::BoardSocketCan, Backend::DrivesSlcan];

    fn options(self) -> Options {
        Options {
            can: if self == Self::BoardSocketCan { CanTransport::SocketCan } else { CanTransport::Slcan },
            cia402: self == Self::DrivesSlcan,
            ..Options::default()
        }
    }

    fn board(self) -> bool {
        self != Self::DrivesSlcan
    }

    fn slcan(self) -> bool {
        self != Self::BoardSocketCan
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::BoardSlcan => "board over SLCAN",
            Self::BoardSocketCan => "board over SocketCAN",
            Self::DrivesSlcan => "CiA 402 drives over SLCAN",
        }
    }
}

/// The kinds of fault the swarm draws from: every fault the simulator plays, on the PSD
/// line, on the CAN bus and its adapter, in the motors, and in the world.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    SerialCorruption,
    SerialDrops,
    SerialRepeats,
    SerialBursts,
    SerialSilence,
    SampleDelay,
    SampleJitter,
    ClockStep,
    OddSyncReply,
    SyncHeld,
    ControllerReset,
    ControllerFault,
    ControllerOverrun,
    SerialVanish,
    RobotOccluded,
    ObstacleOccluded,
    Reflection,
    SequenceJump,
    FrameJump,
    UnscheduledLed,
    CanLoss,
    HeartbeatLoss,
    BoardFault,
    BoardEStop,
    BoardReboot,
    BoardBusOff,
    AdapterBusOff,
    BitrateMismatch,
    DriveUndervoltage,
    DriveBlocked,
    PasserBy,
}

impl Kind {
    pub const ALL: [Kind; 31] = [
        Kind::SerialCorruption,
        Kind::SerialDrops,
        Kind::SerialRepeats,
        Kind::SerialBursts,
        Kind::SerialSilence,
        Kind::SampleDelay,
        Kind::SampleJitter,
        Kind::ClockStep,
        Kind::OddSyncReply,
        Kind::SyncHeld,
        Kind::ControllerReset,
        Kind::ControllerFault,
        Kind::ControllerOverrun,
        Kind::SerialVanish,
        Kind::RobotOccluded,
        Kind::ObstacleOccluded,
        Kind::Reflection,
        Kind::SequenceJump,
        Kind::FrameJump,
        Kind::UnscheduledLed,
        Kind::CanLoss,
        Kind::HeartbeatLoss,
        Kind::BoardFault,
        Kind::BoardEStop,
        Kind::BoardReboot,
        Kind::BoardBusOff,
        Kind::AdapterBusOff,
        Kind::BitrateMismatch,
        Kind::DriveUndervoltage,
        Kind::DriveBlocked,
        Kind::PasserBy,
    ];

    /// What it is, as docs/faults.md prints it.
    pub fn describe(self) -> &'static str {
        match self {
            Kind::SerialCorruption => "PSD bytes corrupted (0.5-10%, or all) for 50 ms-1 s",
            Kind::SerialDrops => "PSD bytes lost (0.05-5%) for 0.2-2 s",
            Kind::SerialRepeats => "PSD packets duplicated and replayed for 0.2-2 s",
            Kind::SerialBursts => "1-3 bursts of 16-512 garbage bytes",
            Kind::SerialSilence => "the PSD line silent for 20-800 ms",
            Kind::SampleDelay => "samples delayed 30-400 ms, stepped or creeping, for 0.2-4 s",
            Kind::SampleJitter => "samples jittered ±0.5-5 ms all run",
            Kind::ClockStep => "the controller's clock steps 20-500 ms",
            Kind::OddSyncReply => "one time-sync reply 20-200 ms off",
            Kind::SyncHeld => "time-sync replies held 15-60 ms for 1-8 s",
            Kind::ControllerReset => "the PSD controller resets",
            Kind::ControllerFault => "the PSD controller reports a fault (codes 3-5)",
            Kind::ControllerOverrun => "the PSD controller reports an overrun",
            Kind::SerialVanish => "the PSD serial device vanishes for 0.2-1 s",
            Kind::RobotOccluded => "a robot LED occluded for 50 ms-1.5 s",
            Kind::ObstacleOccluded => "an obstacle LED occluded for 0.2-2.5 s",
            Kind::Reflection => "a robot LED reflected 3-30 cm off for 20 ms-1 s",
            Kind::SequenceJump => "one PSD packet numbered 0x7FFF ahead",
            Kind::FrameJump => "one frame's counter 2^31 - 1 ahead",
            Kind::UnscheduledLed => "samples of an unscheduled LED for 50 ms-1 s",
            Kind::CanLoss => "CAN frames lost (2-50%) for 0.2-2 s",
            Kind::HeartbeatLoss => "node 1's heartbeat stops for 0.1-1.5 s",
            Kind::BoardFault => "the board's driver faults",
            Kind::BoardEStop => "the board's e-stop input open for 0.1-1.5 s",
            Kind::BoardReboot => "the board (or node 1's drive) reboots",
            Kind::BoardBusOff => "the board bus-off for 0.1-1.5 s",
            Kind::AdapterBusOff => "the gateway's CAN controller bus-off for 50 ms-1.5 s",
            Kind::BitrateMismatch => "the SLCAN adapter opened at 500 kbit/s on the 1 Mbit/s bus",
            Kind::DriveUndervoltage => "node 1's drive under-voltage for 0.1-1 s",
            Kind::DriveBlocked => "node 1's wheel blocked for 0.1-1 s",
            Kind::PasserBy => "an obstacle walks into the view, across, and out",
        }
    }

    fn applies(self, backend: Backend) -> bool {
        match self {
            Kind::BoardFault | Kind::BoardEStop | Kind::BoardBusOff => backend.board(),
            Kind::DriveUndervoltage | Kind::DriveBlocked => !backend.board(),
            Kind::BitrateMismatch => backend.slcan(),
            _ => true,
        }
    }

    /// How often it is drawn against the others: a mismatched bitrate never lets the robot
    /// move, so it is drawn less.
    fn weight(self) -> u32 {
        if self == Kind::BitrateMismatch {
            1
        } else {
            5
        }
    }

    /// Whether a fault of this kind, for `led`, explains a stop named `reason`.
    fn explains(self, led: Option<u8>, reason: StopReason) -> bool {
        use StopReason as R;
        let node1 = |node: u8| node == 1;
        match (self, reason) {
            (Kind::SerialCorruption | Kind::SerialDrops | Kind::SerialBursts, R::SerialGarbled { .. }) => true,
            // A jump is discarded and counted against the budget, which earlier discards may
            // have all but filled.
            (Kind::SerialRepeats | Kind::SequenceJump, R::PsdSequence { .. }) => true,
            (Kind::FrameJump, R::FrameCounterJump) => true,
            (Kind::SerialSilence, R::SamplesStopped) => true,
            (Kind::SampleDelay, R::SamplesStopped | R::PoseDelayed) => true,
            (Kind::ClockStep, R::ClockJumped) => true,
            (Kind::SyncHeld, R::ClockUnsynced) => true,
            (Kind::ControllerReset, R::ControllerReset) => true,
            (Kind::ControllerFault, R::ControllerFault) => true,
            (Kind::SerialVanish, R::SerialLost) => true,
            (Kind::RobotOccluded, R::PoseLost) => true,
            (Kind::ObstacleOccluded, R::ObstacleOccluded { led: l }) => Some(l) == led,
            (Kind::Reflection, R::PoseImplausible) => true,
            (Kind::UnscheduledLed, R::UnscheduledLed { led: l }) => Some(l) == led,
            // Commands lost until the board's own timeout latches its fault; the enable lost.
            (
                Kind::CanLoss,
                R::BoardSequence { node }
                | R::HeartbeatLost { node }
                | R::BoardFault { node }
                | R::BoardNotEnabled { node },
            ) => node1(node),
            // Both drives share the bus: either may go unheard.
            (Kind::CanLoss, R::DriveHeartbeatLost { .. } | R::DriveSdoTimeout { .. }) => true,
            // A drive that stops hearing the gateway's heartbeat reports it (EMCY 0x8130).
            (Kind::CanLoss | Kind::AdapterBusOff | Kind::BitrateMismatch, R::DriveEmergency { code: 0x8130, .. }) => {
                true
            }
            (Kind::HeartbeatLoss, R::HeartbeatLost { node } | R::DriveHeartbeatLost { node }) => node1(node),
            (Kind::BoardFault, R::BoardFault { node }) => node1(node),
            // Once the input closed, the board's e-stop latch reads as its fault.
            (Kind::BoardEStop, R::BoardEStop { node } | R::BoardFault { node }) => node1(node),
            (Kind::BoardReboot, R::BoardReboot { node } | R::DriveRebooted { node }) => node1(node),
            // Unheard, then reporting its bus-off; or its command timeout, commands unheard.
            (Kind::BoardBusOff, R::HeartbeatLost { node } | R::BoardBusOff { node } | R::BoardFault { node }) => {
                node1(node)
            }
            // The board's command timeout, our commands not reaching it.
            (Kind::AdapterBusOff | Kind::BitrateMismatch, R::BoardFault { node }) => node1(node),
            // Samples lost inside the controller count against the sequence budget.
            (Kind::ControllerOverrun, R::PsdSequence { .. }) => true,
            // The adapter's controller off the bus: found by its flags, or by the
            // transmits it refuses meanwhile, or by the drives' answers that never come.
            (Kind::AdapterBusOff | Kind::BitrateMismatch, R::BusOff | R::CanTransmitRefused) => true,
            (Kind::AdapterBusOff | Kind::BitrateMismatch, R::DriveSdoTimeout { .. }) => true,
            (Kind::DriveUndervoltage, R::DriveEmergency { node, code }) => node1(node) && code == 0x3220,
            (Kind::DriveBlocked, R::DriveEmergency { node, code }) => node1(node) && code == 0x8611,
            // The drive's emergency may be lost on the bus: its state word then tells; armed
            // while the cause lasts, it does not enable.
            (Kind::DriveUndervoltage | Kind::DriveBlocked, R::DriveLeftOperation { node, .. }) => node1(node),
            (Kind::DriveUndervoltage | Kind::DriveBlocked, R::DriveNotEnabled { node, .. }) => node1(node),
            // A drive that stops hearing the gateway faults (its emergency may be lost too).
            (Kind::CanLoss | Kind::AdapterBusOff, R::DriveLeftOperation { .. }) => true,
            _ => false,
        }
    }

    /// How long after its cause ends a fault of this kind may still be detected, s: the
    /// watchdog that finds it, and the samples still under way.
    fn grace(self) -> f64 {
        match self {
            Kind::SyncHeld => 5.5,
            Kind::ObstacleOccluded => 1.2,
            // Found at the next periodic time sync and confirmed by a second.
            Kind::ClockStep => 1.5,
            // Latched by the board until a reset: reported when the gateway next looks.
            Kind::BoardBusOff | Kind::BoardEStop => 1.5,
            // Its discards stay in the sequence budget's one-second window.
            Kind::SerialRepeats => 1.0,
            _ => 0.5,
        }
    }

    /// Whether its cause silences what a watchdog watches from its start (a partial cause
    /// lets some through, and its watchdog counts from the last that came).
    fn total(self) -> bool {
        matches!(
            self,
            Kind::SerialSilence
                | Kind::SerialVanish
                | Kind::HeartbeatLoss
                | Kind::RobotOccluded
                | Kind::ObstacleOccluded
                | Kind::SyncHeld
                | Kind::BoardBusOff
                | Kind::AdapterBusOff
        )
    }

    /// Whether it disturbs the gateway's commands reaching the wheels: a stop may then
    /// wait for the motors' own command timeout.
    fn cuts_commands(self) -> bool {
        matches!(self, Kind::CanLoss | Kind::AdapterBusOff | Kind::BoardBusOff | Kind::BitrateMismatch)
    }
}

/// One fault of a schedule: its kind, when its cause is present (`[from, to]`, s; `to`
/// infinite for a cause that never ends), and the LED it concerns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Injected {
    pub kind: Kind,
    pub from: f64,
    pub to: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub led: Option<u8>,
}

/// An episode's draw: the backend, the faults, and the scenario they make.
#[derive(Debug, Clone)]
pub struct FaultSchedule {
    pub backend: Backend,
    pub faults: Vec<Injected>,
    /// The scenario with the faults in its `[faults]` (and a passer-by in its obstacles).
    pub scenario: Scenario,
}

impl FaultSchedule {
    /// When the last cause that ends has ended, s.
    pub fn last_end(&self) -> f64 {
        self.faults.iter().map(|f| f.to).filter(|t| t.is_finite()).fold(0.0, f64::max)
    }

    /// Whether a cause lasts the whole run.
    pub fn lasting(&self) -> bool {
        self.faults.iter().any(|f| f.to.is_infinite())
    }
}

/// Faults start within this window of the run, s (the robot drives from about 0.1 s).
const START_WINDOW: (f64, f64) = (0.5, 7.0);
/// The most faults of one episode.
const MAX_FAULTS: usize = 4;

/// Draw episode `episode`'s schedule around `base`.
pub fn schedule(base: &Scenario, seed: u64, episode: u64) -> FaultSchedule {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0005_a7a2_u64 ^ episode.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let backend = Backend::ALL[rng.random_range(0..Backend::ALL.len())];
    let mut pool: Vec<Kind> = Kind::ALL.iter().copied().filter(|k| k.applies(backend)).collect();
    let count = rng.random_range(1..=MAX_FAULTS);
    let mut kinds = Vec::with_capacity(count);
    for _ in 0..count {
        let total: u32 = pool.iter().map(|k| k.weight()).sum();
        let mut pick = rng.random_range(0..total);
        let k = pool.iter().position(|k| {
            let hit = pick < k.weight();
            pick = pick.saturating_sub(k.weight());
            hit
        });
        kinds.push(pool.remove(k.unwrap_or(0)));
    }
    let mut scenario = base.clone();
    let mut plan = FaultPlan { seed: u64::from(rng.random::<u32>()), ..base.faults.clone() };
    let obstacles = u8::try_from(base.obstacles.len()).unwrap_or(u8::MAX);
    let mut faults = Vec::with_capacity(kinds.len());
    for kind in kinds {
        let a = rng.random_range(START_WINDOW.0..START_WINDOW.1);
        let (to, led) = match kind {
            Kind::BitrateMismatch => {
                faults.push(Injected { kind, from: 0.0, to: f64::INFINITY, led: None });
                continue;
            }
            Kind::PasserBy => {
                // From beyond the view's edge (about ±0.8 m), across the robot's way, and out.
                let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                let speed = rng.random_range(0.03..0.1);
                let drift = rng.random_range(-0.02..0.02);
                scenario.sim.obstacles.push(ObstacleSpec {
                    radius: 0.07,
                    start: [rng.random_range(-0.3..0.5), 0.95 * side],
                    motion: Motion::Constant { velocity: [drift, -speed * side] },
                });
                (a, Some(3 + obstacles))
            }

            _ => line_fault(kind, a, &mut rng, &mut plan)
                .or_else(|| controller_fault(kind, a, &mut rng, &mut plan, obstacles))
                .or_else(|| motor_fault(kind, a, &mut rng, &mut plan))
                .unwrap_or((a, None)),
        };
        faults.push(Injected { kind, from: a, to, led });
    }
    scenario.sim.faults = plan;
    FaultSchedule { backend, faults, scenario }
}

/// A fault of the PSD line's bytes and timing, drawn into `plan` from `a`: when its cause
/// ends, and the LED it concerns (`None`: not one of these kinds).
fn line_fault(kind: Kind, a: f64, rng: &mut ChaCha8Rng, plan: &mut FaultPlan) -> Option<(f64, Option<u8>)> {
    Some(match kind {
        Kind::SerialCorruption => {
            let to = span(rng, a, 0.05, 1.0);
            plan.serial_corrupt = if rng.random_bool(0.3) { 1.0 } else { rng.random_range(0.005..0.1) };
            plan.serial_corrupt_during = Some([a, to]);
            (to, None)
        }
        Kind::SerialDrops => {
            let to = span(rng, a, 0.2, 2.0);
            plan.serial_drop = rng.random_range(0.0005..0.05);
            plan.serial_drop_during = Some([a, to]);
            (to, None)
        }
        Kind::SerialRepeats => {
            let to = span(rng, a, 0.2, 2.0);
            plan.serial_duplicate = rng.random_range(0.0..0.5);
            plan.serial_replay = rng.random_range(0.0..0.2);
            plan.serial_repeat_during = Some([a, to]);
            (to, None)
        }
        Kind::SerialBursts => {
            let n = rng.random_range(1..=3);
            let mut at: Vec<f64> = (0..n).map(|_| a + rng.random_range(0.0..1.0)).collect();
            at.sort_by(f64::total_cmp);
            plan.serial_burst_len = rng.random_range(16..=512);
            let to = at.last().copied().unwrap_or(a);
            plan.serial_burst_at = at;
            (to, None)
        }
        Kind::SerialSilence => {
            let to = span(rng, a, 0.02, 0.8);
            plan.serial_silence = Some([a, to]);
            (to, None)
        }
        Kind::SampleDelay => {
            let ramp = if rng.random_bool(0.5) { 0.0 } else { rng.random_range(0.1..2.0) };
            let until = a + ramp + rng.random_range(0.2..2.0);
            plan.sample_delay_ramp = Some([a, a + ramp, rng.random_range(30.0..400.0)]);
            plan.sample_delay_until = Some(until);
            (until, None)
        }
        Kind::SampleJitter => {
            plan.sample_jitter_ms = rng.random_range(0.5..5.0);
            // Benign all run: it names no stop, and ends none.
            (a, None)
        }
        _ => return None,
    })
}

/// A fault of the PSD controller, its clock, its packets' counters or its LEDs.
fn controller_fault(
    kind: Kind,
    a: f64,
    rng: &mut ChaCha8Rng,
    plan: &mut FaultPlan,
    obstacles: u8,
) -> Option<(f64, Option<u8>)> {
    Some(match kind {
        Kind::ClockStep => {
            let ms = rng.random_range(20.0..500.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            plan.clock_step = Some([a, ms]);
            (a, None)
        }
        Kind::OddSyncReply => {
            let ms = rng.random_range(20.0..200.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            plan.sync_reply_step = Some([a, ms]);
            (a, None)
        }
        Kind::SyncHeld => {
            let to = span(rng, a, 1.0, 8.0);
            plan.sync_reply_hold = Some([a, to, rng.random_range(15.0..60.0)]);
            (to, None)
        }
        Kind::ControllerReset => {
            plan.controller_reset_at = Some(a);
            (a, None)
        }
        Kind::ControllerFault => {
            plan.controller_fault =
                Some([a, f64::from(rng.random_range(3..=5u8)), f64::from(rng.random_range(0..8u8))]);
            (a, None)
        }
        Kind::ControllerOverrun => {
            plan.controller_fault = Some([a, 2.0, 0.0]);
            (a, None)
        }
        Kind::SerialVanish => {
            plan.serial_vanish_s = rng.random_range(0.2..1.0);
            plan.serial_vanish_at = Some(a);
            (a + plan.serial_vanish_s, None)
        }
        Kind::RobotOccluded | Kind::Reflection => {
            let led = rng.random_range(1..=2u8);
            if kind == Kind::RobotOccluded {
                let to = span(rng, a, 0.05, 1.5);
                plan.occlusions.push([f64::from(led), a, to]);
                (to, Some(led))
            } else {
                let to = span(rng, a, 0.02, 1.0);
                let dx = rng.random_range(0.03..0.3) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                plan.reflections.push([f64::from(led), a, to, dx]);
                (to, Some(led))
            }
        }
        Kind::ObstacleOccluded => {
            let led = 3 + rng.random_range(0..obstacles.max(1));
            let to = span(rng, a, 0.2, 2.5);
            plan.occlusions.push([f64::from(led), a, to]);
            (to, Some(led))
        }
        Kind::SequenceJump => {
            plan.seq_jump_at = Some(a);
            (a, None)
        }
        Kind::FrameJump => {
            plan.frame_jump_at = Some(a);
            (a, None)
        }
        Kind::UnscheduledLed => {
            let to = span(rng, a, 0.05, 1.0);
            plan.unscheduled_led = Some([9.0, a, to]);
            (to, Some(9))
        }
        _ => return None,
    })
}

/// A fault of the CAN bus, its adapter, the board or the drives.
fn motor_fault(kind: Kind, a: f64, rng: &mut ChaCha8Rng, plan: &mut FaultPlan) -> Option<(f64, Option<u8>)> {
    Some(match kind {
        Kind::CanLoss => {
            let to = span(rng, a, 0.2, 2.0);
            plan.can_loss = rng.random_range(0.02..0.5);
            plan.can_loss_during = Some([a, to]);
            (to, None)
        }
        Kind::HeartbeatLoss => {
            let to = span(rng, a, 0.1, 1.5);
            plan.heartbeat_stop_at = Some(a);
            plan.heartbeat_resume_at = Some(to);
            (to, None)
        }
        Kind::BoardFault => {
            plan.board_fault_at = Some(a);
            (a, None)
        }
        Kind::BoardEStop => {
            let to = span(rng, a, 0.1, 1.5);
            plan.board_estop = Some([a, to]);
            (to, None)
        }
        Kind::BoardReboot => {
            plan.board_reboot_at = Some(a);
            (a, None)
        }
        Kind::BoardBusOff => {
            plan.bus_off_s = rng.random_range(0.1..1.5);
            plan.bus_off_at = Some(a);
            (a + plan.bus_off_s, None)
        }
        Kind::AdapterBusOff => {
            let to = span(rng, a, 0.05, 1.5);
            plan.adapter_bus_off = Some([a, to]);
            (to, None)
        }
        Kind::DriveUndervoltage => {
            let to = span(rng, a, 0.1, 1.0);
            plan.drive_undervoltage = Some([a, to]);
            (to, None)
        }
        Kind::DriveBlocked => {
            let to = span(rng, a, 0.1, 1.0);
            plan.drive_blocked = Some([a, to]);
            (to, None)
        }
        _ => return None,
    })
}

/// The end of a cause lasting `lo..hi` s from `a`.
fn span(rng: &mut ChaCha8Rng, a: f64, lo: f64, hi: f64) -> f64 {
    a + rng.random_range(lo..hi)
}

/// The operator: after a stop this long, s, the reset, arm, goal and start; again this
/// often while refused.
const REACTION_S: f64 = 0.5;
/// Once the last cause has ended and the goal is reached, the run goes on this long, s.
const SETTLE_S: f64 = 1.0;
/// The CiA 402 drives' quick stop from the wheels' top speed (0.25 m/s at 4 m/s²), s.
const QUICK_STOP_S: f64 = 0.0625;
/// How long CiA 402 drives wait for the gateway's heartbeat before they stop, s.
const CONSUMER_S: f64 = crate::gateway::core::motors::cia402::CONSUMER_TIME_MS as f64 * 1e-3;
/// A reset's handshake takes its own time sync, within this of the reset, s.
const HANDSHAKE_S: f64 = 0.1;
/// More events than this a second of virtual time is a stuck run.
const STEPS_PER_S: f64 = 200_000.0;
/// Rounding of virtual time against the budgets, s.
const FUZZ_S: f64 = 1e-4;

/// A fault state as the episode saw it.
#[derive(Debug, Clone, Serialize)]
pub struct Stop {
    /// When, s.
    pub at: f64,
    /// The reason, as the operator reads it.
    pub reason: String,
    /// The fault of the schedule it is named for (the earliest present that names it).
    pub named_for: Option<Kind>,
    /// How long after it the wheels were at rest, s (`None`: never).
    pub rest_after: Option<f64>,
}

/// An episode as run and judged.
#[derive(Debug, Clone, Serialize)]
pub struct JudgedEpisode {
    pub index: u64,
    pub backend: Backend,
    pub faults: Vec<Injected>,
    pub stops: Vec<Stop>,
    /// The operator's requests refused, and the last of them.
    pub refusals: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_refusal: Option<String>,
    pub reached_goal: bool,
    /// The virtual time the episode ran, s.
    pub duration: f64,
    /// The invariants it broke (none, in a good run).
    pub violations: Vec<String>,
    /// FNV-1a of every byte the gateway sent, in hex: a replay sends the same.
    pub digest: String,
    /// The gateway's states and when it entered each, s (kept with the episode's files).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub states: Vec<(f64, String)>,
}

/// What the episode's operator and the world showed over the run.
#[derive(Debug, Default)]
struct EpisodeLog {
    faults: Vec<Seen>,
    refusals: usize,
    last_refusal: Option<String>,
    /// When the operator's resets, arms and starts were accepted, s.
    resets: Vec<f64>,
    arms: Vec<f64>,
    starts: Vec<f64>,
    /// The wheels turned again in a fault after they had come to rest (the first time).
    turned_in_fault: Option<f64>,
    /// The run stopped advancing at this time (far too many events).
    stuck: Option<f64>,
}

#[derive(Debug, Clone, Copy)]
struct Seen {
    at: f64,
    reason: StopReason,
    /// Since when the wheels were at rest (before the fault, if they stood already).
    rest: Option<f64>,
}

impl EpisodeLog {
    fn faulted(&mut self, t: f64, reason: StopReason, at_rest: Option<f64>) {
        self.faults.push(Seen { at: t, reason, rest: at_rest });
    }

    /// After each step: the wheels in a fault. A command sent in Running and still on the
    /// wire at the fault may land after it (within a cycle): the rest is then timed again.
    fn observe(&mut self, t: f64, state: State, at_rest: Option<f64>, period: f64) {
        let Some(last) = self.faults.last_mut() else { return };
        if !matches!(state, State::Fault(_)) {
            return;
        }
        match (last.rest, at_rest) {
            (None, Some(since)) => last.rest = Some(since),
            (Some(_), None) if t <= last.at + period => last.rest = None,
            (Some(_), None) if self.turned_in_fault.is_none() => self.turned_in_fault = Some(t),
            _ => {}
        }
    }

    fn asked(&mut self, t: f64, request: &Request) {
        match request {
            Request::Reset => self.resets.push(t),
            Request::Arm => self.arms.push(t),
            Request::Start => self.starts.push(t),
            _ => {}
        }
    }
}

/// The rig's settings the budgets come from.
#[derive(Debug, Clone, Copy)]
struct Settings {
    /// The control period T, s.
    period: f64,
    safety: crate::config::SafetySettings,
    /// The motors' own command timeout, s.
    board_timeout: f64,
    backend: Backend,
}

impl Settings {
    /// The watchdog that detects `reason`, s (`None`: detected on the input itself).
    fn watchdog(&self, reason: StopReason) -> Option<f64> {
        use StopReason as R;
        let s = &self.safety;
        Some(match reason {
            // Garbage may let a sample through now and then: the watchdog then counts from a
            // sample after the cause began, which the schedule does not know.
            // Found by the sample watchdog, or by the pose watchdog when the line went quiet
            // for less than the sample timeout but took the robot's poses with it.
            R::SamplesStopped => s.sample_timeout.max(s.pose_timeout).as_secs_f64(),
            R::PoseLost => s.pose_timeout.as_secs_f64(),
            R::HeartbeatLost { .. } | R::DriveHeartbeatLost { .. } => s.heartbeat_timeout.as_secs_f64(),
            R::ObstacleOccluded { .. } => s.occlusion_timeout.as_secs_f64(),
            R::ClockUnsynced => crate::gateway::core::psd_session::SYNC_STALE.as_secs_f64(),
            _ => return None,
        })
    }
}

/// The board stops its axes itself for these (within a millisecond of the cause).
fn board_stops_itself(kind: Kind) -> bool {
    matches!(kind, Kind::BoardFault | Kind::BoardEStop | Kind::BoardReboot | Kind::BoardBusOff)
}

/// The latest the wheels may come to rest for a fault state at `at` named for `cause`,
/// s: the fault table's budgets. A board stopping itself: within 1 ms of its cause. CiA
/// 402 drives: their quick stop from top speed, and a cycle. Commands that may not reach
/// the motors (CAN loss, bus-off): the motors' own command timeout, and a cycle.
/// Otherwise: within a cycle of the fault.
fn rest_by(settings: &Settings, schedule: &FaultSchedule, at: f64, cause: Option<&Injected>) -> f64 {
    if let Some(cause) = cause.filter(|c| settings.backend.board() && board_stops_itself(c.kind)) {
        return cause.from + 1e-3;
    }
    let cut =
        schedule.faults.iter().any(|f| f.kind.cuts_commands() && at >= f.from - FUZZ_S && at <= f.to + f.kind.grace());
    let stop = match (cut, settings.backend.board()) {
        (true, true) => settings.board_timeout,
        // Drives that stop hearing the gateway quick-stop by themselves.
        (true, false) => CONSUMER_S + QUICK_STOP_S,
        (false, false) => QUICK_STOP_S,
        (false, true) => 0.0,
    };
    at + stop + settings.period
}

/// The invariants on one episode's fault states, arms and end.
/// The schedule's faults, as a violation lists them.
fn listed(schedule: &FaultSchedule) -> String {
    let each = schedule.faults.iter().map(|f| format!("{:?} {:.3}-{:.3} s", f.kind, f.from, f.to));
    each.collect::<Vec<_>>().join(", ")
}

/// The invariants on one fault state: named for a fault present, found within its
/// watchdog, the wheels at rest within budget. Violations go to `v`.
fn judge_stop(
    schedule: &FaultSchedule,
    settings: &Settings,
    history: &[(f64, State)],
    watch: &EpisodeLog,
    seen: &Seen,
    v: &mut Vec<String>,
) -> Stop {
    let entered_before = |t: f64, state: State| {
        history.iter().rev().find(|(at, s)| *at <= t + FUZZ_S && *s == state).map_or(0.0, |x| x.0)
    };
    let present: Vec<&Injected> = schedule
        .faults
        .iter()
        .filter(|f| {
            f.kind.explains(f.led, seen.reason) && seen.at >= f.from - FUZZ_S && seen.at <= f.to + f.kind.grace()
        })
        .collect();
    let named_for = present.iter().min_by(|a, b| a.from.total_cmp(&b.from)).copied();
    let stop = Stop {
        at: seen.at,
        reason: seen.reason.to_string(),
        named_for: named_for.map(|f| f.kind),
        rest_after: seen.rest.map(|r| r - seen.at),
    };
    // The world's own: an obstacle that walked onto the robot (inside its planning circle
    // the field is not defined), or a planner refusing what the world made of its input.
    let worldly = matches!(seen.reason, StopReason::ObstacleReachedRobot { .. } | StopReason::PlannerInvalid);
    if named_for.is_none() && !worldly {
        v.push(format!(
            "fault at {:.3} s named \"{}\": no fault present names it ({})",
            seen.at,
            seen.reason,
            listed(schedule)
        ));
        return stop;
    }
    if let Some(watchdog) = settings.watchdog(seen.reason) {
        // The watchdogs start afresh at each arm; the time sync's at each reset.
        let restart = if seen.reason == StopReason::ClockUnsynced {
            watch.resets.iter().copied().filter(|r| *r <= seen.at).fold(0.0, f64::max) + HANDSHAKE_S
        } else {
            entered_before(seen.at, State::Armed)
        };
        // From the latest start of a cause that silences it entirely (partial ones let
        // some through, and the watchdog counts from the last).
        let since = present.iter().filter(|f| f.kind.total()).map(|f| f.from.max(restart)).fold(f64::NAN, f64::max);
        // The pose and occlusion watchdogs watch only a running robot, counting from the
        // arm: one that ran out while the robot stood armed fires as it starts to run.
        let running_only = matches!(seen.reason, StopReason::PoseLost | StopReason::ObstacleOccluded { .. });
        let running = if running_only { entered_before(seen.at, State::Running) } else { 0.0 };
        let by = (since + watchdog).max(running) + settings.period;
        if since.is_finite() && seen.at > by + FUZZ_S {
            v.push(format!(
                "fault \"{}\" at {:.3} s: {:.1} ms after its cause, beyond the {:.0} ms watchdog and a cycle",
                seen.reason,
                seen.at,
                (seen.at - since) * 1e3,
                watchdog * 1e3
            ));
        }
    }
    let by = if present.is_empty() {
        rest_by(settings, schedule, seen.at, None)
    } else {
        present.iter().map(|f| rest_by(settings, schedule, seen.at, Some(f))).fold(f64::NEG_INFINITY, f64::max)
    };
    match seen.rest {
        None => v.push(format!("fault \"{}\" at {:.3} s: the wheels never came to rest in it", seen.reason, seen.at)),
        Some(rest) if rest > by + FUZZ_S => v.push(format!(
            "fault \"{}\" at {:.3} s: wheels at rest {:.1} ms after it, the budget {:.1} ms",
            seen.reason,
            seen.at,
            (rest - seen.at) * 1e3,
            (by - seen.at) * 1e3
        )),
        Some(_) => {}
    }
    stop
}

/// Armed only when the operator armed (or at start, before any fault: `ArmAtStart`);
/// Running only after a start since the last arm.
fn judge_arms(history: &[(f64, State)], watch: &EpisodeLog, v: &mut Vec<String>) {
    // Running only after a start since the last arm.
    let first_fault = history.iter().find(|(_, s)| matches!(s, State::Fault(_))).map_or(f64::INFINITY, |x| x.0);
    let mut last_armed = None;
    for (i, &(t, state)) in history.iter().enumerate() {
        match state {
            State::Armed => {
                let asked = watch.arms.iter().any(|a| (a - t).abs() <= FUZZ_S);
                let at_start = t < first_fault && !history[..i].iter().any(|(_, s)| *s == State::Armed);
                if !asked && !at_start {
                    v.push(format!("armed at {t:.3} s without the operator's arm"));
                }
                last_armed = Some((t, at_start && !asked));
            }
            State::Running => {
                let started = match last_armed {
                    Some((_, true)) => true,
                    Some((armed, false)) => watch.starts.iter().any(|s| *s >= armed - FUZZ_S && *s <= t + FUZZ_S),
                    None => false,
                };
                if !started {
                    v.push(format!("running at {t:.3} s without the operator's start"));
                }
            }
            _ => {}
        }
    }
}

fn judge(
    schedule: &FaultSchedule,
    settings: &Settings,
    history: &[(f64, State)],
    watch: &EpisodeLog,
    reached_goal: bool,
    final_state: State,
) -> (Vec<String>, Vec<Stop>) {
    let mut v = Vec::new();
    let stops = watch.faults.iter().map(|seen| judge_stop(schedule, settings, history, watch, seen, &mut v)).collect();
    if let Some(t) = watch.stuck {
        v.push(format!("the run stopped advancing at {t:.6} s (more than {STEPS_PER_S} events a second)"));
    }
    if let Some(t) = watch.turned_in_fault {
        v.push(format!("the wheels turned in a fault at {t:.3} s, after coming to rest in it"));
    }
    judge_arms(history, watch, &mut v);
    let lasting: Vec<&Injected> = schedule.faults.iter().filter(|f| f.to.is_infinite()).collect();
    if lasting.is_empty() {
        if !reached_goal {
            v.push(format!(
                "the goal was not reached after the last fault ended at {:.3} s: {final_state}; the last refusal: {}",
                schedule.last_end(),
                watch.last_refusal.as_deref().unwrap_or("none")
            ));
        }
    } else {
        let named = matches!(final_state, State::Fault(r) if lasting.iter().any(|f| f.kind.explains(f.led, r)));
        if !named {
            v.push(format!("a cause that never ends, and the run ends {final_state}, not in a fault naming it"));
        }
    }
    (v, stops)
}

/// Run episode `index` of the swarm around `base`, and judge it. With `keep`, the run's
/// telemetry and truth samples come back too (for a replay's files).
pub fn run_episode(base: &Scenario, seed: u64, index: u64, keep: bool) -> (JudgedEpisode, super::virtual_rig::Episode) {
    let schedule = schedule(base, seed, index);
    let backend = schedule.backend;
    let mut options = Options { telemetry: keep, truth_samples: keep, ..backend.options() };
    if schedule.faults.iter().any(|f| f.kind == Kind::BitrateMismatch) {
        options.adjust_rig = Some(|rig: &mut crate::config::Rig| {
            if let crate::config::CanUrl::Slcan { bitrate, .. } = &mut rig.can {
                *bitrate = 500_000;
            }
        });
    }
    let s = &schedule.scenario;
    let mut rig = VirtualRig::new(s, options);
    let watch = operate(&mut rig, &schedule);
    let core = rig.core();
    let history = core.safety().history.clone();
    let settings = Settings {
        period: core.rig().sample_period.as_secs_f64(),
        safety: core.rig().safety,
        board_timeout: f64::from(core.rig().board.command_timeout_ms) * 1e-3,
        backend,
    };
    let final_state = core.state();
    let mut accounting = accounting(&rig);
    let digest = format!("{:016x}", rig.sent_digest());
    let run = rig.finish(s.goal.position, s.goal.tolerance);
    let reached_goal = final_state == State::Stopped(StopReason::GoalReached) && run.reached_goal;
    let (mut violations, stops) = judge(&schedule, &settings, &history, &watch, reached_goal, final_state);
    violations.append(&mut accounting);
    let outcome = JudgedEpisode {
        index,
        backend,
        faults: schedule.faults,
        stops,
        refusals: watch.refusals,
        last_refusal: watch.last_refusal,
        reached_goal,
        duration: run.truth.summary.duration,
        violations,
        digest,
        states: if keep { history.iter().map(|(t, state)| (*t, state.to_string())).collect() } else { Vec::new() },
    };
    (outcome, run)
}

/// Run `rig` to the goal after the schedule's last fault (or its time limit past it), the
/// operator resetting, arming, setting the goal and starting after each stop; what it saw.
fn operate(rig: &mut VirtualRig, schedule: &FaultSchedule) -> EpisodeLog {
    let s = &schedule.scenario;
    let period = rig.core().rig().sample_period.as_secs_f64();
    let goal = Request::Goal { goals: vec![Goal { position: s.goal.position, tolerance: s.goal.tolerance }] };
    let last_end = schedule.last_end();
    let limit = last_end + s.time_limit;
    let mut watch = EpisodeLog::default();
    let (mut next_try, mut shown) = (f64::INFINITY, State::Idle);
    // Liveness: a run that takes far more events than a rig has (a few thousand a second)
    // is stuck, and said so.
    let most_steps = (limit * STEPS_PER_S) as u64;
    let mut steps = 0u64;
    while rig.time() < limit {
        steps += 1;
        if steps > most_steps {
            watch.stuck = Some(rig.time());
            break;
        }
        rig.step();
        let (t, state) = (rig.time(), rig.core().state());
        if state != shown {
            if matches!(state, State::Fault(_) | State::Stopped(_) | State::Idle | State::Armed) {
                next_try = t + REACTION_S;
            }
            if let State::Fault(reason) = state {
                watch.faulted(t, reason, rig.at_rest_since());
            }
            shown = state;
        }
        watch.observe(t, state, rig.at_rest_since(), period);
        match state {
            State::Stopped(StopReason::GoalReached) if t >= last_end + SETTLE_S => break,
            State::Stopped(StopReason::GoalReached) => {}
            State::Fault(_) | State::Stopped(_) | State::Idle | State::Armed if t >= next_try => {
                next_try = t + REACTION_S;
                let steps: &[&Request] = match state {
                    State::Fault(_) => &[&Request::Reset, &Request::Arm, &goal, &Request::Start],
                    // Armed and not started (the goal refused, say): the goal and start again.
                    State::Armed => &[&goal, &Request::Start],
                    _ => &[&Request::Arm, &goal, &Request::Start],
                };
                for &request in steps {
                    if let Err(refusal) = rig.request(request) {
                        watch.refusals += 1;
                        watch.last_refusal = Some(format!("{} at {t:.2} s: {refusal}", request_name(request)));
                        break;
                    }
                    watch.asked(t, request);
                }
            }
            _ => {}
        }
    }
    watch
}

/// The world's and the lines' invariants at the end: no active contact, no motion command
/// outside Running, every byte and frame accounted for.
fn accounting(rig: &VirtualRig) -> Vec<String> {
    let mut v = Vec::new();
    if let Some(c) = rig.world().truth().first_active_contact {
        v.push(format!(
            "active contact with {:?} at {:.3} s, driving into it at {:.3} m/s",
            c.with, c.at, c.approach_speed
        ));
    }
    let motion = rig.motion_outside_running();
    if motion > 0 {
        v.push(format!("{motion} motion commands outside Running"));
    }
    let (bytes, delivered, counters) = (rig.core().serial_bytes(), rig.delivered(), rig.core().counters());
    if !bytes.balanced() || bytes.received != delivered.0 {
        v.push(format!(
            "PSD bytes unaccounted for: the line delivered {}, the gateway received {}, took {}, dropped {}, holds {}",
            delivered.0, bytes.received, bytes.taken, bytes.dropped, bytes.buffered
        ));
    }
    if counters.can_frames_in != delivered.1 {
        v.push(format!(
            "CAN frames unaccounted for: the bus delivered {}, the gateway counted {}",
            delivered.1, counters.can_frames_in
        ));
    }
    v
}

fn request_name(request: &Request) -> &'static str {
    match request {
        Request::Reset => "reset",
        Request::Arm => "arm",
        Request::Start => "start",
        Request::Goal { .. } => "goal",
        _ => "request",
    }
}

/// How often each kind was drawn, and the fault states named for it.
#[derive(Debug, Clone, Default, Serialize)]
pub struct KindRow {
    pub episodes: usize,
    pub stops: usize,
    /// The reasons its stops were named, and how many of each.
    pub reasons: BTreeMap<String, usize>,
}

/// A swarm's report (printed, and written as swarm.json).
#[derive(Debug, Clone, Serialize)]
pub struct SwarmReport {
    pub scenario: String,
    pub seed: u64,
    pub shard: String,
    pub episodes: usize,
    /// Episodes that broke an invariant.
    pub violated: usize,
    pub reached_goal: usize,
    /// Episodes with a cause that never ends (they must end faulted, naming it).
    pub lasting: usize,
    pub faults: usize,
    pub stops: usize,
    pub by_backend: BTreeMap<Backend, usize>,
    pub by_kind: BTreeMap<Kind, KindRow>,
    /// The virtual time run, s.
    pub virtual_s: f64,
    /// Every episode that broke an invariant, in full.
    pub failures: Vec<JudgedEpisode>,
    /// Every episode in one line: what a replay must reproduce.
    pub episode_lines: Vec<EpisodeLine>,
}

/// One episode of a swarm, in brief.
#[derive(Debug, Clone, Serialize)]
pub struct EpisodeLine {
    pub index: u64,
    pub backend: Backend,
    pub faults: Vec<Kind>,
    pub stops: usize,
    pub reached_goal: bool,
    pub violations: usize,
    /// FNV-1a of every byte the gateway sent, in hex.
    pub digest: String,
}

/// Run `n` episodes of the swarm (the shard's) around `base` on `threads` threads.
pub fn run(base: &Scenario, n: u64, seed: u64, threads: usize, shard: Shard) -> Result<Vec<JudgedEpisode>, TooLarge> {
    let mut outcomes = shard.run(n, threads, |i| run_episode(base, seed, i, false).0)?;
    outcomes.sort_by_key(|o| o.index);
    Ok(outcomes)
}

/// The report of a swarm's episodes.
pub fn report(base: &Scenario, seed: u64, shard: Shard, outcomes: &[JudgedEpisode]) -> SwarmReport {
    let mut by_kind: BTreeMap<Kind, KindRow> = BTreeMap::new();
    let mut by_backend = BTreeMap::new();
    for o in outcomes {
        *by_backend.entry(o.backend).or_default() += 1;
        for f in &o.faults {
            by_kind.entry(f.kind).or_default().episodes += 1;
        }
        for s in &o.stops {
            if let Some(kind) = s.named_for {
                let row = by_kind.entry(kind).or_default();
                row.stops += 1;
                // The reason's name without its counts (garbled frames differ every time).
                let name = s.reason.split(" (").next().unwrap_or(&s.reason).to_string();
                *row.reasons.entry(name).or_default() += 1;
            }
        }
    }
    SwarmReport {
        scenario: base.name.clone(),
        seed,
        shard: shard.to_string(),
        episodes: outcomes.len(),
        violated: outcomes.iter().filter(|o| !o.violations.is_empty()).count(),
        reached_goal: outcomes.iter().filter(|o| o.reached_goal).count(),
        lasting: outcomes.iter().filter(|o| o.faults.iter().any(|f| f.to.is_infinite())).count(),
        faults: outcomes.iter().map(|o| o.faults.len()).sum(),
        stops: outcomes.iter().map(|o| o.stops.len()).sum(),
        by_backend,
        by_kind,
        virtual_s: outcomes.iter().map(|o| o.duration).sum(),
        failures: outcomes.iter().filter(|o| !o.violations.is_empty()).cloned().collect(),
        episode_lines: outcomes
            .iter()
            .map(|o| EpisodeLine {
                index: o.index,
                backend: o.backend,
                faults: o.faults.iter().map(|f| f.kind).collect(),
                stops: o.stops.len(),
                reached_goal: o.reached_goal,
                violations: o.violations.len(),
                digest: o.digest.clone(),
            })
            .collect(),
    }
}

impl std::fmt::Display for SwarmReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "fault swarm around {}: {} episodes (seed {}, shard {}), {} faults, {} fault states",
            self.scenario, self.episodes, self.seed, self.shard, self.faults, self.stops
        )?;
        let backends: Vec<String> = self.by_backend.iter().map(|(b, n)| format!("{} {n}", b.name())).collect();
        writeln!(f, "  backends: {}", backends.join(", "))?;
        writeln!(
            f,
            "  goal reached after the last fault: {} of {} ({} with a cause that never ends: faulted, naming it)",
            self.reached_goal,
            self.episodes - self.lasting,
            self.lasting
        )?;
        writeln!(f, "  invariants broken: {} episodes", self.violated)?;
        writeln!(f, "  {:<20} {:>8} {:>6}  named", "fault", "episodes", "stops")?;
        for (kind, row) in &self.by_kind {
            let reasons: Vec<String> = row.reasons.iter().map(|(r, n)| format!("{r} {n}")).collect();
            writeln!(f, "  {:<20} {:>8} {:>6}  {}", format!("{kind:?}"), row.episodes, row.stops, reasons.join("; "))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn e2() -> Scenario {
        Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e2-lane-head-on.toml")).unwrap()
    }

    /// A schedule is a function of (seed, episode) alone, and the draws cover every kind
    /// and backend over a modest number of episodes.
    #[test]
    fn schedules_are_reproducible_and_cover_every_kind() {
        let base = e2();
        let mut kinds = std::collections::BTreeSet::new();
        let mut backends = std::collections::BTreeSet::new();
        for i in 0..400 {
            let a = schedule(&base, 7, i);
            let b = schedule(&base, 7, i);
            assert_eq!(a.faults, b.faults);
            assert_eq!(a.scenario.faults, b.scenario.faults);
            assert!(a.scenario.faults.validate().is_ok(), "{:?}", a.scenario.faults.validate());
            assert!((1..=MAX_FAULTS).contains(&a.faults.len()));
            for f in &a.faults {
                assert!(f.kind.applies(a.backend));
            }
            kinds.extend(a.faults.iter().map(|f| f.kind));
            backends.insert(a.backend);
        }
        assert_eq!(kinds.len(), Kind::ALL.len(), "kinds never drawn");
        assert_eq!(backends.len(), 3);
        assert_ne!(schedule(&base, 7, 1).faults, schedule(&base, 8, 1).faults);
    }

    fn settings() -> Settings {
        let rig = e2().rig_with("slcan:/dev/null", false);
        Settings { period: 0.02, safety: rig.safety, board_timeout: 0.2, backend: Backend::BoardSlcan }
    }

    fn with(faults: Vec<Injected>) -> FaultSchedule {
        FaultSchedule { backend: Backend::BoardSlcan, faults, scenario: e2() }
    }

    fn silence(from: f64, to: f64) -> Injected {
        Injected { kind: Kind::SerialSilence, from, to, led: None }
    }

    /// The judge finds what it is for: a stop named for no fault present, a watchdog late,
    /// wheels late to rest or turning in a fault, an arm nobody asked for, a goal missed.
    #[test]
    fn the_judge_finds_each_broken_invariant() {
        let s = settings();
        let started = vec![(0.0, State::Idle), (0.1, State::Armed), (0.12, State::Running)];
        let fault = |at: f64, reason| {
            let mut h = started.clone();
            h.push((at, State::Fault(reason)));
            h
        };
        let seen = |at: f64, reason, rest: Option<f64>| EpisodeLog {
            faults: vec![Seen { at, reason, rest }],
            ..EpisodeLog::default()
        };
        // Named and stopped in budget, then back to the goal: nothing to say.
        let good = with(vec![silence(2.0, 2.3)]);
        let h = fault(2.1, StopReason::SamplesStopped);
        let (v, stops) = judge(&good, &s, &h, &seen(2.1, StopReason::SamplesStopped, Some(2.1001)), true, State::Idle);
        assert!(v.is_empty(), "{v:?}");
        assert_eq!(stops[0].named_for, Some(Kind::SerialSilence));
        // Named for something no fault explains (the line quiet, named as the pose).
        let (v, _) = judge(
            &good,
            &s,
            &fault(2.1, StopReason::PoseLost),
            &seen(2.1, StopReason::PoseLost, Some(2.1)),
            true,
            State::Idle,
        );
        assert!(v[0].contains("no fault present names it"), "{v:?}");
        // The watchdog late: the pose watchdog (150 ms, the later of the two that may find
        // a silent line) and a cycle after the silence began is the latest.
        let (v, _) = judge(&good, &s, &h, &seen(2.2, StopReason::SamplesStopped, Some(2.2)), true, State::Idle);
        assert!(v[0].contains("200.0 ms after its cause, beyond the 150 ms watchdog"), "{v:?}");
        // The wheels at rest later than a cycle after the fault.
        let (v, _) = judge(&good, &s, &h, &seen(2.1, StopReason::SamplesStopped, Some(2.15)), true, State::Idle);
        assert!(v[0].contains("wheels at rest 50.0 ms after it"), "{v:?}");
        // Turning again in the fault.
        let mut w = seen(2.1, StopReason::SamplesStopped, Some(2.1));
        w.turned_in_fault = Some(2.5);
        let (v, _) = judge(&good, &s, &h, &w, true, State::Idle);
        assert!(v[0].contains("turned in a fault"), "{v:?}");
        // Armed again with no operator's arm.
        let mut h2 = h.clone();
        h2.extend([(2.7, State::Idle), (2.8, State::Armed)]);
        let (v, _) = judge(&good, &s, &h2, &seen(2.1, StopReason::SamplesStopped, Some(2.1)), true, State::Idle);
        assert!(v[0].contains("armed at 2.800 s without the operator's arm"), "{v:?}");
        // The goal not reached after the last fault.
        let (v, _) = judge(&good, &s, &h, &seen(2.1, StopReason::SamplesStopped, Some(2.1)), false, State::Idle);
        assert!(v[0].contains("goal was not reached"), "{v:?}");
    }

    /// The occlusion watchdog watches only a running robot: an obstacle hidden while the
    /// robot stood armed (its goal refused, say) is found as the robot starts, however long
    /// after the occlusion began; one hidden while it ran, within the watchdog and a cycle.
    #[test]
    fn a_watchdog_of_a_running_robot_fires_as_it_starts() {
        let s = settings();
        let hidden = with(vec![Injected { kind: Kind::ObstacleOccluded, from: 5.3, to: 7.6, led: Some(3) }]);
        let reason = StopReason::ObstacleOccluded { led: 3 };
        let seen = |at: f64| EpisodeLog { faults: vec![Seen { at, reason, rest: Some(at) }], ..EpisodeLog::default() };
        let armed = vec![(0.0, State::Idle), (4.36, State::Armed)];
        let ran_at = |t: f64| {
            let mut h = armed.clone();
            h.extend([(t, State::Running), (t, State::Fault(reason))]);
            h
        };
        let (v, _) = judge(&hidden, &s, &ran_at(7.45), &seen(7.45), true, State::Idle);
        assert!(v.is_empty(), "{v:?}");
        // Running since before the occlusion: late beyond the watchdog and a cycle.
        let mut h = vec![(0.0, State::Idle), (4.36, State::Armed), (4.4, State::Running)];
        h.push((7.45, State::Fault(reason)));
        let (v, _) = judge(&hidden, &s, &h, &seen(7.45), true, State::Idle);
        assert!(v[0].contains("beyond the 1000 ms watchdog"), "{v:?}");
    }
}
