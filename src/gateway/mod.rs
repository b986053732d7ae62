//! The gateway service: PSD samples in, motor CAN frames out, under a safety state machine,
//! with every cycle timed.
//!
//! One task runs the loop. It selects over serial bytes, CAN events, a 10 ms watchdog tick,
//! arm requests and shutdown. A cycle is one time-division frame of the PSD controller:
//!
//! ```text
//! serial read -> decode (COBS/CRC) -> frame complete (FrameEnd)
//!   -> track: LEDs to floor (calibration), robot pose from its two LEDs, obstacles through
//!      constant-velocity Kalman filters; everything predicted over the measured delay
//!   -> plan: the control step (navigation function, eq. 30, pulse rates)
//!   -> CAN: one velocity frame for both axes
//! ```
//!
//! Telemetry goes to a writer task through a bounded queue (see [`telemetry`]): the loop
//! never waits on it.

pub mod safety;
pub mod telemetry;

use std::collections::VecDeque;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use bytes::BytesMut;
use flowgate_protocol::codec::{PsdCodec, StreamError};
use flowgate_protocol::motor::{BoardState, EStopReason, FaultBits, MotorMessage, NmtCommand, NodeId, Target};
use flowgate_protocol::psd::{self, FaultCode, LedSlot, Message, Packet, Schedule};
use flowgate_protocol::CanFrame;
use num_complex::Complex64 as C;
use serde::Serialize;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;
use tokio_util::codec::Decoder;

use crate::calib::Calibration;
use crate::config::{GatewayConfig, MarginSection};
use crate::control::{ControlConfig, ControlStep, Estimate, StallConfig, StepStatus};
use crate::link::{open_can, open_serial, CanError, CanEvent, CanLink, SerialError};
use crate::planner::drive::DriveConfig;
use crate::planner::{Margin, ObstacleEstimate, PlannerConfig, Space, TieBreak, MAX_OBSTACLES};
use crate::track::{ConstantVelocityKf, DeadReckoning, KalmanConfig, LedGeometry, Pose};
use safety::{Action, Safety, State, StopReason};
use telemetry::{CanRecord, CycleRecord, Record, Recorder, Timing};

/// How often the gateway sends its heartbeat, s.
const HEARTBEAT_PERIOD: f64 = 0.1;
/// How long an orderly stop may take before the gateway calls the axes at rest, s.
const STOP_GRACE: f64 = 1.0;

