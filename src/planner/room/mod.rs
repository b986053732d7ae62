//! Rooms: walls, furniture and the camera's edge as no-penetration boundaries of the
//! navigation function (docs/planner.md, "Rooms").
//!
//! The robot's centre moves in the configuration space: every wall (a polyline) and every
//! static obstacle (a polygon) grown by the robot's radius (their Minkowski sum with a disc,
//! whose convex corners are arcs), and the camera's view shrunk to where the robot is still
//! seen. On those boundaries the flow must not cross: `∂φ/∂n = 0`.
//!
//! The boundary is traced where the clearance crosses zero on a grid of the room, as closed
//! loops with their corners rounded (`contour`), and cut into straight panels. The
//! boundary condition is met by a panel method: a constant source density on each panel,
//! whose strengths make the normal flow vanish at the panels' midpoints. The matrix depends
//! on the room alone: it is factorised (LU, partial pivoting) once, when the room is built.
//! A new goal then pays two triangular solves.
//!
//! A closed room (the view's edge, or walls all round the goal) cannot hold a lone sink:
//! its flux must come from somewhere. The field closes the balance with a uniform source
//! over the free area, `Δφ = -2π/A` (velocity `(π/A)(z - z₀)`), so that away from the
//! goal `φ` is strictly superharmonic: it has no local minimum inside (the minimum
//! principle) nor on a smooth part of the boundary (Hopf's lemma against `∂φ/∂n = 0`), and
//! every streamline ends at the goal or at a saddle.

use crate::Point;
use flowgate_protocol::plane::{inside_polygon, polygon_edges, segment_distance_sqr};

use super::space::Space;

mod regions;
pub use regions::clearance;
use regions::Regions;
mod contour;
mod tree;

use tree::PanelTree;

/// A robot closer than this to the room's boundary (or beyond it, up to
/// [`ROOM_TOLERANCE`](super::field::ROOM_TOLERANCE)) is steered by the room's flow this far inside, along the boundary's
/// normal: the panels' flow is not the field's beyond them.
pub(crate) const ROOM_HOLD: f64 = 0.005;

/// The room as configured, in floor metres: walls (polylines), static obstacles (closed
/// polygons) and the region the robot's centre must stay in (the camera's view, already
/// shrunk by the robot's reach and the inset), if it is a boundary.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RoomShape {
    pub walls: Vec<Vec<Point>>,
    pub obstacles: Vec<Vec<Point>>,
    pub view: Option<Vec<Point>>,
}

/// What is wrong with a room, naming the item.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RoomError {
    #[error("`{key}`: {why}")]
    Shape { key: String, why: String },
    #[error("`{key}` {at:?} is {why}")]
    Blocked { key: String, at: [f64; 2], why: String },
    #[error("the room's boundary is too long to solve in a cycle ({points} panels, at most {MAX_POINTS})")]
    TooLarge { points: usize },
}

/// The most panels a room may have: each evaluation of the field passes over them all, and
/// their factors take `8 N²` bytes (50 MB at the limit).
pub const MAX_POINTS: usize = 2500;

/// What an outline of the room is (for drawing it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutlineKind {
    /// A wall: an open polyline.
    Wall,
    /// A static obstacle: a polygon, closed by its last edge.
    StaticObstacle,
    /// The view's edge the robot keeps inside: a polygon, closed by its last edge.
    View,
}

impl OutlineKind {
    /// Whether the outline closes back to its first point.
    pub fn closed(self) -> bool {
        self != Self::Wall
    }

    /// The name a drawing gives it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Wall => "wall",
            Self::StaticObstacle => "static_obstacle",
            Self::View => "view",
        }
    }
}

