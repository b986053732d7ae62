//! `flowgate check`: a preflight that moves nothing.
//!
//! It goes through the rig in the order the gateway meets it (the config and its
//! cross-checks, the serial port, the PSD controller's identity, schedule, clock and
//! stream, the goal's reach from where the robot stands, the CAN interface, the motor board's heartbeat and config, or each CiA 402
//! drive's identity and state) and says of each
//! PASS, WARN or FAIL, naming the device or the config key. A step that cannot be reached
//! because an earlier one failed is SKIP, with the reason. It never enables a board: the
//! only frame it sends to one is the config the gateway sends before every enable; a CiA
//! 402 drive it only reads (SDO uploads).

use std::fmt;
use std::path::Path;
use std::time::Duration;

use flowgate_protocol::motor::{BoardState, FaultBits, MotorMessage, NodeId};
use tokio::time::{timeout_at, Instant};

use super::psd_client::{PsdClient, PsdClientError};
use crate::config::CanUrl;
use crate::config::{Cia402Settings, ConfigError, GatewayConfig, Motors, Rig};
use crate::gateway::core::input::CanEvent;
use crate::gateway::core::psd_session::MAX_RTT;
use crate::gateway::core::SetupError;
use crate::gateway::shell::link::{open_can, CanError, CanLink, SerialError};
use crate::Point;

/// Verdict of one line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    Pass,
    /// Works, but something deserves a look (the run would go on).
    Warn,
    Fail,
    /// Not reached: an earlier step failed.
    Skip,
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Verdict::Pass => "PASS",
            Verdict::Warn => "WARN",
            Verdict::Fail => "FAIL",
            Verdict::Skip => "SKIP",
        })
    }
}

/// One line of the report: what was checked, on what (a device or a config key), the
/// verdict and why.
#[derive(Debug, Clone)]
pub struct Line {
    pub item: &'static str,
    pub subject: String,
    pub verdict: Verdict,
    pub detail: String,
}

/// The preflight's findings, in order.
#[derive(Debug, Default)]
pub struct CheckReport {
    pub lines: Vec<Line>,
}

impl CheckReport {
    fn add(&mut self, item: &'static str, subject: impl Into<String>, verdict: Verdict, detail: impl Into<String>) {
        self.lines.push(Line { item, subject: subject.into(), verdict, detail: detail.into() });
    }
    fn pass(&mut self, item: &'static str, subject: impl Into<String>, detail: impl Into<String>) {
        self.add(item, subject, Verdict::Pass, detail);
    }
    fn fail(&mut self, item: &'static str, subject: impl Into<String>, detail: impl Into<String>) {
        self.add(item, subject, Verdict::Fail, detail);
    }
    fn skip(&mut self, items: &[&'static str], subject: &str, why: &str) {
        for item in items {
            self.add(item, subject, Verdict::Skip, why);
        }
    }
    /// How many lines failed.
    pub fn failures(&self) -> usize {
        self.lines.iter().filter(|l| l.verdict == Verdict::Fail).count()
    }
    pub fn line(&self, item: &str) -> Option<&Line> {
        self.lines.iter().find(|l| l.item == item)
    }
}

impl fmt::Display for CheckReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let w_item = self.lines.iter().map(|l| l.item.len()).max().unwrap_or(0);
        let w_subject = self.lines.iter().map(|l| l.subject.chars().count()).max().unwrap_or(0);
        for l in &self.lines {
            writeln!(f, "{}  {:w_item$}  {:w_subject$}  {}", l.verdict, l.item, l.subject, l.detail)?;
        }
        let (fail, warn) = (self.failures(), self.lines.iter().filter(|l| l.verdict == Verdict::Warn).count());
        let warnings = if warn == 1 { "1 warning".to_string() } else { format!("{warn} warnings") };
        match fail {
            0 => write!(f, "all {} checks passed ({warnings}): the rig is ready to arm", self.lines.len()),
            n => write!(f, "{n} of {} checks failed ({warnings}): fix them before arming", self.lines.len()),
        }
    }
}

// The report's items, in order.
const CONFIG: &str = "config";
const WATCHDOGS: &str = "watchdogs vs board timeout";
const SCHEDULE: &str = "LED schedule";
const REALTIME: &str = "real-time settings";
const SERIAL: &str = "serial port";
const ANSWERS: &str = "controller answers";
const IDENTITY: &str = "controller identity";
const ACCEPTED: &str = "schedule accepted";
const TIME_SYNC: &str = "time sync";
const STREAM: &str = "sample stream";
const LEDS: &str = "LEDs in view";
const GOAL: &str = "goal reachable";
const CAN_IF: &str = "CAN interface";
const HEARTBEAT: &str = "board heartbeat";
const OTHERS: &str = "no other master";
const BOARD_CONFIG: &str = "board config";
const LEFT_DRIVE: &str = "left drive";
const RIGHT_DRIVE: &str = "right drive";

