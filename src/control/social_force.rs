//! The social-force baseline (`planner.method = "social_force"`): the robot as a pedestrian
//! of Helbing and Molnár's model (1995), as CrowdNav's social-force robot is. It relaxes
//! towards the velocity that heads for the goal at the cruise speed and is pushed off each
//! obstacle as tracked and off the room's walls, furniture, view's edge and a lane's lines
//! (the model the simulator's people walk by: `flowgate_protocol::plane::social_force`,
//! its constants scaled by the robot's radius and cruise speed). The velocity it reaches is
//! steered to as the straight baseline steers to the goal, and supervised as the field's
//! commands are.

use flowgate_protocol::plane::orca::Body;
use flowgate_protocol::plane::social_force;

use super::baseline::RoomSegments;
use crate::planner::room::Room;
use crate::planner::{ObstacleEstimate, Space};
use crate::Point;

/// How far off a wall still pushes, in the robot's radii (the push is e^-15 of its
/// strength there).
const WALL_REACH_RADII: f64 = 10.0;

/// The robot's social force: the room's segments, made once.
#[derive(Debug, Clone, Default)]
pub struct SocialForceRobot {
    segments: RoomSegments,
}

impl SocialForceRobot {
    /// For a robot in `room` (its walls, furniture and the view's edge) or `space` (a lane).
    pub fn new(room: Option<&Room>, space: Space) -> Self {
        Self { segments: RoomSegments::new(room, space) }
    }

    /// `me`'s velocity one `step` on: towards `preferred` (at most `speed`), pushed off
    /// `obstacles` and the room, at most `max_speed`.
    pub fn velocity(
        &self,
        me: Body,
        preferred: Point,
        speed: f64,
        max_speed: f64,
        obstacles: &[ObstacleEstimate],
        step: f64,
    ) -> Point {
        let others = obstacles.iter().map(|o| Body { position: o.center, velocity: o.velocity, radius: o.radius });
        // A line the centre keeps behind pushes as a wall would a body of no size: its point
        // is moved out by the radius, so the push begins where the centre meets it.
        let walls = self.segments.near(me.position, WALL_REACH_RADII * me.radius).map(|(p, footprint)| {
            if footprint {
                p
            } else {
                let out = p - me.position;
                p + out / out.norm().max(f64::MIN_POSITIVE) * me.radius
            }
        });
        social_force::velocity(me, preferred, speed, max_speed, others, walls, step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Head on at an obstacle walking towards it, the robot is pushed aside and slowed; with
    /// nothing near it relaxes towards the velocity it prefers.
    #[test]
    fn the_social_force_robot_is_pushed_aside_by_what_is_ahead() {
        let robot = SocialForceRobot::new(None, Space::Free);
        let me = Body { position: Point::new(0.0, 0.03), velocity: Point::new(0.1, 0.0), radius: 0.07 };
        let ahead = ObstacleEstimate::exact(Point::new(0.2, 0.0), Point::new(-0.05, 0.0), 0.07);
        let mut v = me.velocity;
        for _ in 0..10 {
            v = robot.velocity(Body { velocity: v, ..me }, Point::new(0.1, 0.0), 0.1, 0.15, &[ahead], 0.02);
        }
        assert!(v.im > 1e-4 && v.re < 0.099, "pushed to its left (it is left of the obstacle) and slowed: {v}");
        let free =
            robot.velocity(Body { velocity: Point::default(), ..me }, Point::new(0.1, 0.0), 0.1, 0.15, &[], 0.02);
        assert!(free.re > 0.0 && free.im.abs() < 1e-12, "{free}");
        let lane = SocialForceRobot::new(None, Space::Lane { half_width: 0.05 });
        let near_line = Body { position: Point::new(0.0, 0.045), velocity: Point::default(), radius: 0.07 };
        let v = lane.velocity(near_line, Point::new(0.1, 0.0), 0.1, 0.15, &[], 0.02);
        assert!(v.im < 0.0, "a lane's line pushes the centre back in: {v}");
    }
}
