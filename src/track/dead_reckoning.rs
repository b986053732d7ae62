//! Dead reckoning from the robot's own commands along the boards' ramps.

use crate::geometry::{rotation, Length};
use crate::Point;

/// Dead reckoning from the robot's own recent commands, to bring a delayed pose up to now.
/// The wheels follow each command along the boards' ramp (both axes ramp at `accel`, as the
/// gateway configures them), so a pose is advanced by what the wheels did, not by what they
/// were told; and the wheels' speeds now are known for the supervisor.
#[derive(Debug, Clone, Default)]
pub struct DeadReckoning {
    /// The wheels' ramp, m/s² (0: they take a command at once).
    accel: f64,
    /// The wheel base the odometry was integrated with.
    wheel_base: f64,
    /// The commands, oldest first.
    commands: std::collections::VecDeque<WheelCommand>,
    /// The last prediction's motion through the newest command's span, from its start to
    /// the prediction's time: (that start, that time, the motion). The next command comes
    /// at that time, and the span's odometry is then this very motion.
    newest_span: Option<(f64, f64, Motion)>,
}

/// One command to the wheels: when, what, and where the wheels were when it came.
#[derive(Debug, Clone, Copy)]
struct WheelCommand {
    t: f64,
    target: [f64; 2],
    from: [f64; 2],
    /// When the wheels reach `target`, s (taken once: every prediction crossing the
    /// command's span asks).
    ramp_end: f64,
    /// Where the robot was when this command came, by the commands before it: filled in
    /// once the previous command's span is over and a prediction needs it.
    odometry: Option<Odometry>,
}

/// A pose in the dead reckoning's own frame (its origin is wherever the first command
/// found the robot). A prediction crosses the same finished spans every cycle; with each
/// span integrated once into this frame, the motion between any two commands is the
/// difference of their odometry, whatever the delay.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Odometry {
    position: Point,
    /// The heading as a unit complex number.
    facing: Point,
}

impl Odometry {
    const ORIGIN: Odometry = Odometry { position: Point::new(0.0, 0.0), facing: Point::new(1.0, 0.0) };

    /// This pose moved by `m` (in its own frame); the heading's direction is renormalised,
    /// so rounding cannot build up over a long run.
    fn then(self, m: Motion) -> Odometry {
        let moved = self.moved(m);
        Odometry { facing: moved.facing / moved.facing.length(), ..moved }
    }

    /// This pose moved by `m`, the heading's direction as it comes (a prediction's few
    /// steps are renormalised once, at their end).
    fn moved(self, m: Motion) -> Odometry {
        Odometry { position: self.position + self.facing * m.displacement, facing: self.facing * m.facing }
    }

    /// The motion from this pose to `to`, in this pose's frame.
    fn to(self, to: Odometry) -> Motion {
        let back = self.facing.conj();
        Motion { displacement: back * (to.position - self.position), facing: to.facing * back }
    }
}

/// A rigid motion of the robot in its own frame at the start: where it ends up, and which
/// way it then faces (a unit complex number).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Motion {
    displacement: Point,
    facing: Point,
}

impl WheelCommand {
    /// The wheels' rim speeds `dt` after this command, m/s.
    fn speeds_after(&self, dt: f64, accel: f64) -> [f64; 2] {
        if accel <= 0.0 {
            return self.target;
        }
        let step = accel * dt.max(0.0);
        [ramp(self.from[0], self.target[0], step), ramp(self.from[1], self.target[1], step)]
    }
}

/// A wheel's speed after its ramp has moved it at most `step` (m/s) from `from` toward
/// `to`: how the boards' axes follow a command.
pub fn ramp(from: f64, to: f64, step: f64) -> f64 {
    from + (to - from).clamp(-step, step)
}

/// The longest step of dead reckoning through a ramp, s: one control period. The wheel
/// speeds change linearly within it and the step is taken at their mean, which is exact in
/// distance; the arc's chord errs by the heading change's square, micrometres here.
const RAMP_STEP: f64 = 0.02;

