//! The judge: what really happened between two instants of the world, against the true
//! radii. Each obstacle's closest approach to the robot, the least gap to a lane line, a
//! wall or a static obstacle, and the first contact are found over the whole interval, to a
//! nanometre and a nanosecond, not at sampled instants.
//!
//! Between two commands the robot's centre follows a curve known in closed form
//! ([`Way::at`]) whose acceleration is bounded ([`Way::swerve`], `A`), and each obstacle
//! moves at one velocity along a leg of its script. Every quantity judged (the distance
//! between two centres, the gap to a line or to a segment) is a convex function of the
//! offset, so along the way its second derivative is at least `-A`. Over a sub-interval of
//! length `L` it is then bounded below three ways: by its least value along the chord
//! between the ends less the curve's bow (`A L² / 8`), and by its value and slope at either
//! end less `A L² / 2`. A sub-interval whose bound neither beats the least value found nor
//! reaches a contact is passed over; the others are halved until the bow is within a
//! nanometre, where the chord's least value is the curve's. Away from everything a whole
//! interval is one bound per obstacle; near a closest approach, a few halvings.

use super::robot::Pose;
use super::{Axis, Contact, DiffDrive, ObstaclePath, Room, Touched, ACTIVE_CONTACT_SPEED};
use crate::Point;
use flowgate_protocol::plane::{nearest_on_segment, polygon_edges};

/// Two values of a gap within this are the same, m.
const EXACT: f64 = 1e-9;
/// A contact's instant is found to this, s.
const INSTANT: f64 = 1e-9;
/// After a passive contact, the instant the robot drives into what it touches is found to
/// this, s.
const ACTIVE_GRAIN: f64 = 1e-6;
/// Nearer than this (m) between the centre and what it touches, the direction toward it
/// is taken to turn at any rate.
const NEAR: f64 = 1e-3;

/// The state the world last settled at (a command changed the axes then). Up to the next
/// command the robot's way on from it is a closed-form function of the time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Settled {
    pub time: f64,
    pub pose: Pose,
    /// The heading as a unit vector: no sine or cosine along the way.
    pub facing: Point,
    pub axes: [Axis; 2],
}

/// The robot at one instant.
#[derive(Debug, Clone, Copy)]
pub(super) struct Moment {
    pub t: f64,
    pub pose: Pose,
    /// The heading as a unit vector.
    pub facing: Point,
    /// The centre's velocity, m/s.
    pub velocity: Point,
    pub axes: [Axis; 2],
    /// Path length of the centre from the settled state, m.
    pub travelled: f64,
}

/// The robot's way on from a settled state.
#[derive(Debug, Clone, Copy)]
pub(super) struct Way {
    pub from: Settled,
    pub drive: DiffDrive,
    /// The most the centre's acceleration can be anywhere on the way up to the time it was
    /// made for, m/s².
    pub swerve: f64,
}

impl Way {
    /// The way from `from` as far as `span` seconds on, its acceleration bounded from the
    /// ramps' pieces (their wheel speeds alone: no integration).
    pub fn to(from: Settled, drive: DiffDrive, span: f64) -> Self {
        let mut swerve = 0.0f64;
        ramps(from.axes, drive, span, |speeds, to, length| swerve = swerve.max(drive.swerve(speeds, to, length)));
        Self { from, drive, swerve }
    }

    /// The way from `from`, its acceleration left unbounded: for taking instants on it.
    pub fn from(from: Settled, drive: DiffDrive) -> Self {
        Self { from, drive, swerve: f64::INFINITY }
    }

    /// The robot at time `t` (from the settled state's time on).
    pub fn at(&self, t: f64) -> Moment {
        self.follow(t - self.from.time, t)
    }

    /// The robot `span` seconds on from the settled state, at time `t`.
    pub fn after(&self, span: f64, t: f64) -> Moment {
        self.follow(span, t)
    }

    /// The robot `span` seconds on (at time `t`), integrated in closed form along the pieces
    /// between the ramps' ends (at most three).
    fn follow(&self, span: f64, t: f64) -> Moment {
        let Settled { time: _, mut pose, mut facing, axes } = self.from;
        let mut travelled = 0.0;
        let (axes, speeds) = ramps(axes, self.drive, span.max(0.0), |from, to, length| {
            let m = self.drive.motion(from, to, length);
            (pose, facing) = m.apply(pose, facing);
            travelled += m.length;
        });
        // Renormalised at each instant taken, so rounding cannot build up over a run.
        let facing = facing / facing.norm_sqr().sqrt();
        Moment { t, pose, facing, velocity: facing * (0.5 * (speeds[0] + speeds[1])), axes, travelled }
    }
}

