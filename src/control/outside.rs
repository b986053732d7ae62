//! Commands from a planner outside flowgate (a ROS 2 node's `cmd_vel`, a line on the
//! control socket): the latest one held with its time, its age judged each cycle, and its
//! wheel speeds within the robot's limits. The supervisor checks them as it checks the
//! field's (`step.rs`): whoever made a command, it goes through one supervisor.

use super::drive::{DriveConfig, WheelSpeeds};

/// Where the robot's commands come from (`planner.method`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CommandSource {
    /// The hydrodynamic field (the default).
    Field,
    /// A baseline: straight at the goal, turning toward it, the supervisor alone in the
    /// way of what is there.
    Straight,
    /// A baseline: the robot as an ORCA agent (`control::orca`), the supervisor behind it.
    Orca,
    /// A baseline: the robot as a social-force pedestrian (`control::social_force`), the
    /// supervisor behind it.
    SocialForce,
    /// A planner outside flowgate; a command older than `max_age` s stops the robot.
    Outside { max_age: f64 },
}

/// A velocity command from outside.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OutsideCommand {
    /// The robot's forward speed, m/s, and turn rate, rad/s (counter-clockwise positive).
    Twist { v: f64, w: f64 },
    /// The wheels' rim speeds, m/s.
    Wheels { left: f64, right: f64 },
}

impl OutsideCommand {
    pub fn is_finite(self) -> bool {
        match self {
            Self::Twist { v, w } => v.is_finite() && w.is_finite(),
            Self::Wheels { left, right } => left.is_finite() && right.is_finite(),
        }
    }

    /// Its wheel speeds, scaled down together (the turn kept) so that neither wheel
    /// exceeds the drive's limit nor the centre `max_speed`; whether it had to be.
    pub fn wheels(self, drive: &DriveConfig, max_speed: f64) -> (WheelSpeeds, bool) {
        let (left, right) = match self {
            Self::Twist { v, w } => (v - w * drive.wheel_base / 2.0, v + w * drive.wheel_base / 2.0),
            Self::Wheels { left, right } => (left, right),
        };
        let wheel = left.abs().max(right.abs()) / drive.max_wheel_speed;
        let centre = ((left + right) / 2.0).abs() / max_speed;
        let scale = wheel.max(centre);
        if scale > 1.0 {
            (WheelSpeeds { left: left / scale, right: right / scale }, true)
        } else {
            (WheelSpeeds { left, right }, false)
        }
    }
}

/// The latest outside command and since when the robot has been asked to drive on them.
#[derive(Debug, Clone, Copy, Default)]
pub struct OutsideCommands {
    latest: Option<(f64, OutsideCommand)>,
    /// When driving started (the operator's `start`): the age of a command is counted from
    /// no earlier than this, so a policy has `max_age` to send its first.
    since: f64,
}

impl OutsideCommands {
    /// A command taken at `t`.
    pub fn take(&mut self, t: f64, command: OutsideCommand) {
        self.latest = Some((t, command));
    }

    /// Driving starts (or starts again) at `t`.
    pub fn start(&mut self, t: f64) {
        self.since = t;
    }

    /// The command to drive on at `t`, or `None` when the latest is older than `max_age`.
    /// Until the first comes, the robot holds still, for `max_age` from the start.
    pub fn current(&self, t: f64, max_age: f64) -> Option<OutsideCommand> {
        let (at, command) = self.latest.unwrap_or((self.since, OutsideCommand::Twist { v: 0.0, w: 0.0 }));
        (t - at.max(self.since) <= max_age).then_some(command)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drive() -> DriveConfig {
        DriveConfig {
            wheel_base: 0.2,
            wheel_radius: 0.03,
            steps_per_rev: 200,
            microsteps: 8,
            max_wheel_speed: 0.25,
            steering_gain: 1.0,
            sample_time: 0.017,
        }
    }

    #[test]
    fn a_twist_is_its_wheels_and_beyond_the_limits_scaled_with_its_turn() {
        let (w, saturated) = OutsideCommand::Twist { v: 0.1, w: 0.5 }.wheels(&drive(), 0.15);
        assert!(!saturated);
        assert!((w.left - 0.05).abs() < 1e-12 && (w.right - 0.15).abs() < 1e-12, "{w:?}");
        let (w, saturated) = OutsideCommand::Twist { v: 1.0, w: 0.0 }.wheels(&drive(), 0.15);
        assert!(saturated && (w.left - 0.15).abs() < 1e-12 && (w.right - 0.15).abs() < 1e-12, "{w:?}");
        let (w, saturated) = OutsideCommand::Wheels { left: -1.0, right: 1.0 }.wheels(&drive(), 0.15);
        assert!(
            saturated && (w.left + 0.25).abs() < 1e-12 && (w.right - 0.25).abs() < 1e-12,
            "a turn on the spot: {w:?}"
        );
        assert!(!OutsideCommand::Twist { v: f64::NAN, w: 0.0 }.is_finite());
        assert!(!OutsideCommand::Wheels { left: 0.0, right: f64::INFINITY }.is_finite());
    }

    #[test]
    fn a_command_ages_from_its_arrival_or_the_start() {
        let mut c = OutsideCommands::default();
        let still = OutsideCommand::Twist { v: 0.0, w: 0.0 };
        assert_eq!(c.current(0.1, 0.2), Some(still), "none yet: hold still");
        assert_eq!(c.current(0.3, 0.2), None, "none within its age");
        let go = OutsideCommand::Twist { v: 0.1, w: 0.0 };
        c.take(1.0, go);
        assert_eq!(c.current(1.2, 0.2), Some(go));
        assert_eq!(c.current(1.21, 0.2), None, "too old");
        c.start(5.0);
        assert_eq!(c.current(5.1, 0.2), Some(go), "a start gives the policy its age again");
        assert_eq!(c.current(5.3, 0.2), None);
    }
}