const PSD_ITEMS: [&str; 7] = [ANSWERS, IDENTITY, ACCEPTED, TIME_SYNC, STREAM, LEDS, GOAL];
const BOARD_ITEMS: [&str; 3] = [HEARTBEAT, OTHERS, BOARD_CONFIG];

/// How long the stream is watched.
const STREAM_WATCH: Duration = Duration::from_millis(600);
/// Time syncs measured.
const SYNCS: usize = 8;
/// How long the bus is listened to for the board (its heartbeat comes every 100 ms).
const LISTEN: Duration = Duration::from_millis(1000);
/// How long a status after the config may take (the board reports every 50 ms).
const STATUS_WAIT: Duration = Duration::from_millis(500);
/// How long opening the CAN endpoint may take (an SLCAN adapter answers three commands).
const CAN_OPEN: Duration = Duration::from_secs(5);

/// Check the rig `config` describes. Never fails itself: every problem is a line.
pub async fn check(config: &Path) -> CheckReport {
    let mut report = CheckReport::default();
    let origin = config.display().to_string();
    let rig = match load(config) {
        Ok(rig) => rig,
        Err((subject, why)) => {
            report.fail(CONFIG, subject, why);
            report.skip(&[SERIAL], "-", "the config failed");
            report.skip(&PSD_ITEMS, "-", "the config failed");
            report.skip(&[CAN_IF], "-", "the config failed");
            report.skip(&BOARD_ITEMS, "-", "the config failed");
            return report;
        }
    };
    report.pass(CONFIG, origin, "parsed; every key in range");
    config_cross_checks(&rig, &mut report);
    // Applied to this process as the gateway applies them to its own: a refusal here is the
    // refusal `flowgate run` would meet, with the same message.
    match crate::gateway::shell::realtime::apply(&rig.realtime) {
        Ok(()) if rig.realtime.is_empty() => report.pass(REALTIME, "realtime", "none asked for"),
        Ok(()) => report.pass(REALTIME, "realtime", format!("{}: granted", rig.realtime)),
        Err(e) => report.fail(REALTIME, "realtime", e.to_string()),
    }
    check_psd(&rig, &mut report).await;
    check_can(&rig, &mut report).await;
    report
}

/// The config, or (the key or file, why).
fn load(path: &Path) -> Result<Rig, (String, String)> {
    GatewayConfig::load(path).map_err(|e| match e {
        ConfigError::Invalid { invalid, .. } => (invalid.key.clone(), invalid.why.clone()),
        other => (path.display().to_string(), other.to_string()),
    })
}

fn config_cross_checks(rig: &Rig, report: &mut CheckReport) {
    // Loading refused a config whose watchdogs would let the board's own timeout fire
    // first; these lines show the figures that rule was checked with.
    let s = &rig.safety;
    let t_us = rig.sample_period.as_micros();
    report.pass(
        WATCHDOGS,
        "safety.*",
        format!(
            "sample {} ms and pose {} ms (+ T = {:.3} ms) fire before drive.command_timeout_ms = {} ms; heartbeat {} ms",
            s.sample_timeout.as_millis(),
            s.pose_timeout.as_millis(),
            t_us as f64 / 1000.0,
            rig.board.command_timeout_ms,
            s.heartbeat_timeout.as_millis()
        ),
    );
    report.pass(
        SCHEDULE,
        "schedule",
        format!(
            "{} LEDs, frame T = {:.3} ms ({:.1} Hz)",
            rig.schedule.slots().len(),
            t_us as f64 / 1000.0,
            1e6 / t_us as f64
        ),
    );
}

