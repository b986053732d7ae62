//! The rules every section's values are held to: bounds of plausibility, and the error that
//! names the key.

use std::path::Path;
use std::time::Duration;

/// Longest watchdog accepted, ms: a minute. Longer is a typo, not a rig.
pub(super) const MAX_WATCHDOG_MS: u32 = 60_000;
/// The largest config (or scenario) file read, bytes: real ones are a few kB.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Read a text file of at most `limit` bytes. A larger one, or an endless one (a device, a
/// pipe), is refused having read `limit` + 1 bytes of it.
pub fn read_text(path: &Path, limit: u64) -> std::io::Result<String> {
    use std::io::Read;
    let mut text = String::new();
    std::fs::File::open(path)?.take(limit + 1).read_to_string(&mut text)?;
    if text.len() as u64 > limit {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("longer than {limit} bytes, far beyond any real one: refused"),
        ));
    }
    Ok(text)
}

/// A bad value: its key and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("`{key}` {why}")]
pub struct Invalid {
    pub key: String,
    pub why: String,
}

pub(super) fn invalid<T>(key: &str, why: impl Into<String>) -> Result<T, Invalid> {
    Err(Invalid { key: key.to_string(), why: why.into() })
}

/// An upper bound of plausibility, with its unit: far beyond any rig a PSD camera watches,
/// a value is a typo (a wheel base of 1e308 m) that would only turn into infinities later.
#[derive(Debug, Clone, Copy)]
pub(super) struct Most(pub(super) f64, pub(super) &'static str);

/// A body's or a noise's size, m.
pub(super) const BODY: Most = Most(2.0, "m");
/// A speed, m/s; an acceleration, m/s².
pub(super) const SPEED: Most = Most(10.0, "m/s");
pub(super) const ACCEL: Most = Most(100.0, "m/s²");
/// A gain of the planner's (dimensionless).
pub(super) const GAIN: Most = Most(1e6, "");
/// The largest goal tolerance, m (a goal set by an operator or a config).
pub const MAX_GOAL_TOLERANCE: f64 = 1.0;

/// A number as an error shows it: huge and tiny ones in exponent form, not 300 digits.
pub fn shown(v: f64) -> String {
    if v != 0.0 && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        v.to_string()
    }
}

pub(super) fn at_most(key: &str, v: f64, Most(most, unit): Most) -> Result<(), Invalid> {
    if v > most {
        let unit = if unit.is_empty() { String::new() } else { format!(" {unit}") };
        invalid(key, format!("must be at most {most}{unit}, is {}", shown(v)))
    } else {
        Ok(())
    }
}

pub(super) fn positive(key: &str, v: f64, most: Most) -> Result<(), Invalid> {
    if v.is_finite() && v > 0.0 {
        at_most(key, v, most)
    } else {
        invalid(key, format!("must be a positive number, is {v}"))
    }
}

pub(super) fn non_negative(key: &str, v: f64, most: Most) -> Result<(), Invalid> {
    if v.is_finite() && v >= 0.0 {
        at_most(key, v, most)
    } else {
        invalid(key, format!("must be a number >= 0, is {v}"))
    }
}

pub(super) fn ms(v: u32) -> Duration {
    Duration::from_millis(u64::from(v))
}
