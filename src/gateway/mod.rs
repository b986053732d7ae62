//! The gateway service: PSD samples in, motor CAN frames out, under a safety state machine,
//! with every cycle timed.
//!
//! Two rooms, with a wall between them (see docs/architecture.md):
//! - [`core`]: the gateway's logic with no I/O and no clock. Inputs (PSD bytes, CAN events,
//!   operator requests, ticks) come with their host time through one door,
//!   [`core::Core::handle`]; outputs (PSD packets, CAN frames, timing records, state
//!   changes) and the next deadline go back. It owns the PSD session, the tracker, the
//!   control step, the safety machine, the motors and the watchdogs, and defines every type
//!   they exchange.
//! - [`shell`]: the tokio driver for the rig and the services around it: it opens the
//!   links, reads, writes (each with a deadline), sleeps until the core's next deadline,
//!   and serves telemetry, recording, `/metrics`, the live view and the control socket.
//!   The shell uses the core; the core knows nothing of the shell. Each is named by its own
//!   path (`gateway::core::operator`, `gateway::shell::recording`).

pub mod core;
pub mod shell;
