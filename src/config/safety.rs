//! `[safety]`: the gateway's watchdogs and the supervisor's limits.

use super::checks::{invalid, ms, Invalid, MAX_WATCHDOG_MS};
use crate::control::StallConfig;
use serde::{Deserialize, Serialize};
use std::time::Duration;

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SafetySection {
    /// Stop when the robot's pose has not been seen for this long, ms.
    #[serde(default = "default_pose_timeout")]
    pub pose_timeout_ms: u32,
    /// Stop when more bad serial frames than this arrive within one second.
    #[serde(default = "default_bad_budget")]
    pub bad_frames_per_s: u32,
    /// Stop when the motor board's heartbeat is missing for this long, ms.
    #[serde(default = "default_heartbeat_timeout")]
    pub heartbeat_timeout_ms: u32,
    /// Stop when no sample arrives for this long, ms (serial line dead).
    #[serde(default = "default_sample_timeout")]
    pub sample_timeout_ms: u32,
    /// How far a robot pose may be off what the rig allows (the LEDs' mounted spacing, the
    /// distance the robot can drive since the last pose) before it is discarded, m.
    #[serde(default = "default_pose_tolerance")]
    pub pose_tolerance_m: f64,
    /// Stop when a tracked obstacle stays unseen inside the view for this long, ms. Past the
    /// pose timeout it is avoided as the region it may have reached; an obstacle seen
    /// leaving the view is dropped instead.
    #[serde(default = "default_occlusion_timeout")]
    pub occlusion_timeout_ms: u32,
    /// The fastest any obstacle on the rig moves, m/s: how fast an unseen obstacle's region
    /// grows.
    #[serde(default = "default_max_obstacle_speed")]
    pub max_obstacle_speed: f64,
    /// Stop, "stalled (no progress)", when the robot has moved less than
    /// `stall_progress_m` in this long while driving, ms.
    #[serde(default = "default_stall_window")]
    pub stall_window_ms: u32,
    #[serde(default = "default_stall_progress")]
    pub stall_progress_m: f64,
    /// How an orderly stop brings a vehicle's wheels down (unset: `arc` on a rig with
    /// `[[vehicles]]`, `each-wheel` for a single robot).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stop_brake: Option<StopBrake>,
}

/// How an orderly stop (the operator's, a goal reached, a stall) or a wait brings a
/// vehicle's wheels down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum StopBrake {
    /// Both wheels lowered together until the centre stands, then both to zero: the
    /// vehicle holds its turn and stays on the arc its supervisor certified.
    Arc,
    /// Zero to each wheel at once: each board ramps its own wheel down, so a turning
    /// vehicle pivots off its arc, by up to `(v_r - v_l)² / 8a` along its way.
    EachWheel,
}

pub(super) fn default_stall_window() -> u32 {
    (StallConfig::default().window * 1e3) as u32
}
pub(super) fn default_stall_progress() -> f64 {
    StallConfig::default().min_progress
}
/// The longest stall window: an hour.
pub(super) const MAX_STALL_WINDOW_MS: u32 = 3_600_000;

pub(super) fn default_occlusion_timeout() -> u32 {
    1000
}
pub(super) fn default_max_obstacle_speed() -> f64 {
    0.5
}

pub(super) fn default_pose_tolerance() -> f64 {
    0.02
}

pub(super) fn default_pose_timeout() -> u32 {
    150
}
pub(super) fn default_bad_budget() -> u32 {
    20
}
pub(super) fn default_heartbeat_timeout() -> u32 {
    400
}
pub(super) fn default_sample_timeout() -> u32 {
    100
}

impl Default for SafetySection {
    fn default() -> Self {
        Self {
            pose_timeout_ms: default_pose_timeout(),
            bad_frames_per_s: default_bad_budget(),
            heartbeat_timeout_ms: default_heartbeat_timeout(),
            sample_timeout_ms: default_sample_timeout(),
            pose_tolerance_m: default_pose_tolerance(),
            occlusion_timeout_ms: default_occlusion_timeout(),
            max_obstacle_speed: default_max_obstacle_speed(),
            stall_window_ms: default_stall_window(),
            stall_progress_m: default_stall_progress(),
            stop_brake: None,
        }
    }
}

