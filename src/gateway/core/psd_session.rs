//! The PSD controller's serial session, without I/O: the byte stream decoded into packets,
//! and the configuration handshake (Info, schedule, time sync, start) as a state machine
//! with its retry deadline. The core feeds it bytes and time; it hands back packets to
//! send and the packets that are not part of the handshake.

use std::time::Duration;

use bytes::BytesMut;
use flowgate_protocol::codec::{PsdCodec, StreamError};
use flowgate_protocol::psd::{self, Info, Message, NackReason, Packet, Schedule};
use tokio_util::codec::Decoder as _;

use super::counter_window::{CounterWindow, Verdict};
use crate::time::{ClockOffset, CtrlTime, HostTime};

/// How long a request waits for its answer before it is sent again.
pub const RETRY_AFTER: Duration = Duration::from_millis(350);
/// How many times a request is sent before the controller counts as silent.
pub const TRIES: u8 = 3;
/// How often the controller's clock is synchronised again while it streams.
pub const RESYNC_EVERY: Duration = Duration::from_secs(1);
/// The longest round trip a resync is taken from: a longer one says more about the line's
/// queueing than about the clocks, and is discarded (and counted).
pub const MAX_RTT: Duration = Duration::from_millis(10);
/// How long the clock offset may go without a good sync while streaming: five resyncs in a
/// row rejected (at 1000 ppm the clocks part by 5 ms meanwhile).
pub const SYNC_STALE: Duration = Duration::from_secs(5);
/// How fast the controller's clock may drift from the host's (the protocol's bound), ppm: a
/// sync whose offset moved further over the interval, beyond the round trips' uncertainty,
/// is a clock step, not drift.
pub const MAX_DRIFT_PPM: u64 = 1000;
/// After a refused step the clock is synced again this soon, to tell one odd reply from a
/// clock that really jumped.
pub const STEP_RECHECK: Duration = Duration::from_millis(20);
/// How far a packet's sequence number may lie from the last one's, either way, and still be
/// judged against it (a second of packets at 1 kHz with four LEDs); beyond is a jump.
pub const SEQ_WINDOW: u32 = 1024;
/// Consecutive sequence numbers beyond the window that confirm the controller's counter
/// really moved.
pub const SEQ_CONFIRM: u8 = 4;
/// Bytes held for decoding: a few frames (the shell reads at most 1 KiB at a time).
const BUFFER: usize = 4096;

/// Why the controller could not be configured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SetupError {
    #[error("PSD controller did not answer {request} ({TRIES} tries, {} ms apart): powered? right port and baud?", RETRY_AFTER.as_millis())]
    Silent { request: &'static str },
    #[error("PSD controller refused {request}: {reason:?}")]
    Refused { request: &'static str, reason: NackReason },
    #[error("PSD controller is not the one configured: {0}")]
    Identity(&'static str),
    #[error(
        "PSD controller drives {drives} LEDs (its Info.max_leds); the schedule has {schedule} ([leds] and [[vehicles]])"
    )]
    FewerLeds { drives: u8, schedule: usize },
}

/// The handshake's steps, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    Info,
    Schedule,
    TimeSync,
    Start,
}

impl Step {
    fn name(self) -> &'static str {
        match self {
            Step::Info => "GetInfo",
            Step::Schedule => "SetSchedule",
            Step::TimeSync => "TimeSync",
            Step::Start => "StartStream",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// No line.
    Down,
    /// Waiting for the answer to `step`'s request, sent as `seq` at `sent`.
    Setup {
        step: Step,
        seq: u16,
        sent: HostTime,
        tries: u8,
    },
    Streaming,
}

/// What a packet meant to the session.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SessionEvent {
    /// Part of the handshake; nothing for the core.
    Consumed,
    /// The handshake finished: samples will flow.
    Streaming,
    /// The handshake failed.
    Failed(SetupError),
    /// Not the session's: the core handles it (samples, frame ends, heartbeats, faults).
    Pass,
    /// A periodic time sync came back: taken, or discarded for its round trip.
    Resynced { accepted: bool },
    /// A periodic time sync put the controller's clock further from the last offset than
    /// drift allows: refused, and checked again at once. `again`: the recheck found the
    /// step too, so the controller's clock really jumped.
    ClockStep { step_us: i64, again: bool },
}

