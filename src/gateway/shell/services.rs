//! The services beside the loop, started before it and stopped after it: the control
//! socket, the telemetry writer (text files and the MCAP recording), `/metrics` and the
//! live view. None of them is on the per-sample path: the loop hands them copies through
//! bounded queues and watch channels, and never waits on them.

use std::path::Path;
use std::sync::atomic::AtomicU64;
use std::sync::Arc;

use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::control_socket::{ClientCounts, ControlSocket, RequestSender};
use super::foxglove::Live;
use super::recording::{McapSink, RecordingSetup};
use super::telemetry::{self, Recorder, Sinks, WrittenFiles};
use super::{metrics, unix_now, view, GatewayError};
use crate::config::CanUrl;
use crate::config::Rig;
use crate::gateway::core::scene::VehicleLabel;
use crate::gateway::core::{Core, StageClock};
use crate::time::HostTime;

/// The services of one run.
pub(super) struct Services {
    /// Where the loop queues its records (a disabled one when nothing is written).
    pub recorder: Recorder,
    /// Inputs handed to the core while recording (each record's `seq`).
    pub inputs_taken: Arc<AtomicU64>,
    /// `/metrics` and the view's statistics: where the loop publishes its snapshot, and
    /// when it next does.
    pub metrics: Option<(watch::Sender<Arc<metrics::Snapshot>>, HostTime)>,
    /// The live view: where the loop publishes its scene, and when it next does.
    pub view: Option<(view::ViewPublisher, HostTime)>,
    /// The ROS 2 node: where the loop publishes its scene, when it next does, and how often.
    #[cfg(feature = "ros2")]
    pub ros2: Option<(super::ros2::Ros2Node, HostTime, std::time::Duration)>,
    /// A fleet's recording: when it next takes a scene of its own (the robot's cycles give it
    /// theirs, but the other vehicles drive while the robot stands too).
    pub fleet_scene: Option<HostTime>,
    /// When the gateway started, s since the Unix epoch.
    pub start_time_s: f64,
    /// What the control socket did to its clients.
    pub control_clients: Arc<ClientCounts>,
    writer: Option<JoinHandle<std::io::Result<WrittenFiles>>>,
    socket: Option<JoinHandle<()>>,
}

impl Services {
    /// Start what the rig's config asks for; operator requests go to `requests`.
    pub async fn start(rig: &Rig, origin: Instant, requests: RequestSender) -> Result<Self, GatewayError> {
        #[cfg(feature = "ros2")]
        let ros2_requests = requests.clone();
        let control_clients = Arc::new(ClientCounts::default());
        let socket = match &rig.operator.socket {
            Some(path) => {
                let socket = ControlSocket::bind(path, rig.operator.group.as_deref())?;
                tracing::info!("control socket {}", path.display());
                Some(tokio::spawn(socket.serve(requests, control_clients.clone())))
            }
            None => None,
        };
        let start_time_s = unix_now() - origin.elapsed().as_secs_f64();
        let inputs_taken = Arc::new(AtomicU64::new(0));
        let live = match rig.operator.foxglove {
            Some(addr) => Some(start_foxglove(addr).await?),
            None => None,
        };
        let (recorder, writer) = start_telemetry(rig, origin, inputs_taken.clone(), live)?;
        // The statistics snapshot feeds `/metrics` and the view's latency histogram.
        let stats = (rig.operator.metrics.is_some() || rig.operator.view.is_some() || rig.ros2.is_some())
            .then(|| watch::channel(Arc::new(metrics::Snapshot::empty(start_time_s))));
        if let (Some(addr), Some((_, rx))) = (rig.operator.metrics, &stats) {
            let listener = std::net::TcpListener::bind(addr)
                .and_then(|l| l.set_nonblocking(true).map(|()| l))
                .and_then(tokio::net::TcpListener::from_std)
                .map_err(|source| GatewayError::Metrics { addr, source })?;
            if !addr.ip().is_loopback() {
                tracing::warn!("/metrics on {addr} is visible beyond this host (read-only)");
            }
            tracing::info!("metrics on http://{addr}/metrics");
            tokio::spawn(metrics::serve(listener, rx.clone()));
        }
        let view = match (rig.operator.view, &stats) {
            (Some(addr), Some((_, rx))) => Some((start_view(rig, addr, rx.clone())?, HostTime::ZERO)),
            _ => None,
        };
        #[cfg(feature = "ros2")]
        let ros2 = match (&rig.ros2, &stats) {
            (Some(config), Some((_, rx))) => Some(start_ros2(rig, config, start_time_s, rx.clone(), ros2_requests)?),
            _ => None,
        };
        #[cfg(not(feature = "ros2"))]
        if rig.ros2.is_some() {
            return Err(GatewayError::Ros2Missing);
        }
        let metrics = stats.map(|(tx, _)| (tx, HostTime::ZERO));
        let fleet_scene = (recorder.recording() && !rig.vehicles.is_empty()).then_some(HostTime::ZERO);
        Ok(Self {
            recorder,
            inputs_taken,
            metrics,
            view,
            #[cfg(feature = "ros2")]
            ros2,
            fleet_scene,
            start_time_s,
            control_clients,
            writer,
            socket,
        })
    }

