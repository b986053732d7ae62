//! The PSD camera controller's firmware, as a state machine: requests in, replies and
//! samples out, time an argument.
//!
//! It fires the scheduled LEDs one slot at a time. Each slot's sample is stamped with the
//! controller's clock at the middle of the slot and sent at the slot's end (plus any
//! injected delay); a `FrameEnd` follows the last slot, and a dark slot (all LEDs off) ends
//! the frame when configured. Heartbeats go out every 100 ms whatever the state.

use flowgate_protocol::psd::{
    self, ControllerState, FaultCode, Info, Message, MessageType, NackReason, Packet, Sample, SampleFlags, Schedule,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::camera::CameraModel;
use crate::faults::FaultPlan;
use crate::Point;
use flowgate_protocol::codec::{PsdCodec, StreamError};

/// Heartbeat period, s.
pub const HEARTBEAT_PERIOD: f64 = 0.1;
/// The simulated firmware's identity.
pub const FIRMWARE: [u8; 3] = [1, 0, 0];
/// The LEDs the simulated controller drives (`Info::max_leds`), ids 1 to this.
pub const MAX_LEDS: u8 = crate::scenario::CONTROLLER_LEDS;
/// Nominal spot intensity and ambient level, counts.
const INTENSITY: f64 = 3000.0;
const AMBIENT: f64 = 180.0;
const WEAK_INTENSITY: u16 = 40;

/// Where each LED id is in the world.
///
/// The robot carries `robot_front` and `robot_rear`, obstacle k `first_obstacle + k`, and
/// the fleet's other vehicles follow the obstacles, two LEDs each, front then rear
/// ([`LedMap::vehicle_leds`]): the order in which a scenario's rig lists them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LedMap {
    pub robot_front: u8,
    pub robot_rear: u8,
    /// Obstacle k carries LED `first_obstacle + k`.
    pub first_obstacle: u8,
    /// Robot LEDs' distance ahead of / behind its centre, m.
    pub robot_led_offset: f64,
    /// The LEDs the controller drives (`Info::max_leds`), ids 1 to this: [`MAX_LEDS`], or
    /// up to the protocol's 64 for a larger controller ([`LedMap::driving`]).
    pub driven: u8,
}

/// What the camera looks at: the vehicles (0: the robot), the obstacles, and a calibration
/// wand someone holds up. The robot's world alone is one; a fleet is another.
pub trait Scene {
    /// The wand's LED and where it is (`None`: out of sight), if one is held.
    fn wand(&self) -> Option<(u8, Option<Point>)>;
    /// Vehicle `k`'s pose and radius, if there is such a vehicle.
    fn vehicle(&self, k: usize) -> Option<(crate::world::Pose, f64)>;
    fn obstacle_count(&self) -> usize;
    fn obstacle_position(&self, k: usize, t: f64) -> Point;
}

impl Scene for crate::world::World {
    fn wand(&self) -> Option<(u8, Option<Point>)> {
        self.wand()
    }
    fn vehicle(&self, k: usize) -> Option<(crate::world::Pose, f64)> {
        (k == 0).then(|| (self.pose(), self.robot_radius()))
    }
    fn obstacle_count(&self) -> usize {
        self.obstacle_count()
    }
    fn obstacle_position(&self, k: usize, t: f64) -> Point {
        self.obstacle_position(k, t)
    }
}

/// A fleet's obstacles and wand are the robot's world's (every world has the same obstacles).
impl Scene for crate::world::fleet::Fleet {
    fn wand(&self) -> Option<(u8, Option<Point>)> {
        self.world(0).wand()
    }
    fn vehicle(&self, k: usize) -> Option<(crate::world::Pose, f64)> {
        (k < self.len()).then(|| (self.world(k).pose(), self.world(k).robot_radius()))
    }
    fn obstacle_count(&self) -> usize {
        self.world(0).obstacle_count()
    }
    fn obstacle_position(&self, k: usize, t: f64) -> Point {
        self.world(0).obstacle_position(k, t)
    }
}

