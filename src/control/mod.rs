//! Control: the per-cycle step (estimate in, pulse rates out), the safety supervisor
//! between the planner and the wheels, and the wheels' kinematics ([`drive`]). Pure in time: `t` is an argument, so the same step
//! runs live, offline, in replay and in benchmarks.

pub mod baseline;
pub mod drive;
pub mod fleet;
pub mod orca;
pub mod outside;
pub mod script;
pub mod social_force;
mod step;
pub mod supervisor;

pub use crate::track::Estimate;
pub use outside::{CommandSource, OutsideCommand};
pub use step::{ControlConfig, ControlStep, Envelope, StallConfig, StepOutput, StepStatus};
pub use supervisor::{evade, supervise, Evasion, Supervision, SupervisorConfig};
