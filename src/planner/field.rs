//! The navigation function: a complex velocity field `F(z) = u - i v` whose streamlines
//! lead to the goal around circular obstacles, moving or not, in free space or in a lane.
//!
//! Built from the corrected equations of docs/planner.md (the paper's print
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
//!        + M_k(z)                                               lane only: the multipole series at k
//! F(z)   = Σ_k w_k F_k(z),   w_k ∝ 1 / (|z - z_k| - R_k)        gap-distance blend (eq. 28, N obstacles)
//! ```
//!
//! with `z_sk' = z_k + R_k² / conj(z_s - z_k)`, `z_kj' = z_k + R_k² / conj(z_j - z_k)`,
//! `μ_kj' = -conj(μ_j) R_k² / conj(z_j - z_k)²` (circle theorem), `K(r) = (r/R)(1 - e^{-c1 r})`.
//! For two obstacles the weights are the paper's `1 - α`, `α` with `α = r_1/(r_1 + r_2)`;
//! on the boundary of obstacle `k` its weight is exactly 1, so each boundary condition holds.
//! Images and weights are recomputed from the current geometry on every [`Field::new`].
//!
//! In a lane the circle theorem's images are free-space ones, so alone they leave each
//! circle only nearly a streamline (21% of the flow's speed at E2's 70% blockage). `M_k`
//! cancels what is left: a series of lane multipoles at `z_k` (with a source carrying the
//! flux a circle across a wall sweeps), fitted by least squares on the circle each time the
//! field is built ([`super::lane_series`]). It leaves the walls exact and each circle a
//! streamline to the fit's residual: below 1e-6 of the flow's speed up to a 90% blockage,
//! clear of the walls or reaching one (which `in_lane` first closes against it).

use crate::Point;
use arrayvec::ArrayVec;

use crate::geometry::Length;

use std::sync::Arc;

use super::lane_series::{self, Fitted, Series, ORDERS, POINTS};
use super::room::{Room, RoomSink, ROOM_HOLD};
use super::space::Space;

/// The most obstacles one field holds (fixed arrays: evaluation never allocates).
pub const MAX_OBSTACLES: usize = 16;

/// An obstacle as the planner sees it: centre, velocity, planning radius `R`
/// (obstacle radius + robot radius + margin).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanObstacle {
    pub center: Point,
    pub velocity: Point,
    pub radius: f64,
}

/// The goal sink: where, how strong, how it is smoothed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sink {
    pub goal: Point,
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
    #[error("goal lies outside the room's free region (in a wall or static obstacle grown by the robot, or beyond the view)")]
    GoalOutsideRoom,
    #[error("point lies {0:.3} m outside the room's free region")]
    OutsideRoom(f64),
    #[error("the lane's aim {0:e} is outside {lo:e} to {hi:e}", lo = lane_series::TIGHTEST_AIM, hi = lane_series::LOOSEST_AIM)]
    BadLaneAim(f64),
}

/// The field for one geometry: obstacles, images and goal fixed, evaluated at any point.
#[derive(Debug, Clone)]
pub struct Field {
    space: Space,
    sink: Sink,
    n: usize,
    obstacles: [PlanObstacle; MAX_OBSTACLES],
    /// Doublet moments `μ_k = R_k² V_k`.
    moments: [Point; MAX_OBSTACLES],
    /// Image of the goal sink in circle k.
    sink_images: [Point; MAX_OBSTACLES],
    /// Lane only (empty in free space, which so never pays for it): each obstacle's
    /// multipole series that makes its circle a streamline (see [`super::lane_series`]).
    lane_series: ArrayVec<LaneSeries, MAX_OBSTACLES>,
    /// Some circle reaching a wall was left unclosed, its closure taking in the robot or the
    /// goal (see `in_lane`): its series is the less exact arc fit.
    unclosed_at_a_wall: bool,
    /// Where the lane series are fitted, kept across rebuilds (see
    /// [`lane_series::Workspace`]); made with a lane's field, so that a control cycle's
    /// rebuild does not allocate.
    fit_work: Option<Box<lane_series::Workspace>>,
    /// What the lane series aim at: their truncation error relative to the flow on the
    /// circle ([`Field::set_lane_aim`]).
    lane_aim: f64,
    /// The room's walls, static obstacles and view's edge, with its sink flow solved for
    /// the goal (kept while the goal stays).
    room: Option<RoomField>,
}

