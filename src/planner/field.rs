//! The navigation function: a complex velocity field `F(z) = u - i v` whose streamlines
//! lead to the goal around circular obstacles, moving or not, in free space or in a lane.
//!
//! Built from the corrected equations of `shared/docs/planner-math.md` (the paper's print
//! has typos), every term expressed through two primitives of the [`Space`]: a unit sink
//! and a doublet. In a lane both primitives carry their wall images in closed form, so the
//! walls are exact streamlines of every term.
//!
//! For obstacle `k` (centre `z_k`, planning radius `R_k`, velocity `V_k`):
//!
//! ```text
//! F_k(z) = K(r) m [ S(z; z_s) + S(z; z_sk') - S(z; z_k) ]     sink, its image in circle k, source at k's centre
//!        + Σ_j D(z; z_j, R_j² V_j)                              every obstacle's own doublet
//!        + Σ_{j≠k} D(z; z_kj', μ_kj')                           images of the other doublets in circle k
//! F(z)   = Σ_k w_k F_k(z),   w_k ∝ 1 / (|z - z_k| - R_k)        gap-distance blend (eq. 28, N obstacles)
//! ```
//!
//! with `z_sk' = z_k + R_k² / conj(z_s - z_k)`, `z_kj' = z_k + R_k² / conj(z_j - z_k)`,
//! `μ_kj' = -conj(μ_j) R_k² / conj(z_j - z_k)²` (circle theorem), `K(r) = (r/R)(1 - e^{-c1 r})`.
//! For two obstacles the weights are the paper's `1 - α`, `α` with `α = r_1/(r_1 + r_2)`;
//! on the boundary of obstacle `k` its weight is exactly 1, so each boundary condition holds.
//! Images and weights are recomputed from the current geometry on every [`Field::new`].

use num_complex::Complex64 as C;

/// The most obstacles one field holds (fixed arrays: evaluation never allocates).
pub const MAX_OBSTACLES: usize = 16;

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
    #[inline]
    pub fn sink(self, z: C, a: C) -> C {
        match self {
            Space::Free => -(z - a).inv(),
            Space::Lane { half_width } => {
                let w = Self::varpi(half_width);
                -w * (coth(w * (z - a)) + tanh(w * (z - a.conj())))
            }
        }
    }

    /// `sink(z, a) - (-1/(z - a))`: the wall images' part of a unit sink, regular at `a`
    /// (zero in free space). At `z = a` its limit is `-ϖ tanh(ϖ (a - conj a))`.
    pub fn sink_wall_part(self, z: C, a: C) -> C {
        match self {
            Space::Free => C::default(),
            Space::Lane { half_width } => {
                let w = Self::varpi(half_width);
                let x = w * (z - a);
                // coth(x) - 1/x, by its series near 0 where the difference cancels.
                let coth_minus = if x.norm() < 1e-3 { x / 3.0 - x * x * x / 45.0 } else { coth(x) - x.inv() };
                -w * (coth_minus + tanh(w * (z - a.conj())))
            }
        }
    }

    /// The uniform flow (`u - i v`) that a lane doublet's wall images induce at its own
    /// position: `W(μ) = α μ + β conj(μ)` with real `α = -ϖ²/3`, `β = -ϖ² / cos²(2ϖ y)`
    /// (from `csch²x - 1/x² -> -1/3`). Zero in free space.
    fn doublet_self_flow(self, at: C) -> (f64, f64) {
        match self {
            Space::Free => (0.0, 0.0),
            Space::Lane { half_width } => {
                let w = Self::varpi(half_width);
                (-w * w / 3.0, -w * w / (2.0 * w * at.im).cos().powi(2))
            }
        }
    }

    /// The moment `μ` of a doublet at the centre of a circle of radius `r` at `at` that
    /// cancels, on the circle, a uniform flow `c` (as `u - i v`) together with the uniform
    /// flow of the doublet's own wall images: `μ = -r² conj(c + W(μ))`, solved exactly
    /// (a 2x2 real system, since `W` is real-linear). In free space `μ = -r² conj(c)`.
    pub fn cancelling_moment(self, at: C, r: f64, c: C) -> C {
        let (alpha, beta) = self.doublet_self_flow(at);
        let r2 = r * r;
        C::new(-r2 * c.re / (1.0 + r2 * (beta + alpha)), r2 * c.im / (1.0 + r2 * (beta - alpha)))
    }

    /// A doublet of moment `mu` at `a`: `mu/(z - a)²`, plus its wall images in a lane:
    /// `ϖ² [mu csch²(ϖ(z - a)) - conj(mu) sech²(ϖ(z - conj a))]`.
    #[inline]
    pub fn doublet(self, z: C, a: C, mu: C) -> C {
        match self {
            Space::Free => mu * ((z - a) * (z - a)).inv(),
            Space::Lane { half_width } => {
                let w = Self::varpi(half_width);
                w * w * (mu * csch2(w * (z - a)) - mu.conj() * sech2(w * (z - a.conj())))
            }
        }
    }
}