impl LedMap {
    /// The default rig: robot front LED 1, rear LED 2, obstacles from LED 3.
    pub fn standard(robot_radius: f64) -> Self {
        Self {
            robot_front: 1,
            robot_rear: 2,
            first_obstacle: 3,
            robot_led_offset: 0.5 * robot_radius,
            driven: MAX_LEDS,
        }
    }

    /// The same map on a controller that drives `leds` LEDs.
    pub fn driving(self, leds: u8) -> Self {
        Self { driven: leds, ..self }
    }

    /// Vehicle `k`'s LEDs (front, rear; `k` from 1) among `obstacles` obstacles, and the
    /// distance of each from its centre for a vehicle of `radius`, as the robot's are placed.
    /// `None` past the 255 LED ids.
    pub fn vehicle_leds(&self, obstacles: usize, k: usize, radius: f64) -> Option<(u8, u8, f64)> {
        let front = usize::from(self.first_obstacle) + obstacles + 2 * k.checked_sub(1)?;
        let front = u8::try_from(front).ok()?;
        Some((front, front.checked_add(1)?, 0.5 * radius))
    }

    /// Where LED `led` is at time `t`, if it exists. A calibration wand takes precedence:
    /// the person holding it has taken that LED in hand.
    pub fn position(&self, led: u8, scene: &(impl Scene + ?Sized), t: f64) -> Option<Point> {
        if let Some((_, at)) = scene.wand().filter(|(wand, _)| *wand == led) {
            return at;
        }
        let lit = |(pose, _): (crate::world::Pose, f64), offset: f64| {
            pose.position + Point::from_polar(1.0, pose.heading) * offset
        };
        if led == self.robot_front {
            return scene.vehicle(0).map(|v| lit(v, self.robot_led_offset));
        }
        if led == self.robot_rear {
            return scene.vehicle(0).map(|v| lit(v, -self.robot_led_offset));
        }
        let k = usize::from(led.checked_sub(self.first_obstacle)?);
        let obstacles = scene.obstacle_count();
        if k < obstacles {
            return Some(scene.obstacle_position(k, t));
        }
        let vehicle = scene.vehicle(1 + (k - obstacles) / 2)?;
        let offset = 0.5 * vehicle.1;
        Some(lit(vehicle, if (k - obstacles).is_multiple_of(2) { offset } else { -offset }))
    }
}

/// A frame from the host that did not decode: why, and its header if it could be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BadRequest {
    pub error: psd::Error,
    pub header: Option<psd::Header>,
}

impl BadRequest {
    /// From the codec's error, with the header the codec could read of that frame.
    pub fn from_stream(e: StreamError<psd::Error>, codec: &PsdCodec) -> Self {
        match e {
            StreamError::Frame { error, .. } => Self { error, header: codec.rejected_header() },
            StreamError::Overlong { .. } => Self { error: psd::Error::TooLong, header: None },
        }
    }
}

/// One message the controller wants sent, and the earliest time it may go.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outgoing {
    pub at: f64,
    pub packet: Packet,
}

/// The controller's serial output in wire order. The sample stream (samples, frame ends)
/// keeps its order whatever delay each sample was given; replies, heartbeats and faults go
/// out at their own time, between stream packets still held back by a sensing delay (the
/// delay is in the controller's pipeline, not on the line).
///
/// Packets are numbered as they go on the wire, as a controller's transmit queue does; the
/// numbering restarts with the boot message, as the controller's does.
#[derive(Debug, Default)]
pub struct SerialQueue {
    pending: std::collections::VecDeque<Outgoing>,
    stream_at: f64,
    seq: u16,
}