/// `axes` run on for `span` seconds, in pieces up to each ramp's end and then on to the
/// span's end (at most three, none empty); `piece` sees each one's rim speeds (m/s; left,
/// right) at its start and its end, and its length. The axes and the rim speeds at the end.
fn ramps(
    mut axes: [Axis; 2],
    drive: DiffDrive,
    span: f64,
    mut piece: impl FnMut([f64; 2], [f64; 2], f64),
) -> ([Axis; 2], [f64; 2]) {
    let rim = |axes: &[Axis; 2]| axes.map(|a| a.rate() / drive.pulses_per_metre);
    let [first, second] = axes.map(|a| a.ramp_left().min(span));
    let ends = if first <= second { [first, second] } else { [second, first] };
    let mut at = 0.0;
    // Each piece starts at the speeds the last one ended on.
    let mut speeds = rim(&axes);
    for end in ends.into_iter().chain([span]) {
        if end > at {
            let length = end - at;
            axes.iter_mut().for_each(|a| {
                a.step(length);
            });
            let to = rim(&axes);
            piece(speeds, to, length);
            (at, speeds) = (end, to);
        }
    }
    (axes, speeds)
}

/// What the judge weighs the way against.
#[derive(Debug, Clone, Copy)]
pub(super) struct Scene<'w> {
    pub obstacles: &'w [(ObstaclePath, f64)],
    pub lane_half_width: Option<f64>,
    pub room: &'w Room,
    pub robot_radius: f64,
}

/// One thing the robot may touch, judged on its own.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Target {
    Obstacle(usize),
    /// A lane line, by its side: `1.0` the line at `+half_width`, `-1.0` the other.
    Line(f64),
    Room,
}

