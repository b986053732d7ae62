//! `[[walls]]`, `[[static_obstacles]]` and `[room]`: the room the robot drives in, checked
//! and solved once at load (docs/planner.md, "Rooms"; docs/configuration.md).

use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};

use super::checks::{invalid, positive, Invalid, BODY};
use super::RigFile;
use crate::calibration::Calibration;
use crate::planner::room::{FarField, Panels, Room, RoomError, RoomShape};
use crate::Point;

/// A wall (a polyline) or a static obstacle (a polygon, closed by its last edge), in floor
/// metres: `points = [[x, y], ...]`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PointsSection {
    pub points: Vec<[f64; 2]>,
}

/// How the room's boundary is made.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RoomSection {
    /// The camera's calibrated view is a boundary: the field keeps the robot's centre
    /// inside it, `view_inset` in from where the camera still sees both its LEDs. Unset:
    /// yes, except in a lane, whose lines bound the robot already and whose exact field a
    /// blend with the view's edge would only dilute (docs/planner.md, "Rooms").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_boundary: Option<bool>,
    /// How far inside the view's edge (less the LEDs' reach) the boundary lies, m.
    #[serde(default = "default_view_inset")]
    pub view_inset: f64,
    /// The boundary's panels' length, m: shorter is closer to the room's shape and costs
    /// more each cycle (docs/planner.md).
    #[serde(default = "default_panel_spacing")]
    pub panel_spacing: f64,
    /// Where the boundary turns toward the free region (a room's corner, the wedge between a
    /// wall and a table), shorter panels, so that none turns more than this from the next,
    /// rad; 0: `panel_spacing` everywhere. 0.03 leaves fewer spurious stalls in corners
    /// (docs/planner.md, "What the tests assert") for more panels.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub corner_turn: f64,
    /// How the panels' flow is taken far from them: `"multipole"` (runs of panels far from
    /// the point by one expansion each, within 1.85e-6; each near panel's by its series
    /// beyond 8 panel lengths), `"series"` (every panel by its series beyond 8 lengths,
    /// within 3.05e-6 of the log) or `"exact"` (the log everywhere: dearest a command; the
    /// reference the others are judged against, docs/planner.md).
    #[serde(default, skip_serializing_if = "is_default_far_field")]
    pub far_field: FarField,
    /// Two straight walls along the floor's x axis, at `y = ±w` and reaching across the
    /// whole calibrated view, with nothing else in the room, are the paper's lane: its exact
    /// field, the walls taken as without end (the lane of half-width `w` less the robot's
    /// radius and `planner.clearance`). false: solved as the finite walls they are.
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    pub walls_as_lane: bool,
}

fn yes() -> bool {
    true
}
fn is_true(b: &bool) -> bool {
    *b
}