/// The room and its unit sink's flow for the present goal.
#[derive(Debug, Clone)]
struct RoomField {
    room: Arc<Room>,
    sink: RoomSink,
    solved: bool,
}

/// Within this distance of the room's boundary, the field loses its part that heads into
/// the boundary, wholly on it, m ([`keep_off`]).
const ROOM_BEND_BAND: f64 = 0.05;

/// The flow `f` (`u - i v`) at a point `depth` inside the room's boundary, whose inward
/// normal there is `inward`, with what of it heads into the boundary taken out: wholly on
/// (or beyond) the boundary, not at all from [`ROOM_BEND_BAND`] inside. The circles'
/// bending is not tangent to the room, and the room's own flow only at the panels'
/// midpoints: so no term carries the robot into a wall, nor against the supervisor, which
/// keeps it off the real walls a little inside the field's boundary.
fn keep_off(f: Point, depth: f64, inward: Point) -> Point {
    let toward = depth.max(0.0) / ROOM_BEND_BAND;
    if toward >= 1.0 {
        return f;
    }
    let v = f.conj();
    let along = (v * inward.conj()).re;
    if along >= 0.0 {
        return f;
    }
    (v - inward * (along * (1.0 - toward))).conj()
}

impl RoomField {
    /// [`keep_off`] the field's boundary (the panels, `depth` inside it, `inward` its
    /// normal there), and then the real room's nearest edge (the walls and furniture grown
    /// as the field grows them, the view's edge), which the supervisor keeps the robot off:
    /// near a rounded corner the two differ a little in place and in direction.
    fn keep_off(&self, f: Point, z: Point, depth: f64, inward: Point) -> Point {
        let f = keep_off(f, depth, inward);
        // The real room's edge lies within the rounding's sliver of the field's boundary.
        if depth > ROOM_BEND_BAND + ROOM_ROUNDING_SLIVER {
            return f;
        }
        let mut nearest = arrayvec::ArrayVec::<(f64, Point, f64), 1>::new();
        self.room.lines_near(z, self.room.grow(), ROOM_BEND_BAND, &mut nearest);
        match nearest.first() {
            Some(&(gap, toward, _)) => keep_off(f, gap, -toward),
            None => f,
        }
    }
}

/// How far the field's boundary strays inside the real room's edge, at most, m: the
/// rounding of a room's corners (its sliver, some 2 cm for a right angle), with room to
/// spare.
const ROOM_ROUNDING_SLIVER: f64 = 0.05;

/// How far beyond the room's boundary (the grown walls and furniture, the view's edge,
/// their corners rounded) the field still steers the robot back, m. The boundary is grown
/// by the robot's radius and the supervisor's margin, so a centre up to here still clears the
/// real room; beyond, there is no field.
pub const ROOM_TOLERANCE: f64 = 0.05;

/// One obstacle's lane series: its frame, and its coefficients for the sink terms (scaled
/// by K like them) and for the obstacles' motion.
#[derive(Debug, Clone)]
struct LaneSeries {
    series: Series,
    sink_fit: Fitted,
    motion_fit: Fitted,
}

fn finite(z: Point) -> bool {
    z.re.is_finite() && z.im.is_finite()
}

impl Field {
    /// Build the field, checking the configuration.
    pub fn new(space: Space, sink: Sink, obstacles: &[PlanObstacle]) -> Result<Self, FieldError> {
        let mut field = Self::empty(space, sink);
        field.rebuild(space, sink, obstacles)?;
        Ok(field)
    }

    /// A field with no obstacles, to [`rebuild`](Self::rebuild) into. The lane series'
    /// storage is left unwritten; a lane's field makes its fit workspace here (about 90 kB,
    /// once), so that rebuilding it never allocates.
    pub fn empty(space: Space, sink: Sink) -> Self {
        Self {
            space,
            sink,
            n: 0,
            obstacles: [PlanObstacle { center: Point::default(), velocity: Point::default(), radius: 1.0 };
                MAX_OBSTACLES],
            moments: [Point::default(); MAX_OBSTACLES],
            sink_images: [Point::default(); MAX_OBSTACLES],
            lane_series: ArrayVec::new(),
            unclosed_at_a_wall: false,
            fit_work: matches!(space, Space::Lane { .. }).then(lane_series::Workspace::new),
            lane_aim: lane_series::EXACT_AIM,
            room: None,
        }
    }