// Lane primitives from one complex exponential each: with q = e^{-2x} (taking x with
// Re x >= 0 by symmetry, so |q| <= 1 and nothing overflows),
// tanh x = (1 - q)/(1 + q), coth x = (1 + q)/(1 - q), csch² x = 4q/(1 - q)², sech² x = 4q/(1 + q)².
#[inline]
fn half_plane(x: C) -> (C, f64) {
    if x.re >= 0.0 {
        ((-2.0 * x).exp(), 1.0)
    } else {
        ((2.0 * x).exp(), -1.0)
    }
}
#[inline]
fn tanh(x: C) -> C {
    let (q, sign) = half_plane(x);
    sign * (1.0 - q) / (1.0 + q)
}
#[inline]
fn coth(x: C) -> C {
    let (q, sign) = half_plane(x);
    sign * (1.0 + q) / (1.0 - q)
}
#[inline]
fn csch2(x: C) -> C {
    let (q, _) = half_plane(x);
    4.0 * q / ((1.0 - q) * (1.0 - q))
}
#[inline]
fn sech2(x: C) -> C {
    let (q, _) = half_plane(x);
    4.0 * q / ((1.0 + q) * (1.0 + q))
}

/// An obstacle as the planner sees it: centre, velocity, planning radius `R`
/// (obstacle radius + robot radius + margin).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanObstacle {
    pub center: C,
    pub velocity: C,
    pub radius: f64,
}

/// The goal sink: where, how strong, how it is smoothed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sink {
    pub goal: C,
    /// Sink strength `m`, m²/s.
    pub strength: f64,
    /// `c1` of `K(r)`, 1/m.
    pub c1: f64,
    /// `R` of `K(r) = (r/R)(1 - e^{-c1 r})`: far from the goal the sink's speed tends to `m/R`.
    pub reference_radius: f64,
}

impl Sink {
    /// `K(r)`.
    #[inline]
    pub fn smoothing(&self, r: f64) -> f64 {
        r / self.reference_radius * -(-self.c1 * r).exp_m1()
    }
}

/// A configuration the field cannot be built for, or a point it is not defined at.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum FieldError {
    #[error("an input is NaN or infinite")]
    NonFinite,
    #[error("lane half-width {0} must be positive")]
    BadLane(f64),
    #[error("obstacle {index} has non-positive planning radius")]
    BadRadius { index: usize },
    #[error("goal lies within obstacle {index}'s planning radius: its image would fall outside the circle")]
    GoalInsideObstacle { index: usize },
    #[error("goal lies outside the lane")]
    GoalOutsideLane,
    #[error("point lies within obstacle {index}'s planning radius")]
    InsideObstacle { index: usize },
    #[error("point lies outside the lane")]
    OutsideLane,
    #[error("more than {MAX_OBSTACLES} obstacles")]
    TooManyObstacles,
}