/// A startup failure: the gateway could not begin.
#[derive(Debug, thiserror::Error)]
pub enum GatewayError {
    #[error(transparent)]
    Serial(#[from] SerialError),
    #[error(transparent)]
    Can(#[from] CanError),
    #[error("PSD controller on {port} did not answer {request} within 1 s (powered? right port and baud?)")]
    PsdSilent { port: String, request: &'static str },
    #[error("PSD controller refused the LED schedule: {0:?}")]
    ScheduleRefused(psd::NackReason),
    #[error("telemetry output {path}: {source}")]
    Telemetry { path: String, source: std::io::Error },
}

/// What the loop is told from outside.
#[derive(Debug)]
pub struct Controls {
    /// Becomes `true` to stop (orderly) and end the run.
    pub shutdown: watch::Receiver<bool>,
    /// The operator re-arms after a stop or fault.
    pub arm: mpsc::Receiver<()>,
}

/// What the gateway shows while it runs (for a live display). Receivers are woken when the
/// state or the reconnect count changes; the per-cycle figures are updated silently, for a
/// display that samples them with `borrow()` at its own pace.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Progress {
    pub t: f64,
    pub state: &'static str,
    pub cycles: u64,
    pub goal_distance: f64,
    /// Smallest estimated gap to an obstacle's footprint, m.
    pub clearance: Option<f64>,
    pub e2e_us: f64,
    pub serial_reconnects: u64,
}

/// Counters of everything unusual the gateway saw.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Counters {
    pub cycles: u64,
    pub samples: u64,
    pub bad_serial_frames: u64,
    pub serial_dropped_bytes: u64,
    pub serial_reconnects: u64,
    pub can_frames_in: u64,
    /// Frames from node ids that are not configured (ignored).
    pub can_foreign: u64,
    /// Frames that do not decode as motor messages, and garbled adapter lines (ignored).
    pub can_undecodable: u64,
    pub can_error_frames: u64,
    pub planner_invalid: u64,
    pub telemetry_dropped: u64,
}

/// The run's report.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub final_state: String,
    pub stop_reason: Option<String>,
    pub transitions: Vec<(f64, String)>,
    pub e2e: telemetry::Distribution,
    pub period: telemetry::Distribution,
    pub deadline_misses: u64,
    /// The control period the schedule gives, s.
    pub sample_time: f64,
    pub counters: Counters,
    pub files: telemetry::WrittenFiles,
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.counters;
        writeln!(f, "final state      {} ({})", self.final_state, self.stop_reason.as_deref().unwrap_or("-"))?;
        writeln!(
            f,
            "cycles           {} at T = {:.1} ms, {} deadline misses (e2e > T)",
            c.cycles,
            self.sample_time * 1e3,
            self.deadline_misses
        )?;
        writeln!(
            f,
            "e2e latency      p50 {:.0} µs  p99 {:.0} µs  p99.9 {:.0} µs  max {:.0} µs   (serial frame read -> CAN write done)",
            self.e2e.p50_us, self.e2e.p99_us, self.e2e.p999_us, self.e2e.max_us
        )?;
        writeln!(
            f,
            "command period   p50 {:.2} ms  p99 {:.2} ms  max {:.2} ms  jitter (σ) {:.0} µs",
            self.period.p50_us / 1e3,
            self.period.p99_us / 1e3,
            self.period.max_us / 1e3,
            self.period.stdev_us
        )?;
        writeln!(
            f,
            "serial           {} samples, {} bad frames, {} bytes dropped, {} reconnects",
            c.samples, c.bad_serial_frames, c.serial_dropped_bytes, c.serial_reconnects
        )?;
        writeln!(
            f,
            "can              {} frames in, {} from other nodes, {} undecodable, {} error frames (all ignored)",
            c.can_frames_in, c.can_foreign, c.can_undecodable, c.can_error_frames
        )?;
        write!(f, "telemetry        {} records dropped (queue full)", c.telemetry_dropped)
    }
}

/// The control configuration a gateway config describes.
pub fn control_config(cfg: &GatewayConfig, sample_time: f64) -> ControlConfig {
    let reference_radius =
        cfg.robot.radius + cfg.leds.obstacles.iter().map(|o| o.radius).fold(cfg.robot.radius, f64::max);
    let p = &cfg.planner;
    ControlConfig {
        planner: PlannerConfig {
            space: cfg.lane.map_or(Space::Free, |l| Space::Lane { half_width: l.half_width }),
            cruise_speed: p.cruise_speed,
            c1: p.c1,
            reference_radius,
            max_speed: cfg.robot.max_speed,
            margin: match p.margin {
                MarginSection::None => Margin::None,
                MarginSection::Fixed { metres } => Margin::Fixed(metres),
                MarginSection::Factor { factor } => Margin::Factor(factor),
                MarginSection::Delay { extra_speed } => Margin::Delay { extra_speed },
            },
            tie_break: p.tie_break.then(TieBreak::default),
        },
        drive: DriveConfig {
            wheel_base: cfg.drive.wheel_base,
            wheel_radius: cfg.drive.wheel_radius,
            steps_per_rev: cfg.drive.steps_per_rev,
            microsteps: cfg.drive.microsteps,
            max_wheel_speed: cfg.drive.max_wheel_speed,
            steering_gain: p.kc,
            sample_time,
        },
        goal: C::new(p.goal[0], p.goal[1]),
        goal_tolerance: p.goal_tolerance,
        robot_radius: cfg.robot.radius,
        stall: StallConfig::default(),
    }
}

