//! What the gateway believed in one cycle: the robot's pose and goal, and each tracked
//! obstacle. The core builds it ([`Core::scene`](super::Core::scene)); the recording and
//! the live view draw it.

use crate::planner::MAX_OBSTACLES;
use crate::time::HostTime;

/// One tracked obstacle in a cycle's scene. `f32`: a micrometre over tens of metres, and
/// half the queue's memory.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ObstacleView {
    pub position: [f32; 2],
    pub velocity: [f32; 2],
    /// Position covariance `[xx, xy, yy]`, m².
    pub covariance: [f32; 3],
    pub planning_radius: f32,
    /// The obstacle's own radius, m.
    pub radius: f32,
}

/// What the gateway believed in one cycle: the robot's pose and goal, each obstacle.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SceneRecord {
    pub cycle: u64,
    pub at: HostTime,
    /// x, y (m), heading (rad).
    pub pose: [f64; 3],
    /// The robot's forward speed (m/s) and yaw rate (rad/s), from the wheels' speeds.
    pub twist: [f64; 2],
    pub goal: [f64; 2],
    pub count: u8,
    pub obstacles: [ObstacleView; MAX_OBSTACLES],
}

impl SceneRecord {
    pub fn obstacles(&self) -> &[ObstacleView] {
        &self.obstacles[..usize::from(self.count).min(MAX_OBSTACLES)]
    }
}