impl RoomShape {
    /// Every item of the room with what it is, walls first, then static obstacles, then
    /// the view's edge: what the live view, Foxglove and the plots draw.
    pub fn outlines(&self) -> impl Iterator<Item = (OutlineKind, &[Point])> + '_ {
        let walls = self.walls.iter().map(|w| (OutlineKind::Wall, w.as_slice()));
        let obstacles = self.obstacles.iter().map(|o| (OutlineKind::StaticObstacle, o.as_slice()));
        walls.chain(obstacles).chain(self.view.iter().map(|v| (OutlineKind::View, v.as_slice())))
    }

    /// No walls, no obstacles, no view's edge: the field is the [`Space`]'s alone.
    pub fn is_empty(&self) -> bool {
        self.walls.is_empty() && self.obstacles.is_empty() && self.view.is_none()
    }

    /// Check every polyline and polygon: finite points, enough of them, no zero-length
    /// edge, polygons simple (no edge crossing another).
    pub fn check(&self) -> Result<(), RoomError> {
        let bad = |key: String, why: &str| RoomError::Shape { key, why: why.to_string() };
        for (i, wall) in self.walls.iter().enumerate() {
            let key = format!("walls[{i}].points");
            check_points(wall, 2, &key)?;
            if polyline_self_intersects(wall) {
                return Err(bad(key, "the wall crosses itself"));
            }
        }
        let polygons = self.obstacles.iter().enumerate().map(|(i, p)| (format!("static_obstacles[{i}].points"), p));
        let view = self.view.iter().map(|p| ("room.view".to_string(), p));
        for (key, polygon) in polygons.chain(view) {
            check_points(polygon, 3, &key)?;
            let closing = (polygon[0] - polygon[polygon.len() - 1]).norm();
            if closing == 0.0 {
                return Err(bad(key, "the last point repeats the first: the polygon closes by itself"));
            }
            if polygon_self_intersects(polygon) {
                return Err(bad(key, "the polygon is not simple: two of its edges cross"));
            }
            if signed_area(polygon).abs() < 1e-12 {
                return Err(bad(key, "the polygon has no area"));
            }
        }
        Ok(())
    }
}

fn check_points(points: &[Point], least: usize, key: &str) -> Result<(), RoomError> {
    let bad = |why: String| RoomError::Shape { key: key.to_string(), why };
    if points.len() < least {
        return Err(bad(format!("needs at least {least} points, has {}", points.len())));
    }
    if let Some(k) = points.iter().position(|p| !(p.re.is_finite() && p.im.is_finite())) {
        return Err(bad(format!("point {k} is not finite")));
    }
    if let Some(k) = points.windows(2).position(|s| (s[1] - s[0]).norm() < 1e-9) {
        return Err(bad(format!("the edge from point {k} to point {} has no length", k + 1)));
    }
    Ok(())
}

/// The polygon's signed area (positive counter-clockwise), m².
pub fn signed_area(polygon: &[Point]) -> f64 {
    0.5 * polygon_edges(polygon).map(|(a, b)| a.re * b.im - b.re * a.im).sum::<f64>()
}

/// The distance from `p` to the segment `a`-`b`.
pub fn segment_distance(p: Point, a: Point, b: Point) -> f64 {
    segment_distance_sqr(p, a, b).sqrt()
}

/// Whether the open segments `a`-`b` and `c`-`d` cross or touch.
fn segments_meet(a: Point, b: Point, c: Point, d: Point) -> bool {
    let cross = |o: Point, p: Point, q: Point| ((p - o).conj() * (q - o)).im;
    let (d1, d2) = (cross(c, d, a), cross(c, d, b));
    let (d3, d4) = (cross(a, b, c), cross(a, b, d));
    if ((d1 > 0.0) != (d2 > 0.0)) && ((d3 > 0.0) != (d4 > 0.0)) && d1 != 0.0 && d2 != 0.0 && d3 != 0.0 && d4 != 0.0 {
        return true;
    }
    // Collinear overlaps and touching ends.
    let on = |p: Point, q: Point, r: Point| segment_distance(r, p, q) < 1e-12;
    on(c, d, a) || on(c, d, b) || on(a, b, c) || on(a, b, d)
}

fn polygon_self_intersects(polygon: &[Point]) -> bool {
    let n = polygon.len();
    let edges: Vec<(Point, Point)> = polygon_edges(polygon).collect();
    (0..n).any(|i| {
        (i + 1..n).any(|j| {
            let adjacent = j == i + 1 || (i == 0 && j == n - 1);
            !adjacent && segments_meet(edges[i].0, edges[i].1, edges[j].0, edges[j].1)
        })
    })
}

fn polyline_self_intersects(line: &[Point]) -> bool {
    let n = line.len() - 1;
    // A wall that ends where it began (a closed ring of walls) meets itself there alone.
    let closed = n >= 3 && line[0] == line[n];
    (0..n).any(|i| {
        (i + 2..n)
            .filter(|&j| !(closed && i == 0 && j == n - 1))
            .any(|j| segments_meet(line[i], line[i + 1], line[j], line[j + 1]))
    })
}

