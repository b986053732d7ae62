//! flowgate: the gateway between a PSD camera controller (serial) and pulse-motor boards
//! (CAN) that steers a mobile robot around moving obstacles.
//!
//! Modules follow the data flow of one sample cycle:
//! [`track`] (robot pose and obstacle motion) -> [`planner`] (navigation function, wheel
//! speeds, pulse rates) -> [`control`] (the control step). [`offline`] closes the loop
//! around the simulator's world in virtual time.

pub mod bench;
pub mod calib;
pub mod config;
pub mod control;
pub mod demo;
pub mod gateway;
pub mod link;
pub mod offline;
pub mod planner;
pub mod report;
pub mod track;

pub use num_complex::Complex64 as Point;