/// Where the serial line's bytes went: every byte received is taken (in a good frame or
/// an idle delimiter), dropped (counted in `serial_dropped_bytes`), or still buffered.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SerialBytes {
    pub received: u64,
    pub taken: u64,
    pub dropped: u64,
    pub buffered: u64,
}

impl SerialBytes {
    /// Every byte received is accounted for.
    pub fn balanced(&self) -> bool {
        self.received == self.taken + self.dropped + self.buffered
    }
}

/// The session.
#[derive(Debug)]
pub struct PsdSession {
    schedule: Schedule,
    /// The PSD's full-scale counts the calibration assumes.
    counts: u16,
    codec: PsdCodec,
    buf: BytesMut,
    seq: u16,
    phase: Phase,
    offset: ClockOffset,
    info: Option<Info>,
    /// The controller's sequence numbers, against the last accepted.
    incoming: CounterWindow,
    /// While streaming: when to sync the clock again, and the sync in flight (sent at).
    next_resync: HostTime,
    resync: Option<(u16, HostTime)>,
    /// When the offset was last taken from a good round trip.
    synced_at: HostTime,
    /// The last time sync's round trip (taken or not).
    round_trip: Option<Duration>,
    /// The round trip the offset was taken from.
    offset_round_trip: Duration,
    /// The last periodic sync found a step (refused).
    stepped: bool,
    /// A handshake's sync that disagreed with the offset held before it, waiting for a
    /// second to agree with one of them (an odd reply is not taken on its own word).
    unconfirmed: Option<(ClockOffset, HostTime, Duration)>,
    /// Handshake syncs taken so far in this handshake.
    handshake_syncs: u8,
    /// An offset has been taken (the session has a clock to judge a handshake's against).
    has_offset: bool,
    /// Time syncs the handshake asked again for, their replies held beyond the bound.
    held_syncs: u8,
    /// Bytes thrown away before the current decoder (its own count starts at zero), and
    /// bytes still buffered when a session ended.
    dropped_before: u64,
    /// Bytes earlier decoders threw away as garbage (bad frames, runs with no delimiter).
    garbage_before: u64,
    /// Bytes taken by decoders before the current one.
    taken_before: u64,
    /// Every byte the line delivered.
    received: u64,
    /// Since when the bytes buffered have waited for their frame's end.
    tail_since: Option<HostTime>,
}

impl PsdSession {
    pub fn new(schedule: Schedule, counts: u16) -> Self {
        Self {
            schedule,
            counts,
            codec: PsdCodec::new(),
            buf: BytesMut::with_capacity(BUFFER),
            seq: 0,
            phase: Phase::Down,
            offset: ClockOffset::default(),
            info: None,
            incoming: CounterWindow::new(16, SEQ_WINDOW, SEQ_CONFIRM),
            next_resync: HostTime::NEVER,
            resync: None,
            synced_at: HostTime::ZERO,
            round_trip: None,
            offset_round_trip: Duration::ZERO,
            stepped: false,
            unconfirmed: None,
            handshake_syncs: 0,
            has_offset: false,
            held_syncs: 0,
            dropped_before: 0,
            garbage_before: 0,
            taken_before: 0,
            received: 0,
            tail_since: None,
        }
    }

    /// The line is open: stop any stream left running and start the handshake.
    pub fn connect(&mut self, now: HostTime, send: &mut impl FnMut(Packet)) {
        self.discard_buffer();
        self.dropped_before += self.codec.stats().dropped_bytes;
        self.garbage_before += self.codec.stats().dropped_bytes;
        self.taken_before += self.codec.stats().taken_bytes;
        self.incoming.reset();
        self.codec = PsdCodec::new();
        (self.unconfirmed, self.handshake_syncs, self.held_syncs) = (None, 0, 0);
        send(self.packet(Message::StopStream));
        self.request(now, Step::Info, 1, send);
    }

