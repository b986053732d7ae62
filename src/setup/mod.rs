//! The tools of a rig's first day, beside the gateway: the preflight ([`check`]) and the
//! camera calibration ([`calibrate`]). Both talk to the PSD controller through the gateway's
//! own sans-I/O session ([`psd_client`]), so they meet the rig exactly as the gateway will.

pub mod calibrate;
pub mod check;
pub mod psd_client;
