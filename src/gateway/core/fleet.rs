//! What each vehicle the core drives sees of the others, cycle by cycle, as
//! [`crate::control::fleet`] states it: every other vehicle an obstacle of its own footprint
//! moving at the velocity it was commanded (known, not estimated), planned in a fixed order
//! (the robot first, then `[[vehicles]]` in the file's order), so a vehicle sees this cycle's
//! command of every vehicle ahead of it and the last cycle's of those behind.
//!
//! Where the camera no longer gives a vehicle's pose (its LEDs unseen, or its pose forgotten
//! at an e-stop), the others avoid the region it may have reached since it was last seen,
//! growing at its top speed, as an occluded obstacle's does. A vehicle stopped for a cause
//! that may not have reached its motors (unheard, or the bus lost) may still move on its last
//! command until their own timeout: the others keep clear of where it could still go, at its
//! top speed, until then. A vehicle never seen is not
//! planned around: nothing is known of where it is, and it cannot be armed until it is seen.

use super::{Core, StageClock, State};
use crate::control::fleet::{FleetRule, VehicleView};
use crate::planner::ObstacleEstimate;
use crate::Point;

/// Every vehicle's view this cycle, and one vehicle's obstacles built from them.
#[derive(Debug)]
pub(super) struct FleetViews {
    rule: FleetRule,
    /// Each vehicle as the others see it (`None`: never seen).
    views: Vec<Option<VehicleView>>,
    /// Scratch: one vehicle's others, as its field and as its supervisor see them.
    seen: Vec<ObstacleEstimate>,
    supervised: Vec<ObstacleEstimate>,
}

impl FleetViews {
    pub(super) fn new(vehicles: usize) -> Self {
        Self {
            rule: FleetRule::default(),
            views: vec![None; vehicles],
            seen: Vec::with_capacity(vehicles),
            supervised: Vec::with_capacity(vehicles),
        }
    }

    /// Whether there are others to see (a fleet, not the robot alone).
    pub(super) fn is_fleet(&self) -> bool {
        self.views.len() > 1
    }

    /// Vehicle `me`'s others, as its field plans on them and as its supervisor judges them.
    pub(super) fn others_of(&mut self, me: usize) -> [&[ObstacleEstimate]; 2] {
        self.seen.clear();
        self.supervised.clear();
        for (_, v) in self.views.iter().enumerate().filter(|&(k, _)| k != me) {
            if let Some(v) = v {
                self.seen.push(self.rule.as_obstacle(v));
                self.supervised.push(self.rule.as_supervised(v));
            }
        }
        [&self.seen, &self.supervised]
    }

    /// Where vehicle `me` at `position` heads for `goal` while another still stands on it
    /// ([`FleetRule::aim_within`], inside `room`'s free region; `None`: the goal itself).
    pub(super) fn aim(
        &self,
        me: usize,
        (position, goal): (Point, Point),
        held: Option<Point>,
        room: Option<&crate::planner::room::Room>,
    ) -> Option<Point> {
        // The rule takes every vehicle by index: one never seen stands nowhere near a goal.
        let far = VehicleView::standing(Point::new(f64::INFINITY, f64::INFINITY), 0.0);
        let mut views = [far; crate::planner::MAX_OBSTACLES + 1];
        for (slot, v) in views.iter_mut().zip(&self.views) {
            *slot = v.unwrap_or(far);
        }
        let n = self.views.len().min(views.len());
        views[me].position = position;
        let free = |p: Point| room.is_none_or(|r| r.blocked_at(p).is_none());
        self.rule.aim_within(me, position, goal, &views[..n], held, free)
    }

    /// The vehicles vehicle `me` sees, in the order its obstacles list them.
    pub(super) fn seen_by(&self, me: usize) -> impl Iterator<Item = usize> + '_ {
        self.views.iter().enumerate().filter(move |&(k, v)| k != me && v.is_some()).map(|(k, _)| k)
    }

    /// Where vehicle `k` stands this cycle, if it was ever seen.
    pub(super) fn position(&self, k: usize) -> Option<Point> {
        self.views.get(k).copied().flatten().map(|v| v.position)
    }

    /// Vehicle `k` was commanded `velocity` this cycle (m/s): the vehicles after it plan on it.
    pub(super) fn commanded(&mut self, k: usize, velocity: Point, lag: f64) {
        if let Some(v) = &mut self.views[k] {
            (v.velocity, v.toward, v.lag) = (velocity, velocity, lag);
        }
    }
}

