//! flowgate as a ROS 2 node, beside the loop as the live view is: the loop hands it copies of
//! its scene through a watch channel and never waits on DDS; operator requests from ROS 2
//! go to the loop through the control socket's queue, so ROS 2 can do nothing the control
//! socket cannot, and gets the same words back.
//!
//! Publishes `/odom`, `/tf`, `~/obstacles`, `~/path` and `/diagnostics`; takes `/goal_pose`;
//! serves `~/arm`, `~/start`, `~/stop`, `~/reset` and `~/estop` (`std_srvs/srv/Trigger`;
//! `~/estop` stops every vehicle). Each of the rig's other vehicles has its own in its
//! namespace: `/<name>/odom`, `/<name>/goal_pose` and `/<name>/arm`, `start`, `stop`,
//! `reset`, `estop`; `/tf` carries its frame (`<name>/base_link`) and `~/obstacles` its
//! body, name and goal.
//! The DDS is RustDDS, through `ros2-client`: no ROS installation is needed.

pub mod convert;
pub mod msgs;

use std::sync::Arc;

use futures_util::StreamExt;
use ros2_client::{
    Context, MessageTypeName, Name, NodeName, NodeOptions, Publisher, QosProfile, Server, ServiceMapping,
    ServiceTypeName,
};
use tokio::sync::{oneshot, watch};

use super::control_socket::{Peer, RequestSender};
use super::metrics;
use super::view::{ViewSetup, ViewSnapshot};
use crate::config::{DiscoveryRange, Ros2Settings};
use crate::gateway::core::operator::Reply;
use crate::gateway::core::operator::Request;
use convert::Frames;
use msgs::{Time, TriggerRequest, TriggerResponse};

impl ros2_client::Message for msgs::Odometry {}
impl ros2_client::Message for msgs::TfMessage {}
impl ros2_client::Message for msgs::MarkerArray {}
impl ros2_client::Message for msgs::Path {}
impl ros2_client::Message for msgs::DiagnosticArray {}
impl ros2_client::Message for msgs::PoseStamped {}
impl ros2_client::Message for msgs::Twist {}
impl ros2_client::Message for msgs::TwistStamped {}
impl ros2_client::Message for TriggerRequest {}
impl ros2_client::Message for TriggerResponse {}

/// The node thread's nice value (below the loop's, as the live view's).
const ROS2_NICE: i32 = 10;

/// What the node needs of the rig.
#[derive(Debug, Clone)]
pub struct Ros2Setup {
    pub settings: Ros2Settings,
    pub view: ViewSetup,
    /// When the gateway started, s since the Unix epoch (the messages' stamps are Unix time).
    pub start_time_s: f64,
    /// The rig's other vehicles (`[[vehicles]]`), by name: each has its goal topic and
    /// services in its own namespace.
    pub vehicles: Vec<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    #[error("[ros2]: cannot join ROS 2 domain {domain}: {why}")]
    Join { domain: u16, why: String },
    #[error("[ros2]: {what}: {why}")]
    Create { what: String, why: String },
    #[error("[ros2]: cannot start the node's thread: {0}")]
    Thread(#[from] std::io::Error),
}

/// The loop's end of the node: publish a scene when one is due.
#[derive(Debug)]
pub struct Ros2Node {
    tx: watch::Sender<ViewSnapshot>,
    done: oneshot::Receiver<()>,
}

impl Ros2Node {
    pub fn publish(&self, snapshot: ViewSnapshot) {
        self.tx.send_replace(snapshot);
    }

