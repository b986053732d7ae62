//! The motors as the core drives them: one PCL-80K-like board for both wheels
//! ([`board`]), or one CiA 402 drive a wheel ([`cia402`]), behind one type, so the core asks
//! the same things of either and never branches on which it has.

pub mod board;
pub mod cia402;

use flowgate_protocol::motor::EStopReason;
use flowgate_protocol::CanFrame;

use super::safety::{State, StopReason};
use crate::config::{BoardSettings, Motors, Rig};
use crate::time::HostTime;
use board::BoardMaster;
use cia402::{Cia402Master, Heard};

/// What the motors' side of the core counts: frames from the bus it could not take, and
/// the board's own sequence errors and the enables sent again. Written here only; the
/// core's counters take them in ([`Counters::with_motors`](super::Counters::with_motors)).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MotorCounters {
    /// Frames from node ids that are not configured.
    pub foreign: u64,
    /// Frames that do not decode as motor messages.
    pub undecodable: u64,
    pub board_seq_errors: u64,
    pub board_enable_retries: u64,
}

/// The gateway's side of the motors the rig has (`can.protocol`).
#[derive(Debug)]
pub enum MotorMaster {
    Board(BoardMaster),
    Cia402(Cia402Master),
}

/// What a frame from the motors asks of the core.
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct FrameEffect {
    /// Stop for this reason.
    pub stop: Option<StopReason>,
    /// Another master was heard commanding our motors.
    pub second_master: bool,
    /// Send the enable again (an armed board still reports Disabled).
    pub enable_again: bool,
    /// The motors reported their rates: check whether an orderly stop has come to rest.
    pub settle: bool,
}

impl MotorMaster {
    /// The robot's motors, as `[can]`, `[drive]` and `[cia402]` give them.
    pub fn new(rig: &Rig) -> Self {
        Self::of(rig.motors, rig.node, rig.board)
    }

    /// A board at `node` set up with `board`, or CiA 402 drives as `motors` says.
    pub fn of(motors: Motors, node: flowgate_protocol::motor::NodeId, board: BoardSettings) -> Self {
        match motors {
            Motors::Pcl80k => Self::Board(BoardMaster::new(node, board)),
            Motors::Cia402(settings) => Self::Cia402(Cia402Master::new(settings)),
        }
    }

    /// Whether `frame` comes from, or is addressed to, these motors (a board's node, or
    /// one of the drives'): on a bus shared by several vehicles, the one it is for.
    pub fn addresses(&self, frame: &CanFrame) -> bool {
        match self {
            Self::Board(b) => b.addresses(frame),
            Self::Cia402(m) => m.addresses(frame),
        }
    }

    /// The motors follow commands: the board Enabled, or both drives in operation enabled.
    pub fn ready(&self) -> bool {
        match self {
            Self::Board(b) => b.ready(),
            Self::Cia402(m) => m.ready(),
        }
    }

    pub fn at_rest(&self) -> bool {
        match self {
            Self::Board(b) => b.at_rest(),
            Self::Cia402(m) => m.at_rest(),
        }
    }

    /// The motors stop by themselves when commands stop coming (the board's command
    /// timeout, which the enable starts): enabled and idle, they need zero commands
    /// ([`Self::keep_alive_due`]). CiA 402 drives watch the gateway's heartbeat instead.
    pub fn time_out_without_commands(&self) -> bool {
        matches!(self, Self::Board(_))
    }

    /// The motors report a heartbeat in every state: one unheard is gone, or off the bus. A
    /// CiA 402 drive stays silent until configured, so silence alone says nothing of it.
    pub fn always_heard(&self) -> bool {
        matches!(self, Self::Board(_))
    }

    /// When motors enabled and idle need their zero command (`None`: they do not), from
    /// the last command sent.
    pub fn keep_alive_due(&self, last_command: Option<HostTime>) -> Option<HostTime> {
        match self {
            Self::Board(b) => b.keep_alive_due(last_command),
            Self::Cia402(_) => None,
        }
    }

    /// The zero command that keeps enabled, idle motors from timing out.
    pub fn keep_alive(&mut self, send: &mut impl FnMut(CanFrame)) {
        if let Self::Board(b) = self {
            b.keep_alive(send);
        }
    }

    /// How long the motors run on their last command once nothing reaches them: the
    /// board's command timeout, or the drives' heartbeat consumer time.
    pub fn hold_when_unreached(&self) -> std::time::Duration {
        let ms = match self {
            Self::Board(b) => u32::from(b.command_timeout_ms()),
            Self::Cia402(_) => crate::config::CIA402_CONSUMER_TIME_MS,
        };
        std::time::Duration::from_millis(u64::from(ms))
    }

    /// The operator armed: the board's retries and heartbeat are counted afresh.
    pub fn armed(&mut self) {
        if let Self::Board(b) = self {
            b.armed();
        }
    }

    /// Take the motors to where they follow commands (the board: reset, configure, enable;
    /// the drives: configure afresh and step to operation enabled).
    pub fn enable(&mut self, now: HostTime, send: &mut impl FnMut(CanFrame)) {
        match self {
            Self::Board(b) => b.enable(now, send),
            Self::Cia402(m) => m.arm(now, send),
        }
    }

    pub fn emergency_stop(&mut self, reason: EStopReason, send: &mut impl FnMut(CanFrame)) {
        match self {
            Self::Board(b) => b.emergency_stop(reason, send),
            Self::Cia402(m) => m.quick_stop(send),
        }
    }

    /// At rest after an orderly stop (`ending`: the gateway is shutting down).
    pub fn disable(&mut self, ending: bool, send: &mut impl FnMut(CanFrame)) {
        match self {
            Self::Board(b) => b.disable(send),
            Self::Cia402(m) => m.disable(ending, send),
        }
    }

