//! The operator's requests: arm, start, stop, e-stop, reset, goals, and the queries. A
//! refusal says exactly why and changes nothing.

use super::operator::{Goal, ObstacleStatus, Refusal, Request, Status, MAX_GOALS};
use super::scene::{FleetScene, ObstacleView, SceneRecord};
use super::vehicle::{DrivenVehicle, LastEstimate};
use super::ROBOT;
use super::{Answer, Core, StageClock, State, StopReason};
use crate::config::MAX_GOAL_TOLERANCE;
use crate::planner::Space;
use crate::time::HostTime;
use crate::Point;

impl<K: StageClock> Core<K> {
    /// An operator's request, for `vehicle` (`None`: as [`Core::request`] says), and its
    /// answer: the status comes with a query or an accepted request.
    pub(super) fn answer(&mut self, now: HostTime, vehicle: Option<usize>, request: &Request) -> Answer {
        let result = self.request(now, vehicle, request);
        let status = (request.is_query() || (result.is_ok() && !request.is_command())).then(|| self.status(now));
        Answer { result, status }
    }

    /// An operator's request at `now` for `vehicle`. Without one, `estop`, `stop` and
    /// `cancel` are every vehicle's, the rest the robot's. Refusals say exactly why and
    /// change nothing.
    pub(super) fn request(&mut self, now: HostTime, vehicle: Option<usize>, request: &Request) -> Result<(), Refusal> {
        let count = self.vehicles.len();
        let k = vehicle.unwrap_or(ROBOT);
        if k >= count {
            return Err(Refusal::NoVehicle { index: k, count });
        }
        let every = |k| if vehicle.is_some() { k..k + 1 } else { 0..count };
        match request {
            Request::Status | Request::Stats { .. } => Ok(()),
            Request::Arm => self.arm(k, now),
            Request::Start => self.start(k),
            Request::Stop => every(k).try_for_each(|k| self.stop_request(k, now, false)),
            Request::Cancel => every(k).try_for_each(|k| self.stop_request(k, now, true)),
            Request::EStop => every(k).try_for_each(|k| self.estop(k, now)),
            Request::Reset => self.reset(k, now),
            Request::Goal { .. } | Request::Drive { .. } | Request::Wheels { .. }
                if self.vehicles[k].script.is_some() =>
            {
                Err(Refusal::Scripted { name: self.vehicles[k].name.clone() })
            }
            Request::Goal { goals } => self.set_goals(k, now, goals),
            Request::Drive { .. } | Request::Wheels { .. } => self.outside_command(k, now, request),
        }
    }

    /// A command from a planner outside flowgate: held for the cycles to drive on; one not
    /// finite stops a moving robot, named.
    fn outside_command(&mut self, k: usize, now: HostTime, request: &Request) -> Result<(), Refusal> {
        let Some(command) = request.command() else { return Ok(()) };
        match self.vehicles[k].control.config().source {
            crate::control::CommandSource::Field => return Err(Refusal::FieldDrives),
            crate::control::CommandSource::Straight => return Err(Refusal::BaselineDrives("straight")),
            crate::control::CommandSource::Orca => return Err(Refusal::BaselineDrives("orca")),
            crate::control::CommandSource::SocialForce => return Err(Refusal::BaselineDrives("social_force")),
            crate::control::CommandSource::Outside { .. } => {}
        }
        if !command.is_finite() {
            if self.vehicles[k].state().is_active() {
                self.stop_vehicle(k, now, StopReason::CommandNotFinite);
            }
            return Err(Refusal::CommandNotFinite);
        }
        self.counters.outside_commands += 1;
        self.vehicles[k].control.take_command(now.secs(), command);
        Ok(())
    }

    fn arm(&mut self, k: usize, now: HostTime) -> Result<(), Refusal> {
        let state = self.vehicles[k].state();
        match state {
            State::Idle | State::Stopped(_) => {}
            State::Fault(_) => return Err(Refusal::Faulted(state)),
            _ => return Err(Refusal::Already(state)),
        }
        let unseen =
            self.rig.obstacles.iter().enumerate().find(|&(k, o)| o.required && self.obstacles.time(k).is_none());
        if let Some((index, o)) = unseen {
            return Err(Refusal::RequiredObstacleUnseen { led: o.led, index });
        }
        if !self.any_active() {
            self.samples_watched_from(now);
        }
        let v = &mut self.vehicles[k];
        let action = v.safety.arm(now.secs());
        v.run.armed(now);
        v.motors.armed();
        v.mission.set_start_requested(false);
        self.act(k, now, action);
        Ok(())
    }