fn is_default_far_field(f: &FarField) -> bool {
    *f == FarField::default()
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl Default for RoomSection {
    fn default() -> Self {
        Self {
            view_boundary: None,
            view_inset: default_view_inset(),
            panel_spacing: default_panel_spacing(),
            corner_turn: 0.0,
            far_field: FarField::default(),
            walls_as_lane: true,
        }
    }
}

fn default_view_inset() -> f64 {
    0.02
}
fn default_panel_spacing() -> f64 {
    0.03
}

/// The shortest panels a room may ask for, m (a finer boundary than the room's grid, 1/400
/// of its extent, resolves nothing more).
const MIN_PANEL_SPACING: f64 = 0.005;

impl From<RoomError> for Invalid {
    fn from(e: RoomError) -> Self {
        match e {
            RoomError::Shape { key, why } => Invalid { key, why },
            RoomError::Blocked { key, at, why } => Invalid { key, why: format!("{at:?} is {why}") },
            e @ RoomError::TooLarge { .. } => Invalid { key: "room.panel_spacing".into(), why: e.to_string() },
        }
    }
}

/// Most walls, and most static obstacles, a room holds: one camera's view with room to
/// spare. Each wall or obstacle, and each point of it, adds to the panels every cycle takes.
pub const MAX_WALLS: usize = 64;
pub const MAX_STATIC_OBSTACLES: usize = 64;
/// Most points of one wall or static obstacle, and of all of them together.
pub const MAX_POINTS: usize = 256;
pub const MAX_ROOM_POINTS: usize = 1024;

impl RigFile {
    /// How many walls, static obstacles and points: checked before anything is built.
    fn room_counts(&self) -> Result<(), Invalid> {
        let most = |key: &str, n: usize, limit: usize| {
            if n > limit {
                invalid(key, format!("has {n} entries: at most {limit}"))
            } else {
                Ok(())
            }
        };
        most("walls", self.walls.len(), MAX_WALLS)?;
        most("static_obstacles", self.static_obstacles.len(), MAX_STATIC_OBSTACLES)?;
        let walls = self.walls.iter().enumerate().map(|(i, w)| (format!("walls[{i}].points"), w.points.len()));
        let polygons = (self.static_obstacles.iter().enumerate())
            .map(|(i, o)| (format!("static_obstacles[{i}].points"), o.points.len()));
        let mut total = 0;
        for (key, n) in walls.chain(polygons) {
            most(&key, n, MAX_POINTS)?;
            total += n;
        }
        if total > MAX_ROOM_POINTS {
            return invalid(
                "walls",
                format!("the walls and static obstacles have {total} points together: at most {MAX_ROOM_POINTS}"),
            );
        }
        Ok(())
    }

    /// The room's shape as configured: walls, static obstacles, the view's edge (when it
    /// is a boundary) and, with any of those, a lane's lines as two more walls.
    pub fn room_shape(&self, calibration: &Calibration) -> Result<RoomShape, Invalid> {
        self.room_counts()?;
        let r = &self.room;
        positive("room.panel_spacing", r.panel_spacing, BODY)?;
        if r.panel_spacing < MIN_PANEL_SPACING {
            return invalid(
                "room.panel_spacing",
                format!("must be at least {MIN_PANEL_SPACING} m, is {}", r.panel_spacing),
            );
        }
        if !(r.corner_turn == 0.0 || (0.01..=0.5).contains(&r.corner_turn)) {
            return invalid("room.corner_turn", format!("must be 0 (off) or 0.01-0.5 rad, is {}", r.corner_turn));
        }
        if !(r.view_inset.is_finite() && r.view_inset >= 0.0) {
            return invalid("room.view_inset", format!("must be >= 0, is {}", r.view_inset));
        }
        let points = |s: &PointsSection| s.points.iter().map(|&[x, y]| Point::new(x, y)).collect::<Vec<_>>();
        let mut shape = RoomShape {
            walls: self.walls.iter().map(points).collect(),
            obstacles: self.static_obstacles.iter().map(points).collect(),
            view: None,
        };
        if r.view_boundary.unwrap_or(self.lane.is_none()) {
            let led = self.leds.front_offset.max(self.leds.rear_offset) + r.view_inset;
            let Some([x0, x1, y0, y1]) = calibration.inner_rect() else {
                return invalid("room.view_boundary", "the calibrated view has a corner beyond the horizon");
            };
            let (x0, x1, y0, y1) = (x0 + led, x1 - led, y0 + led, y1 - led);
            if x1 - x0 <= 0.0 || y1 - y0 <= 0.0 {
                return invalid("room.view_inset", "leaves nothing of the view");
            }
            shape.view = Some(vec![Point::new(x0, y0), Point::new(x1, y0), Point::new(x1, y1), Point::new(x0, y1)]);
        }
        shape.check()?;
        if let Some(lane) = self.lane.filter(|_| !shape.is_empty()) {
            // The lines bound the centre: walls grown by the robot (and the supervisor's
            // room) lie that much beyond them, along the whole room and a metre more.
            let all = shape.walls.iter().chain(&shape.obstacles).chain(shape.view.iter()).flatten();
            let (lo, hi) = all.fold((-1.0f64, 1.0f64), |(lo, hi), p| (lo.min(p.re), hi.max(p.re)));
            let y = lane.half_width + self.room_growth();
            for side in [1.0, -1.0] {
                shape.walls.push(vec![Point::new(lo - 1.0, side * y), Point::new(hi + 1.0, side * y)]);
            }
        }
        Ok(shape)
    }

    /// The lane two walls make (`room.walls_as_lane`): each straight along the x axis, at
    /// `y = ±w` to a micrometre, both reaching across the calibrated view, with no `[lane]`,
    /// static obstacle or view boundary asked for. Its half-width bounds the robot's centre,
    /// as a `[lane]`'s does: `w` less the growth.
    pub fn walls_lane(&self, calibration: &Calibration) -> Option<super::LaneSection> {
        const SAME: f64 = 1e-6;
        let r = &self.room;
        if !r.walls_as_lane || self.lane.is_some() || !self.static_obstacles.is_empty() || r.view_boundary == Some(true)
        {
            return None;
        }
        let [x0, x1, _, _] = calibration.inner_rect()?;
        let straight = |w: &PointsSection| match w.points[..] {
            [[xa, ya], [xb, yb]] if (ya - yb).abs() <= SAME && xa.min(xb) <= x0 && xa.max(xb) >= x1 => Some(ya),
            _ => None,
        };
        let [a, b] = &self.walls[..] else { return None };
        let (ya, yb) = (straight(a)?, straight(b)?);
        let half_width = 0.5 * (ya - yb).abs() - self.room_growth();
        ((ya + yb).abs() <= SAME && half_width > 0.0).then_some(super::LaneSection { half_width })
    }

    /// How far walls and static obstacles are grown for the robot's centre: its radius and
    /// the supervisor's margin (`planner.clearance`), m.
    pub fn room_growth(&self) -> f64 {
        self.robot.radius + self.planner.clearance
    }

    /// The room, solved (`None` without walls, static obstacles or the view's edge: the
    /// field of free space or the lane is exact), and the goal, if given, clear of it.
    pub fn room(&self, calibration: &Calibration) -> Result<Option<Arc<Room>>, Invalid> {
        let shape = self.room_shape(calibration)?;
        let panels = Panels {
            spacing: self.room.panel_spacing,
            corner_turn: (self.room.corner_turn > 0.0).then_some(self.room.corner_turn),
            far_field: self.room.far_field,
        };
        let Some(room) = solved(&shape, self.room_growth(), panels)? else { return Ok(None) };
        if let Some(g) = &self.goal {
            let at = Point::new(g.position[0], g.position[1]);
            if let Some(why) = room.blocked_at(at) {
                return invalid("goal.position", format!("{:?} {why}", g.position));
            }
        }
        Ok(Some(room))
    }
}

/// The rooms solved in this process, by what each was made from: a sweep's episodes, and
/// the rigs the lab tools derive from one scenario, share one room rather than solve it
/// each time (some 10 ms for a view's edge). Kept few; used at load only.
static SOLVED: Mutex<Vec<Solved>> = Mutex::new(Vec::new());

/// A solved room and what it was made from (the growth and spacing as bits).
struct Solved {
    shape: RoomShape,
    grow: u64,
    panels: Panels,
    room: Arc<Room>,
}

/// How many solved rooms [`SOLVED`] keeps.
const SOLVED_KEPT: usize = 8;

fn solved(shape: &RoomShape, grow: f64, panels: Panels) -> Result<Option<Arc<Room>>, RoomError> {
    let grow_bits = grow.to_bits();
    let mut solved = SOLVED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some(s) = solved.iter().find(|s| s.shape == *shape && s.grow == grow_bits && s.panels == panels) {
        return Ok(Some(Arc::clone(&s.room)));
    }
    let Some(room) = Room::with_panels(shape, grow, panels)?.map(Arc::new) else { return Ok(None) };
    if solved.len() == SOLVED_KEPT {
        solved.remove(0);
    }
    solved.push(Solved { shape: shape.clone(), grow: grow_bits, panels, room: Arc::clone(&room) });
    Ok(Some(room))
}