/// How the boundary is cut into panels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Panels {
    /// The panels' length, m.
    pub spacing: f64,
    /// Where the boundary turns toward the free region (a room's corner, the wedge between
    /// a wall and a table), panels short enough that none turns more than this from the
    /// next, rad (down to a twentieth of the spacing). `None`: the spacing everywhere.
    pub corner_turn: Option<f64>,
    /// How a panel's flow is taken far from it.
    pub far_field: FarField,
}

/// How a panel's flow is taken far from the panel (`room.far_field`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FarField {
    /// The panels in runs along the boundary, each run far from the point (beyond `1/θ` of
    /// the disc holding it) by one multipole expansion about the disc's centre, within
    /// 1.85e-6 a unit of density and length over the distance; the panels of near runs
    /// by their own series beyond `FAR` lengths, by the log nearer.
    #[default]
    Multipole,
    /// Every panel by itself: beyond `FAR` panel lengths, the log's series about the
    /// panel's midpoint to its second term, within 3.05e-6 of the log; the log nearer.
    Series,
    /// The log at every distance: the reference the series is judged against.
    Exact,
}

/// One panel of the configuration space's boundary: a straight piece from `a` to `b`,
/// with the unit normal pointing out of the free region (into the grown furniture, or out
/// of the view). Its midpoint is its collocation point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Panel {
    pub a: Point,
    pub b: Point,
    pub normal: Point,
    /// The boundary's normals at `a` and `b`: the mean of this panel's and its neighbour's
    /// there (which side of the boundary a point nearest a panel's end lies on).
    pub normal_at: [Point; 2],
    /// Its midpoint and length, and beyond how far from the midpoint (squared) its series
    /// stands for it: kept, as every evaluation needs them.
    mid: Point,
    length: f64,
    far_sqr: f64,
    /// `1/t`, the inverse of its unit direction, and `t²`.
    inverse_direction: Point,
    direction_sqr: Point,
}

impl Panel {
    fn new(a: Point, b: Point, normal: Point, normal_at: [Point; 2], far_field: FarField) -> Self {
        let length = (b - a).norm();
        let t = (b - a) / length;
        Self {
            a,
            b,
            normal,
            normal_at,
            mid: (a + b) * 0.5,
            length,
            far_sqr: match far_field {
                FarField::Multipole | FarField::Series => (FAR * length) * (FAR * length),
                FarField::Exact => f64::INFINITY,
            },
            // 1/t = conj(t) for the unit direction t.
            inverse_direction: t.conj(),
            direction_sqr: t * t,
        }
    }
    pub fn mid(&self) -> Point {
        self.mid
    }
    pub fn length(&self) -> f64 {
        self.length
    }

    /// The squared distance from `p` to the panel, and where along it (0 at `a`, 1 at `b`)
    /// its nearest point lies.
    fn nearest(&self, p: Point) -> (f64, f64) {
        let ab = self.b - self.a;
        let t = (((p - self.a) * ab.conj()).re / ab.norm_sqr()).clamp(0.0, 1.0);
        ((p - (self.a + ab * t)).norm_sqr(), t)
    }

    /// The signed depth of `p` and the boundary's inward normal, for this panel nearest
    /// `p` at squared distance `d` and parameter `t` ([`nearest`](Self::nearest)): signed
    /// by the side of the panel (at an end, of the boundary's mean normal there).
    fn depth_and_inward(&self, p: Point, d: f64, t: f64) -> (f64, Point) {
        let normal = if t <= 0.0 {
            self.normal_at[0]
        } else if t >= 1.0 {
            self.normal_at[1]
        } else {
            self.normal
        };
        let q = self.a + (self.b - self.a) * t;
        let outward = ((p - q) * normal.conj()).re;
        let depth = d.sqrt();
        (if outward > 0.0 { -depth } else { depth }, -normal)
    }