impl SerialQueue {
    pub fn push(&mut self, o: Outgoing) {
        if matches!(o.packet.message, Message::Fault { code: FaultCode::Reset, .. }) {
            // A reboot loses the samples still in the pipeline (stamped on the old clock).
            self.pending.retain(|p| !matches!(p.packet.message, Message::Sample(_) | Message::FrameEnd { .. }));
            self.stream_at = o.at;
        }
        let at = match o.packet.message {
            Message::Sample(_) | Message::FrameEnd { .. } => {
                self.stream_at = self.stream_at.max(o.at);
                self.stream_at
            }
            _ => o.at,
        };
        let pos = self.pending.partition_point(|p| p.at <= at);
        self.pending.insert(pos, Outgoing { at, packet: o.packet });
    }

    /// The next packet due by `t`.
    pub fn pop_due(&mut self, t: f64) -> Option<Packet> {
        if !self.pending.front().is_some_and(|o| o.at <= t) {
            return None;
        }
        let mut packet = self.pending.pop_front()?.packet;
        if matches!(packet.message, Message::Fault { code: FaultCode::Reset, .. }) {
            self.seq = packet.seq;
        }
        packet.seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        Some(packet)
    }

    /// When the next packet is due (infinity: none queued).
    pub fn next_at(&self) -> f64 {
        self.pending.front().map_or(f64::INFINITY, |o| o.at)
    }

    /// The line is gone: what was queued is lost.
    pub fn clear(&mut self) {
        self.pending.clear();
    }
}

/// The controller.
#[derive(Debug)]
pub struct PsdController {
    camera: CameraModel,
    leds: LedMap,
    noise: Option<Normal<f64>>,
    rng: ChaCha8Rng,
    faults: FaultPlan,
    /// Controller clock at sim time 0, µs (a controller that booted earlier).
    clock_origin_us: f64,
    seq: u16,
    schedule: Option<Schedule>,
    streaming: bool,
    frame: u32,
    /// The slot to fire next and when it starts.
    slot: usize,
    slot_start: f64,
    samples_in_frame: u8,
    next_heartbeat: f64,
    reset_done: bool,
    fault_done: bool,
    /// The one-off faults: the frame whose counter jumps; the odd sync reply sent.
    jumped_frame: Option<u32>,
    sync_step_done: bool,
}

impl PsdController {
    /// A controller with `noise_counts` of Gaussian position noise, seeded.
    pub fn new(camera: CameraModel, leds: LedMap, noise_counts: f64, seed: u64, faults: FaultPlan) -> Self {
        Self {
            camera,
            leds,
            noise: (noise_counts > 0.0).then(|| Normal::new(0.0, noise_counts).expect("finite noise")),
            rng: ChaCha8Rng::seed_from_u64(seed),
            faults,
            clock_origin_us: 1_000_000.0,
            seq: 0,
            schedule: None,
            streaming: false,
            frame: 0,
            slot: 0,
            slot_start: 0.0,
            samples_in_frame: 0,
            next_heartbeat: 0.0,
            reset_done: false,
            fault_done: false,
            jumped_frame: None,
            sync_step_done: false,
        }
    }

    pub fn info(&self) -> Info {
        Info {
            firmware: FIRMWARE,
            psd_counts: [self.camera.counts; 2],
            max_leds: self.leds.driven,
            clock_hz: 1_000_000,
        }
    }

    /// The controller clock at sim time `t`, µs.
    pub fn clock_us(&self, t: f64) -> u64 {
        let rate = 1.0 + self.faults.clock_drift_ppm * 1e-6;
        (self.clock_origin_us + t * 1e6 * rate + self.faults.clock_step_us(t)).round().max(0.0) as u64
    }

    pub fn streaming(&self) -> bool {
        self.streaming
    }

    fn packet(&mut self, message: Message) -> Packet {
        let p = Packet::new(self.seq, message);
        self.seq = self.seq.wrapping_add(1);
        p
    }

    /// The boot message (a controller announces every start).
    pub fn boot(&mut self, t: f64, out: &mut Vec<Outgoing>) {
        let p = self.packet(Message::Fault { code: FaultCode::Reset, detail: 0 });
        out.push(Outgoing { at: t, packet: p });
    }

