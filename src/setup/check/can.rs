//! The CAN side of `flowgate check`: the interface, the motor board or the CiA 402 drives,
//! and what they answer.

use super::{
    CheckReport, BOARD_CONFIG, BOARD_ITEMS, CAN_IF, CAN_OPEN, HEARTBEAT, LEFT_DRIVE, LISTEN, OTHERS, RIGHT_DRIVE,
    STATUS_WAIT, VEHICLE_MOTORS,
};
use crate::config::CanUrl;
use crate::config::{Cia402Settings, Motors, Rig, VehicleMotors};
use crate::gateway::core::input::CanEvent;
use crate::gateway::shell::link::{open_can, CanError, CanLink, SerialError};
use flowgate_protocol::motor::{BoardState, FaultBits, MotorMessage, NodeId};
use std::path::Path;
use tokio::time::{timeout_at, Instant};

pub(super) async fn check_can(rig: &Rig, report: &mut CheckReport) {
    let endpoint = match &rig.can {
        CanUrl::SocketCan { interface } => interface.clone(),
        CanUrl::Slcan { path, .. } => path.display().to_string(),
        #[cfg(feature = "lab")]
        CanUrl::Memory => "memory".to_string(),
    };
    let opened = match open_checked(rig).await {
        Ok(opened) => opened,
        Err(why) => {
            report.fail(CAN_IF, &endpoint, why);
            report.skip(&BOARD_ITEMS, &endpoint, "the CAN interface failed");
            if !rig.vehicles.is_empty() {
                report.skip(&[VEHICLE_MOTORS], &endpoint, "the CAN interface failed");
            }
            return;
        }
    };
    let (mut link, heard) = opened;
    judge_interface(rig, &heard, &endpoint, report);
    match rig.motors {
        Motors::Cia402(settings) => check_drives(&mut link, &settings, &endpoint, report).await,
        Motors::Pcl80k => check_board(rig, &mut link, &heard, &endpoint, report).await,
    }
    check_vehicle_motors(rig, &mut link, &heard, &endpoint, report).await;
}

/// The CAN link opened (SocketCAN's interface up first), and a while of the bus heard.
pub(super) async fn open_checked(rig: &Rig) -> Result<(CanLink, Heard), String> {
    if let CanUrl::SocketCan { interface } = &rig.can {
        socketcan_state(interface)?;
    }
    let mut link = match tokio::time::timeout(CAN_OPEN, open_can(&rig.can)).await {
        Ok(Ok(link)) => link,
        Ok(Err(e)) => return Err(can_open_error(e)),
        Err(_) => return Err(format!("did not open within {} s", CAN_OPEN.as_secs())),
    };
    let heard = listen(&mut link, rig.node, rig.can.polls_status()).await.map_err(|e| e.to_string())?;
    Ok((link, heard))
}

/// The interface: error frames, or an SLCAN adapter's status flags.
pub(super) fn judge_interface(rig: &Rig, heard: &Heard, endpoint: &str, report: &mut CheckReport) {
    match (&rig.can, heard.adapter) {
        (_, _) if heard.error_frames > 0 => report.fail(
            CAN_IF,
            endpoint,
            format!("{} error frames in {} ms (bus-off: {})", heard.error_frames, LISTEN.as_millis(), heard.bus_off),
        ),
        (CanUrl::Slcan { .. }, None) => {
            report.fail(CAN_IF, endpoint, "the SLCAN adapter did not report its status flags (F)")
        }
        (CanUrl::Slcan { .. }, Some((bus_off, passive))) if bus_off || passive => report.fail(
            CAN_IF,
            endpoint,
            format!("the adapter's controller is {}", if bus_off { "bus-off" } else { "error-passive" }),
        ),
        (CanUrl::Slcan { bitrate, .. }, Some(_)) => {
            report.pass(CAN_IF, endpoint, format!("SLCAN adapter open at {bitrate} bit/s, status flags clear"))
        }
        _ => report.pass(CAN_IF, endpoint, format!("up, no error frames in {} ms", LISTEN.as_millis())),
    }
}