    /// The flow (`u - i v`) at `z` of a unit source density along the panel (each metre of
    /// it emitting what a unit point source does, `2π`): `(1/t) Log((z - a)/(z - b))`, `t`
    /// the panel's unit direction. Far from the panel (beyond `FAR` lengths, with
    /// [`FarField::Series`]) the log's series about the midpoint `m` to its second term
    /// stands for it, much cheaper: `(L/w)(1 + (Lt/w)²/12)` with `w = z - m`, within
    /// `(L/|w|)⁴/80` of it (3.05e-6 at `FAR`).
    #[inline]
    fn source_flow(&self, z: Point) -> Point {
        let rel = z - self.mid;
        let r2 = rel.norm_sqr();
        if r2 > self.far_sqr {
            // L/w with one real division.
            let s = rel.conj() * (self.length / r2);
            return s * (1.0 + self.direction_sqr * s * s / 12.0);
        }
        // The log's real part from the squared modulus: no hypot.
        let w = (z - self.a) / (z - self.b);
        Point::new(0.5 * w.norm_sqr().ln(), w.im.atan2(w.re)) * self.inverse_direction
    }
}

/// Beyond this many panel lengths a panel's flow is taken from its series
/// ([`FarField::Series`]).
const FAR: f64 = 8.0;

/// Sharp corners of the free region (a room's corners, where a wall meets the view or
/// another wall) are rounded over this length, conservatively (the free region loses a
/// sliver of each): a sharp corner's panels would leave a singular flow at it.
const ROUNDING: f64 = 0.08;

/// The configuration space's boundary as loops of panels of about `spacing` metres: the zero
/// set of the clearance on the regions' grid, each loop walked with the free region on its
/// left and its corners rounded.
fn boundary(regions: &Regions, shape: &RoomShape, grow: f64, panels: Panels) -> Vec<Panel> {
    let mut out = Vec::new();
    for mut points in contour::loops(&regions.clearance, regions.nx, regions.ny, regions.lo, regions.cell) {
        let n = points.len();
        // A speck the grid left (a loop shorter than the rounding) bounds nothing a robot uses.
        let perimeter: f64 = (0..n).map(|k| (points[(k + 1) % n] - points[k]).norm()).sum();
        if perimeter < ROUNDING {
            continue;
        }
        contour::orient(&mut points, |p| clearance(shape, grow, p));
        let mut points = contour::smooth_and_space(&points, ROUNDING, panels.spacing, panels.corner_turn);
        // Rounding pulls a point toward its curve's centre: at a room's corner that is into
        // the free region (it gives up a sliver), but round a grown obstacle's convex corner
        // it is into the obstacle, where the supervisor would stop a robot the field let
        // in. Such points go back out to the obstacle's edge.
        for p in &mut points {
            let c = clearance(shape, grow, *p);
            if c < 0.0 {
                let h = 1e-5;
                let g = Point::new(
                    clearance(shape, grow, *p + Point::new(h, 0.0)) - clearance(shape, grow, *p - Point::new(h, 0.0)),
                    clearance(shape, grow, *p + Point::new(0.0, h)) - clearance(shape, grow, *p - Point::new(0.0, h)),
                );
                if g.norm() > 0.0 {
                    *p -= g / g.norm() * c;
                }
            }
        }
        let n = points.len();
        let normal = |k: usize| {
            let (a, b) = (points[k % n], points[(k + 1) % n]);
            (b - a) / (b - a).norm() * Point::new(0.0, -1.0)
        };
        let mean = |u: Point, v: Point| (u + v) / (u + v).norm();
        for k in 0..n {
            let (a, b) = (points[k], points[(k + 1) % n]);
            let here = normal(k);
            let normal_at = [mean(normal(k + n - 1), here), mean(here, normal(k + 1))];
            out.push(Panel::new(a, b, here, normal_at, panels.far_field));
        }
    }
    out
}

/// A factorised system whose smallest pivot is below this fraction of its largest is
/// refused as singular. The discrete system of a closed room is nearly singular in one
/// direction (the flux through the whole boundary, which the exact operator cannot carry),
/// but only as far as the midpoint rule errs (its smallest singular value stays orders of
/// magnitude above rounding), and the right-hand sides solved for (the sink's, the
/// closure's) carry no net flux to excite it.
const SINGULAR_PIVOT: f64 = 1e-12;

/// A room solved for its boundary: the panels, and the map from the normal flow to cancel
/// at their midpoints to their source densities.
#[derive(Debug, Clone)]
pub struct Room {
    shape: RoomShape,
    grow: f64,
    panels: Vec<Panel>,
    /// The panels' runs, for the flow far from them and the nearest panel.
    tree: PanelTree,
    /// The system's LU factors: densities from the normal flow to cancel.
    system: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
    /// The free region's parts, with each closed part's closure.
    regions: Regions,
}

