//! Exact obstacle boundaries in a lane: a multipole series at each obstacle's centre,
//! fitted by least squares on its circle.
//!
//! The lane's closed-form images (see [`super::field`]) keep the walls exact, but the
//! circle theorem's images are free-space ones, so in a lane a circle is only nearly a
//! streamline. What is left over is a flow that is regular outside the circle and has the
//! walls as streamlines; it is cancelled by lane multipoles of orders 1..=[`ORDERS`] at the
//! centre, whose coefficients are fitted by least squares on [`POINTS`] points of the
//! circle's part inside the lane.
//!
//! The lane multipoles are rational in `s = e^{2ϖ(z - x_0)}` (`ϖ = π/4h`), which maps the
//! lane onto the half-plane `Re s > 0` and the walls onto the imaginary axis. A potential
//! `c (σ/(s - s_a))^n` plus its mirror `conj(c) (-conj σ/(s + conj s_a))^n` is real on
//! the walls (so they stay streamlines exactly), vanishes at both ends of the lane, and near
//! the centre is `c (R/(z - a))^n`: the free-space multipole. `x_0` is the centre's `x`, so
//! `s` stays moderate near the circle wherever the obstacle is.
//!
//! A circle that reaches a wall is closed against it first ([`super::field`]): centred on
//! the wall, so that it meets it at right angles and, reflected in it, is a whole circle in
//! a lane twice as wide. Its series lives in that doubled lane with real coefficients (see
//! [`Series::new`]) and converges as a circle's clear of the walls does.
//!
//! Where that closure would take in the robot or the goal the circle is left as it is, and
//! a circle that reaches a wall is then fitted on its arc inside the lane, where no series
//! at the centre converges geometrically (there is a corner where circle meets wall): it
//! gets [`WALL_ORDERS`] orders, where its residual levels off, and a light Tikhonov
//! regularisation, without which the arc's nearly dependent orders take huge cancelling
//! coefficients whose rounding shows on the walls.
//!
//! The fit is a dense Householder QR in a [`Workspace`] the field keeps from one build to the
//! next (no allocation, nothing cleared): about `3 orders · (2 orders)²` flops per obstacle
//! each time the field is built (10 to 130 µs here), shared by the two right-hand sides (the
//! goal sink's flow and the obstacles' motion).

use crate::Point;

use crate::geometry::Length;

/// The most multipole orders an obstacle gets: a circle centred on a wall has real
/// coefficients only (see [`Series::real`]), and gets up to this many.
pub const ORDERS: usize = 48;
/// The most orders a circle with complex coefficients gets (one off the walls).
const COMPLEX_ORDERS: usize = 32;
/// Collocation points per order on a circle clear of the walls: 1.5 a real unknown, enough
/// where the orders are well separated around the whole circle.
const POINTS_PER_ORDER: usize = 3;
/// On a circle that reaches a wall but was left unclosed, twice the unknowns: the fit sees
/// only an arc (with 3, E2's residual was 2.6e-3 instead of 9.4e-6 when it was fitted so).
const POINTS_PER_ORDER_AT_A_WALL: usize = 4;
/// On a circle centred on a wall (whose coefficients are real), 4 an order round the
/// circle: half lie in the lane, 2 a real unknown (with 1.5, as clear of the walls, the
/// worst residual across docs/simulation.md's grid is 1.0e-6 instead of 3.7e-7).
const POINTS_PER_ORDER_ON_A_WALL: usize = 4;
/// The most collocation points in the lane on one circle: a circle clear of the walls at
/// its most orders, or a circle centred on a wall at its (half its points are in the lane).
pub const POINTS: usize = POINTS_PER_ORDER * COMPLEX_ORDERS;
const _: () = assert!(POINTS_PER_ORDER_ON_A_WALL * ORDERS / 2 <= POINTS);
const _: () = assert!(POINTS_PER_ORDER_AT_A_WALL * WALL_ORDERS <= POINTS);

/// Whether a circle at `a` is centred on a wall of the lane of half-width `h`: a circle
/// closed against it (`field::in_lane` puts the centre exactly there).
fn centred_on_a_wall(h: f64, a: Point) -> bool {
    a.im.abs() == h
}
/// The fit's aim for a [`Field`](super::Field) made directly: the series' truncation error,
/// relative to the flow on the circle. The property tests hold the lane to it.
pub const EXACT_AIM: f64 = 1e-8;
/// The loosest aim a configuration may set, and a rig's default (`planner.lane_residual`):
/// a tenth of a millimetre on a circle of a metre, below the camera's millimetre of noise.
/// Sweeps at it are the same in distribution as at [`EXACT_AIM`] (docs/simulation.md).
pub const LOOSEST_AIM: f64 = 1e-4;
/// The tightest: rounding sets in below it.
pub const TIGHTEST_AIM: f64 = 1e-10;

