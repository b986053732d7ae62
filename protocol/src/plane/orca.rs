//! Optimal reciprocal collision avoidance: each person's new velocity, the one nearest the
//! velocity it prefers among those that keep it clear of every neighbour for a time
//! horizon, each neighbour taking half of the change needed (van den Berg, Guy, Lin and
//! Manocha, "Reciprocal n-body collision avoidance", 2011).
//!
//! Each neighbour gives a half-plane of velocities (an [`OrcaLine`]: the side left of its
//! direction through its point is allowed); walls give half-planes too, which come first and
//! are never relaxed. The velocity is the solution of a 2-D linear program over the
//! half-planes and the speed disc; when they have no common point, of a 3-D one that
//! minimises the largest violation of the neighbours' half-planes.
//!
//! Shared by the simulator's people and the gateway's ORCA baseline, so both avoid alike.

use super::Point;

/// Below this, two directions are parallel.
const EPSILON: f64 = 1e-9;

/// Velocities allowed: those left of `direction` (a unit vector) through `point`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrcaLine {
    pub point: Point,
    pub direction: Point,
}

/// A vector's length (`norm` calls `hypot`, several times the cost, guarding against
/// overflows no floor distance comes near).
#[inline]
pub fn length(p: Point) -> f64 {
    p.norm_sqr().sqrt()
}

fn det(a: Point, b: Point) -> f64 {
    a.re * b.im - a.im * b.re
}

fn dot(a: Point, b: Point) -> f64 {
    a.re * b.re + a.im * b.im
}

/// One person as ORCA sees another: where, how fast, how big, and how much of the change
/// it takes (a half for a person who avoids in turn, all of it for one who does not).
#[derive(Debug, Clone, Copy)]
pub struct Body {
    pub position: Point,
    pub velocity: Point,
    pub radius: f64,
}

/// The half-plane of velocities of `me` that keeps clear of `other` for `horizon` seconds,
/// `me` taking `share` of the change (1/2 reciprocal, 1 alone); `step` is the time step,
/// over which two bodies already overlapping are to part.
#[inline]
pub fn line_to(me: Body, other: Body, share: f64, horizon: f64, step: f64) -> OrcaLine {
    let rel_pos = other.position - me.position;
    let rel_vel = me.velocity - other.velocity;
    let dist_sq = rel_pos.norm_sqr();
    let r = me.radius + other.radius;
    let (direction, u) = if dist_sq > r * r {
        // The cone of velocities that meet within the horizon, cut off by a disc at its tip.
        let w = rel_vel - rel_pos / horizon;
        let w_len_sq = w.norm_sqr();
        let dot1 = dot(w, rel_pos);
        if dot1 < 0.0 && dot1 * dot1 > r * r * w_len_sq {
            // Nearest to the cut-off disc.
            let w_len = w_len_sq.sqrt();
            let unit_w = w / w_len;
            (Point::new(unit_w.im, -unit_w.re), unit_w * (r / horizon - w_len))
        } else {
            // Nearest to one of the cone's legs.
            let leg = (dist_sq - r * r).sqrt();
            let direction = if det(rel_pos, w) > 0.0 {
                Point::new(rel_pos.re * leg - rel_pos.im * r, rel_pos.re * r + rel_pos.im * leg) / dist_sq
            } else {
                -Point::new(rel_pos.re * leg + rel_pos.im * r, -rel_pos.re * r + rel_pos.im * leg) / dist_sq
            };
            (direction, direction * dot(rel_vel, direction) - rel_vel)
        }
    } else {
        // Overlapping: part within one step.
        let w = rel_vel - rel_pos / step;
        let w_len = length(w);
        let unit_w = if w_len > 0.0 { w / w_len } else { Point::new(1.0, 0.0) };
        (Point::new(unit_w.im, -unit_w.re), unit_w * (r / step - w_len))
    };
    OrcaLine { point: me.velocity + u * share, direction }
}

