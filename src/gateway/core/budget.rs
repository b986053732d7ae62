//! Events counted over a sliding second against a budget: a few bad frames, sequence errors
//! or refused transmits are noise to count; more within a second is a fault to name.

use std::collections::VecDeque;
use std::time::Duration;

use crate::time::HostTime;

/// The window over which events are counted against their budget.
const WINDOW: Duration = Duration::from_secs(1);

/// Events within the last second, against a limit (the window never grows past it).
#[derive(Debug)]
pub struct Budget {
    times: VecDeque<HostTime>,
    limit: usize,
}

impl Budget {
    pub fn new(per_second: u32) -> Self {
        let limit = per_second as usize;
        Self { times: VecDeque::with_capacity((limit + 1).min(4096)), limit }
    }

    /// Count one at `now`; whether more than the budget fell within the last second.
    pub fn exceeded(&mut self, now: HostTime) -> bool {
        while self.times.front().is_some_and(|&b| now.since(b) > WINDOW) {
            self.times.pop_front();
        }
        if self.times.len() > self.limit.min(4095) {
            self.times.pop_front();
        }
        self.times.push_back(now);
        self.times.len() > self.limit
    }

    /// The window's capacity, in events (a soak holds it to a bound).
    pub fn capacity(&self) -> usize {
        self.times.capacity()
    }
}