async fn check_psd(rig: &Rig, report: &mut CheckReport) {
    let port = rig.serial.port.display().to_string();
    let mut client = match PsdClient::open(&rig.serial, rig.schedule, rig.psd_counts) {
        Ok(c) => c,
        Err(e) => {
            report.fail(SERIAL, &port, e.to_string());
            report.skip(&PSD_ITEMS, &port, "the serial port failed");
            return;
        }
    };
    report.pass(SERIAL, &port, format!("exists and opened exclusively at {} baud", rig.serial.baud));
    let handshake = match client.configure().await {
        Ok(h) => h,
        Err(e) => {
            handshake_failed(&e, &port, report);
            client.stop().await;
            return;
        }
    };
    let i = handshake.info;
    report.pass(ANSWERS, &port, "answers GetInfo");
    report.pass(
        IDENTITY,
        &port,
        format!(
            "firmware {}.{}.{}, drives up to {} LEDs, PSD {}x{} counts, µs timestamps",
            i.firmware[0], i.firmware[1], i.firmware[2], i.max_leds, i.psd_counts[0], i.psd_counts[1]
        ),
    );
    report.pass(
        ACCEPTED,
        &port,
        format!("{} slots, T = {} µs", rig.schedule.slots().len(), rig.sample_period.as_micros()),
    );
    match client.round_trips(SYNCS).await {
        Ok(mut trips) => {
            trips.push(handshake.round_trip);
            trips.sort();
            let median = trips[trips.len() / 2];
            let detail = format!(
                "{} round trips: min {} µs, median {} µs, max {} µs",
                trips.len(),
                trips[0].as_micros(),
                median.as_micros(),
                trips[trips.len() - 1].as_micros()
            );
            if median > MAX_RTT {
                report.fail(
                    TIME_SYNC,
                    &port,
                    format!("{detail}: over {} ms, the gateway would discard its resyncs", MAX_RTT.as_millis()),
                );
            } else {
                report.pass(TIME_SYNC, &port, detail);
            }
        }
        Err(e) => report.fail(TIME_SYNC, &port, e.to_string()),
    }
    watch_stream(rig, &mut client, &port, report).await;
    client.stop().await;
}

