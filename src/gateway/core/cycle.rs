//! One time-division frame's cycle: the frame's samples into the tracker (floor coordinates,
//! host clock), the estimate, the control step (plan, supervise, wheel speeds, pulse rates)
//! while Running, and one command to the motors with its timing record.

use flowgate_protocol::psd::{Message, Packet, Sample, SampleFlags, MAX_WIRE_LEN};

use super::safety::RobotMotion;
use super::script_run::Followed;
use super::timing::CycleRecord;
use super::vehicle::LastEstimate;
use super::ROBOT;
use super::{Core, Notice, Output, StageClock, State, StopReason};
use crate::config::StopBrake;
use crate::control::drive::braking_pulse_rates;
use crate::control::{StepOutput, StepStatus, Supervision};
use crate::planner::PlannerError;
use crate::time::{ClockOffset, CtrlTime, HostTime};
use crate::track::Pose;
use crate::Point;

/// What the tracker and the control step made of a frame.
struct Decision {
    pose: Pose,
    delay: f64,
    /// The wheels' rim speeds the tracker holds, m/s: left, right.
    wheels: [f64; 2],
    clearance: Option<f64>,
    /// The control step's output, in Running.
    step: Option<StepOutput>,
    /// The gateway went from Armed to Running this cycle.
    started: bool,
    /// A scripted vehicle's script ended, or it lost it: its stop.
    script_stop: Option<StopReason>,
    track_ns: u64,
    plan_start: u64,
}

impl<K: StageClock> Core<K> {
    /// One time-division frame is complete: track, then decide and command each vehicle in
    /// the fleet's order (the robot first).
    pub(super) fn cycle(&mut self, now: HostTime, frame_no: u32, end: CtrlTime) {
        let track_start = self.clock.now_ns();
        self.stages.checks_end(|| track_start);
        // This frame's decode and checks, whether or not it ends in a command.
        let (decode_ns, checks_ns) = self.stages.take_for_cycle();
        self.check_stamps(now, frame_no, end);
        self.track_frame(now);
        self.see_fleet(now.secs());
        for k in 0..self.vehicles.len() {
            let stages = (k == ROBOT).then_some((frame_no, end, decode_ns, checks_ns, track_start));
            self.drive(k, now, stages);
        }
    }

    /// Vehicle `k`'s part of the cycle: its estimate, its step, its command. The robot's
    /// command carries the cycle's timing record (`stages`: its frame, end stamp, decode and
    /// check times, and when tracking began).
    fn drive(&mut self, k: usize, now: HostTime, stages: Option<(u32, CtrlTime, u64, u64, u64)>) {
        let track_start = stages.map_or_else(|| self.clock.now_ns(), |s| s.4);
        // No fresh pose: no command (the pose watchdog stops a running vehicle; the keep-alive
        // feeds a board that waits for its first pose), but an arc brake goes on.
        let Some(d) = self.decide(k, now, track_start) else {
            self.brake_unseen(k, now);
            return;
        };
        if d.started {
            self.state_changed(k, now);
        }
        if let Some(reason) = d.script_stop {
            self.stop_vehicle(k, now, reason);
        }
        self.vehicles[k].last_estimate = Some(LastEstimate { pose: d.pose, delay: d.delay, wheels: d.wheels });
        if k == ROBOT {
            self.progress.clearance = d.clearance.map(|c| c - self.rig.control.robot_radius);
        }
        let asked = d.step.map_or([0.0; 2], |out| [out.asked.left, out.asked.right]);
        let (pulses, wheels) =
            d.step.and_then(|out| self.carry_out(k, now, out)).unwrap_or_else(|| self.brake(k, d.wheels));
        let plan_ns = self.clock.now_ns().saturating_sub(d.plan_start);
        // Commands go out in Running (motion), Armed and Stopping (zero or the arc brake,
        // keeping the enabled board's command timeout fed).
        if !matches!(self.vehicles[k].state(), State::Running | State::Armed | State::Stopping(_)) {
            return;
        }
        self.vehicles[k].pose.commanded(now.secs(), wheels.0, wheels.1);
        self.fleet_commanded(k, d.pose.heading, wheels);
        let record = stages.map(|(frame_no, end, decode_ns, checks_ns, _)| CycleRecord {
            decode_ns,
            checks_ns,
            track_ns: d.track_ns,
            plan_ns,
            asked,
            passed: [wheels.0, wheels.1],
            ..self.record(now, frame_no, end, pulses, d.delay, d.pose.position)
        });
        self.command(k, now, pulses, record.map(|r| (r, d.pose.position)));
    }