    /// End the node (its last scene published), waiting at most 2 s.
    pub async fn close(self) {
        drop(self.tx);
        if tokio::time::timeout(std::time::Duration::from_secs(2), self.done).await.is_err() {
            tracing::debug!("the ROS 2 node did not close within 2 s");
        }
    }
}

/// The node's DDS side: made before its thread starts, so a failure is the caller's.
struct Endpoints {
    /// Held past the node: the participant must outlive every endpoint as it leaves.
    context: Context,
    node: ros2_client::Node,
    /// Where each scene goes.
    scene: SceneOut,
    diagnostics: Publisher<msgs::DiagnosticArray>,
    /// The goal topics: the robot's (`None`), then each vehicle's.
    goals: GoalTopics,
    /// An outside planner's velocity commands (`planner.method = "ros2"`).
    cmd_vel: Option<CmdVel>,
    /// Each service, for the robot (`None`; `estop` for every vehicle) or a vehicle.
    services: Services,
}

/// `cmd_vel`, plain or stamped.
enum CmdVel {
    Plain(ros2_client::Subscription<msgs::Twist>),
    Stamped(ros2_client::Subscription<msgs::TwistStamped>),
}

/// The commands a subscription brings, as twists (none without one).
fn twists(
    cmd_vel: &Option<CmdVel>,
) -> std::pin::Pin<Box<dyn futures_util::Stream<Item = Result<msgs::Twist, String>> + '_>> {
    let error = |e: &dyn std::fmt::Debug| format!("{e:?}");
    match cmd_vel {
        None => Box::pin(futures_util::stream::pending()),
        Some(CmdVel::Plain(s)) => Box::pin(s.async_stream().map(move |r| r.map(|(t, _)| t).map_err(|e| error(&e)))),
        Some(CmdVel::Stamped(s)) => {
            Box::pin(s.async_stream().map(move |r| r.map(|(t, _)| t.twist).map_err(|e| error(&e))))
        }
    }
}

/// The node's fully qualified name, the prefix of its private (`~/`) names.
fn node_fqn(s: &Ros2Settings) -> String {
    let ns = s.namespace.trim_end_matches('/');
    format!("{ns}/{}", s.node_name)
}

fn join(s: &Ros2Settings, vehicles: &[String]) -> Result<Endpoints, Ros2Error> {
    let mut participant = rustdds::DomainParticipantBuilder::new(s.domain_id);
    if s.discovery_range == DiscoveryRange::Localhost {
        participant = participant.with_only_networks([std::net::Ipv4Addr::LOCALHOST]);
    }
    let join_err = |e: &dyn std::fmt::Display| Ros2Error::Join { domain: s.domain_id, why: e.to_string() };
    let participant = participant.build().map_err(|e| join_err(&e))?;
    let context = Context::from_domain_participant(participant).map_err(|e| join_err(&e))?;
    let create = |what: &str| {
        let what = what.to_owned();
        move |e: &dyn std::fmt::Display| Ros2Error::Create { what: what.clone(), why: e.to_string() }
    };
    let name = NodeName::new(&s.namespace, &s.node_name).map_err(|e| create("node name")(&e))?;
    let mut node = context.new_node(name, NodeOptions::new().enable_rosout(true)).map_err(|e| create("node")(&e))?;
    let qos = QosProfile::publisher_default()
        .reliability_reliable(ros2_client::qos::WhenFull::DEFAULT)
        .durability(ros2_client::qos::Durability::Volatile)
        .history(ros2_client::qos::History::KeepLast { depth: usize::from(s.qos_depth) });
    let fqn = node_fqn(s);
    let topic = |ns: &str, base: &str, package: &str, kind: &str| {
        let name = Name::new(ns, base).map_err(|e| create(base)(&e))?;
        node.create_topic(&name, MessageTypeName::new(package, kind), &qos).map_err(|e| create(base)(&e))
    };
    let t_odom = topic("/", "odom", "nav_msgs", "Odometry")?;
    let t_tf = topic("/", "tf", "tf2_msgs", "TFMessage")?;
    let t_obstacles = topic(&fqn, "obstacles", "visualization_msgs", "MarkerArray")?;
    let t_path = topic(&fqn, "path", "nav_msgs", "Path")?;
    let t_diagnostics = topic("/", "diagnostics", "diagnostic_msgs", "DiagnosticArray")?;
    let t_vehicle_odoms: Vec<_> =
        vehicles.iter().map(|v| topic(&format!("/{v}"), "odom", "nav_msgs", "Odometry")).collect::<Result<_, _>>()?;
    let t_cmd_vel = match &s.cmd_vel {
        Some((name, stamped)) => {
            let kind = if *stamped { "TwistStamped" } else { "Twist" };
            let (ns, base) = name.rsplit_once('/').unwrap_or(("", name));
            Some(topic(if ns.is_empty() { "/" } else { ns }, base, "geometry_msgs", kind)?)
        }
        None => None,
    };
    let publisher_err = create("publisher");
    let odom = node.create_publisher(&t_odom, None).map_err(|e| publisher_err(&e))?;
    let tf = node.create_publisher(&t_tf, None).map_err(|e| publisher_err(&e))?;
    let obstacles = node.create_publisher(&t_obstacles, None).map_err(|e| publisher_err(&e))?;
    let path = node.create_publisher(&t_path, None).map_err(|e| publisher_err(&e))?;
    let diagnostics = node.create_publisher(&t_diagnostics, None).map_err(|e| publisher_err(&e))?;
    let cmd_vel = match (&s.cmd_vel, t_cmd_vel) {
        (Some((name, stamped)), Some(t)) => {
            let failed = |e: &dyn std::fmt::Display| create(name)(e);
            Some(if *stamped {
                CmdVel::Stamped(node.create_subscription(&t, None).map_err(|e| failed(&e))?)
            } else {
                CmdVel::Plain(node.create_subscription(&t, None).map_err(|e| failed(&e))?)
            })
        }
        _ => None,
    };
    let mut vehicle_odoms = Vec::with_capacity(vehicles.len());
    for t in &t_vehicle_odoms {
        vehicle_odoms.push(node.create_publisher(t, None).map_err(|e| publisher_err(&e))?);
    }
    let (goals, services) = operator_endpoints(&mut node, &qos, &fqn, vehicles)?;
    let scene = SceneOut { odom, vehicle_odoms, tf, obstacles, path };
    Ok(Endpoints { context, node, scene, diagnostics, goals, cmd_vel, services })
}

