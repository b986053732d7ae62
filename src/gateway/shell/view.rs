//! The live view (`[operator] view = ADDR`, `flowgate run --view ADDR`): an operator's
//! screen. It draws the arena as the gateway sees it, on axes in metres, and gives the
//! numbers beside it (pose, distance to the goal, clearance, the robot's and each obstacle's
//! speed, the state with its reason), updated by server-sent events. When the run ends it
//! sends a last frame marked `ended` and the page keeps showing it.
//!
//! The loop only publishes: about 20 times a second it puts a copy of its scene (a
//! [`SceneRecord`], no allocation) into a `watch` channel. Everything else runs on a thread
//! of its own, with its own runtime: a renderer turns the latest scene into a frame (JSON:
//! the lane's lines and the room's walls, static obstacles and view's edge, goal, obstacles
//! with planning circles and velocities, the robot and its path, a fleet's other vehicles
//! (each named, with its path, goal and state), streamlines of the field, the state, the latency histogram) ten times a second, and the
//! server hands the latest frame to each client. A client too slow for every frame skips to
//! the latest; the frames it skipped are counted (`dropped` in each frame, and in
//! `/metrics`). A client that takes a write over two seconds is dropped. Nothing a client
//! does reaches the loop, and the page has no way to command anything.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use crate::Point;
use serde_json::json;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;

use super::http::{self, Asked};
use super::metrics;
use crate::gateway::core::scene::{FleetScene, SceneRecord, VehicleLabel};
use crate::gateway::core::State;
use crate::planner::room::{OutlineKind, Room, RoomShape};
use crate::planner::{streamlines, Field, PlanObstacle, Planner, PlannerConfig, MAX_OBSTACLES};
use crate::time::HostTime;

/// How often the loop publishes its scene.
pub const PUBLISH_EVERY: Duration = Duration::from_millis(50);
/// How often the renderer makes a frame.
const RENDER_EVERY: Duration = Duration::from_millis(100);
/// The longest a client may take to take one frame (or to send its request).
const CLIENT_DEADLINE: Duration = Duration::from_secs(2);
/// Clients served at once; more are told to come back later.
const MAX_CLIENTS: usize = 8;
/// Path points kept (a point every 5 mm of travel; the oldest go first).
const MAX_PATH: usize = 4000;

/// Rendered scenes the robot's speed is reckoned over: half a second's worth at
/// [`RENDER_EVERY`].
const SPEED_OVER: usize = 6;
/// How long closing the view waits for its thread: every client connected takes the last
/// frame within its own deadline ([`CLIENT_DEADLINE`]), or is dropped.
const CLOSE_DEADLINE: Duration = Duration::from_secs(3);

/// The view thread's nice value (the loop keeps the process's, 0 or SCHED_FIFO).
const VIEW_NICE: i32 = 10;

const PAGE: &str = include_str!("view.html");

/// What the loop publishes.
#[derive(Debug, Clone, Copy, Default)]
pub struct ViewSnapshot {
    pub scene: SceneRecord,
    /// A fleet's other vehicles.
    pub fleet: FleetScene,
    pub state: State,
    pub cycles: u64,
}

/// What the renderer needs of the rig.
#[derive(Debug, Clone)]
pub struct ViewSetup {
    pub planner: PlannerConfig,
    pub robot_radius: f64,
    pub lane_half_width: Option<f64>,
    /// The room the planner keeps to, if any: its field streamed.
    pub room: Option<Arc<Room>>,
    /// The room as drawn ([`Rig::room_outline`](crate::config::Rig::room_outline)).
    pub outline: Option<RoomShape>,
    /// A fleet's other vehicles, in order.
    pub vehicles: Vec<VehicleLabel>,
}

impl ViewSetup {
    /// What `rig` gives the drawing (and the ROS 2 node's markers and path).
    pub fn of(rig: &crate::config::Rig) -> Self {
        Self {
            planner: rig.control.planner,
            robot_radius: rig.control.robot_radius,
            lane_half_width: lane_half_width(rig),
            room: rig.control.room.clone(),
            outline: rig.room_outline(),
            vehicles: VehicleLabel::of_rig(rig),
        }
    }
}

/// The lane's half-width, when the planner's space is a lane.
pub fn lane_half_width(rig: &crate::config::Rig) -> Option<f64> {
    match rig.control.planner.space {
        crate::planner::Space::Lane { half_width } => Some(half_width),
        crate::planner::Space::Free => None,
    }
}