    /// Vehicle `k` was commanded these wheel speeds: the vehicles after it plan on the
    /// velocity they ask.
    fn fleet_commanded(&mut self, k: usize, heading: f64, (left, right): (f64, f64)) {
        if !self.fleet.is_fleet() {
            return;
        }
        let v = &mut self.vehicles[k];
        let was = v.commanded;
        v.commanded = Point::from_polar(0.5 * (left + right), heading);
        let accel = v.control.config().supervisor.as_ref().map_or(0.0, |s| s.wheel_accel);
        self.fleet.commanded(k, v.commanded, super::fleet::ramp_lag(was, v.commanded, accel));
    }

    /// Vehicle `k`'s estimate at `now`, its start once everything is ready, and its control
    /// step in Running. `None` without a fresh pose.
    fn decide(&mut self, k: usize, now: HostTime, track_start: u64) -> Option<Decision> {
        let t = now.secs();
        let period = self.rig.sample_period.as_secs_f64();
        let pose_timeout = self.rig.safety.pose_timeout.as_secs_f64();
        let fleet = self.fleet.is_fleet();
        let v = &mut self.vehicles[k];
        let wheel_base = v.control.config().drive.wheel_base;
        let ready = v.ready_to_start() && v.motors.ready();
        let others = self.fleet.others_of(k);
        // The estimate borrows the tracks: decide inside, act on the decision after.
        let tracked = crate::track::estimate(&mut v.pose, &mut self.obstacles, others, t, period, wheel_base)
            .filter(|tr| t - tr.pose_valid_at < pose_timeout)?;
        let track_ns = self.clock.now_ns().saturating_sub(track_start);
        let started = ready && v.safety.state() == State::Armed;
        if started {
            v.safety.ready(t);
            v.control.start(t);
            if let Some(script) = v.script.as_mut() {
                script.start(t);
            }
        }
        if fleet && v.script.is_none() {
            let config = v.control.config();
            let aim =
                self.fleet.aim(k, (tracked.estimate.position, config.goal), v.control.aim(), config.room.as_deref());
            v.control.aim_at(aim);
        }
        let plan_start = self.clock.now_ns();
        let (mut step, mut script_stop) = (None, None);
        if v.safety.state().may_move() {
            let e = &tracked.estimate;
            match v.script.as_mut().map(|s| s.follow(t, e.position, e.facing)) {
                None => step = Some(v.control.step(t, e)),
                Some(Followed::Command { command, error }) => {
                    v.control.take_command(t, command);
                    let out = v.control.step(t, e);
                    if let (Some(s), Supervision::Passed) = (v.script.as_mut(), out.supervision) {
                        s.passed(error);
                    }
                    step = Some(out);
                }
                Some(Followed::Lost { error, tolerance }) => {
                    let mm = |m: f64| (m * 1e3).round().min(f64::from(u16::MAX)) as u16;
                    script_stop = Some(StopReason::OffScript { error_mm: mm(error), tolerance_mm: mm(tolerance) });
                }
                Some(Followed::Ended) => script_stop = Some(StopReason::ScriptEnded),
            }
        }
        let (pose, delay, wheels) = (tracked.estimate.pose(), tracked.estimate.delay, tracked.estimate.wheels);
        let clearance = tracked.clearance;
        Some(Decision { pose, delay, wheels, clearance, step, started, script_stop, track_ns, plan_start })
    }

