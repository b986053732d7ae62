//! `[can]`, `[cia402]` and `[drive]`: the motors and how the gateway drives them.

use super::can_url::CanUrl;
use super::checks::{invalid, ms, positive, Invalid, ACCEL, BODY, MAX_WATCHDOG_MS, SPEED};
use super::safety::SafetySection;
use flowgate_protocol::canopen;
use flowgate_protocol::motor::{NodeId, MAX_U24};
use serde::{Deserialize, Serialize};
use std::time::Duration;

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CanSection {
    /// `socketcan:can0`, `slcan:/dev/ttyACM0?bitrate=1000000`.
    pub endpoint: String,
    /// What the motors speak: one PCL-80K-like board for both wheels (the default), or one
    /// CiA 402 drive a wheel (`[cia402]`).
    #[serde(default)]
    pub protocol: MotorProtocolName,
    /// The motor board's node id, 1-15.
    #[serde(default = "default_node")]
    pub node: u8,
}

pub(super) fn default_node() -> u8 {
    1
}

/// `can.protocol`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MotorProtocolName {
    #[default]
    Pcl80k,
    Cia402,
}

/// How long a CiA 402 drive waits for the gateway's heartbeat before it stops itself, ms
/// (its consumer heartbeat time, 0x1016, written at configuration).
pub const CIA402_CONSUMER_TIME_MS: u32 = 300;

/// `[cia402]`: one CiA 402 drive a wheel, in profile velocity mode (docs/cia402.md).
#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Cia402Section {
    /// The left and right wheels' drives' node ids, 1-127.
    pub left_node: u8,
    pub right_node: u8,
    /// The gateway's own node id: its heartbeat is `0x700 +` this, consumed by the drives.
    #[serde(default = "default_gateway_node")]
    pub gateway_node: u8,
    /// How long each configuration SDO may go unanswered, ms.
    #[serde(default = "default_sdo_timeout")]
    pub sdo_timeout_ms: u32,
    /// From the arm, how long the drives may take to reach operation enabled, ms.
    #[serde(default = "default_enable_timeout")]
    pub enable_timeout_ms: u32,
    /// Each drive's heartbeat period (0x1017), ms.
    #[serde(default = "default_drive_heartbeat")]
    pub heartbeat_ms: u16,
    /// Each drive's TPDO event timer (statusword, velocity, position), ms.
    #[serde(default = "default_report")]
    pub report_ms: u16,
    /// Drive velocity units per pulse (microstep) a second; accelerations take the same
    /// unit per second. 1 when the drive counts in microsteps.
    #[serde(default = "default_velocity_scale")]
    pub velocity_scale: f64,
    /// The wheels' quick-stop deceleration (e-stop), m/s².
    #[serde(default = "default_quick_stop_decel")]
    pub quick_stop_decel: f64,
}

