//! The tokio shell around the [`Core`] on a rig, a short driver of named steps in the manner
//! of quinn's connection driver:
//!
//! 1. [`run`] opens the links and starts the services (`services.rs`);
//! 2. then, until the core is finished: carry out what the core asks (`drain`), publish the
//!    statistics and the scene when due (`wake_at`), wait for the next event or the core's
//!    deadline (`next_event`), and hand it to the core (`take`);
//! 3. finally stop the services and report (`finish`).
//!
//! Every decision is the core's, including when a lost line is opened again
//! ([`Output::OpenPsd`], [`Output::OpenCan`]); the shell moves bytes, reads the clock, puts a
//! deadline on every write and measures how long each takes.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use flowgate_protocol::psd::{self, Packet};
use flowgate_protocol::CanFrame;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::watch;
use tokio::time::{timeout, Instant};

pub mod control_client;
pub mod control_socket;
pub mod foxglove;
pub mod http;
pub mod link;
pub mod low_latency;
pub mod metrics;
pub mod realtime;
pub mod recording;
pub mod report;
#[cfg(feature = "ros2")]
pub mod ros2;
mod services;
pub mod systemd;
pub mod telemetry;
pub mod view;

use control_socket::{Command, RequestReceiver, RequestSender};
use low_latency::{SpinWindow, Wait};
pub use report::Report;
use services::Services;
use systemd::Notifier;
use telemetry::{CanRecord, Record, Timing};

use self::link::{open_can, open_serial, CanError, CanLink, SerialError};
use super::core::input::{Answer, Input, InputRecord, RecordedInput, PSD_CHUNK};
use super::core::operator::{Reply, Request};
use super::core::{Core, Counters, Level, Output, Progress, SetupError, StageClock, State};
use crate::config::CanUrl;
use crate::config::Rig;
use crate::gateway::core::input::CanEvent;
use crate::time::HostTime;

/// Deadline of one write to the PSD line (a few frames at 921600 baud take well under 1 ms).
const PSD_WRITE_DEADLINE: Duration = Duration::from_millis(50);
/// Deadline of one CAN frame's write (SocketCAN queue or one SLCAN line): half the board's
/// default command timeout, so a stalled adapter is named before the board stops itself.
const CAN_WRITE_DEADLINE: Duration = Duration::from_millis(50);
/// Deadline of opening the CAN link (an SLCAN adapter answers three commands).
const CAN_OPEN_DEADLINE: Duration = Duration::from_secs(5);

/// What the loop is told from outside.
#[derive(Debug)]
pub struct Controls {
    /// Becomes `true` to stop (orderly) and end the run.
    pub shutdown: watch::Receiver<bool>,
    /// Arm and start towards the config's `[goal]` as soon as the controller streams
    /// (`flowgate run --arm`, the demo). Otherwise the gateway waits, idle, for an operator.
    pub arm_at_start: bool,
    requests: RequestReceiver,
    sender: RequestSender,
    /// Shutdown was asked for and handed to the core.
    shutdown_seen: bool,
}

impl Controls {
    pub fn new(shutdown: watch::Receiver<bool>, arm_at_start: bool) -> Self {
        let (sender, requests) = control_socket::request_channel();
        Self { shutdown, arm_at_start, requests, sender, shutdown_seen: false }
    }

    /// Where operator requests go (the control socket uses one too).
    pub fn sender(&self) -> RequestSender {
        self.sender.clone()
    }
}

/// The host's monotonic clock, for the stage timings.
#[derive(Debug, Clone, Copy)]
struct Monotonic(std::time::Instant);

impl StageClock for Monotonic {
    fn now_ns(&mut self) -> u64 {
        self.0.elapsed().as_nanos() as u64
    }
}

