//! The tokio shell around the [`Core`] on a rig: it opens the links, reads the PSD serial
//! line and the CAN bus, writes what the core asks (every write under a deadline), sleeps
//! until the core's next deadline, and reopens a lost serial line or CAN link. All decisions are the
//! core's; the shell only moves bytes and reads the clock.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use flowgate_protocol::psd::{self, Packet};
use flowgate_protocol::CanFrame;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, watch};
use tokio::time::{timeout, Instant};

pub mod control_socket;
pub mod http;
pub mod low_latency;
pub mod metrics;
pub mod realtime;
pub mod recording;
pub mod systemd;
pub mod telemetry;
pub mod view;

use control_socket::{Command, ControlSocket, Reply};
use low_latency::{SpinWindow, Wait};
use recording::{McapSink, RecordingSetup};
use systemd::Notifier;
use telemetry::{CanRecord, Record, Recorder, Sinks, Timing};

use super::core::input::{Answer, Input, InputRecord, RecordedInput, PSD_CHUNK};
use super::core::operator::Request;
use super::core::{Core, Output, Progress, SetupError, StageClock, State};
use super::Report;
use crate::config::Rig;
use crate::link::{open_can, open_serial, CanError, CanEvent, CanLink, CanUrl, SerialError};
use crate::time::HostTime;

/// Deadline of one write to the PSD line (a few frames at 921600 baud take well under 1 ms).
const PSD_WRITE_DEADLINE: Duration = Duration::from_millis(50);
/// Deadline of one CAN frame's write (SocketCAN queue or one SLCAN line): half the board's
/// default command timeout, so a stalled adapter is named before the board stops itself.
const CAN_WRITE_DEADLINE: Duration = Duration::from_millis(50);
/// Deadline of opening the CAN link (an SLCAN adapter answers three commands).
const CAN_OPEN_DEADLINE: Duration = Duration::from_secs(5);
/// How often a lost serial line or CAN link is tried again.
const REOPEN_EVERY: Duration = Duration::from_millis(200);

/// What the loop is told from outside.
#[derive(Debug)]
pub struct Controls {
    /// Becomes `true` to stop (orderly) and end the run.
    pub shutdown: watch::Receiver<bool>,
    /// Arm and start towards the config's `[goal]` as soon as the controller streams
    /// (`flowgate run --arm`, the demo). Otherwise the gateway waits, idle, for an operator.
    pub arm_at_start: bool,
    requests: mpsc::Receiver<Command>,
    sender: mpsc::Sender<Command>,
}

impl Controls {
    pub fn new(shutdown: watch::Receiver<bool>, arm_at_start: bool) -> Self {
        let (sender, requests) = mpsc::channel(control_socket::QUEUE);
        Self { shutdown, arm_at_start, requests, sender }
    }