impl DeadReckoning {
    /// Room for `n` commands before it allocates (the delay over the period, plus some);
    /// wheels that ramp at `accel` m/s² (0: at once).
    pub fn with_capacity(n: usize, accel: f64) -> Self {
        Self { accel, wheel_base: 0.0, commands: std::collections::VecDeque::with_capacity(n), newest_span: None }
    }

    /// Record the wheel speeds commanded at `t`.
    pub fn command(&mut self, t: f64, left: f64, right: f64) {
        let from = self.wheels_at(t);
        let target = [left, right];
        // The wheels reach it after the larger change at the ramp's acceleration.
        let ramp = if self.accel <= 0.0 {
            0.0
        } else {
            (target[0] - from[0]).abs().max((target[1] - from[1]).abs()) / self.accel
        };
        self.commands.push_back(WheelCommand { t, target, from, ramp_end: t + ramp, odometry: None });
    }

    /// The wheels' rim speeds at `t` as the ramps have brought them (at rest before any
    /// command), m/s: left, right.
    pub fn wheels_at(&self, t: f64) -> [f64; 2] {
        // Mostly asked for now, when the newest command is in force; else the commands are
        // in time order: a binary search, not a scan of the delay window.
        if let Some(c) = self.commands.back().filter(|c| c.t <= t) {
            return c.speeds_after(t - c.t, self.accel);
        }
        match self.commands.partition_point(|c| c.t <= t) {
            0 => [0.0; 2],
            k => {
                let c = &self.commands[k - 1];
                c.speeds_after(t - c.t, self.accel)
            }
        }
    }

    /// The wheels stopped at once (an emergency stop): forget every command.
    /// When the newest command's ramp ends (at rest from then, when it asked for rest).
    pub fn at_rest_from(&self) -> f64 {
        self.commands.back().map_or(f64::NEG_INFINITY, |c| c.ramp_end)
    }

    pub fn halt(&mut self) {
        self.commands.clear();
        self.newest_span = None;
    }

    /// Forget commands that ended before `t` (keeps the one in force at `t`).
    pub fn forget_before(&mut self, t: f64) {
        while self.commands.len() > 1 && self.commands[1].t <= t {
            self.commands.pop_front();
        }
    }

    /// The centre and the heading (a unit vector) measured at `t_valid`, advanced to `t`
    /// with the commands in force meanwhile: the two spans the window cuts are integrated,
    /// the whole ones between are taken from the odometry (see `Odometry`), so a
    /// prediction costs the same whatever the delay.
    pub fn predict(&mut self, position: Point, facing: Point, t_valid: f64, t: f64, wheel_base: f64) -> (Point, Point) {
        // The commands in force at the window's ends (none before the first command: at rest).
        // The commands are in time order: the newest is mostly the one in force now.
        let newest_in_force = self.commands.back().is_some_and(|c| c.t < t);
        let in_force = if newest_in_force { self.commands.len() } else { self.commands.partition_point(|c| c.t < t) };
        let Some(last) = in_force.checked_sub(1) else { return (position, facing) };
        // The window's start is near the front ([`DeadReckoning::forget_before`] keeps
        // the command in force a period before it): counted from there, one or two steps.
        let first = self.commands.iter().take_while(|c| c.t <= t_valid).count().saturating_sub(1).min(last);
        // Heading counted from the measured one, so the turn adds to it exactly as measured.
        let mut pose = Odometry { position, facing };
        let accel = self.accel;
        let c = self.commands[first];
        let first_end = if first == last { t } else { self.commands[first + 1].t };
        let from = c.t.max(t_valid);
        if first_end > from {
            pose = pose.moved(c.motion(from, first_end, accel, wheel_base));
        }
        if last > first {
            pose = pose.moved(self.odometry(first + 1, wheel_base).to(self.odometry(last, wheel_base)));
            let c = self.commands[last];
            let m = c.motion(c.t, t, accel, wheel_base);
            self.newest_span = Some((c.t, t, m));
            pose = pose.moved(m);
        }
        (pose.position, pose.facing / pose.facing.length())
    }

