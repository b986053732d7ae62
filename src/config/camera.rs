//! `[serial]`, `[leds]`, `[schedule]` and `[calibration]`: the PSD camera, its LEDs and how
//! their positions map to the floor.

use super::checks::{invalid, non_negative, positive, Invalid, BODY};
use crate::planner::MAX_OBSTACLES;
use flowgate_protocol::psd::{LedSlot, Schedule, MAX_SCHEDULE_LEDS};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SerialSection {
    pub port: PathBuf,
    #[serde(default = "default_baud")]
    pub baud: u32,
}

pub(super) fn default_baud() -> u32 {
    921_600
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LedSection {
    pub robot_front: u8,
    pub robot_rear: u8,
    /// Distance of the front LED ahead of the robot's centre, m.
    pub front_offset: f64,
    /// Distance of the rear LED behind the robot's centre, m.
    pub rear_offset: f64,
    #[serde(default)]
    pub obstacles: Vec<ObstacleLed>,
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleLed {
    pub led: u8,
    /// The obstacle's radius `a_0`, m.
    pub radius: f64,
    /// Whether the gateway may arm only once this LED has been seen. By default an obstacle
    /// not seen yet is absent (parked outside the arena, not switched on) and is avoided
    /// from its first sample.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub required: bool,
}

/// The time-division schedule: each LED's slot (`slot_us`), or the whole frame
/// (`frame_us`, split over the LEDs to the microsecond so the period is exact).
#[derive(Debug, Clone, Copy, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduleSection {
    /// Each LED's slot, µs (default 4000 when `frame_us` is not given).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slot_us: Option<u32>,
    /// The whole frame, µs, dark slot included: the control period T.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_us: Option<u32>,
    /// Dark slot for ambient subtraction, µs; 0 = none.
    #[serde(default)]
    pub dark_slot_us: u16,
    #[serde(default = "default_one")]
    pub averaging: u8,
}

pub(super) fn default_one() -> u8 {
    1
}

pub(super) const DEFAULT_SLOT_US: u32 = 4000;

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSection {
    /// Floor metres -> PSD counts, row-major. Either this or `points`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub homography: Option<[[f64; 3]; 3]>,
    /// Reference points measured on the rig, fitted by least squares (at least 4).
    #[serde(default)]
    pub points: Vec<RefPoint>,
    #[serde(default)]
    pub k1: f64,
    #[serde(default = "default_counts")]
    pub counts: u16,
}

pub(super) fn default_counts() -> u16 {
    4096
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RefPoint {
    pub raw: [f64; 2],
    pub floor: [f64; 2],
}

impl SerialSection {
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        if self.baud == 0 {
            return invalid("serial.baud", "must be positive");
        }
        if self.port.as_os_str().is_empty() {
            return invalid("serial.port", "is empty");
        }
        Ok(())
    }
}

impl LedSection {
    /// The LEDs' ids in firing order: the robot's two, then the obstacles'.
    pub(super) fn validate(&self) -> Result<Vec<u8>, Invalid> {
        if self.robot_front == self.robot_rear {
            return invalid("leds.robot_rear", format!("must differ from leds.robot_front ({})", self.robot_front));
        }
        non_negative("leds.front_offset", self.front_offset, BODY)?;
        non_negative("leds.rear_offset", self.rear_offset, BODY)?;
        positive("leds.front_offset", self.front_offset + self.rear_offset, BODY)?;
        // Counted first: a list of thousands is refused before its entries are looked at.
        let most = MAX_OBSTACLES.min(MAX_SCHEDULE_LEDS - 2);
        if self.obstacles.len() > most {
            return invalid(
                "leds.obstacles",
                format!(
                    "{} obstacles ({} LEDs in all): at most {most} obstacles and {MAX_SCHEDULE_LEDS} LEDs",
                    self.obstacles.len(),
                    self.obstacles.len() + 2,
                ),
            );
        }
        let mut ids = vec![self.robot_front, self.robot_rear];
        for (i, o) in self.obstacles.iter().enumerate() {
            if ids.contains(&o.led) {
                return invalid(&format!("leds.obstacles[{i}].led"), format!("LED {} is used twice", o.led));
            }
            ids.push(o.led);
            positive(&format!("leds.obstacles[{i}].radius"), o.radius, BODY)?;
        }
        Ok(ids)
    }
}

impl ScheduleSection {
    /// The schedule for `leds` in firing order.
    pub(super) fn build(&self, leds: &[u8]) -> Result<Schedule, Invalid> {
        let n = leds.len() as u32;
        let slots: Vec<u32> = match (self.slot_us, self.frame_us) {
            (Some(_), Some(_)) => return invalid("schedule", "give `slot_us` or `frame_us`, not both"),
            (slot, None) => vec![slot.unwrap_or(DEFAULT_SLOT_US); leds.len()],
            (None, Some(frame)) => {
                let lit =
                    frame.checked_sub(u32::from(self.dark_slot_us)).filter(|&lit| lit >= n).ok_or_else(|| Invalid {
                        key: "schedule.frame_us".into(),
                        why: format!("{frame} µs leaves less than 1 µs per LED after the dark slot"),
                    })?;
                // The remainder goes one microsecond at a time to the first slots: exact T.
                (0..n).map(|i| lit / n + u32::from(i < lit % n)).collect()
            }
        };
        let key = if self.frame_us.is_some() { "schedule.frame_us" } else { "schedule.slot_us" };
        let mut wire = Vec::with_capacity(leds.len());
        for (&led, &us) in leds.iter().zip(&slots) {
            let slot_us = u16::try_from(us).ok().filter(|&us| us > 0).ok_or_else(|| Invalid {
                key: key.into(),
                why: format!("a slot of {us} µs is outside 1-{} µs", u16::MAX),
            })?;
            wire.push(LedSlot { led, slot_us });
        }
        if self.averaging == 0 {
            return invalid("schedule.averaging", "must be at least 1");
        }
        Schedule::new(&wire, self.dark_slot_us, self.averaging).or_else(|e| invalid(key, e.to_string()))
    }
}