/// The field for one geometry: obstacles, images and goal fixed, evaluated at any point.
#[derive(Debug, Clone)]
pub struct Field {
    space: Space,
    sink: Sink,
    n: usize,
    obstacles: [PlanObstacle; MAX_OBSTACLES],
    /// Doublet moments `μ_k = R_k² V_k`.
    moments: [C; MAX_OBSTACLES],
    /// Image of the goal sink in circle k.
    sink_images: [C; MAX_OBSTACLES],
    /// Lane only (zero in free space): moments of the doublets at obstacle k's centre that
    /// cancel, on its circle, the uniform part of the wall images' flow: of the sink terms
    /// (scaled by K like them), and of the obstacle's own motion doublet.
    lane_corrections: [C; MAX_OBSTACLES],
    motion_corrections: [C; MAX_OBSTACLES],
}

fn finite(z: C) -> bool {
    z.re.is_finite() && z.im.is_finite()
}

impl Field {
    /// Build the field, checking the configuration.
    pub fn new(space: Space, sink: Sink, obstacles: &[PlanObstacle]) -> Result<Self, FieldError> {
        if obstacles.len() > MAX_OBSTACLES {
            return Err(FieldError::TooManyObstacles);
        }
        let scalars = [sink.strength, sink.c1, sink.reference_radius];
        if !finite(sink.goal) || scalars.iter().any(|v| !v.is_finite()) {
            return Err(FieldError::NonFinite);
        }
        if let Space::Lane { half_width } = space {
            if !(half_width.is_finite() && half_width > 0.0) {
                return Err(FieldError::BadLane(half_width));
            }
            if sink.goal.im.abs() >= half_width {
                return Err(FieldError::GoalOutsideLane);
            }
        }
        let mut field = Self {
            space,
            sink,
            n: obstacles.len(),
            obstacles: [PlanObstacle { center: C::default(), velocity: C::default(), radius: 1.0 }; MAX_OBSTACLES],
            moments: [C::default(); MAX_OBSTACLES],
            sink_images: [C::default(); MAX_OBSTACLES],
            lane_corrections: [C::default(); MAX_OBSTACLES],
            motion_corrections: [C::default(); MAX_OBSTACLES],
        };
        for (k, o) in obstacles.iter().enumerate() {
            if !finite(o.center) || !finite(o.velocity) || !o.radius.is_finite() {
                return Err(FieldError::NonFinite);
            }
            if o.radius <= 0.0 {
                return Err(FieldError::BadRadius { index: k });
            }
            let to_goal = sink.goal - o.center;
            if to_goal.norm() <= o.radius {
                return Err(FieldError::GoalInsideObstacle { index: k });
            }
            let r2 = o.radius * o.radius;
            field.obstacles[k] = *o;
            field.moments[k] = o.velocity * r2;
            field.sink_images[k] = o.center + r2 / to_goal.conj();
            // In a lane the wall images of the sink, its image and the centre source flow
            // nearly uniformly past the circle with u - i v = c (the channel's flow is much
            // faster than a free sink's m/d). Cancel it with the circle theorem's image of a
            // uniform flow: a doublet at the centre, itself in lane form so the walls stay
            // exact, its moment solved together with its own wall images' flow. Likewise for
            // the uniform flow that the motion doublet's wall images induce.
            let c = space.sink_wall_part(o.center, sink.goal) + space.sink_wall_part(o.center, field.sink_images[k])
                - space.sink_wall_part(o.center, o.center);
            field.lane_corrections[k] = space.cancelling_moment(o.center, o.radius, c);
            let (alpha, beta) = space.doublet_self_flow(o.center);
            let motion_flow = alpha * field.moments[k] + beta * field.moments[k].conj();
            field.motion_corrections[k] = space.cancelling_moment(o.center, o.radius, motion_flow);
        }
        Ok(field)
    }