    fn start(&mut self, k: usize) -> Result<(), Refusal> {
        let v = &mut self.vehicles[k];
        let state = v.state();
        if let (Some(script), Some(e), State::Armed) = (&v.script, v.last_estimate, state) {
            let distance = script.distance_from_start(e.pose.position);
            if distance > script.tolerance() {
                let [x, y] = script.start_point();
                let (name, tolerance) = (v.name.clone(), script.tolerance());
                return Err(Refusal::AwayFromScript { name, distance, x, y, tolerance });
            }
        }
        match state {
            State::Armed if !v.mission.has_goals() && v.script.is_none() => Err(Refusal::NoGoal),
            State::Armed => {
                v.mission.set_start_requested(true);
                Ok(())
            }
            State::Running => Err(Refusal::Already(state)),
            State::Fault(_) => Err(Refusal::Faulted(state)),
            _ => Err(Refusal::NotArmed(state)),
        }
    }

    /// Stop vehicle `k` in order (`cancel`: and forget its goals).
    fn stop_request(&mut self, k: usize, now: HostTime, cancel: bool) -> Result<(), Refusal> {
        let v = &mut self.vehicles[k];
        if cancel {
            v.mission.clear_goals();
        }
        v.mission.set_start_requested(false);
        if matches!(v.state(), State::Running | State::Armed) {
            self.stop_vehicle(k, now, StopReason::Operator);
        }
        Ok(())
    }

    /// Accepted whatever vehicle `k`'s state. In a fault its motors were e-stopped already;
    /// they hear the operator's e-stop again all the same.
    fn estop(&mut self, k: usize, now: HostTime) -> Result<(), Refusal> {
        let v = &mut self.vehicles[k];
        v.mission.set_start_requested(false);
        if matches!(v.state(), State::Fault(_)) {
            v.motors.emergency_stop(flowgate_protocol::motor::EStopReason::Operator, &mut self.out.can());
        } else {
            self.stop_vehicle(k, now, StopReason::OperatorEStop);
        }
        Ok(())
    }

    /// Leave vehicle `k`'s fault whose cause is gone.
    fn reset(&mut self, k: usize, now: HostTime) -> Result<(), Refusal> {
        let state = self.vehicles[k].state();
        let State::Fault(reason) = state else { return Err(Refusal::NotFaulted(state)) };
        if self.cause_present(k, now, reason) {
            return Err(Refusal::CauseStillPresent(reason));
        }
        // Armed again, the drives go pre-operational to be configured, and no longer hear
        // a quick stop: a wheel still turning (its stop lost on the bus) must stand first.
        if let Some(node) = self.vehicles[k].motors.moving(now) {
            return Err(Refusal::StillMoving { node });
        }
        self.vehicles[k].motors.fault_reset(&mut self.out.can());
        // The PSD session starts afresh: sequence numbers, frame counter and clock taken
        // anew, so no baseline a fault left behind outlives the reset (unless another vehicle
        // is under way on the stream).
        if !self.psd.is_down() && !self.any_active() {
            self.psd.connect(now, &mut self.out.psd());
            self.frame.forget_counter();
            for v in &mut self.vehicles {
                v.pose_watch.forget_future();
            }
            self.forget_frame_pace();
            self.stamps.forget_step();
            self.psd_link.reconfigure();
        }
        self.vehicles[k].safety.reset(now.secs());
        self.state_changed(k, now);
        Ok(())
    }

    /// Arm, set `goal` (a scripted vehicle: none) and start `vehicle` (the robot without
    /// one; `--arm`).
    pub(super) fn arm_and_start(
        &mut self,
        now: HostTime,
        vehicle: Option<usize>,
        goal: Option<Goal>,
    ) -> Result<(), Refusal> {
        self.request(now, vehicle, &Request::Arm)?;
        if let Some(goal) = goal {
            self.request(now, vehicle, &Request::Goal { goals: vec![goal] })?;
        }
        self.request(now, vehicle, &Request::Start)
    }