    /// Handle one frame from the host: a packet, or why it did not decode.
    pub fn handle(&mut self, t: f64, request: Result<Packet, BadRequest>, out: &mut Vec<Outgoing>) {
        let reply = match request {
            // The Nack names the request by the seq and type in its header whenever the
            // header could be read (a bad CRC, version, type, length or value); seq 0 and
            // type 0 only when it could not (COBS garbage, fewer than 4 bytes).
            Err(BadRequest { error, header }) => {
                let (seq, msg_type) = header.map_or((0, 0), |h| (h.seq, h.msg_type));
                Message::Nack { seq, msg_type, reason: error.nack_reason() }
            }
            Ok(Packet { seq, message }) => {
                let msg_type = message.msg_type() as u8;
                let ack = Message::Ack { seq, msg_type };
                let nack = |reason| Message::Nack { seq, msg_type, reason };
                match message {
                    Message::GetInfo => Message::Info { request_seq: seq, info: self.info() },
                    Message::SetSchedule(_) if self.streaming => nack(NackReason::Busy),
                    Message::SetSchedule(s) if s.slots().len() > usize::from(self.leds.driven) => {
                        nack(NackReason::TooManyLeds)
                    }
                    // An LED id this controller has no driver for.
                    Message::SetSchedule(s) if s.slots().iter().any(|l| l.led > self.leds.driven) => {
                        nack(NackReason::BadValue)
                    }
                    Message::SetSchedule(s) => {
                        self.schedule = Some(s);
                        ack
                    }
                    Message::StartStream => match self.schedule {
                        None => nack(NackReason::NotConfigured),
                        Some(_) => {
                            if !self.streaming {
                                self.streaming = true;
                                self.slot = 0;
                                self.slot_start = t;
                                self.samples_in_frame = 0;
                            }
                            ack
                        }
                    },
                    Message::StopStream => {
                        self.streaming = false;
                        ack
                    }
                    Message::Ping { nonce } => Message::Pong { request_seq: seq, nonce, t_ctrl_us: self.clock_us(t) },
                    Message::TimeSync { host_time_us } => {
                        let mut t_ctrl_us = self.clock_us(t);
                        if let (Some([at, ms]), false) = (self.faults.sync_reply_step, self.sync_step_done) {
                            if t >= at {
                                self.sync_step_done = true;
                                t_ctrl_us = (t_ctrl_us as f64 + ms * 1e3).max(0.0) as u64;
                            }
                        }
                        Message::TimeSyncReply { request_seq: seq, host_time_us, t_ctrl_us }
                    }
                    m if !m.msg_type().is_request() => nack(NackReason::WrongDirection),
                    _ => nack(NackReason::UnknownType),
                }
            }
        };
        // A reply held back by the controller (a busy firmware): it carries the stamp of when
        // the request came, so the host's round trip grows by the hold.
        let held = match (reply, self.faults.sync_reply_hold) {
            (Message::TimeSyncReply { .. }, Some([from, to, ms])) if t >= from && t < to => ms * 1e-3,
            _ => 0.0,
        };
        let p = self.packet(reply);
        out.push(Outgoing { at: t + held, packet: p });
    }

    /// When [`PsdController::poll`] next has something to do.
    pub fn next_event(&self) -> f64 {
        let mut next = self.next_heartbeat;
        if let (true, Some(s)) = (self.streaming, &self.schedule) {
            next = next.min(self.slot_start + self.slot_len(s));
        }
        if let (Some(at), false) = (self.faults.controller_reset_at, self.reset_done) {
            next = next.min(at);
        }
        if let (Some([at, ..]), false) = (self.faults.controller_fault, self.fault_done) {
            next = next.min(at);
        }
        next
    }

    fn slot_len(&self, s: &Schedule) -> f64 {
        match s.slots().get(self.slot) {
            Some(slot) => f64::from(slot.slot_us) * 1e-6,
            None => f64::from(s.dark_slot_us) * 1e-6,
        }
    }

