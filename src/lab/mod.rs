//! The lab tools (cargo feature `lab`, on by default): everything that needs the simulator.
//! The deployed gateway is built without them (`--no-default-features`) and so never
//! contains the simulator.
//!
//! - [`scenario`]: scenario files as the gateway sees them, and the rig config a scenario
//!   implies (the same [`crate::config::RigFile`] and rules a rig uses);
//! - [`virtual_rig`]: the whole stack in deterministic virtual time: the real gateway core
//!   wired to the simulator's firmware and world through the real encoders and decoders;
//! - [`policy`]: a planner outside flowgate as a process speaking JSON lines with the
//!   whole stack in virtual time (`plan --policy`);
//! - [`planner_only`]: the planner-only runner (control step against the world, with a
//!   modelled sensing chain), and one run of either mode;
//! - [`sweep`]: many seeded episodes of either mode, sharded and merged;
//! - [`plots`]: trajectories and histories as SVG;
//! - [`demo`]: the simulator and the gateway in real time over real ptys;
//! - [`bench`](mod@bench): the gateway benchmark over ptys and SocketCAN.

pub mod bench;
pub mod bus_load;
pub mod demo;
pub mod fleet;
pub mod outputs;
pub mod people_benchmark;
pub mod planner_only;
pub mod plots;
pub mod policy;
pub mod scenario;
pub mod swarm;
pub mod sweep;
pub mod virtual_rig;

pub use scenario::Scenario;

use serde::{Deserialize, Serialize};

/// How a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    Goal,
    Collision,
    Timeout,
    Stall,
    /// The gateway faulted (full-stack runs), or a fleet's vehicle lost its own link.
    Fault,
    /// The run stopped in order for another reason than the goal or a stall (e.g. the goal
    /// stayed inside an obstacle's planning circle for longer than `planner.goal_wait`).
    Stopped,
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Outcome::Goal => "goal",
            Outcome::Collision => "collision",
            Outcome::Timeout => "timeout",
            Outcome::Stall => "stall",
            Outcome::Fault => "fault",
            Outcome::Stopped => "stopped",
        })
    }
}
