//! What the core counts (everything unusual it saw) and shows while it runs.

use serde::Serialize;

use super::motors::MotorCounters;
use super::safety::State;

/// What the gateway shows while it runs (for a live display). Receivers are woken when the
/// state or the reconnect count changes; the per-cycle figures are updated silently, for a
/// display that samples them with `borrow()` at its own pace.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Progress {
    pub t: f64,
    pub state: State,
    pub cycles: u64,
    pub goal_distance: f64,
    /// Smallest estimated gap to an obstacle's footprint, m.
    pub clearance: Option<f64>,
    pub e2e_us: f64,
    pub serial_reconnects: u64,
    /// The rig's other vehicles armed, running or stopping (0 for a robot alone).
    pub others_active: u32,
}

/// Counters of everything unusual the gateway saw.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Counters {
    pub cycles: u64,
    pub samples: u64,
    /// Samples and frame ends that came before time sync (discarded).
    pub samples_unsynced: u64,
    /// Samples stamped in the future by more than a period (discarded).
    pub samples_from_future: u64,
    /// Overruns the controller reported (samples lost inside it), and its other faults.
    pub controller_overruns: u64,
    pub controller_faults: u64,
    /// Periodic time syncs taken, and discarded for a round trip over 10 ms.
    pub time_syncs: u64,
    pub time_syncs_rejected: u64,
    /// Controller packets lost (gaps in their sequence numbers).
    pub psd_packets_lost: u64,
    /// Controller packets seen twice (discarded).
    pub psd_duplicates: u64,
    /// Controller packets behind the sequence: replays, reordering (discarded).
    pub psd_out_of_order: u64,
    /// Frames that never ended (gaps in the frame counter, or samples of another frame).
    pub frames_lost: u64,
    /// Frame ends for a frame already done (discarded: no second command).
    pub frames_repeated: u64,
    /// Frames whose sample count disagrees with their end (run on what came).
    pub frames_incomplete: u64,
    /// Samples from an LED or slot that is not in the schedule (discarded).
    pub samples_unscheduled: u64,
    /// Robot poses discarded: LEDs off their mounted spacing, or further than the robot can go.
    pub poses_implausible: u64,
    pub bad_serial_frames: u64,
    /// Every byte from the PSD line thrown away: bad frames with their delimiters, runs with
    /// no delimiter, bytes left undecoded when the line closed.
    pub serial_dropped_bytes: u64,
    pub serial_reconnects: u64,
    pub can_frames_in: u64,
    /// Times the CAN link was lost and opened again.
    pub can_reconnects: u64,
    /// Frames from node ids that are not configured (ignored).
    pub can_foreign: u64,
    /// Frames that do not decode as motor messages, and garbled adapter lines (ignored).
    pub can_undecodable: u64,
    /// Error frames (SocketCAN) and bus-off reports (an SLCAN adapter's status flags).
    pub can_error_frames: u64,
    /// Transmits the SLCAN adapter refused (BEL), and its error-passive reports.
    pub can_tx_refused: u64,
    pub can_error_passive: u64,
    /// Sequence errors the motor board counted in our velocity commands (lost or foreign).
    pub board_seq_errors: u64,
    /// Enables sent again because an armed board still reported Disabled (one was lost).
    pub board_enable_retries: u64,
    pub planner_invalid: u64,
    /// Cycles whose command the safety supervisor slowed (a hazard within the robot's
    /// stopping path).
    pub supervisor_slowed: u64,
    /// Cycles in which the supervisor braked because no slower command could keep its
    /// promise (the estimate moved faster than a reaction time allows for).
    pub supervisor_braking: u64,
    /// Cycles in which slowing or braking would have left the robot in an obstacle's way,
    /// and it evaded instead (the supervisor's [`crate::control::supervisor::evade`]).
    pub supervisor_evaded: u64,
    /// Cycles in which some obstacle outran what the robot can deliver (judged with
    /// hysteresis on its tracked speed): avoidance is not guaranteed then.
    pub obstacle_outran_robot: u64,
    /// Cycles the robot held still because the goal was inside an obstacle's planning
    /// circle (it waits up to `planner.goal_wait` for the obstacle to pass).
    pub goal_occupied: u64,
    /// Obstacle tracks dropped because the obstacle was seen leaving the calibrated arena
    /// (its filter's prediction beyond the view's edge once unseen).
    pub obstacles_left_view: u64,
    /// PSD packets whose sequence number lay beyond the window (discarded: a suspicious
    /// jump), and runs of them that confirmed the controller's numbering moved (followed).
    pub psd_seq_jumps: u64,
    pub psd_seq_rebased: u64,
    /// Frames whose counter lay beyond the window (discarded), and runs that confirmed the
    /// counter moved (followed).
    pub frames_jumped: u64,
    pub frames_rebased: u64,
    /// Time syncs refused because the controller's clock moved further than drift allows.
    pub time_syncs_implausible: u64,
    /// Obstacles that came into view and got a track (each first sighting, and each return
    /// after leaving).
    pub obstacles_entered_view: u64,
    /// Cycles planned with some obstacle unseen inside the view, avoided as the region it
    /// may have reached.
    pub obstacle_occluded_cycles: u64,
    /// Cycles whose plan raised each of the planner's flags ([`crate::planner::PlanFlags`]):
    /// the field's speed scaled down to the limit; the tie-break shifting a circle; a
    /// margin shrunk because the robot or the goal stood in it; a circle at a lane wall
    /// left unclosed, its boundary met less exactly.
    pub planner_saturated: u64,
    pub planner_tie_break: u64,
    pub planner_margin_shrunk: u64,
    pub planner_unclosed_at_a_wall: u64,
    pub telemetry_dropped: u64,
    /// Commands taken from a planner outside flowgate, and the cycles that drove on one
    /// beyond the robot's limits (scaled down to them).
    pub outside_commands: u64,
    pub outside_commands_saturated: u64,
    /// Operator requests dropped unanswered: their client had been told they failed
    /// (`stop` and `estop` are never dropped).
    pub requests_expired: u64,
    /// Control-socket connections closed to make room for a new one (the one idle
    /// longest), closed for silence or a stalled line, and refused (every held one waiting
    /// on the gateway).
    pub control_clients_evicted: u64,
    pub control_clients_timed_out: u64,
    pub control_clients_refused: u64,
}

impl Counters {
    /// These counters with the motors' (the core's own `can_undecodable` counts the SLCAN
    /// adapter's garbled lines; the motors', the frames they could not decode).
    pub fn with_motors(mut self, motors: MotorCounters) -> Self {
        self.can_foreign += motors.foreign;
        self.can_undecodable += motors.undecodable;
        self.board_seq_errors += motors.board_seq_errors;
        self.board_enable_retries += motors.board_enable_retries;
        self
    }

    /// Controller packets discarded for their sequence numbers: seen twice, behind the
    /// sequence, or beyond its window.
    pub fn psd_sequence_discards(&self) -> u64 {
        self.psd_duplicates + self.psd_out_of_order + self.psd_seq_jumps
    }
}