    /// The controller rebooted (it announced a reset): its schedule is gone, configure it
    /// again from the schedule on.
    /// Returns whether it had been streaming (a reset in the middle of a run).
    pub fn restart(&mut self, now: HostTime, send: &mut impl FnMut(Packet)) -> bool {
        self.incoming.reset();
        let was_streaming = self.phase == Phase::Streaming;
        if self.phase != Phase::Down {
            (self.unconfirmed, self.handshake_syncs, self.held_syncs) = (None, 0, 0);
            self.request(now, Step::Schedule, 1, send);
        }
        was_streaming
    }

    /// Stop the stream and end the session (the setup tools, when done).
    pub fn stop(&mut self, send: &mut impl FnMut(Packet)) {
        send(self.packet(Message::StopStream));
        self.down();
    }

    /// The line is gone.
    pub fn down(&mut self) {
        self.phase = Phase::Down;
        self.discard_buffer();
    }

    /// Bytes received and not decoded are thrown away, and counted.
    fn discard_buffer(&mut self) {
        self.dropped_before += self.buf.len() as u64;
        self.buf.clear();
        self.tail_since = None;
    }

    /// Every byte received and thrown away so far: bad frames with their delimiters, runs
    /// with no delimiter, bytes left undecoded when a session ended.
    pub fn dropped_bytes(&self) -> u64 {
        self.dropped_before + self.codec.stats().dropped_bytes
    }

    /// Every byte the decoders threw away as garbage: of the bytes dropped, those not
    /// merely discarded with the line down or a session's end (the line's noise).
    pub fn garbage_bytes(&self) -> u64 {
        self.garbage_before + self.codec.stats().dropped_bytes
    }

    /// Where every byte the line delivered went.
    pub fn bytes(&self) -> SerialBytes {
        SerialBytes {
            received: self.received,
            taken: self.taken_before + self.codec.stats().taken_bytes,
            dropped: self.dropped_bytes(),
            buffered: self.buf.len() as u64,
        }
    }

    /// Bytes that arrived with the session down (after the line failed, before it opened
    /// again): thrown away, and counted.
    pub fn discard(&mut self, bytes: &[u8]) {
        self.received += bytes.len() as u64;
        self.dropped_before += bytes.len() as u64;
    }

    /// The handshake waits on the controller's clock: a time sync answered too late to be
    /// taken, or unanswered beyond the round trip's bound.
    pub fn clock_waiting(&self, now: HostTime) -> bool {
        match self.phase {
            Phase::Setup { step: Step::TimeSync, sent, .. } => self.held_syncs > 0 || now > sent + MAX_RTT,
            // Its syncs were held, and the handshake goes on late for them.
            Phase::Setup { .. } => self.held_syncs > 0,
            _ => false,
        }
    }

    pub fn is_streaming(&self) -> bool {
        self.phase == Phase::Streaming
    }
    /// Configuring the controller: no samples until the handshake ends, which has its own
    /// deadlines (each request's tries, the time sync's bound).
    pub fn in_handshake(&self) -> bool {
        matches!(self.phase, Phase::Setup { .. })
    }
    pub fn is_down(&self) -> bool {
        self.phase == Phase::Down
    }
    pub fn info(&self) -> Option<Info> {
        self.info
    }
    /// Controller stamps to host time, from the last time sync.
    /// The receive buffer's capacity, bytes.
    pub fn buffered_capacity(&self) -> usize {
        self.buf.capacity()
    }
    pub fn clock(&self) -> ClockOffset {
        self.offset
    }
    /// The last time sync's round trip, taken or discarded.
    pub fn round_trip(&self) -> Option<Duration> {
        self.round_trip
    }