/// Run the gateway until shutdown. Startup failures are returned; everything after is
/// handled by the core's safety state machine and reported.
pub async fn run(
    rig: Rig,
    mut controls: Controls,
    progress: Option<watch::Sender<Progress>>,
) -> Result<Report, GatewayError> {
    let origin = Instant::now();
    let notifier = Notifier::from_env()?;
    let can = match timeout(CAN_OPEN_DEADLINE, open_can(&rig.can)).await {
        Ok(link) => link?,
        Err(_) => return Err(CanError::Timeout { what: "open" }.into()),
    };
    let psd = open_serial(&rig.serial.port, rig.serial.baud)?;
    let services = Services::start(&rig, origin, controls.sender()).await?;
    // On the loop's thread, once everything is open (the writer thread keeps the normal
    // policy) and before the first cycle.
    if !rig.realtime.is_empty() {
        realtime::apply(&rig.realtime)?;
        tracing::info!("real-time settings: {}", rig.realtime);
    }
    let mut io = Io::new(&rig, origin, psd, can, services, progress, notifier);
    let mut core = Core::new(rig, Monotonic(std::time::Instant::now()));
    io.begin(&mut core, &mut controls);
    loop {
        io.drain(&mut core).await?;
        if core.finished() {
            break;
        }
        let wake = io.wake_at(&core);
        let event = io.next_event(&mut controls, wake).await;
        io.take(&mut core, &mut controls, event);
    }
    Ok(io.finish(&core).await)
}

/// What woke the loop.
enum Event {
    /// A read from the PSD line: bytes in the read buffer, or the line failed.
    PsdRead(std::io::Result<usize>),
    /// An event from the CAN link, or its failure.
    Can(Result<CanEvent, CanError>),
    /// A reopen of the CAN link ended.
    CanOpened(Result<CanLink, CanError>),
    /// The core's deadline (or a service's) came.
    Deadline,
    /// An operator's request.
    Request(Command),
    /// The low-latency window's pause ended: poll again.
    Spin,
    /// Shutdown was asked for (or nobody is left to ask).
    Shutdown,
}

/// The shell's I/O: the links, the services, the timing summary.
struct Io {
    origin: Instant,
    port: String,
    serial: crate::config::SerialSection,
    psd: Option<tokio_serial::SerialStream>,
    /// One read is one input (a recording holds it whole).
    read_buf: [u8; PSD_CHUNK],
    /// The CAN link; `None` while it is lost and being reopened.
    can: Option<CanLink>,
    can_url: CanUrl,
    /// A reopen in flight: opening an SLCAN adapter waits on its answers, so it runs as its
    /// own task and the loop keeps ticking the core meanwhile.
    can_opening: Option<tokio::task::JoinHandle<Result<CanLink, CanError>>>,
    services: Services,
    timing: Timing,
    progress: Option<watch::Sender<Progress>>,
    sample_period: Duration,
    /// The low-latency mode's window, when it is on.
    spin: Option<SpinWindow>,
    /// Rehearse the cycle as each window opens (`[realtime] warm_up`).
    warm_up: bool,
    /// Where the operator's stats window starts (`ctl stats --reset`); none: the run's start.
    stats_from: Option<Timing>,
    /// systemd's notification socket, when it started the gateway.
    notifier: Option<Notifier>,
    /// Requests dropped because their client had been told they failed.
    requests_expired: u64,
}

impl Io {
    fn new(
        rig: &Rig,
        origin: Instant,
        psd: tokio_serial::SerialStream,
        can: CanLink,
        services: Services,
        progress: Option<watch::Sender<Progress>>,
        notifier: Option<Notifier>,
    ) -> Self {
        Self {
            origin,
            port: rig.serial.port.display().to_string(),
            serial: rig.serial.clone(),
            psd: Some(psd),
            read_buf: [0; PSD_CHUNK],
            can: Some(can),
            can_url: rig.can.clone(),
            can_opening: None,
            services,
            timing: Timing::default(),
            progress,
            sample_period: rig.sample_period,
            spin: rig.spin.map(SpinWindow::new),
            warm_up: rig.warm_up,
            stats_from: None,
            notifier,
            requests_expired: 0,
        }
    }

