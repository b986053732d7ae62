//! The floor plane both ends of the rig share: the gateway's planner and tracker and the
//! simulator's world reckon points and headings the same way, so they agree to the bit.
//!
//! A point (or a vector: a velocity, an offset) is a complex number `x + iy` in metres, the
//! floor's frame as the calibration defines it. Headings are angles from the x axis,
//! counter-clockwise, in `(-π, π]`.

use core::f64::consts::{PI, TAU};

#[cfg(feature = "std")]
pub mod orca;
#[cfg(feature = "std")]
pub mod script;
#[cfg(feature = "std")]
pub mod social_force;

/// A point or vector on the floor, `x + iy`, m (or m/s).
pub type Point = num_complex::Complex64;

/// `a` wrapped to `(-π, π]`. An angle already there is returned as it is (no rounding):
/// the common case, every step of a run.
pub fn wrap_angle(a: f64) -> f64 {
    if a > -PI && a <= PI {
        return a;
    }
    // The Euclidean remainder, written with `%` so it needs no `std`.
    let r = (a + PI) % TAU;
    let w = if r < 0.0 { r + TAU } else { r } - PI;
    if w <= -PI {
        w + TAU
    } else {
        w
    }
}

/// A polygon's edges `(from, to)`, closed by the last one back to the first.
pub fn polygon_edges(polygon: &[Point]) -> impl Iterator<Item = (Point, Point)> + '_ {
    (0..polygon.len()).map(move |k| (polygon[k], polygon[(k + 1) % polygon.len()]))
}

/// The squared distance from `p` to the segment `a`-`b`, m² (a root is the caller's: the
/// simulator's judge compares squares).
pub fn segment_distance_sqr(p: Point, a: Point, b: Point) -> f64 {
    let ab = b - a;
    let length_sqr = ab.norm_sqr();
    let t = if length_sqr > 0.0 { ((p - a) * ab.conj()).re / length_sqr } else { 0.0 };
    (p - (a + ab * t.clamp(0.0, 1.0))).norm_sqr()
}

/// The point of the segment `a`-`b` nearest `p`.
pub fn nearest_on_segment(p: Point, a: Point, b: Point) -> Point {
    let ab = b - a;
    let length_sqr = ab.norm_sqr();
    let t = if length_sqr > 0.0 { ((p - a) * ab.conj()).re / length_sqr } else { 0.0 };
    a + ab * t.clamp(0.0, 1.0)
}

/// Whether `p` lies inside the polygon (even-odd rule; a point on an edge may fall either
/// way).
pub fn inside_polygon(p: Point, polygon: &[Point]) -> bool {
    let mut inside = false;
    for (a, b) in polygon_edges(polygon) {
        if (a.im > p.im) != (b.im > p.im) {
            let x = a.re + (p.im - a.im) / (b.im - a.im) * (b.re - a.re);
            if p.re < x {
                inside = !inside;
            }
        }
    }
    inside
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_wrap_into_the_half_open_interval() {
        assert_eq!(wrap_angle(0.5), 0.5);
        assert_eq!(wrap_angle(PI), PI);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-3.5 * PI) - 0.5 * PI).abs() < 1e-12);
        assert!((wrap_angle(2.0 * TAU + 0.25) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn segments_and_polygons() {
        let (a, b) = (Point::new(0.0, 0.0), Point::new(2.0, 0.0));
        assert_eq!(segment_distance_sqr(Point::new(1.0, 3.0), a, b), 9.0);
        assert_eq!(segment_distance_sqr(Point::new(-3.0, 4.0), a, b), 25.0);
        assert_eq!(nearest_on_segment(Point::new(5.0, 1.0), a, b), b);
        let square = [Point::new(0.0, 0.0), Point::new(1.0, 0.0), Point::new(1.0, 1.0), Point::new(0.0, 1.0)];
        assert!(inside_polygon(Point::new(0.5, 0.5), &square));
        assert!(!inside_polygon(Point::new(1.5, 0.5), &square));
        assert_eq!(polygon_edges(&square).last(), Some((square[3], square[0])));
    }

    proptest::proptest! {
        /// Wrapped, an angle lies in (-π, π] and differs from the original by whole turns.
        #[test]
        fn wrapping_keeps_the_direction(a in -1e4f64..1e4) {
            let w = wrap_angle(a);
            proptest::prop_assert!(w > -PI && w <= PI, "{a} -> {w}");
            let turns = (a - w) / TAU;
            proptest::prop_assert!((turns - turns.round()).abs() < 1e-9, "{a} -> {w}");
        }
    }
}
