//! The core's one timer table: every deadline it keeps, in the order a tick fires them. The
//! same table gives [`Core::next_deadline`] (the soonest entry) and runs [`Input::Tick`]
//! (every entry that is due), so a deadline cannot be asked for without being fired, or
//! fired without being asked for.
//!
//! The watchdogs come in the order in which they name a stop: when several expire together
//! the first names it, and only it fires in that tick.
//!
//! [`Input::Tick`]: super::Input::Tick

use super::safety::Garbled;
use super::ROBOT;
use super::{Core, Output, StageClock, State, StopReason, HEARTBEAT_PERIOD, STOP_GRACE};
use crate::time::HostTime;
use crate::Point;
use std::f64::consts::FRAC_PI_4;

/// How far a measured position may be off, m, for judging it at the view's edge.
const EDGE_NOISE_M: f64 = 0.01;

/// A streaming controller silent this long is configured again.
pub const RESTREAM_AFTER: std::time::Duration = std::time::Duration::from_secs(1);

/// One entry of the timer table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Timer {
    /// The gateway's own heartbeat to the motors (and an SLCAN adapter's status poll).
    Heartbeat,
    /// The PSD handshake's retries and the periodic time sync.
    PsdSession,
    /// The controller streaming, and no sample for [`RESTREAM_AFTER`]: configure it again
    /// (a reboot whose announcement was lost leaves it answering, but not streaming).
    Restream,
    /// Ask for the lost PSD line, or the lost CAN link, again.
    ReopenPsd,
    ReopenCan,
    /// Watchdog: no sample within `safety.sample_timeout` (armed, running or stopping),
    /// counted from the last sample, the arm or the stream's start.
    Samples,
    /// Watchdog: no fresh robot pose within `safety.pose_timeout` (running).
    Pose,
    /// Watchdog: a tracked obstacle unseen for `safety.occlusion_timeout` (running).
    Occlusion,
    /// Watchdog: the motors' heartbeat not heard within `safety.heartbeat_timeout`.
    MotorHeartbeat,
    /// Watchdog: the controller's clock not synchronised for too long.
    ClockSync,
    /// The CiA 402 drives' SDO and enable timeouts.
    Motors,
    /// The end of an orderly stop's grace. The stop also ends as soon as the motors are at
    /// rest, whenever the core is ticked.
    StopGrace,
    /// A zero command that keeps an enabled, idle board's command timeout from firing.
    KeepAlive,
}

impl Timer {
    /// The table, in the order a tick fires its entries.
    pub const TABLE: [Timer; 13] = [
        Timer::Heartbeat,
        Timer::PsdSession,
        Timer::Restream,
        Timer::ReopenPsd,
        Timer::ReopenCan,
        Timer::Samples,
        Timer::Pose,
        Timer::Occlusion,
        Timer::MotorHeartbeat,
        Timer::ClockSync,
        Timer::Motors,
        Timer::StopGrace,
        Timer::KeepAlive,
    ];

    /// Whether the entry is a watchdog (it stops the robot when it fires).
    pub fn is_watchdog(self) -> bool {
        matches!(self, Timer::Samples | Timer::Pose | Timer::Occlusion | Timer::MotorHeartbeat | Timer::ClockSync)
    }
}

impl Timer {
    /// Whether each vehicle keeps its own entry (its pose, its motors, its stop); the rest
    /// are the rig's (the heartbeat, the PSD line, the CAN link, the samples, the clock).
    pub fn is_per_vehicle(self) -> bool {
        matches!(
            self,
            Timer::Pose
                | Timer::Occlusion
                | Timer::MotorHeartbeat
                | Timer::Motors
                | Timer::StopGrace
                | Timer::KeepAlive
        )
    }
}

impl<K: StageClock> Core<K> {
    /// When the core next needs an [`Input::Tick`](super::Input::Tick), whatever else happens;
    /// asked once the outputs are drained ([`Core::poll`] decodes what is left of a read).
    pub fn next_deadline(&self) -> HostTime {
        Timer::TABLE.iter().map(|&t| self.deadline(t)).min().unwrap_or(HostTime::NEVER)
    }

    /// When `timer` fires ([`HostTime::NEVER`] while it is not armed): a vehicle's entry for
    /// the first vehicle it fires for.
    pub fn deadline(&self, timer: Timer) -> HostTime {
        if timer.is_per_vehicle() {
            return (0..self.vehicles.len()).map(|k| self.vehicle_deadline(timer, k)).min().unwrap_or(HostTime::NEVER);
        }
        let active = self.any_active();
        let s = &self.rig.safety;
        match timer {
            Timer::Heartbeat => self.vehicles[ROBOT].run.next_heartbeat(),
            Timer::PsdSession => self.psd.deadline(),
            Timer::Restream if self.psd.is_streaming() => {
                self.samples.last().max(self.psd_link.restreamed_at()) + RESTREAM_AFTER
            }
            Timer::ReopenPsd => self.psd_link.reopen_at(),
            Timer::ReopenCan => self.can_link.reopen_at(),
            Timer::Samples if active => self.samples.last() + s.sample_timeout,
            Timer::ClockSync if active => self.psd.sync_deadline(),
            _ => HostTime::NEVER,
        }
    }