    /// The lane series' aim from the next rebuild on: their truncation error relative to
    /// the flow on each circle, from [`lane_series::TIGHTEST_AIM`] to [`lane_series::LOOSEST_AIM`],
    /// [`lane_series::EXACT_AIM`] unless set. A looser aim fits fewer orders. An aim outside
    /// that range (or NaN) is refused and the field keeps its aim.
    pub fn set_lane_aim(&mut self, aim: f64) -> Result<(), FieldError> {
        if !lane_series::aim_allowed(aim) {
            return Err(FieldError::BadLaneAim(aim));
        }
        self.lane_aim = aim;
        Ok(())
    }

    /// Put the field in `room` (or in no room). The room's sink flow is solved for the goal
    /// on the next build, and again only when the goal changes.
    pub fn set_room(&mut self, room: Option<&Arc<Room>>) {
        let same = match (&self.room, room) {
            (Some(a), Some(b)) => Arc::ptr_eq(&a.room, b),
            (None, None) => true,
            _ => false,
        };
        if !same {
            self.room = room.map(|r| RoomField { room: Arc::clone(r), sink: RoomSink::for_room(r), solved: false });
        }
    }

    /// The room the field is in, if any.
    pub fn room(&self) -> Option<&Room> {
        self.room.as_ref().map(|r| &*r.room)
    }

    /// Build the field in place, checking the configuration. A field is large in a lane
    /// (its series: about 17 kB), so a control cycle builds into one rather than copying a
    /// new one out. On an error the field is left without obstacles: do not use it.
    pub fn rebuild(&mut self, space: Space, sink: Sink, obstacles: &[PlanObstacle]) -> Result<(), FieldError> {
        self.rebuild_clear_of(space, sink, obstacles, None)
    }

    /// [`rebuild`](Self::rebuild), leaving `robot` (where the robot is) outside any circle
    /// that `in_lane` would close over it, as it leaves the goal.
    pub fn rebuild_clear_of(
        &mut self,
        space: Space,
        sink: Sink,
        obstacles: &[PlanObstacle],
        robot: Option<Point>,
    ) -> Result<(), FieldError> {
        self.n = 0;
        self.lane_series.clear();
        self.unclosed_at_a_wall = false;
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
        if let Some(r) = &mut self.room {
            // Checked and solved when the goal changes; a goal refused stays unsolved, and
            // is refused again the next time.
            if !r.solved || r.sink.goal() != sink.goal {
                if r.room.depth(sink.goal) <= 0.0 {
                    return Err(FieldError::GoalOutsideRoom);
                }
                r.room.sink_flow(sink.goal, &mut r.sink);
                r.solved = true;
            }
        }
        self.space = space;
        self.sink = sink;
        for (k, o) in obstacles.iter().enumerate() {
            if !finite(o.center) || !finite(o.velocity) || !o.radius.is_finite() {
                return Err(FieldError::NonFinite);
            }
            if o.radius <= 0.0 {
                return Err(FieldError::BadRadius { index: k });
            }
            let o = match space {
                Space::Free => *o,
                Space::Lane { half_width } => {
                    let (o, unclosed) = in_lane(*o, half_width, [Some(sink.goal), robot]);
                    self.unclosed_at_a_wall |= unclosed;
                    o
                }
            };
            let to_goal = sink.goal - o.center;
            if to_goal.length() <= o.radius {
                return Err(FieldError::GoalInsideObstacle { index: k });
            }
            let r2 = o.radius * o.radius;
            self.obstacles[k] = o;
            self.moments[k] = o.velocity * r2;
            self.sink_images[k] = o.center + r2 / to_goal.conj();
        }
        let n = obstacles.len();
        if let Space::Lane { half_width } = space {
            let mut work = self.fit_work.take().unwrap_or_else(lane_series::Workspace::new);
            for k in 0..n {
                let fitted = self.fit_lane_series(k, n, half_width, &mut work);
                self.lane_series.push(fitted);
            }
            self.fit_work = Some(work);
        }
        self.n = n;
        Ok(())
    }

