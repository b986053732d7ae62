//! The room's fixed parts in the world: walls (polylines) and static obstacles (polygons),
//! judged against the robot's true footprint.
//!
//! The judge reckons with the floor plane's shared primitives
//! ([`flowgate_protocol::plane`]) but none of the planner's code: what is judged does not
//! judge itself.

use flowgate_protocol::plane::{inside_polygon, nearest_on_segment, polygon_edges, segment_distance_sqr};

use super::Touched;
use crate::scenario::SimScenario;
use crate::Point;

/// The walls and static obstacles of a scenario.
#[derive(Debug, Clone, Default)]
pub struct Room {
    walls: Vec<Vec<Point>>,
    polygons: Vec<Vec<Point>>,
}

/// The nearest part of the room to a robot: how far its footprint is from it (negative:
/// overlapping), what it is, and the unit vector from the robot's centre toward it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoomGap {
    pub gap: f64,
    pub with: Touched,
    pub toward: Point,
}

impl Room {
    pub fn new(scenario: &SimScenario) -> Self {
        let points = |p: &Vec<[f64; 2]>| p.iter().map(|&[x, y]| Point::new(x, y)).collect();
        Self {
            walls: scenario.walls.iter().map(|w| points(&w.points)).collect(),
            polygons: scenario.static_obstacles.iter().map(|o| points(&o.points)).collect(),
        }
    }

    /// Walls (polylines) and static obstacles (polygons) as given.
    pub fn from_parts(walls: Vec<Vec<Point>>, polygons: Vec<Vec<Point>>) -> Self {
        Self { walls, polygons }
    }

    pub fn is_empty(&self) -> bool {
        self.walls.is_empty() && self.polygons.is_empty()
    }

    pub fn walls(&self) -> &[Vec<Point>] {
        &self.walls
    }
    pub fn polygons(&self) -> &[Vec<Point>] {
        &self.polygons
    }

    /// Whether `point` lies inside a static obstacle.
    pub fn inside_any(&self, point: Point) -> bool {
        self.polygons.iter().any(|p| inside_polygon(point, p))
    }

    /// The gap between a footprint of `radius` at `centre` and the nearest wall or static
    /// obstacle (`None` in an empty room). A centre inside a polygon overlaps it by the
    /// radius and its depth.
    pub fn gap(&self, centre: Point, radius: f64) -> Option<RoomGap> {
        let mut best: Option<(f64, Touched, Point)> = None;
        let mut consider = |d2: f64, with: Touched, a: Point, b: Point| {
            if best.is_none_or(|(least, _, _)| d2 < least) {
                best = Some((d2, with, nearest_on_segment(centre, a, b)));
            }
        };
        for wall in &self.walls {
            for s in wall.windows(2) {
                consider(segment_distance_sqr(centre, s[0], s[1]), Touched::Wall, s[0], s[1]);
            }
        }
        for (k, polygon) in self.polygons.iter().enumerate() {
            for (a, b) in polygon_edges(polygon) {
                consider(segment_distance_sqr(centre, a, b), Touched::StaticObstacle(k), a, b);
            }
        }
        let (d2, with, nearest) = best?;
        let distance = d2.sqrt();
        let inside = match with {
            Touched::StaticObstacle(k) => inside_polygon(centre, &self.polygons[k]),
            _ => false,
        };
        let offset = nearest - centre;
        let toward = if distance > 0.0 { offset / distance } else { Point::default() };
        Some(if inside {
            RoomGap { gap: -distance - radius, with, toward: -toward }
        } else {
            RoomGap { gap: distance - radius, with, toward }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gap_is_the_footprints_to_the_nearest_part() {
        let room = Room {
            walls: vec![vec![Point::new(-1.0, 1.0), Point::new(1.0, 1.0)]],
            polygons: vec![vec![
                Point::new(0.5, -0.5),
                Point::new(0.9, -0.5),
                Point::new(0.9, -0.1),
                Point::new(0.5, -0.1),
            ]],
        };
        let g = room.gap(Point::new(0.0, 0.5), 0.1).unwrap();
        assert!(
            (g.gap - 0.4).abs() < 1e-12 && g.with == Touched::Wall && (g.toward - Point::new(0.0, 1.0)).norm() < 1e-12
        );
        let g = room.gap(Point::new(0.7, 0.0), 0.07).unwrap();
        assert!((g.gap - 0.03).abs() < 1e-12 && g.with == Touched::StaticObstacle(0), "{g:?}");
        // Inside the table: overlapping by its depth and the radius; the table lies downward.
        let g = room.gap(Point::new(0.7, -0.2), 0.07).unwrap();
        assert!((g.gap + 0.17).abs() < 1e-12 && (g.toward - Point::new(0.0, -1.0)).norm() < 1e-12, "{g:?}");
        assert!(Room::default().gap(Point::new(0.0, 0.0), 0.1).is_none());
    }
}
