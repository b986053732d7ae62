//! The faults an episode draws: their kinds, when they start and end, and what each does to
//! the rig.

use crate::gateway::core::StopReason;
use crate::lab::virtual_rig::{CanTransport, Options};
use crate::lab::Scenario;
use flowgate_sim::faults::FaultPlan;
use flowgate_sim::scenario::{Motion, ObstacleSpec};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

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

    pub(super) fn options(self) -> Options {
        Options {
            can: if self == Self::BoardSocketCan { CanTransport::SocketCan } else { CanTransport::Slcan },
            cia402: self == Self::DrivesSlcan,
            ..Options::default()
        }
    }

    pub(super) fn board(self) -> bool {
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

    pub(super) fn applies(self, backend: Backend) -> bool {
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
    pub(super) fn explains(self, led: Option<u8>, reason: StopReason) -> bool {
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
            (Kind::ObstacleOccluded, R::ObstacleOccluded { led: l, .. }) => Some(l) == led,
            // Gone out of the view at its edge slowly, at a grazing angle: to the camera, hidden there.
            (Kind::PasserBy, R::ObstacleOccluded { led: l, at_edge: true }) => Some(l) == led,
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
    pub(super) fn grace(self) -> f64 {
        match self {
            Kind::SyncHeld => 5.5,
            Kind::ObstacleOccluded => 1.2,
            // Found at the next periodic time sync and confirmed by a second.
            Kind::ClockStep => 1.5,
            // Latched by the board until a reset: reported when the gateway next looks.
            Kind::BoardBusOff | Kind::BoardEStop => 1.5,
            // Its discards stay in the sequence budget's one-second window.
            Kind::SerialRepeats => 1.0,
            // It walks on after it comes, and leaves the view whenever its way takes it out.
            Kind::PasserBy => f64::INFINITY,
            _ => 0.5,
        }
    }

    /// Whether its cause silences what a watchdog watches from its start (a partial cause
    /// lets some through, and its watchdog counts from the last that came).
    pub(super) fn total(self) -> bool {
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
    pub(super) fn cuts_commands(self) -> bool {
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
pub(super) const START_WINDOW: (f64, f64) = (0.5, 7.0);
/// The most faults of one episode.
pub(super) const MAX_FAULTS: usize = 4;

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
                scenario.sim.obstacles.push(ObstacleSpec::scripted(
                    0.07,
                    [rng.random_range(-0.3..0.5), 0.95 * side],
                    Motion::Constant { velocity: [drift, -speed * side] },
                ));
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
pub(super) fn line_fault(kind: Kind, a: f64, rng: &mut ChaCha8Rng, plan: &mut FaultPlan) -> Option<(f64, Option<u8>)> {
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
pub(super) fn controller_fault(
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
pub(super) fn motor_fault(kind: Kind, a: f64, rng: &mut ChaCha8Rng, plan: &mut FaultPlan) -> Option<(f64, Option<u8>)> {
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
pub(super) fn span(rng: &mut ChaCha8Rng, a: f64, lo: f64, hi: f64) -> f64 {
    a + rng.random_range(lo..hi)
}