    /// While streaming, synchronise the clock now instead of at the next resync (the
    /// preflight measures the round trip this way). Its reply is a `Resynced` event.
    pub fn sync_now(&mut self, now: HostTime, send: &mut impl FnMut(Packet)) {
        if self.phase == Phase::Streaming {
            self.next_resync = now;
            self.tick(now, send);
        }
    }
    /// When the clock offset goes stale while streaming (no good sync since `SYNC_STALE`).
    pub fn sync_deadline(&self) -> HostTime {
        if self.phase == Phase::Streaming {
            self.synced_at + SYNC_STALE
        } else {
            HostTime::NEVER
        }
    }

    /// Accept whatever sequence number comes next (a controller that rebooted).
    pub fn forget_sequence(&mut self) {
        self.incoming.reset();
    }

    /// Check a packet's sequence number against the window ([`CounterWindow`]).
    pub fn sequence(&mut self, seq: u16) -> Verdict {
        self.incoming.check(u32::from(seq))
    }

    /// Bytes read from the line.
    pub fn feed(&mut self, bytes: &[u8]) {
        self.received += bytes.len() as u64;
        self.buf.extend_from_slice(bytes);
    }

    /// Everything fed at `now` is decoded: what is left waits for its frame's end.
    pub fn decoded(&mut self, now: HostTime) {
        self.tail_since = if self.buf.is_empty() { None } else { self.tail_since.or(Some(now)) };
    }

    /// The bytes of a frame begun before `before` and not ended since: on a line that
    /// went quiet, its end (the delimiter) was lost.
    pub fn cut_short(&self, before: HostTime) -> u64 {
        match self.tail_since {
            Some(since) if since < before => self.buf.len() as u64,
            _ => 0,
        }
    }

    /// The next decoded item, `None` when more bytes are needed.
    pub fn next_item(&mut self) -> Option<Result<Packet, StreamError<psd::Error>>> {
        // The codec's io::Error is for I/O only, which a byte buffer never has.
        self.codec.decode(&mut self.buf).ok().flatten()
    }

    /// When the pending request is due again.
    pub fn deadline(&self) -> HostTime {
        match self.phase {
            Phase::Setup { sent, .. } => sent + RETRY_AFTER,
            Phase::Streaming => self.next_resync,
            Phase::Down => HostTime::NEVER,
        }
    }

    /// Retry or give up on a request that went unanswered.
    pub fn tick(&mut self, now: HostTime, send: &mut impl FnMut(Packet)) -> Option<SetupError> {
        if self.phase == Phase::Streaming && now >= self.next_resync {
            // A sync still unanswered a period later is simply replaced.
            let sent = HostTime::from_nanos(now.as_nanos() / 1000 * 1000);
            let packet = self.packet(Message::TimeSync { host_time_us: sent.as_nanos() / 1000 });
            self.resync = Some((packet.seq, sent));
            self.next_resync = now + RESYNC_EVERY;
            send(packet);
            return None;
        }
        let Phase::Setup { step, tries, .. } = self.phase else { return None };
        if now < self.deadline() {
            return None;
        }
        if tries >= TRIES {
            self.phase = Phase::Down;
            return Some(SetupError::Silent { request: step.name() });
        }
        self.request(now, step, tries + 1, send);
        None
    }

