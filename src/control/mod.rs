//! Control: the per-cycle step (estimate in, pulse rates out). Pure in time: `t` is an
//! argument, so the same step runs live, offline, in replay and in benchmarks.

mod step;

pub use crate::track::Estimate;
pub use step::{ControlConfig, ControlStep, StallConfig, StepOutput, StepStatus};