/// The board: its heartbeat and state, no other master, and its configuration.
pub(super) async fn check_board(
    rig: &Rig,
    link: &mut CanLink,
    heard: &Heard,
    endpoint: &str,
    report: &mut CheckReport,
) {
    let board = format!("{endpoint}, node {}", rig.node.get());
    // The board's heartbeat and state.
    let others = if heard.other_nodes.is_empty() {
        "no other node heard".to_string()
    } else {
        format!("nodes heard: {:?}", heard.other_nodes)
    };
    let healthy = match (heard.heartbeats, heard.state) {
        (0, _) => {
            report.fail(
                HEARTBEAT,
                &board,
                format!("no heartbeat in {} ms (powered? node id = can.node? bitrate?); {others}", LISTEN.as_millis()),
            );
            false
        }
        (_, Some(BoardState::Fault | BoardState::EStop)) => {
            report.fail(
                HEARTBEAT,
                &board,
                format!(
                    "in {:?} (faults: {}): clear the cause, then reset it",
                    heard.state.unwrap_or(BoardState::Fault),
                    fault_names(heard.faults)
                ),
            );
            false
        }
        (_, Some(BoardState::Enabled)) => {
            report.fail(HEARTBEAT, &board, "already Enabled: is another gateway driving it?");
            false
        }
        (n, state) => {
            report.pass(
                HEARTBEAT,
                &board,
                format!("{n} heartbeats in {} ms, {:?}", LISTEN.as_millis(), state.unwrap_or(BoardState::Disabled)),
            );
            true
        }
    };
    if heard.foreign_commands > 0 || heard.gateway_heartbeats > 0 {
        report.fail(
            OTHERS,
            endpoint,
            format!(
                "{} velocity commands and {} gateway heartbeats from elsewhere on the bus: another gateway is running",
                heard.foreign_commands, heard.gateway_heartbeats
            ),
        );
    } else {
        report.pass(OTHERS, endpoint, "no velocity commands or gateway heartbeats on the bus");
    }
    if !healthy {
        report.skip(&[BOARD_CONFIG], &board, "the board is not ready");
        return;
    }
    match configure_board(link, rig).await {
        Ok(detail) => report.pass(BOARD_CONFIG, &board, detail),
        Err(why) => report.fail(BOARD_CONFIG, &board, why),
    }
}

/// Each CiA 402 drive, read by SDO only: its device type (CiA 402), its supported drive
/// modes (profile velocity) and its state (not faulted, not already enabled by another
/// master). Then whether another master speaks to them.
pub(super) async fn check_drives(
    link: &mut CanLink,
    settings: &Cia402Settings,
    endpoint: &str,
    report: &mut CheckReport,
) {
    let mut others = 0;
    for (item, node) in [(LEFT_DRIVE, settings.left), (RIGHT_DRIVE, settings.right)] {
        let subject = format!("{endpoint}, node {}", node.get());
        match drive_verdict(link, settings, node, &mut others).await {
            Ok(detail) => report.pass(item, &subject, detail),
            Err(why) => report.fail(item, &subject, why),
        }
    }
    if others > 0 {
        report.fail(
            OTHERS,
            endpoint,
            format!("{others} RPDOs, SDO requests or gateway heartbeats from another master"),
        );
    } else {
        report.pass(OTHERS, endpoint, "no other master heard while the drives were read");
    }
}

/// One drive read by SDO: a CiA 402 device with profile velocity, neither in fault nor
/// already enabled.
async fn drive_verdict(
    link: &mut CanLink,
    settings: &Cia402Settings,
    node: flowgate_protocol::canopen::NodeId,
    others: &mut u32,
) -> Result<String, String> {
    use flowgate_protocol::canopen::{object, DriveState};
    let device = sdo_upload(link, settings, node, 0x1000, others).await?;
    if device & 0xFFFF != 402 {
        return Err(format!("device type 0x{device:08X}: not a CiA 402 drive"));
    }
    let modes = sdo_upload(link, settings, node, 0x6502, others).await?;
    if modes & 0x4 == 0 {
        return Err(format!("supported drive modes 0x{modes:08X}: no profile velocity (bit 2)"));
    }
    let sw = sdo_upload(link, settings, node, object::STATUSWORD, others).await? as u16;
    match DriveState::from_statusword(sw) {
        DriveState::Fault | DriveState::FaultReactionActive => {
            Err(format!("statusword 0x{sw:04X}: in fault (error code at 0x603F); clear the cause, the arm resets it"))
        }
        DriveState::OperationEnabled => {
            Err(format!("statusword 0x{sw:04X}: already operation enabled: is another master driving it?"))
        }
        state => Ok(format!("CiA 402, profile velocity supported, statusword 0x{sw:04X} ({})", state.name())),
    }
}