    /// Everything due by time `t`: samples of finished slots, frame ends, heartbeats, faults.
    pub fn poll(&mut self, t: f64, scene: &(impl Scene + ?Sized), out: &mut Vec<Outgoing>) {
        if let (Some([at, code, detail]), false) = (self.faults.controller_fault, self.fault_done) {
            if t >= at {
                self.fault_done = true;
                if let Some(code) = FaultCode::from_u8(code as u8) {
                    let p = self.packet(Message::Fault { code, detail: detail as u32 });
                    out.push(Outgoing { at, packet: p });
                }
            }
        }
        if let (Some(at), false) = (self.faults.controller_reset_at, self.reset_done) {
            if t >= at {
                self.reset_done = true;
                self.schedule = None;
                self.streaming = false;
                self.seq = 0;
                // The clock restarts from zero, and a step before the reset went with it.
                let rate = 1.0 + self.faults.clock_drift_ppm * 1e-6;
                self.clock_origin_us = -(at * 1e6 * rate + self.faults.clock_step_us(at));
                self.boot(at, out);
            }
        }
        while let (true, Some(schedule)) = (self.streaming, self.schedule) {
            let end = self.slot_start + self.slot_len(&schedule);
            if end > t {
                break;
            }
            let n = schedule.slots().len();
            if self.slot == 0
                && self.jumped_frame.is_none()
                && self.faults.frame_jump_at.is_some_and(|at| self.slot_start >= at)
            {
                self.jumped_frame = Some(self.frame);
            }
            if self.slot < n {
                let slot = schedule.slots()[self.slot];
                let mid = self.slot_start + 0.5 * f64::from(slot.slot_us) * 1e-6;
                let sample = self.sample(self.slot as u8, slot.led, mid, scene, schedule.dark_slot_us > 0);
                let delay = self.injected_delay(end);
                let p = self.packet(Message::Sample(sample));
                out.push(Outgoing { at: end + delay, packet: p });
                self.samples_in_frame += 1;
                // An extra sample naming an LED the schedule does not have in this slot.
                if let Some(led) = self.faults.unscheduled_led(mid).filter(|_| self.slot == 0) {
                    let stray = self.sample(self.slot as u8, led, mid, scene, schedule.dark_slot_us > 0);
                    let p = self.packet(Message::Sample(stray));
                    out.push(Outgoing { at: end + delay, packet: p });
                }
            }
            self.slot += 1;
            self.slot_start = end;
            let frame_done = self.slot > n || (self.slot == n && schedule.dark_slot_us == 0);
            if frame_done {
                let p = self.packet(Message::FrameEnd {
                    frame: self.frame_no(),
                    t_ctrl_us: self.clock_us(end),
                    samples: self.samples_in_frame,
                });
                out.push(Outgoing { at: end, packet: p });
                self.frame = self.frame.wrapping_add(1);
                self.slot = 0;
                self.samples_in_frame = 0;
            }
        }
        while self.next_heartbeat <= t {
            let state = if self.streaming { ControllerState::Streaming } else { ControllerState::Idle };
            let at = self.next_heartbeat;
            let p = self.packet(Message::Heartbeat { t_ctrl_us: self.clock_us(at), state });
            out.push(Outgoing { at, packet: p });
            self.next_heartbeat += HEARTBEAT_PERIOD;
        }
    }

    /// The frame counter as sent: the frame's own, or 2^31 - 1 ahead for the one frame a
    /// `frame_jump_at` fault picked.
    fn frame_no(&self) -> u32 {
        if self.jumped_frame == Some(self.frame) {
            self.frame.wrapping_add(0x7FFF_FFFF)
        } else {
            self.frame
        }
    }

    fn injected_delay(&mut self, t: f64) -> f64 {
        let f = &self.faults;
        let ramp = f.ramp_delay(t);
        if f.sample_delay_ms <= 0.0 && f.sample_jitter_ms <= 0.0 {
            return ramp;
        }
        let jitter = f.sample_jitter_ms * rand::Rng::random_range(&mut self.rng, -1.0..1.0);
        ((f.sample_delay_ms + jitter) * 1e-3).max(0.0) + ramp
    }