    fn now(&self) -> HostTime {
        HostTime::from_nanos(self.origin.elapsed().as_nanos() as u64)
    }

    fn instant(&self, t: HostTime) -> Instant {
        // A deadline that never comes still needs an instant: an hour ahead will do.
        let far = self.origin.elapsed() + Duration::from_secs(3600);
        self.origin + Duration::from_nanos(t.as_nanos()).min(far)
    }

    /// Hand the core an input, recording it first when a recording is on.
    fn feed<K: StageClock>(&mut self, core: &mut Core<K>, now: HostTime, input: Input<'_>) -> Option<Answer> {
        let recorder = &mut self.services.recorder;
        if recorder.recording() {
            let seq = self.services.inputs_taken.fetch_add(1, Ordering::Relaxed);
            recorder.record(Record::Input(InputRecord { seq, at: now, input: RecordedInput::of(input) }));
        }
        core.handle(now, input)
    }

    /// The first inputs: arm at start when asked, the PSD line open, a shutdown asked for
    /// before the loop began.
    fn begin<K: StageClock>(&mut self, core: &mut Core<K>, controls: &mut Controls) {
        if controls.arm_at_start {
            self.feed(core, self.now(), Input::ArmAtStart);
        }
        self.feed(core, self.now(), Input::PsdConnected);
        if *controls.shutdown.borrow() {
            self.shut_down(core, controls);
        }
    }

    /// When to wake if nothing happens: the core's deadline, a publication, the watchdog's
    /// notification. The watchdog is fed from here, the loop itself: a wedged loop starves it.
    fn wake_at<K: StageClock>(&mut self, core: &Core<K>) -> Instant {
        let publish_at = self.publish_metrics(core).min(self.services.publish_scene(core, self.now()));
        let mut wake = self.instant(core.next_deadline().min(publish_at));
        if let Some(n) = &mut self.notifier {
            n.alive(std::time::Instant::now());
            wake = wake.min(n.next_due().map_or(wake, Instant::from_std));
        }
        wake
    }

    /// Wait for the next event, or `wake`.
    async fn next_event(&mut self, controls: &mut Controls, wake: Instant) -> Event {
        let spin = self.spin.as_ref().map_or(Wait::Sleep, |s| s.wait(std::time::Instant::now()));
        let Io { psd, read_buf, can, can_opening, .. } = self;
        let shutdown_seen = controls.shutdown_seen;
        tokio::select! {
            read = async {
                match psd.as_mut() {
                    Some(port) => port.read(read_buf).await,
                    None => std::future::pending().await,
                }
            } => Event::PsdRead(read),
            event = async {
                match can.as_mut() {
                    Some(can) => can.recv().await,
                    None => std::future::pending().await,
                }
            } => Event::Can(event),
            opened = async {
                match can_opening.as_mut() {
                    Some(task) => task.await.unwrap_or(Err(CanError::Closed)),
                    None => std::future::pending().await,
                }
            } => Event::CanOpened(opened),
            _ = tokio::time::sleep_until(wake) => Event::Deadline,
            Some(cmd) = controls.requests.recv() => Event::Request(cmd),
            // Low-latency mode: poll for the frame due now instead of sleeping to it.
            () = spin.pause() => Event::Spin,
            changed = controls.shutdown.changed(), if !shutdown_seen => {
                // A dropped sender is a shutdown too: nobody is left to ask for one.
                if changed.is_err() || *controls.shutdown.borrow() { Event::Shutdown } else { Event::Spin }
            }
        }
    }