/// Each other vehicle's motors: its board's heartbeat heard in a state the gateway could
/// enable, or each of its drives read as the robot's are.
pub(super) async fn check_vehicle_motors(
    rig: &Rig,
    link: &mut CanLink,
    heard: &Heard,
    endpoint: &str,
    report: &mut CheckReport,
) {
    let mut others = 0;
    for v in &rig.vehicles {
        match v.motors {
            VehicleMotors::Board(node) => {
                let subject = format!("vehicles: {}, {endpoint} node {}", v.name, node.get());
                match heard.boards[usize::from(node.get())] {
                    (0, _) => report.fail(
                        VEHICLE_MOTORS,
                        subject,
                        format!("no heartbeat in {} ms (powered? vehicles.node? bitrate?)", LISTEN.as_millis()),
                    ),
                    (_, Some(state @ (BoardState::Fault | BoardState::EStop | BoardState::Enabled))) => report.fail(
                        VEHICLE_MOTORS,
                        subject,
                        format!("its board is {state:?}: clear it (or the gateway driving it) before arming"),
                    ),
                    (n, state) => report.pass(
                        VEHICLE_MOTORS,
                        subject,
                        format!(
                            "{n} heartbeats in {} ms, {:?}",
                            LISTEN.as_millis(),
                            state.unwrap_or(BoardState::Disabled)
                        ),
                    ),
                }
            }
            VehicleMotors::Drives { left, right } => {
                let Motors::Cia402(robot) = rig.motors else { continue };
                let settings = Cia402Settings { left, right, ..robot };
                for node in [left, right] {
                    let subject = format!("vehicles: {}, {endpoint} drive {}", v.name, node.get());
                    match drive_verdict(link, &settings, node, &mut others).await {
                        Ok(detail) => report.pass(VEHICLE_MOTORS, subject, detail),
                        Err(why) => report.fail(VEHICLE_MOTORS, subject, why),
                    }
                }
            }
        }
    }
}

/// Read `index`:0 of drive `node` (an expedited SDO upload) within the SDO timeout, counting
/// frames of another master heard meanwhile.
pub(super) async fn sdo_upload(
    link: &mut CanLink,
    settings: &Cia402Settings,
    node: flowgate_protocol::canopen::NodeId,
    index: u16,
    others: &mut u32,
) -> Result<u32, String> {
    use flowgate_protocol::canopen::{sdo_abort_text, CanOpenMessage, PdoDirection, SdoRequest, SdoResponse};
    let request = CanOpenMessage::SdoRequest { node, request: SdoRequest::Upload { index, sub: 0 } };
    let frame = request.to_frame().ok_or("the request does not encode")?;
    let end = Instant::now() + settings.sdo_timeout;
    timeout_at(end, link.send(frame))
        .await
        .map_err(|_| format!("SDO 0x{index:04X}:0 not sent within cia402.sdo_timeout_ms"))?
        .map_err(|e| e.to_string())?;
    let ours = [settings.left, settings.right];
    loop {
        let event = timeout_at(end, link.recv()).await.map_err(|_| {
            format!("no answer to SDO 0x{index:04X}:0 within cia402.sdo_timeout_ms (powered? node id? bitrate?)")
        })?;
        let CanEvent::Frame(f) = event.map_err(|e| e.to_string())? else { continue };
        match CanOpenMessage::parse(&f) {
            Ok(CanOpenMessage::SdoResponse { node: n, response }) if n == node && response.object() == (index, 0) => {
                return match response {
                    SdoResponse::Uploaded { data, .. } => Ok(data.value()),
                    SdoResponse::Abort { code, .. } => {
                        Err(format!("SDO 0x{index:04X}:0 aborted: 0x{code:08X} ({})", sdo_abort_text(code)))
                    }
                    SdoResponse::Downloaded { .. } => Err(format!("SDO 0x{index:04X}:0 answered as a write")),
                };
            }
            Ok(CanOpenMessage::Pdo { direction: PdoDirection::Receive, node: n, .. })
            | Ok(CanOpenMessage::SdoRequest { node: n, .. })
                if ours.contains(&n) =>
            {
                *others += 1
            }
            Ok(CanOpenMessage::Heartbeat { node: n, .. }) if n == settings.gateway => *others += 1,
            _ => {}
        }
    }
}

