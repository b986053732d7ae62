//! The PSD controller's serial link as the core sees it: bytes in, decoded into packets,
//! each checked against the controller's sequence; the session's packets (handshake, time
//! sync) to [`PsdSession`](super::psd_session::PsdSession), samples and frame ends to the
//! [`FrameAssembler`](super::frame::FrameAssembler), whose good frames run the cycle; the
//! controller's faults named. Discards are counted, and beyond their budget a named fault.

use flowgate_protocol::codec::StreamError;
use flowgate_protocol::psd::{FaultCode, Message, Packet};

use super::budget::Budget;
use super::counter_window::Verdict;
use super::frame::{Ended, Taken};
use super::operator::Refusal;
use super::psd_session::SessionEvent;
use super::safety::Garbled;
use super::ROBOT;
use super::{Core, Notice, Output, StageClock, StopReason, REOPEN_EVERY};
use crate::time::{CtrlTime, HostTime};

/// The PSD line's health: its bad frames and sequence errors within the last second,
/// whether the controller has streamed and is being configured again, and when a lost line
/// is asked for again. One value a line: its fields change only through its methods.
#[derive(Debug)]
pub(super) struct PsdLinkHealth {
    bad_frames: Budget,
    sequence_errors: Budget,
    /// When to ask for the lost line to be opened again.
    reopen_at: HostTime,
    /// The controller has streamed at least once.
    streamed: bool,
    /// The session is being configured again, for an operator's reset or a controller
    /// gone silent (not a reconnect).
    reconfiguring: bool,
    /// When the silent controller was last configured again.
    restreamed_at: HostTime,
    /// The instant of the read whose packets are still being decoded: a read is decoded
    /// as its outputs are drained, so each cycle's command is drained in that cycle's state.
    read_at: Option<HostTime>,
}

impl PsdLinkHealth {
    /// A line not yet open, its budgets `per_second` bad frames and sequence errors.
    pub(super) fn new(per_second: u32) -> Self {
        Self {
            bad_frames: Budget::new(per_second),
            sequence_errors: Budget::new(per_second),
            reopen_at: HostTime::NEVER,
            streamed: false,
            reconfiguring: false,
            restreamed_at: HostTime::ZERO,
            read_at: None,
        }
    }

    /// A bad frame at `now`: whether more than the budget came within the last second.
    pub(super) fn bad_frame(&mut self, now: HostTime) -> bool {
        self.bad_frames.exceeded(now)
    }

    /// A packet discarded for its sequence at `now`: whether beyond the budget.
    pub(super) fn sequence_error(&mut self, now: HostTime) -> bool {
        self.sequence_errors.exceeded(now)
    }

    /// The line opened.
    pub(super) fn opened(&mut self) {
        self.reopen_at = HostTime::NEVER;
    }

    /// The line is lost at `now`: ask for it again a little later (once per loss); a
    /// configuration under way on it is not the next line's.
    pub(super) fn lost(&mut self, now: HostTime) {
        if self.reopen_at == HostTime::NEVER {
            self.reopen_at = now + REOPEN_EVERY;
        }
        self.reconfiguring = false;
    }

    /// The reopen was asked for at `now`: the next ask, should this one fail.
    pub(super) fn reopen_asked(&mut self, now: HostTime) {
        self.reopen_at = now + REOPEN_EVERY;
    }

    /// The controller on the same line is configured again (an operator's reset).
    pub(super) fn reconfigure(&mut self) {
        self.reconfiguring = true;
    }

    /// The silent controller is configured again at `now`.
    pub(super) fn restream(&mut self, now: HostTime) {
        self.restreamed_at = now;
        self.reconfiguring = true;
    }

    /// The controller streams: whether this is a reconnect (it streamed before, and no
    /// reconfiguration on the same line was under way).
    pub(super) fn streaming(&mut self) -> bool {
        let reconnect = self.streamed && !std::mem::take(&mut self.reconfiguring);
        self.streamed = true;
        reconnect
    }

    /// A read at `now` is being decoded; `None`: done.
    pub(super) fn decoding(&mut self, read_at: Option<HostTime>) {
        self.read_at = read_at;
    }

    pub(super) fn read_at(&self) -> Option<HostTime> {
        self.read_at
    }

    pub(super) fn has_streamed(&self) -> bool {
        self.streamed
    }

    pub(super) fn reopen_at(&self) -> HostTime {
        self.reopen_at
    }

    pub(super) fn restreamed_at(&self) -> HostTime {
        self.restreamed_at
    }

    /// The budgets' windows, in elements of capacity.
    pub(super) fn footprint(&self) -> usize {
        self.bad_frames.capacity() + self.sequence_errors.capacity()
    }
}