/// Whether `aim` is one the fit can be set to, from [`TIGHTEST_AIM`] to [`LOOSEST_AIM`]
/// (never NaN).
pub fn aim_allowed(aim: f64) -> bool {
    (TIGHTEST_AIM..=LOOSEST_AIM).contains(&aim)
}
const UNKNOWNS: usize = 2 * COMPLEX_ORDERS + 1;
/// Rows of the fit: the collocation points and one Tikhonov row per unknown.
const ROWS: usize = POINTS + UNKNOWNS;
/// The Tikhonov weight for a circle that reaches a wall, relative to each column's norm
/// (see [`fit`]; a circle clear of the walls is fitted on its whole circumference, where the
/// orders are well separated, and needs none).
pub const WALL_REGULARISATION: f64 = 1e-5;
/// The orders a circle that reaches a wall gets (see [`orders_for`]).
pub const WALL_ORDERS: usize = 16;

/// Beyond this `|2ϖ (x - x_0)|` a multipole's flow is below `e^-600` of its size at the
/// circle: zero (and `s` would overflow).
const FAR: f64 = 600.0;

/// A multipole series at one obstacle's centre, in the lane's coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Series {
    /// `2ϖ`.
    two_varpi: f64,
    /// `x_0`: the origin of `s` (the centre's `x`).
    x0: f64,
    /// `y_0`: the axis of the series' lane (0, or the wall a circle is centred on).
    y0: f64,
    /// The centre in `s`.
    sa: Point,
    /// The scale `σ = 2ϖ s_a R`: `σ/(s - s_a) ≈ R/(z - a)` near the centre.
    sigma: Point,
    /// The centre is on a wall (a circle closed against it), see [`Series::new`].
    real: bool,
}

impl Series {
    /// The series frame for a circle of radius `r` at `a` in a lane of half-width `h`.
    ///
    /// A circle centred on a wall (closed against it) is symmetric about that wall, and so is
    /// its flow: its series lives in the lane doubled by reflection in the wall (half-width
    /// `2h`, its axis the wall, its walls the far wall and that one's mirror image), centred
    /// on the axis (`s_a = 1`), with real coefficients only, which make the axis, the wall,
    /// a streamline. In the doubled lane `s` spreads half as much over the circle as it
    /// would in the lane (the circle is up to twice the half-width across), which keeps
    /// the fit well conditioned.
    pub fn new(h: f64, a: Point, r: f64) -> Self {
        let real = centred_on_a_wall(h, a);
        let (h, y0) = if real { (2.0 * h, a.im) } else { (h, 0.0) };
        let two_varpi = std::f64::consts::PI / (2.0 * h);
        let sa = if real { Point::new(1.0, 0.0) } else { Point::from_polar(1.0, two_varpi * a.im) };
        Self { two_varpi, x0: a.re, y0, sa, sigma: sa * (two_varpi * r), real }
    }

    /// Whether the series is centred on a wall, with real coefficients only.
    pub fn real(&self) -> bool {
        self.real
    }

    /// `s` at `z`, or None where every multipole is negligible.
    #[inline]
    fn s(&self, z: Point) -> Option<Point> {
        let x = self.two_varpi * (z.re - self.x0);
        (x.abs() < FAR).then(|| Point::from_polar(x.exp(), self.two_varpi * (z.im - self.y0)))
    }

    /// What every term at `z` is made of: `s`, `d = s - s_a`, `m = s + conj s_a`, and the
    /// ratios `t = σ/d`, `u = -conj σ/m` (`u = conj t` on the walls, which keeps them exact);
    /// None where every multipole is negligible.
    #[inline]
    fn at(&self, z: Point) -> Option<SeriesFrame> {
        let s = self.s(z)?;
        let (d, m) = (s - self.sa, s + self.sa.conj());
        Some(SeriesFrame { s, d, m, t: self.sigma / d, u: -self.sigma.conj() / m })
    }