/// The LED schedule: robot LEDs first, then the obstacles'.
pub fn schedule(cfg: &GatewayConfig) -> Schedule {
    let mut slots = vec![cfg.leds.robot_front, cfg.leds.robot_rear];
    slots.extend(cfg.leds.obstacles.iter().map(|o| o.led));
    let slots: Vec<LedSlot> = slots.into_iter().map(|led| LedSlot { led, slot_us: cfg.schedule.slot_us }).collect();
    Schedule::new(&slots, cfg.schedule.dark_slot_us, cfg.schedule.averaging).expect("validated config")
}

fn unix_now() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

/// The PSD serial line, with its decoder and our sequence counter. The port is not split:
/// the loop never reads and writes at once, so halves (and their lock) are not needed.
struct PsdLine {
    port: tokio_serial::SerialStream,
    buf: BytesMut,
    codec: PsdCodec,
    seq: u16,
}

impl PsdLine {
    fn open(cfg: &GatewayConfig) -> Result<Self, SerialError> {
        let port = open_serial(&cfg.serial.port, cfg.serial.baud)?;
        Ok(Self { port, buf: BytesMut::with_capacity(4096), codec: PsdCodec::new(), seq: 0 })
    }

    async fn send(&mut self, message: Message) -> std::io::Result<u16> {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let n = Packet::new(seq, message)
            .encode(&mut wire)
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        self.port.write_all(&wire[..n]).await?;
        Ok(seq)
    }

    /// Send a request and wait (1 s) for its answer, skipping everything else.
    async fn ask(&mut self, message: Message, name: &'static str, port: &str) -> Result<Message, GatewayError> {
        let silent = || GatewayError::PsdSilent { port: port.to_string(), request: name };
        for _ in 0..3 {
            let seq = self.send(message).await.map_err(|_| silent())?;
            let deadline = Instant::now() + Duration::from_millis(350);
            loop {
                let item = match self.codec.decode(&mut self.buf) {
                    Ok(Some(item)) => item,
                    _ => match tokio::time::timeout_at(deadline, self.port.read_buf(&mut self.buf)).await {
                        Ok(Ok(n)) if n > 0 => continue,
                        Ok(_) => return Err(silent()),
                        Err(_) => break, // resend
                    },
                };
                if let Ok(p) = item {
                    match p.message {
                        Message::Ack { seq: s, .. } | Message::Nack { seq: s, .. } if s == seq => return Ok(p.message),
                        Message::Info(_) | Message::TimeSyncReply { .. } => return Ok(p.message),
                        _ => {}
                    }
                }
            }
        }
        Err(silent())
    }
}

/// Configure the controller: info, schedule, time sync, start. Returns the offset that maps
/// the controller clock to ours (µs to add to a controller stamp).
async fn configure_psd(line: &mut PsdLine, cfg: &GatewayConfig, origin: Instant) -> Result<f64, GatewayError> {
    let port = cfg.serial.port.display().to_string();
    let _ = line.send(Message::StopStream).await;
    let Message::Info(info) = line.ask(Message::GetInfo, "GetInfo", &port).await? else {
        return Err(GatewayError::PsdSilent { port, request: "GetInfo" });
    };
    tracing::info!(firmware = ?info.firmware, max_leds = info.max_leds, "PSD controller");
    if let Message::Nack { reason, .. } = line.ask(Message::SetSchedule(schedule(cfg)), "SetSchedule", &port).await? {
        return Err(GatewayError::ScheduleRefused(reason));
    }
    let sent = origin.elapsed().as_secs_f64() * 1e6;
    let reply = line.ask(Message::TimeSync { host_time_us: sent as u64 }, "TimeSync", &port).await?;
    let received = origin.elapsed().as_secs_f64() * 1e6;
    let offset = match reply {
        Message::TimeSyncReply { t_ctrl_us, .. } => 0.5 * (sent + received) - t_ctrl_us as f64,
        _ => 0.0,
    };
    if let Message::Nack { reason, .. } = line.ask(Message::StartStream, "StartStream", &port).await? {
        return Err(GatewayError::ScheduleRefused(reason));
    }
    Ok(offset)
}

/// What the gateway knows of the motor board.
#[derive(Debug, Default)]
struct Board {
    last_heartbeat: Option<f64>,
    state: Option<BoardState>,
    faults: FaultBits,
    rates: [i32; 2],
}