    /// The command that brings vehicle `k`'s wheels down, stopping or waiting, from their
    /// rim speeds `wheels` now: with `[safety] stop_brake = "arc"` both together
    /// ([`braking_pulse_rates`]: it keeps the arc the supervisor certified), else zero to each.
    fn brake(&self, k: usize, wheels: [f64; 2]) -> ([i32; 2], (f64, f64)) {
        if self.rig.safety.stop_brake != StopBrake::Arc {
            return ([0; 2], (0.0, 0.0));
        }
        let drive = &self.vehicles[k].control.config().drive;
        let pulses = braking_pulse_rates(wheels, drive);
        let ppm = drive.pulses_per_metre();
        (pulses, (f64::from(pulses[0]) / ppm, f64::from(pulses[1]) / ppm))
    }

    /// Vehicle `k` stopping on the arc brake without a fresh pose: the brake goes on, from
    /// where its commands and the boards' ramp have brought the wheels, so that it ends
    /// whether or not the camera sees the vehicle. Whether it commanded.
    pub(super) fn brake_unseen(&mut self, k: usize, now: HostTime) -> bool {
        let v = &self.vehicles[k];
        let stopping = matches!(v.state(), State::Stopping(_)) && v.motors.takes_commands();
        if self.rig.safety.stop_brake != StopBrake::Arc || !stopping {
            return false;
        }
        let t = now.secs();
        let (pulses, wheels) = self.brake(k, self.vehicles[k].pose.wheels_at(t));
        self.vehicles[k].pose.commanded(t, wheels.0, wheels.1);
        self.command(k, now, pulses, None);
        true
    }

    /// Count what vehicle `k`'s step saw and act on its status; the pulses and wheel speeds
    /// to command, `None` when it does not drive (the brake's, then).
    fn carry_out(&mut self, k: usize, now: HostTime, out: StepOutput) -> Option<([i32; 2], (f64, f64))> {
        let t = now.secs();
        let c = &mut self.counters;
        c.obstacle_outran_robot += u64::from(out.outrun);
        c.obstacle_occluded_cycles += u64::from(self.obstacles.tracked().any(|k| self.obstacles.occluded(k, t)));
        if let Some(plan) = out.plan {
            let f = plan.flags;
            c.planner_saturated += u64::from(f.saturated);
            c.planner_tie_break += u64::from(f.tie_break);
            c.planner_margin_shrunk += u64::from(f.margin_shrunk);
            c.planner_unclosed_at_a_wall += u64::from(f.unclosed_at_a_wall);
        }
        if out.status != StepStatus::Driving {
            self.step_stopped(k, now, out.status);
            return None;
        }
        c.outside_commands_saturated += u64::from(out.saturated);
        match out.supervision {
            Supervision::Passed => {}
            Supervision::Slowed { .. } => c.supervisor_slowed += 1,
            Supervision::Braking { .. } => c.supervisor_braking += 1,
            Supervision::Evaded { .. } => c.supervisor_evaded += 1,
        }
        Some((out.pulses, (out.wheels.left, out.wheels.right)))
    }

    /// Vehicle `k`'s step did not drive: the goal reached, a stall, an occupied goal, a
    /// refusal.
    fn step_stopped(&mut self, k: usize, now: HostTime, status: StepStatus) {
        match status {
            StepStatus::Driving => {}
            StepStatus::AtGoal => self.goal_reached(k, now),
            StepStatus::Stalled => self.stop_vehicle(k, now, StopReason::Stalled),
            StepStatus::CommandStale => self.stop_vehicle(k, now, StopReason::CommandStale),
            StepStatus::GoalOccupied { index, since } => {
                self.counters.goal_occupied += 1;
                if since == now.secs() {
                    let led = self.obstacle_led(k, index);
                    self.vehicle_notice(k, now, Notice::GoalOccupied { led });
                }
            }
            StepStatus::GoalBlocked { index } => {
                let wait = self.vehicles[k].control.config().goal_wait;
                let led = self.obstacle_led(k, index);
                self.vehicle_notice(k, now, Notice::GoalBlocked { led, wait_s: wait });
                self.stop_vehicle(k, now, StopReason::GoalBlocked);
            }
            StepStatus::Invalid(PlannerError::InsideObstacle { index }) => {
                // The vehicle inside an obstacle's planning circle: the obstacle came to it.
                self.counters.planner_invalid += 1;
                let (led, robot) = (self.obstacle_led(k, index), self.motion_towards(k, now, index));
                self.stop_vehicle(k, now, StopReason::ObstacleReachedRobot { led, robot });
            }
            StepStatus::Invalid(e) => {
                self.counters.planner_invalid += 1;
                let led = match e {
                    PlannerError::GoalInsideObstacle { index } | PlannerError::BadRadius { index } => {
                        Some(self.obstacle_led(k, index))
                    }
                    _ => None,
                };
                self.vehicle_notice(k, now, Notice::PlannerRefused { error: e, led });
                self.stop_vehicle(k, now, StopReason::PlannerInvalid);
            }
        }
    }