    fn sample(&mut self, slot: u8, led: u8, t: f64, scene: &(impl Scene + ?Sized), dark: bool) -> Sample {
        let half = f64::from(self.camera.counts) / 2.0;
        let reflected = self.faults.reflected(led, t);
        let raw = self.leds.position(led, scene, t).and_then(|p| self.camera.project(p + reflected));
        let mut flags = if dark { SampleFlags::AMBIENT_SUBTRACTED } else { 0 };
        let (mut x, mut y, intensity) = match raw {
            Some(r) if self.camera.in_view(r) && !self.faults.occluded(led, t) => {
                let ambient = if dark { 0.0 } else { AMBIENT };
                (r.0, r.1, (INTENSITY + ambient) as u16)
            }
            // Out of view, occluded, or an LED that is not there: too little light.
            Some(r) => {
                flags |= SampleFlags::WEAK_SIGNAL;
                (r.0, r.1, WEAK_INTENSITY)
            }
            None => {
                flags |= SampleFlags::WEAK_SIGNAL;
                (0.0, 0.0, WEAK_INTENSITY)
            }
        };
        if let Some(n) = self.noise {
            x += n.sample(&mut self.rng);
            y += n.sample(&mut self.rng);
        }
        x = x.clamp(-half, half - 1.0);
        y = y.clamp(-half, half - 1.0);
        Sample {
            frame: self.frame_no(),
            slot,
            led,
            t_ctrl_us: self.clock_us(t),
            x: x.round() as i32,
            y: y.round() as i32,
            intensity,
            flags: SampleFlags(flags),
        }
    }
}

/// Helpers for tests and tools: the message type of a packet.
pub fn kind(p: &Packet) -> MessageType {
    p.message.msg_type()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::SimScenario;
    use crate::world::fleet::Fleet;
    use crate::world::World;

    fn scenario(name: &str) -> SimScenario {
        SimScenario::load(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios").join(name)).unwrap()
    }

    /// A fleet's vehicles carry two LEDs each after the obstacles', front then rear, half
    /// their radius from their centres, as the robot's are.
    #[test]
    fn every_vehicle_of_a_fleet_is_lit_where_it_stands() {
        let s = scenario("fleet/e5-scripted.toml");
        let (obstacles, map) = (s.obstacles.len(), LedMap::standard(s.robot.radius));
        let fleet = Fleet::for_rig(&s);
        assert_eq!(fleet.len(), 2);
        let radius = s.vehicles[0].body(&s.robot).radius;
        let (front, rear, offset) = map.vehicle_leds(obstacles, 1, radius).unwrap();
        assert_eq!((front, rear, offset), (3 + obstacles as u8, 4 + obstacles as u8, 0.5 * radius));
        let pose = fleet.world(1).pose();
        let ahead = Point::from_polar(offset, pose.heading);
        let at = |led| map.position(led, &fleet, 0.0).unwrap();
        assert!((at(front) - (pose.position + ahead)).norm() < 1e-12);
        assert!((at(rear) - (pose.position - ahead)).norm() < 1e-12);
        let robot = fleet.world(0).pose().position;
        assert!((at(1) - at(2)).norm() > 0.0 && ((at(1) + at(2)) * 0.5 - robot).norm() < 1e-12);
        assert_eq!(map.position(rear + 1, &fleet, 0.0), None, "no third vehicle");
        // The robot's world alone lights the same LEDs as a fleet of one, and no vehicle's.
        let alone = World::new(&s.vehicle_alone(0));
        let one = Fleet::for_rig(&s.vehicle_alone(0));
        for led in 1..=rear {
            assert_eq!(map.position(led, &alone, 0.0), map.position(led, &one, 0.0), "LED {led}");
        }
        assert_eq!(map.position(front, &alone, 0.0), None);
    }
}
