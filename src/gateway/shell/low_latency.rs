//! The low-latency mode (`[realtime] spin_us`), for a rig that gives the gateway a core of
//! its own.
//!
//! Between frames the loop sleeps in the kernel, and waking a thread that slept through a
//! whole period (17 ms at the paper's rate) costs more than the cycle's work: the CPU may
//! have left its idle state, the caches went cold. In this mode the loop stops sleeping a
//! bounded window before the next frame is due, and polls instead: each turn yields to the
//! runtime, which asks the kernel for ready I/O without blocking (`epoll_wait` with a zero
//! timeout), so the frame's bytes are read within about a microsecond of arriving.
//!
//! When the next frame is due comes from the frames themselves: the measured period (a
//! running mean of the intervals between frame ends, which ignores gaps, such as a paused
//! stream) after the last frame. The window is `spin` before that moment and `spin` after
//! it; if no frame came by then, the loop sleeps again until one does. The runtime's timer
//! wakes up to a millisecond late, so the loop sets it a millisecond early and polls from
//! there: the CPU it costs is about `(spin + 1 ms) / period` of a core when frames come on
//! time (measured by `flowgate bench`).

use std::time::{Duration, Instant};

/// What the loop does until the next input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wait {
    /// Inside the window: poll, and come back at once.
    Poll,
    /// Sleep as usual, but no later than this: the next window opens then.
    Until(Instant),
    /// No frame is expected (none yet, or the last window passed empty): sleep as usual.
    Sleep,
}

/// Predicts the next frame and says when to poll for it.
#[derive(Debug, Clone)]
pub struct SpinWindow {
    spin: Duration,
    last_frame: Option<Instant>,
    /// Running mean of the frame interval, ns (`None` until two frames came).
    period_ns: Option<f64>,
    /// Long intervals in a row: a gap, or the stream slowed down for good.
    long_intervals: u8,
    /// When the cycle was last warmed up, and for which frame (its due time)
    /// ([`SpinWindow::warm_due`]).
    warmed: Option<(Instant, Option<Instant>)>,
}

/// The runtime's timers wake no sooner than their deadline and up to a millisecond later
/// (tokio's timer wheel): a window is slept towards until this long before it opens, and
/// polled from there.
pub const TIMER_GRANULARITY: Duration = Duration::from_millis(1);

/// Weight of each new interval in the running mean.
const GAIN: f64 = 1.0 / 16.0;
/// An interval beyond this many periods is a gap in the stream, not a new period...
const GAP: f64 = 2.0;
/// ... unless this many come in a row: then the stream is slower, and that is the period.
const SLOWER_AFTER: u8 = 3;

impl SpinWindow {
    pub fn new(spin: Duration) -> Self {
        Self { spin, last_frame: None, period_ns: None, long_intervals: 0, warmed: None }
    }

    /// A frame ended at `now` (its last byte was read).
    pub fn frame(&mut self, now: Instant) {
        if let Some(last) = self.last_frame {
            let interval = now.saturating_duration_since(last).as_nanos() as f64;
            let long = self.period_ns.is_some_and(|p| interval > GAP * p);
            self.long_intervals = if long { self.long_intervals + 1 } else { 0 };
            self.period_ns = match self.period_ns {
                Some(p) if long && self.long_intervals < SLOWER_AFTER => Some(p),
                Some(p) if !long => Some(p + GAIN * (interval - p)),
                _ => {
                    self.long_intervals = 0;
                    Some(interval)
                }
            };
        }
        self.last_frame = Some(now);
    }

    /// The frame period measured so far.
    pub fn period(&self) -> Option<Duration> {
        self.period_ns.map(|p| Duration::from_nanos(p as u64))
    }

    /// When the next frame is due.
    pub fn next_due(&self) -> Option<Instant> {
        Some(self.last_frame? + self.period()?)
    }

    /// What to do at `now`.
    pub fn wait(&self, now: Instant) -> Wait {
        let Some(due) = self.next_due() else { return Wait::Sleep };
        let (open, close) = (due.checked_sub(self.spin).unwrap_or(due), due + self.spin);
        let wake = open.checked_sub(TIMER_GRANULARITY).unwrap_or(open);
        if now < wake {
            Wait::Until(wake)
        } else if now <= close {
            Wait::Poll
        } else {
            Wait::Sleep
        }
    }
}