/// One time-division frame being collected.
#[derive(Debug)]
struct FrameSamples {
    /// Per LED id: raw position, controller stamp, usable.
    leds: [Option<(i32, i32, u64, bool)>; 256],
}

impl Default for FrameSamples {
    fn default() -> Self {
        Self { leds: [None; 256] }
    }
}

impl FrameSamples {
    /// Forget the scheduled LEDs' samples for the next frame. Only scheduled LEDs are read,
    /// so only they are cleared (a handful of slots, not all 256, on every cycle).
    fn clear(&mut self, schedule: &Schedule) {
        for slot in schedule.slots() {
            self.leds[usize::from(slot.led)] = None;
        }
    }
}

/// Run the gateway until shutdown. Startup failures are returned; everything after is
/// handled by the safety state machine and reported.
pub async fn run(
    cfg: GatewayConfig,
    mut controls: Controls,
    progress: Option<watch::Sender<Progress>>,
) -> Result<Report, GatewayError> {
    let origin = Instant::now();
    let now = || origin.elapsed().as_secs_f64();
    let node = NodeId::new(cfg.can.node).expect("validated");
    let calibration: Calibration = cfg.calibration();
    let leds = LedGeometry { front: cfg.leds.front_offset, rear: cfg.leds.rear_offset };
    let sched = schedule(&cfg);
    let sample_time = f64::from(sched.frame_period_us()) * 1e-6;
    let control_cfg = control_config(&cfg, sample_time);
    let mut control = ControlStep::new(control_cfg);
    let goal = control_cfg.goal;

    let mut can: CanLink = open_can(&cfg.can_url()).await?;
    let mut line = Some(PsdLine::open(&cfg)?);
    let (recorder, writer) = match &cfg.telemetry.out_dir {
        Some(dir) => {
            let iface = match cfg.can_url() {
                crate::link::CanUrl::SocketCan { interface } => interface,
                _ => "slcan0".to_string(),
            };
            let (r, w) = telemetry::start_writer(dir, cfg.telemetry.queue, iface)
                .map_err(|source| GatewayError::Telemetry { path: dir.display().to_string(), source })?;
            (r, Some(w))
        }
        None => (Recorder::disabled(), None),
    };
    let mut clock_offset_us = configure_psd(line.as_mut().expect("just opened"), &cfg, origin).await?;

    let mut safety = Safety::default();
    let mut board = Board::default();
    let mut counters = Counters::default();
    let mut timing = Timing::default();
    let mut frame = FrameSamples::default();
    let mut filters: Vec<Option<ConstantVelocityKf>> = vec![None; cfg.leds.obstacles.len()];
    let mut dead_reckoning = DeadReckoning::default();
    let mut last_pose: Option<(f64, Pose)> = None;
    let mut last_sample = now();
    let mut bad_frames: VecDeque<f64> = VecDeque::new();
    let mut velocity_seq: u8 = 0;
    let mut last_command: Option<f64> = None;
    let mut next_heartbeat = 0.0;
    let mut stopping_since: Option<f64> = None;
    let mut next_reconnect = 0.0;
    let mut decode_ns_pending: u64 = 0;
    let mut tick = tokio::time::interval(Duration::from_millis(10));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut estimates = [ObstacleEstimate { center: C::default(), velocity: C::default(), radius: 0.0 }; MAX_OBSTACLES];
    let n_obstacles = cfg.leds.obstacles.len().min(MAX_OBSTACLES);
    let mut read_buf = [0u8; 1024];

    // Sends a frame and logs it; CAN write errors count as a bus problem.
    macro_rules! send_can {
        ($msg:expr) => {{
            let frame: CanFrame = ($msg).to_frame().expect("gateway messages are in range");
            let result = can.send(frame).await;
            recorder.record(Record::Can(CanRecord { unix_s: unix_now(), frame, sent: true }));
            result
        }};
    }

    // Starting the run is the operator's arm.
    let mut pending_action = safety.arm(now());

    loop {
        // Act on what the state machine asked for.
        match std::mem::replace(&mut pending_action, Action::None) {
            Action::None => {}
            Action::EnableBoard => {
                let accel = (cfg.drive.wheel_accel * control_cfg.drive.pulses_per_metre()).round() as u32;
                let max_rate = (cfg.drive.max_wheel_speed * control_cfg.drive.pulses_per_metre()).round() as u32;
                let _ = send_can!(MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::FaultReset });
                let _ = send_can!(MotorMessage::Config {
                    node,
                    accel: accel.min(flowgate_protocol::motor::MAX_U24),
                    max_rate: max_rate.min(flowgate_protocol::motor::MAX_U24),
                    timeout_ms: cfg.drive.command_timeout_ms
                });
                let _ = send_can!(MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::Enable });
                last_command = Some(now());
            }
            Action::OrderlyStop => stopping_since = Some(now()),
            Action::EmergencyStop => {
                let _ =
                    send_can!(MotorMessage::EStop { target: Target::Node(node), reason: EStopReason::GatewayFault });
                tracing::warn!("emergency stop: {:?}", safety.state());
            }
        }
        if let Some(tx) = &progress {
            let state = state_name(safety.state());
            tx.send_if_modified(|p| std::mem::replace(&mut p.state, state) != state);
        }

        let shutdown_requested = *controls.shutdown.borrow();
        if shutdown_requested {
            match safety.state() {
                State::Stopped(_) | State::Fault(_) | State::Idle => break,
                State::Stopping(_) => {}
                _ => pending_action = safety.stop(now(), StopReason::Shutdown),
            }
        }

        tokio::select! {
            // Serial bytes.
            read = async {
                match line.as_mut() {
                    Some(l) => l.port.read(&mut read_buf).await,
                    None => std::future::pending().await,
                }
            } => {
                let t_read = now();
                match read {
                    Ok(0) | Err(_) => {
                        line = None;
                        next_reconnect = t_read + 0.2;
                        pending_action = safety.stop(t_read, StopReason::SerialLost);
                        tracing::error!("serial line lost; reconnecting");
                        continue;
                    }
                    Ok(n) => {
                        let l = line.as_mut().expect("read from it");
                        l.buf.extend_from_slice(&read_buf[..n]);
                        loop {
                            let started = Instant::now();
                            let item = l.codec.decode(&mut l.buf);
                            decode_ns_pending += started.elapsed().as_nanos() as u64;
                            let item = match item {
                                Ok(Some(item)) => item,
                                _ => break,
                            };
                            match item {
                                Err(e) => {
                                    counters.bad_serial_frames += 1;
                                    bad_frames.push_back(t_read);
                                    tracing::debug!("bad serial frame: {e}");
                                    if let StreamError::Overlong { dropped } = e {
                                        counters.serial_dropped_bytes += dropped as u64;
                                    }
                                }
                                Ok(Packet { message: Message::Sample(s), .. }) => {
                                    counters.samples += 1;
                                    last_sample = t_read;
                                    frame.leds[usize::from(s.led)] = Some((s.x, s.y, s.t_ctrl_us, s.flags.is_usable()));
                                }
                                Ok(Packet { message: Message::Fault { code: FaultCode::Reset, .. }, .. }) => {
                                    // The controller rebooted: its schedule is gone. Reconfigure;
                                    // any motion was already stopped by the sample watchdog.
                                    tracing::warn!("PSD controller reset; reconfiguring");
                                    let _ = l.send(Message::SetSchedule(sched)).await;
                                    let _ = l.send(Message::TimeSync { host_time_us: (now() * 1e6) as u64 }).await;
                                    let _ = l.send(Message::StartStream).await;
                                }
                                Ok(Packet { message: Message::TimeSyncReply { host_time_us, t_ctrl_us }, .. }) => {
                                    clock_offset_us = 0.5 * (host_time_us as f64 + now() * 1e6) - t_ctrl_us as f64;
                                }
                                Ok(Packet { message: Message::FrameEnd { frame: frame_no, t_ctrl_us, .. }, .. }) => {
                                    // One cycle, with a tracing span carrying its stage timings.
                                    let decode_ns = std::mem::take(&mut decode_ns_pending);
                                    let span = tracing::debug_span!(
                                        "cycle",
                                        n = counters.cycles,
                                        frame = frame_no,
                                        decode_ns,
                                        track_ns = tracing::field::Empty,
                                        plan_ns = tracing::field::Empty,
                                        can_write_ns = tracing::field::Empty,
                                        e2e_ns = tracing::field::Empty,
                                    );
                                    let track_start = Instant::now();
                                    let host_s = |t_ctrl: u64| (t_ctrl as f64 + clock_offset_us) * 1e-6;
                                    let usable = |led: u8| frame.leds[usize::from(led)].filter(|s| s.3);
                                    let to_floor = |s: (i32, i32, u64, bool)| calibration.to_floor(f64::from(s.0), f64::from(s.1));
                                    if let (Some(f), Some(r)) = (usable(cfg.leds.robot_front), usable(cfg.leds.robot_rear)) {
                                        if let (Some(fp), Some(rp)) = (to_floor(f), to_floor(r)) {
                                            if let Some(pose) = leds.pose(fp, rp) {
                                                last_pose = Some((host_s((f.2 + r.2) / 2), pose));
                                            }
                                        }
                                    }
                                    for (k, o) in cfg.leds.obstacles.iter().enumerate().take(n_obstacles) {
                                        if let Some(s) = usable(o.led) {
                                            if let Some(p) = to_floor(s) {
                                                let t_valid = host_s(s.2);
                                                match &mut filters[k] {
                                                    Some(kf) => { kf.update(t_valid, p); }
                                                    None => filters[k] = Some(ConstantVelocityKf::new(KalmanConfig::default(), t_valid, p)),
                                                }
                                            }
                                        }
                                    }
                                    frame.clear(&sched);
                                    let t = now();
                                    let mut plan_ns = 0;
                                    let mut pulses = [0i32; 2];
                                    let mut clearance: Option<f64> = None;
                                    let fresh_pose = last_pose.filter(|(tv, _)| t - tv < f64::from(cfg.safety.pose_timeout_ms) * 1e-3);
                                    if let Some((t_valid, measured)) = fresh_pose {
                                        dead_reckoning.forget_before(t_valid - sample_time);
                                        let pose = dead_reckoning.predict(measured, t_valid, t, cfg.drive.wheel_base);
                                        let position = pose.position;
                                        // The measured sensing-to-actuation delay: from the samples'
                                        // time of validity to now, plus the period the command holds.
                                        let delay = t - t_valid + sample_time;
                                        let mut n = 0;
                                        for (k, kf) in filters.iter().enumerate() {
                                            if let Some(kf) = kf {
                                                let (center, velocity) = kf.predict(t);
                                                estimates[n] = ObstacleEstimate { center, velocity, radius: cfg.leds.obstacles[k].radius };
                                                let gap = (center - position).norm() - cfg.leds.obstacles[k].radius - cfg.robot.radius;
                                                clearance = Some(clearance.map_or(gap, |c: f64| c.min(gap)));
                                                n += 1;
                                            }
                                        }
                                        let track_ns = track_start.elapsed().as_nanos() as u64;
                                        if safety.state() == State::Armed && board.state == Some(BoardState::Enabled) {
                                            safety.ready(t);
                                        }
                                        if safety.state().may_move() {
                                            let plan_start = Instant::now();
                                            let out = control.step(t, &Estimate { pose, obstacles: &estimates[..n], delay });
                                            plan_ns = plan_start.elapsed().as_nanos() as u64;
                                            match out.status {
                                                StepStatus::Driving => {
                                                    pulses = out.pulses;
                                                    dead_reckoning.command(t, out.wheels.left, out.wheels.right);
                                                }
                                                StepStatus::AtGoal => pending_action = safety.stop(t, StopReason::GoalReached),
                                                StepStatus::Stalled => pending_action = safety.stop(t, StopReason::Stalled),
                                                StepStatus::Invalid(e) => {
                                                    counters.planner_invalid += 1;
                                                    tracing::error!("planner: {e}");
                                                    pending_action = safety.stop(t, StopReason::PlannerInvalid);
                                                }
                                            }
                                        }
                                        // Commands go out in Running (motion), Armed and Stopping (zero,
                                        // keeping the enabled board's command timeout fed).
                                        let can_start = Instant::now();
                                        let send = matches!(safety.state(), State::Running | State::Armed | State::Stopping(_));
                                        if send {
                                            if !safety.state().may_move() {
                                                pulses = [0, 0];
                                                dead_reckoning.command(t, 0.0, 0.0);
                                            }
                                            if let Err(e) = send_can!(MotorMessage::Velocity { node, left: pulses[0], right: pulses[1], seq: velocity_seq }) {
                                                tracing::error!("CAN write: {e}");
                                                pending_action = safety.stop(t, StopReason::BusOff);
                                            }
                                            velocity_seq = velocity_seq.wrapping_add(1);
                                        }
                                        let can_write_ns = can_start.elapsed().as_nanos() as u64;
                                        if send {
                                            let done = now();
                                            let rec = CycleRecord {
                                                cycle: counters.cycles,
                                                frame: frame_no,
                                                t_ctrl_us,
                                                rx_ns: (t_read * 1e9) as u64,
                                                decode_ns,
                                                track_ns,
                                                plan_ns,
                                                can_write_ns,
                                                can_done_ns: (done * 1e9) as u64,
                                                e2e_ns: ((done - t_read) * 1e9) as u64,
                                                period_ns: last_command.map_or(0, |lc| ((done - lc) * 1e9) as u64),
                                                deadline_miss: done - t_read > sample_time,
                                                delay_s: delay,
                                                state: state_name(safety.state()),
                                                pulses,
                                                x: position.re,
                                                y: position.im,
                                                goal_distance: (goal - position).norm(),
                                            };
                                            span.record("track_ns", track_ns);
                                            span.record("plan_ns", plan_ns);
                                            span.record("can_write_ns", can_write_ns);
                                            span.record("e2e_ns", rec.e2e_ns);
                                            last_command = Some(done);
                                            counters.cycles += 1;
                                            timing.add(&rec);
                                            recorder.record(Record::Cycle(rec));
                                            if let Some(tx) = &progress {
                                                tx.send_if_modified(|p| {
                                                    p.t = done;
                                                    p.cycles = counters.cycles;
                                                    p.goal_distance = rec.goal_distance;
                                                    p.clearance = clearance;
                                                    p.e2e_us = rec.e2e_ns as f64 / 1e3;
                                                    false // no wake-up per cycle
                                                });
                                            }
                                        }
                                    }
                                }
                                Ok(_) => {} // acks, heartbeats, pongs
                            }
                        }
                    }
                }
            }
            // CAN.
            event = can.recv() => {
                match event {
                    Ok(CanEvent::Frame(f)) => {
                        counters.can_frames_in += 1;
                        recorder.record(Record::Can(CanRecord { unix_s: unix_now(), frame: f, sent: false }));
                        match MotorMessage::parse(&f) {
                            Ok(m) if m.node() == Some(node) => {
                                let t = now();
                                match m {
                                    MotorMessage::Heartbeat { state, .. } => {
                                        board.last_heartbeat = Some(t);
                                        board.state = Some(state);
                                    }
                                    MotorMessage::Status { state, faults, .. } => {
                                        board.state = Some(state);
                                        board.faults = faults;
                                    }
                                    MotorMessage::AxisRates { left, right, .. } => board.rates = [left, right],
                                    _ => {}
                                }
                            }
                            Ok(MotorMessage::GatewayHeartbeat { .. }) => {}
                            Ok(m) if m.node().is_some() => counters.can_foreign += 1,
                            Ok(_) => {}
                            Err(_) => counters.can_undecodable += 1,
                        }
                    }
                    Ok(CanEvent::Garbled) => counters.can_undecodable += 1,
                    Ok(CanEvent::ErrorFrame { bus_off }) => {
                        counters.can_error_frames += 1;
                        if bus_off {
                            pending_action = safety.stop(now(), StopReason::BusOff);
                        }
                    }
                    Err(e) => {
                        tracing::error!("CAN: {e}");
                        pending_action = safety.stop(now(), StopReason::BusOff);
                        tokio::time::sleep(Duration::from_millis(50)).await;
                    }
                }
            }
            // Watchdogs.
            _ = tick.tick() => {
                let t = now();
                if t >= next_heartbeat {
                    let _ = send_can!(MotorMessage::GatewayHeartbeat { state: safety.state().wire() });
                    next_heartbeat = t + HEARTBEAT_PERIOD;
                }
                while bad_frames.front().is_some_and(|&b| t - b > 1.0) {
                    bad_frames.pop_front();
                }
                let active = matches!(safety.state(), State::Armed | State::Running | State::Stopping(_));
                let reason = if !active {
                    None
                } else if bad_frames.len() as u32 > cfg.safety.bad_frames_per_s {
                    Some(StopReason::SerialGarbled)
                } else if t - last_sample > f64::from(cfg.safety.sample_timeout_ms) * 1e-3 {
                    Some(StopReason::SamplesStopped)
                } else if safety.state() == State::Running
                    && last_pose.is_none_or(|(tv, _)| t - tv > f64::from(cfg.safety.pose_timeout_ms) * 1e-3)
                {
                    Some(StopReason::PoseLost)
                } else if board.last_heartbeat.is_none_or(|h| t - h > f64::from(cfg.safety.heartbeat_timeout_ms) * 1e-3) && t > 0.5 {
                    Some(StopReason::HeartbeatLost)
                } else if board.faults.contains(FaultBits::BUS) {
                    Some(StopReason::BusOff)
                } else if safety.state() == State::Running && matches!(board.state, Some(BoardState::Fault | BoardState::EStop)) {
                    Some(StopReason::BoardFault)
                } else {
                    None
                };
                if let Some(r) = reason {
                    pending_action = safety.stop(t, r);
                }
                if let (State::Stopping(_), Some(since)) = (safety.state(), stopping_since) {
                    if board.rates == [0, 0] || t - since > STOP_GRACE {
                        safety.at_rest(t);
                        let _ = send_can!(MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::Disable });
                        stopping_since = None;
                    }
                }
                if line.is_none() && t >= next_reconnect {
                    next_reconnect = t + 0.2;
                    if let Ok(mut l) = PsdLine::open(&cfg) {
                        match configure_psd(&mut l, &cfg, origin).await {
                            Ok(offset) => {
                                clock_offset_us = offset;
                                line = Some(l);
                                last_sample = now();
                                counters.serial_reconnects += 1;
                                tracing::info!("serial line back; waiting to be re-armed");
                                if let Some(tx) = &progress {
                                    tx.send_modify(|p| p.serial_reconnects = counters.serial_reconnects);
                                }
                            }
                            Err(e) => tracing::warn!("serial reconnect: {e}"),
                        }
                    }
                }
            }
            Some(()) = controls.arm.recv() => {
                pending_action = safety.arm(now());
                last_sample = now();
            }
            _ = controls.shutdown.changed() => {}
        }
    }

    counters.telemetry_dropped = recorder.dropped();
    drop(recorder);
    let files = match writer {
        Some(w) => w.await.ok().and_then(Result::ok).unwrap_or_default(),
        None => telemetry::WrittenFiles::default(),
    };
    let state = safety.state();
    Ok(Report {
        final_state: state_name(state).to_string(),
        stop_reason: match state {
            State::Stopping(r) | State::Stopped(r) | State::Fault(r) => Some(r.to_string()),
            _ => None,
        },
        transitions: safety.history.iter().map(|(t, s)| (*t, format!("{s:?}"))).collect(),
        e2e: timing.e2e(),
        period: timing.period(),
        deadline_misses: timing.deadline_misses,
        sample_time,
        counters,
        files,
    })
}

fn state_name(s: State) -> &'static str {
    match s {
        State::Idle => "idle",
        State::Armed => "armed",
        State::Running => "running",
        State::Stopping(_) => "stopping",
        State::Stopped(_) => "stopped",
        State::Fault(_) => "fault",
    }
}
