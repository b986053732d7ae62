//! Plane geometry on complex numbers, for the per-sample path: lengths and small rotations
//! without the library calls that dominate a cycle's cost when taken every step.

use crate::Point;

/// The length of a vector in metres (or m/s): the square root of the squares. `hypot`
/// guards against overflow and underflow that floor coordinates never reach, and costs
/// about as much as the rest of a planner evaluation.
pub trait Length {
    fn length(self) -> f64;
}

impl Length for Point {
    #[inline]
    fn length(self) -> f64 {
        self.norm_sqr().sqrt()
    }
}

/// `e^{iθ}`; for the small angles of one step (|θ| ≤ 0.1 rad) by its series, which is
/// exact to rounding there.
#[inline]
pub fn rotation(theta: f64) -> Point {
    if theta.abs() > 0.1 {
        return Point::from_polar(1.0, theta);
    }
    // Horner's form with the reciprocals as constants: no division.
    let t2 = theta * theta;
    let cos = 1.0 - t2 * 0.5 * (1.0 - t2 * (1.0 / 12.0) * (1.0 - t2 * (1.0 / 30.0) * (1.0 - t2 * (1.0 / 56.0))));
    let sin = theta
        * (1.0 - t2 * (1.0 / 6.0) * (1.0 - t2 * (1.0 / 20.0) * (1.0 - t2 * (1.0 / 42.0) * (1.0 - t2 * (1.0 / 72.0)))));
    Point::new(cos, sin)
}

/// The angle of `z` from the positive real axis, in `(-π, π]` (`atan2`); within a tenth
/// of a radian of that axis (|im| ≤ re / 10), where a robot steering toward its command
/// mostly is, by the arctangent's series: within an ulp or two of the library, without
/// its call.
#[inline]
pub fn angle(z: Point) -> f64 {
    if !(z.re > 0.0 && z.im.abs() <= 0.1 * z.re) {
        return z.im.atan2(z.re);
    }
    let t = z.im / z.re;
    let u = t * t;
    // Horner's form; the next term, t¹⁷/17, is below 1e-18 of the sum.
    t * (1.0
        + u * (-1.0 / 3.0
            + u * (1.0 / 5.0
                + u * (-1.0 / 7.0 + u * (1.0 / 9.0 + u * (-1.0 / 11.0 + u * (1.0 / 13.0 + u * (-1.0 / 15.0))))))))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_near_the_axis_by_their_series() {
        for k in -2000..=2000 {
            for r in [1e-9, 0.3, 1.0, 7.0] {
                let z = Point::from_polar(r, f64::from(k) * 1e-4);
                let (mine, library) = (angle(z), z.im.atan2(z.re));
                assert!((mine - library).abs() <= 2.0 * f64::EPSILON * library.abs(), "{z}: {mine} {library}");
            }
        }
        // Elsewhere it is the library's.
        for z in [
            Point::new(-1.0, 0.0),
            Point::new(0.0, 1.0),
            Point::new(1.0, 0.2),
            Point::new(-1.0, -1e-3),
            Point::new(0.0, 0.0),
        ] {
            assert_eq!(angle(z).to_bits(), z.im.atan2(z.re).to_bits(), "{z}");
        }
    }

    #[test]
    fn small_rotations_by_their_series() {
        for k in -100..=100 {
            let theta = f64::from(k) * 1e-3;
            assert!((rotation(theta) - Point::from_polar(1.0, theta)).norm() < 1e-15, "{theta}");
        }
        assert!((rotation(0.7) - Point::from_polar(1.0, 0.7)).norm() < 1e-15);
    }

    #[test]
    fn lengths_agree_with_hypot() {
        for (x, y) in [(3.0, 4.0), (-0.2, 0.05), (1e-9, -2e-9), (0.0, 0.0), (12.5, -0.001)] {
            let z = Point::new(x, y);
            assert!((z.length() - z.norm()).abs() <= 1e-15 * z.norm(), "{z}");
        }
    }
}
