//! One step of the stack: the next event found, the faults due, the firmware polled and
//! every line's bytes delivered, the core drained onto its lines.

use crate::gateway::core::input::CanEvent;
use crate::gateway::core::input::PSD_CHUNK;
use crate::gateway::core::{Input, Output, StageClock, State};
use crate::gateway::shell::link::slcan_event;
use crate::gateway::shell::telemetry::CanRecord;
use crate::time::HostTime;
use flowgate_protocol::psd;
use flowgate_protocol::slcan::{Command, Line as _, MAX_LINE_LEN};
use flowgate_protocol::CanFrame;
use flowgate_sim::psd_controller::BadRequest;
use flowgate_sim::truth::SAMPLE_PERIOD;
use tokio_util::codec::Decoder as _;

use super::{feed, fnv, ns, CanTransport, VirtualRig, MAX_STEP_NS};

impl<K: StageClock> VirtualRig<K> {
    /// The core's next deadline (the core changes only through [`feed`], draining its outputs
    /// and a rehearsal).
    pub(super) fn core_deadline(&self) -> HostTime {
        debug_assert_eq!(self.core_deadline, self.core.next_deadline(), "the core changed outside `feed`");
        self.core_deadline
    }

    pub(super) fn next_event(&self) -> u64 {
        // The firmware's and the faults' times in seconds, their soonest taken to whole
        // nanoseconds once (`ns` keeps their order).
        let mut soonest = f64::INFINITY;
        let mut at = |s: f64| soonest = soonest.min(s);
        if !self.psd_gone {
            at(self.controller.next_event());
        }
        at(self.motors.next_event());
        at(self.pending.next_at());
        at(self.next_truth);
        at(self.bursts.front().copied().unwrap_or(f64::INFINITY));
        at(self.vanish.map_or(f64::INFINITY, |(gone, back)| if self.psd_gone { back } else { gone }));
        at(self.next_foreign);
        at(self.next_master);
        if let Some([from, to]) = self.plan.adapter_bus_off {
            let t = self.time();
            at(if t < from {
                from
            } else if t < to {
                to
            } else {
                f64::INFINITY
            });
        }
        let mut next = self.core_deadline().as_nanos().min(self.t + MAX_STEP_NS).min(ns(soonest));
        for w in [&self.to_host, &self.to_controller, &self.can_up, &self.can_down] {
            next = next.min(w.next());
        }
        next.min(self.host_tx.next()).min(self.host_rx_frames.next())
    }

    /// The serial device vanishing and coming back; foreign traffic on the bus.
    pub(super) fn faults_due(&mut self) {
        let t = self.time();
        if let Some((gone_at, back_at)) = self.vanish {
            if !self.psd_gone && t >= gone_at {
                // The pty closes: the host's read fails at once.
                self.psd_gone = true;
                self.to_host.clear();
                self.to_controller.clear();
                self.pending.clear();
                self.psd_out.clear();
                self.feed(Input::PsdLost);
            } else if self.psd_gone && t >= back_at {
                self.vanish = None;
                self.psd_gone = false;
                self.controller = self.spec.build(t);
                self.controller.boot(t, &mut self.psd_out);
            }
        }
        if t >= self.next_foreign {
            self.next_foreign += 0.1;
            if let Some(node) = self.motors.robot().board_node() {
                self.can_out.extend(flowgate_sim::rig::foreign_frames(node));
            }
        }
        if t >= self.next_master {
            // Another device on the bus commands our board: both the board and the host see it.
            self.next_master += flowgate_sim::rig::SECOND_MASTER_PERIOD;
            if let Some(node) = self.motors.robot().board_node() {
                let frame = flowgate_sim::rig::second_master_command(node);
                self.motors.robot().handle(t, &frame, self.fleet.world_mut(0), &mut self.can_out);
                self.can_out.push(frame);
            }
        }
    }

    pub(super) fn firmware_poll(&mut self) {
        let t = self.time();
        if !self.psd_gone {
            self.controller.poll(t, &self.fleet, &mut self.psd_out);
        }
        self.motors.poll(t, &mut self.fleet, &mut self.can_out);
        self.firmware_out();
    }

