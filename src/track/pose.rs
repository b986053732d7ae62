//! One vehicle's pose from its two LEDs: the last measured pose, the last plausible one
//! that every new pose is checked against, and its recent commands for dead reckoning.

use super::{DeadReckoning, Implausible, LedGeometry, PoseReach, TrackingSettings, SETTLE};
use crate::geometry::Length;
use crate::Point;

/// A vehicle's pose as its LEDs give it. Allocation-free after construction.
#[derive(Debug, Clone)]
pub struct PoseTrack {
    geometry: LedGeometry,
    /// Dead-reckon the pose to the moment a command acts (`[tracking] predict_robot`).
    predict: bool,
    /// When the last measured pose was valid, its centre, and its heading as a unit vector.
    pose: Option<(f64, Point, Point)>,
    /// The last plausible pose, kept when the pose is forgotten at a stop (so that a stale
    /// one is never driven on): every pose is checked against it.
    reference: Option<(f64, Point, Point)>,
    /// Since when the wheels have been at rest and commanded to stay so (None: they may be
    /// moving).
    still_since: Option<f64>,
    /// A pose refused while the wheels are at rest, and where it stood since: taken once it
    /// has stood still for [`SETTLE`] (the vehicle carried to a new place by hand).
    settling: Option<(f64, Point, Point)>,
    dead_reckoning: DeadReckoning,
}

/// Where a vehicle is at the moment its command will act.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseAt {
    pub position: Point,
    /// Its heading as a unit vector.
    pub facing: Point,
    /// Its wheels' rim speeds, m/s: left, right.
    pub wheels: [f64; 2],
    /// When the pose it is reckoned from was valid, s.
    pub valid_at: f64,
}

impl PoseTrack {
    pub fn new(settings: TrackingSettings, geometry: LedGeometry) -> Self {
        Self {
            geometry,
            predict: settings.predict_robot,
            pose: None,
            reference: None,
            still_since: Some(f64::NEG_INFINITY),
            settling: None,
            dead_reckoning: DeadReckoning::with_capacity(64, settings.wheel_accel),
        }
    }

    /// The two LEDs, valid at `t_valid`. Returns whether they gave a pose (they do unless
    /// they coincide).
    pub fn observe(&mut self, t_valid: f64, front: Point, rear: Point) -> bool {
        match self.geometry.locate(front, rear) {
            Some((position, facing)) if self.pose.is_none_or(|(t, ..)| t_valid >= t) => {
                self.pose = Some((t_valid, position, facing));
                self.reference = self.pose;
                self.settling = None;
                true
            }
            _ => false,
        }
    }

    /// Whether the two LEDs at `t_valid` can be the vehicle's pose: they sit their mounted
    /// distance apart, and since the last plausible pose the centre moved no further than
    /// the vehicle can drive and the heading turned no further than its wheels can turn it,
    /// each within `reach.tolerance`. A CRC-valid but wrong sample (a reflection, a mixed-up
    /// slot) fails one of the three.
    ///
    /// The wheels move the vehicle only while they are not at rest: a reflection that comes
    /// while it stands (stopped, faulted, armed) is refused however long it lasts, where
    /// against the time since the last pose alone it would soon be in reach. The last
    /// plausible pose is kept when the pose is forgotten at a stop, so the pose seen again is
    /// checked too. A pose refused while the wheels are at rest that stands still for
    /// [`SETTLE`] is taken (the vehicle carried to a new place by hand).
    pub fn plausible(&mut self, t_valid: f64, front: Point, rear: Point, reach: PoseReach) -> Result<(), Implausible> {
        let spacing = (front - rear).length();
        let mounted = self.geometry.front + self.geometry.rear;
        let off = (spacing - mounted).abs();
        if off.is_nan() || off > reach.tolerance {
            return Err(Implausible::LedSpacing { measured: spacing, mounted });
        }
        let (Some((position, facing)), Some(last)) = (self.geometry.locate(front, rear), self.reference) else {
            return Ok(());
        };
        let moving = match self.still_since {
            Some(still) => (still.min(t_valid) - last.0).max(0.0),
            None => (t_valid - last.0).abs(),
        };
        let check = Self::within(last, position, facing, moving, reach, mounted);
        if check.is_err() && self.still_since.is_some() && self.settled(t_valid, position, facing, reach, mounted) {
            return Ok(());
        }
        check
    }