/// The half-plane of velocities that keeps a body at `position` of `radius` off the wall
/// point `nearest` for `horizon` seconds (or parts them within `step` when they overlap).
#[inline]
pub fn line_off_wall(position: Point, radius: f64, nearest: Point, horizon: f64, step: f64) -> Option<OrcaLine> {
    let away = position - nearest;
    let d = length(away);
    if d <= 0.0 {
        return None;
    }
    let n = away / d;
    // Towards the wall no faster than closes the gap within the horizon; when overlapping,
    // away at the speed that parts them within the step.
    let approach = if d > radius { (d - radius) / horizon } else { -(radius - d) / step };
    Some(OrcaLine { point: -n * approach, direction: Point::new(n.im, -n.re) })
}

/// The velocity nearest `preferred` within `max_speed` that satisfies every line, the
/// first `hard` of them (walls) relaxed only when they cannot all be met.
#[inline]
pub fn solve(lines: &[OrcaLine], hard: usize, max_speed: f64, preferred: Point, scratch: &mut Vec<OrcaLine>) -> Point {
    let mut result = Point::default();
    let failed = program_2d(lines, max_speed, preferred, false, &mut result);
    if failed < lines.len() {
        // The walls themselves cannot all be met within the speed (a person pressed into
        // a corner): then they too are only violated least.
        let hard = if failed < hard { 0 } else { hard };
        program_3d(lines, hard, failed, max_speed, &mut result, scratch);
    }
    result
}

/// The best point on line `n` within the disc and the lines before it (`None`: none).
fn program_1d(lines: &[OrcaLine], n: usize, radius: f64, opt: Point, direction_opt: bool) -> Option<Point> {
    let line = lines[n];
    let dot_p = dot(line.point, line.direction);
    let discriminant = dot_p * dot_p + radius * radius - line.point.norm_sqr();
    if discriminant < 0.0 {
        return None;
    }
    let sqrt_d = discriminant.sqrt();
    let (mut t_left, mut t_right) = (-dot_p - sqrt_d, -dot_p + sqrt_d);
    for other in &lines[..n] {
        let denominator = det(line.direction, other.direction);
        let numerator = det(other.direction, line.point - other.point);
        if denominator.abs() <= EPSILON {
            if numerator < 0.0 {
                return None;
            }
            continue;
        }
        let t = numerator / denominator;
        if denominator >= 0.0 {
            t_right = t_right.min(t);
        } else {
            t_left = t_left.max(t);
        }
        if t_left > t_right {
            return None;
        }
    }
    let t = if direction_opt {
        if dot(opt, line.direction) > 0.0 {
            t_right
        } else {
            t_left
        }
    } else {
        dot(line.direction, opt - line.point).clamp(t_left, t_right)
    };
    Some(line.point + line.direction * t)
}

/// The point nearest `opt` (or furthest along it, `direction_opt`) in the disc and every
/// line; returns the number of lines met, less than their count where it failed.
fn program_2d(lines: &[OrcaLine], radius: f64, opt: Point, direction_opt: bool, result: &mut Point) -> usize {
    *result = if direction_opt {
        opt * radius
    } else if opt.norm_sqr() > radius * radius {
        opt / length(opt) * radius
    } else {
        opt
    };
    for (i, line) in lines.iter().enumerate() {
        if det(line.direction, line.point - *result) > 0.0 {
            match program_1d(lines, i, radius, opt, direction_opt) {
                Some(p) => *result = p,
                None => return i,
            }
        }
    }
    lines.len()
}