type GoalTopics = Vec<(Option<String>, ros2_client::Subscription<msgs::PoseStamped>)>;
type Services = Vec<(Option<String>, Request, Server<TriggerRequest, TriggerResponse>)>;

/// The goal topic and the services of the robot (under the node, `~/`) and of each vehicle
/// (in its own namespace).
fn operator_endpoints(
    node: &mut ros2_client::Node,
    qos: &QosProfile,
    fqn: &str,
    vehicles: &[String],
) -> Result<(GoalTopics, Services), Ros2Error> {
    let create = |what: &str| {
        let what = what.to_owned();
        move |e: &dyn std::fmt::Display| Ros2Error::Create { what: what.clone(), why: e.to_string() }
    };
    let owners = std::iter::once((None, fqn.to_string(), "/".to_string()))
        .chain(vehicles.iter().map(|v| (Some(v.clone()), format!("/{v}"), format!("/{v}"))));
    let (mut goals, mut services) = (Vec::new(), Vec::new());
    for (vehicle, service_ns, goal_ns) in owners {
        let what = format!("{}/goal_pose", goal_ns.trim_end_matches('/'));
        let failed = |e: &dyn std::fmt::Display| create(&what)(e);
        let name = Name::new(&goal_ns, "goal_pose").map_err(|e| failed(&e))?;
        let kind = MessageTypeName::new("geometry_msgs", "PoseStamped");
        let t_goal = node.create_topic(&name, kind, qos).map_err(|e| failed(&e))?;
        let goal = node.create_subscription(&t_goal, None).map_err(|e| failed(&e))?;
        goals.push((vehicle.clone(), goal));
        for (request, base) in [
            (Request::Arm, "arm"),
            (Request::Start, "start"),
            (Request::Stop, "stop"),
            (Request::Reset, "reset"),
            (Request::EStop, "estop"),
        ] {
            let name = Name::new(&service_ns, base).map_err(|e| create(base)(&e))?;
            let kind = ServiceTypeName::new("std_srvs", "Trigger");
            let server = node
                .create_server(ServiceMapping::Enhanced, &name, &kind, qos.clone(), qos.clone())
                .map_err(|e| create(&format!("{service_ns}/{base}"))(&e))?;
            services.push((vehicle.clone(), request, server));
        }
    }
    Ok((goals, services))
}

/// Join the ROS 2 domain and start the node's thread. It ends when the returned node is
/// closed or dropped.
pub fn start(
    setup: Ros2Setup,
    stats: watch::Receiver<Arc<metrics::Snapshot>>,
    requests: RequestSender,
) -> Result<Ros2Node, Ros2Error> {
    let endpoints = join(&setup.settings, &setup.vehicles)?;
    let (tx, rx) = watch::channel(ViewSnapshot::default());
    let (done_tx, done) = oneshot::channel();
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let s = &setup.settings;
    tracing::info!(
        "ROS 2: node {} in domain {} ({} discovery)",
        node_fqn(s),
        s.domain_id,
        s.discovery_range.ros_name()
    );
    std::thread::Builder::new().name("flowgate-ros2".into()).spawn(move || {
        if let Err(e) = rustix::process::setpriority_process(None, ROS2_NICE) {
            tracing::debug!("ROS 2 thread priority: {e}");
        }
        runtime.block_on(serve(endpoints, setup, rx, stats, requests));
        let _ = done_tx.send(());
    })?;
    Ok(Ros2Node { tx, done })
}