impl Scene<'_> {
    fn targets(&self) -> impl Iterator<Item = Target> + '_ {
        let lines = self.lane_half_width.map(|_| [Target::Line(1.0), Target::Line(-1.0)]);
        (0..self.obstacles.len())
            .map(Target::Obstacle)
            .chain(lines.into_iter().flatten())
            .chain((!self.room.is_empty()).then_some(Target::Room))
    }

    /// Below this value of the target's reading the footprints touch: the centres'
    /// distance for an obstacle, the gap for a line or the room.
    fn reach(&self, target: Target) -> f64 {
        match target {
            Target::Obstacle(k) => self.obstacles[k].1 + self.robot_radius,
            Target::Line(_) | Target::Room => 0.0,
        }
    }

    /// The target's reading with the robot at `m`: its value, and the unit vector from the
    /// robot toward it.
    fn read(&self, target: Target, m: &Moment) -> (f64, Point, Touched) {
        let c = m.pose.position;
        match target {
            Target::Obstacle(k) => {
                let r = self.obstacles[k].0.position(m.t) - c;
                let d = r.norm_sqr().sqrt();
                (d, if d > 0.0 { r / d } else { Point::default() }, Touched::Obstacle(k))
            }
            Target::Line(side) => {
                (self.lane_half_width.unwrap_or(f64::INFINITY) - side * c.im, Point::new(0.0, side), Touched::Wall)
            }
            Target::Room => match self.room.gap(c, self.robot_radius) {
                Some(g) => (g.gap, g.toward, g.with),
                None => (f64::INFINITY, Point::default(), Touched::Wall),
            },
        }
    }

    /// A lower bound of the target's value over `[a, b]` (the way's acceleration at most
    /// `swerve`), and the instant the bound is least at along the chord. `tight`: within
    /// [`EXACT`] of the least value there. `level`: the least value found so far, which
    /// decides whether the finer bounds are worth taking.
    fn bound(&self, target: Target, a: &Moment, b: &Moment, swerve: f64, level: f64) -> Bound {
        let length = b.t - a.t;
        let bow = swerve * length * length / 8.0;
        // A value and its slope at an end bound it over the interval: the curvature is at
        // least `-swerve`, so the bound is a concave parabola, least at an end.
        let bend = swerve * length * length / 2.0;
        let from_ends =
            |fa: f64, sa: f64, fb: f64, sb: f64| fa.min(fa + sa * length - bend).max(fb.min(fb - sb * length - bend));
        let (ca, cb) = (a.pose.position, b.pose.position);
        match target {
            Target::Obstacle(k) => {
                let path = &self.obstacles[k].0;
                if path.change_between(a.t, b.t).is_some() {
                    // Split there first: each side keeps one velocity.
                    return Bound { least: f64::NEG_INFINITY, at: a.t, tight: false };
                }
                let (oa, ob) = (path.position(a.t), path.position(b.t));
                let (ra, rb) = (oa - ca, ob - cb);
                let change = rb - ra;
                let along = change.norm_sqr();
                let tau = if along > 0.0 { (-dot(ra, change) / along).clamp(0.0, 1.0) } else { 0.0 };
                let chord = (ra + change * tau).norm_sqr().sqrt() - bow;
                // The obstacle keeps one velocity over the interval (split at its legs' ends).
                let vo = if length > 0.0 { (ob - oa) / length } else { Point::default() };
                let (da, db) = (ra.norm_sqr().sqrt(), rb.norm_sqr().sqrt());
                let slope = |r: Point, d: f64, v: Point| if d > 0.0 { dot(r, vo - v) / d } else { 0.0 };
                let ends = from_ends(da, slope(ra, da, a.velocity), db, slope(rb, db, b.velocity));
                Bound { least: chord.max(ends), at: a.t + tau * length, tight: bow <= EXACT }
            }
            Target::Line(side) => {
                let h = self.lane_half_width.unwrap_or(f64::INFINITY);
                let (fa, fb) = (h - side * ca.im, h - side * cb.im);
                let chord = fa.min(fb) - bow;
                let ends = from_ends(fa, -side * a.velocity.im, fb, -side * b.velocity.im);
                Bound { least: chord.max(ends), at: if fa <= fb { a.t } else { b.t }, tight: bow <= EXACT }
            }
            Target::Room => self.room_bound(a, b, bow, bend, level),
        }
    }

    /// [`Self::bound`] for the room: the gap changes no faster than the centre moves; and,
    /// while the way keeps out of the static obstacles, each part's distance along the
    /// chord (least where the chord passes nearest), less the bow, or from its ends.
    fn room_bound(&self, a: &Moment, b: &Moment, bow: f64, bend: f64, level: f64) -> Bound {
        let (ca, cb) = (a.pose.position, b.pose.position);
        let gap = |c: Point| self.room.gap(c, self.robot_radius).map_or(f64::INFINITY, |g| g.gap);
        let chord = (cb - ca).norm_sqr().sqrt();
        let (ga, gb) = (gap(ca), gap(cb));
        let moved = 0.5 * (ga + gb - chord) - bow;
        let at_end = if ga <= gb { a.t } else { b.t };
        if moved >= level - EXACT || chord + 2.0 * bow <= EXACT {
            return Bound { least: moved, at: at_end, tight: true };
        }
        if self.room.inside_any(ca) || self.room.inside_any(cb) {
            return Bound { least: moved, at: at_end, tight: false };
        }
        let length = b.t - a.t;
        let r = self.robot_radius;
        let mut least = (f64::INFINITY, 0.0);
        let walls = self.room.walls().iter().flat_map(|w| w.windows(2).map(|s| (s[0], s[1], false)));
        let edges = self.room.polygons().iter().flat_map(|p| polygon_edges(p).map(|(p, q)| (p, q, true)));
        for (p, q, edge) in walls.chain(edges) {
            let (distance, tau) = segments_apart(ca, cb, p, q);
            if edge && distance == 0.0 {
                // The chord enters a static obstacle: only the first bound holds.
                return Bound { least: moved, at: at_end, tight: false };
            }
            let mut part = distance - r - bow;
            if part < level - EXACT {
                let end = |c: Point, v: Point| {
                    let off = nearest_on_segment(c, p, q) - c;
                    let d = off.norm_sqr().sqrt();
                    (d - r, if d > 0.0 { -dot(off, v) / d } else { 0.0 })
                };
                let ((fa, sa), (fb, sb)) = (end(ca, a.velocity), end(cb, b.velocity));
                part = part.max(fa.min(fa + sa * length - bend).max(fb.min(fb - sb * length - bend)));
            }
            if part < least.0 {
                least = (part, tau);
            }
        }
        Bound { least: moved.max(least.0), at: a.t + least.1 * length, tight: bow <= EXACT }
    }

    /// Where to split `[a, b]` for `target`: where the obstacle's velocity changes, if it
    /// does inside; else the middle.
    fn split(&self, target: Target, a: f64, b: f64) -> f64 {
        let middle = 0.5 * (a + b);
        match target {
            Target::Obstacle(k) => self.obstacles[k].0.change_between(a, b).unwrap_or(middle),
            _ => middle,
        }
    }
}

