//! The ORCA baseline (`planner.method = "orca"`): the robot as an agent of optimal
//! reciprocal collision avoidance (van den Berg, Guy, Lin and Manocha, 2011), as CrowdNav's
//! ORCA robot is. Each obstacle as tracked is assumed to take half the change, as an ORCA
//! agent would (people who do not see the robot take none of it, which is what CrowdNav's
//! invisible setting measures); the room's walls, furniture, the view's edge and a lane's
//! lines are half-planes never relaxed unless they cannot all be met. The solver is the one
//! the simulator's people walk by (`flowgate_protocol::plane::orca`). The velocity it picks
//! is steered to as the straight baseline steers to the goal, and supervised as the field's
//! commands are.

use flowgate_protocol::plane::orca::{self, Body, OrcaLine};

use super::baseline::RoomSegments;
use crate::planner::room::Room;
use crate::planner::{ObstacleEstimate, Space};
use crate::Point;

/// How far ahead ORCA keeps the robot clear, in the time the robot takes to cover this many
/// of its radii at its cruise speed: CrowdNav's 5 s at 1 m/s and 0.3 m.
pub const HORIZON_RADII: f64 = 5.0 / 0.3;
/// The nearest obstacles it avoids (CrowdNav's `max_neighbors`).
const MAX_NEIGHBOURS: usize = 10;

/// The robot's ORCA: the room's segments, made once, and the buffers each cycle reuses.
#[derive(Debug, Clone, Default)]
pub struct OrcaRobot {
    segments: RoomSegments,
    lines: Vec<OrcaLine>,
    projected: Vec<OrcaLine>,
    near: Vec<(f64, usize)>,
}

impl OrcaRobot {
    /// For a robot in `room` (its walls, furniture and the view's edge) or `space` (a lane).
    pub fn new(room: Option<&Room>, space: Space) -> Self {
        let segments = RoomSegments::new(room, space);
        let most = segments.len() + MAX_NEIGHBOURS;
        Self {
            segments,
            lines: Vec::with_capacity(most),
            projected: Vec::with_capacity(most),
            near: Vec::with_capacity(MAX_NEIGHBOURS + 1),
        }
    }

    /// The velocity ORCA picks for `me` (moving at `me.velocity`), nearest `preferred`
    /// within `max_speed`, among `obstacles`; `horizon` and `step` in seconds.
    pub fn velocity(
        &mut self,
        me: Body,
        preferred: Point,
        max_speed: f64,
        obstacles: &[ObstacleEstimate],
        horizon: f64,
        step: f64,
    ) -> Point {
        self.lines.clear();
        let range = me.radius + max_speed * horizon;
        for (nearest, footprint) in self.segments.near(me.position, range) {
            let radius = if footprint { me.radius } else { 0.0 };
            self.lines.extend(orca::line_off_wall(me.position, radius, nearest, horizon, step));
        }
        let hard = self.lines.len();
        // The nearest obstacles, nearest first (the earlier first among equals).
        self.near.clear();
        for (k, o) in obstacles.iter().enumerate() {
            let d2 = (o.center - me.position).norm_sqr();
            let at = self.near.partition_point(|&(e, _)| e <= d2);
            if at < MAX_NEIGHBOURS {
                self.near.insert(at, (d2, k));
                self.near.truncate(MAX_NEIGHBOURS);
            }
        }
        for &(_, k) in &self.near {
            let o = &obstacles[k];
            let other = Body { position: o.center, velocity: o.velocity, radius: o.radius };
            self.lines.push(orca::line_to(me, other, 0.5, horizon, step));
        }
        orca::solve(&self.lines, hard, max_speed, preferred, &mut self.projected)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Head on at an obstacle walking towards it, the robot turns aside and never plans to
    /// meet it within the horizon; in a lane it keeps its centre behind the lines.
    #[test]
    fn the_orca_robot_turns_aside_and_keeps_to_a_lane() {
        let obstacle = ObstacleEstimate::exact(Point::new(0.5, 0.0), Point::new(-0.05, 0.0), 0.07);
        let me = Body { position: Point::new(0.0, 0.0), velocity: Point::new(0.1, 0.0), radius: 0.07 };
        let mut robot = OrcaRobot::new(None, Space::Free);
        let v = robot.velocity(me, Point::new(0.1, 0.0), 0.15, &[obstacle], 10.0, 0.02);
        assert!(v.im.abs() > 1e-3, "{v}");
        let mut lane = OrcaRobot::new(None, Space::Lane { half_width: 0.05 });
        let me = Body { position: Point::new(0.0, 0.04), ..me };
        let v = lane.velocity(me, Point::new(0.0, 0.1), 0.15, &[], 1.0, 0.02);
        assert!(v.im <= 0.01 / 1.0 + 1e-9, "{v}");
    }
}