/// A reply as a Trigger's response: the refusal's words, or the state now (of `vehicle`,
/// the robot's without one).
fn trigger_response(reply: Reply, vehicle: Option<&str>) -> TriggerResponse {
    let message = match (&reply.error, &reply.status, vehicle) {
        (Some(e), _, _) => e.clone(),
        (None, Some(status), Some(name)) => {
            status.vehicles.iter().find(|v| v.name == name).map_or("ok".into(), |v| v.state.to_string())
        }
        (None, Some(status), None) => status.state.to_string(),
        (None, None, _) => "ok".into(),
    };
    TriggerResponse { success: reply.ok, message }
}

/// What the node keeps between events.
struct NodeState {
    setup: Ros2Setup,
    frames: Frames,
    hardware_id: String,
    /// The last request from ROS 2 the gateway refused, in the control socket's words.
    last_refusal: Option<String>,
}

impl NodeState {
    fn stamp(&self, at: crate::time::HostTime) -> Time {
        Time::from_secs(self.setup.start_time_s + at.secs())
    }
}

/// The node's loop: publish each scene and statistics the loop hands over, answer goals and
/// services, until the loop's end of the scene channel is gone.
async fn serve(
    e: Endpoints,
    setup: Ros2Setup,
    mut scenes: watch::Receiver<ViewSnapshot>,
    mut stats: watch::Receiver<Arc<metrics::Snapshot>>,
    requests: RequestSender,
) {
    let Endpoints { context, mut node, scene: scene_out, diagnostics, goals, cmd_vel, services } = e;
    let frames = Frames { floor: setup.settings.floor_frame.clone(), base: setup.settings.base_frame.clone() };
    let hardware_id = node_fqn(&setup.settings);
    let mut state = NodeState { setup, frames, hardware_id, last_refusal: None };
    let spin = match node.spinner() {
        Ok(spinner) => spinner.spin(),
        Err(e) => return tracing::warn!("ROS 2: the node's spinner: {e:?}"),
    };
    let mut spin = Box::pin(spin);
    let mut goal_poses = futures_util::stream::select_all(
        goals.iter().map(|(vehicle, goal)| Box::pin(goal.async_stream().map(move |r| (vehicle, r)))),
    );
    let mut commands = twists(&cmd_vel);
    let mut calls =
        futures_util::stream::select_all(services.iter().map(|(vehicle, request, server)| {
            server.receive_request_stream().map(move |r| (vehicle, request, server, r))
        }));
    let mut stats_open = true;
    loop {
        tokio::select! {
            _ = &mut spin => tracing::debug!("ROS 2: the node's spinner ended"),
            changed = scenes.changed() => {
                if changed.is_err() {
                    break;
                }
                let snapshot = *scenes.borrow_and_update();
                publish_scene(&state, &snapshot, &scene_out);
            }
            changed = stats.changed(), if stats_open => {
                if changed.is_err() {
                    stats_open = false;
                    continue;
                }
                let snapshot = stats.borrow_and_update().clone();
                let stamp = Time::from_secs(state.setup.start_time_s + snapshot.uptime_s);
                let msg = convert::diagnostics(&snapshot, state.last_refusal.as_deref(), stamp, &state.hardware_id);
                if let Err(e) = diagnostics.publish(msg) {
                    tracing::debug!("ROS 2: /diagnostics: {e:?}");
                }
            }
            Some(received) = commands.next() => match received {
                Ok(twist) => take_command(&mut state, &requests, twist).await,
                Err(e) => tracing::warn!("ROS 2: cmd_vel: {e}"),
            },
            Some((vehicle, received)) = goal_poses.next() => match received {
                Ok((pose, _)) => take_goal(&mut state, &requests, vehicle.clone(), pose).await,
                Err(e) => tracing::warn!("ROS 2: a goal pose: {e:?}"),
            },
            Some((vehicle, request, server, received)) = calls.next() => match received {
                Ok((id, _)) => {
                    let reply = requests.ask_for(vehicle.clone(), request.clone(), Peer::Ros2).await;
                    if let Some(e) = &reply.error {
                        state.last_refusal = Some(e.clone());
                    }
                    if let Err(e) = server.send_response(id, trigger_response(reply, vehicle.as_deref())) {
                        tracing::warn!("ROS 2: answering {request:?}: {e:?}");
                    }
                }
                Err(e) => tracing::warn!("ROS 2: a {request:?} call: {e:?}"),
            },
        }
    }
    // Leave the graph in order while the participant still runs: our endpoints, the node
    // (which tells the spinner to stop), the spinner's own endpoints, the participant last.
    drop(calls);
    drop(goal_poses);
    drop(commands);
    drop((services, goals, cmd_vel, scene_out, diagnostics));
    drop(node);
    drop(spin);
    drop(context);
}

