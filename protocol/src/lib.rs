//! # flowgate-protocol
//!
//! The wire formats of a flowgate rig, and the floor plane ([`plane`]) that both its ends,
//! the gateway and the simulator, reckon in: no I/O, no allocation, no clock.
//!
//! | module    | link                                   | framing                              |
//! |-----------|----------------------------------------|--------------------------------------|
//! | [`psd`]   | host <-> PSD camera controller, serial | COBS, 0x00 delimiter, CRC-16/IBM-3740 |
//! | [`motor`] | gateway <-> pulse-motor boards, CAN    | CAN 2.0A, 11-bit ids, node ids 1-15  |
//! | [`slcan`] | host <-> USB-CAN adapter, serial       | LAWICEL ASCII lines, CR / BEL        |
//! | [`canopen`] | gateway <-> CiA 402 drives, CAN      | CANopen (CiA 301), node ids 1-127    |
//!
//! Every message is a plain Rust value (a "repr", after smoltcp) with `parse` from bytes and
//! `emit` into a caller's buffer. The byte layouts are drawn in `protocol/README.md` and in
//! each module's documentation.
//!
//! ## No-panic contract
//!
//! Every function that reads bytes from outside (`parse`, `decode`, the streaming codecs)
//! returns an error for any input it cannot accept and never panics, whatever the bytes.
//! Emitting into a buffer that is too small is an error too, never a panic. The fuzz
//! targets in `protocol/fuzz/` hold the decoders to this.
//!
//! ## Features
//!
//! - `std` (default): `std::error::Error` for the error types, `num-complex`'s `std`. Without
//!   it the crate is `no_std`.
//! - `codec`: `tokio_util::codec` decoders/encoders ([`codec`]) that yield a bad frame as an
//!   error item and carry on, resynchronise after garbage, and count what they dropped.
//! - `socketcan`: `From`/`TryFrom` between [`CanFrame`] and `socketcan::CanFrame`.
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]

pub mod can;
pub mod canopen;
pub mod cobs;
pub mod crc;
pub mod motor;
pub mod plane;
pub mod psd;
pub mod slcan;
mod wire;

#[cfg(feature = "codec")]
pub mod codec;

#[cfg(feature = "socketcan")]
pub mod socketcan_frames;

pub use can::{CanFrame, CanId};
