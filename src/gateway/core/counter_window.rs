//! Sequence checks in the manner of an anti-replay window (IPsec's ESP, RFC 4303 §3.4.3;
//! DTLS, RFC 6347 §4.1.2.6): a counter value is judged against the last one accepted. A
//! value a little ahead is the next one (or one after a gap); the same again is a repeat; a
//! little behind is a replay or a reordering. Anything further away in either direction is
//! a *jump*: discarded and counted as suspicious, never taken as the new baseline, so one
//! odd packet with a valid CRC (a bit error the CRC missed, a stray frame) cannot lock the
//! link. A controller that really restarted or skipped its counters is followed once a run
//! of consecutive values confirms the new place.

/// Where a counter value falls.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// The next one.
    Next,
    /// Ahead within the window: this many were lost in between (accepted).
    Gap(u32),
    /// The same again: a duplicate (discarded).
    Repeat,
    /// Behind within the window: a replay or a reordering (discarded).
    Old,
    /// Beyond the window, either way: discarded and counted as suspicious.
    Jump,
    /// The last of a run of consecutive values beyond the window: the counter really moved
    /// (a controller restarted its counters); this value is the new baseline (accepted).
    Rebased,
}

impl Verdict {
    /// Whether the value's packet or frame is taken.
    pub fn accepted(self) -> bool {
        matches!(self, Self::Next | Self::Gap(_) | Self::Rebased)
    }
}

/// The window over one wrapping counter of `bits` bits.
#[derive(Debug, Clone, Copy)]
pub struct CounterWindow {
    mask: u32,
    window: u32,
    confirm: u8,
    last: Option<u32>,
    /// A run of consecutive values beyond the window: its last value and its length.
    run: Option<(u32, u8)>,
}

impl CounterWindow {
    /// A window of `window` values either side over a counter of `bits` bits (at most 32,
    /// `window` under a quarter of its range); `confirm` consecutive values beyond it
    /// rebase it.
    pub const fn new(bits: u32, window: u32, confirm: u8) -> Self {
        let mask = if bits >= 32 { u32::MAX } else { (1 << bits) - 1 };
        Self { mask, window, confirm, last: None, run: None }
    }

    /// Forget the baseline: the next value is taken as it comes (a new session).
    pub fn reset(&mut self) {
        self.last = None;
        self.run = None;
    }

    /// The last value accepted.
    pub fn last(&self) -> Option<u32> {
        self.last
    }

    /// Judge `value`; an accepted one becomes the last.
    pub fn check(&mut self, value: u32) -> Verdict {
        let value = value & self.mask;
        let Some(last) = self.last else {
            self.last = Some(value);
            return Verdict::Next;
        };
        let ahead = value.wrapping_sub(last) & self.mask;
        let behind = last.wrapping_sub(value) & self.mask;
        let verdict = if ahead == 0 {
            Verdict::Repeat
        } else if ahead <= self.window {
            if ahead == 1 {
                Verdict::Next
            } else {
                Verdict::Gap(ahead - 1)
            }
        } else if behind <= self.window {
            Verdict::Old
        } else {
            return self.beyond(value);
        };
        if verdict.accepted() {
            self.last = Some(value);
            self.run = None;
        }
        verdict
    }

    /// A value beyond the window: part of a run that may confirm a new baseline.
    fn beyond(&mut self, value: u32) -> Verdict {
        let length = match self.run {
            Some((prev, n)) if value == (prev.wrapping_add(1) & self.mask) => n.saturating_add(1),
            _ => 1,
        };
        if length >= self.confirm {
            self.last = Some(value);
            self.run = None;
            Verdict::Rebased
        } else {
            self.run = Some((value, length));
            Verdict::Jump
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_lone_jump_is_discarded_and_the_baseline_kept() {
        let mut w = CounterWindow::new(16, 1024, 4);
        assert_eq!(w.check(10), Verdict::Next);
        assert_eq!(w.check(11), Verdict::Next);
        assert_eq!(w.check(11 + 0x7FFF), Verdict::Jump);
        assert_eq!(w.check(12), Verdict::Next, "the real packet after the odd one is the next");
        assert_eq!(w.check(15), Verdict::Gap(2));
        assert_eq!(w.check(15), Verdict::Repeat);
        assert_eq!(w.check(13), Verdict::Old);
        assert_eq!(w.last(), Some(15));
    }

    #[test]
    fn a_run_of_consecutive_values_beyond_the_window_rebases_it() {
        let mut w = CounterWindow::new(16, 1024, 4);
        w.check(40_000);
        // A controller that restarted its counters at 0.
        assert_eq!(w.check(0), Verdict::Jump);
        assert_eq!(w.check(1), Verdict::Jump);
        assert_eq!(w.check(2), Verdict::Jump);
        assert_eq!(w.check(3), Verdict::Rebased);
        assert_eq!(w.check(4), Verdict::Next);
        // A run broken by a value of the old sequence starts again.
        let mut w = CounterWindow::new(16, 1024, 3);
        w.check(100);
        assert_eq!(w.check(30_000), Verdict::Jump);
        assert_eq!(w.check(101), Verdict::Next);
        assert_eq!(w.check(30_001), Verdict::Jump);
        assert_eq!(w.check(30_002), Verdict::Jump);
        assert_eq!(w.check(30_003), Verdict::Rebased);
    }

    #[test]
    fn it_wraps_at_the_counters_width() {
        let mut w = CounterWindow::new(16, 1024, 4);
        w.check(0xFFFF);
        assert_eq!(w.check(0), Verdict::Next);
        let mut w = CounterWindow::new(32, 1024, 3);
        w.check(u32::MAX - 1);
        assert_eq!(w.check(1), Verdict::Gap(2));
        assert_eq!(w.check(1u32.wrapping_add(0x7FFF_FFFF)), Verdict::Jump, "a jump of 2^31 - 1");
        assert_eq!(w.check(2), Verdict::Next);
    }

    proptest! {
        /// Whatever single value is injected into a steady sequence, the sequence is
        /// accepted again at once when the value lies beyond the window, and within the
        /// window's length when it lies inside it (taken as a gap, the real values behind
        /// it are old until the sequence passes it): no value locks the window.
        #[test]
        fn no_single_value_locks_the_window(start in any::<u16>(), odd in any::<u16>(), at in 1usize..50) {
            let mut w = CounterWindow::new(16, 1024, 4);
            let mut n = start;
            let ahead = odd.wrapping_sub(start.wrapping_add(at as u16));
            let inside = usize::from(ahead) <= 1024;
            for i in 0..at + 1100 {
                if i == at {
                    w.check(u32::from(odd));
                }
                let v = w.check(u32::from(n));
                let excused = i == at && n == odd || inside && i >= at && i <= at + usize::from(ahead);
                prop_assert!(v.accepted() || excused, "{i}: {v:?}");
                n = n.wrapping_add(1);
            }
        }
    }
}
