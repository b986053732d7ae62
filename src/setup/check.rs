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

use tokio::time::Instant;

use super::psd_client::{PsdClient, PsdClientError};
use crate::config::{ConfigError, Rig, RigFile, VehicleMotors};
use crate::gateway::core::psd_session::MAX_RTT;
use crate::gateway::core::SetupError;
use crate::Point;

mod can;
use can::check_can;
pub use can::fault_names;
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
const VEHICLE: &str = "vehicle";
const REALTIME: &str = "real-time settings";
const SERIAL: &str = "serial port";
const ANSWERS: &str = "controller answers";
const IDENTITY: &str = "controller identity";
const ACCEPTED: &str = "schedule accepted";
const TIME_SYNC: &str = "time sync";
const STREAM: &str = "sample stream";
const LEDS: &str = "LEDs in view";
const GOAL: &str = "goal reachable";
const APART: &str = "vehicles apart";
const CAN_IF: &str = "CAN interface";
const HEARTBEAT: &str = "board heartbeat";
const OTHERS: &str = "no other master";
const BOARD_CONFIG: &str = "board config";
const LEFT_DRIVE: &str = "left drive";
const RIGHT_DRIVE: &str = "right drive";
const VEHICLE_MOTORS: &str = "vehicle motors";

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
    RigFile::load(path).map_err(|e| match e {
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
    report.pass(SCHEDULE, "schedule", schedule_detail(rig));
    for v in &rig.vehicles {
        let motors = match v.motors {
            VehicleMotors::Board(n) => format!("board node {}", n.get()),
            VehicleMotors::Drives { left, right } => format!("drives {} and {}", left.get(), right.get()),
        };
        let mut detail = format!(
            "LEDs {} and {}, {motors}, radius {} m, up to {} m/s",
            v.front_led, v.rear_led, v.robot.radius, v.robot.max_speed
        );
        if let Some(s) = &v.script {
            detail += &script_detail(s);
        }
        report.pass(VEHICLE, format!("vehicles: {}", v.name), detail);
    }
}

/// A scripted vehicle's script: from where, how fast, to where, and where it was cut.
fn script_detail(s: &crate::config::VehicleScript) -> String {
    let (start, end) = (s.script.start(), s.script.last_point());
    let to = match s.script.end_time() {
        Some(t) => format!(" to ({:.3}, {:.3}) in {t:.1} s", end.re, end.im),
        None => ", round and round".to_string(),
    };
    let mut detail = format!(
        "; script from ({:.3}, {:.3}) at {} m/s{to}, within {} m",
        start.re,
        start.im,
        s.script.speed(),
        s.tolerance
    );
    if let Some(cut) = &s.cut {
        detail += &format!(" ({cut})");
    }
    detail
}

/// The frame T, each slot's time, and the delay margin (eq. 29) T alone gives: the sample
/// of the frame's first LED is a frame old when the frame ends, so an obstacle or a vehicle
/// moving at its top speed for T is that far from where it was seen.
fn schedule_detail(rig: &Rig) -> String {
    let t_us = rig.sample_period.as_micros();
    let t = rig.sample_period.as_secs_f64();
    let slots = rig.schedule.slots();
    let mut detail =
        format!("{} LEDs, frame T = {:.3} ms ({:.1} Hz)", slots.len(), t_us as f64 / 1000.0, 1e6 / t_us as f64);
    if rig.vehicles.is_empty() {
        return detail;
    }
    let each: Vec<String> = slots.iter().map(|s| format!("{}: {} µs", s.led, s.slot_us)).collect();
    let dark = rig.schedule.dark_slot_us;
    let fastest = rig.vehicles.iter().map(|v| v.robot.max_speed).fold(rig.control.planner.max_speed, f64::max);
    detail += &format!(
        "; slots {}{}; delay margin U·T at T: {:.1} mm for a vehicle at {fastest} m/s, {:.1} mm for an obstacle at \
         safety.max_obstacle_speed = {} m/s",
        each.join(", "),
        if dark > 0 { format!(", dark {dark} µs") } else { String::new() },
        fastest * t * 1e3,
        rig.tracking.max_obstacle_speed * t * 1e3,
        rig.tracking.max_obstacle_speed,
    );
    detail
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
        PsdClientError::Setup(SetupError::Identity(_) | SetupError::FewerLeds { .. }) => (IDENTITY, &[ANSWERS]),
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
    // Each LED on the floor, as last seen clearly: where the robot and every vehicle stand.
    let mut at: Vec<Option<Point>> = vec![None; leds.len()];
    let before = client.tally;
    let start = Instant::now();
    let end = start + STREAM_WATCH;
    loop {
        match client.next_sample(end).await {
            Ok(Some(s)) => {
                let clear = !s.flags.contains(flowgate_protocol::psd::SampleFlags::WEAK_SIGNAL)
                    && !s.flags.contains(flowgate_protocol::psd::SampleFlags::SATURATED);
                if let Some(k) = leds.iter().position(|&l| l == s.led) {
                    if clear {
                        at[k] = rig.calibration.to_floor(f64::from(s.x), f64::from(s.y));
                    }
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
    let floor = |led: u8| leds.iter().position(|&l| l == led).and_then(|k| at[k]);
    let locate = |front: u8, rear: u8, geometry: &crate::track::LedGeometry| {
        floor(front).zip(floor(rear)).and_then(|(f, r)| geometry.locate(f, r)).map(|(at, _)| at)
    };
    let robot = locate(rig.robot_front, rig.robot_rear, &rig.led_geometry);
    check_goal(rig, robot, report);
    if !rig.vehicles.is_empty() {
        let mut bodies = vec![("robot", robot, rig.control.robot_radius)];
        let vehicles = rig.vehicles.iter();
        bodies.extend(
            vehicles.map(|v| (v.name.as_str(), locate(v.front_led, v.rear_led, &v.led_geometry), v.robot.radius)),
        );
        check_apart(&bodies, report);
    }
}

/// A fleet's vehicles (`bodies`: each one's name, where the camera puts it and its radius)
/// no two closer than their radii, which no two bodies can be: one's LEDs, their offsets or
/// its radius are wrong in the config, and every field and supervisor would plan on a body
/// where none is. The closest pair is shown.
fn check_apart(bodies: &[(&str, Option<Point>, f64)], report: &mut CheckReport) {
    let seen: Vec<(&str, Point, f64)> = bodies.iter().filter_map(|&(name, at, r)| Some((name, at?, r))).collect();
    let unseen: Vec<&str> = bodies.iter().filter(|b| b.1.is_none()).map(|b| b.0).collect();
    let (mut overlaps, mut closest) = (Vec::new(), None::<(f64, &str, &str)>);
    for (i, &(a, pa, ra)) in seen.iter().enumerate() {
        for &(b, pb, rb) in &seen[i + 1..] {
            let apart = (pa - pb).norm();
            if apart < ra + rb {
                overlaps.push(format!(
                    "{a} at ({:.3}, {:.3}) and {b} at ({:.3}, {:.3}) are {:.1} cm apart, closer than their radii ({:.1} + {:.1} cm)",
                    pa.re, pa.im, pb.re, pb.im, apart * 100.0, ra * 100.0, rb * 100.0
                ));
            }
            if closest.is_none_or(|(gap, _, _)| apart - ra - rb < gap) {
                closest = Some((apart - ra - rb, a, b));
            }
        }
    }
    let unseen = if unseen.is_empty() { String::new() } else { format!("; not seen clearly: {}", unseen.join(", ")) };
    match closest {
        _ if !overlaps.is_empty() => report.fail(
            APART,
            "vehicles",
            format!("{}: a vehicle's LEDs, their offsets or its radius are wrong{unseen}", overlaps.join("; ")),
        ),
        Some((gap, a, b)) => report.pass(
            APART,
            "vehicles",
            format!(
                "{} seen clear of each other, the closest {a} and {b}, {:.1} cm between them{unseen}",
                seen.len(),
                gap * 100.0
            ),
        ),
        None => report.skip(&[APART], "vehicles", &format!("fewer than two vehicles seen clearly{unseen}")),
    }
}

/// The robot's two LEDs and every required obstacle's must be seen to arm; any other
/// obstacle out of view is absent until it comes into view: worth a warning.
fn judge_leds(rig: &Rig, leds: &[u8], seen: &[u64], weak: &[u64], saturated: &[u64], report: &mut CheckReport) {
    let mut problems = Vec::new();
    let mut fail = false;
    for (k, &led) in leds.iter().enumerate() {
        let robot = led == rig.robot_front || led == rig.robot_rear;
        let obstacle = rig.obstacles.iter().position(|o| o.led == led);
        let vehicle = rig.vehicles.iter().find(|v| led == v.front_led || led == v.rear_led);
        let required = robot || vehicle.is_some() || obstacle.is_some_and(|i| rig.obstacles[i].required);
        let role = match (obstacle, vehicle) {
            _ if robot => " (robot)".to_string(),
            (_, Some(v)) => format!(" (vehicle {})", v.name),
            (Some(i), None) if required => format!(" (leds.obstacles[{i}].required)"),
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

#[cfg(test)]
mod tests;