    /// Hand an event to the core (or to the shell's own bookkeeping).
    fn take<K: StageClock>(&mut self, core: &mut Core<K>, controls: &mut Controls, event: Event) {
        match event {
            Event::PsdRead(Ok(n)) if n > 0 => {
                let now = self.now();
                let read_buf = self.read_buf;
                self.feed(core, now, Input::PsdBytes(&read_buf[..n]));
            }
            Event::PsdRead(_) => {
                tracing::error!("serial line lost; reconnecting");
                self.lose_psd(core);
            }
            Event::Can(Ok(event)) => {
                if let CanEvent::Frame(frame) = event {
                    self.services.recorder.record(Record::Can(CanRecord { at_s: unix_now(), frame, sent: false }));
                }
                self.feed(core, self.now(), Input::Can(event));
            }
            Event::Can(Err(e)) => {
                tracing::error!("CAN link: {e}; reopening");
                self.lose_can(core);
            }
            Event::CanOpened(opened) => self.can_opened(core, opened),
            Event::Deadline => {
                self.feed(core, self.now(), Input::Tick);
            }
            Event::Request(cmd) => self.answer(core, cmd),
            Event::Spin => {
                // Warm-up: the cycle's work once, as the window opens (`[realtime] warm_up`).
                let now = std::time::Instant::now();
                if self.warm_up && self.spin.as_mut().is_some_and(|s| s.warm_due(now)) {
                    core.rehearse(self.now());
                }
            }
            Event::Shutdown => self.shut_down(core, controls),
        }
    }

    fn shut_down<K: StageClock>(&mut self, core: &mut Core<K>, controls: &mut Controls) {
        controls.shutdown_seen = true;
        if let Some(n) = &mut self.notifier {
            n.stopping();
        }
        self.feed(core, self.now(), Input::Shutdown);
    }

    /// Carry out everything the core has asked for. A startup failure ends the run.
    async fn drain<K: StageClock>(&mut self, core: &mut Core<K>) -> Result<(), GatewayError> {
        while let Some(output) = core.poll() {
            match output {
                Output::Psd(packet) => {
                    if self.services.recorder.recording() {
                        self.services.recorder.record(Record::PsdSent { at: self.now(), packet });
                    }
                    if self.write_psd(packet).await.is_err() {
                        tracing::error!("serial write failed or timed out; reconnecting");
                        self.lose_psd(core);
                    }
                }
                Output::Can(frame) => {
                    if self.send_can(frame).await.is_err() {
                        self.lose_can(core);
                    }
                }
                Output::Command { frame, record } => self.command(core, frame, record).await,
                Output::State { state, at, vehicle: 0 } => self.state_changed(core, state, at),
                Output::State { state, at, vehicle } => self.vehicle_state_changed(core, vehicle, state, at),
                Output::PollCanStatus => self.poll_can_status(core).await,
                Output::Streaming => {
                    if let Some(n) = &mut self.notifier {
                        n.ready(&core.state().to_string());
                    }
                    if let Some(tx) = &self.progress {
                        let reconnects = core.counters().serial_reconnects;
                        tx.send_if_modified(|p| std::mem::replace(&mut p.serial_reconnects, reconnects) != reconnects);
                    }
                }
                Output::SetupFailed(source) if !core.has_streamed() => {
                    return Err(GatewayError::Setup { port: self.port.clone(), source });
                }
                Output::SetupFailed(e) => {
                    tracing::warn!("serial reconnect: {e}");
                    self.lose_psd(core);
                }
                Output::OpenPsd => self.reopen_psd(core),
                Output::OpenCan => self.reopen_can(),
                Output::Notice { at, notice } => {
                    match notice.level() {
                        Level::Info => tracing::info!("{notice}"),
                        Level::Warning => tracing::warn!("{notice}"),
                        Level::Error => tracing::error!("{notice}"),
                    }
                    self.services.recorder.record(Record::Event(telemetry::EventRecord::notice(at.secs(), &notice)));
                }
            }
        }
        Ok(())
    }