/// Where a vehicle has been: a point every 5 mm of travel, at most [`MAX_PATH`] (the
/// oldest go first).
#[derive(Debug, Default)]
struct Trail(std::collections::VecDeque<[f64; 2]>);

impl Trail {
    fn extend_to(&mut self, [x, y]: [f64; 2]) {
        if self.0.back().is_none_or(|&[px, py]| (x - px).hypot(y - py) >= 0.005) {
            if self.0.len() == MAX_PATH {
                self.0.pop_front();
            }
            self.0.push_back([x, y]);
        }
    }

    fn points(&self) -> Vec<[f64; 2]> {
        self.0.iter().copied().collect()
    }
}

/// One frame for the page.
#[derive(Debug, Clone, Default)]
struct Frame {
    seq: u64,
    json: Arc<str>,
}

/// The loop's end: publish a scene when one is due.
#[derive(Debug)]
pub struct ViewPublisher {
    tx: watch::Sender<ViewSnapshot>,
    /// Frames the view's clients skipped (for `/metrics`).
    pub dropped: Arc<AtomicU64>,
    /// Said by the view's thread once its last frame is out.
    done: tokio::sync::oneshot::Receiver<()>,
}

impl ViewPublisher {
    pub fn publish(&self, snapshot: ViewSnapshot) {
        self.tx.send_replace(snapshot);
    }

    /// End the view: it sends its clients a last frame, marked `ended`, of the last scene
    /// published, and waits until each has taken it (each within its deadline, 2 s), at most
    /// `CLOSE_DEADLINE` (3 s) in all.
    pub async fn close(self) {
        drop(self.tx);
        if tokio::time::timeout(CLOSE_DEADLINE, self.done).await.is_err() {
            tracing::debug!("the live view did not close within {CLOSE_DEADLINE:?}");
        }
    }
}

/// Bind `addr` and start the view's thread. It ends when the publisher is dropped.
pub fn start(
    addr: std::net::SocketAddr,
    setup: ViewSetup,
    stats: watch::Receiver<Arc<metrics::Snapshot>>,
) -> std::io::Result<ViewPublisher> {
    let listener = std::net::TcpListener::bind(addr)?;
    listener.set_nonblocking(true)?;
    let (tx, rx) = watch::channel(ViewSnapshot::default());
    let (done_tx, done) = tokio::sync::oneshot::channel();
    let dropped = Arc::new(AtomicU64::new(0));
    let counted = dropped.clone();
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    std::thread::Builder::new().name("flowgate-view".into()).spawn(move || {
        // Below the loop's priority (on Linux this sets the calling thread's nice value):
        // where the loop shares a core with it, the view waits, not the loop.
        if let Err(e) = rustix::process::setpriority_process(None, VIEW_NICE) {
            tracing::debug!("view thread priority: {e}");
        }
        runtime.block_on(async move {
            let Ok(listener) = TcpListener::from_std(listener) else { return };
            let (frames_tx, frames_rx) = watch::channel(Frame::default());
            // Each client holds a clone of `serving` until it is done: once the last frame is
            // out and no new client is taken, the channel closes when the last one is served.
            let (serving, mut all_served) = tokio::sync::mpsc::channel::<()>(1);
            let accepting = tokio::spawn(serve(listener, frames_rx, counted, serving));
            render(rx, stats, setup, frames_tx).await;
            accepting.abort();
            let _ = accepting.await;
            let _ = tokio::time::timeout(CLOSE_DEADLINE, all_served.recv()).await;
        });
        let _ = done_tx.send(());
    })?;
    Ok(ViewPublisher { tx, dropped, done })
}