impl<K: StageClock> Core<K> {
    /// The PSD line opened: configure the controller.
    pub(super) fn psd_connected(&mut self, now: HostTime) {
        self.psd_link.opened();
        // A line opened afresh carries nothing of the last one's order.
        self.stamps.new_baseline();
        self.psd.connect(now, &mut self.out.psd());
    }

    /// The PSD line failed (read error, end of file, write timeout): a serial fault.
    pub(super) fn psd_lost(&mut self, now: HostTime) {
        self.psd_link.lost(now);
        self.psd.down();
        self.counters.serial_dropped_bytes = self.psd.dropped_bytes();
        self.stop(now, StopReason::SerialLost);
    }

    /// Bytes read from the PSD line at `now`: decoded up to the first packet that gives an
    /// output, the rest as [`Core::poll`] drains them.
    pub(super) fn psd_bytes(&mut self, now: HostTime, bytes: &[u8]) {
        if self.psd.is_down() {
            self.psd.discard(bytes);
            self.counters.serial_dropped_bytes = self.psd.dropped_bytes();
            return;
        }
        self.psd.feed(bytes);
        self.psd_link.decoding(Some(now));
        self.decode_read(true);
    }

    /// Decode the read under way, packet by packet, at its instant: all of it, or
    /// (`until_output`) until there is an output to drain.
    pub(super) fn decode_read(&mut self, until_output: bool) {
        let Some(now) = self.psd_link.read_at() else { return };
        loop {
            if until_output && !self.out.is_empty() {
                return;
            }
            let started = self.clock.now_ns();
            let item = self.psd.next_item();
            let decoded = self.clock.now_ns();
            self.stages.decoded(decoded.saturating_sub(started));
            match item {
                None => break,
                Some(Err(e)) => self.bad_frame(now, e),
                Some(Ok(packet)) => {
                    // A frame end's checks end where its cycle starts (`cycle` takes them).
                    self.stages.checks_begin(decoded);
                    self.packet(now, packet);
                    let clock = &mut self.clock;
                    self.stages.checks_end(|| clock.now_ns());
                }
            }
        }
        self.psd_link.decoding(None);
        self.psd.decoded(now);
        self.counters.serial_dropped_bytes = self.psd.dropped_bytes();
    }

    fn bad_frame(&mut self, now: HostTime, e: StreamError<flowgate_protocol::psd::Error>) {
        self.counters.bad_serial_frames += 1;
        tracing::debug!("bad serial frame: {e}");
        if self.psd_link.bad_frame(now) {
            self.stop_if_active(now, self.garbled_since_last_sample(Garbled::BeyondBudget));
        }
    }

    /// A sample taken (or the stream starting afresh) at `now`: the sample watchdog starts
    /// again, and so does the count of garbage since the last sample.
    pub(super) fn sampled(&mut self, now: HostTime) {
        self.samples_watched_from(now);
        let garbage = (self.counters.bad_serial_frames, self.psd.garbage_bytes());
        self.samples.sampled(garbage, self.counters.psd_sequence_discards());
    }

    /// The sample watchdog counts from `now` (a sample, the stream's start, an arm). An arm
    /// is no sample: the garbage since the last one still names a stop that follows.
    pub(super) fn samples_watched_from(&mut self, now: HostTime) {
        let quiet = self.samples.count_from(now, self.rig.sample_period);
        self.vehicles[ROBOT].pose_watch.line_quiet(quiet);
    }

    /// Frames are no longer judged against the last one (a new stream, a reset); it is
    /// kept to tell the new stream's frames from the old one's still in flight.
    pub(super) fn forget_frame_pace(&mut self) {
        self.stamps.forget_pace();
    }

    /// The serial link garbled: the bad frames and dropped bytes since the last sample.
    pub(super) fn garbled_since_last_sample(&self, found: Garbled) -> StopReason {
        self.garbled_since(self.samples.garbage_at_last(), found)
    }

    /// The serial link garbled: the bad frames and dropped bytes since they were
    /// `(frames, bytes)`.
    pub(super) fn garbled_since(&self, (frames, bytes): (u64, u64), found: Garbled) -> StopReason {
        self.garbled_counting((frames, bytes), found, 0)
    }

    /// As [`Self::garbled_since`], found by a watchdog at `now`: the line has gone quiet,
    /// and a frame begun over a period ago and not ended counts as a bad frame too.
    pub(super) fn garbled_when_quiet(&self, now: HostTime, since: (u64, u64), found: Garbled) -> StopReason {
        self.garbled_counting(since, found, self.psd.cut_short(now - self.rig.sample_period))
    }