pub(super) fn can_open_error(e: CanError) -> String {
    match e {
        CanError::Serial(SerialError::Missing { path }) => format!("SLCAN adapter {path} does not exist (plugged in?)"),
        other => other.to_string(),
    }
}

/// A SocketCAN interface's state from sysfs (and `ip`'s view of a real controller).
pub(super) fn socketcan_state(interface: &str) -> Result<(), String> {
    let dir = Path::new("/sys/class/net").join(interface);
    if !dir.exists() {
        return Err(format!("no such interface (ip link show {interface})"));
    }
    let read = |name: &str| std::fs::read_to_string(dir.join(name)).map(|s| s.trim().to_string()).unwrap_or_default();
    let flags = u32::from_str_radix(read("flags").trim_start_matches("0x"), 16).unwrap_or(0);
    if flags & 1 == 0 {
        return Err(format!("is down (ip link set up {interface})"));
    }
    let errors: u64 =
        ["statistics/rx_errors", "statistics/tx_errors"].iter().filter_map(|n| read(n).parse::<u64>().ok()).sum();
    if errors > 0 {
        return Err(format!(
            "{errors} rx/tx errors counted since it came up (ip -details -statistics link show {interface})"
        ));
    }
    // A real controller has a state (vcan has none): anything but ERROR-ACTIVE is a fault.
    if let Ok(out) =
        std::process::Command::new("ip").args(["-details", "-json", "link", "show", "dev", interface]).output()
    {
        if let Ok(v) = serde_json::from_slice::<serde_json::Value>(&out.stdout) {
            if let Some(state) = v[0]["linkinfo"]["info_data"]["state"].as_str() {
                if state != "ERROR-ACTIVE" {
                    return Err(format!("controller state {state} (not ERROR-ACTIVE)"));
                }
            }
        }
    }
    Ok(())
}

/// What the bus said while the check listened.
#[derive(Debug, Default)]
pub(super) struct Heard {
    heartbeats: u32,
    state: Option<BoardState>,
    faults: FaultBits,
    other_nodes: Vec<u8>,
    foreign_commands: u32,
    gateway_heartbeats: u32,
    error_frames: u32,
    bus_off: bool,
    /// An SLCAN adapter's flags: (bus-off, error-passive).
    adapter: Option<(bool, bool)>,
    /// Every other board's heartbeats and last state, by node id (the fleet's vehicles').
    boards: [(u32, Option<BoardState>); 16],
}