    /// A packet from the controller.
    pub fn on_packet(&mut self, now: HostTime, packet: &Packet, send: &mut impl FnMut(Packet)) -> SessionEvent {
        if let Some(event) = self.resync_reply(now, packet) {
            return event;
        }
        let Phase::Setup { step, seq, sent, .. } = self.phase else { return SessionEvent::Pass };
        let next = match (step, packet.message) {
            (Step::Info, Message::Info { request_seq, info }) if request_seq == seq => {
                self.info = Some(info);
                if let Some(problem) = self.identity_problem(&info) {
                    self.phase = Phase::Down;
                    return SessionEvent::Failed(problem);
                }
                Step::Schedule
            }
            // The answer to a GetInfo that a reboot's announcement overtook (the handshake
            // went on from the schedule): the controller's identity is still checked.
            (_, Message::Info { info, .. }) if self.info.is_none() => {
                self.info = Some(info);
                if let Some(problem) = self.identity_problem(&info) {
                    self.phase = Phase::Down;
                    return SessionEvent::Failed(problem);
                }
                return SessionEvent::Consumed;
            }
            (Step::Schedule, Message::Ack { seq: s, .. }) if s == seq => Step::TimeSync,
            (Step::TimeSync, Message::TimeSyncReply { request_seq, host_time_us, t_ctrl_us })
                if request_seq == seq && host_time_us == sent.as_nanos() / 1000 =>
            {
                match self.handshake_sync(now, sent, CtrlTime(t_ctrl_us), send) {
                    Some(next) => next,
                    None => return SessionEvent::Consumed,
                }
            }
            (Step::Start, Message::Ack { seq: s, .. }) if s == seq => {
                self.phase = Phase::Streaming;
                self.next_resync = now + RESYNC_EVERY;
                self.resync = None;
                return SessionEvent::Streaming;
            }
            (_, Message::Nack { seq: s, reason, .. }) if s == seq => {
                self.phase = Phase::Down;
                return SessionEvent::Failed(SetupError::Refused { request: step.name(), reason });
            }
            (_, Message::Sample(_) | Message::FrameEnd { .. } | Message::Heartbeat { .. } | Message::Fault { .. }) => {
                return SessionEvent::Pass
            }
            _ => return SessionEvent::Consumed, // late or foreign answers
        };
        self.request(now, next, 1, send);
        SessionEvent::Consumed
    }

    /// The handshake's time-sync reply to the request sent at `sent`: the next step, or
    /// `None` when the sync is asked for again (a reply held in a queue).
    fn handshake_sync(
        &mut self,
        now: HostTime,
        sent: HostTime,
        t_ctrl: CtrlTime,
        send: &mut impl FnMut(Packet),
    ) -> Option<Step> {
        // The handshake's sync sets the clock afresh (a new session, or a controller
        // that rebooted). One that disagrees with the clock held before it is taken
        // only once a second agrees with it (the clock stepped, or the controller
        // rebooted); a second that agrees with the old clock says the first reply
        // was the odd one. Either way two replies in a row agree.
        let rtt = now.since(sent);
        self.round_trip = Some(rtt);
        if rtt > MAX_RTT && self.held_syncs < TRIES {
            // Held in a queue: its stamp says little about the clocks (stamps put
            // tens of ms off would make true samples look as if from the future).
            // Asked again a few times; then taken all the same, the periodic syncs
            // judging it, and the stale-clock watchdog faulting if none is good.
            self.held_syncs += 1;
            self.request(now, Step::TimeSync, 1, send);
            return None;
        }
        self.stepped = false;
        self.handshake_syncs = self.handshake_syncs.saturating_add(1);
        let offset = ClockOffset::from_round_trip(sent, t_ctrl, now);
        let agrees = |(held, at, held_rtt): (ClockOffset, HostTime, Duration)| {
            let drift = now.since(at).as_nanos() * u128::from(MAX_DRIFT_PPM) / 1_000_000;
            let bound = drift + (rtt.as_nanos() + held_rtt.as_nanos()) / 2 + 2_000;
            (offset.as_nanos() - held.as_nanos()).unsigned_abs() <= bound
        };
        let held = self.has_offset.then_some((self.offset, self.synced_at, self.offset_round_trip));
        let confirmed = match self.unconfirmed.or(held) {
            None => true,
            Some(earlier) => agrees(earlier) || held.is_some_and(agrees),
        };
        if confirmed || self.handshake_syncs >= TRIES {
            self.unconfirmed = None;
            self.take_offset(offset, now, rtt);
            Some(Step::Start)
        } else {
            self.unconfirmed = Some((offset, now, rtt));
            Some(Step::TimeSync)
        }
    }

