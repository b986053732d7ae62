//! The motor side of the simulated rig: one PCL-80K-like board for both wheels, or one
//! CiA 402 drive a wheel. Either takes the bus's frames and the time, and moves the world's
//! wheels.

use flowgate_protocol::{canopen, motor, CanFrame};

use crate::cia402_drive::Cia402Drive;
use crate::faults::FaultPlan;
use crate::motor_board::MotorBoard;
use crate::world::{World, LEFT, RIGHT};

/// Which motor firmware the rig runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotorKind {
    /// One PCL-80K-like board at this node.
    Board(motor::NodeId),
    /// One CiA 402 drive a wheel, at these nodes.
    Cia402 { left: canopen::NodeId, right: canopen::NodeId },
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