    /// The firmware's outputs onto the lines: the controller's packets in order, each no
    /// earlier than its time (injected delay), through the serial faults; the board's
    /// frames through the adapter to the host.
    pub(super) fn firmware_out(&mut self) {
        let t = self.time();
        for o in self.psd_out.drain(..) {
            self.pending.push(o);
        }
        self.scratch.clear();
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        while let Some(packet) = self.pending.pop_due(t) {
            let scratch = &mut self.scratch;
            self.serial_faults.packets(t, packet, &mut |p| {
                if let Ok(n) = p.encode(&mut wire) {
                    scratch.extend_from_slice(&wire[..n]);
                }
            });
        }
        while self.bursts.front().is_some_and(|&at| at <= t) {
            self.bursts.pop_front();
            let burst = self.serial_faults.burst(self.plan.serial_burst_len);
            self.scratch.extend(burst);
        }
        if !self.scratch.is_empty() && !self.psd_gone {
            self.serial_faults.apply(t, &mut self.scratch);
            self.to_host.send(self.t, &self.scratch);
        }
        let bus_off = self.plan.bus_off(t);
        let mut line = [0u8; MAX_LINE_LEN];
        let host_bus_off = self.plan.adapter_bus_off(t);
        self.adapter.bus_off = host_bus_off;
        for f in self.can_out.drain(..) {
            if bus_off || self.can_faults.lose(t) {
                continue;
            }
            match self.options.can {
                CanTransport::Slcan => {
                    if let Some(Ok(n)) = self.adapter.from_bus(f, t).map(|r| r.emit(&mut line)) {
                        self.can_up.send(self.t, &line[..n]);
                    }
                }
                CanTransport::SocketCan if !host_bus_off => {
                    self.host_rx_frames.send(self.t, f);
                }
                CanTransport::SocketCan => {}
            }
        }
    }

    /// How long, on the host's clock, each handling of the controller's bytes that ran a
    /// cycle took (with [`Options::time_cycles`](super::Options::time_cycles)), ns: the
    /// decode of its bytes and the cycle of every vehicle.
    pub fn cycle_ns(&self) -> &[u64] {
        self.cycle_ns.as_deref().unwrap_or_default()
    }

    /// Everything the lines deliver by now.
    pub(super) fn deliver(&mut self) {
        let t = self.time();
        let now = HostTime::from_nanos(self.t);
        while self.to_controller.take(self.t, &mut self.scratch) {
            self.controller_rx.extend_from_slice(&self.scratch);
            while let Ok(Some(item)) = self.controller_codec.decode(&mut self.controller_rx) {
                let request = item.map_err(|e| BadRequest::from_stream(e, &self.controller_codec));
                self.controller.handle(t, request, &mut self.psd_out);
            }
        }
        while self.to_host.take(self.t, &mut self.scratch) {
            self.lines.psd_delivered += self.scratch.len() as u64;
            // In reads of at most a chunk, as the shell's.
            for chunk in self.scratch.chunks(PSD_CHUNK) {
                let Some(times) = self.cycle_ns.as_mut() else {
                    feed(&mut self.core, &mut self.inputs, &mut self.core_deadline, now, Input::PsdBytes(chunk));
                    continue;
                };
                let cycles = self.core.progress().cycles;
                let start = std::time::Instant::now();
                feed(&mut self.core, &mut self.inputs, &mut self.core_deadline, now, Input::PsdBytes(chunk));
                let took = start.elapsed().as_nanos() as u64;
                if self.core.progress().cycles > cycles {
                    times.push(took);
                }
            }
        }
        while self.can_down.take(self.t, &mut self.scratch) {
            self.adapter_rx.extend_from_slice(&self.scratch);
            while let Ok(Some(line)) = self.adapter_codec.decode(&mut self.adapter_rx) {
                self.adapter.bus_off = self.plan.adapter_bus_off(t);
                self.adapter.handle(line.ok(), &mut self.adapter_replies, &mut self.to_bus);
            }
            let mut buf = [0u8; MAX_LINE_LEN];
            for r in self.adapter_replies.drain(..) {
                if let Ok(n) = r.emit(&mut buf) {
                    self.can_up.send(self.t, &buf[..n]);
                }
            }
        }
        while let Some(f) = self.host_tx.take(self.t) {
            self.to_bus.push(f);
        }
        let bus_off = self.plan.bus_off(t);
        for f in self.to_bus.drain(..) {
            if !bus_off && !self.can_faults.lose(t) {
                self.motors.handle(t, &f, &mut self.fleet, &mut self.can_out);
            }
        }
        let interface = self.options.can.interface();
        while let Some(frame) = self.host_rx_frames.take(self.t) {
            if let Some(tel) = &mut self.telemetry {
                let _ = CanRecord { at_s: t, frame, sent: false }.candump(interface, &mut tel.can_log);
            }
            self.lines.can_delivered += 1;
            self.feed(Input::Can(CanEvent::Frame(frame)));
        }
        // SocketCAN tells of its controller going bus-off with an error frame, unasked.
        let host_bus_off = self.options.can == CanTransport::SocketCan && self.plan.adapter_bus_off(t);
        if host_bus_off && !self.host_bus_off {
            self.feed(Input::Can(CanEvent::ErrorFrame { bus_off: true }));
        }
        self.host_bus_off = host_bus_off;
        while self.can_up.take(self.t, &mut self.scratch) {
            self.host_rx.extend_from_slice(&self.scratch);
            while let Ok(Some(line)) = self.host_codec.decode(&mut self.host_rx) {
                if let Some(event) = slcan_event(line) {
                    if let CanEvent::Frame(frame) = event {
                        self.lines.can_delivered += 1;
                        if let Some(tel) = &mut self.telemetry {
                            let _ = CanRecord { at_s: t, frame, sent: false }.candump(interface, &mut tel.can_log);
                        }
                    }
                    feed(&mut self.core, &mut self.inputs, &mut self.core_deadline, now, Input::Can(event));
                }
            }
        }
    }

