//! Links to the rig: the PSD controller's serial line and the motor boards' CAN bus.
//!
//! CAN backends sit behind one enum, [`CanLink`], selected by a URL-like string
//! ([`CanUrl`]): `socketcan:can0`, `slcan:/dev/ttyACM0?bitrate=1000000`, or `memory`
//! (an in-process bus for unit tests only).

mod can;
mod serial;

pub use can::{
    interface_down, open_can, slcan_event, CanError, CanEvent, CanLink, CanUrl, MemoryBus, MemoryLink, SlcanLink,
    SocketCanLink,
};
pub use serial::{open_serial, SerialError};