    /// When vehicle `k`'s own `timer` fires.
    fn vehicle_deadline(&self, timer: Timer, k: usize) -> HostTime {
        let v = &self.vehicles[k];
        let state = v.state();
        let (active, running) = (state.is_active(), state == State::Running);
        match timer {
            Timer::Pose if running => self.pose_deadline(k),
            Timer::Occlusion if running => self.occlusion_deadline(k).map_or(HostTime::NEVER, |(at, _)| at),
            Timer::MotorHeartbeat if active => {
                v.motors.heartbeat_deadline(v.run.armed_at(), self.rig.safety.heartbeat_timeout).0
            }
            Timer::Motors => v.motors.deadline(),
            Timer::StopGrace => v.run.stopping_since().map_or(HostTime::NEVER, |since| since + STOP_GRACE),
            Timer::KeepAlive => v.keep_alive_due().unwrap_or(HostTime::NEVER),
            _ => HostTime::NEVER,
        }
    }

    /// Time passed: fire every entry that is due, in the table's order (one watchdog at
    /// most a vehicle; a watchdog of the rig's counts for every vehicle).
    pub(super) fn tick(&mut self, now: HostTime) {
        let mut stopped_by_watchdog: u64 = 0;
        for timer in Timer::TABLE {
            if timer.is_per_vehicle() {
                for k in 0..self.vehicles.len() {
                    let due = match timer {
                        Timer::StopGrace => self.vehicles[k].run.stopping_since().is_some(),
                        _ => now >= self.vehicle_deadline(timer, k),
                    };
                    if !due || (timer.is_watchdog() && stopped_by_watchdog & (1 << k) != 0) {
                        continue;
                    }
                    if timer.is_watchdog() {
                        stopped_by_watchdog |= 1 << k;
                    }
                    self.fire_vehicle(timer, k, now);
                }
            } else {
                if now < self.deadline(timer) || (timer.is_watchdog() && stopped_by_watchdog != 0) {
                    continue;
                }
                if timer.is_watchdog() {
                    stopped_by_watchdog = u64::MAX;
                }
                self.fire(timer, now);
            }
        }
    }

    /// One of the rig's entries.
    fn fire(&mut self, timer: Timer, now: HostTime) {
        match timer {
            Timer::Heartbeat => {
                self.heartbeat();
                self.vehicles[ROBOT].run.heartbeat_sent(now + HEARTBEAT_PERIOD);
                // An SLCAN adapter reports bus-off only when asked: ask with each heartbeat.
                if self.rig.can.polls_status() {
                    self.can_link.status_asked(now);
                    self.out.push(Output::PollCanStatus);
                }
            }
            Timer::PsdSession => self.psd_session_due(now),
            Timer::Restream => self.restream(now),
            Timer::ReopenPsd => {
                self.psd_link.reopen_asked(now);
                self.out.push(Output::OpenPsd);
            }
            Timer::ReopenCan => {
                self.can_link.reopen_asked(now);
                self.out.push(Output::OpenCan);
            }
            Timer::Samples => self.stop_if_active(now, self.samples_stopped_cause(now)),
            Timer::ClockSync => self.stop_if_active(now, StopReason::ClockUnsynced),
            _ => {}
        }
    }

    /// The gateway's heartbeat: one frame for the boards and one for the drives, however
    /// many vehicles share the bus, each kind's sent by its first vehicle (in its state),
    /// and the drives' withheld while any drive's quick stop is unconfirmed.
    fn heartbeat(&mut self) {
        let withheld = self.vehicles.iter().any(|v| v.motors.withholds_heartbeat());
        let mut sent = [false; 2];
        for v in &mut self.vehicles {
            let board = usize::from(v.motors.always_heard());
            let beat = !sent[board] && (board == 1 || !withheld);
            sent[board] = true;
            let state = v.state();
            v.motors.heartbeat(state, beat, &mut self.out.can());
        }
    }

    /// One of vehicle `k`'s entries.
    fn fire_vehicle(&mut self, timer: Timer, k: usize, now: HostTime) {
        match timer {
            Timer::Pose => self.stop_vehicle(k, now, self.pose_lost_cause(k, now)),
            Timer::Occlusion => {
                if let Some((_, o)) = self.occlusion_deadline(k) {
                    let (led, at_edge) = (self.rig.obstacles[o].led, self.lost_at_edge(o));
                    self.stop_vehicle(k, now, StopReason::ObstacleOccluded { led, at_edge });
                }
            }
            Timer::MotorHeartbeat => {
                let v = &self.vehicles[k];
                let (_, reason) = v.motors.heartbeat_deadline(v.run.armed_at(), self.rig.safety.heartbeat_timeout);
                // Unheard because our own controller is off the bus: named for that, and
                // then every vehicle's.
                if self.can_link.is_bus_off() {
                    self.stop(now, StopReason::BusOff);
                } else {
                    self.stop_vehicle(k, now, reason);
                }
            }
            Timer::Motors => {
                if let Some(reason) = self.vehicles[k].motors.tick(now) {
                    self.stop_vehicle(k, now, reason);
                }
            }
            Timer::StopGrace => self.check_at_rest(k, now),
            // An arc brake under way is the command that keeps the board fed.
            Timer::KeepAlive if !self.brake_unseen(k, now) => {
                let v = &mut self.vehicles[k];
                v.run.commanded(now);
                v.motors.keep_alive(&mut self.out.can());
            }
            _ => {}
        }
    }

