//! What the watchdogs and the core's own timers count from, each kept by the type that
//! changes it: the samples' watch, the pose's, the frame stamps' pace, and the run's
//! instants (the arm, the heartbeat, an orderly stop, the last command).

use std::time::Duration;

use crate::time::{CtrlTime, HostTime};
use crate::track::Implausible;

/// A frame's end stamp may stray this far from the frames counted, µs, beyond drift.
const STAMP_SLACK_US: f64 = 2000.0;
/// Frames apart beyond which two frame ends are not compared.
const STAMP_CHECK_FRAMES: u32 = 64;
/// The most frames the controller may count between the last frame before a restart and
/// the new stream's first (a minute at 1 kHz): beyond, its counter is taken to have begun
/// again (a reboot).
const RESTART_FRAMES: u32 = 1 << 16;
/// The controller's clock drift bound (1000 ppm, as the time syncs allow).
const DRIFT_BOUND: f64 = 1e-3;

/// The sample watchdog's memory: when it last started counting, and the serial line's
/// garbage (bad frames, dropped bytes) and sequence discards counted at the last sample.
#[derive(Debug, Default)]
pub(super) struct SampleWatch {
    last: HostTime,
    garbage_at_last: (u64, u64),
    discards_at_last: u64,
}

impl SampleWatch {
    /// Count from `now` (a sample, a stream's start, an arm); whether the line had been
    /// quiet for more than two `period`s before.
    pub(super) fn count_from(&mut self, now: HostTime, period: Duration) -> bool {
        let quiet = now.since(self.last) > 2 * period;
        self.last = now;
        quiet
    }

    /// A sample came: what garbage and discards count as since it.
    pub(super) fn sampled(&mut self, garbage: (u64, u64), discards: u64) {
        (self.garbage_at_last, self.discards_at_last) = (garbage, discards);
    }

    pub(super) fn last(&self) -> HostTime {
        self.last
    }

    pub(super) fn garbage_at_last(&self) -> (u64, u64) {
        self.garbage_at_last
    }

    pub(super) fn discards_at_last(&self) -> u64 {
        self.discards_at_last
    }
}

/// The pose watchdog's memory, to name a pose stop by its first cause.
#[derive(Debug, Default)]
pub(super) struct PoseWatch {
    /// When the last plausible robot pose arrived (host time, whatever its age).
    arrived: HostTime,
    /// Why the last robot sample was discarded as implausible, until a plausible one comes.
    implausible: Option<Implausible>,
    /// When a robot sample was last discarded as stamped in the future (the clock, not the
    /// robot, is then what went wrong).
    from_future: Option<HostTime>,
    /// The garbage counted at the last plausible pose.
    garbage_at_last: (u64, u64),
    /// The robot's LEDs have come in frames since, but unusable (weak: occluded), rather
    /// than not at all.
    weak: bool,
    /// The samples stopped for longer than two periods since the last plausible pose (the
    /// line went quiet, even if it came back before the sample watchdog fired).
    quiet_since: bool,
}

impl PoseWatch {
    /// A plausible pose arrived at `now`, with the line's garbage counted then.
    pub(super) fn plausible(&mut self, now: HostTime, garbage: (u64, u64)) {
        *self = Self { arrived: now, garbage_at_last: garbage, from_future: self.from_future, ..Self::default() };
    }

    /// A robot sample discarded as implausible: whether it is the first since a plausible one.
    pub(super) fn implausible(&mut self, why: Implausible) -> bool {
        self.implausible.replace(why).is_none()
    }

    /// The robot's LEDs came weak (`weak`), or not at all.
    pub(super) fn seen_weak(&mut self, weak: bool) {
        self.weak |= weak;
    }

    /// A robot sample stamped in the future was discarded at `now`.
    pub(super) fn stamped_in_future(&mut self, now: HostTime) {
        self.from_future = Some(now);
    }

    /// The line went quiet for more than two periods.
    pub(super) fn line_quiet(&mut self, quiet: bool) {
        self.quiet_since |= quiet;
    }

    /// A reset: a future stamp before it names nothing after.
    pub(super) fn forget_future(&mut self) {
        self.from_future = None;
    }

    pub(super) fn arrived(&self) -> HostTime {
        self.arrived
    }
    pub(super) fn is_implausible(&self) -> bool {
        self.implausible.is_some()
    }
    pub(super) fn last_from_future(&self) -> Option<HostTime> {
        self.from_future
    }
    pub(super) fn garbage_at_last(&self) -> (u64, u64) {
        self.garbage_at_last
    }
    pub(super) fn weak(&self) -> bool {
        self.weak
    }
    pub(super) fn quiet_since(&self) -> bool {
        self.quiet_since
    }
}