    /// A cycle's command: write it, complete its timing record, and show it.
    async fn command<K: StageClock>(
        &mut self,
        core: &mut Core<K>,
        frame: CanFrame,
        mut record: telemetry::CycleRecord,
    ) {
        if let Some(spin) = &mut self.spin {
            spin.frame(self.origin.into_std() + Duration::from_nanos(record.rx_ns));
        }
        let started = Instant::now();
        let sent = self.send_can(frame).await;
        record.written(started.elapsed().as_nanos() as u64, self.now(), self.sample_period);
        self.timing.add(&record);
        let recorder = &mut self.services.recorder;
        recorder.record(Record::Cycle(record));
        if recorder.recording() {
            recorder.scene(core.scene(HostTime::from_nanos(record.rx_ns)), core.fleet_scene());
        }
        if let Some(tx) = &self.progress {
            // Sampled by displays at their own pace: no wake-up per cycle.
            tx.send_if_modified(|p| {
                *p = core.progress();
                p.e2e_us = record.e2e_ns as f64 / 1e3;
                false
            });
        }
        if sent.is_err() {
            self.lose_can(core);
        }
    }

    fn state_changed<K: StageClock>(&mut self, core: &Core<K>, state: State, at: HostTime) {
        tracing::info!("state: {state}");
        self.publish_state_soon();
        if let Some(n) = &mut self.notifier {
            n.status(&state.to_string());
        }
        let text = format!("state: {state}");
        let event = telemetry::EventRecord { at_s: at.secs(), level: Level::Info, kind: "state", text, fields: None };
        self.services.recorder.record(Record::Event(event));
        if let Some(tx) = &self.progress {
            let p = core.progress();
            tx.send_modify(|shown| *shown = Progress { e2e_us: shown.e2e_us, ..p });
        }
    }

    /// `/metrics`, the view's statistics and ROS 2's `/diagnostics` show a new state at the
    /// loop's next pass, not up to a second late: a client waiting for a stop sees it before
    /// a run that ends there is gone.
    fn publish_state_soon(&mut self) {
        if let Some((_, next)) = &mut self.services.metrics {
            *next = HostTime::ZERO;
        }
    }

    /// A vehicle's other than the robot's: logged and recorded, named.
    fn vehicle_state_changed<K: StageClock>(&mut self, core: &Core<K>, vehicle: usize, state: State, at: HostTime) {
        let name = core.vehicle_name(vehicle);
        tracing::info!("vehicle {name}: state: {state}");
        self.publish_state_soon();
        let text = format!("vehicle {name}: state: {state}");
        let fields = Some(serde_json::json!({ "vehicle": name }));
        let event = telemetry::EventRecord { at_s: at.secs(), level: Level::Info, kind: "state", text, fields };
        self.services.recorder.record(Record::Event(event));
        if let Some(tx) = &self.progress {
            let p = core.progress();
            tx.send_modify(|shown| *shown = Progress { e2e_us: shown.e2e_us, ..p });
        }
    }

    async fn poll_can_status<K: StageClock>(&mut self, core: &mut Core<K>) {
        let Some(can) = &mut self.can else { return };
        let polled = match timeout(CAN_WRITE_DEADLINE, can.poll_status()).await {
            Ok(r) => r,
            Err(_) => Err(CanError::Timeout { what: "status poll" }),
        };
        if let Err(e) = polled {
            tracing::error!("CAN status poll: {e}");
            self.lose_can(core);
        }
    }

    async fn write_psd(&mut self, packet: Packet) -> std::io::Result<()> {
        let Some(port) = &mut self.psd else { return Ok(()) };
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let n = packet.encode(&mut wire).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        timeout(PSD_WRITE_DEADLINE, port.write_all(&wire[..n])).await.map_err(|_| std::io::ErrorKind::TimedOut)?
    }

    async fn send_can(&mut self, frame: CanFrame) -> Result<(), CanError> {
        let Some(can) = &mut self.can else {
            if self.services.recorder.recording() {
                self.services.recorder.record(Record::CanUnwritten { at: self.now(), frame });
            }
            return Err(CanError::Closed);
        };
        let result = match timeout(CAN_WRITE_DEADLINE, can.send(frame)).await {
            Ok(r) => r,
            Err(_) => Err(CanError::Timeout { what: "write" }),
        };
        self.services.recorder.record(Record::Can(CanRecord { at_s: unix_now(), frame, sent: true }));
        if let Err(e) = &result {
            tracing::error!("CAN write: {e}");
        }
        result
    }