/// Two rooms are the same when they were made from the same shape, growth and spacing
/// (the rest follows from those).
impl PartialEq for Room {
    fn eq(&self, other: &Self) -> bool {
        self.shape == other.shape && self.grow == other.grow && self.panels == other.panels
    }
}

impl Room {
    /// Solve `shape` grown by `grow` (the robot's radius), with panels of about `spacing`
    /// metres. `None` for an empty room (free space's own field is exact).
    pub fn new(shape: &RoomShape, grow: f64, spacing: f64) -> Result<Option<Self>, RoomError> {
        Self::with_panels(shape, grow, Panels { spacing, corner_turn: None, far_field: FarField::default() })
    }

    /// [`new`](Self::new), with the panels as `panels` says.
    pub fn with_panels(shape: &RoomShape, grow: f64, panels: Panels) -> Result<Option<Self>, RoomError> {
        shape.check()?;
        if shape.is_empty() {
            return Ok(None);
        }
        let regions = Regions::new(shape, grow);
        let far_field = panels.far_field;
        let panels = boundary(&regions, shape, grow, panels);
        if panels.len() > MAX_POINTS {
            return Err(RoomError::TooLarge { points: panels.len() });
        }
        let n = panels.len();
        let tree = PanelTree::new(&panels, far_field == FarField::Multipole);
        let mut a = nalgebra::DMatrix::<f64>::zeros(n, n);
        for (i, p) in panels.iter().enumerate() {
            // Each midpoint a hair on the free side, where the panel's own flow is `-π`.
            let at = p.mid() - p.normal * (1e-9 * p.length());
            tree.unit_flows(&panels, at, |j, f| a[(i, j)] = (f * p.normal).re);
        }
        let system = a.lu();
        let pivots = system.u().diagonal().abs();
        // A NaN pivot (a degenerate panel) is singular too.
        if pivots.iter().any(|p| p.is_nan()) || pivots.min() <= SINGULAR_PIVOT * pivots.max() {
            return Err(RoomError::Shape {
                key: "room".into(),
                why: format!(
                    "the boundary's system is singular (its pivots run from {:e} to {:e})",
                    pivots.min(),
                    pivots.max()
                ),
            });
        }
        let mut room = Self { shape: shape.clone(), grow, panels, tree, system, regions };
        for k in 0..room.regions.parts.len() {
            let part = &room.regions.parts[k];
            if part.closed {
                let rhs: Vec<f64> =
                    room.panels.iter().map(|p| -(closure_flow(part.centroid, p.mid()) * p.normal).re).collect();
                let mut densities = vec![0.0; n];
                room.solve_into(&rhs, &mut densities);
                room.regions.parts[k].closure = Some(densities);
            }
        }
        Ok(Some(room))
    }

    pub fn shape(&self) -> &RoomShape {
        &self.shape
    }
    /// How far the walls and static obstacles are grown (the robot's radius and the
    /// supervisor's margin), m.
    pub fn grow(&self) -> f64 {
        self.grow
    }
    pub fn panels(&self) -> &[Panel] {
        &self.panels
    }

    /// Whether the free part that `p` lies in is closed (a uniform source balances a sink
    /// there).
    pub fn closed_at(&self, p: Point) -> bool {
        self.regions.part_of(p).is_some_and(|k| self.regions.parts[k].closed)
    }

    /// The clearance of a robot centre at `p` (see [`clearance`]).
    pub fn clearance(&self, p: Point) -> f64 {
        clearance(&self.shape, self.grow, p)
    }

    /// How far `p` lies inside the field's boundary, the room with its corners rounded
    /// (negative outside it): the distance to the nearest panel, signed by the panels'
    /// winding round `p` (the free region is on each loop's left).
    pub fn depth(&self, p: Point) -> f64 {
        self.depth_and_inward(p).0
    }

