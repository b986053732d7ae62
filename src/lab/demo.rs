//! The demo harness: the simulator and the gateway together, in one process, over real
//! ptys (SLCAN on a pty by default, or SocketCAN where vcan exists). `flowgate demo` and
//! the full-stack tests use it; runs are judged by the simulator's world truth.

use std::path::{Path, PathBuf};
use std::time::Duration;

use flowgate_sim::rig::{self, CanEndpoint, RigConfig};
use flowgate_sim::truth::TruthRecord;
use tokio::sync::watch;

use super::fleet::{contact_report, FleetTrace};
use super::planner_only::TraceRow;
use super::plots::{fleet_svg, trajectory_svg, Ending, FleetEnding};
use super::{Outcome, Scenario};
use crate::config::ConfigError;
use crate::gateway;
use crate::gateway::core::Progress;
use crate::gateway::shell::{Controls, GatewayError, Report};
use crate::track::Pose;
use crate::Point;

/// The scenario the demo runs by default (E2, the lane head-on).
pub const DEFAULT_SCENARIO: &str = include_str!("../../scenarios/e2-lane-head-on.toml");

/// How long the simulator keeps running after the gateway stopped.
const LINGER: Duration = Duration::from_millis(800);

/// How a demo run went.
#[derive(Debug)]
pub struct DemoRun {
    pub report: Report,
    pub truth: TruthRecord,
    /// Whether the robot, and every other vehicle of a fleet, ended within its goal's
    /// tolerance (+1 cm for the stop ramp).
    pub reached_goal: bool,
    /// Whether any vehicle touched anything.
    pub contact: bool,
    /// Each other vehicle of a fleet: its name and whether it ended at its goal.
    pub vehicles: Vec<(String, bool)>,
}

/// The files a demo run writes beside the gateway's telemetry.
pub const DEMO_FILES: &str = "{trajectory.svg,trace.json,cycles.csv,can.log,events.jsonl,truth.json,report.json}";

impl DemoRun {
    /// How the run ended, judged by the world's truth.
    pub fn outcome(&self) -> Outcome {
        if self.contact {
            Outcome::Collision
        } else if self.reached_goal {
            Outcome::Goal
        } else {
            Outcome::Timeout
        }
    }

    /// The robot's and the obstacles' true paths, as the plots take them.
    pub fn trace(&self) -> Vec<TraceRow> {
        let rows = self.truth.samples.iter().map(|s| TraceRow {
            t: s.t,
            pose: Pose { position: Point::new(s.x, s.y), heading: s.heading },
            command: Point::default(),
            speed: 0.5 * (s.wheel_speeds[0] + s.wheel_speeds[1]),
            obstacles: s.obstacles.iter().map(|o| Point::new(o[0], o[1])).collect(),
        });
        rows.collect()
    }

    /// A fleet's true paths, every vehicle's (the robot's first) and the obstacles'.
    pub fn fleet_trace(&self) -> FleetTrace {
        let samples = &self.truth.samples;
        let others = samples.first().map_or(0, |s| s.vehicles.len());
        let obstacles = samples.first().map_or(0, |s| s.obstacles.len());
        let robot = samples.iter().map(|s| Point::new(s.x, s.y)).collect();
        let other = |k: usize| samples.iter().filter_map(|s| s.vehicles.get(k)).map(|v| Point::new(v.x, v.y)).collect();
        let obstacle =
            |k: usize| samples.iter().filter_map(|s| s.obstacles.get(k)).map(|o| Point::new(o[0], o[1])).collect();
        FleetTrace {
            t: samples.iter().map(|s| s.t).collect(),
            vehicles: std::iter::once(robot).chain((0..others).map(other)).collect(),
            obstacles: (0..obstacles).map(obstacle).collect(),
        }
    }

