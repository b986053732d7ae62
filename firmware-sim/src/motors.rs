//! The motor side of the simulated rig: one PCL-80K-like board for both wheels, or one
//! CiA 402 drive a wheel. Either takes the bus's frames and the time, and moves the world's
//! wheels. A fleet has one set a vehicle on the one bus ([`FleetMotors`]).

use flowgate_protocol::{canopen, motor, CanFrame};

use crate::cia402_drive::Cia402Drive;
use crate::faults::FaultPlan;
use crate::motor_board::MotorBoard;
use crate::world::fleet::Fleet;
use crate::world::{World, LEFT, RIGHT};

/// Which motor firmware the rig runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotorKind {
    /// One PCL-80K-like board at this node.
    Board(motor::NodeId),
    /// One CiA 402 drive a wheel, at these nodes.
    Cia402 { left: canopen::NodeId, right: canopen::NodeId },
}

impl MotorKind {
    /// Vehicle `k`'s motors in a fleet whose robot (vehicle 0) has these: the boards at the
    /// nodes after the robot's, the drive pairs after the robot's pair. `None` past the
    /// protocol's node ids (a board's 15, a drive's 127).
    pub fn for_vehicle(self, k: usize) -> Option<Self> {
        let k = u8::try_from(k).ok()?;
        match self {
            Self::Board(node) => Some(Self::Board(motor::NodeId::new(node.get().checked_add(k)?)?)),
            Self::Cia402 { left, right } => {
                let at = |n: canopen::NodeId| canopen::NodeId::new(n.get().checked_add(k.checked_mul(2)?)?);
                Some(Self::Cia402 { left: at(left)?, right: at(right)? })
            }
        }
    }

    /// Its nodes, as an operator reads them (`board node 2`, `drives 3 and 4`).
    pub fn describe(self) -> String {
        match self {
            Self::Board(node) => format!("board node {}", node.get()),
            Self::Cia402 { left, right } => format!("drives {} and {}", left.get(), right.get()),
        }
    }
}

/// The motor firmware.
#[derive(Debug)]
pub enum Motors {
    Board(Box<MotorBoard>),
    Cia402(Box<[Cia402Drive; 2]>),
}

/// Faults of the plan that only the PCL-80K-like board plays.
const BOARD_ONLY: [&str; 5] = ["board_fault_at", "board_estop", "bus_off_at", "second_master_at", "foreign_frames"];

impl Motors {
    /// The firmware of `kind`, with the plan's faults. CiA 402 drives do not play the
    /// board's own faults: [`Motors::unplayed`] names them, for a caller to refuse.
    pub fn new(kind: MotorKind, plan: &FaultPlan) -> Self {
        match kind {
            MotorKind::Board(node) => Self::Board(Box::new(MotorBoard::new(node, plan.clone()))),
            MotorKind::Cia402 { left, right } => Self::Cia402(Box::new([
                Cia402Drive::new(left, LEFT, Some(plan.clone())),
                Cia402Drive::new(right, RIGHT, None),
            ])),
        }
    }

    /// The first fault of `plan` that `kind` does not play, as its key.
    pub fn unplayed(kind: MotorKind, plan: &FaultPlan) -> Option<String> {
        let MotorKind::Cia402 { .. } = kind else { return None };
        let set = [
            plan.board_fault_at.is_some(),
            plan.board_estop.is_some(),
            plan.bus_off_at.is_some(),
            plan.second_master_at.is_some(),
            plan.foreign_frames,
        ];
        set.iter().position(|&s| s).map(|k| format!("faults.{}", BOARD_ONLY[k]))
    }

    /// The board's node (the board's own faults address it); `None` for CiA 402 drives.
    pub fn board_node(&self) -> Option<motor::NodeId> {
        match self {
            Self::Board(b) => Some(b.node()),
            Self::Cia402(_) => None,
        }
    }

    pub fn boot(&mut self, t: f64, world: &mut World, out: &mut Vec<CanFrame>) {
        match self {
            Self::Board(b) => b.boot(t, world, out),
            Self::Cia402(d) => d.iter_mut().for_each(|d| d.boot(t, world, out)),
        }
    }

    pub fn handle(&mut self, t: f64, frame: &CanFrame, world: &mut World, out: &mut Vec<CanFrame>) {
        match self {
            Self::Board(b) => b.handle(t, frame, world, out),
            Self::Cia402(d) => d.iter_mut().for_each(|d| d.handle(t, frame, world, out)),
        }
    }

    pub fn poll(&mut self, t: f64, world: &mut World, out: &mut Vec<CanFrame>) {
        match self {
            Self::Board(b) => b.poll(t, world, out),
            Self::Cia402(d) => d.iter_mut().for_each(|d| d.poll(t, world, out)),
        }
    }

    pub fn next_event(&self) -> f64 {
        match self {
            Self::Board(b) => b.next_event(),
            Self::Cia402(d) => d[0].next_event().min(d[1].next_event()),
        }
    }
}

/// Every vehicle's motors on the one bus (0: the robot's). Each hears every frame on the
/// bus and moves its own vehicle's wheels. A vehicle whose own CAN link is lost
/// (`link_lost_at`) neither hears the bus nor is heard on it from then on: its motors run
/// on, and their command timeout stops the wheels.
#[derive(Debug)]
pub struct FleetMotors {
    motors: Vec<Motors>,
    link_lost_at: Vec<f64>,
    /// What a vehicle whose link is lost sends: to no one.
    unheard: Vec<CanFrame>,
}

impl FleetMotors {
    /// `kinds[k]` for vehicle k; the robot's motors play `plan`'s faults, the others none.
    /// `link_lost_at[k]`: when vehicle k's link fails (infinite: never).
    pub fn new(kinds: &[MotorKind], plan: &FaultPlan, link_lost_at: Vec<f64>) -> Self {
        let none = FaultPlan::default();
        let motors = kinds.iter().enumerate().map(|(k, &kind)| Motors::new(kind, if k == 0 { plan } else { &none }));
        Self { motors: motors.collect(), link_lost_at, unheard: Vec::new() }
    }

    /// The robot's motors.
    pub fn robot(&mut self) -> &mut Motors {
        &mut self.motors[0]
    }

    fn linked(&self, k: usize, t: f64) -> bool {
        self.link_lost_at.get(k).is_none_or(|&at| t < at)
    }

    pub fn boot(&mut self, t: f64, fleet: &mut Fleet, out: &mut Vec<CanFrame>) {
        for (k, m) in self.motors.iter_mut().enumerate() {
            m.boot(t, fleet.world_mut(k), out);
        }
    }

    /// A frame on the bus at `t`, to every vehicle that hears it.
    pub fn handle(&mut self, t: f64, frame: &CanFrame, fleet: &mut Fleet, out: &mut Vec<CanFrame>) {
        for k in 0..self.motors.len() {
            if self.linked(k, t) {
                self.motors[k].handle(t, frame, fleet.world_mut(k), out);
            }
        }
    }

    pub fn poll(&mut self, t: f64, fleet: &mut Fleet, out: &mut Vec<CanFrame>) {
        for k in 0..self.motors.len() {
            let to = if self.linked(k, t) { &mut *out } else { &mut self.unheard };
            self.motors[k].poll(t, fleet.world_mut(k), to);
        }
        self.unheard.clear();
    }

    pub fn next_event(&self) -> f64 {
        self.motors.iter().map(Motors::next_event).fold(f64::INFINITY, f64::min)
    }
}