    /// An operator's request: the core decides, the peer gets the answer and the state.
    fn answer<K: StageClock>(&mut self, core: &mut Core<K>, cmd: Command) {
        let now = self.now();
        if cmd.expired(Instant::now()) {
            // Its client was told it failed: carrying it out now would surprise the operator.
            self.requests_expired += 1;
            let text = format!("{}: {:?} dropped: expired before the gateway took it", cmd.peer, cmd.request);
            tracing::warn!("{text}");
            let event =
                telemetry::EventRecord { at_s: now.secs(), level: Level::Warning, kind: "request", text, fields: None };
            self.services.recorder.record(Record::Event(event));
            return;
        }
        if let Some(refusal) = command_from_elsewhere(core.rig(), &cmd) {
            let _ = cmd.reply.send(Reply::error(refusal));
            return;
        }
        let input = match cmd.vehicle.as_deref().map(|name| (name, core.vehicle_index(name))) {
            None => Input::Request(&cmd.request),
            Some((_, Some(vehicle))) => Input::VehicleRequest { vehicle, request: &cmd.request },
            Some((name, None)) => {
                let names: Vec<&str> = (0..core.vehicle_count()).map(|k| core.vehicle_name(k)).collect();
                let _ =
                    cmd.reply.send(Reply::error(format!("no vehicle {name:?}: the rig's are {}", names.join(", "))));
                return;
            }
        };
        let Some(Answer { result, status }) = self.feed(core, now, input) else { return };
        let status = status.map(|mut status| {
            // The write times are the shell's to measure: it adds them to the answer.
            let window = match cmd.request {
                Request::Stats { reset } => Some(self.stats_window(reset)),
                _ => None,
            };
            let whole = (self.timing.cycles > 0).then(|| self.timing.e2e());
            status.latency_us = window.as_ref().map_or(whole, |w| (w.cycles > 0).then(|| w.e2e()));
            status.stages = window.map(|w| w.stages());
            status
        });
        let of = cmd.vehicle.as_deref().map(|v| format!(" for vehicle {v}")).unwrap_or_default();
        let text = match &result {
            Ok(()) => format!("{}: {:?}{of} accepted", cmd.peer, cmd.request),
            Err(e) => format!("{}: {:?}{of} refused: {e}", cmd.peer, cmd.request),
        };
        if !cmd.request.is_query() && !cmd.request.is_command() {
            match &result {
                Ok(()) => tracing::info!("{text}"),
                Err(_) => tracing::warn!("{text}"),
            }
            let level = if result.is_ok() { Level::Info } else { Level::Warning };
            let event = telemetry::EventRecord { at_s: now.secs(), level, kind: "request", text, fields: None };
            self.services.recorder.record(Record::Event(event));
        }
        let reply = match result {
            Ok(()) => Reply { ok: true, error: None, status },
            Err(e) => Reply { ok: false, error: Some(e.to_string()), status },
        };
        let _ = cmd.reply.send(reply);
    }

    /// The cycles since the operator's last `stats --reset` (or the start); with `reset`,
    /// a new window starts after this one.
    fn stats_window(&mut self, reset: bool) -> Timing {
        let window = match &self.stats_from {
            Some(base) => self.timing.since(base),
            None => self.timing.clone(),
        };
        if reset {
            self.stats_from = Some(self.timing.clone());
        }
        window
    }