    /// [`depth`](Self::depth), and the boundary's inward normal (into the free region)
    /// nearest `p`. Signed by the side of the nearest panel `p` is on (at a panel's end, by
    /// the boundary's mean normal there), which is exact for a point nearest one panel and
    /// needs no winding count.
    pub fn depth_and_inward(&self, p: Point) -> (f64, Point) {
        // A bound on the distance first, from a sixteenth of the panels: the walk over them
        // then skips any run whose disc, and any panel whose midpoint, lies too far for it to
        // come nearer (a panel is no nearer than its midpoint less half its length), and
        // finds the same panel as a pass over all, the first of equals. The slack covers
        // rounding.
        let bound = self.panels.iter().step_by(16).map(|q| q.nearest(p).0).fold(f64::INFINITY, f64::min);
        let reach = bound.sqrt() * (1.0 + 1e-9) + 1e-12;
        let mut best = (f64::INFINITY, 0usize, 0.5);
        self.tree.panels_within(p, reach, |k| {
            let panel = &self.panels[k];
            let far = reach + 0.5 * panel.length;
            if (p - panel.mid).norm_sqr() > far * far {
                return;
            }
            let (d, t) = panel.nearest(p);
            if d < best.0 {
                best = (d, k, t);
            }
        });
        match self.panels.get(best.1) {
            Some(panel) => panel.depth_and_inward(p, best.0, best.2),
            None => (f64::INFINITY, Point::default()),
        }
    }

    /// The lines that touch the room's parts nearest `p`, each with the part on its far
    /// side: for a wall's segment or a static obstacle's edge grown by `grow`, the tangent
    /// at the point nearest `p`; for the view, its edge's own line. Up to `out`'s capacity,
    /// the nearest first kept, those within `reach` of `p`: `(distance, normal, offset)`
    /// with `normal` a unit vector from `p` across the line and `offset = normal · z` on
    /// it. No allocation.
    pub fn lines_near<const N: usize>(
        &self,
        p: Point,
        grow: f64,
        reach: f64,
        out: &mut arrayvec::ArrayVec<(f64, Point, f64), N>,
    ) {
        out.clear();
        let mut keep = |line: (f64, Point, f64)| {
            if line.0 > reach || !line.0.is_finite() {
                return;
            }
            if out.is_full() {
                let (k, far) =
                    out.iter().enumerate().fold((0, f64::MIN), |m, (k, l)| if l.0 > m.1 { (k, l.0) } else { m });
                if far > line.0 {
                    out[k] = line;
                }
            } else {
                out.push(line);
            }
        };
        let mut grown = |a: Point, b: Point, inside: bool| {
            let q = flowgate_protocol::plane::nearest_on_segment(p, a, b);
            let d = (q - p).norm();
            if d == 0.0 {
                return;
            }
            let (normal, gap) = if inside { (-(q - p) / d, -d - grow) } else { ((q - p) / d, d - grow) };
            keep((gap, normal, (normal.conj() * p).re + gap));
        };
        for wall in &self.shape.walls {
            for s in wall.windows(2) {
                grown(s[0], s[1], false);
            }
        }
        for polygon in &self.shape.obstacles {
            let inside = inside_polygon(p, polygon);
            for (a, b) in polygon_edges(polygon) {
                grown(a, b, inside);
            }
        }
        if let Some(view) = &self.shape.view {
            let turn = if signed_area(view) > 0.0 { Point::new(0.0, -1.0) } else { Point::new(0.0, 1.0) };
            for (a, b) in polygon_edges(view) {
                let normal = (b - a) / (b - a).norm() * turn;
                let offset = (normal.conj() * a).re;
                keep((offset - (normal.conj() * p).re, normal, offset));
            }
        }
    }

    /// Why a robot's centre cannot be at `p`, naming the item: inside a wall or static
    /// obstacle grown by the robot (and the supervisor's margin), beyond the view's edge, or
    /// in a corner the field's boundary rounds off. `None` where it can.
    pub fn blocked_at(&self, p: Point) -> Option<String> {
        let grow = self.grow;
        for (i, wall) in self.shape.walls.iter().enumerate() {
            if let Some(d) =
                wall.windows(2).map(|s| segment_distance(p, s[0], s[1])).reduce(f64::min).filter(|&d| d <= grow)
            {
                return Some(format!("is {d:.3} m from walls[{i}]: the robot's centre keeps {grow:.3} m from a wall"));
            }
        }
        for (i, polygon) in self.shape.obstacles.iter().enumerate() {
            let d = polygon_edges(polygon).map(|(a, b)| segment_distance(p, a, b)).fold(f64::INFINITY, f64::min);
            if inside_polygon(p, polygon) {
                return Some(format!("lies inside static_obstacles[{i}]"));
            }
            if d <= grow {
                return Some(format!(
                    "is {d:.3} m from static_obstacles[{i}]: the robot's centre keeps {grow:.3} m from it"
                ));
            }
        }
        if let Some(view) = &self.shape.view {
            if !inside_polygon(p, view) {
                return Some("lies beyond the view's edge (less the LEDs' reach and room.view_inset), where the camera may lose the robot".into());
            }
        }
        (self.depth(p) <= 0.0).then(|| "lies in a corner the field's boundary rounds off".to_string())
    }