    /// Publish the scene where it is due: to the live view (20 times a second: a copy, no
    /// allocation), to the ROS 2 node (at its rate), and in a fleet to the recording (at its
    /// display rate). Returns when the next is due.
    pub fn publish_scene<K: StageClock>(&mut self, core: &Core<K>, now: HostTime) -> HostTime {
        let snapshot = || view::ViewSnapshot {
            scene: core.scene(now),
            fleet: core.fleet_scene().unwrap_or_default(),
            state: core.state(),
            cycles: core.counters().cycles,
        };
        let mut next_due = HostTime::NEVER;
        #[cfg(feature = "ros2")]
        if let Some((node, next, every)) = &mut self.ros2 {
            if now >= *next {
                node.publish(snapshot());
                *next = now + *every;
            }
            next_due = next_due.min(*next);
        }
        if let Some((publisher, next)) = &mut self.view {
            if now >= *next {
                publisher.publish(snapshot());
                *next = now + view::PUBLISH_EVERY;
            }
            next_due = next_due.min(*next);
        }
        if let Some(next) = &mut self.fleet_scene {
            if now >= *next {
                self.recorder.scene(core.scene(now), core.fleet_scene());
                *next = now + std::time::Duration::from_nanos(super::recording::ARENA_EVERY_NS);
            }
            next_due = next_due.min(*next);
        }
        next_due
    }

    /// Every scene is due now (the run's end publishes its last).
    pub fn scenes_due_now(&mut self) {
        if let Some((_, next)) = &mut self.view {
            *next = HostTime::ZERO;
        }
        #[cfg(feature = "ros2")]
        if let Some((_, next, _)) = &mut self.ros2 {
            *next = HostTime::ZERO;
        }
        if let Some(next) = &mut self.fleet_scene {
            *next = HostTime::ZERO;
        }
    }

    /// Stop the services and wait for the telemetry writer to finish its files.
    pub async fn finish(mut self) -> WrittenFiles {
        if let Some(task) = self.socket.take() {
            task.abort();
        }
        // The view's last frame, marked ended, goes out before the process can end.
        if let Some((view, _)) = self.view.take() {
            view.close().await;
        }
        #[cfg(feature = "ros2")]
        if let Some((node, ..)) = self.ros2.take() {
            node.close().await;
        }
        // Dropping the recorder closes the writer's queue: it writes what is left and ends.
        drop(self.recorder);
        match self.writer {
            Some(w) => w.await.ok().and_then(Result::ok).unwrap_or_default(),
            None => WrittenFiles::default(),
        }
    }
}

use view::lane_half_width;

/// Join ROS 2 as `[ros2]` and its environment say.
#[cfg(feature = "ros2")]
fn start_ros2(
    rig: &Rig,
    config: &crate::config::Ros2Section,
    start_time_s: f64,
    stats: watch::Receiver<Arc<metrics::Snapshot>>,
    requests: RequestSender,
) -> Result<(super::ros2::Ros2Node, HostTime, std::time::Duration), GatewayError> {
    let mut settings = config.resolve(|name| std::env::var(name).ok()).map_err(GatewayError::Ros2Section)?;
    if rig.config.planner.method == crate::config::PlannerMethod::Ros2 {
        settings.cmd_vel = Some((config.cmd_vel.clone(), config.cmd_vel_stamped));
    }
    let every = settings.publish_every;
    let vehicles = rig.vehicles.iter().map(|v| v.name.clone()).collect();
    let setup = super::ros2::Ros2Setup { settings, view: view::ViewSetup::of(rig), start_time_s, vehicles };
    let node = super::ros2::start(setup, stats, requests)?;
    Ok((node, HostTime::ZERO, every))
}

fn start_view(
    rig: &Rig,
    addr: std::net::SocketAddr,
    stats: watch::Receiver<Arc<metrics::Snapshot>>,
) -> Result<view::ViewPublisher, GatewayError> {
    let publisher =
        view::start(addr, view::ViewSetup::of(rig), stats).map_err(|source| GatewayError::View { addr, source })?;
    if !addr.ip().is_loopback() {
        tracing::warn!("the live view on {addr} is visible beyond this host (read-only)");
    }
    tracing::info!("live view on http://{addr}/");
    Ok(publisher)
}

async fn start_foxglove(addr: std::net::SocketAddr) -> Result<Live, GatewayError> {
    let live = Live::start(addr).await.map_err(|source| GatewayError::Foxglove { addr, source })?;
    if !addr.ip().is_loopback() {
        tracing::warn!("Foxglove live on {addr} is visible beyond this host (read-only)");
    }
    tracing::info!("Foxglove live on ws://{}:{}", addr.ip(), live.port());
    Ok(live)
}

/// The telemetry writer, when the rig asks for a directory of files, a recording or
/// Foxglove live.
#[allow(clippy::type_complexity)]
fn start_telemetry(
    rig: &Rig,
    origin: Instant,
    inputs_taken: Arc<AtomicU64>,
    live: Option<Live>,
) -> Result<(Recorder, Option<JoinHandle<std::io::Result<WrittenFiles>>>), GatewayError> {
    let interface = match &rig.can {
        CanUrl::SocketCan { interface } => interface.clone(),
        _ => "slcan0".to_string(),
    };
    let failed = |path: &std::path::Path| {
        let path = path.display().to_string();
        move |source| GatewayError::Telemetry { path, source }
    };
    let mcap = match (&rig.telemetry.record, live) {
        (None, None) => None,
        (path, live) => {
            // The host clock's zero on the Unix clock: MCAP log times are absolute.
            let origin_unix_ns = ((unix_now() * 1e9) as u64).saturating_sub(origin.elapsed().as_nanos() as u64);
            let setup = RecordingSetup {
                config_toml: rig.config.to_toml(),
                lane_half_width: lane_half_width(rig),
                room: rig.room_outline(),
                robot_radius: rig.control.robot_radius,
                vehicles: VehicleLabel::of_rig(rig),
                origin_unix_ns,
                compression: rig.telemetry.record_compression,
            };
            let file = path.as_deref();
            Some(McapSink::create(file, setup, live).map_err(failed(file.unwrap_or(Path::new("foxglove"))))?)
        }
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