    /// The handshake's retry or the periodic time sync is due. A controller that streamed,
    /// configured again and now silent is named as the sample watchdog names it (garbage,
    /// or no samples), before the shell reopens the line for it.
    fn psd_session_due(&mut self, now: HostTime) {
        let failed = self.psd.tick(now, &mut self.out.psd());
        if let Some(e) = failed {
            self.setup_failed(now, e);
        }
    }

    /// The handshake gave up (unanswered, or refused): a robot armed meanwhile stops,
    /// named as the sample watchdog would have named it.
    pub(super) fn setup_failed(&mut self, now: HostTime, e: super::psd_session::SetupError) {
        if self.psd_link.has_streamed() {
            let reason = match self.samples_stopped_cause(now) {
                // Given up on, not waiting: the controller did not answer.
                StopReason::ClockUnsynced => StopReason::SamplesStopped,
                reason => reason,
            };
            self.stop(now, reason);
        }
        self.out.push(Output::SetupFailed(e));
    }

    /// The streaming controller has been silent for [`RESTREAM_AFTER`]: configure it again.
    fn restream(&mut self, now: HostTime) {
        let silent_ms = now.since(self.samples.last()).as_millis() as u64;
        self.notice(now, super::Notice::ControllerSilent { silent_ms });
        // The same line, configured again: not a reconnect (the notice counts it).
        self.psd_link.restream(now);
        self.psd.connect(now, &mut self.out.psd());
    }

    /// Why no fresh pose came, named by the first cause: the line gone quiet; the
    /// controller's clock jumped (the robot's samples stamped in the future, or frames
    /// stamped out of step with their count); seen where it cannot be; arriving, but too
    /// old (delay); lost with frames the line garbled (no weak sample of the robot since);
    /// lost while the line went quiet for a while; or not arriving.
    pub(super) fn pose_lost_cause(&self, k: usize, now: HostTime) -> StopReason {
        let s = &self.rig.safety;
        let watch = &self.vehicles[k].pose_watch;
        let quiet = now.since(self.samples.last()) > 2 * self.rig.sample_period;
        let recent = |at: Option<HostTime>, within| at.is_some_and(|at| now.since(at) < within);
        let garbled = self.garbled_when_quiet(now, watch.garbage_at_last(), Garbled::NoPose);
        if quiet {
            self.samples_stopped_cause(now)
        } else if recent(watch.last_from_future(), s.sample_timeout)
            || recent(self.stamps.stepped(), s.sample_timeout + s.pose_timeout)
        {
            StopReason::ClockJumped
        } else if watch.is_implausible() {
            StopReason::PoseImplausible
        } else if now.since(watch.arrived()) < s.sample_timeout {
            StopReason::PoseDelayed
        } else if !watch.weak() && !matches!(garbled, StopReason::SerialGarbled { frames: 0, bytes: 0, .. }) {
            garbled
        } else if watch.quiet_since() && !watch.weak() {
            StopReason::SamplesStopped
        } else {
            StopReason::PoseLost
        }
    }

    fn pose_deadline(&self, k: usize) -> HostTime {
        let seen = self.vehicles[k].pose.time().map_or(HostTime::ZERO, HostTime::from_secs_f64);
        seen + self.rig.safety.pose_timeout
    }

    /// When the longest-unseen tracked obstacle has been occluded too long for vehicle `k`
    /// (counted from its last sighting, or `k`'s arm if later), and which: the region it may have reached
    /// keeps growing, and a robot must not drive around a guess for ever. An obstacle never
    /// seen, or seen leaving the view, has no track and no deadline.
    fn occlusion_deadline(&self, k: usize) -> Option<(HostTime, usize)> {
        let armed_at = self.vehicles[k].run.armed_at();
        self.obstacles
            .tracked()
            .filter_map(|o| Some((HostTime::from_secs_f64(self.obstacles.time(o)?).max(armed_at), o)))
            .min_by_key(|&(seen, _)| seen)
            .map(|(seen, k)| (seen + self.rig.safety.occlusion_timeout, k))
    }

    /// Whether obstacle `k` was last seen so near the view's edge that it may have gone out
    /// of it by the next frame: within two periods at the top obstacle speed, and the
    /// measurement's noise, of a point the camera does not see.
    fn lost_at_edge(&self, k: usize) -> bool {
        let Some(p) = self.obstacles.last_measured(k) else { return false };
        let period = self.rig.sample_period.as_secs_f64();
        let band = 2.0 * period * self.rig.tracking.max_obstacle_speed + EDGE_NOISE_M;
        (0..8).any(|i| !self.rig.calibration.in_view(p + Point::from_polar(band, f64::from(i) * FRAC_PI_4)))
    }
}
