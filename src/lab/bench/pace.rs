//! Pacing the scripted controller: absolute deadlines on the monotonic clock, slept with
//! `clock_nanosleep(TIMER_ABSTIME)` and a 1 ns timer slack, so the rate holds on average
//! without a spinning thread stealing a core from the gateway being measured.

use std::num::NonZeroU64;
use std::time::Duration;

use rustix::thread::clock_nanosleep_absolute;
use rustix::time::{clock_gettime, ClockId, Timespec};

/// Frames due at `start + k * period`.
pub struct Pacer {
    next_ns: u128,
    period_ns: u128,
}

fn monotonic_ns() -> u128 {
    let t = clock_gettime(ClockId::Monotonic);
    t.tv_sec as u128 * 1_000_000_000 + t.tv_nsec as u128
}

impl Pacer {
    /// A pacer whose first deadline is now. Also sets this thread's timer slack to 1 ns:
    /// the default 50 µs would blur sub-millisecond periods.
    pub fn new(period: Duration) -> Self {
        let _ = rustix::thread::set_current_timer_slack(NonZeroU64::new(1));
        Self { next_ns: monotonic_ns(), period_ns: period.as_nanos().max(1) }
    }

    /// Sleep until the next deadline (at once if it has passed) and move it one period on.
    pub fn wait(&mut self) {
        let due = self.next_ns;
        self.next_ns += self.period_ns;
        let ts = Timespec { tv_sec: (due / 1_000_000_000) as _, tv_nsec: (due % 1_000_000_000) as _ };
        // EINTR only cuts a sleep short; the loop sleeps again to the same deadline.
        while let Err(rustix::io::Errno::INTR) = clock_nanosleep_absolute(ClockId::Monotonic, &ts) {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deadlines are absolute: a late start catches up instead of shifting every later frame.
    #[test]
    fn deadlines_do_not_drift() {
        let period = Duration::from_millis(2);
        let start = std::time::Instant::now();
        let mut pacer = Pacer::new(period);
        let first = pacer.next_ns;
        std::thread::sleep(Duration::from_millis(10)); // five deadlines pass while we are away
        for _ in 0..10 {
            pacer.wait();
        }
        // The tenth deadline is 18 ms after the first: waiting cannot end before it, and
        // the deadlines stayed on the grid whatever the sleep took.
        assert!(start.elapsed() >= Duration::from_millis(18));
        assert_eq!(pacer.next_ns, first + 10 * period.as_nanos());
    }
}