    /// Whether a robot centre can go from `a` to `b` without meeting the room: both free
    /// and in one part of the free region (on the room's 1/400 grid).
    pub fn reachable(&self, a: Point, b: Point) -> bool {
        let free = self.clearance(a) > 0.0 && self.clearance(b) > 0.0;
        free && self.regions.part_of(a).is_some() && self.regions.part_of(a) == self.regions.part_of(b)
    }

    /// The room's own flow towards a unit sink at `goal`: the panels' densities that make
    /// the sink's flow tangent to the boundary, and in a closed part the uniform source that
    /// balances the sink, with its own densities. What a cycle keeps of it.
    pub fn sink_flow(&self, goal: Point, out: &mut RoomSink) {
        out.densities.resize(self.panels.len(), 0.0);
        out.rhs.resize(self.panels.len(), 0.0);
        for (r, p) in out.rhs.iter_mut().zip(&self.panels) {
            *r = -(Space::Free.sink(p.mid(), goal) * p.normal).re;
        }
        self.solve_into(&out.rhs, &mut out.densities);
        out.goal = goal;
        out.closure = None;
        out.moments.clear();
        if let Some(part) = self.regions.part_of(goal).map(|k| &self.regions.parts[k]) {
            if let (true, Some(closure)) = (part.closed, &part.closure) {
                // The unit sink's 2π of flux, from a uniform source over the part's area.
                let density = std::f64::consts::TAU / part.area;
                for (s, c) in out.densities.iter_mut().zip(closure) {
                    *s += density * c;
                }
                out.closure = Some((part.centroid, density));
            }
        }
        self.tree.expand(&self.panels, &out.densities, &mut out.moments);
    }

    /// The flow (`u - i v`) at `z` of a unit sink at the goal in the room: the sink, the
    /// panels, and the closure.
    pub fn eval_sink(&self, sink: &RoomSink, z: Point) -> Point {
        Space::Free.sink(z, sink.goal) + self.eval_correction(sink, z)
    }

    /// What the room adds to a unit sink's flow at `z` (`u - i v`): the panels' and the
    /// closure's, without the sink itself.
    pub fn eval_correction(&self, sink: &RoomSink, z: Point) -> Point {
        let mut f = self.tree.flow(&self.panels, &sink.densities, &sink.moments, z);
        if let Some((center, density)) = sink.closure {
            f += closure_flow(center, z) * density;
        }
        f
    }

    /// Densities from normal flows to cancel, by the factors' triangular solves (in place,
    /// no allocation).
    fn solve_into(&self, rhs: &[f64], out: &mut [f64]) {
        out.copy_from_slice(rhs);
        let n = out.len();
        let mut view = nalgebra::DVectorViewMut::from_slice(out, n);
        // The factors were checked for a zero pivot when the room was built.
        let solved = self.system.solve_mut(&mut view);
        debug_assert!(solved);
    }
}

/// A unit sink's flow in a room, solved for one goal (kept across cycles while the goal
/// stays; its buffers are made once, so solving it again does not allocate).
#[derive(Debug, Clone, Default)]
pub struct RoomSink {
    goal: Point,
    densities: Vec<f64>,
    rhs: Vec<f64>,
    /// The panels' runs' expansions (`tree::ORDER` terms a run), with `FarField::Multipole`.
    moments: Vec<Point>,
    /// A closed part's uniform source: its centre and density.
    closure: Option<(Point, f64)>,
}

impl RoomSink {
    /// Buffers for `room`'s panels, so that solving for a goal never allocates.
    pub fn for_room(room: &Room) -> Self {
        let n = room.panels.len();
        let moments = Vec::with_capacity(room.tree.node_count() * tree::ORDER);
        Self { goal: Point::default(), densities: vec![0.0; n], rhs: vec![0.0; n], moments, closure: None }
    }
    pub fn goal(&self) -> Point {
        self.goal
    }
}

/// The closure's radial flow (`u - i v`) per unit source density: `(1/2) conj(z - z₀)`.
fn closure_flow(center: Point, z: Point) -> Point {
    0.5 * (z - center).conj()
}

#[cfg(test)]
mod tests;