    /// Where operator requests go (the control socket uses one too).
    pub fn sender(&self) -> mpsc::Sender<Command> {
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

/// The shell's I/O: the links, the telemetry queue, the timing summary.
struct Io {
    origin: Instant,
    port: String,
    psd: Option<tokio_serial::SerialStream>,
    /// The CAN link; `None` while it is lost and being reopened.
    can: Option<CanLink>,
    can_url: CanUrl,
    /// A reopen in flight: opening an SLCAN adapter waits on its answers, so it runs as its
    /// own task and the loop keeps ticking the core meanwhile.
    can_opening: Option<tokio::task::JoinHandle<Result<CanLink, CanError>>>,
    next_can_reopen: HostTime,
    recorder: Recorder,
    timing: Timing,
    progress: Option<watch::Sender<Progress>>,
    sample_period: Duration,
    next_reopen: HostTime,
    /// The low-latency mode's window, when it is on.
    spin: Option<SpinWindow>,
    /// Where the operator's stats window starts (`ctl stats --reset`); none: the run's start.
    stats_from: Option<Timing>,
    /// systemd's notification socket, when it started the gateway.
    notifier: Option<Notifier>,
    /// `/metrics` and the view's statistics: where the loop publishes its snapshot, and
    /// when it next does.
    metrics: Option<(watch::Sender<Arc<metrics::Snapshot>>, HostTime)>,
    /// The live view: where the loop publishes its scene, and when it next does.
    view: Option<(view::ViewPublisher, HostTime)>,
    /// Inputs handed to the core while recording (each record's `seq`).
    inputs_taken: Arc<AtomicU64>,
}

impl Io {
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
        if self.recorder.recording() {
            let seq = self.inputs_taken.fetch_add(1, Ordering::Relaxed);
            self.recorder.record(Record::Input(InputRecord { seq, at: now, input: RecordedInput::of(input) }));
        }
        core.handle(now, input)
    }

    fn lose_psd<K: StageClock>(&mut self, core: &mut Core<K>) {
        self.psd = None;
        let now = self.now();
        self.next_reopen = now + REOPEN_EVERY;
        self.feed(core, now, Input::PsdLost);
    }

    /// Carry out everything the core has asked for. A startup failure ends the run.
    async fn drain<K: StageClock>(&mut self, core: &mut Core<K>) -> Result<(), GatewayError> {
        while let Some(output) = core.poll() {
            match output {
                Output::Psd(packet) => {
                    if self.recorder.recording() {
                        self.recorder.record(Record::PsdSent { at: self.now(), packet });
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
                Output::Command { frame, mut record } => {
                    if let Some(spin) = &mut self.spin {
                        spin.frame(self.origin.into_std() + Duration::from_nanos(record.rx_ns));
                    }
                    let started = Instant::now();
                    let sent = self.send_can(frame).await;
                    record.written(started.elapsed().as_nanos() as u64, self.now(), self.sample_period);
                    self.timing.add(&record);
                    self.recorder.record(Record::Cycle(record));
                    if self.recorder.recording() {
                        self.recorder.record(Record::Scene(core.scene(HostTime::from_nanos(record.rx_ns))));
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
                Output::State { state, at } => {
                    tracing::info!("state: {state}");
                    if let Some(n) = &mut self.notifier {
                        n.status(&state.to_string());
                    }
                    self.recorder.record(Record::Event(telemetry::EventRecord {
                        at_s: at.secs(),
                        text: format!("state: {state}"),
                    }));
                    if let Some(tx) = &self.progress {
                        let p = core.progress();
                        tx.send_modify(|shown| *shown = Progress { e2e_us: shown.e2e_us, ..p });
                    }
                }
                Output::PollCanStatus => {
                    let Some(can) = &mut self.can else { continue };
                    let polled = match timeout(CAN_WRITE_DEADLINE, can.poll_status()).await {
                        Ok(r) => r,
                        Err(_) => Err(CanError::Timeout { what: "status poll" }),
                    };
                    if let Err(e) = polled {
                        tracing::error!("CAN status poll: {e}");
                        self.lose_can(core);
                    }
                }
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
            }
        }
        Ok(())
    }

    async fn write_psd(&mut self, packet: Packet) -> std::io::Result<()> {
        let Some(port) = &mut self.psd else { return Ok(()) };
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let n = packet.encode(&mut wire).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        timeout(PSD_WRITE_DEADLINE, port.write_all(&wire[..n])).await.map_err(|_| std::io::ErrorKind::TimedOut)?
    }

    async fn send_can(&mut self, frame: CanFrame) -> Result<(), CanError> {
        let Some(can) = &mut self.can else {
            if self.recorder.recording() {
                self.recorder.record(Record::CanUnwritten { at: self.now(), frame });
            }
            return Err(CanError::Closed);
        };
        let result = match timeout(CAN_WRITE_DEADLINE, can.send(frame)).await {
            Ok(r) => r,
            Err(_) => Err(CanError::Timeout { what: "write" }),
        };
        self.recorder.record(Record::Can(CanRecord { at_s: unix_now(), frame, sent: true }));
        if let Err(e) = &result {
            tracing::error!("CAN write: {e}");
        }
        result
    }

    /// An operator's request: the core decides, the peer gets the answer and the state.
    fn handle<K: StageClock>(&mut self, core: &mut Core<K>, cmd: Command) {
        let now = self.now();
        let Some(Answer { result, status }) = self.feed(core, now, Input::Request(&cmd.request)) else { return };
        let status = status.map(|mut status| {
            status.latency_us = (self.timing.cycles > 0).then(|| self.timing.e2e());
            if let Request::Stats { reset } = cmd.request {
                let window = match &self.stats_from {
                    Some(base) => self.timing.since(base),
                    None => self.timing.clone(),
                };
                status.latency_us = (window.cycles > 0).then(|| window.e2e());
                status.stages = Some(window.stages());
                if reset {
                    self.stats_from = Some(self.timing.clone());
                }
            }
            status
        });
        let text = match &result {
            Ok(()) => format!("{}: {:?} accepted", cmd.peer, cmd.request),
            Err(e) => format!("{}: {:?} refused: {e}", cmd.peer, cmd.request),
        };
        if !cmd.request.is_query() {
            match &result {
                Ok(()) => tracing::info!("{text}"),
                Err(_) => tracing::warn!("{text}"),
            }
            self.recorder.record(Record::Event(telemetry::EventRecord { at_s: now.secs(), text }));
        }
        let reply = match result {
            Ok(()) => Reply { ok: true, error: None, status },
            Err(e) => Reply { ok: false, error: Some(e.to_string()), status },
        };
        let _ = cmd.reply.send(reply);
    }

    /// Publish a metrics snapshot when one is due (about once a second: a copy of the
    /// counters and the latency histogram, never per cycle). Returns when the next is due.
    fn publish_metrics<K: StageClock>(&mut self, core: &Core<K>) -> HostTime {
        let now = self.now();
        let Some((tx, next)) = &mut self.metrics else { return HostTime::NEVER };
        if now >= *next {
            let mut counters = core.counters();
            counters.telemetry_dropped = self.recorder.dropped();
            tx.send_replace(Arc::new(metrics::Snapshot {
                state: core.state(),
                counters,
                e2e_ns: self.timing.e2e_histogram().clone(),
                deadline_misses: self.timing.deadline_misses,
                uptime_s: now.secs(),
                stops: stops_by_reason(core),
                view_frames_dropped: self.view.as_ref().map_or(0, |(v, _)| v.dropped.load(Ordering::Relaxed)),
            }));
            *next = now + metrics::PUBLISH_EVERY;
        }
        *next
    }

    /// Publish the scene to the live view when due (20 times a second: a copy, no
    /// allocation). Returns when the next is due.
    fn publish_view<K: StageClock>(&mut self, core: &Core<K>) -> HostTime {
        let now = self.now();
        let Some((publisher, next)) = &mut self.view else { return HostTime::NEVER };
        if now >= *next {
            let scene = core.scene(now);
            publisher.publish(view::ViewSnapshot { scene, state: core.state(), cycles: core.counters().cycles });
            *next = now + view::PUBLISH_EVERY;
        }
        *next
    }

    /// The CAN link failed: fault the core (named for the link), drop the link and reopen
    /// it every `REOPEN_EVERY`. The core stays faulted: an operator resets and arms again.
    fn lose_can<K: StageClock>(&mut self, core: &mut Core<K>) {
        let now = self.now();
        // A SocketCAN interface that went down or away is named as such, not as the link.
        let down = matches!(&self.can_url, CanUrl::SocketCan { interface } if crate::link::interface_down(interface));
        self.feed(core, now, if down { Input::Can(CanEvent::InterfaceDown) } else { Input::CanFailed });
        if self.can.take().is_some() {
            self.next_can_reopen = now + REOPEN_EVERY;
        }
    }

    /// The service is stopping in order (SIGINT, SIGTERM).
    fn stopping(&mut self) {
        if let Some(n) = &mut self.notifier {
            n.stopping();
        }
    }

    fn reopen_can(&mut self) {
        self.next_can_reopen = HostTime::NEVER;
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
            Err(e) => {
                tracing::debug!("CAN reopen: {e}");
                self.next_can_reopen = self.now() + REOPEN_EVERY;
            }
        }
    }

    fn reopen<K: StageClock>(&mut self, core: &mut Core<K>, path: &std::path::Path, baud: u32) {
        let now = self.now();
        self.next_reopen = now + REOPEN_EVERY;
        if let Ok(port) = open_serial(path, baud) {
            self.psd = Some(port);
            self.next_reopen = HostTime::NEVER;
            self.feed(core, now, Input::PsdConnected);
        }
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

/// The telemetry writer, when the rig asks for a directory of files or a recording.
#[allow(clippy::type_complexity)]
fn start_telemetry(
    rig: &Rig,
    origin: Instant,
    inputs_taken: Arc<AtomicU64>,
) -> Result<(Recorder, Option<tokio::task::JoinHandle<std::io::Result<telemetry::WrittenFiles>>>), GatewayError> {
    let interface = match &rig.can {
        CanUrl::SocketCan { interface } => interface.clone(),
        _ => "slcan0".to_string(),
    };
    let failed = |path: &std::path::Path| {
        let path = path.display().to_string();
        move |source| GatewayError::Telemetry { path, source }
    };
    let mcap = match &rig.telemetry.record {
        Some(path) => {
            // The host clock's zero on the Unix clock: MCAP log times are absolute.
            let origin_unix_ns = ((unix_now() * 1e9) as u64).saturating_sub(origin.elapsed().as_nanos() as u64);
            let setup = RecordingSetup {
                config_toml: rig.config.to_toml(),
                lane_half_width: match rig.control.planner.space {
                    crate::planner::Space::Lane { half_width } => Some(half_width),
                    crate::planner::Space::Free => None,
                },
                robot_radius: rig.control.robot_radius,
                origin_unix_ns,
            };
            Some(McapSink::create(path, setup).map_err(failed(path))?)
        }
        None => None,
    };
    let sinks = Sinks { dir: rig.telemetry.out_dir.clone().map(|d| (d, interface)), mcap };
    if sinks.is_empty() {
        return Ok((Recorder::disabled(), None));
    }
    let where_ = rig.telemetry.out_dir.clone().or(rig.telemetry.record.clone()).unwrap_or_default();
    let (recorder, writer) =
        telemetry::start_writer(sinks, rig.telemetry.queue, inputs_taken).map_err(failed(&where_))?;
    Ok((recorder, Some(writer)))
}

fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
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
    let _socket_task = match &rig.operator.socket {
        Some(path) => {
            let socket = ControlSocket::bind(path, rig.operator.group.as_deref())?;
            tracing::info!("control socket {}", path.display());
            Some(tokio::spawn(socket.serve(controls.sender())))
        }
        None => None,
    };
    let inputs_taken = Arc::new(AtomicU64::new(0));
    let (recorder, writer) = start_telemetry(&rig, origin, inputs_taken.clone())?;
    // The statistics snapshot feeds `/metrics` and the view's latency histogram.
    let stats = (rig.operator.metrics.is_some() || rig.operator.view.is_some())
        .then(|| watch::channel(Arc::new(metrics::Snapshot::empty())));
    if let (Some(addr), Some((_, rx))) = (rig.operator.metrics, &stats) {
        let listener = std::net::TcpListener::bind(addr)
            .and_then(|l| l.set_nonblocking(true).map(|()| l))
            .and_then(tokio::net::TcpListener::from_std)
            .map_err(|source| GatewayError::Metrics { addr, source })?;
        tracing::info!("metrics on http://{addr}/metrics");
        tokio::spawn(metrics::serve(listener, rx.clone()));
    }
    let view = match (rig.operator.view, &stats) {
        (Some(addr), Some((_, rx))) => {
            let setup = view::ViewSetup {
                planner: rig.control.planner,
                robot_radius: rig.control.robot_radius,
                lane_half_width: match rig.control.planner.space {
                    crate::planner::Space::Lane { half_width } => Some(half_width),
                    crate::planner::Space::Free => None,
                },
            };
            let publisher =
                view::start(addr, setup, rx.clone()).map_err(|source| GatewayError::View { addr, source })?;
            if !addr.ip().is_loopback() {
                tracing::warn!("the live view on {addr} is visible beyond this host (read-only)");
            }
            tracing::info!("live view on http://{addr}/");
            Some((publisher, HostTime::ZERO))
        }
        _ => None,
    };
    let metrics = stats.map(|(tx, _)| (tx, HostTime::ZERO));
    // On the loop's thread, once everything is open (the writer thread keeps the normal
    // policy) and before the first cycle.
    if !rig.realtime.is_empty() {
        realtime::apply(&rig.realtime)?;
        tracing::info!("real-time settings: {}", rig.realtime);
    }
    let (path, baud) = (rig.serial.port.clone(), rig.serial.baud);
    let mut io = Io {
        origin,
        port: path.display().to_string(),
        psd: Some(psd),
        can: Some(can),
        can_url: rig.can.clone(),
        can_opening: None,
        next_can_reopen: HostTime::NEVER,
        recorder,
        timing: Timing::default(),
        progress,
        sample_period: rig.sample_period,
        next_reopen: HostTime::NEVER,
        spin: rig.spin.map(SpinWindow::new),
        stats_from: None,
        notifier,
        metrics,
        view,
        inputs_taken,
    };
    let mut core = Core::new(rig, Monotonic(std::time::Instant::now()));
    if controls.arm_at_start {
        io.feed(&mut core, io.now(), Input::ArmAtStart);
    }
    io.feed(&mut core, io.now(), Input::PsdConnected);
    // One read is one input (a recording holds it whole).
    let mut read_buf = [0u8; PSD_CHUNK];
    let mut shutdown_seen = *controls.shutdown.borrow();
    if shutdown_seen {
        io.stopping();
        io.feed(&mut core, io.now(), Input::Shutdown);
    }
    loop {
        io.drain(&mut core).await?;
        if core.finished() {
            break;
        }
        let publish_at = io.publish_metrics(&core).min(io.publish_view(&core));
        // The watchdog is fed from here, the loop itself: a wedged loop starves it.
        let mut wake = io.instant(core.next_deadline().min(io.next_reopen).min(io.next_can_reopen).min(publish_at));
        if let Some(n) = &mut io.notifier {
            n.alive(std::time::Instant::now());
            wake = wake.min(n.next_due().map_or(wake, Instant::from_std));
        }
        let spin = io.spin.as_ref().map_or(Wait::Sleep, |s| s.wait(std::time::Instant::now()));
        tokio::select! {
            read = async {
                match io.psd.as_mut() {
                    Some(port) => port.read(&mut read_buf).await,
                    None => std::future::pending().await,
                }
            } => match read {
                Ok(n) if n > 0 => {
                    io.feed(&mut core, io.now(), Input::PsdBytes(&read_buf[..n]));
                }
                _ => {
                    tracing::error!("serial line lost; reconnecting");
                    io.lose_psd(&mut core);
                }
            },
            event = async {
                match io.can.as_mut() {
                    Some(can) => can.recv().await,
                    None => std::future::pending().await,
                }
            } => match event {
                Ok(event) => {
                    if let CanEvent::Frame(frame) = event {
                        io.recorder.record(Record::Can(CanRecord { at_s: unix_now(), frame, sent: false }));
                    }
                    io.feed(&mut core, io.now(), Input::Can(event));
                }
                Err(e) => {
                    tracing::error!("CAN link: {e}; reopening");
                    io.lose_can(&mut core);
                }
            },
            opened = async {
                match io.can_opening.as_mut() {
                    Some(task) => task.await,
                    None => std::future::pending().await,
                }
            } => {
                let opened = opened.unwrap_or(Err(CanError::Closed));
                io.can_opened(&mut core, opened);
            },
            _ = tokio::time::sleep_until(wake) => {
                let now = io.now();
                if io.psd.is_none() && now >= io.next_reopen {
                    io.reopen(&mut core, &path, baud);
                }
                if io.can.is_none() && io.can_opening.is_none() && now >= io.next_can_reopen {
                    io.reopen_can();
                }
                io.feed(&mut core, now, Input::Tick);
            }
            Some(cmd) = controls.requests.recv() => io.handle(&mut core, cmd),
            // Low-latency mode: poll for the frame due now instead of sleeping to it.
            () = spin.pause() => {}
            changed = controls.shutdown.changed(), if !shutdown_seen => {
                // A dropped sender is a shutdown too: nobody is left to ask for one.
                if changed.is_err() || *controls.shutdown.borrow() {
                    shutdown_seen = true;
                    io.stopping();
                    io.feed(&mut core, io.now(), Input::Shutdown);
                }
            }
        }
    }
    if let Some(task) = _socket_task {
        task.abort();
    }
    if let Some(task) = io.can_opening.take() {
        task.abort();
    }
    let dropped = io.recorder.dropped();
    let timing = std::mem::take(&mut io.timing);
    drop(io);
    let files = match writer {
        Some(w) => w.await.ok().and_then(Result::ok).unwrap_or_default(),
        None => telemetry::WrittenFiles::default(),
    };
    Ok(Report::new(&core, Some(&timing), dropped, files))
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
}