    /// Command `i`'s odometry, integrating the spans before it that have none yet.
    fn odometry(&mut self, i: usize, wheel_base: f64) -> Odometry {
        if wheel_base != self.wheel_base {
            // Integrated with another wheel base (only ever a test's doing): start afresh.
            self.wheel_base = wheel_base;
            self.commands.iter_mut().for_each(|c| c.odometry = None);
            self.newest_span = None;
        }
        // Mostly asked for one it has, or the newest, whose predecessor it has.
        if let Some(at) = self.commands[i].odometry {
            return at;
        }
        let known = self.commands.range(..=i).rposition(|c| c.odometry.is_some());
        let mut at = known.map_or(Odometry::ORIGIN, |k| self.commands[k].odometry.unwrap_or(Odometry::ORIGIN));
        for k in known.map_or(0, |k| k + 1)..=i {
            if k > 0 {
                let (c, next) = (self.commands[k - 1], self.commands[k].t);
                let motion = match self.newest_span {
                    Some((from, to, m)) if from == c.t && to == next => m,
                    _ => c.motion(c.t, next, self.accel, wheel_base),
                };
                at = at.then(motion);
            }
            self.commands[k].odometry = Some(at);
        }
        at
    }
}

impl WheelCommand {
    /// The robot's motion from `from` to `to` (both within this command's span): through
    /// the ramp in short steps at their mean speeds, then on at the command's. The heading
    /// is a unit complex number turned by each step's small rotation: no sine or cosine.
    fn motion(&self, mut from: f64, to: f64, accel: f64, wheel_base: f64) -> Motion {
        let mut m = Motion { displacement: Point::default(), facing: Point::new(1.0, 0.0) };
        let mut advance = |[left, right]: [f64; 2], span: f64| {
            let v = 0.5 * (left + right);
            let angle = (right - left) / wheel_base * span;
            let half = rotation(0.5 * angle);
            m.displacement += m.facing * half * (v * span);
            m.facing *= half * half;
        };
        let ramp_end = self.ramp_end.min(to);
        if ramp_end > from {
            // Most ramps fit in one step (a command changes the speeds a little).
            let (n, h) = if ramp_end - from <= RAMP_STEP {
                (1.0, ramp_end - from)
            } else {
                let n = ((ramp_end - from) / RAMP_STEP).ceil();
                (n, (ramp_end - from) / n)
            };
            for k in 0..n as usize {
                let mid = from + (k as f64 + 0.5) * h - self.t;
                advance(self.speeds_after(mid, accel), h);
            }
            from = ramp_end;
        }
        if to > from {
            advance(self.target, to - from);
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::Pose;

    #[test]
    fn dead_reckoning_bridges_the_delay() {
        let mut dr = DeadReckoning::default();
        dr.command(0.0, 0.1, 0.1); // straight at 0.1 m/s
        dr.command(1.0, 0.0, 0.0); // then stopped
        let (start, east) = (Point::new(0.0, 0.0), Point::new(1.0, 0.0));
        let (p, _) = dr.predict(start, east, 0.5, 2.0, 0.1);
        assert!((p - Point::new(0.05, 0.0)).length() < 1e-12, "{p}");
        dr.forget_before(1.5);
        assert_eq!(dr.predict(start, east, 1.5, 2.0, 0.1), (start, east));
    }

    /// With the boards' ramp: the wheels' speeds follow each command at the acceleration,
    /// and the predicted pose matches the drive integrated in 0.1 ms steps within 10 µm
    /// after a second of turning, ramping up and braking.
    #[test]
    fn dead_reckoning_follows_the_ramp() {
        let accel = 1.0;
        let mut dr = DeadReckoning::with_capacity(8, accel);
        assert_eq!(dr.wheels_at(0.0), [0.0; 2], "at rest before any command");
        dr.command(0.0, 0.15, 0.25); // from rest: 0.15 s and 0.25 s of ramp
        assert!((dr.wheels_at(0.1)[0] - 0.1).abs() < 1e-12 && (dr.wheels_at(0.1)[1] - 0.1).abs() < 1e-12);
        dr.command(0.2, 0.0, 0.0); // braking from (0.15, 0.2)
        let w = dr.wheels_at(0.25);
        assert!((w[0] - 0.10).abs() < 1e-12 && (w[1] - 0.15).abs() < 1e-12, "{w:?}");
        assert_eq!(dr.wheels_at(1.0), [0.0; 2]);
        // The same commands, integrated finely as the simulator's world does.
        let (base, start) = (0.108, Pose { position: Point::new(0.1, 0.2), heading: 0.3 });
        let (mut pose, mut wheels, dt) = (start, [0.0f64; 2], 1e-4);
        for k in 0..10_000 {
            let t = f64::from(k) * dt;
            let target = if t < 0.2 { [0.15, 0.25] } else { [0.0, 0.0] };
            let next = [0, 1].map(|w| wheels[w] + (target[w] - wheels[w]).clamp(-accel * dt, accel * dt));
            let (l, r) = (0.5 * (wheels[0] + next[0]), 0.5 * (wheels[1] + next[1]));
            let angle = (r - l) / base * dt;
            pose.position += Point::from_polar(0.5 * (l + r) * dt, pose.heading + 0.5 * angle);
            pose.heading += angle;
            wheels = next;
        }
        let (p, facing) = dr.predict(start.position, Point::from_polar(1.0, start.heading), 0.0, 1.0, base);
        assert!((p - pose.position).length() < 1e-5, "{p} vs {}", pose.position);
        // The heading, carried as a unit vector without angles.
        assert!((facing - Point::from_polar(1.0, pose.heading)).length() < 1e-9, "{facing} vs {}", pose.heading);
    }

    /// A prediction takes the whole spans inside its window from the odometry that earlier
    /// cycles integrated: sliding the window over 20 s of ramping, turning commands, it
    /// agrees to rounding with integrating every span in the window afresh, one after the
    /// other.
    #[test]
    fn dead_reckoning_reuses_the_odometry() {
        let (period, delay, base, accel) = (0.02, 0.3, 0.108, 1.0);
        let mut dr = DeadReckoning::with_capacity(32, accel);
        let start = Pose { position: Point::new(-0.4, 0.1), heading: -0.2 };
        for k in 0..1000 {
            let t = f64::from(k) * period;
            let phase = f64::from(k) * 0.37;
            dr.command(t, 0.12 + 0.1 * phase.sin(), 0.12 + 0.1 * (1.3 * phase).cos());
            let t_valid = (t - delay + 0.007).max(0.0);
            dr.forget_before(t_valid - period);
            let now = t + 0.5 * period;
            let (predicted, facing) =
                dr.predict(start.position, Point::from_polar(1.0, start.heading), t_valid, now, base);
            let mut afresh = Odometry { position: start.position, facing: Point::from_polar(1.0, start.heading) };
            for (i, c) in dr.commands.iter().enumerate() {
                let end = dr.commands.get(i + 1).map_or(now, |n| n.t.min(now));
                let from = c.t.max(t_valid);
                if end > from {
                    afresh = afresh.then(c.motion(from, end, accel, base));
                }
            }
            assert!((predicted - afresh.position).length() < 1e-13, "{k}");
            assert!((facing - afresh.facing).length() < 1e-13, "{k}");
        }
        assert!(dr.commands.iter().filter(|c| c.odometry.is_some()).count() >= 10, "the odometry is kept");
    }
}