    /// `trajectory.svg` (a fleet's: every vehicle's path), `truth.json` and `report.json`
    /// into `dir`.
    pub fn write_files(&self, scenario: &Scenario, dir: &Path) -> std::io::Result<()> {
        let t = &self.truth.summary;
        let svg = if scenario.vehicles.is_empty() {
            let ending = Ending {
                outcome: self.outcome(),
                min_obstacle_clearance: t.min_obstacle_clearance,
                end_time: t.duration,
            };
            trajectory_svg(scenario, &self.trace(), ending)
        } else {
            let contacts = t.vehicles.iter().map(|v| contact_report(&scenario.sim, v.contact, v.vehicle_contact));
            let ending = FleetEnding { outcome: self.outcome(), end_time: t.duration, contacts: contacts.collect() };
            fleet_svg(scenario, &ending, &self.fleet_trace())
        };
        std::fs::write(dir.join("trajectory.svg"), svg)?;
        self.truth.write(&dir.join("truth.json"))?;
        self.report.write_json(dir).map(drop)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("simulator: {0}")]
    Rig(#[from] rig::RigError),
    #[error("gateway: {0}")]
    Gateway(#[from] GatewayError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("--can: {0}")]
    Endpoint(String),
    #[error("gateway task: {0}")]
    Join(#[from] tokio::task::JoinError),
}

/// What the demo's gateway writes and serves besides driving.
#[derive(Debug, Clone, Default)]
pub struct Outputs {
    /// The telemetry directory (cycles.csv, trace.json, can.log, events.jsonl).
    pub dir: Option<PathBuf>,
    /// An MCAP recording.
    pub record: Option<PathBuf>,
    /// The live view's address.
    pub view: Option<std::net::SocketAddr>,
    /// Foxglove live's address.
    pub foxglove: Option<std::net::SocketAddr>,
    /// A control socket for `flowgate ctl`.
    pub socket: Option<PathBuf>,
    /// Join ROS 2 with this `[ros2]` (ROS 2's environment honoured) and wait for its goal,
    /// arm and start instead of driving to the scenario's goal at once.
    pub ros2: Option<crate::config::Ros2Section>,
}

/// How long a demo driven from ROS 2 waits for its operator, beyond the scenario's time.
pub const ROS2_OPERATOR_WAIT: Duration = Duration::from_secs(300);

/// The motors of the demo's rig.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum DemoDrive {
    /// One PCL-80K-like board for both wheels.
    #[default]
    Pcl80k,
    /// One CiA 402 drive a wheel (nodes 1 and 2, `[cia402]` at its defaults).
    Cia402,
}

/// Run `scenario` with the simulator and the gateway until the gateway stops (goal, fault)
/// or the scenario's time limit. `on_progress` is called about twice a second.
pub async fn run(
    scenario: &Scenario,
    can: &str,
    drive: DemoDrive,
    outputs: Outputs,
    mut on_progress: impl FnMut(&Progress),
) -> Result<DemoRun, DemoError> {
    let mut rig_cfg = RigConfig::new(scenario.sim.clone());
    if drive == DemoDrive::Cia402 {
        let node = |n| flowgate_protocol::canopen::NodeId::new(n).expect("1-127");
        rig_cfg.cia402 = Some([node(1), node(2)]);
    }
    let can_url = match can.parse::<CanEndpoint>().map_err(DemoError::Endpoint)? {
        CanEndpoint::SocketCan { interface } => {
            rig_cfg.can = CanEndpoint::SocketCan { interface: interface.clone() };
            format!("socketcan:{interface}")
        }
        CanEndpoint::SlcanPty { .. } => String::new(),
    };
    let wiring = rig_cfg.clone();
    // The simulator on a thread of its own: on a loaded machine it keeps its pace.
    let handle = rig::spawn(rig_cfg).await?;
    let can_url = if can_url.is_empty() {
        format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().expect("slcan pty").display())
    } else {
        can_url
    };
    let mut config = scenario.rig_file_wired(&handle.psd_path, &can_url, outputs.dir, &wiring);
    if drive == DemoDrive::Cia402 {
        config.use_cia402(crate::config::Cia402Section::with_nodes(1, 2));
    }
    config.telemetry.record = outputs.record;
    config.operator.view = outputs.view;
    config.operator.foxglove = outputs.foxglove;
    config.operator.socket = outputs.socket;
    config.ros2 = outputs.ros2.clone();
    let rig = config.rig("the demo's rig")?;
    let (stop_tx, stop_rx) = watch::channel(false);
    let (progress_tx, mut progress_rx) = watch::channel(Progress::default());
    let controls = Controls::new(stop_rx, outputs.ros2.is_none());
    let gw = tokio::spawn(gateway::shell::run(rig, controls, Some(progress_tx)));
    let wait = if outputs.ros2.is_some() { ROS2_OPERATOR_WAIT } else { Duration::ZERO };
    let limit = tokio::time::Instant::now() + Duration::from_secs_f64(scenario.time_limit) + wait;
    let mut ticker = tokio::time::interval(Duration::from_millis(500));
    loop {
        tokio::select! {
            _ = ticker.tick() => on_progress(&progress_rx.borrow()),
            changed = progress_rx.changed() => {
                let p = *progress_rx.borrow();
                if changed.is_err() || (p.state.is_terminal() && p.others_active == 0) {
                    break;
                }
            }
            _ = tokio::time::sleep_until(limit) => break,
        }
    }
    // Keep the world running a moment, so its truth shows the robot at rest after a stop.
    tokio::time::sleep(LINGER).await;
    on_progress(&progress_rx.borrow());
    let _ = stop_tx.send(true);
    let report = gw.await??;
    let truth = handle.stop().await;
    let at_goal = |k: usize, end: [f64; 2]| {
        let goal = scenario.vehicle(k).sim.goal;
        (end[0] - goal.position[0]).hypot(end[1] - goal.position[1]) <= goal.tolerance + 0.01
    };
    let vehicles: Vec<(String, bool)> = truth
        .summary
        .vehicles
        .iter()
        .enumerate()
        .skip(1)
        .map(|(k, v)| (v.name.clone(), at_goal(k, v.final_position)))
        .collect();
    let reached_goal = at_goal(0, truth.summary.final_position) && vehicles.iter().all(|(_, home)| *home);
    let touched = truth.summary.vehicles.iter().any(|v| v.contact.is_some() || v.vehicle_contact.is_some());
    let contact = truth.summary.first_contact.is_some() || touched;
    Ok(DemoRun { report, truth, reached_goal, contact, vehicles })
}