    /// Hand each of the core's outputs to its line, as the shell does.
    pub(super) fn drain_core(&mut self) {
        while let Some(output) = self.core.poll() {
            match output {
                Output::Psd(packet) => {
                    let mut wire = [0u8; psd::MAX_WIRE_LEN];
                    if let Ok(n) = packet.encode(&mut wire) {
                        self.lines.sent_digest = fnv(self.lines.sent_digest, &wire[..n]);
                        if !self.psd_gone {
                            self.to_controller.send(self.t, &wire[..n]);
                        }
                    }
                }
                Output::Can(frame) => {
                    self.check_motion(&frame);
                    self.send_can(frame);
                }
                Output::Command { frame, mut record } => {
                    self.check_motion(&frame);
                    let done = self.send_can(frame);
                    record.written(done - self.t, HostTime::from_nanos(done), self.core.rig().sample_period);
                    if let Some(timing) = &mut self.timing {
                        timing.add(&record);
                    }
                    if let Some(tel) = &mut self.telemetry {
                        let _ = record.csv(&mut tel.cycles_csv);
                    }
                }
                Output::PollCanStatus => {
                    if self.options.can == CanTransport::Slcan {
                        self.host_line(Command::StatusFlags);
                    }
                }
                Output::State { vehicle, state, .. } => {
                    if state == State::Stopping(crate::gateway::core::StopReason::GoalReached) {
                        let t = self.time();
                        self.reached_at[vehicle].get_or_insert(t);
                    }
                    self.announced[vehicle] = state;
                }
                Output::Streaming => {}
                Output::SetupFailed(e) if !self.core.has_streamed() => self.setup_error = Some(e),
                Output::SetupFailed(_) => {
                    self.feed(Input::PsdLost);
                }
                // The pty opens again once the device is back.
                Output::OpenPsd if !self.psd_gone => {
                    self.controller_rx.clear();
                    self.feed(Input::PsdConnected);
                }
                Output::OpenPsd => {}
                // The virtual rig's CAN link is never lost.
                Output::OpenCan => {}
                // A sweep's thousands of episodes keep quiet; one run shows them with
                // `RUST_LOG=debug`.
                Output::Notice { at, notice } => tracing::debug!(t_s = at.secs(), "{notice}"),
            }
        }
        self.core_deadline = self.core.next_deadline();
    }