/// Make a frame from each new scene, at most every [`RENDER_EVERY`]; ends when the loop's
/// publisher is gone.
async fn render(
    mut scenes: watch::Receiver<ViewSnapshot>,
    stats: watch::Receiver<Arc<metrics::Snapshot>>,
    setup: ViewSetup,
    frames: watch::Sender<Frame>,
) {
    let mut path = Trail::default();
    let mut trails: Vec<Trail> = setup.vehicles.iter().map(|_| Trail::default()).collect();
    let mut seq = 0;
    let mut last: Option<ViewSnapshot> = None;
    let mut speed = None;
    // The robot's speed over the last half second: a pose differenced over 0.1 s carries
    // the camera's millimetre of noise as a centimetre a second or more.
    let mut recent: std::collections::VecDeque<(HostTime, [f64; 3])> =
        std::collections::VecDeque::with_capacity(SPEED_OVER);
    loop {
        if scenes.changed().await.is_err() {
            // The run is over: its last scene once more, marked so, for the page to keep.
            if let Some(snapshot) = last {
                seq += 1;
                let paths = Paths { robot: path.points(), vehicles: trails.iter().map(Trail::points).collect() };
                let json = frame_json(&snapshot, &setup, &paths, &stats.borrow(), seq, speed, true);
                frames.send_replace(Frame { seq, json: json.into() });
            }
            return;
        }
        let snapshot = *scenes.borrow_and_update();
        let [x, y, _] = snapshot.scene.pose;
        if snapshot.scene.count > 0 || snapshot.cycles > 0 {
            path.extend_to([x, y]);
        }
        for (trail, v) in trails.iter_mut().zip(snapshot.fleet.vehicles()).filter(|(_, v)| v.seen) {
            trail.extend_to([f64::from(v.pose[0]), f64::from(v.pose[1])]);
        }
        if last.is_none_or(|b| snapshot.scene.cycle > b.scene.cycle) {
            if recent.len() == SPEED_OVER {
                recent.pop_front();
            }
            recent.push_back((snapshot.scene.at, snapshot.scene.pose));
            if let (Some(&(t0, [x0, y0, _])), true) = (recent.front(), recent.len() > 1) {
                let dt = snapshot.scene.at.since(t0).as_secs_f64();
                speed = (dt > 0.0).then(|| (x - x0).hypot(y - y0) / dt);
            }
        }
        last = Some(snapshot);
        seq += 1;
        let paths = Paths { robot: path.points(), vehicles: trails.iter().map(Trail::points).collect() };
        let json = frame_json(&snapshot, &setup, &paths, &stats.borrow(), seq, speed, false);
        frames.send_replace(Frame { seq, json: json.into() });
        tokio::time::sleep(RENDER_EVERY).await;
    }
}

/// The planner's field for the scene (planning circles as the loop last grew them), for
/// streamlines. `None` before a pose, or when the planner could not make one.
pub(super) fn field(s: &SceneRecord, fleet: &FleetScene, setup: &ViewSetup) -> Option<Field> {
    let mut planned =
        [PlanObstacle { center: Point::default(), velocity: Point::default(), radius: 1.0 }; MAX_OBSTACLES];
    let obstacles = s.obstacles().iter().map(|o| PlanObstacle {
        center: Point::new(f64::from(o.position[0]), f64::from(o.position[1])),
        velocity: Point::new(f64::from(o.velocity[0]), f64::from(o.velocity[1])),
        radius: f64::from(o.planning_radius),
    });
    // The other vehicles, each a circle of the two bodies' radii moving on at its speed.
    let vehicles = setup.vehicles.iter().zip(fleet.vehicles()).filter(|(_, v)| v.seen).map(|(label, v)| {
        let heading = f64::from(v.pose[2]);
        PlanObstacle {
            center: Point::new(f64::from(v.pose[0]), f64::from(v.pose[1])),
            velocity: Point::from_polar(f64::from(v.twist[0]), heading),
            radius: label.radius + setup.robot_radius,
        }
    });
    let mut n = 0;
    for (slot, o) in planned.iter_mut().zip(obstacles.chain(vehicles)) {
        *slot = o;
        n += 1;
    }
    // Built as the control step builds it: no circle closed against a wall over the robot.
    let (space, sink) = (setup.planner.space, Planner::new(setup.planner).sink(Point::new(s.goal[0], s.goal[1])));
    let mut field = Field::empty(space, sink);
    field.set_room(setup.room.as_ref());
    field.rebuild_clear_of(space, sink, &planned[..n], Some(Point::new(s.pose[0], s.pose[1]))).ok()?;
    Some(field)
}

/// What the operator reads beside the drawing: the pose, the distance to the goal, the
/// clearance (the smallest gap between the robot's and an obstacle's or another vehicle's
/// footprints, as the gateway estimates them), the robot's speed over the last frames (`None` until two
/// cycles apart) and each obstacle's.
fn numbers(s: &SceneRecord, fleet: &FleetScene, setup: &ViewSetup, speed: Option<f64>) -> serde_json::Value {
    let [x, y, heading] = s.pose;
    let robot = Point::new(x, y);
    let bodies = s.obstacles().iter().map(|o| (o.position, f64::from(o.radius)));
    let vehicles = setup.vehicles.iter().zip(fleet.vehicles()).filter(|(_, v)| v.seen);
    let clearance = bodies
        .chain(vehicles.map(|(label, v)| ([v.pose[0], v.pose[1]], label.radius)))
        .map(|([cx, cy], radius)| {
            (robot - Point::new(f64::from(cx), f64::from(cy))).norm() - setup.robot_radius - radius
        })
        .reduce(f64::min);
    let obstacle_speeds: Vec<f64> =
        s.obstacles().iter().map(|o| f64::from(o.velocity[0]).hypot(f64::from(o.velocity[1]))).collect();
    json!({
        "x": x, "y": y, "heading_deg": heading.to_degrees(),
        "goal_distance": (robot - Point::new(s.goal[0], s.goal[1])).norm(),
        "clearance": clearance, "speed": speed, "obstacle_speeds": obstacle_speeds,
    })
}