    /// Fit obstacle `k`'s multipole series: on its circle the normal flow of the sink terms
    /// becomes zero, and that of the motion terms (every obstacle's doublet, the other
    /// doublets' images in this circle) becomes the obstacle's own normal speed.
    fn fit_lane_series(&self, k: usize, n: usize, half_width: f64, work: &mut lane_series::Workspace) -> LaneSeries {
        let space = self.space;
        let o = self.obstacles[k];
        let series = Series::new(half_width, o.center, o.radius);
        let others = self.obstacles[..n].iter().enumerate().filter(|&(i, _)| i != k).map(|(_, p)| p.center);
        let rho = lane_series::convergence_rate(half_width, o.center, o.radius, others.chain([self.sink.goal]));
        let orders = lane_series::orders_for(rho, series.real(), self.lane_aim);
        let regularisation = if rho >= 1.0 { lane_series::WALL_REGULARISATION } else { 0.0 };
        let mut points = [(Point::default(), Point::default()); POINTS];
        let m = lane_series::collocation(half_width, o.center, o.radius, orders, rho >= 1.0, work, &mut points);
        let (mut sink_target, mut motion_target, mut source_flow) = ([0.0; POINTS], [0.0; POINTS], [0.0; POINTS]);
        for (j, &(z, normal)) in points[..m].iter().enumerate() {
            let source = space.sink(z, o.center);
            let sink_flow = space.sink(z, self.sink.goal) + space.sink(z, self.sink_images[k]) - source;
            let mut motion_flow = Point::default();
            for (i, other) in self.obstacles[..n].iter().enumerate() {
                motion_flow += space.doublet(z, other.center, self.moments[i]);
                if i != k {
                    if let Some((at, moment)) = self.doublet_image(k, i) {
                        motion_flow += space.doublet(z, at, moment);
                    }
                }
            }
            sink_target[j] = -(sink_flow * normal).re;
            source_flow[j] = -(source * normal).re;
            motion_target[j] = (o.velocity * normal.conj()).re - (motion_flow * normal).re;
        }
        let [sink_fit, motion_fit] = lane_series::fit(
            &series,
            orders,
            &points[..m],
            &source_flow[..m],
            [&sink_target[..m], &motion_target[..m]],
            regularisation,
            work,
        );
        LaneSeries { series, sink_fit, motion_fit }
    }

    /// The image of obstacle `j`'s doublet in circle `k` (circle theorem): at
    /// `z_k + R_k²/conj(z_j - z_k)`, moment `-conj(μ_j) R_k² / conj(z_j - z_k)²`.
    #[inline]
    fn doublet_image(&self, k: usize, j: usize) -> Option<(Point, Point)> {
        let o = &self.obstacles[k];
        let d = (self.obstacles[j].center - o.center).conj();
        let r2 = o.radius * o.radius;
        (d.length() > 0.0).then(|| (o.center + r2 / d, -self.moments[j].conj() * r2 / (d * d)))
    }

    pub fn space(&self) -> Space {
        self.space
    }
    /// Whether a circle reaching a wall was left unclosed in this build, because closing it
    /// would take in the robot or the goal: its residual is the arc fit's (1e-5 to 1e-2),
    /// not the closed circles' 1e-6.
    pub fn unclosed_at_a_wall(&self) -> bool {
        self.unclosed_at_a_wall
    }
    pub fn sink(&self) -> &Sink {
        &self.sink
    }
    pub fn obstacles(&self) -> &[PlanObstacle] {
        &self.obstacles[..self.n]
    }

    /// The multipole orders obstacle `k`'s lane series was fitted with (None in free
    /// space, or if there is no obstacle `k`).
    pub fn lane_orders(&self, k: usize) -> Option<usize> {
        self.lane_series.get(k).map(|l| l.sink_fit.orders)
    }

    /// How far obstacle `k`'s planned circle is from a streamline of the field: the worst
    /// normal-flow residual, the flow's normal component minus the obstacle's own, over
    /// `samples` points of the circle's part inside the lane (just outside the circle),
    /// relative to the largest flow speed met there (or the obstacle's speed if larger).
    /// None if there is no obstacle `k`.
    pub fn circle_residual(&self, k: usize, samples: usize) -> Option<f64> {
        let o = self.obstacles().get(k)?;
        let (mut worst, mut scale) = (0.0f64, o.velocity.length());
        for j in 0..samples {
            let normal = Point::from_polar(1.0, std::f64::consts::TAU * j as f64 / samples as f64);
            let z = o.center + normal * (o.radius * (1.0 + 1e-11));
            if let Ok(v) = self.velocity(z) {
                worst = worst.max(((v - o.velocity) * normal.conj()).re.abs());
                scale = scale.max(v.length());
            }
        }
        Some(worst / scale.max(1e-300))
    }