    fn garbled_counting(&self, (frames, bytes): (u64, u64), found: Garbled, cut_short: u64) -> StopReason {
        let count = |now: u64, then: u64| u32::try_from(now.saturating_sub(then)).unwrap_or(u32::MAX);
        let cut = u64::from(cut_short > 0);
        StopReason::SerialGarbled {
            frames: count(self.counters.bad_serial_frames + cut, frames),
            bytes: count(self.psd.garbage_bytes() + cut_short, bytes),
            found,
        }
    }

    /// Why no sample came for the sample timeout, named by the first cause: the line gone;
    /// garbage on the line since the last sample (noise, a bad cable or baud rate; a frame
    /// cut short) is the line garbled, not the controller silent; whole packets discarded
    /// for their sequence numbers while a handshake waits (its answer among them, maybe)
    /// are the sequence; a handshake waiting on, or held up by, the time sync is the clock.
    pub(super) fn samples_stopped_cause(&self, now: HostTime) -> StopReason {
        // A line gone (a device that vanished, not yet back) is the first cause of all.
        if self.psd.is_down() {
            return StopReason::SerialLost;
        }
        match self.garbled_when_quiet(now, self.samples.garbage_at_last(), Garbled::NoSample) {
            StopReason::SerialGarbled { frames: 0, bytes: 0, .. } => {}
            garbled => return garbled,
        }
        // A handshake's answer may be among them: the stream waits for it.
        if self.psd.in_handshake() && self.counters.psd_sequence_discards() > self.samples.discards_at_last() {
            return StopReason::PsdSequence { handshake: true };
        }
        if self.psd.clock_waiting(now) {
            return StopReason::ClockUnsynced;
        }
        StopReason::SamplesStopped
    }

    /// A packet discarded for its place in the sequence or the schedule: counted (by the
    /// caller), and against the budget.
    fn sequence_error(&mut self, now: HostTime) {
        if self.psd_link.sequence_error(now) {
            self.stop_if_active(now, StopReason::PsdSequence { handshake: false });
        }
    }

    /// The controller's sequence: duplicates and replays are discarded, gaps counted.
    fn in_sequence(&mut self, now: HostTime, packet: &Packet) -> bool {
        if let Message::Fault { code: FaultCode::Reset, .. } = packet.message {
            self.psd.forget_sequence(); // a rebooted controller counts from zero
        }
        let c = &mut self.counters;
        match self.psd.sequence(packet.seq) {
            Verdict::Next => return true,
            Verdict::Gap(n) => {
                c.psd_packets_lost += u64::from(n);
                return true;
            }
            Verdict::Rebased => {
                c.psd_seq_rebased += 1;
                let seq = packet.seq;
                self.notice(now, Notice::SequenceRebased { seq });
                return true;
            }
            Verdict::Repeat => c.psd_duplicates += 1,
            Verdict::Old => c.psd_out_of_order += 1,
            Verdict::Jump => c.psd_seq_jumps += 1,
        }
        self.sequence_error(now);
        false
    }

    fn packet(&mut self, now: HostTime, packet: Packet) {
        if !self.in_sequence(now, &packet) {
            return;
        }
        let event = self.psd.on_packet(now, &packet, &mut self.out.psd());
        if self.session_event(now, event) {
            return;
        }
        let timed = matches!(packet.message, Message::Sample(_) | Message::FrameEnd { .. });
        if timed && !self.psd.is_streaming() {
            // Before time sync its stamps mean nothing on our clock: discard, and count.
            self.counters.samples_unsynced += 1;
            return;
        }
        self.message(now, packet.message);
    }

    /// What the session made of a packet; whether it consumed the packet.
    fn session_event(&mut self, now: HostTime, event: SessionEvent) -> bool {
        match event {
            SessionEvent::Pass => return false,
            SessionEvent::Consumed => {}
            SessionEvent::Failed(e) => self.setup_failed(now, e),
            SessionEvent::Streaming => self.streaming(now),
            SessionEvent::Resynced { accepted: true } => self.counters.time_syncs += 1,
            SessionEvent::Resynced { accepted: false } => self.counters.time_syncs_rejected += 1,
            SessionEvent::ClockStep { step_us, again } => {
                self.counters.time_syncs_implausible += 1;
                if again {
                    self.notice(now, Notice::ClockJumped { step_us });
                    self.stop_if_active(now, StopReason::ClockJumped);
                } else {
                    self.notice(now, Notice::ClockStepRefused { step_us });
                }
            }
        }
        true
    }