pub(super) fn default_gateway_node() -> u8 {
    127
}
pub(super) fn default_sdo_timeout() -> u32 {
    100
}
pub(super) fn default_enable_timeout() -> u32 {
    1000
}
pub(super) fn default_drive_heartbeat() -> u16 {
    100
}
pub(super) fn default_report() -> u16 {
    10
}
pub(super) fn default_velocity_scale() -> f64 {
    1.0
}
pub(super) fn default_quick_stop_decel() -> f64 {
    4.0
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DriveSection {
    pub wheel_radius: f64,
    pub steps_per_rev: u32,
    pub microsteps: u32,
    pub wheel_base: f64,
    /// Wheel rim speed limit, m/s (sent to the board as its rate limit).
    pub max_wheel_speed: f64,
    /// Wheel acceleration ramp, m/s² (sent to the board).
    pub wheel_accel: f64,
    /// The board's command timeout, ms: the board stops by itself after this silence. The
    /// last line of defence (the gateway's own watchdogs must fire first, checked at load).
    #[serde(default = "default_cmd_timeout")]
    pub command_timeout_ms: u16,
}

pub(super) fn default_cmd_timeout() -> u16 {
    200
}

/// The finest microstepping of a stepper driver, and the most full steps per revolution.
pub(super) const MAX_MICROSTEPS: u32 = 256;
pub(super) const MAX_STEPS_PER_REV: u32 = 10_000;

impl CanSection {
    pub(super) fn validate(&self) -> Result<(CanUrl, NodeId), Invalid> {
        let can: CanUrl = self.endpoint.parse().or_else(|e: String| invalid("can.endpoint", e))?;
        let Some(node) = NodeId::new(self.node) else {
            return invalid("can.node", format!("must be 1-15, is {}", self.node));
        };
        Ok((can, node))
    }
}

impl Cia402Section {
    /// Drives at `left` and `right`, every other key at its default.
    pub fn with_nodes(left: u8, right: u8) -> Self {
        Self {
            left_node: left,
            right_node: right,
            gateway_node: default_gateway_node(),
            sdo_timeout_ms: default_sdo_timeout(),
            enable_timeout_ms: default_enable_timeout(),
            heartbeat_ms: default_drive_heartbeat(),
            report_ms: default_report(),
            velocity_scale: default_velocity_scale(),
            quick_stop_decel: default_quick_stop_decel(),
        }
    }

    /// The nodes, the timeouts against the gateway's heartbeat watchdog, the units against
    /// the drives' 32-bit objects.
    pub(super) fn settings(
        &self,
        safety: &SafetySection,
        drive: &DriveSection,
        pulses_per_metre: f64,
    ) -> Result<Cia402Settings, Invalid> {
        let node = |key: &str, v: u8| {
            canopen::NodeId::new(v).map_or_else(|| invalid(key, format!("must be 1-127, is {v}")), Ok)
        };
        let (left, right) = (node("cia402.left_node", self.left_node)?, node("cia402.right_node", self.right_node)?);
        let gateway = node("cia402.gateway_node", self.gateway_node)?;
        if left == right {
            return invalid("cia402.right_node", format!("is {}, the left wheel's drive's too", self.right_node));
        }
        if gateway == left || gateway == right {
            return invalid("cia402.gateway_node", format!("is {}, a drive's node id", self.gateway_node));
        }
        for (key, v) in
            [("cia402.sdo_timeout_ms", self.sdo_timeout_ms), ("cia402.enable_timeout_ms", self.enable_timeout_ms)]
        {
            if v == 0 || v > MAX_WATCHDOG_MS {
                return invalid(key, format!("must be 1-{MAX_WATCHDOG_MS} ms, is {v}"));
            }
        }
        // Two heartbeats at least within the gateway's watchdog, so one lost is no fault.
        if self.heartbeat_ms == 0 || 2 * u32::from(self.heartbeat_ms) > safety.heartbeat_timeout_ms {
            return invalid(
                "cia402.heartbeat_ms",
                format!(
                    "must be 1 ms to half of safety.heartbeat_timeout_ms = {} ms, is {}",
                    safety.heartbeat_timeout_ms, self.heartbeat_ms
                ),
            );
        }
        if !(1..=1000).contains(&self.report_ms) {
            return invalid("cia402.report_ms", format!("must be 1-1000 ms, is {}", self.report_ms));
        }
        if !(self.velocity_scale.is_finite() && self.velocity_scale > 0.0) {
            return invalid("cia402.velocity_scale", format!("must be positive, is {}", self.velocity_scale));
        }
        let scale = self.velocity_scale;
        let to_units = |key: &str, metres: f64| {
            let v = (metres * pulses_per_metre * scale).round();
            if v >= 1.0 && v <= f64::from(i32::MAX) {
                Ok(v as u32)
            } else {
                invalid(
                    key,
                    format!(
                        "is {v} drive units at this wheel, stepper and cia402.velocity_scale: must be 1-{}",
                        i32::MAX
                    ),
                )
            }
        };
        positive("cia402.quick_stop_decel", self.quick_stop_decel, ACCEL)?;
        Ok(Cia402Settings {
            left,
            right,
            gateway,
            sdo_timeout: ms(self.sdo_timeout_ms),
            enable_timeout: ms(self.enable_timeout_ms),
            heartbeat_ms: self.heartbeat_ms,
            report_ms: self.report_ms,
            velocity_scale: scale,
            max_velocity: to_units("drive.max_wheel_speed", drive.max_wheel_speed)?,
            accel: to_units("drive.wheel_accel", drive.wheel_accel)?,
            quick_stop_decel: to_units("cia402.quick_stop_decel", self.quick_stop_decel)?,
        })
    }
}

impl DriveSection {
    pub(super) fn validate(&self, sample_period: Duration) -> Result<(), Invalid> {
        positive("drive.wheel_radius", self.wheel_radius, BODY)?;
        positive("drive.wheel_base", self.wheel_base, BODY)?;
        positive("drive.max_wheel_speed", self.max_wheel_speed, SPEED)?;
        positive("drive.wheel_accel", self.wheel_accel, ACCEL)?;
        if self.steps_per_rev == 0 || self.microsteps == 0 {
            return invalid("drive.steps_per_rev", "steps_per_rev and microsteps must be at least 1");
        }
        if self.microsteps > MAX_MICROSTEPS {
            return invalid(
                "drive.microsteps",
                format!("must be 1-{MAX_MICROSTEPS} (what stepper drivers do), is {}", self.microsteps),
            );
        }
        if self.steps_per_rev > MAX_STEPS_PER_REV {
            return invalid("drive.steps_per_rev", format!("must be 1-{MAX_STEPS_PER_REV}, is {}", self.steps_per_rev));
        }
        if self.command_timeout_ms == 0 {
            return invalid("drive.command_timeout_ms", "must be positive");
        }
        if sample_period >= ms(self.command_timeout_ms.into()) {
            return invalid(
                "drive.command_timeout_ms",
                format!(
                    "{} ms is not longer than the control period T = {} µs: the board would stop between commands",
                    self.command_timeout_ms,
                    sample_period.as_micros()
                ),
            );
        }
        Ok(())
    }

    /// What the board is configured with, in its pulses: each must fit its 24 bits.
    pub(super) fn board_settings(&self, pulses_per_metre: f64) -> Result<BoardSettings, Invalid> {
        let to_rate = |key: &str, v: f64| {
            let rate = (v * pulses_per_metre).round();
            if rate >= 1.0 && rate <= f64::from(MAX_U24) {
                Ok(rate as u32)
            } else {
                invalid(key, format!("is {rate} pulses/s at this wheel and stepper: must be 1-{MAX_U24}"))
            }
        };
        Ok(BoardSettings {
            accel: to_rate("drive.wheel_accel", self.wheel_accel)?,
            max_rate: to_rate("drive.max_wheel_speed", self.max_wheel_speed)?,
            command_timeout_ms: self.command_timeout_ms,
        })
    }
}

/// The motors the gateway drives, as checked at load.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Motors {
    /// One PCL-80K-like board for both wheels, at [`Rig::node`](super::Rig::node).
    Pcl80k,
    /// One CiA 402 drive a wheel.
    Cia402(Cia402Settings),
}

/// `[cia402]`, typed: what the drives are configured with, in their units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cia402Settings {
    pub left: canopen::NodeId,
    pub right: canopen::NodeId,
    pub gateway: canopen::NodeId,
    pub sdo_timeout: Duration,
    pub enable_timeout: Duration,
    pub heartbeat_ms: u16,
    pub report_ms: u16,
    /// Drive velocity units per pulse a second.
    pub velocity_scale: f64,
    /// Max profile velocity (0x607F), velocity units.
    pub max_velocity: u32,
    /// Profile acceleration and deceleration (0x6083, 0x6084), velocity units per second.
    pub accel: u32,
    /// Quick-stop deceleration (0x6085), velocity units per second.
    pub quick_stop_decel: u32,
}

/// What the motor board is configured with, in its units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardSettings {
    /// Acceleration ramp, pulses/s².
    pub accel: u32,
    /// Rate limit, pulses/s.
    pub max_rate: u32,
    pub command_timeout_ms: u16,
}