    /// Publish a metrics snapshot when one is due (about once a second: a copy of the
    /// counters and the latency histogram, never per cycle). Returns when the next is due.
    fn publish_metrics<K: StageClock>(&mut self, core: &Core<K>) -> HostTime {
        let now = self.now();
        match &self.services.metrics {
            None => return HostTime::NEVER,
            Some((_, next)) if now < *next => return *next,
            Some(_) => {}
        }
        let view_frames_dropped = self.services.view.as_ref().map_or(0, |(v, _)| v.dropped.load(Ordering::Relaxed));
        let mut counters = core.counters();
        counters.telemetry_dropped = self.services.recorder.dropped();
        self.count_operator(&mut counters);
        let Some((tx, next)) = &mut self.services.metrics else { return HostTime::NEVER };
        let vehicles = (1..core.vehicle_count())
            .map(|k| (core.vehicle_name(k).to_string(), core.vehicle_state(k).unwrap_or_default()))
            .collect();
        tx.send_replace(Arc::new(metrics::Snapshot {
            state: core.state(),
            vehicles,
            counters,
            e2e_ns: self.timing.e2e_histogram().clone(),
            deadline_misses: self.timing.deadline_misses,
            uptime_s: now.secs(),
            stops: stops_by_reason(core),
            view_frames_dropped,
            stages: self.timing.stage_histograms().clone(),
            start_time_s: self.services.start_time_s,
        }));
        *next = now + metrics::PUBLISH_EVERY;
        *next
    }

    /// The serial line failed: close it and tell the core (which asks for it again).
    fn lose_psd<K: StageClock>(&mut self, core: &mut Core<K>) {
        self.psd = None;
        self.feed(core, self.now(), Input::PsdLost);
    }

    /// The CAN link failed: drop it and tell the core, naming an interface that went down
    /// (the core stays faulted until an operator resets it, and asks for the link again).
    fn lose_can<K: StageClock>(&mut self, core: &mut Core<K>) {
        let down = matches!(&self.can_url, CanUrl::SocketCan { interface } if self::link::interface_down(interface));
        self.can = None;
        self.feed(core, self.now(), if down { Input::Can(CanEvent::InterfaceDown) } else { Input::CanFailed });
    }

    /// The core asks for the serial line again: try once.
    fn reopen_psd<K: StageClock>(&mut self, core: &mut Core<K>) {
        if self.psd.is_some() {
            return;
        }
        if let Ok(port) = open_serial(&self.serial.port, self.serial.baud) {
            self.psd = Some(port);
            self.feed(core, self.now(), Input::PsdConnected);
        }
    }

    /// The core asks for the CAN link again: open it in a task (an attempt under way goes on).
    fn reopen_can(&mut self) {
        if self.can.is_some() || self.can_opening.is_some() {
            return;
        }
        let url = self.can_url.clone();
        self.can_opening = Some(tokio::spawn(async move {
            timeout(CAN_OPEN_DEADLINE, open_can(&url)).await.unwrap_or(Err(CanError::Timeout { what: "open" }))
        }));
    }

    fn can_opened<K: StageClock>(&mut self, core: &mut Core<K>, opened: Result<CanLink, CanError>) {
        self.can_opening = None;
        match opened {
            Ok(link) => {
                tracing::info!("CAN link reopened");
                self.can = Some(link);
                self.feed(core, self.now(), Input::CanReopened);
            }
            Err(e) => tracing::debug!("CAN reopen: {e}"),
        }
    }

    /// Stop the services, wait for the telemetry's files, and report.
    async fn finish<K: StageClock>(mut self, core: &Core<K>) -> Report {
        if let Some(task) = self.can_opening.take() {
            task.abort();
        }
        // The final state for `/metrics` and the view (whose last frame then shows the
        // same cycle count in its header and its histogram).
        if let Some((_, next)) = &mut self.services.metrics {
            *next = HostTime::ZERO;
        }
        self.services.scenes_due_now();
        self.publish_metrics(core);
        self.services.publish_scene(core, self.now());
        let timing = std::mem::take(&mut self.timing);
        let mut counters = core.counters();
        counters.telemetry_dropped = self.services.recorder.dropped();
        self.count_operator(&mut counters);
        let files = self.services.finish().await;
        Report::new(core, Some(&timing), counters, files)
    }