    /// How vehicle `k` moved relative to the obstacle its planner calls `index`, by this
    /// cycle's estimate: standing (under [`RobotMotion::STANDING_SPEED`]), driving towards it
    /// faster than that, or otherwise driving (turning, or away from it).
    fn motion_towards(&self, k: usize, now: HostTime, index: usize) -> RobotMotion {
        let Some(e) = self.vehicles[k].last_estimate else { return RobotMotion::Standing };
        let speed = (e.wheels[0] + e.wheels[1]) / 2.0;
        if speed.abs() < RobotMotion::STANDING_SPEED {
            return RobotMotion::Standing;
        }
        let obstacle = match self.obstacles.tracked().nth(index) {
            Some(o) => self.obstacles.prediction(o, now.secs()),
            None => self.other_vehicle(k, index).and_then(|j| self.fleet.position(j)),
        };
        let Some(ahead) = obstacle.map(|o| o - e.pose.position).filter(|a| a.norm() > 0.0) else {
            return RobotMotion::Away;
        };
        let towards = speed * (ahead.re * e.pose.heading.cos() + ahead.im * e.pose.heading.sin()) / ahead.norm();
        if towards >= RobotMotion::STANDING_SPEED {
            RobotMotion::Towards
        } else {
            RobotMotion::Away
        }
    }

    /// The LED of the obstacle vehicle `k`'s planner and supervisor call `index`: they
    /// number the tracked obstacles, then the other vehicles they see (named by their front
    /// LED).
    fn obstacle_led(&self, k: usize, index: usize) -> u8 {
        match self.obstacles.tracked().nth(index) {
            Some(o) => self.rig.obstacles[o].led,
            None => self.other_vehicle(k, index).map_or(u8::MAX, |j| self.vehicles[j].leds[0]),
        }
    }

    /// Which vehicle vehicle `k`'s planner calls obstacle `index`, beyond the tracked
    /// obstacles.
    fn other_vehicle(&self, k: usize, index: usize) -> Option<usize> {
        let beyond = index.checked_sub(self.obstacles.tracked().count())?;
        self.fleet.seen_by(k).nth(beyond)
    }

    /// A cycle's record, its stage timings left at zero.
    fn record(
        &mut self,
        now: HostTime,
        frame: u32,
        end: CtrlTime,
        pulses: [i32; 2],
        delay: f64,
        at: Point,
    ) -> CycleRecord {
        CycleRecord {
            cycle: self.counters.cycles,
            frame,
            t_ctrl_us: end.0,
            rx_ns: now.as_nanos(),
            period_ns: self.vehicles[ROBOT].run.last_command().map_or(0, |lc| now.since(lc).as_nanos() as u64),
            delay_s: delay,
            state: self.state(),
            pulses,
            x: at.re,
            y: at.im,
            goal_distance: (self.vehicles[ROBOT].control.config().goal - at).norm(),
            ..CycleRecord::default()
        }
    }