/// A lower bound over an interval.
#[derive(Debug, Clone, Copy)]
struct Bound {
    least: f64,
    /// Where along the interval the bound is least, s.
    at: f64,
    /// The curve's least value is within [`EXACT`] of the chord's there.
    tight: bool,
}

/// The judge's findings so far.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Judge {
    /// Per obstacle: the least distance between the centres so far, m.
    pub min_distance: Vec<f64>,
    /// The least gap to a lane line (the centre's), a wall or a static obstacle (the
    /// footprint's) so far, m.
    pub min_wall_clearance: f64,
    pub contact: Option<Contact>,
    pub active_contact: Option<Contact>,
}

/// Contacts found within one interval, the earliest kept.
#[derive(Debug, Default)]
struct Found {
    first: Option<Contact>,
    active: Option<Contact>,
}

impl Judge {
    pub fn new(obstacles: usize) -> Self {
        Self {
            min_distance: vec![f64::INFINITY; obstacles],
            min_wall_clearance: f64::INFINITY,
            contact: None,
            active_contact: None,
        }
    }

    /// Judge the robot at one instant (the start of a run).
    pub fn instant(&mut self, scene: &Scene<'_>, m: &Moment) {
        let mut found = Found::default();
        for target in scene.targets() {
            self.observe(scene, target, None, m, &mut found);
        }
        self.take(found);
    }

    /// Judge the way from `a` to `b` (both on `way`), `b` included, `a` already judged.
    pub fn interval(&mut self, scene: &Scene<'_>, way: &Way, a: &Moment, b: &Moment) {
        if b.t <= a.t {
            return;
        }
        let mut found = Found::default();
        for target in scene.targets() {
            self.observe(scene, target, Some((way, a)), b, &mut found);
            self.visit(scene, way, target, a, b, &mut found);
        }
        self.take(found);
    }

    fn take(&mut self, found: Found) {
        if self.contact.is_none() {
            self.contact = found.first;
        }
        if self.active_contact.is_none() {
            self.active_contact = found.active;
        }
    }

    fn least(&self, target: Target) -> f64 {
        match target {
            Target::Obstacle(k) => self.min_distance[k],
            Target::Line(_) | Target::Room => self.min_wall_clearance,
        }
    }

    /// Whether a contact at or after `t` would still be news.
    fn pending(&self, found: &Found, t: f64) -> (bool, bool) {
        let open =
            |judged: &Option<Contact>, found: &Option<Contact>| judged.is_none() && found.is_none_or(|c| c.at > t);
        (open(&self.contact, &found.first), open(&self.active_contact, &found.active))
    }

    /// Search `[a, b]` for `target`'s least value and contacts; `a` and `b` observed.
    fn visit(&mut self, scene: &Scene<'_>, way: &Way, target: Target, a: &Moment, b: &Moment, found: &mut Found) {
        let bound = scene.bound(target, a, b, way.swerve, self.least(target));
        let (first, active) = self.pending(found, a.t);
        let touching = bound.least < scene.reach(target);
        let seek_first = touching && first;
        // After a passive contact, the first instant the robot drives into what it touches.
        let seek_active = touching && !first && active && may_drive_into(scene, target, a, b, way.swerve, bound.least);
        if !seek_first && !seek_active && bound.least >= self.least(target) - EXACT {
            return;
        }
        let length = b.t - a.t;
        if length <= INSTANT || (seek_active && length <= ACTIVE_GRAIN) || (bound.tight && !seek_active) {
            if bound.at > a.t && bound.at < b.t {
                let m = way.at(bound.at);
                self.observe(scene, target, Some((way, a)), &m, found);
            }
            return;
        }
        let m = way.at(scene.split(target, a.t, b.t));
        self.observe(scene, target, Some((way, a)), &m, found);
        self.visit(scene, way, target, a, &m, found);
        self.visit(scene, way, target, &m, b, found);
    }

