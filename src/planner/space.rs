//! Free space or a lane: the two primitives every term of the field is made of, a unit
//! sink and a doublet, with a lane's wall images in closed form (docs/planner.md).

use crate::Point;

/// Free space, or a lane between walls at `y = ±h`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Space {
    Free,
    Lane { half_width: f64 },
}

impl Space {
    /// `ϖ = π / 4h` of a lane.
    fn varpi(half_width: f64) -> f64 {
        std::f64::consts::PI / (4.0 * half_width)
    }

    /// A unit sink at `a` (as `u - i v`): `-1/(z - a)`, plus its wall images in a lane:
    /// `-ϖ [coth(ϖ(z - a)) + tanh(ϖ(z - conj a))]`.
    #[inline(always)]
    pub fn sink(self, z: Point, a: Point) -> Point {
        match self {
            Space::Free => -(z - a).inv(),
            Space::Lane { half_width } => Self::lane_sink(half_width, z, a),
        }
    }

    // The lane's terms out of line, so that free space's inline to a few operations.
    fn lane_sink(half_width: f64, z: Point, a: Point) -> Point {
        let w = Self::varpi(half_width);
        -w * (coth(w * (z - a)) + tanh(w * (z - a.conj())))
    }

    /// A doublet of moment `mu` at `a`: `mu/(z - a)²`, plus its wall images in a lane:
    /// `ϖ² [mu csch²(ϖ(z - a)) - conj(mu) sech²(ϖ(z - conj a))]`.
    #[inline(always)]
    pub fn doublet(self, z: Point, a: Point, mu: Point) -> Point {
        match self {
            Space::Free => mu * ((z - a) * (z - a)).inv(),
            Space::Lane { half_width } => Self::lane_doublet(half_width, z, a, mu),
        }
    }

    fn lane_doublet(half_width: f64, z: Point, a: Point, mu: Point) -> Point {
        let w = Self::varpi(half_width);
        w * w * (mu * csch2(w * (z - a)) - mu.conj() * sech2(w * (z - a.conj())))
    }
}

// Lane primitives from one complex exponential each: with q = e^{-2x} (taking x with
// Re x >= 0 by symmetry, so |q| <= 1 and nothing overflows),
// tanh x = (1 - q)/(1 + q), coth x = (1 + q)/(1 - q), csch² x = 4q/(1 - q)², sech² x = 4q/(1 + q)².
#[inline]
fn half_plane(x: Point) -> (Point, f64) {
    if x.re >= 0.0 {
        ((-2.0 * x).exp(), 1.0)
    } else {
        ((2.0 * x).exp(), -1.0)
    }
}
#[inline]
fn tanh(x: Point) -> Point {
    let (q, sign) = half_plane(x);
    sign * (1.0 - q) / (1.0 + q)
}
#[inline]
fn coth(x: Point) -> Point {
    let (q, sign) = half_plane(x);
    sign * (1.0 + q) / (1.0 - q)
}
#[inline]
fn csch2(x: Point) -> Point {
    let (q, _) = half_plane(x);
    4.0 * q / ((1.0 - q) * (1.0 - q))
}
#[inline]
fn sech2(x: Point) -> Point {
    let (q, _) = half_plane(x);
    4.0 * q / ((1.0 + q) * (1.0 + q))
}