    /// The answer to a periodic time sync, if `packet` is it. A reply names its request
    /// twice: by seq, and by the host time it echoes.
    fn resync_reply(&mut self, now: HostTime, packet: &Packet) -> Option<SessionEvent> {
        let Message::TimeSyncReply { request_seq, host_time_us, t_ctrl_us } = packet.message else { return None };
        let (seq, sent) = self.resync?;
        if request_seq != seq || host_time_us != sent.as_nanos() / 1000 {
            return None;
        }
        self.resync = None;
        let rtt = now.since(sent);
        self.round_trip = Some(rtt);
        if rtt > MAX_RTT {
            return Some(SessionEvent::Resynced { accepted: false });
        }
        let offset = ClockOffset::from_round_trip(sent, CtrlTime(t_ctrl_us), now);
        let step_ns = offset.as_nanos() - self.offset.as_nanos();
        if step_ns.unsigned_abs() > self.step_bound_ns(now, rtt) {
            let again = std::mem::replace(&mut self.stepped, true);
            self.next_resync = now + STEP_RECHECK;
            if again {
                // Confirmed: the controller's clock is there now. Taken, so that its stamps
                // mean the right times again (the core faults on the step all the same); held
                // at the old offset, every sample would look old or from the future, and the
                // pose would stay lost for good.
                self.stepped = false;
                self.take_offset(offset, now, rtt);
                self.next_resync = now + RESYNC_EVERY;
            }
            let step_us = i64::try_from(step_ns / 1000).unwrap_or(if step_ns < 0 { i64::MIN } else { i64::MAX });
            return Some(SessionEvent::ClockStep { step_us, again });
        }
        self.stepped = false;
        self.take_offset(offset, now, rtt);
        Some(SessionEvent::Resynced { accepted: true })
    }

    /// Identity: a controller that cannot run this schedule, or reads another PSD, or stamps
    /// in other units, is not the configured one.
    fn identity_problem(&self, info: &Info) -> Option<SetupError> {
        let schedule = self.schedule.slots().len();
        if usize::from(info.max_leds) < schedule {
            Some(SetupError::FewerLeds { drives: info.max_leds, schedule })
        } else if info.psd_counts != [self.counts; 2] {
            Some(SetupError::Identity("its PSD's counts differ from calibration.counts"))
        } else if info.clock_hz != 1_000_000 {
            Some(SetupError::Identity("its timestamps are not in microseconds"))
        } else {
            None
        }
    }

    fn take_offset(&mut self, offset: ClockOffset, now: HostTime, rtt: Duration) {
        self.has_offset = true;
        self.offset = offset;
        self.synced_at = now;
        self.offset_round_trip = rtt;
    }

    /// How far a sync at `now` with round trip `rtt` may move the offset: the drift bound
    /// over the time since the offset was taken, plus half of each round trip (either
    /// stamp may lie anywhere within its own), plus a microsecond of each stamp's rounding.
    fn step_bound_ns(&self, now: HostTime, rtt: Duration) -> u128 {
        let drift = now.since(self.synced_at).as_nanos() * u128::from(MAX_DRIFT_PPM) / 1_000_000;
        drift + (rtt.as_nanos() + self.offset_round_trip.as_nanos()) / 2 + 2_000
    }

    fn request(&mut self, now: HostTime, step: Step, tries: u8, send: &mut impl FnMut(Packet)) {
        let message = match step {
            Step::Info => Message::GetInfo,
            Step::Schedule => Message::SetSchedule(self.schedule),
            Step::TimeSync => Message::TimeSync { host_time_us: now.as_nanos() / 1000 },
            Step::Start => Message::StartStream,
        };
        // The reply echoes whole microseconds: keep `sent` on that grid so it matches.
        let sent = HostTime::from_nanos(now.as_nanos() / 1000 * 1000);
        let packet = self.packet(message);
        self.phase = Phase::Setup { step, seq: packet.seq, sent, tries };
        send(packet);
    }

    fn packet(&mut self, message: Message) -> Packet {
        let p = Packet::new(self.seq, message);
        self.seq = self.seq.wrapping_add(1);
        p
    }
}
