//! What the gateway believed in one cycle: the robot's pose and goal, each tracked
//! obstacle, and each other vehicle of a fleet. The core builds it ([`Core::scene`](super::Core::scene)); the recording and
//! the live view draw it.

use super::safety::State;
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

/// One of a fleet's `[[vehicles]]` in a cycle's scene (the robot's is the scene's own pose).
/// `f32`, as an obstacle's.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SceneVehicle {
    /// Whether the camera has given its pose (before, nothing below is known).
    pub seen: bool,
    pub state: State,
    /// x, y (m), heading (rad), as its last cycle estimated.
    pub pose: [f32; 3],
    /// Forward speed (m/s) and yaw rate (rad/s), from its wheels' speeds.
    pub twist: [f32; 2],
    /// Where it is bound: its goal, or a scripted vehicle's script's end.
    pub goal: [f32; 2],
    /// A scripted vehicle's distance from its script at its last cycle in Running, m.
    pub script_error: Option<f32>,
}

/// What the gateway believed in one cycle: the robot's pose and goal, each obstacle, each
/// other vehicle.
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

/// A fleet's other vehicles in a cycle's scene, in the rig's `[[vehicles]]` order (a
/// vehicle's field takes every other as a circle, so they are at most [`MAX_OBSTACLES`]).
/// Beside the [`SceneRecord`], not in it: a single robot's scene stays small enough to queue
/// by value, and a fleet's goes to the recording in [`VehicleChunk`]s.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FleetScene {
    pub count: u8,
    pub vehicles: [SceneVehicle; MAX_OBSTACLES],
}

/// Vehicles in a chunk of a [`FleetScene`]: what one telemetry record carries.
pub const CHUNK_VEHICLES: usize = 8;

/// Part of a fleet's scene: its vehicles from `first` on, `count` of them.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct VehicleChunk {
    pub first: u8,
    pub count: u8,
    pub vehicles: [SceneVehicle; CHUNK_VEHICLES],
}

impl FleetScene {
    /// The other vehicles: the `k`-th is the rig's `k`-th `[[vehicles]]` entry.
    pub fn vehicles(&self) -> &[SceneVehicle] {
        &self.vehicles[..usize::from(self.count).min(MAX_OBSTACLES)]
    }

    /// Add `vehicle` after those there (none beyond [`MAX_OBSTACLES`], which the rig's
    /// loader refuses).
    pub fn push(&mut self, vehicle: SceneVehicle) {
        if let Some(slot) = self.vehicles.get_mut(usize::from(self.count)) {
            *slot = vehicle;
            self.count += 1;
        }
    }

    /// Its vehicles in chunks, in order (none for a single robot).
    pub fn chunks(&self) -> impl Iterator<Item = VehicleChunk> + '_ {
        self.vehicles().chunks(CHUNK_VEHICLES).enumerate().map(|(k, part)| {
            let mut chunk =
                VehicleChunk { first: (k * CHUNK_VEHICLES) as u8, count: part.len() as u8, ..VehicleChunk::default() };
            chunk.vehicles[..part.len()].copy_from_slice(part);
            chunk
        })
    }

    /// Take a chunk back in: the fleet is then as far as its end.
    pub fn take(&mut self, chunk: &VehicleChunk) {
        let first = usize::from(chunk.first);
        let count = usize::from(chunk.count).min(CHUNK_VEHICLES).min(MAX_OBSTACLES.saturating_sub(first));
        self.vehicles[first..first + count].copy_from_slice(&chunk.vehicles[..count]);
        self.count = (first + count) as u8;
    }
}

/// What a drawing or a message names and sizes a `[[vehicles]]` entry by: fixed for a run.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleLabel {
    pub name: String,
    /// Its body's radius, m.
    pub radius: f64,
    /// It follows a script (else it navigates to goals).
    pub scripted: bool,
}

impl VehicleLabel {
    /// The rig's `[[vehicles]]`, in order (a single robot's rig: none).
    pub fn of_rig(rig: &crate::config::Rig) -> Vec<Self> {
        rig.vehicles
            .iter()
            .map(|v| Self { name: v.name.clone(), radius: v.driven.control.robot_radius, scripted: v.script.is_some() })
            .collect()
    }
}

impl SceneRecord {
    pub fn obstacles(&self) -> &[ObstacleView] {
        &self.obstacles[..usize::from(self.count).min(MAX_OBSTACLES)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fleet's scene goes in chunks and comes back whole, in order.
    #[test]
    fn a_fleets_scene_comes_back_whole_from_its_chunks() {
        let mut fleet = FleetScene::default();
        for k in 0..11 {
            fleet.push(SceneVehicle { seen: true, pose: [k as f32, 0.0, 0.0], ..SceneVehicle::default() });
        }
        let chunks: Vec<VehicleChunk> = fleet.chunks().collect();
        assert_eq!(chunks.iter().map(|c| (c.first, c.count)).collect::<Vec<_>>(), [(0, 8), (8, 3)]);
        let mut back = FleetScene::default();
        for c in &chunks {
            back.take(c);
        }
        assert_eq!(back, fleet);
        assert_eq!(FleetScene::default().chunks().count(), 0, "a single robot sends none");
        let record = std::mem::size_of::<VehicleChunk>();
        assert!(record <= std::mem::size_of::<SceneRecord>(), "a chunk ({record} bytes) queues as a scene does");
    }
}
