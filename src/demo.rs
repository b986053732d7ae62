//! The demo harness: the simulator and the gateway together, in one process, over real
//! ptys (SLCAN on a pty by default, or SocketCAN where vcan exists). `flowgate demo` and
//! the full-stack tests use it; runs are judged by the simulator's world truth.

use std::path::{Path, PathBuf};
use std::time::Duration;

use flowgate_sim::calibration::CameraModel;
use flowgate_sim::psd_controller::LedMap;
use flowgate_sim::rig::{self, CanEndpoint, RigConfig};
use flowgate_sim::scenario::{MarginSpec, Scenario};
use flowgate_sim::truth::TruthRecord;
use tokio::sync::{mpsc, watch};

use crate::config::*;
use crate::gateway::{self, Controls, GatewayError, Progress, Report};

/// The scenario the demo runs by default (E2, the lane head-on).
pub const DEFAULT_SCENARIO: &str = include_str!("../scenarios/e2-lane-head-on.toml");

/// The gateway configuration for a simulated rig running `scenario`: the simulator's
/// standard camera and LEDs, the scenario's robot, goal and planner.
pub fn gateway_config(s: &Scenario, psd: &Path, can: &str, out_dir: Option<PathBuf>) -> GatewayConfig {
    let leds = LedMap::standard(s.robot.radius);
    let cam = CameraModel::default();
    let n_leds = 2 + s.obstacles.len() as u32;
    let slot_us = ((s.sensing.sample_time * 1e6) as u32 / n_leds).clamp(100, u32::from(u16::MAX)) as u16;
    GatewayConfig {
        serial: SerialConfig { port: psd.to_path_buf(), baud: 921_600 },
        leds: LedConfig {
            robot_front: leds.robot_front,
            robot_rear: leds.robot_rear,
            front_offset: leds.robot_led_offset,
            rear_offset: leds.robot_led_offset,
            obstacles: s
                .obstacles
                .iter()
                .enumerate()
                .map(|(k, o)| ObstacleLed { led: leds.first_obstacle + k as u8, radius: o.radius })
                .collect(),
        },
        schedule: ScheduleConfig { slot_us, dark_slot_us: 0, averaging: 1 },
        calibration: CalibrationConfig {
            homography: Some(cam.homography),
            points: Vec::new(),
            k1: cam.k1,
            counts: cam.counts,
        },
        can: CanConfig { endpoint: can.to_string(), node: 1 },
        drive: DriveSection {
            wheel_radius: s.robot.wheel_radius,
            steps_per_rev: s.robot.steps_per_rev,
            microsteps: s.robot.microsteps,
            wheel_base: s.robot.wheel_base,
            max_wheel_speed: s.robot.max_wheel_speed,
            wheel_accel: s.robot.wheel_accel,
            // Ten cycles: a shared test machine can stall a cycle or two.
            command_timeout_ms: 200,
        },
        robot: RobotSection { radius: s.robot.radius, max_speed: s.robot.max_speed },
        planner: PlannerSection {
            goal: s.goal.position,
            goal_tolerance: s.goal.tolerance,
            cruise_speed: s.planner.cruise_speed,
            c1: s.planner.c1,
            kc: s.planner.kc,
            margin: match s.planner.margin {
                MarginSpec::None => MarginSection::None,
                MarginSpec::Fixed { metres } => MarginSection::Fixed { metres },
                MarginSpec::Factor { factor } => MarginSection::Factor { factor },
                MarginSpec::Delay { extra_speed } => MarginSection::Delay { extra_speed },
            },
            tie_break: s.planner.tie_break,
        },
        lane: s.lane.map(|l| LaneSection { half_width: l.half_width }),
        safety: SafetyConfig::default(),
        telemetry: TelemetryConfig { out_dir, queue: 8192 },
    }
}

/// How long the simulator keeps running after the gateway stopped.
const LINGER: Duration = Duration::from_millis(800);

/// How a demo run went.
#[derive(Debug)]
pub struct DemoRun {
    pub report: Report,
    pub truth: TruthRecord,
    /// Whether the robot ended within the goal tolerance (+1 cm for the stop ramp).
    pub reached_goal: bool,
    pub contact: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("simulator: {0}")]
    Rig(#[from] rig::RigError),
    #[error("gateway: {0}")]
    Gateway(#[from] GatewayError),
    #[error("gateway task: {0}")]
    Join(#[from] tokio::task::JoinError),
}

/// Run `scenario` with the simulator and the gateway until the gateway stops (goal, fault)
/// or the scenario's time limit. `on_progress` is called about twice a second.
pub async fn run(
    scenario: &Scenario,
    can: &str,
    out_dir: Option<PathBuf>,
    mut on_progress: impl FnMut(&Progress),
) -> Result<DemoRun, DemoError> {
    let mut rig_cfg = RigConfig::new(scenario.clone());
    let can_url = match can.parse::<CanEndpoint>() {
        Ok(CanEndpoint::SocketCan { interface }) => {
            rig_cfg.can = CanEndpoint::SocketCan { interface: interface.clone() };
            format!("socketcan:{interface}")
        }
        _ => String::new(),
    };
    let handle = rig::start(rig_cfg).await?;
    let can_url = if can_url.is_empty() {
        format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().expect("slcan pty").display())
    } else {
        can_url
    };
    let cfg = gateway_config(scenario, &handle.psd_path, &can_url, out_dir);
    let (stop_tx, stop_rx) = watch::channel(false);
    let (_arm_tx, arm_rx) = mpsc::channel(1);
    let (progress_tx, mut progress_rx) = watch::channel(Progress::default());
    let gw = tokio::spawn(gateway::run(cfg, Controls { shutdown: stop_rx, arm: arm_rx }, Some(progress_tx)));
    let limit = tokio::time::Instant::now() + Duration::from_secs_f64(scenario.time_limit);
    let mut ticker = tokio::time::interval(Duration::from_millis(500));
    loop {
        tokio::select! {
            _ = ticker.tick() => on_progress(&progress_rx.borrow()),
            changed = progress_rx.changed() => {
                let state = progress_rx.borrow().state;
                if changed.is_err() || matches!(state, "stopped" | "fault") {
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
    let end = truth.summary.final_position;
    let goal = scenario.goal.position;
    let reached_goal = (end[0] - goal[0]).hypot(end[1] - goal[1]) <= scenario.goal.tolerance + 0.01;
    let contact = truth.summary.first_contact.is_some();
    Ok(DemoRun { report, truth, reached_goal, contact })
}