/// The paths drawn: the robot's, and each other vehicle's.
struct Paths {
    robot: Vec<[f64; 2]>,
    vehicles: Vec<Vec<[f64; 2]>>,
}

/// Each of a fleet's other vehicles for the page: its name, role and state, and where the
/// camera last put it (`p` null before), its path and goal.
fn vehicles_json(fleet: &FleetScene, setup: &ViewSetup, paths: &Paths) -> Vec<serde_json::Value> {
    setup
        .vehicles
        .iter()
        .zip(fleet.vehicles())
        .zip(&paths.vehicles)
        .map(|((label, v), path)| {
            let p = v.seen.then(|| [round(f64::from(v.pose[0])), round(f64::from(v.pose[1]))]);
            json!({
                "name": label.name, "scripted": label.scripted, "radius": label.radius,
                "state": v.state.to_string(), "state_name": v.state.name(),
                "p": p, "heading": v.pose[2], "speed": v.twist[0], "goal": v.goal,
                "script_error": v.script_error, "path": path,
            })
        })
        .collect()
}

fn frame_json(
    v: &ViewSnapshot,
    setup: &ViewSetup,
    paths: &Paths,
    stats: &metrics::Snapshot,
    seq: u64,
    speed: Option<f64>,
    ended: bool,
) -> String {
    let s = &v.scene;
    let path = &paths.robot;
    let bounds = drawing_bounds(v, setup, paths);
    let lines = streamline_points(v, setup, path, bounds);
    let obstacles: Vec<_> = s
        .obstacles()
        .iter()
        .map(|o| json!({ "p": o.position, "v": o.velocity, "planning_radius": o.planning_radius, "radius": o.radius }))
        .collect();
    json!({
        "seq": seq,
        "state": v.state.to_string(),
        "state_name": v.state.name(),
        "reason": v.state.reason().map(|r| r.to_string()),
        "ended": ended,
        "cycles": v.cycles,
        "numbers": numbers(s, &v.fleet, setup, speed),
        "t": s.at.secs(),
        "robot": { "p": [s.pose[0], s.pose[1]], "heading": s.pose[2], "radius": setup.robot_radius },
        "goal": s.goal,
        "lane_half_width": setup.lane_half_width,
        "room": room_json(setup),
        "obstacles": obstacles,
        "vehicles": vehicles_json(&v.fleet, setup, paths),
        "path": path,
        "streamlines": lines,
        "bounds": [[bounds.0.re, bounds.0.im], [bounds.1.re, bounds.1.im]],
        "latency": {
            "histogram": latency_buckets(&stats.e2e_ns),
            "cycles": stats.e2e_ns.len(),
            "deadline_misses": stats.deadline_misses,
            "as_of_s": stats.uptime_s
        },
    })
    .to_string()
}

/// The room's items as the page draws them: `[{kind, closed, points}]`, walls first.
fn room_json(setup: &ViewSetup) -> serde_json::Value {
    let Some(outline) = &setup.outline else { return json!([]) };
    let items: Vec<_> = outline
        .outlines()
        .map(|(kind, points)| {
            let points: Vec<[f64; 2]> = points.iter().map(|p| [round(p.re), round(p.im)]).collect();
            json!({ "kind": kind.name(), "closed": kind.closed(), "points": points })
        })
        .collect();
    json!(items)
}