    /// Whether vehicle `k`'s fault's cause persists now.
    fn cause_present(&self, k: usize, now: HostTime, reason: StopReason) -> bool {
        let s = &self.rig.safety;
        let v = &self.vehicles[k];
        let heard = v.motors.heard_within(now, s.heartbeat_timeout);
        let sampling = !self.psd.is_down() && now < self.samples.last() + s.sample_timeout;
        match reason {
            StopReason::SerialLost => self.psd.is_down(),
            StopReason::ClockUnsynced => self.psd.clock_waiting(now),
            StopReason::SamplesStopped | StopReason::SerialGarbled { .. } => !sampling,
            StopReason::PoseLost => {
                !sampling || v.pose.time().is_none_or(|t| now.secs() - t >= s.pose_timeout.as_secs_f64())
            }
            StopReason::HeartbeatLost { .. } => !heard,
            // A drive that rebooted unheard (its boot-up lost) stays silent, its heartbeat
            // off until configured: listening cannot tell it from a dead one. The arm
            // configures each drive afresh by SDO and faults naming the one that does not
            // answer, so the reset need not wait for a heartbeat that may never come.
            StopReason::DriveHeartbeatLost { .. } => false,
            // The reset keeps the occluded track: the robot, armed again, drives around the
            // region the obstacle may have reached (it is not forgotten while unseen: that
            // drove robots blind into it), and faults again if it stays unseen.
            StopReason::ObstacleOccluded { .. } => false,
            // Back on the bus once heard again; the board's BUS bit records that it was off,
            // a latch the reset itself clears (refusing the reset for it would never end).
            // Our controller back on the bus (its flags, or a frame heard since), and a board
            // heard again (drives may be silent: see above).
            StopReason::BusOff => self.can_link.is_bus_off() || (!heard && v.motors.always_heard()),
            StopReason::BoardBusOff { .. } => !heard,
            // The board whose input was pressed, whichever vehicle it drives.
            StopReason::BoardEStop { node } => match self.vehicles.iter().find(|o| o.motors.is_board(node)) {
                Some(o) => !o.motors.heard_within(now, s.heartbeat_timeout) || o.motors.latched(reason),
                None => !heard,
            },
            StopReason::CanLinkLost | StopReason::CanInterfaceDown => !self.can_link.is_up(),
            // Two masters must never drive one board: refused while the other is heard.
            StopReason::SecondMaster { .. } | StopReason::DriveSecondMaster { .. } => {
                self.can_link.second_master_within(now, s.heartbeat_timeout)
            }
            // The reset clears the board's latched fault; a driver fault that persists
            // faults the gateway again once it runs.
            _ => false,
        }
    }

    /// What the gateway knows now: state, goals, pose, obstacles.
    pub(super) fn status(&mut self, now: HostTime) -> Status {
        let period = self.rig.sample_period.as_secs_f64();
        let (wheel_base, robot, margin) =
            (self.rig.control.drive.wheel_base, self.rig.control.robot_radius, self.rig.control.planner.margin);
        let tracked: Vec<usize> = self.obstacles.tracked().collect();
        let (pose, obstacles) = match crate::track::estimate(
            &mut self.vehicles[ROBOT].pose,
            &mut self.obstacles,
            [&[], &[]],
            now.secs(),
            period,
            wheel_base,
        ) {
            Some(tr) => {
                let p = tr.estimate.pose();
                let delay = tr.estimate.delay;
                let obstacles = tr
                    .estimate
                    .obstacles
                    .iter()
                    .zip(tracked)
                    .map(|(o, k)| ObstacleStatus {
                        led: self.rig.obstacles[k].led,
                        occluded: o.spread > 0.0,
                        position: [o.center.re, o.center.im],
                        velocity: [o.velocity.re, o.velocity.im],
                        planning_radius: margin.radius(o.radius + robot, o.velocity.norm(), delay),
                    })
                    .collect();
                (Some([p.position.re, p.position.im, p.heading]), obstacles)
            }
            None => (None, Vec::new()),
        };
        Status {
            state: self.state().into(),
            last_stop: self.vehicles[ROBOT].last_stop(),
            goals: self.vehicles[ROBOT].mission.goals().collect(),
            pose,
            obstacles,
            absent: (0..self.rig.obstacles.len())
                .filter(|&k| self.obstacles.time(k).is_none())
                .map(|k| self.rig.obstacles[k].led)
                .collect(),
            cycles: self.counters.cycles,
            latency_us: None,
            stages: None,
            vehicles: self.vehicles[ROBOT + 1..].iter().map(DrivenVehicle::status).collect(),
        }
    }