/// The frame stamps' pace: whether each frame's end stamp keeps pace with the frames
/// counted since the last, and when it last did not (the controller's clock stepped).
#[derive(Debug, Default)]
pub(super) struct StampWatch {
    /// The last frame's number and end stamp, and when it arrived.
    last_frame_end: Option<(u32, CtrlTime, HostTime)>,
    /// The controller began to stream again at this time, and its new stream's first
    /// frame has not come yet.
    new_stream_since: Option<HostTime>,
    /// The last frame judged before the stream restarted (its number and end stamp), until
    /// the new stream's first frame comes.
    frame_before_stream: Option<(u32, CtrlTime)>,
    stepped: Option<HostTime>,
}

impl StampWatch {
    /// Frame `frame_no` ended at `end` (at `end_host` on the host's clock) and arrived at
    /// `now`; `period`: the schedule's. A stamp that keeps pace with neither the frames
    /// counted nor the time between their arrivals (beyond drift and jitter) is the clock
    /// stepping. (A stream restarted behind a delay breaks the count's pace but keeps the
    /// arrivals'; a creeping delay the other way round.)
    pub(super) fn frame(&mut self, now: HostTime, frame_no: u32, end: CtrlTime, end_host: HostTime, period: Duration) {
        // Frames of the stream before a restart, still on their way behind a delay, come
        // first: neither judged nor judged against until the new stream's first frame.
        if let Some(since) = self.new_stream_since {
            // Its first frame ends a period after the restart; the old ones before it (half
            // a period apart from either is more than the clock offset's error).
            if end_host < since + period / 2 {
                // The line keeps order: a frame counted after the last one before the
                // restart but stamped before it was not left in flight. The clock stepped
                // back after the handshake's sync.
                let counted_after = |last: u32| (1..=RESTART_FRAMES).contains(&frame_no.wrapping_sub(last));
                if self.frame_before_stream.is_some_and(|(last, last_end)| counted_after(last) && end < last_end) {
                    self.stepped = Some(now);
                }
                return;
            }
            (self.new_stream_since, self.frame_before_stream) = (None, None);
        }
        let within =
            |&(last, _, _): &(u32, CtrlTime, HostTime)| (1..=STAMP_CHECK_FRAMES).contains(&frame_no.wrapping_sub(last));
        if let Some((last, last_end, arrived)) = self.last_frame_end.filter(within) {
            let frames = f64::from(frame_no.wrapping_sub(last));
            let counted = frames * period.as_secs_f64() * 1e6;
            let stamped = end.0 as f64 - last_end.0 as f64;
            let between = now.since(arrived).as_secs_f64() * 1e6;
            let off = |expected: f64| (stamped - expected).abs() > STAMP_SLACK_US + expected.abs() * DRIFT_BOUND;
            if off(counted) && off(between) {
                self.stepped = Some(now);
            }
        }
        self.last_frame_end = Some((frame_no, end, now));
    }

    /// Frames are no longer judged against the last one (a new stream, a reset); it is
    /// kept to tell the new stream's frames from the old one's still in flight.
    pub(super) fn forget_pace(&mut self) {
        if let Some((last, end, _)) = self.last_frame_end.take() {
            self.frame_before_stream = Some((last, end));
        }
    }

    /// A new stream began at `now`.
    pub(super) fn stream_started(&mut self, now: HostTime) {
        self.new_stream_since = Some(now);
    }

    /// A line opened afresh, or a controller rebooted: no frame before is a baseline.
    pub(super) fn new_baseline(&mut self) {
        (self.last_frame_end, self.frame_before_stream) = (None, None);
    }

    /// A reset: a step before it names nothing after.
    pub(super) fn forget_step(&mut self) {
        self.stepped = None;
    }

    /// When the clock was last seen stepping.
    pub(super) fn stepped(&self) -> Option<HostTime> {
        self.stepped
    }
}

/// The run's instants the core's timers count from.
#[derive(Debug, Default)]
pub(super) struct RunWatch {
    armed_at: HostTime,
    next_heartbeat: HostTime,
    stopping_since: Option<HostTime>,
    last_command: Option<HostTime>,
}

impl RunWatch {
    pub(super) fn armed(&mut self, now: HostTime) {
        self.armed_at = now;
    }
    pub(super) fn heartbeat_sent(&mut self, next: HostTime) {
        self.next_heartbeat = next;
    }
    /// An orderly stop began at `now`; `None`: it ended, or an emergency stop replaced it.
    pub(super) fn stopping(&mut self, since: Option<HostTime>) {
        self.stopping_since = since;
    }
    pub(super) fn commanded(&mut self, now: HostTime) {
        self.last_command = Some(now);
    }
    pub(super) fn armed_at(&self) -> HostTime {
        self.armed_at
    }
    pub(super) fn next_heartbeat(&self) -> HostTime {
        self.next_heartbeat
    }
    pub(super) fn stopping_since(&self) -> Option<HostTime> {
        self.stopping_since
    }
    pub(super) fn last_command(&self) -> Option<HostTime> {
        self.last_command
    }
}