    /// The flow `u - i v` of the series with coefficients `c` (orders 1, 2, ...) at `z`.
    #[inline]
    pub fn eval(&self, z: Point, c: &[Point]) -> Point {
        let Some(p) = self.at(z) else { return Point::default() };
        // Σ n c_n t^n and Σ n conj(c_n) u^n by Horner.
        let (mut direct, mut mirror) = (Point::default(), Point::default());
        for (n, cn) in c.iter().enumerate().rev() {
            let order = (n + 1) as f64;
            direct = (direct + cn * order) * p.t;
            mirror = (mirror + cn.conj() * order) * p.u;
        }
        -self.two_varpi * p.s * (direct / p.d + mirror / p.m)
    }

    /// The flows of the terms of orders `1..=orders` at `z` for the coefficients 1 and `i`.
    fn terms(&self, z: Point, orders: usize, out: &mut [(Point, Point); ORDERS]) {
        let Some(p) = self.at(z) else {
            out.fill((Point::default(), Point::default()));
            return;
        };
        let scale = -self.two_varpi * p.s;
        // t^n/d and u^n/m by multiplication: one division each for all orders.
        let (mut tn, mut un) = (scale / p.d, scale / p.m);
        for (n, slot) in out[..orders].iter_mut().enumerate() {
            tn *= p.t;
            un *= p.u;
            let order = (n + 1) as f64;
            let (direct, mirror) = (tn * order, un * order);
            *slot = (direct + mirror, Point::i() * (direct - mirror));
        }
    }
}

/// A point in a series' frame (see [`Series::at`]).
struct SeriesFrame {
    s: Point,
    d: Point,
    m: Point,
    t: Point,
    u: Point,
}

/// A fitted series: multipole coefficients (those beyond `orders` are zero) and the
/// strength of the centre source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fitted {
    pub coeffs: [Point; ORDERS],
    pub orders: usize,
    pub source: f64,
}

impl Default for Fitted {
    fn default() -> Self {
        Self { coeffs: [Point::default(); ORDERS], orders: 0, source: 0.0 }
    }
}

/// The series' convergence rate `ρ` for a circle of radius `r` at `a` in a lane of
/// half-width `h`, with the flow's other singularities (the goal, the other obstacles'
/// centres) at `others`: the coefficients fall like `ρ^n`, `ρR` the distance from the
/// centre to the farthest singularity of the continued flow inside the circle. Two kinds
/// matter: the circle's own wall images reflected back into it, which sit at its limiting
/// point with the nearer wall, `ρR = d - sqrt(d² - R²)` for a wall `d` away; and the
/// reflection in the circle of another singularity's wall image at distance `D`, `ρ = R/D`.
/// A circle that reaches a wall (`d <= R`) has `ρ = 1`.
///
/// A circle centred on a wall meets it at right angles: reflected in that wall it is a
/// whole circle, whose nearer wall is the far one, `2h` away. Everything reflected in the
/// wall it sits on is already in the flow the series corrects (the lane's images of a sink
/// or a doublet, and of their images in this circle, which the circle's symmetry maps onto
/// one another), so only images in the far wall count.
pub fn convergence_rate(h: f64, a: Point, r: f64, others: impl Iterator<Item = Point>) -> f64 {
    let on_a_wall = centred_on_a_wall(h, a);
    let d = if on_a_wall { 2.0 * h } else { (h - a.im.abs()).max(0.0) };
    if d <= r {
        return 1.0;
    }
    let mut rho = (d - (d * d - r * r).sqrt()) / r;
    let far_wall = -a.im.signum() * h;
    for p in others {
        for wall in [h, -h] {
            if on_a_wall && wall != far_wall {
                continue;
            }
            let mirror = Point::new(p.re, 2.0 * wall - p.im);
            rho = rho.max(r / (mirror - a).length());
        }
    }
    rho.min(1.0)
}

/// How many orders a circle of convergence rate `rho` (see [`convergence_rate`]) needs to
/// reach `aim` (the series' truncation error relative to the flow): `n = ln(aim)/ln(ρ)`, capped at [`ORDERS`] for real coefficients (`real`: a circle centred
/// on a wall), at 32 for complex ones. A circle that reaches a wall (`ρ = 1`) has a
/// corner where it meets the wall, around which no series at the centre converges
/// geometrically: its residual levels off near 1e-5 of the flow's speed from
/// [`WALL_ORDERS`] on (measured: `examples/lane_residuals.rs`), so it gets those.
pub fn orders_for(rho: f64, real: bool, aim: f64) -> usize {
    if rho.is_nan() || rho <= 0.0 {
        return 1;
    }
    if rho >= 1.0 {
        return WALL_ORDERS;
    }
    let cap = if real { ORDERS } else { COMPLEX_ORDERS };
    ((aim.ln() / rho.ln()).ceil() as usize).clamp(1, cap)
}