    /// What the last cycle believed: the robot's pose, the goal, each obstacle with its
    /// covariance and planning radius. Reads only (a recording takes one per command).
    pub fn scene(&self, now: HostTime) -> SceneRecord {
        // The last cycle's number (its `CycleRecord::cycle`): cycles count from 0.
        let cycle = self.counters.cycles.saturating_sub(1);
        let mut scene = SceneRecord { cycle, at: now, ..SceneRecord::default() };
        let Some(LastEstimate { pose, delay, wheels: [left, right] }) = self.vehicles[ROBOT].last_estimate else {
            return scene;
        };
        let goal = self.vehicles[ROBOT].control.config().goal;
        scene.pose = [pose.position.re, pose.position.im, pose.heading];
        scene.twist = [0.5 * (left + right), (right - left) / self.rig.control.drive.wheel_base];
        scene.goal = [goal.re, goal.im];
        let (robot, margin) = (self.rig.control.robot_radius, self.rig.control.planner.margin);
        for (view, (o, cov)) in scene.obstacles.iter_mut().zip(self.obstacles.at(now.secs())) {
            *view = ObstacleView {
                position: [o.center.re as f32, o.center.im as f32],
                velocity: [o.velocity.re as f32, o.velocity.im as f32],
                covariance: cov.map(|c| c as f32),
                planning_radius: margin.radius(o.radius + robot, o.velocity.norm(), delay) as f32,
                radius: o.radius as f32,
            };
            scene.count += 1;
        }
        scene
    }

    /// Each other vehicle of a fleet as its last cycle left it: its pose, state and goal
    /// (`None`: the robot alone, nothing to build). Reads only.
    pub fn fleet_scene(&self) -> Option<FleetScene> {
        let others = self.vehicles.get(ROBOT + 1..).filter(|others| !others.is_empty())?;
        let mut fleet = FleetScene::default();
        for v in others {
            fleet.push(v.scene());
        }
        Some(fleet)
    }

    /// Check and take a goal or a queue: each inside the calibrated arena, inside the lane,
    /// clear of the room's walls and static obstacles and within the robot's reach there,
    /// outside every obstacle's planning circle now.
    pub(super) fn set_goals(&mut self, k: usize, now: HostTime, goals: &[Goal]) -> Result<(), Refusal> {
        if goals.is_empty() {
            return Err(Refusal::EmptyQueue);
        }
        if goals.len() > MAX_GOALS {
            return Err(Refusal::TooManyGoals(goals.len()));
        }
        let obstacles = self.status(now).obstacles;
        for (index, g) in goals.iter().enumerate() {
            let [x, y] = g.position;
            let bad = |why: String| Refusal::BadGoal { index, x, y, why };
            let at = Point::new(x, y);
            if !(x.is_finite() && y.is_finite() && g.tolerance.is_finite() && g.tolerance > 0.0) {
                return Err(bad("position and tolerance must be finite, the tolerance positive".into()));
            }
            if g.tolerance > MAX_GOAL_TOLERANCE {
                return Err(bad(format!(
                    "tolerance {} m: at most {MAX_GOAL_TOLERANCE} m",
                    crate::config::shown(g.tolerance)
                )));
            }
            if !self.rig.calibration.in_view(at) {
                return Err(bad(format!("outside the calibrated arena: {}", self.rig.calibration.view_extent())));
            }
            if let Space::Lane { half_width } = self.rig.control.planner.space {
                if y.abs() >= half_width {
                    return Err(bad(format!("outside the lane (|y| >= {half_width} m)")));
                }
            }
            if let Some(room) = &self.rig.control.room {
                if let Some(why) = room.blocked_at(at) {
                    return Err(bad(why));
                }
                let robot = self.vehicles[k].last_estimate.map(|e| e.pose.position);
                if let Some(robot) = robot.filter(|&r| room.blocked_at(r).is_none() && !room.reachable(r, at)) {
                    return Err(bad(format!(
                        "out of the robot's reach from ({:.3}, {:.3}): the walls, static obstacles or the view's edge \
                         close it off",
                        robot.re, robot.im
                    )));
                }
            }
            for o in &obstacles {
                let gap = (at - Point::new(o.position[0], o.position[1])).norm();
                if gap <= o.planning_radius {
                    return Err(bad(format!(
                        "inside obstacle LED {}'s planning circle ({gap:.3} m from it, radius {:.3} m)",
                        o.led, o.planning_radius
                    )));
                }
            }
        }
        self.vehicles[k].mission.set_goals(goals);
        let first = goals[0];
        self.vehicles[k].control.set_goal(Point::new(first.position[0], first.position[1]), first.tolerance);
        Ok(())
    }
}