    /// `F(z) = u - i v` at `z`. The robot's velocity command is `conj(F)`.
    pub fn eval(&self, z: Point) -> Result<Point, FieldError> {
        if !finite(z) {
            return Err(FieldError::NonFinite);
        }
        if let Space::Lane { half_width } = self.space {
            if z.im.abs() >= half_width {
                return Err(FieldError::OutsideLane);
            }
        }
        let r = (z - self.sink.goal).length();
        if r == 0.0 {
            return Ok(Point::default()); // K(0) = 0: at rest on the goal
        }
        let km = self.sink.smoothing(r) * self.sink.strength;
        let Some(room) = &self.room else { return self.eval_obstacles(z, km) };
        // The room is one more boundary of the gap-distance blend (docs/planner.md, "Rooms").
        let (depth, inward) = room.room.depth_and_inward(z);
        if depth < -ROOM_TOLERANCE {
            return Err(FieldError::OutsideRoom(-depth));
        }
        let at = if depth < ROOM_HOLD { z + inward * (ROOM_HOLD - depth) } else { z };
        let room_flow = self.sink.smoothing((at - self.sink.goal).length())
            * self.sink.strength
            * room.room.eval_sink(&room.sink, at);
        if self.n == 0 {
            return Ok(room.keep_off(room_flow, z, depth, inward));
        }
        // The circles bend the room's flow as they bend the sink's: each one's field less
        // the bare sink, and the image in it of the room's own correction, so that its
        // circle stays a streamline (the circle theorem).
        let (circles, total) = self.eval_obstacles_weighed(z, km)?;
        let mut bend = circles - km * self.space.sink(z, self.sink.goal);
        for o in &self.obstacles[..self.n] {
            let gap = (z - o.center).length() - o.radius;
            let d = z - o.center;
            let r2 = o.radius * o.radius;
            let image = -r2 / (d * d) * room.room.eval_correction(&room.sink, o.center + r2 / d.conj()).conj();
            bend += image * (km / (gap * total));
        }
        Ok(room.keep_off(room_flow + bend, z, depth, inward))
    }

    /// The field of the sink and the obstacles alone (the lane's walls included).
    #[inline]
    fn eval_obstacles(&self, z: Point, km: f64) -> Result<Point, FieldError> {
        if self.n == 0 {
            return Ok(km * self.space.sink(z, self.sink.goal));
        }
        self.eval_obstacles_weighed(z, km).map(|(f, _)| f)
    }

    /// The field of the sink and the obstacles, and the sum of their gap-distance weights'
    /// numerators `Σ 1/gap_k` (what another boundary's weight is set against).
    fn eval_obstacles_weighed(&self, z: Point, km: f64) -> Result<(Point, f64), FieldError> {
        let space = self.space;
        let mut f = km * space.sink(z, self.sink.goal);
        // Gap-distance weights w_k ∝ 1/gap_k.
        let mut inv_gap = [0.0; MAX_OBSTACLES];
        let mut total = 0.0;
        for (k, (o, inv)) in self.obstacles[..self.n].iter().zip(&mut inv_gap).enumerate() {
            let gap = (z - o.center).length() - o.radius;
            if gap <= 0.0 {
                return Err(FieldError::InsideObstacle { index: k });
            }
            *inv = gap.recip();
            total += *inv;
        }
        for (k, (o, inv)) in self.obstacles[..self.n].iter().zip(inv_gap).enumerate() {
            let w = inv / total;
            f += space.doublet(z, o.center, self.moments[k]);
            // The circle theorem's source at the centre (scaled by K like the sink), with
            // the lane fit's sources (zero clear of the walls).
            let lane = self.lane_series.get(k);
            let (sink_source, motion_source) = lane.map_or((0.0, 0.0), |l| (l.sink_fit.source, l.motion_fit.source));
            let source = km * (1.0 + sink_source) + motion_source;
            let mut fk = km * space.sink(z, self.sink_images[k]) - source * space.sink(z, o.center);
            for j in (0..self.n).filter(|&j| j != k) {
                if let Some((at, moment)) = self.doublet_image(k, j) {
                    fk += space.doublet(z, at, moment);
                }
            }
            if let Some(lane) = lane {
                // The series is real-linear in its coefficients: one evaluation for both.
                let orders = lane.sink_fit.orders.max(lane.motion_fit.orders);
                let mut c = [Point::default(); ORDERS];
                for ((c, a), b) in c[..orders].iter_mut().zip(&lane.sink_fit.coeffs).zip(&lane.motion_fit.coeffs) {
                    *c = a * km + b;
                }
                fk += lane.series.eval(z, &c[..orders]);
            }
            f += fk * w;
        }
        Ok((f, total))
    }