/// The most points [`collocation`] spaces round a circle (half of them in the lane, for a
/// circle centred on a wall at its most orders).
const CIRCLE_POINTS: usize = POINTS_PER_ORDER_ON_A_WALL * ORDERS;

/// What one fit works in, kept from one build of the field to the next: the least-squares
/// system (about 85 kB, which a fresh one would clear each time) and the unit circle's
/// points for the last count asked for (the same count from cycle to cycle, while the orders
/// stay).
#[derive(Clone)]
pub struct Workspace {
    a: [f64; ROWS * UNKNOWNS],
    b: [[f64; ROWS]; 2],
    /// How many points `circle` holds, 0 before the first fit.
    circle_points: usize,
    circle: [Point; CIRCLE_POINTS],
}

impl std::fmt::Debug for Workspace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Workspace").field("circle_points", &self.circle_points).finish_non_exhaustive()
    }
}

impl Workspace {
    pub fn new() -> Box<Self> {
        Box::new(Self {
            a: [0.0; ROWS * UNKNOWNS],
            b: [[0.0; ROWS]; 2],
            circle_points: 0,
            circle: [Point::default(); CIRCLE_POINTS],
        })
    }

    /// `points` unit vectors evenly round the circle, at half-steps from the `x` axis.
    fn unit_circle(&mut self, points: usize) -> &[Point] {
        if self.circle_points != points {
            for (j, n) in self.circle[..points].iter_mut().enumerate() {
                *n = Point::from_polar(1.0, std::f64::consts::TAU * (j as f64 + 0.5) / points as f64);
            }
            self.circle_points = points;
        }
        &self.circle[..points]
    }
}

/// The collocation points for `orders` on a circle of radius `r` at `a` that lie inside the
/// lane (`at_a_wall`: the circle reaches a wall, and gets denser points): `(z, unit
/// normal)` into `out`; returns how many.
pub fn collocation(
    h: f64,
    a: Point,
    r: f64,
    orders: usize,
    at_a_wall: bool,
    work: &mut Workspace,
    out: &mut [(Point, Point); POINTS],
) -> usize {
    let per_order = if centred_on_a_wall(h, a) {
        POINTS_PER_ORDER_ON_A_WALL
    } else if at_a_wall {
        POINTS_PER_ORDER_AT_A_WALL
    } else {
        POINTS_PER_ORDER
    };
    let points = per_order * orders.clamp(1, ORDERS);
    let mut m = 0;
    for &n in work.unit_circle(points) {
        let z = a + n * r;
        if z.im.abs() < h * (1.0 - 1e-9) && m < out.len() {
            out[m] = (z, n);
            m += 1;
        }
    }
    m
}

/// Fit the series' coefficients so that, at the collocation `points` (at most [`POINTS`]),
/// the normal flow of the series plus a source at the centre (whose unit normal flow there
/// is `source_flow`) equals `targets` (two right-hand sides), by least squares. The source carries the net
/// flux a circle across a wall sweeps through its part in the lane as it moves (zero for
/// a circle clear of the walls, where the fit finds it so). Orders beyond
/// what the points can determine stay zero.
pub fn fit(
    series: &Series,
    orders: usize,
    points: &[(Point, Point)],
    source_flow: &[f64],
    targets: [&[f64]; 2],
    regularisation: f64,
    work: &mut Workspace,
) -> [Fitted; 2] {
    let mut out = [Fitted::default(); 2];
    let m = points.len();
    // Keep the system over-determined (at least 1.5 rows an unknown): a circle mostly
    // beyond a wall has few points in the lane.
    let real = series.real;
    let orders = if real { orders.min(m / 2).min(ORDERS) } else { orders.min(m / 3).min(COMPLEX_ORDERS) };
    if orders == 0 {
        return out;
    }
    // Unknowns: Re c_n (and Im c_n unless the series is real), and the source.
    let per_order = if real { 1 } else { 2 };
    let p = per_order * orders + 1;
    // Rows: the points, and one Tikhonov row an unknown if regularised.
    let rows = if regularisation > 0.0 { m + p } else { m };
    // Column-major with a stride of the rows in use: a[col * rows + row]. Column 2(n-1) is
    // Re c_n, 2(n-1)+1 is Im c_n (for a real series, column n-1 is Re c_n), the last the
    // source. Every entry in use is written below, so the workspace is not cleared.
    let a = &mut work.a[..rows * p];
    let mut flows = [(Point::default(), Point::default()); ORDERS];
    for (row, &(z, normal)) in points.iter().enumerate() {
        series.terms(z, orders, &mut flows);
        for (n, (re, im)) in flows[..orders].iter().enumerate() {
            a[per_order * n * rows + row] = (re * normal).re;
            if !real {
                a[(2 * n + 1) * rows + row] = (im * normal).re;
            }
        }
    }
    a[(p - 1) * rows..(p - 1) * rows + m].copy_from_slice(&source_flow[..m]);
    let b = &mut work.b;
    for (b, t) in b.iter_mut().zip(targets) {
        b[..m].copy_from_slice(&t[..m]);
        b[m..rows].fill(0.0);
    }
    // Tikhonov rows (target zero): `regularisation` times each column's norm. On an arc (a
    // circle across a wall) the high orders are nearly dependent, and an unregularised fit
    // buys the last digits of the residual with huge cancelling coefficients, whose
    // rounding then shows everywhere else (the walls drift from exact by 1e-5).
    if regularisation > 0.0 {
        for (j, col) in a.chunks_exact_mut(rows).enumerate() {
            let (fitted, tikhonov) = col.split_at_mut(m);
            let norm = fitted.iter().map(|v| v * v).sum::<f64>().sqrt();
            tikhonov.fill(0.0);
            tikhonov[j] = regularisation * norm;
        }
    }
    let solutions = least_squares(a, rows, p, b);
    for (x, fitted) in solutions.iter().zip(&mut out) {
        for n in 0..orders {
            fitted.coeffs[n] = if real { Point::new(x[n], 0.0) } else { Point::new(x[2 * n], x[2 * n + 1]) };
        }
        fitted.orders = orders;
        fitted.source = x[p - 1];
    }
    out
}

