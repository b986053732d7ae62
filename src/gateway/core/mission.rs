//! What the operator asked the robot to do: the goals in order, whether to start, and
//! whether to arm and start at the controller's first stream (`flowgate run --arm`).

use std::collections::VecDeque;

use super::operator::{Goal, MAX_GOALS};

#[derive(Debug)]
pub(super) struct Mission {
    /// The goal being driven to, then the rest of the queue.
    goals: VecDeque<Goal>,
    /// The operator asked to start: go from Armed to Running once ready.
    start_requested: bool,
    /// Arm and start towards the rig's goal when the controller first streams.
    arm_at_start: bool,
}

impl Mission {
    pub(super) fn new() -> Self {
        Self { goals: VecDeque::with_capacity(MAX_GOALS), start_requested: false, arm_at_start: false }
    }

    /// The goals, the one being driven to first.
    pub(super) fn goals(&self) -> impl Iterator<Item = Goal> + '_ {
        self.goals.iter().copied()
    }

    pub(super) fn has_goals(&self) -> bool {
        !self.goals.is_empty()
    }

    /// A new queue of goals in place of the old.
    pub(super) fn set_goals(&mut self, goals: &[Goal]) {
        self.goals.clear();
        self.goals.extend(goals.iter().copied());
    }

    pub(super) fn clear_goals(&mut self) {
        self.goals.clear();
    }

    /// The goal being driven to is reached: the next, if any.
    pub(super) fn next_goal(&mut self) -> Option<Goal> {
        self.goals.pop_front();
        self.goals.front().copied()
    }

    /// The operator asked to start (`true`), or the start is called off.
    pub(super) fn set_start_requested(&mut self, requested: bool) {
        self.start_requested = requested;
    }

    /// The operator asked to start, and has not called it off.
    pub(super) fn start_requested(&self) -> bool {
        self.start_requested
    }

    /// Arm and start at the controller's first stream.
    pub(super) fn arm_at_start(&mut self) {
        self.arm_at_start = true;
    }

    /// Whether to arm and start now (once).
    pub(super) fn take_arm_at_start(&mut self) -> bool {
        std::mem::take(&mut self.arm_at_start)
    }

    /// The queue's capacity, in goals.
    pub(super) fn capacity(&self) -> usize {
        self.goals.capacity()
    }
}