    /// The operator reset a fault. CiA 402 drives are reset on the way to operation enabled
    /// at the next arm; the board has its latched faults cleared now.
    pub fn fault_reset(&mut self, send: &mut impl FnMut(CanFrame)) {
        if let Self::Board(b) = self {
            b.fault_reset(send);
        }
    }

    /// The gateway's heartbeat to these motors, in `state`. `beat`: this master sends the
    /// heartbeat frame itself (on a bus with several vehicles, one master of each kind does,
    /// and none of the drives' while one of them withholds it); the drives' quick stops are
    /// repeated whatever `beat` is.
    pub fn heartbeat(&mut self, state: State, beat: bool, send: &mut impl FnMut(CanFrame)) {
        match self {
            Self::Board(b) if beat => b.heartbeat(state, send),
            Self::Board(_) => {}
            Self::Cia402(m) => m.heartbeat(beat, send),
        }
    }

    /// The gateway's heartbeat is withheld from the drives ([`Cia402Master::heartbeat`]).
    pub fn withholds_heartbeat(&self) -> bool {
        matches!(self, Self::Cia402(m) if m.withholds_heartbeat())
    }

    /// One cycle's command. The CiA 402 drives get one RPDO each: the left one goes out
    /// through `send`, the right one closes the cycle. `None`: the frame could not be built
    /// (a planner fault).
    pub fn command(&mut self, pulses: [i32; 2], send: &mut impl FnMut(CanFrame)) -> Option<CanFrame> {
        match self {
            Self::Board(b) => b.command(pulses),
            Self::Cia402(m) => match m.command(pulses) {
                [Some(left), right @ Some(_)] => {
                    send(left);
                    right
                }
                _ => None,
            },
        }
    }

    /// Whether the cycle's command may go out now: the drives take only the state machine's
    /// controlwords until both are in operation enabled (a cycle's enable-operation RPDO
    /// would jump a step, or undo one). The board takes commands whenever it is enabled.
    pub fn takes_commands(&self) -> bool {
        match self {
            Self::Board(_) => true,
            Self::Cia402(m) => m.ready(),
        }
    }

    /// When [`MotorMaster::tick`] next has something to do.
    pub fn deadline(&self) -> HostTime {
        match self {
            Self::Board(_) => HostTime::NEVER,
            Self::Cia402(m) => m.deadline(),
        }
    }

    pub fn tick(&mut self, now: HostTime) -> Option<StopReason> {
        match self {
            Self::Board(_) => None,
            Self::Cia402(m) => m.tick(now),
        }
    }

    /// When the motors' heartbeat watchdog fires, and what it is named: the board's, or the
    /// drive heard longest ago (each counted from the arm at the earliest).
    pub fn heartbeat_deadline(&self, armed_at: HostTime, timeout: std::time::Duration) -> (HostTime, StopReason) {
        let from = |heard: Option<HostTime>| heard.map_or(armed_at, |h| h.max(armed_at));
        match self {
            Self::Board(b) => (from(b.last_heartbeat()) + timeout, StopReason::HeartbeatLost { node: b.node().get() }),
            Self::Cia402(m) => {
                let [l, r] = m.heard().map(from);
                let [ln, rn] = m.nodes().map(|n| n.get());
                let (heard, node) = if r < l { (r, rn) } else { (l, ln) };
                (heard + timeout, StopReason::DriveHeartbeatLost { node })
            }
        }
    }

    /// A CiA 402 drive that last reported its wheel turning (its node). The board stops by
    /// itself on its command timeout; a drive does not.
    pub fn moving(&self, now: HostTime) -> Option<u8> {
        match self {
            Self::Board(_) => None,
            Self::Cia402(m) => m.moving(now),
        }
    }

    /// Every motor was heard within `timeout` of `now` (a CiA 402 drive that announced its
    /// boot since counts: it is silent until configured).
    pub fn heard_within(&self, now: HostTime, timeout: std::time::Duration) -> bool {
        match self {
            Self::Board(b) => b.last_heartbeat().is_some_and(|h| now < h + timeout),
            Self::Cia402(m) => m.alive_within(now, timeout),
        }
    }

    /// Whether these are the board at `node`.
    pub fn is_board(&self, node: u8) -> bool {
        matches!(self, Self::Board(b) if b.node().get() == node)
    }

    /// Whether the board still latches the fault bit behind `reason` (the drives report no
    /// bus or e-stop bits).
    pub fn latched(&self, reason: StopReason) -> bool {
        match self {
            Self::Board(b) => b.latched(reason),
            Self::Cia402(_) => false,
        }
    }

    /// A frame from the bus at `now`, in gateway state `state`.
    pub fn frame(
        &mut self,
        now: HostTime,
        frame: &CanFrame,
        state: State,
        counters: &mut MotorCounters,
        send: &mut impl FnMut(CanFrame),
    ) -> FrameEffect {
        match self {
            Self::Board(b) => b.frame(now, frame, state, counters),
            Self::Cia402(m) => {
                let (heard, stop) = m.frame(now, frame, state.is_active(), send);
                match heard {
                    Heard::Ours => {}
                    Heard::Foreign => counters.foreign += 1,
                    Heard::Undecodable => counters.undecodable += 1,
                }
                let second_master = matches!(stop, Some(StopReason::DriveSecondMaster { .. }));
                FrameEffect { stop, second_master, enable_again: false, settle: true }
            }
        }
    }

    /// A frame like a cycle's, built and dropped (the low-latency mode's rehearsal).
    pub fn rehearse(&self) {
        match self {
            Self::Board(b) => b.rehearse(),
            Self::Cia402(m) => m.rehearse(),
        }
    }
}
