//! The gateway service: PSD samples in, motor CAN frames out, under a safety state machine,
//! with every cycle timed.
//!
//! Two rooms (see docs/architecture.md):
//! - [`core`]: the gateway's logic with no I/O and no clock. Inputs (PSD bytes, CAN events,
//!   operator requests, ticks) come with their host time through one door,
//!   [`Core::handle`]; outputs (PSD packets, CAN frames, timing records, state changes) and
//!   the next deadline go back. It owns the PSD session, the tracker, the control step, the
//!   safety machine and the watchdogs, and defines every type they exchange.
//! - [`shell`]: the tokio driver for the rig and the services around it: it opens the
//!   links, reads, writes (each with a deadline), sleeps until the core's next deadline,
//!   and serves telemetry, recording, `/metrics`, the live view and the control socket.
//!   The shell uses the core; the core knows nothing of the shell.
//!
//! The core's and the shell's modules are re-exported here under their own names, so
//! `gateway::operator` is `gateway::core::operator`.

pub mod core;
pub mod shell;

pub use self::core::{
    counter_window, input, operator, psd_session, safety, scene, timing, Answer, Core, Counters, Input, NoClock,
    Output, Progress, SetupError, StageClock, State, StopReason,
};
pub use shell::{
    control_socket, http, low_latency, metrics, realtime, recording, report, run, systemd, telemetry, view, Controls,
    GatewayError, Report,
};