/// The drawing's extent: the robot, the goal, the obstacles, the other vehicles, the paths
/// and the room's walls and static obstacles (not the view's edge: the drawing follows the
/// robot), with a margin.
fn drawing_bounds(v: &ViewSnapshot, setup: &ViewSetup, paths: &Paths) -> (Point, Point) {
    let (s, fleet) = (&v.scene, &v.fleet);
    let robot = Point::new(s.pose[0], s.pose[1]);
    let mut lo = robot;
    let mut hi = robot;
    let mut grow = |p: Point, r: f64| {
        lo = Point::new(lo.re.min(p.re - r), lo.im.min(p.im - r));
        hi = Point::new(hi.re.max(p.re + r), hi.im.max(p.im + r));
    };
    grow(Point::new(s.goal[0], s.goal[1]), 0.05);
    for o in s.obstacles() {
        grow(Point::new(f64::from(o.position[0]), f64::from(o.position[1])), f64::from(o.planning_radius));
    }
    for p in &paths.robot {
        grow(Point::new(p[0], p[1]), setup.robot_radius);
    }
    for ((label, v), path) in setup.vehicles.iter().zip(fleet.vehicles()).zip(&paths.vehicles) {
        grow(Point::new(f64::from(v.goal[0]), f64::from(v.goal[1])), 0.05);
        for p in path {
            grow(Point::new(p[0], p[1]), label.radius);
        }
    }
    if let Some(h) = setup.lane_half_width {
        grow(Point::new(robot.re, 0.0), h);
    }
    if let Some(outline) = &setup.outline {
        for (_, points) in outline.outlines().filter(|(kind, _)| *kind != OutlineKind::View) {
            for &p in points {
                grow(p, 0.0);
            }
        }
    }
    let pad = Point::new(0.15, 0.15);
    (lo - pad, hi + pad)
}

/// The field's streamlines through seeds across the way to the goal, within `bounds`.
fn streamline_points(
    v: &ViewSnapshot,
    setup: &ViewSetup,
    path: &[[f64; 2]],
    bounds: (Point, Point),
) -> Vec<Vec<[f64; 2]>> {
    let s = &v.scene;
    let Some(field) = (s.count > 0 || path.len() > 1).then(|| field(s, &v.fleet, setup)).flatten() else {
        return Vec::new();
    };
    let robot = Point::new(s.pose[0], s.pose[1]);
    let to_goal = Point::new(s.goal[0], s.goal[1]) - robot;
    let across = Point::i() * to_goal / to_goal.norm().max(1e-9);
    let span = (bounds.1 - bounds.0).norm() * 0.5;
    let seeds: Vec<Point> = (-8..=8).map(|k| robot + across * (span * f64::from(k) / 8.0)).collect();
    streamlines(&field, &seeds, 0.01, 400, bounds)
        .into_iter()
        .map(|l| l.into_iter().map(|z| [round(z.re), round(z.im)]).collect())
        .collect()
}

/// The latency histogram's counts per bucket (not cumulative), for the view's bars.
fn latency_buckets(h: &hdrhistogram::Histogram<u64>) -> Vec<serde_json::Value> {
    let mut below = 0;
    metrics::BUCKETS_S
        .iter()
        .map(|&le| {
            let bound = (le * 1e9) as u64;
            let n: u64 = h.iter_recorded().filter(|x| x.value_iterated_to() <= bound).map(|x| x.count_at_value()).sum();
            let in_bucket = n - below;
            below = n;
            json!({ "le_s": le, "count": in_bucket })
        })
        .collect()
}