/// The fastest obstacle speed a config may give, m/s (a running person is about 5).
pub(super) const MAX_OBSTACLE_SPEED: f64 = 10.0;
impl SafetySection {
    /// The watchdogs, against each other and against the board's command timeout.
    pub(super) fn validate(&self, sample_period: Duration, board_timeout_ms: u16) -> Result<(), Invalid> {
        for (key, v) in [
            ("safety.pose_timeout_ms", self.pose_timeout_ms),
            ("safety.heartbeat_timeout_ms", self.heartbeat_timeout_ms),
            ("safety.sample_timeout_ms", self.sample_timeout_ms),
            ("safety.occlusion_timeout_ms", self.occlusion_timeout_ms),
        ] {
            if v == 0 || v > MAX_WATCHDOG_MS {
                return invalid(key, format!("must be 1-{MAX_WATCHDOG_MS} ms, is {v}"));
            }
        }
        if !(self.pose_tolerance_m.is_finite() && self.pose_tolerance_m > 0.0 && self.pose_tolerance_m <= 1.0) {
            return invalid("safety.pose_tolerance_m", format!("must be 0-1 m, is {}", self.pose_tolerance_m));
        }
        if self.occlusion_timeout_ms <= self.pose_timeout_ms {
            return invalid(
                "safety.occlusion_timeout_ms",
                format!(
                    "{} ms must exceed safety.pose_timeout_ms = {} ms: an obstacle is judged occluded only past the pose timeout",
                    self.occlusion_timeout_ms, self.pose_timeout_ms
                ),
            );
        }
        if !(self.max_obstacle_speed.is_finite()
            && self.max_obstacle_speed > 0.0
            && self.max_obstacle_speed <= MAX_OBSTACLE_SPEED)
        {
            return invalid(
                "safety.max_obstacle_speed",
                format!("must be 0-{MAX_OBSTACLE_SPEED} m/s, is {}", self.max_obstacle_speed),
            );
        }
        if !(100..=MAX_STALL_WINDOW_MS).contains(&self.stall_window_ms) {
            return invalid(
                "safety.stall_window_ms",
                format!("must be 100-{MAX_STALL_WINDOW_MS} ms, is {}", self.stall_window_ms),
            );
        }
        if !(self.stall_progress_m.is_finite() && self.stall_progress_m > 0.0 && self.stall_progress_m <= 1.0) {
            return invalid("safety.stall_progress_m", format!("must be 0-1 m, is {}", self.stall_progress_m));
        }
        // Without samples or a fresh pose the gateway sends no command, and the board stops
        // by itself after its command timeout. The gateway's own watchdog must fire first,
        // with a cycle to spare, so the stop is named by its cause (serial, pose), not as a
        // board fault.
        let board_timeout = ms(board_timeout_ms.into());
        for (key, v) in
            [("safety.sample_timeout_ms", self.sample_timeout_ms), ("safety.pose_timeout_ms", self.pose_timeout_ms)]
        {
            if ms(v) + sample_period > board_timeout {
                return invalid(
                    key,
                    format!(
                        "{v} ms plus the period T = {} µs exceeds drive.command_timeout_ms = {} ms: the board would \
                         stop the robot before the gateway names the cause",
                        sample_period.as_micros(),
                        board_timeout_ms
                    ),
                );
            }
        }
        Ok(())
    }

    /// The watchdogs' settings; `fleet`: the rig has other vehicles (the stop's brake
    /// defaults to `arc`).
    pub(super) fn settings(&self, fleet: bool) -> SafetySettings {
        let brake_default = if fleet { StopBrake::Arc } else { StopBrake::EachWheel };
        SafetySettings {
            stop_brake: self.stop_brake.unwrap_or(brake_default),
            pose_timeout: ms(self.pose_timeout_ms),
            bad_frames_per_s: self.bad_frames_per_s,
            heartbeat_timeout: ms(self.heartbeat_timeout_ms),
            sample_timeout: ms(self.sample_timeout_ms),
            pose_tolerance: self.pose_tolerance_m,
            occlusion_timeout: ms(self.occlusion_timeout_ms),
        }
    }
}

/// The gateway's watchdogs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafetySettings {
    pub pose_timeout: Duration,
    pub bad_frames_per_s: u32,
    pub heartbeat_timeout: Duration,
    pub sample_timeout: Duration,
    pub pose_tolerance: f64,
    pub occlusion_timeout: Duration,
    pub stop_brake: StopBrake,
}