pub(super) async fn listen(link: &mut CanLink, node: NodeId, poll_status: bool) -> Result<Heard, CanError> {
    let mut heard = Heard::default();
    if poll_status {
        tokio::time::timeout(STATUS_WAIT, link.poll_status())
            .await
            .map_err(|_| CanError::Timeout { what: "status poll" })??;
    }
    let end = Instant::now() + LISTEN;
    while let Ok(event) = timeout_at(end, link.recv()).await {
        match event? {
            CanEvent::Frame(frame) => match MotorMessage::parse(&frame) {
                Ok(MotorMessage::Heartbeat { node: n, state }) if n == node => {
                    heard.heartbeats += 1;
                    heard.state = Some(state);
                }
                Ok(MotorMessage::Status { node: n, state, faults, .. }) if n == node => {
                    heard.state = Some(state);
                    heard.faults = faults;
                }
                Ok(MotorMessage::Heartbeat { node: n, state }) => {
                    let board = &mut heard.boards[usize::from(n.get())];
                    board.0 += 1;
                    board.1 = Some(state);
                    if !heard.other_nodes.contains(&n.get()) {
                        heard.other_nodes.push(n.get());
                    }
                }
                Ok(MotorMessage::Velocity { .. }) => heard.foreign_commands += 1,
                Ok(MotorMessage::GatewayHeartbeat { .. }) => heard.gateway_heartbeats += 1,
                Ok(m) => {
                    if let Some(n) = m.node().filter(|n| *n != node) {
                        if !heard.other_nodes.contains(&n.get()) {
                            heard.other_nodes.push(n.get());
                        }
                    }
                }
                Err(_) => {}
            },
            CanEvent::ErrorFrame { bus_off } => {
                heard.error_frames += 1;
                heard.bus_off |= bus_off;
            }
            CanEvent::AdapterStatus { bus_off, error_passive } => heard.adapter = Some((bus_off, error_passive)),
            CanEvent::Garbled | CanEvent::TransmitRefused => heard.error_frames += 1,
            CanEvent::InterfaceDown => return Err(CanError::InterfaceDown),
        }
    }
    heard.other_nodes.sort_unstable();
    Ok(heard)
}

/// Send the config the gateway sends before every enable (never the enable), and read the
/// board's next status: the motor protocol has no acknowledgement of a config, so
/// "accepted" is the board's status after it still Disabled, fault-free and at rest.
pub(super) async fn configure_board(link: &mut CanLink, rig: &Rig) -> Result<String, String> {
    let b = rig.board;
    let node = rig.node;
    let frame = MotorMessage::Config { node, accel: b.accel, max_rate: b.max_rate, timeout_ms: b.command_timeout_ms }
        .to_frame()
        .map_err(|e| format!("the config does not encode: {e}"))?;
    tokio::time::timeout(STATUS_WAIT, link.send(frame))
        .await
        .map_err(|_| "the config frame was not taken within its deadline".to_string())?
        .map_err(|e| e.to_string())?;
    let end = Instant::now() + STATUS_WAIT;
    let mut status = None;
    let mut rates = None;
    while status.is_none() || rates.is_none() {
        match timeout_at(end, link.recv()).await {
            Err(_) => break,
            Ok(Err(e)) => return Err(e.to_string()),
            Ok(Ok(CanEvent::Frame(f))) => match MotorMessage::parse(&f) {
                Ok(MotorMessage::Status { node: n, state, faults, .. }) if n == node => status = Some((state, faults)),
                Ok(MotorMessage::AxisRates { node: n, left, right }) if n == node && status.is_some() => {
                    rates = Some((left, right))
                }
                _ => {}
            },
            Ok(Ok(_)) => {}
        }
    }
    let Some((state, faults)) = status else {
        return Err(format!("no status within {} ms of the config", STATUS_WAIT.as_millis()));
    };
    if state != BoardState::Disabled || !faults.is_empty() {
        return Err(format!("after the config: {state:?}, faults {}", fault_names(faults)));
    }
    if let Some((l, r)) = rates.filter(|&(l, r)| l != 0 || r != 0) {
        return Err(format!("its axes are moving ({l}, {r} pulses/s) while Disabled"));
    }
    Ok(format!(
        "accel {} pulses/s², max rate {} pulses/s, timeout {} ms sent; then Disabled, no faults, at rest",
        b.accel, b.max_rate, b.command_timeout_ms
    ))
}

/// A board's fault bits by name.
pub fn fault_names(f: FaultBits) -> String {
    const NAMES: [(u8, &str); 6] = [
        (FaultBits::CMD_TIMEOUT, "command timeout"),
        (FaultBits::ESTOP, "e-stop"),
        (FaultBits::RATE_LIMIT, "rate limit"),
        (FaultBits::BUS, "bus"),
        (FaultBits::DRIVER, "driver"),
        (FaultBits::GATEWAY_LOST, "gateway lost"),
    ];
    let names: Vec<&str> = NAMES.iter().filter(|(bit, _)| f.contains(*bit)).map(|(_, n)| *n).collect();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}