/// What a scene is published on.
struct SceneOut {
    odom: Publisher<msgs::Odometry>,
    /// Each other vehicle's `/<name>/odom`, in the rig's order.
    vehicle_odoms: Vec<Publisher<msgs::Odometry>>,
    tf: Publisher<msgs::TfMessage>,
    obstacles: Publisher<msgs::MarkerArray>,
    path: Publisher<msgs::Path>,
}

/// `/odom`, `/tf`, `~/obstacles` and `~/path` for one scene (nothing before a pose), and each
/// other vehicle's `/<name>/odom` (nothing before the camera shows it).
fn publish_scene(state: &NodeState, snapshot: &ViewSnapshot, out: &SceneOut) {
    let (s, fleet) = (&snapshot.scene, &snapshot.fleet);
    let stamp = state.stamp(s.at);
    let (frames, view) = (&state.frames, &state.setup.view);
    let has_pose = s.pose != [0.0; 3] || s.goal != [0.0; 2];
    let failed = |topic: &str, e: &dyn std::fmt::Debug| tracing::debug!("ROS 2: {topic}: {e:?}");
    if has_pose {
        out.odom.publish(convert::odometry(s, stamp, frames)).unwrap_or_else(|e| failed("/odom", &e));
        let mut tf = convert::transform(s, stamp, frames);
        tf.transforms.extend(convert::vehicle_transforms(fleet, &view.vehicles, stamp, frames));
        out.tf.publish(tf).unwrap_or_else(|e| failed("/tf", &e));
        out.path.publish(convert::path(s, fleet, view, stamp, frames)).unwrap_or_else(|e| failed("~/path", &e));
    }
    for ((label, v), odom) in view.vehicles.iter().zip(fleet.vehicles()).zip(&out.vehicle_odoms) {
        if v.seen {
            let message = convert::vehicle_odometry(label, v, stamp, frames);
            odom.publish(message).unwrap_or_else(|e| failed(&convert::vehicle_odometry_topic(&label.name), &e));
        }
    }
    let markers = convert::obstacles(s, fleet, view, stamp, frames);
    out.obstacles.publish(markers).unwrap_or_else(|e| failed("~/obstacles", &e));
}

/// A velocity command from `cmd_vel`: forward speed and yaw rate, to the loop as a `drive`
/// request (its other components a differential-drive robot cannot follow).
async fn take_command(state: &mut NodeState, requests: &RequestSender, twist: msgs::Twist) {
    let reply = requests.ask(Request::Drive { v: twist.linear.x, w: twist.angular.z }, Peer::Ros2).await;
    if let Some(e) = reply.error {
        state.last_refusal = Some(e);
    }
}

/// A goal from `/goal_pose` (RViz's "2D Goal Pose"; `/<name>/goal_pose` for `vehicle`),
/// checked by the loop as `ctl goal` is; a goal in another frame is refused here.
async fn take_goal(state: &mut NodeState, requests: &RequestSender, vehicle: Option<String>, goal: msgs::PoseStamped) {
    let frame = &goal.header.frame_id;
    let (x, y) = (goal.pose.position.x, goal.pose.position.y);
    if !frame.is_empty() && *frame != state.frames.floor {
        let text = format!("goal in frame `{frame}`: flowgate takes goals in `{}`", state.frames.floor);
        tracing::warn!("ROS 2: {text}");
        state.last_refusal = Some(text);
        return;
    }
    let goals = vec![crate::config::Goal { position: [x, y], tolerance: crate::config::default_tolerance() }];
    let reply = requests.ask_for(vehicle, Request::Goal { goals }, Peer::Ros2).await;
    if let Some(e) = reply.error {
        state.last_refusal = Some(e);
    }
}
