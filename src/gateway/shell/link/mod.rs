//! Links to the rig: the PSD controller's serial line and the motor boards' CAN bus.
//!
//! CAN backends sit behind one enum, [`CanLink`], selected by a URL-like string
//! ([`crate::config::CanUrl`]): `socketcan:can0` or `slcan:/dev/ttyACM0?bitrate=1000000`; builds with the
//! lab tools also know `memory`, an in-process bus for tests.

mod can;
#[cfg(feature = "lab")]
pub mod memory;
mod serial;

pub use can::{interface_down, open_can, slcan_event, CanError, CanLink, SlcanLink, SocketCanLink};
pub use serial::{open_serial, SerialError};