/// Least squares of the column-major `a` (`rows` by `p`) against both right-hand sides, by
/// Householder QR applied to them as it goes, then back substitution; a column the points
/// cannot see stays zero. `a` and `b` are overwritten.
fn least_squares(a: &mut [f64], rows: usize, p: usize, b: &mut [[f64; ROWS]; 2]) -> [[f64; UNKNOWNS]; 2] {
    let m = rows;
    let mut diag = [0.0; UNKNOWNS];
    for k in 0..p {
        let (head, tail) = a.split_at_mut((k + 1) * rows);
        let v = &mut head[k * rows + k..];
        let norm = v.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm == 0.0 {
            continue;
        }
        let alpha = if v[0] > 0.0 { -norm } else { norm };
        // v = x - alpha e_1, stored in place of column k.
        v[0] -= alpha;
        let vnorm2 = v.iter().map(|v| v * v).sum::<f64>();
        diag[k] = alpha;
        if vnorm2 == 0.0 {
            continue;
        }
        let v = &*v;
        for col in tail.chunks_exact_mut(rows) {
            reflect(v, vnorm2, &mut col[k..m]);
        }
        for rhs in b.iter_mut() {
            reflect(v, vnorm2, &mut rhs[k..m]);
        }
    }
    let scale = diag[..p].iter().fold(0.0f64, |acc, d| acc.max(d.abs()));
    let mut out = [[0.0; UNKNOWNS]; 2];
    for (rhs, x) in b.iter().zip(&mut out) {
        for k in (0..p).rev() {
            if diag[k].abs() <= 1e-12 * scale {
                continue;
            }
            let sum: f64 = (k + 1..p).map(|j| a[j * rows + k] * x[j]).sum();
            x[k] = (rhs[k] - sum) / diag[k];
        }
    }
    out
}

/// Apply the Householder reflection `I - 2 v vᵀ/|v|²` to `x`. The dot product runs in four
/// independent sums, so it vectorises instead of waiting on one chain of additions (the
/// fit is most of a lane cycle's planning).
#[inline]
fn reflect(v: &[f64], vnorm2: f64, x: &mut [f64]) {
    let mut sums = [0.0; 4];
    let (vc, xc) = (v.chunks_exact(4), x.chunks_exact(4));
    let (vr, xr) = (vc.remainder(), xc.remainder());
    for (v4, x4) in vc.zip(xc) {
        for j in 0..4 {
            sums[j] += v4[j] * x4[j];
        }
    }
    let tail: f64 = vr.iter().zip(xr).map(|(v, x)| v * x).sum();
    let f = 2.0 * ((sums[0] + sums[1]) + (sums[2] + sums[3]) + tail) / vnorm2;
    for (x, v) in x.iter_mut().zip(v) {
        *x -= f * v;
    }
}