/// The handshake's steps in order: which one failed says which lines passed.
fn handshake_failed(e: &PsdClientError, port: &str, report: &mut CheckReport) {
    let (failed, passed): (&str, &[&'static str]) = match e {
        PsdClientError::Setup(SetupError::Silent { request: "GetInfo" }) => (ANSWERS, &[]),
        PsdClientError::Setup(SetupError::Identity(_)) => (IDENTITY, &[ANSWERS]),
        PsdClientError::Setup(SetupError::Refused { request: "SetSchedule", .. })
        | PsdClientError::Setup(SetupError::Silent { request: "SetSchedule" }) => (ACCEPTED, &[ANSWERS, IDENTITY]),
        PsdClientError::Setup(SetupError::Silent { request: "TimeSync" }) => {
            (TIME_SYNC, &[ANSWERS, IDENTITY, ACCEPTED])
        }
        PsdClientError::Setup(_) => (STREAM, &[ANSWERS, IDENTITY, ACCEPTED, TIME_SYNC]),
        _ => (ANSWERS, &[]),
    };
    for item in passed {
        report.pass(item, port, "yes");
    }
    let subject = if failed == IDENTITY { format!("{port}, calibration.counts") } else { port.to_string() };
    report.fail(failed, subject, e.to_string());
    let rest: Vec<&'static str> = PSD_ITEMS.iter().copied().skip_while(|i| *i != failed).skip(1).collect();
    report.skip(&rest, port, "the controller's setup failed");
}

async fn watch_stream(rig: &Rig, client: &mut PsdClient, port: &str, report: &mut CheckReport) {
    let leds: Vec<u8> = rig.schedule.slots().iter().map(|s| s.led).collect();
    let mut seen = vec![0u64; leds.len()];
    let mut weak = vec![0u64; leds.len()];
    let mut saturated = vec![0u64; leds.len()];
    // The robot's LEDs on the floor, as last seen clearly: where the robot stands.
    let (mut front, mut rear) = (None, None);
    let before = client.tally;
    let start = Instant::now();
    let end = start + STREAM_WATCH;
    loop {
        match client.next_sample(end).await {
            Ok(Some(s)) => {
                let clear = !s.flags.contains(flowgate_protocol::psd::SampleFlags::WEAK_SIGNAL)
                    && !s.flags.contains(flowgate_protocol::psd::SampleFlags::SATURATED);
                if clear && (s.led == rig.robot_front || s.led == rig.robot_rear) {
                    let at = rig.calibration.to_floor(f64::from(s.x), f64::from(s.y));
                    *if s.led == rig.robot_front { &mut front } else { &mut rear } = at;
                }
                if let Some(k) = leds.iter().position(|&l| l == s.led) {
                    seen[k] += 1;
                    weak[k] += u64::from(s.flags.contains(flowgate_protocol::psd::SampleFlags::WEAK_SIGNAL));
                    saturated[k] += u64::from(s.flags.contains(flowgate_protocol::psd::SampleFlags::SATURATED));
                }
            }
            Ok(None) => break,
            Err(e) => {
                report.fail(STREAM, port, e.to_string());
                report.skip(&[LEDS, GOAL], port, "the stream failed");
                return;
            }
        }
    }
    let t = client.tally;
    let frames = t.frame_ends - before.frame_ends;
    let expected = STREAM_WATCH.as_secs_f64() / rig.sample_period.as_secs_f64();
    let rate = frames as f64 / STREAM_WATCH.as_secs_f64();
    let (bad, lost, discarded, faults) = (
        t.bad_frames - before.bad_frames,
        t.lost - before.lost,
        t.discarded - before.discarded,
        t.faults - before.faults,
    );
    let detail = format!(
        "{frames} frames in {} ms ({rate:.1} Hz of {:.1}); {bad} bad, {lost} lost, {discarded} duplicate or old, {faults} controller faults",
        STREAM_WATCH.as_millis(),
        1.0 / rig.sample_period.as_secs_f64()
    );
    report.add(STREAM, port, stream_verdict(frames, expected, faults, bad + lost + discarded), detail);
    judge_leds(rig, &leds, &seen, &weak, &saturated, report);
    let robot = front.zip(rear).and_then(|(f, r)| rig.led_geometry.locate(f, r)).map(|(at, _)| at);
    check_goal(rig, robot, report);
}

/// The robot's two LEDs and every required obstacle's must be seen to arm; any other
/// obstacle out of view is absent until it comes into view: worth a warning.
fn judge_leds(rig: &Rig, leds: &[u8], seen: &[u64], weak: &[u64], saturated: &[u64], report: &mut CheckReport) {
    let mut problems = Vec::new();
    let mut fail = false;
    for (k, &led) in leds.iter().enumerate() {
        let robot = led == rig.robot_front || led == rig.robot_rear;
        let obstacle = rig.obstacles.iter().position(|o| o.led == led);
        let required = robot || obstacle.is_some_and(|i| rig.obstacles[i].required);
        let role = match obstacle {
            _ if robot => " (robot)".to_string(),
            Some(i) if required => format!(" (leds.obstacles[{i}].required)"),
            _ => String::new(),
        };
        let consequence = match obstacle {
            _ if required => "",
            Some(_) => ": not seen, absent until it comes into view",
            None => "",
        };
        if seen[k] == 0 {
            problems.push(format!("LED {led}{role}: no samples{consequence}"));
            fail |= required;
        } else if weak[k] * 2 > seen[k] || saturated[k] * 2 > seen[k] {
            problems.push(format!(
                "LED {led}{role}: {} of {} samples weak, {} saturated (out of view, occluded or dead?){consequence}",
                weak[k], seen[k], saturated[k]
            ));
            fail |= required;
        }
    }
    let leds_key = "leds";
    match (problems.is_empty(), fail) {
        (true, _) => report.pass(LEDS, leds_key, format!("all {} LEDs seen, none weak or saturated", leds.len())),
        (false, true) => report.fail(LEDS, leds_key, problems.join("; ")),
        (false, false) => report.add(LEDS, leds_key, Verdict::Warn, problems.join("; ")),
    }
}

/// Whether the robot, where the camera sees it, can reach the configured goal: the room's
/// walls, static obstacles and view's edge may close it off (`ctl goal` judges an
/// operator's goal the same way).
fn check_goal(rig: &Rig, robot: Option<Point>, report: &mut CheckReport) {
    let Some(goal) = &rig.goal else {
        report.pass(GOAL, "goal", "no [goal]: each operator's goal is checked as it is given (`ctl goal`)");
        return;
    };
    let at = Point::new(goal.position[0], goal.position[1]);
    let Some(robot) = robot else {
        report.skip(&[GOAL], "goal.position", "the robot's LEDs were not seen clearly");
        return;
    };
    let from = format!("({:.3}, {:.3})", robot.re, robot.im);
    if let crate::planner::Space::Lane { half_width } = rig.control.planner.space {
        // The goal is inside the lane (the config says so); the robot must be too.
        if robot.im.abs() >= half_width {
            let why = format!(
                "the robot at {from} is outside the lane (|y| >= {half_width:.3} m): the field cannot take it along"
            );
            report.fail(GOAL, "goal.position", why);
        } else {
            report.pass(GOAL, "goal.position", format!("{:?} along the lane from the robot at {from}", goal.position));
        }
        return;
    }
    let Some(room) = &rig.control.room else {
        report.pass(
            GOAL,
            "goal.position",
            format!("no walls, static obstacles or view's edge between it and the robot at {from}"),
        );
        return;
    };
    match room.blocked_at(robot) {
        Some(why) => report.add(
            GOAL,
            "goal.position",
            Verdict::Warn,
            format!("the robot at {from} {why}: the field takes it clear first; the goal's reach is not judged from there"),
        ),
        None if !room.reachable(robot, at) => report.fail(
            GOAL,
            "goal.position",
            format!(
                "{:?} is out of the robot's reach from {from}: the walls, static obstacles or the view's edge close it off",
                goal.position
            ),
        ),
        None => report.pass(GOAL, "goal.position", format!("{:?} reachable from the robot at {from}", goal.position)),
    }
}

/// A stream delivering under 80% of its frames, or reporting faults, fails; one that
/// delivers them with bad, lost or repeated packets is a warning.
fn stream_verdict(frames: u64, expected: f64, faults: u64, anomalies: u64) -> Verdict {
    if (frames as f64) < 0.8 * expected || faults > 0 {
        Verdict::Fail
    } else if anomalies > 0 {
        Verdict::Warn
    } else {
        Verdict::Pass
    }
}

async fn check_can(rig: &Rig, report: &mut CheckReport) {
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
            return;
        }
    };
    let (mut link, heard) = opened;
    judge_interface(rig, &heard, &endpoint, report);
    if let Motors::Cia402(settings) = rig.motors {
        check_drives(&mut link, &settings, &endpoint, report).await;
        return;
    }
    check_board(rig, &mut link, &heard, &endpoint, report).await;
}