    /// Record the target's value at `m`; at a contact, find when it began (after `before`,
    /// where it had not, on the same way as `m`) and how the robot was moving.
    fn observe(
        &mut self,
        scene: &Scene<'_>,
        target: Target,
        before: Option<(&Way, &Moment)>,
        m: &Moment,
        found: &mut Found,
    ) {
        let (value, toward, with) = scene.read(target, m);
        match target {
            Target::Obstacle(k) => self.min_distance[k] = self.min_distance[k].min(value),
            _ => self.min_wall_clearance = self.min_wall_clearance.min(value),
        }
        let reach = scene.reach(target);
        if value >= reach {
            return;
        }
        let (first, active) = self.pending(found, m.t);
        if first {
            let began = before.map_or(*m, |(way, before)| began(scene, way, target, before, m));
            let (_, toward, with) = scene.read(target, &began);
            keep_earliest(&mut found.first, contact(&began, with, toward));
        }
        let here = contact(m, with, toward);
        if active && here.active {
            keep_earliest(&mut found.active, here);
        }
    }
}

/// The instant between `a` (not touching) and `b` (touching) the target's value first
/// falls below its reach, to [`INSTANT`], by halving along the way.
fn began(scene: &Scene<'_>, way: &Way, target: Target, a: &Moment, b: &Moment) -> Moment {
    let reach = scene.reach(target);
    if scene.read(target, a).0 < reach {
        return *a;
    }
    let (mut lo, mut hi) = (a.t, *b);
    while hi.t - lo > INSTANT {
        let mid = way.at(0.5 * (lo + hi.t));
        if scene.read(target, &mid).0 < reach {
            hi = mid;
        } else {
            lo = mid.t;
        }
    }
    hi
}

/// The contact of a robot at `m` touching `with`, which lies along `toward`.
fn contact(m: &Moment, with: Touched, toward: Point) -> Contact {
    let approach_speed = dot(m.velocity, toward);
    Contact { at: m.t, with, approach_speed, active: approach_speed > ACTIVE_CONTACT_SPEED }
}

fn keep_earliest(slot: &mut Option<Contact>, c: Contact) {
    if slot.is_none_or(|s| c.at < s.at) {
        *slot = Some(c);
    }
}

/// Whether the robot may be driving into `target` anywhere in `[a, b]`, where the target's
/// value is at least `least`: its speed toward the target changes no faster than its
/// acceleration and its speed times the turn of the direction toward it.
fn may_drive_into(scene: &Scene<'_>, target: Target, a: &Moment, b: &Moment, swerve: f64, least: f64) -> bool {
    let length = b.t - a.t;
    let (_, ta, _) = scene.read(target, a);
    let (_, tb, _) = scene.read(target, b);
    let speed = a.velocity.norm().max(b.velocity.norm()) + swerve * length;
    // The direction toward a line keeps; toward an obstacle or a part of the room it turns
    // at most at the relative speed over the distance between the centre and it.
    let (near, relative) = match target {
        Target::Line(_) => (f64::INFINITY, 0.0),
        Target::Obstacle(k) => (least, speed + scene.obstacles[k].0.top_speed()),
        Target::Room => (least + scene.robot_radius, speed),
    };
    let turn = if near > NEAR { relative / near } else { f64::INFINITY };
    let most = 0.5 * (dot(a.velocity, ta) + dot(b.velocity, tb)) + 0.5 * (swerve + speed * turn) * length;
    most > ACTIVE_CONTACT_SPEED
}

fn dot(a: Point, b: Point) -> f64 {
    a.re * b.re + a.im * b.im
}

/// The least distance between segments `p0 p1` and `q0 q1`, and the fraction along the
/// first where it is.
fn segments_apart(p0: Point, p1: Point, q0: Point, q1: Point) -> (f64, f64) {
    let d = p1 - p0;
    let e = q1 - q0;
    let cross = |u: Point, v: Point| u.re * v.im - u.im * v.re;
    let denominator = cross(d, e);
    if denominator != 0.0 {
        let s = cross(q0 - p0, e) / denominator;
        let u = cross(q0 - p0, d) / denominator;
        if (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&u) {
            return (0.0, s);
        }
    }
    let along = |x: Point| {
        let n = d.norm_sqr();
        if n > 0.0 {
            (dot(x - p0, d) / n).clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    [p0, p1, q0, q1]
        .into_iter()
        .enumerate()
        .map(|(k, x)| match k {
            0 => ((nearest_on_segment(x, q0, q1) - x).norm(), 0.0),
            1 => ((nearest_on_segment(x, q0, q1) - x).norm(), 1.0),
            _ => {
                let s = along(x);
                ((p0 + d * s - x).norm(), s)
            }
        })
        .fold((f64::INFINITY, 0.0), |best, c| if c.0 < best.0 { c } else { best })
}