    /// A velocity command outside Running that is neither zero nor, in Stopping, a brake is
    /// counted: motion only in Running. A brake (`[safety] stop_brake = "arc"`) asks for the centre
    /// at rest (the wheels' targets opposite, within a pulse a second) and neither wheel
    /// faster than the faster turns now: it takes speed off, never adds it.
    pub(super) fn check_motion(&mut self, frame: &CanFrame) {
        use flowgate_protocol::motor::MotorMessage;
        let Ok(message) = MotorMessage::parse(frame) else { return };
        let MotorMessage::Velocity { left, right, .. } = message else { return };
        let node = message.node();
        let k = node.and_then(|n| self.board_nodes.iter().position(|&b| b == Some(n.get()))).unwrap_or(0);
        if (left, right) == (0, 0) || self.announced[k] == State::Running {
            return;
        }
        let turning = self.fleet.world(k).axes().iter().map(|a| a.rate().abs()).fold(0.0, f64::max);
        let (left, right) = (i64::from(left), i64::from(right));
        let stopping = matches!(self.announced[k], State::Stopping(_));
        let brake = stopping && (left + right).abs() <= 1 && left.abs().max(right.abs()) as f64 <= turning + 1.0;
        if !brake {
            self.motion_outside_running += 1;
        }
    }

    /// Velocity commands outside Running that were neither zero nor a brake (the invariant:
    /// none).
    pub fn motion_outside_running(&self) -> u64 {
        self.motion_outside_running
    }

    /// One SLCAN command from the host to the adapter; returns when it has left the line.
    pub(super) fn host_line(&mut self, cmd: Command) -> u64 {
        let mut line = [0u8; MAX_LINE_LEN];
        match cmd.emit(&mut line) {
            Ok(n) => self.can_down.send(self.t, &line[..n]),
            Err(_) => self.t,
        }
    }

    pub(super) fn send_can(&mut self, frame: CanFrame) -> u64 {
        let at_s = self.time();
        let id = match frame.id() {
            flowgate_protocol::CanId::Standard(id) => u32::from(id),
            flowgate_protocol::CanId::Extended(id) => id | 1 << 31,
        };
        self.lines.sent_digest = fnv(fnv(self.lines.sent_digest, &id.to_le_bytes()), frame.data());
        if self.inputs.is_some() {
            self.can_sent.push(frame);
        }
        if let Some(tel) = &mut self.telemetry {
            let _ = CanRecord { at_s, frame, sent: true }.candump(self.options.can.interface(), &mut tel.can_log);
        }
        match self.options.can {
            CanTransport::Slcan => self.host_line(Command::Transmit(frame)),
            // A bus-off controller sends nothing.
            CanTransport::SocketCan if self.plan.adapter_bus_off(at_s) => self.t,
            CanTransport::SocketCan => self.host_tx.send(self.t, frame),
        }
    }

    /// The world's truth: samples for plots, and since when the wheels stand still.
    pub(super) fn observe(&mut self) {
        let t = self.time();
        let fleet = &self.fleet;
        if (0..fleet.len()).all(|k| fleet.world(k).wheel_speeds().iter().all(|v| v.abs() < 1e-9)) {
            self.at_rest_since.get_or_insert(t);
        } else {
            self.at_rest_since = None;
        }
        while self.next_truth <= t {
            self.record_truth();
            self.next_truth += SAMPLE_PERIOD;
        }
    }

    /// The truth now: the robot's world, or every vehicle's.
    pub(super) fn record_truth(&mut self) {
        if self.fleet.len() == 1 {
            self.truth.record(self.fleet.world(0));
        } else {
            self.truth.record_fleet(&self.fleet, &self.names);
        }
    }

    /// Whether any vehicle has touched anything (the robot's contacts, or any vehicle's
    /// with another or with the world).
    pub(super) fn touched(&self) -> bool {
        let f = &self.fleet;
        (0..f.len()).any(|k| f.world(k).first_contact().is_some() || f.vehicle_contact(k).is_some())
    }

    /// The robot has stopped or faulted, and every other vehicle too (or was never armed):
    /// the run can end once the world has run on.
    pub(super) fn at_rest_all(&self) -> bool {
        let done = |k| self.core.vehicle_state(k).is_some_and(|s| s.is_terminal() || (k > 0 && s == State::Idle));
        (0..self.core.vehicle_count()).all(done)
    }
}
