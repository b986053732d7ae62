//! flowgate: the gateway between a PSD camera controller (serial) and pulse-motor boards
//! (CAN) that steers a mobile robot around moving obstacles.
//!
//! Modules follow the data flow of one sample cycle:
//! [`gateway`] (its shell's links, serial and CAN; the core: PSD session, tracking,
//! control, safety; and the tokio shell) -> [`calibration`] (PSD counts to floor) -> [`track`]
//! (robot pose and obstacle motion) -> [`control`] and [`planner`] (navigation function,
//! wheel speeds, pulse rates), on [`geometry`]'s lengths and rotations. [`config`] parses the rig once into a typed [`config::Rig`];
//! [`time`] keeps host and controller clocks apart. [`setup`] holds the tools of a rig's
//! first day: the preflight check and the calibration. The lab tools ([`lab`]: the simulator
//! in virtual and real time, sweeps, plots, the benchmark) are behind the `lab` feature, so
//! the deployed gateway never contains the simulator.

pub mod calibration;
pub mod config;
pub mod control;
pub mod gateway;
pub mod geometry;
#[cfg(feature = "lab")]
pub mod lab;
pub mod planner;
pub mod replay;
pub mod setup;
pub mod svg;
pub mod time;
pub mod track;

pub use flowgate_protocol::plane::{wrap_angle, Point};
