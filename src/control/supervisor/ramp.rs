//! The ramp beyond which the supervisor holds the robot back: how far it can still brake.

use super::{Context, MAX_PATH_STEPS};
use crate::control::drive::WheelSpeeds;
use crate::Point;

pub(super) fn dot(a: Point, b: Point) -> f64 {
    a.re * b.re + a.im * b.im
}

/// Verdicts on the commands neither wheel's ramp reaches within the reaction time. Such a
/// wheel ramps at the full rate for every step toward the command, whatever the command, so
/// all commands beyond reach in the same sense on each wheel walk the very same path and
/// get the same verdict: a bisection toward a hard brake walks it once, not sixteen times.
pub(super) struct BeyondRamp {
    /// The path's step these were found for.
    pub(super) h: f64,
    /// Steps toward the command (those that start before `τ`).
    steps: usize,
    /// Each wheel's speed at the start of the last of them, having ramped down, and up, at
    /// the full rate from its speed now.
    last: [[f64; 2]; 2],
    /// The verdicts found, by each wheel's sense (down, up).
    pub(super) verdicts: [[Option<bool>; 2]; 2],
}

impl BeyondRamp {
    pub(super) fn new(ctx: &Context<'_>) -> Self {
        // The step every command whose wheels stay within the ones now and the limits gets
        // (a faster one gets a longer step, and its own walk: see `sense`).
        let h = ctx.path_step(ctx.fastest(WheelSpeeds { left: 0.0, right: 0.0 }));
        let (step, tau) = (ctx.cfg.wheel_accel * h, ctx.cfg.reaction_time);
        let (mut steps, mut s) = (0, 0.0);
        // As the path counts them: `s` grows by `h` a step while it is below `τ` (some
        // 129 steps at most: `h` is at least `τ`/[`MAX_PATH_STEPS`]).
        while s < tau {
            if steps > 2 * MAX_PATH_STEPS as usize {
                // Not the path's count: no verdict is shared (no step is NaN's equal).
                return Self { h: f64::NAN, steps, last: [ctx.wheels; 2], verdicts: [[None; 2]; 2] };
            }
            s += h;
            steps += 1;
        }
        let mut last = [ctx.wheels; 2];
        let [down, up] = &mut last;
        for _ in 1..steps {
            // As `ramp` moves a wheel the full step down, and up.
            down.iter_mut().for_each(|w| *w += -step);
            up.iter_mut().for_each(|w| *w += step);
        }
        Self { h, steps, last, verdicts: [[None; 2]; 2] }
    }

    /// Each wheel's sense, down (0) or up (1), if `command` is beyond its ramp's reach in it
    /// at every step toward it. Checking the last step is enough: the wheel's speed moves
    /// one way, and a rounded difference with it does too. `None`: within reach, or a step
    /// other than the one found.
    pub(super) fn sense(&self, ctx: &Context<'_>, command: WheelSpeeds) -> Option<[usize; 2]> {
        if ctx.path_step(ctx.fastest(command)) != self.h {
            return None;
        }
        if self.steps == 0 {
            return Some([0, 0]); // no step toward any command: one path for all
        }
        let step = ctx.cfg.wheel_accel * self.h;
        let one = |k: usize, target: f64| {
            if target - self.last[0][k] <= -step {
                Some(0)
            } else if target - self.last[1][k] >= step {
                Some(1)
            } else {
                None
            }
        };
        Some([one(0, command.left)?, one(1, command.right)?])
    }
}