    pub fn space(&self) -> Space {
        self.space
    }
    pub fn sink(&self) -> &Sink {
        &self.sink
    }
    pub fn obstacles(&self) -> &[PlanObstacle] {
        &self.obstacles[..self.n]
    }

    /// `F(z) = u - i v` at `z`. The robot's velocity command is `conj(F)`.
    pub fn eval(&self, z: C) -> Result<C, FieldError> {
        if !finite(z) {
            return Err(FieldError::NonFinite);
        }
        if let Space::Lane { half_width } = self.space {
            if z.im.abs() >= half_width {
                return Err(FieldError::OutsideLane);
            }
        }
        let space = self.space;
        let r = (z - self.sink.goal).norm();
        if r == 0.0 {
            return Ok(C::default()); // K(0) = 0: at rest on the goal
        }
        let km = self.sink.smoothing(r) * self.sink.strength;
        let mut f = km * space.sink(z, self.sink.goal);
        if self.n == 0 {
            return Ok(f);
        }
        // Gap-distance weights w_k ∝ 1/gap_k.
        let mut inv_gap = [0.0; MAX_OBSTACLES];
        let mut total = 0.0;
        for (k, (o, inv)) in self.obstacles[..self.n].iter().zip(&mut inv_gap).enumerate() {
            let gap = (z - o.center).norm() - o.radius;
            if gap <= 0.0 {
                return Err(FieldError::InsideObstacle { index: k });
            }
            *inv = gap.recip();
            total += *inv;
        }
        for (k, (o, inv)) in self.obstacles[..self.n].iter().zip(inv_gap).enumerate() {
            let w = inv / total;
            // Three doublets sit at the centre: the obstacle's own motion (weight 1), and its
            // two lane corrections (weight w_k, the sink's scaled by K). Doublets are linear
            // in their moment, so one evaluation serves all three.
            let centre_moment = self.moments[k] + w * (km * self.lane_corrections[k] + self.motion_corrections[k]);
            f += space.doublet(z, o.center, centre_moment);
            let mut fk = km * (space.sink(z, self.sink_images[k]) - space.sink(z, o.center));
            // Images of the other obstacles' doublets in circle k (circle theorem):
            // at z_k + R_k²/conj(z_j - z_k), moment -conj(μ_j) R_k² / conj(z_j - z_k)².
            let r2 = o.radius * o.radius;
            for j in (0..self.n).filter(|&j| j != k) {
                let d = (self.obstacles[j].center - o.center).conj();
                if d.norm() > 0.0 {
                    let at = o.center + r2 / d;
                    fk += space.doublet(z, at, -self.moments[j].conj() * r2 / (d * d));
                }
            }
            f += fk * w;
        }
        Ok(f)
    }

    /// The velocity command at `z`: `u + i v = conj(F(z))`.
    pub fn velocity(&self, z: C) -> Result<C, FieldError> {
        self.eval(z).map(|f| f.conj())
    }
}

/// Streamlines of `field` from `seeds`: unit-speed RK2 steps of `step` metres until they
/// leave `bounds`, reach the goal, or meet an obstacle.
pub fn streamlines(field: &Field, seeds: &[C], step: f64, max_steps: usize, bounds: (C, C)) -> Vec<Vec<C>> {
    let dir = |z: C| field.velocity(z).ok().filter(|v| v.norm() > 1e-12).map(|v| v / v.norm());
    let inside = |z: C| z.re >= bounds.0.re && z.re <= bounds.1.re && z.im >= bounds.0.im && z.im <= bounds.1.im;
    seeds
        .iter()
        .map(|&seed| {
            let mut line = vec![seed];
            let mut z = seed;
            for _ in 0..max_steps {
                let Some(d1) = dir(z) else { break };
                let Some(d2) = dir(z + d1 * (0.5 * step)) else { break };
                z += d2 * step;
                if !inside(z) || (z - field.sink().goal).norm() < step {
                    break;
                }
                line.push(z);
            }
            line
        })
        .collect()
}
