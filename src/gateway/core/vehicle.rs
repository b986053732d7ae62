//! One vehicle as the core drives it: its safety state, its control step, its motors, its
//! goals, and what its own watchdogs count from. What the vehicles share (the PSD session and
//! its frames, the tracker's obstacles, the CAN link, the counters) stays with the core.

use flowgate_protocol::motor::EStopReason;
use flowgate_protocol::CanFrame;

use super::mission::Mission;
use super::motors::MotorMaster;
use super::operator::VehicleStatus;
use super::safety::{Action, Safety, State, StopReason};
use super::scene::SceneVehicle;
use super::script_run::ScriptRun;
use super::watch::{PoseWatch, RunWatch};
use super::STOP_GRACE;
use crate::config::{Rig, Vehicle};
use crate::control::{ControlConfig, ControlStep};
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

/// A vehicle's control among others (`fleet`): a vehicle closes on another within its
/// reach only as it slows, a stop's last sliver of speed; held by its supervisor beside a
/// vehicle that stands, its field pushing on, it would creep into it at the robot's
/// tolerance toward obstacles.
fn in_fleet(mut control: ControlConfig, fleet: bool) -> ControlConfig {
    if let Some(supervisor) = control.supervisor.as_mut().filter(|_| fleet) {
        supervisor.vehicle_approach_tolerance = 0.0;
    }
    control
}

#[derive(Debug)]
pub(super) struct DrivenVehicle {
    /// `robot`, or its `[[vehicles]]` name.
    pub(super) name: String,
    /// Its LEDs on the controller's driver bus: front, rear.
    pub(super) leds: [u8; 2],
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
    /// The state last announced ([`Output::State`](super::Output::State)).
    pub(super) announced: State,
    /// The velocity its last command asks of it, m/s: what the other vehicles plan on.
    pub(super) commanded: crate::Point,
    /// Until when its motors may run on after a stop that may not have reached them, s:
    /// the others keep clear of where it could still go.
    pub(super) unreached_until: Option<f64>,
    /// A scripted vehicle's run along its script.
    pub(super) script: Option<ScriptRun>,
}

impl DrivenVehicle {
    /// The robot: `[leds]`, `[can]`, `[drive]`, `[robot]` and `[planner]` of the rig.
    pub(super) fn robot(rig: &Rig) -> Self {
        let pose = PoseTrack::new(rig.tracking, rig.led_geometry);
        let leds = [rig.robot_front, rig.robot_rear];
        let control = in_fleet(rig.control.clone(), !rig.vehicles.is_empty());
        Self::new("robot", leds, pose, ControlStep::new(control), MotorMaster::new(rig))
    }

    /// A `[[vehicles]]` entry: driven as the robot would be with its body, wheels, LEDs and
    /// motors, keeping clear of every other vehicle as the fleet's rule has it
    /// ([`crate::control::fleet`]).
    pub(super) fn vehicle(v: &Vehicle) -> Self {
        let d = &v.driven;
        let pose = PoseTrack::new(d.tracking, v.led_geometry);
        let motors = MotorMaster::of(d.motors, d.node, d.board);
        let control = ControlStep::new(in_fleet(d.control.clone(), true));
        let script = v.script.as_ref().map(ScriptRun::new);
        Self { script, ..Self::new(&v.name, [v.front_led, v.rear_led], pose, control, motors) }
    }

    fn new(name: &str, leds: [u8; 2], pose: PoseTrack, control: ControlStep, motors: MotorMaster) -> Self {
        Self {
            name: name.to_string(),
            leds,
            pose,
            safety: Safety::default(),
            control,
            motors,
            mission: Mission::new(),
            run: RunWatch::default(),
            pose_watch: PoseWatch::default(),
            last_estimate: None,
            announced: State::Idle,
            commanded: crate::Point::default(),
            unreached_until: None,
            script: None,
        }
    }

    pub(super) fn state(&self) -> State {
        self.safety.state()
    }

    /// It in a cycle's scene: its last estimate, its state, where it is bound.
    pub(super) fn scene(&self) -> SceneVehicle {
        let config = self.control.config();
        let goal = [config.goal.re as f32, config.goal.im as f32];
        let script_error = self.script.as_ref().map(|s| s.status().error as f32);
        let mut scene = SceneVehicle { state: self.state(), goal, script_error, ..SceneVehicle::default() };
        if let Some(LastEstimate { pose, wheels: [left, right], .. }) = self.last_estimate {
            scene.seen = true;
            scene.pose = [pose.position.re as f32, pose.position.im as f32, pose.heading as f32];
            scene.twist = [(0.5 * (left + right)) as f32, ((right - left) / config.drive.wheel_base) as f32];
        }
        scene
    }

    /// Running may begin: a start was asked for, and it has a goal or a script.
    pub(super) fn ready_to_start(&self) -> bool {
        self.mission.start_requested() && (self.mission.has_goals() || self.script.is_some())
    }

    /// It will leave where it stands: under control with a goal to go to or a script.
    pub(super) fn moving_on(&self) -> bool {
        matches!(self.state(), State::Running | State::Armed) && (self.mission.has_goals() || self.script.is_some())
    }

    /// Carry out on its motors what a transition of its safety state asks. Whether they were
    /// e-stopped (they stop at once: the pose it had is forgotten, its wheels at rest).
    pub(super) fn act(&mut self, now: HostTime, action: Action, send: &mut impl FnMut(CanFrame)) -> bool {
        match action {
            Action::None => {}
            Action::EnableBoard => {
                self.unreached_until = None;
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
                if self.state().reason().is_some_and(StopReason::motors_unreachable) {
                    self.unreached_until = Some((now + self.motors.hold_when_unreached()).secs());
                }
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

    /// Why it last stopped or faulted, in words.
    pub(super) fn last_stop(&self) -> Option<String> {
        self.safety.history.iter().rev().find_map(|(_, s)| s.reason()).map(|r| r.to_string())
    }

    /// What the control socket reports of it.
    pub(super) fn status(&self) -> VehicleStatus {
        VehicleStatus {
            name: self.name.clone(),
            state: self.state().into(),
            last_stop: self.last_stop(),
            goals: self.mission.goals().collect(),
            pose: self.last_estimate.map(|e| [e.pose.position.re, e.pose.position.im, e.pose.heading]),
            script: self.script.as_ref().map(ScriptRun::status),
        }
    }
}