    /// Vehicle `k`'s goal is reached: on to the next in its queue, or stop.
    fn goal_reached(&mut self, k: usize, now: HostTime) {
        match self.vehicles[k].mission.next_goal() {
            Some(next) => {
                self.vehicle_notice(k, now, Notice::NextGoal { position: next.position });
                self.vehicles[k].control.set_goal(Point::new(next.position[0], next.position[1]), next.tolerance);
            }
            None => {
                self.vehicles[k].mission.set_start_requested(false);
                self.stop_vehicle(k, now, StopReason::GoalReached);
            }
        }
    }

    /// The frame's end stamp against the frames before it ([`StampWatch::frame`]): a pose
    /// stop soon after a step is named for the clock, whichever way it stepped (backwards,
    /// the poses only look old).
    ///
    /// [`StampWatch::frame`]: super::watch::StampWatch::frame
    fn check_stamps(&mut self, now: HostTime, frame_no: u32, end: CtrlTime) {
        let end_host = self.psd.clock().to_host(end);
        self.stamps.frame(now, frame_no, end, end_host, self.rig.sample_period);
    }

    /// The frame's samples into the tracker, in floor coordinates on the host clock. A
    /// sample stamped after `now` (beyond a period of clock tolerance) is discarded and
    /// counted: one future stamp would otherwise make every later, true one look old.
    fn track_frame(&mut self, now: HostTime) {
        let clock = self.psd.clock();
        let latest = now + self.rig.sample_period;
        let vehicles = &self.vehicles;
        let vehicle_of = |led| vehicles.iter().position(|v| v.leds.contains(&led));
        let future = self.frame.discard_future(clock, latest, &self.rig.schedule, vehicle_of, &mut self.counters);
        for k in 0..self.vehicles.len() {
            if future & (1 << k) != 0 {
                self.vehicles[k].pose_watch.stamped_in_future(now);
            }
            self.observe_vehicle(k, now, clock);
        }
        self.observe_obstacles(now, clock);
        self.frame.clear(&self.rig.schedule);
    }

    /// Vehicle `k`'s two LEDs into its pose, if plausible.
    fn observe_vehicle(&mut self, k: usize, now: HostTime, clock: ClockOffset) {
        let [front, rear] = self.vehicles[k].leds;
        let (Some(f), Some(r)) = (self.frame.usable(front), self.frame.usable(rear)) else {
            // Seen but weak (occluded), as against not come at all (lost with its frame).
            let weak = |led| self.frame.received(led) && self.frame.usable(led).is_none();
            let weak = weak(front) || weak(rear);
            self.vehicles[k].pose_watch.seen_weak(weak);
            return;
        };
        let cal = &self.rig.calibration;
        let (Some(fp), Some(rp)) =
            (cal.to_floor(f64::from(f.x), f64::from(f.y)), cal.to_floor(f64::from(r.x), f64::from(r.y)))
        else {
            return;
        };
        let at = clock.to_host(f.at.midpoint(r.at)).secs();
        let reach = self.rig.pose_reach_of(&self.vehicles[k].control.config().drive);
        let v = &mut self.vehicles[k];
        match v.pose.plausible(at, fp, rp, reach) {
            Ok(()) => {
                v.pose_watch.plausible(now, (self.counters.bad_serial_frames, self.psd.garbage_bytes()));
                v.pose.observe(at, fp, rp);
            }
            Err(e) => {
                self.counters.poses_implausible += 1;
                if v.pose_watch.implausible(e) {
                    self.vehicle_notice(k, now, Notice::PoseDiscarded { why: e });
                }
            }
        }
    }