    /// The operator channel's counts, which the shell keeps (the core never sees a dropped
    /// request or a closed connection).
    fn count_operator(&self, counters: &mut Counters) {
        let clients = &self.services.control_clients;
        counters.requests_expired = self.requests_expired;
        counters.control_clients_evicted = clients.evicted.load(Ordering::Relaxed);
        counters.control_clients_timed_out = clients.timed_out.load(Ordering::Relaxed);
        counters.control_clients_refused = clients.refused.load(Ordering::Relaxed);
    }
}

/// Every stop and fault so far, by reason (`snake_case`), with whether it was a fault.
fn stops_by_reason<K: StageClock>(core: &Core<K>) -> Vec<(String, bool, u64)> {
    let mut out: Vec<(String, bool, u64)> = Vec::new();
    // An orderly stop usually passes Stopping then Stopped: count it once, as it begins.
    let began = core.safety().history.windows(2).filter_map(|w| match (w[0].1, w[1].1) {
        (_, State::Stopping(r) | State::Fault(r)) => Some(r),
        (State::Stopping(_), State::Stopped(_)) => None,
        (_, State::Stopped(r)) => Some(r),
        _ => None,
    });
    for reason in began {
        let name = reason.snake_name();
        match out.iter_mut().find(|(n, ..)| *n == name) {
            Some((.., count)) => *count += 1,
            None => out.push((name, reason.is_fault(), 1)),
        }
    }
    out
}

fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

/// A startup failure: the gateway could not begin.
#[derive(Debug, thiserror::Error)]
pub enum GatewayError {
    #[error(transparent)]
    Serial(#[from] SerialError),
    #[error(transparent)]
    Can(#[from] CanError),
    #[error("PSD controller on {port}: {source}")]
    Setup { port: String, source: SetupError },
    #[error("telemetry output {path}: {source}")]
    Telemetry { path: String, source: std::io::Error },
    #[error(transparent)]
    ControlSocket(#[from] control_socket::ControlSocketError),
    #[error("systemd notification: {0}")]
    Notify(#[from] systemd::NotifyError),
    #[error(transparent)]
    Realtime(#[from] realtime::RealtimeError),
    #[error("operator.metrics = \"{addr}\": cannot listen there: {source}")]
    Metrics { addr: std::net::SocketAddr, source: std::io::Error },
    #[error("operator.view = \"{addr}\": cannot listen there: {source}")]
    View { addr: std::net::SocketAddr, source: std::io::Error },
    #[error("operator.foxglove = \"{addr}\": cannot serve Foxglove live there: {source}")]
    Foxglove { addr: std::net::SocketAddr, source: ::foxglove::FoxgloveError },
    #[error("{0}")]
    Ros2Section(crate::config::Invalid),
    #[cfg(feature = "ros2")]
    #[error(transparent)]
    Ros2(#[from] ros2::Ros2Error),
    #[cfg(not(feature = "ros2"))]
    #[error("[ros2] is enabled, but this flowgate was built without ROS 2 (the `ros2` feature)")]
    Ros2Missing,
}

/// An outside planner's command that came another way than `planner.method` names (the
/// control socket's with `"ros2"`, a ROS 2 one with `"socket"`): refused before the core,
/// so one planner drives.
fn command_from_elsewhere(rig: &crate::config::Rig, cmd: &Command) -> Option<String> {
    use crate::config::PlannerMethod;
    if !cmd.request.is_command() {
        return None;
    }
    match (rig.config.planner.method, cmd.peer) {
        (PlannerMethod::Ros2, control_socket::Peer::Socket { .. }) => {
            Some("planner.method is \"ros2\": the robot's commands come on cmd_vel".into())
        }
        (PlannerMethod::Socket, control_socket::Peer::Ros2) => {
            Some("planner.method is \"socket\": the robot's commands come on the control socket".into())
        }
        _ => None,
    }
}