/// The CAN link opened (SocketCAN's interface up first), and a while of the bus heard.
async fn open_checked(rig: &Rig) -> Result<(CanLink, Heard), String> {
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
fn judge_interface(rig: &Rig, heard: &Heard, endpoint: &str, report: &mut CheckReport) {
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
async fn check_board(rig: &Rig, link: &mut CanLink, heard: &Heard, endpoint: &str, report: &mut CheckReport) {
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
async fn check_drives(link: &mut CanLink, settings: &Cia402Settings, endpoint: &str, report: &mut CheckReport) {
    use flowgate_protocol::canopen::{object, DriveState};
    let mut others = 0;
    for (item, node) in [(LEFT_DRIVE, settings.left), (RIGHT_DRIVE, settings.right)] {
        let subject = format!("{endpoint}, node {}", node.get());
        let mut verdict = async || -> Result<String, String> {
            let device = sdo_upload(link, settings, node, 0x1000, &mut others).await?;
            if device & 0xFFFF != 402 {
                return Err(format!("device type 0x{device:08X}: not a CiA 402 drive"));
            }
            let modes = sdo_upload(link, settings, node, 0x6502, &mut others).await?;
            if modes & 0x4 == 0 {
                return Err(format!("supported drive modes 0x{modes:08X}: no profile velocity (bit 2)"));
            }
            let sw = sdo_upload(link, settings, node, object::STATUSWORD, &mut others).await? as u16;
            match DriveState::from_statusword(sw) {
                DriveState::Fault | DriveState::FaultReactionActive => Err(format!(
                    "statusword 0x{sw:04X}: in fault (error code at 0x603F); clear the cause, the arm resets it"
                )),
                DriveState::OperationEnabled => {
                    Err(format!("statusword 0x{sw:04X}: already operation enabled: is another master driving it?"))
                }
                state => Ok(format!("CiA 402, profile velocity supported, statusword 0x{sw:04X} ({})", state.name())),
            }
        };
        match verdict().await {
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

/// Read `index`:0 of drive `node` (an expedited SDO upload) within the SDO timeout, counting
/// frames of another master heard meanwhile.
async fn sdo_upload(
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

fn can_open_error(e: CanError) -> String {
    match e {
        CanError::Serial(SerialError::Missing { path }) => format!("SLCAN adapter {path} does not exist (plugged in?)"),
        other => other.to_string(),
    }
}

/// A SocketCAN interface's state from sysfs (and `ip`'s view of a real controller).
fn socketcan_state(interface: &str) -> Result<(), String> {
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
struct Heard {
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
}

async fn listen(link: &mut CanLink, node: NodeId, poll_status: bool) -> Result<Heard, CanError> {
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
async fn configure_board(link: &mut CanLink, rig: &Rig) -> Result<String, String> {
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

#[cfg(test)]
mod tests;