impl SpinWindow {
    /// Whether to warm the cycle up at `now` (`[realtime] warm_up`): as the window opens,
    /// then every [`WARM_EVERY`] while it polls. The loop spends the window's CPU anyway;
    /// a rehearsal (about a cycle's work, a few µs) keeps the cycle's code and data in the
    /// caches the polling would otherwise slowly evict.
    pub fn warm_due(&mut self, now: Instant) -> bool {
        let due = self.next_due();
        if self.wait(now) != Wait::Poll {
            return false;
        }
        let fresh = match self.warmed {
            Some((at, warmed_for)) => warmed_for != due || now >= at + WARM_EVERY,
            None => true,
        };
        if fresh {
            self.warmed = Some((now, due));
        }
        fresh
    }
}

/// How often a polling window rehearses the cycle.
pub const WARM_EVERY: Duration = Duration::from_micros(250);

impl Wait {
    /// Carry it out in an async loop, beside the loop's inputs: returns after one yield to
    /// the runtime (which polls the kernel for I/O without blocking) when polling, at the
    /// window's opening when sleeping until it, never when no frame is expected (the
    /// loop's other branches wake it).
    pub async fn pause(self) {
        match self {
            Wait::Poll => tokio::task::yield_now().await,
            Wait::Until(t) => tokio::time::sleep_until(t.into()).await,
            Wait::Sleep => std::future::pending().await,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn no_window_before_a_period_is_measured() {
        let t0 = Instant::now();
        let mut w = SpinWindow::new(MS / 2);
        assert_eq!(w.wait(t0), Wait::Sleep);
        w.frame(t0);
        assert_eq!(w.wait(t0 + MS), Wait::Sleep, "one frame gives no period");
    }

    #[test]
    fn polls_in_a_window_around_the_next_frame() {
        let t0 = Instant::now();
        let mut w = SpinWindow::new(MS / 2);
        w.frame(t0);
        w.frame(t0 + 17 * MS);
        assert_eq!(w.period(), Some(17 * MS));
        let due = t0 + 34 * MS;
        assert_eq!(w.next_due(), Some(due));
        // The timer may wake a millisecond late: it is set a millisecond early.
        let wake = due - MS / 2 - TIMER_GRANULARITY;
        assert_eq!(w.wait(t0 + 20 * MS), Wait::Until(wake));
        assert_eq!(w.wait(wake), Wait::Poll);
        assert_eq!(w.wait(due + MS / 2), Wait::Poll);
        assert_eq!(w.wait(due + MS), Wait::Sleep, "an empty window ends the polling");
    }

    #[test]
    fn the_cycle_is_warmed_up_as_the_window_opens_and_while_it_polls() {
        let t0 = Instant::now();
        let mut w = SpinWindow::new(MS / 2);
        w.frame(t0);
        w.frame(t0 + 17 * MS);
        let wake = t0 + 34 * MS - MS / 2 - TIMER_GRANULARITY;
        assert!(!w.warm_due(t0 + 20 * MS), "not before the window");
        assert!(w.warm_due(wake), "as it opens");
        assert!(!w.warm_due(wake + WARM_EVERY / 2), "not again at once");
        assert!(w.warm_due(wake + WARM_EVERY), "then every WARM_EVERY");
        w.frame(t0 + 34 * MS);
        assert!(!w.warm_due(t0 + 35 * MS), "not between windows");
        assert!(w.warm_due(t0 + 51 * MS - MS / 2 - TIMER_GRANULARITY), "and again for the next frame");
    }

    #[test]
    fn the_period_follows_the_stream_and_ignores_gaps() {
        let t0 = Instant::now();
        let mut w = SpinWindow::new(MS / 2);
        let mut t = t0;
        for _ in 0..3 {
            w.frame(t);
            t += 10 * MS;
        }
        t += 500 * MS; // the stream pauses
        w.frame(t);
        assert_eq!(w.period(), Some(10 * MS), "a gap is not a period");
        for _ in 0..200 {
            t += 12 * MS;
            w.frame(t);
        }
        let p = w.period().unwrap().as_secs_f64();
        assert!((p - 0.012).abs() < 1e-6, "converged to the new period: {p}");
        // The stream slows to a third: after three such intervals that is the period.
        for k in 1..=3 {
            t += 36 * MS;
            w.frame(t);
            assert_eq!(w.period() == Some(36 * MS), k == 3, "after {k} slow intervals");
        }
    }
}