    /// The controller is configured and streams: frames start afresh; a reconnect is
    /// counted; `--arm` arms and starts now.
    fn streaming(&mut self, now: HostTime) {
        self.sampled(now);
        self.forget_frame_pace();
        self.stamps.stream_started(now);
        self.frame.restart(&self.rig.schedule);
        if self.psd_link.streaming() {
            self.counters.serial_reconnects += 1;
            self.progress.serial_reconnects = self.counters.serial_reconnects;
        }
        let firmware = self.psd.info().map(|info| info.firmware);
        self.notice(now, Notice::Streaming { firmware });
        self.out.push(Output::Streaming);
        if self.vehicles[ROBOT].mission.take_arm_at_start() {
            let result = match self.rig.goal {
                Some(goal) => self.arm_and_start(now, None, Some(goal)),
                None => Err(Refusal::NoGoal),
            };
            if let Err(e) = result {
                self.notice(now, Notice::ArmAtStartRefused(e));
            }
            // Every other vehicle with a goal of its own (`[[vehicles]] goal`) or a script
            // goes too.
            for k in ROBOT + 1..self.vehicles.len() {
                let goal = self.rig.vehicles[k - 1].goal;
                if goal.is_some() || self.vehicles[k].script.is_some() {
                    if let Err(e) = self.arm_and_start(now, Some(k), goal) {
                        self.vehicle_notice(k, now, Notice::ArmAtStartRefused(e));
                    }
                }
            }
        }
    }

    /// A packet past the session's checks: a sample, a frame's end, a controller's fault.
    fn message(&mut self, now: HostTime, message: Message) {
        match message {
            Message::Sample(s) => match self.frame.sample(now, &s, &self.rig.schedule, &mut self.counters) {
                Taken::Yes => self.sampled(now),
                Taken::Unscheduled { over_budget } => {
                    if over_budget {
                        self.stop_if_active(now, StopReason::UnscheduledLed { led: s.led });
                    }
                }
            },
            Message::FrameEnd { frame, t_ctrl_us, samples } => {
                let rebased = self.counters.frames_rebased;
                let ended = self.frame.end(now, frame, samples, &self.rig.schedule, &mut self.counters);
                if self.counters.frames_rebased > rebased {
                    self.notice(now, Notice::FrameCounterRebased { frame });
                }
                match ended {
                    Ended::Cycle => self.cycle(now, frame, CtrlTime(t_ctrl_us)),
                    Ended::Repeated => self.sequence_error(now),
                    Ended::Jumped { over_budget: true } => self.stop_if_active(now, StopReason::FrameCounterJump),
                    Ended::Jumped { over_budget: false } => {}
                }
            }
            Message::Fault { code: FaultCode::Reset, .. } => {
                // The controller rebooted (or announces its boot while we configure it): its
                // schedule and clock are gone. A robot driving on it stops, named for it (a
                // quick reconfigure must not hide a reboot); the controller is configured
                // again so an operator can reset and arm.
                // Its clock and frame counter begin again: no frame before is a baseline.
                self.stamps.new_baseline();
                let restarted = self.psd.restart(now, &mut self.out.psd());
                if restarted {
                    self.notice(now, Notice::ControllerReset);
                    self.stop_if_active(now, StopReason::ControllerReset);
                }
            }
            Message::Fault { code: FaultCode::Overrun, .. } => {
                // Samples lost inside the controller: loss, counted against the budget.
                self.counters.controller_overruns += 1;
                self.sequence_error(now);
            }
            Message::Fault { code, detail } => {
                self.counters.controller_faults += 1;
                self.notice(now, Notice::ControllerFault { code, detail });
                self.stop_if_active(now, StopReason::ControllerFault);
            }
            _ => {} // heartbeats
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two lines are two values: a reconnect on one, a reconfiguration on the other.
    #[test]
    fn two_psd_links_side_by_side() {
        let t = |ms: u64| HostTime::from_nanos(ms * 1_000_000);
        let (mut a, mut b) = (PsdLinkHealth::new(2), PsdLinkHealth::new(2));
        assert!(!a.streaming() && !b.streaming(), "a first stream is no reconnect");
        a.lost(t(10));
        b.reconfigure();
        assert_eq!(a.reopen_at(), t(10) + REOPEN_EVERY);
        assert_eq!(b.reopen_at(), HostTime::NEVER);
        a.opened();
        assert!(a.streaming(), "streaming again after a loss is a reconnect");
        assert!(!b.streaming(), "streaming again after a reconfiguration is not");
        // Each counts its bad frames against its own budget of 2 a second.
        assert!(!a.bad_frame(t(20)) && !a.bad_frame(t(21)) && a.bad_frame(t(22)));
        assert!(!b.bad_frame(t(22)));
        b.restream(t(30));
        assert_eq!((a.restreamed_at(), b.restreamed_at()), (HostTime::ZERO, t(30)));
    }
}