    /// Each obstacle's LED into its track; an obstacle unseen past the pose timeout and
    /// carried beyond the view's edge has left it.
    fn observe_obstacles(&mut self, now: HostTime, clock: ClockOffset) {
        let t = now.secs();
        let cal = self.rig.calibration;
        for (k, o) in self.rig.obstacles.iter().enumerate() {
            let tracked = self.obstacles.time(k).is_some();
            let seen = self.frame.usable(o.led).and_then(|s| {
                let p = cal.to_floor(f64::from(s.x), f64::from(s.y))?;
                Some((p, clock.to_host(s.at).secs()))
            });
            if let Some((p, at)) = seen {
                if self.obstacles.observe(k, at, p) && !tracked {
                    self.counters.obstacles_entered_view += 1;
                    let led = o.led;
                    self.out
                        .push(Output::Notice { at: now, notice: Notice::ObstacleEntered { led, at: [p.re, p.im] } });
                }
            } else if self.obstacles.occluded(k, t) {
                // Unseen past the pose timeout: gone out of the view if its filter carries it
                // beyond the edge by now (it was at the edge, heading out); otherwise occluded,
                // and avoided as a region until it is seen again or the timeout faults.
                let beyond = self.obstacles.prediction(k, t).is_some_and(|p| !cal.in_view(p));
                if beyond {
                    self.obstacles.drop_track(k);
                    self.counters.obstacles_left_view += 1;
                    self.out.push(Output::Notice { at: now, notice: Notice::ObstacleLeft { led: o.led } });
                }
            }
        }
    }

    /// The cycle's command to vehicle `k`'s motors; the robot's with the cycle's record.
    fn command(&mut self, k: usize, now: HostTime, pulses: [i32; 2], record: Option<(CycleRecord, Point)>) {
        if !self.vehicles[k].motors.takes_commands() {
            return;
        }
        let encode_start = self.clock.now_ns();
        let frame = self.vehicles[k].motors.command(pulses, &mut self.out.can());
        let encode_ns = self.clock.now_ns().saturating_sub(encode_start);
        let Some(frame) = frame else {
            // Pulse rates come from the drive model clamped to the wheel limit, which the
            // config keeps in range; a frame that cannot be built is a planner fault.
            self.stop_vehicle(k, now, StopReason::PlannerInvalid);
            return;
        };
        self.vehicles[k].run.commanded(now);
        let Some((record, position)) = record else {
            self.out.push(Output::Can(frame));
            return;
        };
        let record = CycleRecord { encode_ns, ..record };
        self.counters.cycles += 1;
        self.progress.t = now.secs();
        self.progress.cycles = self.counters.cycles;
        self.progress.goal_distance = (self.vehicles[ROBOT].control.config().goal - position).norm();
        self.out.push(Output::Command { frame, record });
    }

    /// Run the cycle's work once on the last state and discard it, so that its code and
    /// data are in cache when the next frame comes (`[realtime] warm_up`: the shell calls it
    /// as each low-latency window opens, about a frame's worth of work ahead). A packet is
    /// encoded and decoded, a point calibrated, the state estimated, the control step
    /// planned and supervised, a velocity frame built. It is not an input: nothing the next
    /// cycle computes depends on it (the tracker's estimate and the plan's field are
    /// scratch, rebuilt every cycle), so a replay without rehearsals is the run's, byte for
    /// byte (`a_rehearsal_changes_nothing`). Only in Running, where cycles plan.
    pub fn rehearse(&mut self, now: HostTime) {
        if !self.vehicles[ROBOT].safety.state().may_move() {
            return;
        }
        let led = self.rig.robot_front;
        let sample = Sample { frame: 0, slot: 0, led, t_ctrl_us: 0, x: 0, y: 0, intensity: 0, flags: SampleFlags(0) };
        let mut wire = [0u8; MAX_WIRE_LEN];
        if let Ok(n) = Packet::new(0, Message::Sample(sample)).encode(&mut wire) {
            // Without its closing `0x00`, as the stream hands a frame over.
            let _ = std::hint::black_box(Packet::decode(&wire[..n - 1]));
        }
        std::hint::black_box(self.rig.calibration.to_floor(0.0, 0.0));
        let (period, wheel_base) = (self.rig.sample_period.as_secs_f64(), self.rig.control.drive.wheel_base);
        if let Some(tracked) = crate::track::estimate(
            &mut self.vehicles[ROBOT].pose,
            &mut self.obstacles,
            [&[], &[]],
            now.secs(),
            period,
            wheel_base,
        ) {
            self.vehicles[ROBOT].control.rehearse(&tracked.estimate);
        }
        self.vehicles[ROBOT].motors.rehearse();
    }
}