/// How far behind the way `toward` would take a vehicle moving at `velocity` its wheels'
/// ramps may leave it, m: the gap, times the time the ramps take to close it.
pub(super) fn ramp_lag(velocity: Point, toward: Point, wheel_accel: f64) -> f64 {
    let gap = (toward - velocity).norm();
    if gap == 0.0 || wheel_accel <= 0.0 {
        return 0.0;
    }
    gap * gap / wheel_accel
}

impl<K: StageClock> Core<K> {
    /// Every vehicle as the others see it at the start of this cycle: where the camera puts
    /// it, moving as it was last commanded (or, stopped, as its wheels still turn).
    pub(super) fn see_fleet(&mut self, t: f64) {
        if !self.fleet.is_fleet() {
            return;
        }
        let (period, pose_timeout) = (self.rig.sample_period.as_secs_f64(), self.rig.safety.pose_timeout.as_secs_f64());
        for k in 0..self.vehicles.len() {
            let v = &mut self.vehicles[k];
            let config = v.control.config();
            let (radius, top_speed, wheel_base) =
                (config.robot_radius, config.planner.max_speed, config.drive.wheel_base);
            let wheel_accel = config.supervisor.as_ref().map_or(0.0, |s| s.wheel_accel);
            let under_control = matches!(v.state(), State::Running | State::Armed);
            let view = match v.pose.at(t, period, wheel_base).filter(|at| t - at.valid_at < pose_timeout) {
                Some(at) => {
                    let moving = at.facing * (0.5 * (at.wheels[0] + at.wheels[1]));
                    let (velocity, toward) =
                        if under_control { (v.commanded, v.commanded) } else { (moving, Point::default()) };
                    let lag = ramp_lag(moving, toward, wheel_accel);
                    let moving_on = v.moving_on();
                    let reach = v.unreached_until.map_or(0.0, |until| top_speed * (until - t).max(0.0));
                    Some(VehicleView { position: at.position, velocity, toward, lag, radius, moving_on, reach })
                }
                None => v.pose.last_seen().map(|(seen, position)| VehicleView {
                    reach: top_speed * (t - seen).max(period),
                    ..VehicleView::standing(position, radius)
                }),
            };
            self.fleet.views[k] = view;
        }
    }
}

#[cfg(test)]
mod tests {
    use flowgate_protocol::motor::{BoardState, MotorMessage, NmtCommand, NodeId, Target};

    use super::super::input::CanEvent;
    use super::super::operator::Request;
    use super::super::timers::Timer;
    use super::super::{Core, Input, NoClock, Output, State, StopReason};
    use crate::config::{RigFile, VehicleSection};
    use crate::time::HostTime;

    /// The example rig with two board vehicles at nodes 2 and 3.
    fn fleet() -> Core<NoClock> {
        let mut file = RigFile::from_toml(include_str!("../../../rig.example.toml"), "rig").unwrap();
        file.vehicles = ["a", "b"]
            .iter()
            .zip(2u8..)
            .map(|(name, node)| VehicleSection {
                name: name.to_string(),
                front_led: 2 * node + 1,
                rear_led: 2 * node + 2,
                node: Some(node),
                ..Default::default()
            })
            .collect();
        Core::new(file.rig("rig").unwrap(), NoClock)
    }

    fn heartbeat(node: u8, state: BoardState) -> CanEvent {
        let node = NodeId::new(node).unwrap();
        CanEvent::Frame(MotorMessage::Heartbeat { node, state }.to_frame().unwrap())
    }

    fn is_enable(output: &Output, node: u8) -> bool {
        let enable =
            MotorMessage::Nmt { target: Target::Node(NodeId::new(node).unwrap()), command: NmtCommand::Enable };
        matches!(output, Output::Can(f) if MotorMessage::parse(f).is_ok_and(|m| m == enable))
    }

    fn drain(c: &mut Core<NoClock>) -> Vec<Output> {
        std::iter::from_fn(|| c.poll()).collect()
    }

    /// One gateway heartbeat for the three boards, however many vehicles share the bus.
    #[test]
    fn one_heartbeat_goes_out_for_every_board() {
        let mut c = fleet();
        let at = c.deadline(Timer::Heartbeat);
        c.handle(at, Input::Tick);
        let beats = drain(&mut c)
            .into_iter()
            .filter(|o| {
                matches!(o, Output::Can(f) if matches!(MotorMessage::parse(f), Ok(MotorMessage::GatewayHeartbeat { .. })))
            })
            .count();
        assert_eq!(beats, 1);
    }

