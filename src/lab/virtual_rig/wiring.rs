//! How the virtual rig is wired: the simulated controller and every vehicle's motors as
//! the simulated rig wires them, the scenario's faults, and the gateway's rig to match.

use flowgate_protocol::slcan::Bitrate;
use flowgate_sim::camera::CameraModel;
use flowgate_sim::faults::FaultPlan;
use flowgate_sim::motors::{FleetMotors, MotorKind};
use flowgate_sim::psd_controller::LedMap;
use flowgate_sim::rig::{RigConfig, WiredVehicle};

use super::{CanTransport, ControllerSpec, Options};
use crate::lab::Scenario;

/// The simulated controller (the scenario's camera, LEDs, noise and faults) and every
/// vehicle as the simulated rig wires it (the robot's motors a board at node 1, or CiA 402
/// drives at nodes 1 and 2; the other vehicles' after them).
pub(super) fn firmware_spec(
    scenario: &Scenario,
    options: &Options,
    plan: &FaultPlan,
) -> (ControllerSpec, Vec<WiredVehicle>) {
    let camera = scenario.camera;
    let spec = ControllerSpec {
        camera,
        leds: options
            .controller_leds
            .map_or(LedMap::standard(scenario.robot.radius), |n| LedMap::standard(scenario.robot.radius).driving(n)),
        noise_counts: scenario.sensing.position_noise * counts_per_metre(&camera),
        seed: scenario.sensing.seed,
        faults: plan.clone(),
    };
    let wired = wiring(scenario, options).vehicles().expect("loading refused a fleet the simulated rig cannot wire");
    (spec, wired)
}

/// The scenario's faults, its sensing delay played as the controller's sample delay.
pub(super) fn fault_plan(scenario: &Scenario) -> FaultPlan {
    let mut plan = scenario.faults.clone();
    if plan.sample_delay_ms == 0.0 {
        plan.sample_delay_ms = scenario.sensing.delay * 1e3;
    }
    plan
}

/// Every vehicle's motors on the simulated bus (the robot's playing the scenario's faults,
/// each vehicle's own link failing at its `link_lost_at`, the robot's at
/// `options.robot_link_lost_at`), and each one's board node.
pub(super) fn fleet_motors(
    scenario: &Scenario,
    wired: &[WiredVehicle],
    plan: &FaultPlan,
    options: &Options,
) -> (FleetMotors, Vec<Option<u8>>) {
    let kinds: Vec<MotorKind> = wired.iter().map(|v| v.motors).collect();
    let link_lost_at = std::iter::once(options.robot_link_lost_at.unwrap_or(f64::INFINITY))
        .chain(scenario.sim.vehicles.iter().map(|v| v.link_lost_at.unwrap_or(f64::INFINITY)))
        .collect();
    let board_nodes = kinds
        .iter()
        .map(|k| match k {
            MotorKind::Board(n) => Some(n.get()),
            MotorKind::Cia402 { .. } => None,
        })
        .collect();
    (FleetMotors::new(&kinds, plan, link_lost_at), board_nodes)
}

/// How the simulated rig wires the scenario's vehicles.
fn wiring(scenario: &Scenario, options: &Options) -> RigConfig {
    let mut wiring = RigConfig::new(scenario.sim.clone());
    if let Some(n) = options.controller_leds {
        wiring.leds = wiring.leds.driving(n);
    }
    if options.cia402 {
        let node = |n| flowgate_protocol::canopen::NodeId::new(n).expect("1-127");
        wiring.cia402 = Some([node(1), node(2)]);
    }
    wiring
}

/// The gateway's rig for the scenario, and the bitrate the shell opens its SLCAN adapter at
/// (the simulated bus runs at 1 Mbit/s).
pub(super) fn gateway_rig(scenario: &Scenario, options: &Options) -> (crate::config::Rig, Bitrate) {
    let wiring = wiring(scenario, options);
    let mut rig = match options.can {
        CanTransport::Slcan => scenario.rig_wired("slcan:/dev/null", &wiring),
        CanTransport::SocketCan => scenario.rig_wired("socketcan:vcan0", &wiring),
    };
    if let Some(adjust) = options.adjust_rig {
        adjust(&mut rig);
    }
    let bitrate = match &rig.can {
        crate::config::CanUrl::Slcan { bitrate, .. } => Bitrate::from_bps(*bitrate).unwrap_or(Bitrate::M1),
        _ => Bitrate::M1,
    };
    (rig, bitrate)
}

/// PSD counts per metre of floor near the origin, from the camera model.
fn counts_per_metre(camera: &CameraModel) -> f64 {
    let (a, b) =
        (camera.project(num_complex::Complex64::new(0.0, 0.0)), camera.project(num_complex::Complex64::new(0.01, 0.0)));
    match (a, b) {
        (Some(a), Some(b)) => (b.0 - a.0).hypot(b.1 - a.1) / 0.01,
        _ => 0.0,
    }
}