    /// Whether a pose at `position`, `facing` is within what the wheels can do in `moving`
    /// seconds from `last`.
    fn within(
        (_, last, last_facing): (f64, Point, Point),
        position: Point,
        facing: Point,
        moving: f64,
        reach: PoseReach,
        mounted: f64,
    ) -> Result<(), Implausible> {
        let moved = (position - last).length();
        let can_move = reach.speed * moving + reach.tolerance;
        if moved.is_nan() || moved > can_move {
            return Err(Implausible::Jump { moved, reach: can_move });
        }
        // Each LED off by the tolerance across the axis, opposite ways, turns it this far.
        let can_turn = reach.turn_rate * moving + (2.0 * reach.tolerance).atan2(mounted);
        let turned = (facing * last_facing.conj()).arg().abs();
        if turned.is_nan() || turned > can_turn {
            return Err(Implausible::Turn { turned, reach: can_turn });
        }
        Ok(())
    }

    /// A refused pose at `t`: whether it has stood within the tolerance of where it stands
    /// now for [`SETTLE`].
    fn settled(&mut self, t: f64, position: Point, facing: Point, reach: PoseReach, mounted: f64) -> bool {
        match self.settling {
            Some(since) if Self::within(since, position, facing, 0.0, reach, mounted).is_ok() => t - since.0 >= SETTLE,
            _ => {
                self.settling = Some((t, position, facing));
                false
            }
        }
    }

    /// The last plausible pose (kept when the pose is forgotten at a stop): when it was
    /// valid, s, and its centre.
    pub fn last_seen(&self) -> Option<(f64, Point)> {
        self.reference.map(|(t, p, _)| (t, p))
    }

    /// When the last pose was valid, s.
    pub fn time(&self) -> Option<f64> {
        self.pose.map(|(t, ..)| t)
    }

    /// Forget the pose (after a stop, so a stale one is never driven on).
    pub fn forget(&mut self) {
        self.pose = None;
    }

    /// The wheels were stopped at once (an emergency stop): they are at rest, whatever
    /// was commanded before.
    pub fn halted(&mut self, t: f64) {
        self.dead_reckoning.halt();
        self.still_since = Some(t);
    }

    /// The wheels' rim speeds at `t`, as the commands and the boards' ramp have brought them.
    pub fn wheels_at(&self, t: f64) -> [f64; 2] {
        self.dead_reckoning.wheels_at(t)
    }

    /// The wheels were commanded these speeds at `t` (for dead reckoning).
    pub fn commanded(&mut self, t: f64, left: f64, right: f64) {
        self.dead_reckoning.command(t, left, right);
        self.still_since = if left == 0.0 && right == 0.0 {
            self.still_since.or(Some(self.dead_reckoning.at_rest_from()))
        } else {
            None
        };
    }

    /// Where the vehicle is at `t`, when the command will act: the pose dead-reckoned from
    /// its time of validity (or as measured, without prediction). `None` before any pose.
    pub fn at(&mut self, t: f64, sample_time: f64, wheel_base: f64) -> Option<PoseAt> {
        let (valid_at, measured, facing) = self.pose?;
        self.dead_reckoning.forget_before(valid_at - sample_time);
        let (position, facing) = if self.predict {
            self.dead_reckoning.predict(measured, facing, valid_at, t, wheel_base)
        } else {
            (measured, facing)
        };
        Some(PoseAt { position, facing, wheels: self.dead_reckoning.wheels_at(t), valid_at })
    }
}
