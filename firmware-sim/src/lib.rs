//! flowgate-sim: the simulated rig.
//!
//! It depends on `flowgate-protocol` only: like real firmware, it knows nothing of the
//! gateway and speaks only the wire protocols. The world model here (robot kinematics
//! driven by step pulses, scripted obstacles, clearance against the true radii) is shared
//! by the real-time simulator and by the gateway's offline scenario runner, so both judge
//! a run by the same truth.
//!
//! Points in the plane are `Complex64` (`x + i y`, metres): the planner works in the
//! complex plane, and so does the world, to keep one convention.

pub mod camera;
pub mod cia402_drive;
pub mod faults;
pub mod motor_board;
pub mod motors;
pub mod psd_controller;
pub mod rig;
pub mod scenario;
pub mod slcan_adapter;
pub mod truth;
pub mod world;

pub use flowgate_protocol::plane::{wrap_angle, Point};