fn round(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// Take clients until aborted; each holds a clone of `serving` while it is served.
async fn serve(
    listener: TcpListener,
    frames: watch::Receiver<Frame>,
    dropped: Arc<AtomicU64>,
    serving: tokio::sync::mpsc::Sender<()>,
) {
    let clients = Arc::new(tokio::sync::Semaphore::new(MAX_CLIENTS));
    loop {
        let Ok((stream, _)) = listener.accept().await else { continue };
        let (frames, dropped, clients, serving) = (frames.clone(), dropped.clone(), clients.clone(), serving.clone());
        tokio::spawn(async move {
            if let Err(e) = client(stream, frames, dropped, clients).await {
                tracing::debug!("view client: {e}");
            }
            drop(serving);
        });
    }
}

async fn client(
    mut stream: TcpStream,
    mut frames: watch::Receiver<Frame>,
    dropped: Arc<AtomicU64>,
    clients: Arc<tokio::sync::Semaphore>,
) -> std::io::Result<()> {
    let timed_out = || std::io::Error::from(std::io::ErrorKind::TimedOut);
    let asked =
        tokio::time::timeout(CLIENT_DEADLINE, http::read_request(&mut stream)).await.map_err(|_| timed_out())??;
    let path = match asked {
        None => return Ok(()),
        Some(Asked::Other) => return http::method_not_allowed(&mut stream).await,
        Some(Asked::Get(path)) => path,
    };
    let Ok(_permit) = clients.try_acquire() else {
        return http::reply(&mut stream, "503 Service Unavailable", "text/plain", b"too many viewers\n").await;
    };
    if path != "/events" {
        let frame = frames.borrow().clone();
        let answer = async {
            match path.as_str() {
                "/" | "/index.html" => {
                    http::reply(&mut stream, "200 OK", "text/html; charset=utf-8", PAGE.as_bytes()).await
                }
                "/frame.json" => http::reply(&mut stream, "200 OK", "application/json", frame.json.as_bytes()).await,
                _ => {
                    let text = b"/, /events and /frame.json are served here\n";
                    http::reply(&mut stream, "404 Not Found", "text/plain", text).await
                }
            }
        };
        return tokio::time::timeout(CLIENT_DEADLINE, answer).await.map_err(|_| timed_out())?;
    }
    let head = "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\nConnection: keep-alive\r\n\r\n";
    tokio::time::timeout(CLIENT_DEADLINE, stream.write_all(head.as_bytes())).await.map_err(|_| timed_out())??;
    let mut last = frames.borrow().seq;
    loop {
        if frames.changed().await.is_err() {
            return Ok(());
        }
        let frame = frames.borrow_and_update().clone();
        // Frames made while this client was still taking an earlier one: skipped, counted.
        dropped.fetch_add(frame.seq.saturating_sub(last + 1), Ordering::Relaxed);
        last = frame.seq;
        let event = format!("data: {}\n\n", frame.json);
        tokio::time::timeout(CLIENT_DEADLINE, stream.write_all(event.as_bytes())).await.map_err(|_| timed_out())??;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gateway::core::scene::ObstacleView;
    use crate::planner::Space;

    fn robot_path(points: &[[f64; 2]]) -> Paths {
        Paths { robot: points.to_vec(), vehicles: Vec::new() }
    }

    fn setup() -> ViewSetup {
        let planner = PlannerConfig {
            space: Space::Lane { half_width: 0.3 },
            cruise_speed: 0.1,
            c1: 20.0,
            reference_radius: 0.1,
            max_speed: 0.15,
            margin: crate::planner::Margin::None,
            uncertainty_sigmas: 0.0,
            clearance: 0.0,
            tie_break: None,
            anticipation: 0.0,
            lane_residual: crate::planner::lane_series::EXACT_AIM,
        };
        ViewSetup {
            planner,
            robot_radius: 0.05,
            lane_half_width: Some(0.3),
            room: None,
            outline: None,
            vehicles: Vec::new(),
        }
    }

    #[test]
    fn a_frame_draws_the_scene_with_streamlines_around_the_obstacle() {
        let mut scene = SceneRecord { pose: [-0.5, 0.0, 0.0], goal: [0.6, 0.0], count: 1, ..SceneRecord::default() };
        scene.obstacles[0] = ObstacleView {
            position: [0.0, 0.02],
            velocity: [-0.05, 0.0],
            planning_radius: 0.12,
            radius: 0.05,
            ..ObstacleView::default()
        };
        let v = ViewSnapshot { scene, state: State::Running, cycles: 10, ..ViewSnapshot::default() };
        let stats = metrics::Snapshot::empty(0.0);
        let text = frame_json(&v, &setup(), &robot_path(&[[-0.6, 0.0], [-0.5, 0.0]]), &stats, 7, Some(0.12), false);
        let f: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(f["seq"], 7);
        assert_eq!(f["state_name"], "running");
        assert_eq!((f["ended"].as_bool(), f["reason"].is_null()), (Some(false), true));
        // The numbers: 1.1 m to the goal; 0.5 m between centres less both radii.
        let n = &f["numbers"];
        assert!((n["goal_distance"].as_f64().unwrap() - 1.1).abs() < 1e-12, "{n}");
        let gap = (0.5f64).hypot(0.02) - 0.05 - 0.05;
        assert!((n["clearance"].as_f64().unwrap() - gap).abs() < 1e-6, "{n}");
        assert_eq!(n["speed"], 0.12);
        assert!((n["obstacle_speeds"][0].as_f64().unwrap() - 0.05).abs() < 1e-6, "{n}");
        assert_eq!(f["obstacles"][0]["planning_radius"].as_f64().unwrap() as f32, 0.12);
        let lines = f["streamlines"].as_array().unwrap();
        assert_eq!(lines.len(), 17);
        // No streamline enters the planning circle.
        for line in lines {
            for p in line.as_array().unwrap() {
                let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap() - 0.02);
                assert!(x.hypot(y) > 0.12 - 0.011, "a streamline at ({x}, {y}) inside the circle");
            }
        }
        assert_eq!(f["latency"]["histogram"].as_array().unwrap().len(), metrics::BUCKETS_S.len());
    }

    /// A fleet's frame names each other vehicle with its state, place, path and goal; the
    /// robot's clearance counts it, and no streamline enters the circle it plans around it.
    #[test]
    fn a_fleets_frame_draws_every_vehicle() {
        use crate::gateway::core::scene::SceneVehicle;
        let scene = SceneRecord { pose: [-0.5, 0.0, 0.0], goal: [0.6, 0.0], ..SceneRecord::default() };
        let mut fleet = FleetScene::default();
        fleet.push(SceneVehicle {
            seen: true,
            state: State::Running,
            pose: [0.0, 0.0, std::f32::consts::PI],
            twist: [0.05, 0.0],
            goal: [-0.6, 0.0],
            script_error: Some(0.004),
        });
        fleet.push(SceneVehicle { goal: [0.3, 0.3], ..SceneVehicle::default() });
        let label = |name: &str, scripted| VehicleLabel { name: name.into(), radius: 0.06, scripted };
        let setup = ViewSetup { vehicles: vec![label("oncoming", true), label("late", false)], ..setup() };
        let paths = Paths { robot: vec![[-0.5, 0.0]], vehicles: vec![vec![[0.1, 0.0], [0.0, 0.0]], Vec::new()] };
        let v = ViewSnapshot { scene, fleet, state: State::Running, cycles: 10 };
        let text = frame_json(&v, &setup, &paths, &metrics::Snapshot::empty(0.0), 1, None, false);
        let f: serde_json::Value = serde_json::from_str(&text).unwrap();
        let [oncoming, late] = [&f["vehicles"][0], &f["vehicles"][1]];
        assert_eq!((oncoming["name"].as_str(), oncoming["scripted"].as_bool()), (Some("oncoming"), Some(true)));
        assert_eq!(oncoming["state_name"], "running");
        assert_eq!(oncoming["p"], json!([0.0, 0.0]));
        assert_eq!(oncoming["path"].as_array().unwrap().len(), 2);
        assert!((oncoming["script_error"].as_f64().unwrap() - 0.004).abs() < 1e-6);
        assert!(late["p"].is_null(), "a vehicle the camera has not shown has no place: {late}");
        assert_eq!(late["state_name"], "idle");
        // 0.5 m between centres less the robot's 0.05 m and the vehicle's 0.06 m.
        let clearance = f["numbers"]["clearance"].as_f64().unwrap();
        assert!((clearance - 0.39).abs() < 1e-6, "{clearance}");
        for line in f["streamlines"].as_array().unwrap() {
            for p in line.as_array().unwrap() {
                let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
                assert!(x.hypot(y) > 0.11 - 0.011, "a streamline at ({x}, {y}) inside the vehicle's circle");
            }
        }
        let [[x0, _], [x1, _]] = [0, 1].map(|k| [f["bounds"][k][0].as_f64().unwrap(), 0.0]);
        assert!(x0 < -0.6 && x1 > 0.6, "the bounds take every goal: {}", f["bounds"]);
    }

    /// In a room the frame carries its items, and the streamlines are the room's: none
    /// enters the table grown by the robot's radius.
    #[test]
    fn a_frame_in_a_room_draws_it_and_streams_around_it() {
        let square = |c: Point, h: f64| {
            vec![c + Point::new(-h, -h), c + Point::new(h, -h), c + Point::new(h, h), c + Point::new(-h, h)]
        };
        let shape = RoomShape {
            walls: vec![vec![Point::new(-1.0, 0.6), Point::new(1.0, 0.6)]],
            obstacles: vec![square(Point::new(0.0, 0.0), 0.15)],
            view: Some(square(Point::new(0.0, 0.0), 1.2)),
        };
        let room = Room::new(&shape, 0.05, 0.03).unwrap().unwrap();
        let setup = ViewSetup {
            planner: PlannerConfig { space: Space::Free, ..setup().planner },
            outline: Some(room.shape().clone()),
            room: Some(Arc::new(room)),
            lane_half_width: None,
            ..setup()
        };
        let scene = SceneRecord { pose: [-0.6, 0.05, 0.0], goal: [0.6, 0.0], ..SceneRecord::default() };
        let v = ViewSnapshot { scene, state: State::Running, cycles: 10, ..ViewSnapshot::default() };
        let stats = metrics::Snapshot::empty(0.0);
        let text = frame_json(&v, &setup, &robot_path(&[[-0.7, 0.05], [-0.6, 0.05]]), &stats, 1, None, false);
        let f: serde_json::Value = serde_json::from_str(&text).unwrap();
        let kinds: Vec<_> = f["room"].as_array().unwrap().iter().map(|r| r["kind"].as_str().unwrap()).collect();
        assert_eq!(kinds, ["wall", "static_obstacle", "view"]);
        assert_eq!(f["room"][1]["points"][2], json!([0.15, 0.15]));
        assert_eq!(f["room"][1]["closed"], true);
        let lines = f["streamlines"].as_array().unwrap();
        let mut points = 0;
        for p in lines.iter().flat_map(|l| l.as_array().unwrap()) {
            let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
            // Outside the grown table (less a streamline's step and the rounding).
            let gap = (x.abs() - 0.15).max(0.0).hypot((y.abs() - 0.15).max(0.0));
            assert!(gap > 0.05 - 0.011, "a streamline at ({x}, {y}) in the table");
            points += 1;
        }
        assert!(points > 100, "{points} streamline points");
    }

    /// A stopped gateway's frame says why, and the last one says the run ended.
    #[test]
    fn a_final_frame_keeps_the_state_and_its_reason() {
        let scene = SceneRecord { pose: [0.6, 0.0, 0.0], goal: [0.6, 0.0], ..SceneRecord::default() };
        let v = ViewSnapshot {
            scene,
            state: State::Stopped(crate::gateway::core::safety::StopReason::GoalReached),
            cycles: 10,
            ..ViewSnapshot::default()
        };
        let f: serde_json::Value = serde_json::from_str(&frame_json(
            &v,
            &setup(),
            &robot_path(&[]),
            &metrics::Snapshot::empty(0.0),
            9,
            None,
            true,
        ))
        .unwrap();
        assert_eq!((f["state_name"].as_str(), f["reason"].as_str()), (Some("stopped"), Some("goal reached")));
        assert_eq!(f["ended"], true);
        assert!(f["numbers"]["clearance"].is_null() && f["numbers"]["speed"].is_null());
    }

    /// Closing the view waits for its clients: an event stream that has its first frame
    /// when the run ends takes the last one, marked `ended`, before the view closes it.
    #[tokio::test]
    async fn closing_the_view_sends_each_event_stream_the_last_frame() {
        use std::io::{Read, Write};
        let (_stats_tx, stats) = watch::channel(Arc::new(metrics::Snapshot::empty(0.0)));
        let addr = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap();
        let view = start(addr, setup(), stats).unwrap();
        let scene =
            SceneRecord { pose: [0.6, 0.0, 0.0], goal: [0.6, 0.0], count: 1, cycle: 1, ..SceneRecord::default() };
        view.publish(ViewSnapshot { scene, state: State::Running, cycles: 1, ..ViewSnapshot::default() });
        let (first_tx, first) = tokio::sync::oneshot::channel();
        let reader = std::thread::spawn(move || {
            let mut stream = std::net::TcpStream::connect(addr).unwrap();
            stream.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
            stream.write_all(b"GET /events HTTP/1.1\r\n\r\n").unwrap();
            let (mut text, mut buf, mut first_tx) = (String::new(), [0u8; 65536], Some(first_tx));
            // Until the view closes the stream (or the read deadline fails the test).
            loop {
                match stream.read(&mut buf).unwrap() {
                    0 => return text,
                    n => text.push_str(std::str::from_utf8(&buf[..n]).unwrap()),
                }
                if text.contains("\"ended\":false") {
                    first_tx.take().map(|tx| tx.send(()));
                }
            }
        });
        first.await.expect("the stream's first frame");
        view.close().await;
        let text = tokio::task::spawn_blocking(move || reader.join().unwrap()).await.unwrap();
        let last = text.rsplit("data: ").next().unwrap();
        assert!(last.contains("\"ended\":true"), "the stream ended without the last frame: {text}");
    }

    /// The drawn field is the one the robot follows: with the robot between an obstacle and
    /// the wall it nearly touches, the circle is not closed over the robot, so the field is
    /// defined where the robot stands (closed, the robot would be inside it).
    #[test]
    fn the_view_draws_the_field_the_robot_follows() {
        // h = 0.3; R = 0.12 at y = 0.175: 5 mm from the wall; the robot 2 mm outside it.
        let mut scene = SceneRecord { pose: [0.0, 0.297, 0.0], goal: [0.6, 0.0], count: 1, ..SceneRecord::default() };
        scene.obstacles[0] =
            ObstacleView { position: [0.0, 0.175], planning_radius: 0.12, radius: 0.05, ..ObstacleView::default() };
        let f = field(&scene, &FleetScene::default(), &setup()).unwrap();
        assert!(f.velocity(Point::new(0.0, 0.297)).is_ok());
        assert!((f.obstacles()[0].radius - 0.12).abs() < 1e-6, "left as planned");
    }
}