    /// The velocity command at `z`: `u + i v = conj(F(z))`.
    pub fn velocity(&self, z: Point) -> Result<Point, FieldError> {
        self.eval(z).map(|f| f.conj())
    }
}

/// How an obstacle meets the lane's walls in the field. A circle that nearly touches a wall
/// leaves a passage the robot could not take anyway, and a cusp of nearly still flow that
/// no series at the centre converges in; one that crosses a wall meets it at a corner that
/// no series converges at either. Either is closed against the wall: replaced by the
/// smallest circle centred on the wall that covers it (its part in the lane, for a centre
/// estimated beyond the wall). Centred there it meets the wall at right angles, and the
/// wall is a line of symmetry of its flow (see [`lane_series::Series::new`]). Its far side
/// is the true circle's, so it blocks the lane no more; it is longer along the wall.
///
/// The closed circle slides along the wall with the obstacle's velocity along it. Its
/// motion across the wall is not in the field: a circle centred on a wall cannot leave it,
/// and a boundary moving across a fixed wall has a corner where the flow is singular. The
/// closure is made afresh from each cycle's estimate, which carries that motion.
///
/// A closure is not made where it would take in a point that the circle leaves out (the
/// goal, the robot): the robot would be stopped, or the goal blocked, by a circle grown for
/// the series' sake. That circle stays as planned, its series converging less well.
/// Returns the circle as planned, and whether it reaches a wall but was left unclosed.
fn in_lane(o: PlanObstacle, half_width: f64, keep_clear: [Option<Point>; 2]) -> (PlanObstacle, bool) {
    let closed = closed_against_the_wall(o, half_width);
    let takes_in = |p: Point| (p - closed.center).length() <= closed.radius && (p - o.center).length() > o.radius;
    if closed != o && keep_clear.into_iter().flatten().any(takes_in) {
        (o, true)
    } else {
        (closed, false)
    }
}

fn closed_against_the_wall(o: PlanObstacle, half_width: f64) -> PlanObstacle {
    let side = if o.center.im >= 0.0 { 1.0 } else { -1.0 };
    let d = half_width - o.center.im.abs(); // to the nearer wall, negative beyond it
    let gap = d - o.radius;
    if gap >= WALL_CLOSE * o.radius {
        return o; // clear of the walls: as it is
    }
    // Centred on the wall, the smallest circle that covers the true one's part in the lane:
    // out to its far side (d + R) for a centre inside the lane, to the ends of its chord on
    // the wall for one beyond it.
    let radius = if d >= 0.0 { d + o.radius } else { (o.radius * o.radius - d * d).max(0.0).sqrt() };
    let radius = radius.max(MIN_CLOSED * o.radius);
    PlanObstacle {
        center: Point::new(o.center.re, side * half_width),
        velocity: Point::new(o.velocity.re, 0.0),
        radius,
    }
}

/// The smallest closed circle, as a fraction of the planned radius (a centre estimated
/// beyond the wall by nearly the radius).
const MIN_CLOSED: f64 = 0.25;

/// A gap to a wall below this fraction of the radius is closed (see `in_lane`).
pub const WALL_CLOSE: f64 = 0.1;
/// Streamlines of `field` from `seeds`: unit-speed RK2 steps of `step` metres until they
/// leave `bounds`, reach the goal, or meet an obstacle.
pub fn streamlines(
    field: &Field,
    seeds: &[Point],
    step: f64,
    max_steps: usize,
    bounds: (Point, Point),
) -> Vec<Vec<Point>> {
    let dir = |z: Point| field.velocity(z).ok().filter(|v| v.length() > 1e-12).map(|v| v / v.length());
    let inside = |z: Point| z.re >= bounds.0.re && z.re <= bounds.1.re && z.im >= bounds.0.im && z.im <= bounds.1.im;
    seeds
        .iter()
        .map(|&seed| {
            let mut line = vec![seed];
            let mut z = seed;
            for _ in 0..max_steps {
                let Some(d1) = dir(z) else { break };
                let Some(d2) = dir(z + d1 * (0.5 * step)) else { break };
                z += d2 * step;
                if !inside(z) || (z - field.sink().goal).length() < step {
                    break;
                }
                line.push(z);
            }
            line
        })
        .collect()
}