    /// A board's frame goes to the vehicle whose board it is: heard there, not counted as
    /// foreign. A board rebooting under an armed vehicle faults that vehicle alone, named by
    /// its node; the rig's own watchdog (no samples) stops every armed vehicle and leaves an
    /// idle one be.
    #[test]
    fn each_board_is_its_own_vehicles_and_the_rigs_faults_every_armed_one() {
        let mut c = fleet();
        let t = |ms: u64| HostTime::from_nanos(ms * 1_000_000);
        for node in 1..=3 {
            c.handle(t(1), Input::Can(heartbeat(node, BoardState::Disabled)));
        }
        assert_eq!(c.counters().can_foreign, 0);
        c.handle(t(2), Input::Can(heartbeat(9, BoardState::Disabled)));
        assert_eq!(c.counters().can_foreign, 1, "node 9 is no vehicle's");
        for vehicle in [1, 2] {
            c.handle(t(3), Input::VehicleRequest { vehicle, request: &Request::Arm });
        }
        drain(&mut c);
        let states = |c: &Core<NoClock>| (0..3).map(|k| c.vehicle_state(k).unwrap()).collect::<Vec<_>>();
        assert_eq!(states(&c), [State::Idle, State::Armed, State::Armed]);
        // Powered up with the gateway: its boot-up heard while it is being enabled is no
        // reboot; it is enabled afresh (the enable it missed goes out again).
        drain(&mut c);
        c.handle(t(4), Input::Can(heartbeat(3, BoardState::BootUp)));
        assert_eq!(states(&c), [State::Idle, State::Armed, State::Armed]);
        let enables = drain(&mut c).iter().filter(|o| is_enable(o, 3)).count();
        assert_eq!(enables, 1, "node 3 is told to enable again");
        c.handle(t(5), Input::Can(heartbeat(3, BoardState::Enabled)));
        c.handle(t(6), Input::Can(heartbeat(3, BoardState::BootUp)));
        let rebooted = State::Fault(StopReason::BoardReboot { node: 3 });
        assert_eq!(states(&c), [State::Idle, State::Armed, rebooted]);
        let named = drain(&mut c)
            .into_iter()
            .any(|o| matches!(o, Output::State { vehicle: 2, state, .. } if state == rebooted));
        assert!(named, "the state change names vehicle 2");
        let due = c.deadline(Timer::Samples);
        c.handle(due, Input::Tick);
        assert_eq!(states(&c), [State::Idle, State::Fault(StopReason::SerialLost), rebooted]);
    }

    /// A board's e-stop input stops every vehicle, and no vehicle leaves the fault while
    /// that board still latches it.
    #[test]
    fn a_boards_estop_input_stops_every_vehicle_until_released() {
        use flowgate_protocol::motor::FaultBits;
        let mut c = fleet();
        let t = |ms: u64| HostTime::from_nanos(ms * 1_000_000);
        let status = |state, faults| {
            let node = NodeId::new(3).unwrap();
            let m = MotorMessage::Status { node, state, faults, last_seq: 0, seq_errors: 0 };
            Input::Can(CanEvent::Frame(m.to_frame().unwrap()))
        };
        for node in 1..=3 {
            c.handle(t(1), Input::Can(heartbeat(node, BoardState::Disabled)));
        }
        c.handle(t(2), Input::VehicleRequest { vehicle: 2, request: &Request::Arm });
        c.handle(t(200), status(BoardState::EStop, FaultBits(FaultBits::ESTOP_INPUT)));
        drain(&mut c);
        let pressed = State::Fault(StopReason::BoardEStop { node: 3 });
        assert_eq!((0..3).map(|k| c.vehicle_state(k).unwrap()).collect::<Vec<_>>(), [pressed; 3]);
        for node in 1..=3 {
            c.handle(t(300), Input::Can(heartbeat(node, BoardState::EStop)));
        }
        let reset =
            |c: &mut Core<NoClock>, at| c.handle(at, Input::VehicleRequest { vehicle: 1, request: &Request::Reset });
        let refused = reset(&mut c, t(301)).unwrap().result;
        assert_eq!(
            refused,
            Err(super::super::operator::Refusal::CauseStillPresent(StopReason::BoardEStop { node: 3 }))
        );
        c.handle(t(400), status(BoardState::EStop, FaultBits::default()));
        assert_eq!(reset(&mut c, t(401)).unwrap().result, Ok(()), "released: vehicle a leaves the fault");
        assert_eq!(c.vehicle_state(1), Some(State::Idle));
    }
}
