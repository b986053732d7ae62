//! The social force model (Helbing and Molnár, "Social force model for pedestrian
//! dynamics", 1995): a person accelerates towards the velocity it prefers and is pushed off
//! the others and the walls by forces that fall off exponentially with the gap, stronger
//! ahead of it than behind.
//!
//! The constants are those commonly used at human scale (a relaxation time of 0.5 s, a
//! person's push of 2.1 m/s² over 0.3 m, a wall's of 10 m/s² over 0.2 m, for people of 0.3 m
//! at 1 m/s), scaled by each person's radius and preferred speed so that the rig's small,
//! slow people behave as people do at their own scale. The simulator's people walk by it,
//! and so does the gateway's social-force baseline.

use super::orca::{length, Body};
use super::Point;

/// The relaxation time, in the time a person takes to walk its own radius.
const RELAXATION_RADII: f64 = 0.5 / 0.3;
/// A person's push, in (preferred speed)² / radius, and its range, in radii.
const PERSON_PUSH: f64 = 2.1 * 0.3;
const PERSON_RANGE: f64 = 1.0;
/// A wall's push and range, likewise.
const WALL_PUSH: f64 = 10.0 * 0.3;
const WALL_RANGE: f64 = 0.2 / 0.3;
/// How much of a push from behind a person feels (1 ahead).
const BEHIND: f64 = 0.5;

/// `me`'s velocity after one `step`: towards `preferred` (of speed at most `speed`), pushed
/// off `others` and the wall points `walls`, capped at `cap`.
pub fn velocity(
    me: Body,
    preferred: Point,
    speed: f64,
    cap: f64,
    others: impl Iterator<Item = Body>,
    walls: impl Iterator<Item = Point>,
    step: f64,
) -> Point {
    let r = me.radius;
    let scale = speed * speed / r;
    let heading = if length(preferred) > 0.0 { preferred / length(preferred) } else { Point::default() };
    let mut accel = (preferred - me.velocity) / (RELAXATION_RADII * r / speed);
    for o in others {
        let away = me.position - o.position;
        let d = length(away).max(1e-9);
        let n = away / d;
        // Stronger from ahead (the other in the way) than from behind.
        let cos = -(n.re * heading.re + n.im * heading.im);
        let weight = BEHIND + (1.0 - BEHIND) * (1.0 + cos) / 2.0;
        accel += n * (PERSON_PUSH * scale * ((r + o.radius - d) / (PERSON_RANGE * r)).exp() * weight);
    }
    for p in walls {
        let away = me.position - p;
        let d = length(away).max(1e-9);
        accel += away / d * (WALL_PUSH * scale * ((r - d) / (WALL_RANGE * r)).exp());
    }
    let v = me.velocity + accel * step;
    let s = length(v);
    if s > cap {
        v * (cap / s)
    } else {
        v
    }
}
