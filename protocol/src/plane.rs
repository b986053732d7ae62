//! The floor plane both ends of the rig share: the gateway's planner and tracker and the
//! simulator's world reckon points and headings the same way, so they agree to the bit.
//!
//! A point (or a vector: a velocity, an offset) is a complex number `x + iy` in metres, the
//! floor's frame as the calibration defines it. Headings are angles from the x axis,
//! counter-clockwise, in `(-π, π]`.

use core::f64::consts::{PI, TAU};

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