/// From line `begin` on, where the 2-D program failed: the point that least violates the
/// soft lines, the `hard` ones kept.
fn program_3d(
    lines: &[OrcaLine],
    hard: usize,
    begin: usize,
    radius: f64,
    result: &mut Point,
    projected: &mut Vec<OrcaLine>,
) {
    let mut distance = 0.0;
    for i in begin..lines.len() {
        let li = lines[i];
        if det(li.direction, li.point - *result) <= distance {
            continue;
        }
        projected.clear();
        projected.extend_from_slice(&lines[..hard]);
        for lj in &lines[hard..i] {
            let determinant = det(li.direction, lj.direction);
            let point = if determinant.abs() <= EPSILON {
                if dot(li.direction, lj.direction) > 0.0 {
                    continue; // the same way: no constraint between them
                }
                (li.point + lj.point) * 0.5
            } else {
                li.point + li.direction * (det(lj.direction, li.point - lj.point) / determinant)
            };
            let d = lj.direction - li.direction;
            projected.push(OrcaLine { point, direction: d / length(d) });
        }
        let before = *result;
        let opt = Point::new(-li.direction.im, li.direction.re);
        if program_2d(projected, radius, opt, true, result) < projected.len() {
            // Only rounding can make this fail: keep the last point.
            *result = before;
        }
        distance = det(li.direction, li.point - *result);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(x: f64, y: f64, vx: f64, vy: f64) -> Body {
        Body { position: Point::new(x, y), velocity: Point::new(vx, vy), radius: 0.1 }
    }

    /// Head on, each takes half the change: their new velocities keep them apart over the
    /// horizon, and both turn the same way (to their right), not into each other.
    #[test]
    fn two_head_on_pass_each_other() {
        let (a, b) = (body(-1.0, 0.001, 1.0, 0.0), body(1.0, -0.001, -1.0, 0.0));
        let mut scratch = Vec::new();
        let va = solve(&[line_to(a, b, 0.5, 5.0, 0.1)], 0, 1.0, a.velocity, &mut scratch);
        let vb = solve(&[line_to(b, a, 0.5, 5.0, 0.1)], 0, 1.0, b.velocity, &mut scratch);
        assert!(va.im * vb.im < 0.0, "{va} {vb}");
        // Closest approach within the horizon, moving at the new velocities.
        let (dp, dv) = (b.position - a.position, vb - va);
        let t = (-dot(dp, dv) / dv.norm_sqr()).clamp(0.0, 5.0);
        assert!((dp + dv * t).norm() >= 0.2 - 1e-9, "{}", (dp + dv * t).norm());
    }

    /// A wall ahead: the velocity towards it is cut to what closes the gap in the horizon.
    #[test]
    fn a_wall_slows_the_approach() {
        let line = line_off_wall(Point::new(0.0, 0.0), 0.1, Point::new(0.0, 0.6), 5.0, 0.1).unwrap();
        let v = solve(&[line], 1, 1.0, Point::new(0.0, 1.0), &mut Vec::new());
        assert!((v.im - 0.1).abs() < 1e-12, "{v}");
    }

    /// Lines with no common point within the disc: the 3-D program gives the velocity that
    /// violates them least, equally.
    /// Walls that cannot all be met (one each side, closer than a step's worth of speed
    /// allows) are violated least too, not a panic.
    #[test]
    fn infeasible_walls_are_violated_least() {
        let up = OrcaLine { point: Point::new(0.0, 0.5), direction: Point::new(1.0, 0.0) };
        let down = OrcaLine { point: Point::new(0.0, -0.5), direction: Point::new(-1.0, 0.0) };
        let v = solve(&[up, down], 2, 1.0, Point::new(0.3, 0.0), &mut Vec::new());
        assert!(v.im.abs() < 1e-9, "{v}");
    }

    #[test]
    fn infeasible_lines_are_violated_least() {
        let up = OrcaLine { point: Point::new(0.0, 0.5), direction: Point::new(1.0, 0.0) }; // v.y >= 0.5
        let down = OrcaLine { point: Point::new(0.0, -0.5), direction: Point::new(-1.0, 0.0) }; // v.y <= -0.5
        let v = solve(&[up, down], 0, 1.0, Point::new(0.3, 0.0), &mut Vec::new());
        assert!(v.im.abs() < 1e-9, "{v}");
    }
}
