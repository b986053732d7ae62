//! What the reactive baselines (`planner.method = "orca"` and `"social_force"`) share: the
//! room as segments to keep off, and the velocity each prefers, towards the goal.

use flowgate_protocol::plane::orca::length;
use flowgate_protocol::plane::{nearest_on_segment, polygon_edges};

use crate::planner::room::Room;
use crate::planner::Space;
use crate::Point;

/// A lane's lines as segments this long either side of the origin, m: beyond any view.
const LANE_REACH: f64 = 1e3;

/// The room's walls, furniture and view's edge, which the robot's footprint keeps off, and a
/// lane's lines, which its centre keeps behind: made once, when the control step is.
#[derive(Debug, Clone, Default)]
pub struct RoomSegments {
    /// Each segment, and whether the footprint keeps off it (`false`: the centre does).
    segments: Vec<(Point, Point, bool)>,
}

impl RoomSegments {
    /// For a robot in `room` or `space` (a lane).
    pub fn new(room: Option<&Room>, space: Space) -> Self {
        let mut segments = Vec::new();
        if let Some(room) = room {
            let shape = room.shape();
            for wall in &shape.walls {
                segments.extend(wall.windows(2).map(|s| (s[0], s[1], true)));
            }
            for polygon in shape.obstacles.iter().chain(&shape.view) {
                segments.extend(polygon_edges(polygon).map(|(a, b)| (a, b, true)));
            }
        }
        if let Space::Lane { half_width } = space {
            for y in [half_width, -half_width] {
                segments.push((Point::new(-LANE_REACH, y), Point::new(LANE_REACH, y), false));
            }
        }
        Self { segments }
    }

    pub fn len(&self) -> usize {
        self.segments.len()
    }
    pub fn is_empty(&self) -> bool {
        self.segments.is_empty()
    }

    /// The nearest point of each segment within `range` of `position`, and whether the
    /// footprint keeps off it.
    pub fn near(&self, position: Point, range: f64) -> impl Iterator<Item = (Point, bool)> + '_ {
        self.segments.iter().filter_map(move |&(a, b, footprint)| {
            let nearest = nearest_on_segment(position, a, b);
            ((nearest - position).norm_sqr() < range * range).then_some((nearest, footprint))
        })
    }
}

/// The velocity towards `goal` from `position` at `speed`, slowing to stop on it within a
/// `step`.
pub fn preferred(position: Point, goal: Point, speed: f64, step: f64) -> Point {
    let to = goal - position;
    let d = length(to);
    if d <= 0.0 {
        return Point::default();
    }
    to / d * speed.min(d / step)
}
