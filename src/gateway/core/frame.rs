//! One time-division frame being collected: each scheduled LED's sample, checked against the
//! schedule and its frame, closed by the controller's `FrameEnd`, whose counter is checked
//! against the last frame's. A frame that ends well runs the core's cycle.

use flowgate_protocol::psd::{Sample, Schedule};

use super::budget::Budget;
use super::counter_window::{CounterWindow, Verdict};
use super::counters::Counters;
use crate::time::{ClockOffset, CtrlTime, HostTime};

/// How far a frame counter may lie from the last frame's, either way, and still be judged
/// against it (a second of frames at 1 kHz); beyond is a jump.
const FRAME_WINDOW: u32 = 1024;
/// Consecutive frame counters beyond the window that confirm the controller's counter
/// really moved.
const FRAME_CONFIRM: u8 = 3;

/// One LED's sample in the frame being collected.
#[derive(Debug, Clone, Copy)]
pub struct RawSample {
    pub x: i32,
    pub y: i32,
    pub at: CtrlTime,
    pub usable: bool,
}

/// What became of a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Taken {
    /// Into the frame.
    Yes,
    /// Its LED is not scheduled in its slot: discarded and counted; `over_budget` when more
    /// than the budget came within a second.
    Unscheduled { over_budget: bool },
}

/// What a frame's end means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// Run the frame's cycle.
    Cycle,
    /// A frame already done (a repeat, or older): discarded, a link error.
    Repeated,
    /// The counter jumped beyond the window: discarded; `over_budget` as for samples.
    Jumped { over_budget: bool },
}

/// The frame being collected, and the frame counter it is judged by.
#[derive(Debug)]
pub struct FrameAssembler {
    /// Per LED id: this frame's sample.
    samples: [Option<RawSample>; 256],
    /// The frame whose samples are being collected, and how many came.
    collecting: Option<(u32, u8)>,
    /// The frame counter, against the last frame that ended.
    frames: CounterWindow,
    /// Samples of LEDs the schedule does not have in their slot, and frame counters beyond
    /// the window, within the last second: each its own named fault beyond the budget.
    unscheduled: Budget,
    jumps: Budget,
}

impl FrameAssembler {
    pub fn new(bad_frames_per_s: u32) -> Self {
        Self {
            samples: [None; 256],
            collecting: None,
            frames: CounterWindow::new(32, FRAME_WINDOW, FRAME_CONFIRM),
            unscheduled: Budget::new(bad_frames_per_s),
            jumps: Budget::new(bad_frames_per_s),
        }
    }

    /// The controller streams afresh: no frame under way, the counter taken anew.
    pub fn restart(&mut self, schedule: &Schedule) {
        self.frames.reset();
        self.collecting = None;
        self.clear(schedule);
    }

    /// The frame counter is taken anew at the next frame (an operator's reset).
    pub fn forget_counter(&mut self) {
        self.frames.reset();
    }

    /// A sample: from a scheduled LED in its slot, into the frame being collected.
    pub fn sample(&mut self, now: HostTime, s: &Sample, schedule: &Schedule, counters: &mut Counters) -> Taken {
        let scheduled = schedule.slots().get(usize::from(s.slot)).is_some_and(|slot| slot.led == s.led);
        if !scheduled {
            counters.samples_unscheduled += 1;
            return Taken::Unscheduled { over_budget: self.unscheduled.exceeded(now) };
        }
        match self.collecting {
            Some((frame, _)) if frame != s.frame => {
                // The frame before never ended: its samples go, this frame starts.
                counters.frames_lost += 1;
                self.clear(schedule);
                self.collecting = Some((s.frame, 0));
            }
            None => self.collecting = Some((s.frame, 0)),
            Some(_) => {}
        }
        if let Some((_, n)) = &mut self.collecting {
            *n = n.saturating_add(1);
        }
        counters.samples += 1;
        let at = CtrlTime(s.t_ctrl_us);
        self.samples[usize::from(s.led)] = Some(RawSample { x: s.x, y: s.y, at, usable: s.flags.is_usable() });
        Taken::Yes
    }

    /// A frame's end. A frame already done is discarded (no second command from it); samples
    /// of another frame are dropped; gaps are counted.
    pub fn end(
        &mut self,
        now: HostTime,
        frame: u32,
        samples: u8,
        schedule: &Schedule,
        counters: &mut Counters,
    ) -> Ended {
        match self.frames.check(frame) {
            Verdict::Next => {}
            Verdict::Gap(n) => counters.frames_lost += u64::from(n),
            Verdict::Rebased => {
                counters.frames_rebased += 1;
            }
            Verdict::Repeat | Verdict::Old => {
                counters.frames_repeated += 1;
                self.drop_collected(frame, schedule);
                return Ended::Repeated;
            }
            Verdict::Jump => {
                counters.frames_jumped += 1;
                let over_budget = self.jumps.exceeded(now);
                self.drop_collected(frame, schedule);
                return Ended::Jumped { over_budget };
            }
        }
        let received = match self.collecting.take() {
            Some((f, n)) if f == frame => n,
            Some(_) => {
                counters.frames_lost += 1;
                self.clear(schedule);
                0
            }
            None => 0,
        };
        if received != samples {
            counters.frames_incomplete += 1;
        }
        Ended::Cycle
    }

    /// Discard the samples stamped after `latest` on the host clock (beyond a period of clock
    /// tolerance), counted: one future stamp would otherwise make every later, true one look
    /// old. Which vehicles' LEDs were among them, a bit a vehicle (`vehicle_of` says whose
    /// an LED is).
    pub fn discard_future(
        &mut self,
        clock: ClockOffset,
        latest: HostTime,
        schedule: &Schedule,
        vehicle_of: impl Fn(u8) -> Option<usize>,
        counters: &mut Counters,
    ) -> u64 {
        let mut hit = 0;
        for slot in schedule.slots() {
            let entry = &mut self.samples[usize::from(slot.led)];
            if entry.is_some_and(|s| clock.to_host(s.at) > latest) {
                *entry = None;
                counters.samples_from_future += 1;
                hit |= vehicle_of(slot.led).map_or(0, |k| 1 << k);
            }
        }
        hit
    }

    /// Whether the LED's sample came in this frame, usable or not.
    pub fn received(&self, led: u8) -> bool {
        self.samples[usize::from(led)].is_some()
    }

    /// The LED's sample in this frame, if the controller judged it usable.
    pub fn usable(&self, led: u8) -> Option<RawSample> {
        self.samples[usize::from(led)].filter(|s| s.usable)
    }

    /// A discarded frame's samples go with it (they must not join the next frame).
    fn drop_collected(&mut self, frame: u32, schedule: &Schedule) {
        if self.collecting.is_some_and(|(f, _)| f == frame) {
            self.collecting = None;
            self.clear(schedule);
        }
    }

    /// Forget the scheduled LEDs' samples.
    pub fn clear(&mut self, schedule: &Schedule) {
        for slot in schedule.slots() {
            self.samples[usize::from(slot.led)] = None;
        }
    }
}
