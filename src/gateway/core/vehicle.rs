//! One vehicle as the core drives it: its safety state, its control step, its motors, its
//! goals, and what its own watchdogs count from. What the vehicles share (the PSD session and
//! its frames, the tracker's obstacles, the CAN link, the counters) stays with the core.

use flowgate_protocol::motor::EStopReason;
use flowgate_protocol::CanFrame;

use super::mission::Mission;
use super::motors::MotorMaster;
use super::safety::{Action, Safety, State, StopReason};
use super::watch::{PoseWatch, RunWatch};
use super::STOP_GRACE;
use crate::config::Rig;
use crate::control::ControlStep;
use crate::time::HostTime;
use crate::track::{Pose, PoseTrack};

/// What the last cycle estimated of a vehicle.
#[derive(Debug, Clone, Copy)]
pub(super) struct LastEstimate {
    pub(super) pose: Pose,
    pub(super) delay: f64,
    /// The wheels' rim speeds, m/s: left, right.
    pub(super) wheels: [f64; 2],
}

#[derive(Debug)]
pub(super) struct DrivenVehicle {
    /// Its pose from its two LEDs.
    pub(super) pose: PoseTrack,
    pub(super) safety: Safety,
    pub(super) control: ControlStep,
    pub(super) motors: MotorMaster,
    pub(super) mission: Mission,
    /// When it was armed, last commanded, began to stop.
    pub(super) run: RunWatch,
    /// What became of its LEDs' samples: the pose watchdog names its stop from it.
    pub(super) pose_watch: PoseWatch,
    /// The last cycle's pose estimate and sensing delay (for the scene and the goal checks).
    pub(super) last_estimate: Option<LastEstimate>,
}

impl DrivenVehicle {
    /// The robot: `[leds]`, `[can]`, `[drive]`, `[robot]` and `[planner]` of the rig.
    pub(super) fn robot(rig: &Rig) -> Self {
        Self {
            pose: PoseTrack::new(rig.tracking, rig.led_geometry),
            safety: Safety::default(),
            control: ControlStep::new(rig.control.clone()),
            motors: MotorMaster::new(rig),
            mission: Mission::new(),
            run: RunWatch::default(),
            pose_watch: PoseWatch::default(),
            last_estimate: None,
        }
    }

    pub(super) fn state(&self) -> State {
        self.safety.state()
    }

    /// Carry out on its motors what a transition of its safety state asks. Whether they were
    /// e-stopped (they stop at once: the pose it had is forgotten, its wheels at rest).
    pub(super) fn act(&mut self, now: HostTime, action: Action, send: &mut impl FnMut(CanFrame)) -> bool {
        match action {
            Action::None => {}
            Action::EnableBoard => {
                self.motors.enable(now, send);
                if self.motors.time_out_without_commands() {
                    self.run.commanded(now);
                }
            }
            Action::OrderlyStop => self.run.stopping(Some(now)),
            Action::EmergencyStop => {
                let reason = if self.state() == State::Fault(StopReason::OperatorEStop) {
                    EStopReason::Operator
                } else {
                    EStopReason::GatewayFault
                };
                self.motors.emergency_stop(reason, send);
                self.run.stopping(None);
                self.pose.forget();
                self.pose.halted(now.secs()); // the boards stop at once: dead reckoning starts from rest
                return true;
            }
        }
        false
    }

    /// An orderly stop ends once its motors are at rest, or its grace has passed; then they
    /// are disabled (`shutdown`: for good). Whether it ended.
    pub(super) fn settle(&mut self, now: HostTime, shutdown: bool, send: &mut impl FnMut(CanFrame)) -> bool {
        let (State::Stopping(_), Some(since)) = (self.state(), self.run.stopping_since()) else { return false };
        if !(self.motors.at_rest() || now >= since + STOP_GRACE) {
            return false;
        }
        self.safety.at_rest(now.secs());
        self.run.stopping(None);
        self.motors.disable(shutdown, send);
        true
    }

    /// When its enabled but idle board (Armed, Stopping) needs a zero command to keep its
    /// command timeout from firing.
    pub(super) fn keep_alive_due(&self) -> Option<HostTime> {
        let idle_enabled = matches!(self.state(), State::Armed | State::Stopping(_));
        if !idle_enabled {
            return None;
        }
        self.motors.keep_alive_due(self.run.last_command())
    }
}
