//! A planner outside flowgate in the simulator (`flowgate plan --policy CMD SCENARIO`): CMD
//! runs as a process of its own and speaks JSON lines with the whole stack in virtual time,
//! its commands going through the gateway's supervisor as a rig's would
//! (docs/policies.md, "In the simulator").
//!
//! The protocol, one JSON object a line each way:
//!
//! 1. flowgate → policy: the hello, `{"flowgate": VERSION, "scenario": NAME, "limits":
//!    {...}, "room": {"walls": [...], "furniture": [...], "view": [...]}}`;
//! 2. each control period, flowgate → policy: an [`Observation`]; policy → flowgate:
//!    `{"v": m/s, "w": rad/s}` or `{"left": m/s, "right": m/s}`;
//! 3. at the end, flowgate → policy: `{"outcome": ..., "contact": ..., "stop": ...}`.
//!
//! The policy sees what the gateway estimates (its pose, its obstacles' tracks), not the
//! world's truth. A policy that answers within its budget gives the same bytes for the same
//! seed: the budget is host time, and decides only whether a slow policy ends its episode.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::process::CommandExt;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::virtual_rig::{Options, VirtualRig, VirtualRun};
use super::Scenario;
use crate::config::PlannerMethod;
use crate::control::OutsideCommand;
use crate::gateway::core::operator::{non_finite_as_null, number_or_nan, Request};
use crate::planner::room::OutlineKind;

/// How long a policy may take to answer one observation, host time, by default.
pub const DEFAULT_BUDGET: Duration = Duration::from_secs(1);

/// The longest line a policy may write, bytes.
const MAX_LINE: usize = 64 * 1024;

/// Why a policy ended its episode: `policy: ...` in the run's stop.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PolicyError {
    #[error("policy: could not start `{command}`: {why}")]
    Start { command: String, why: String },
    #[error("policy: exited ({status})")]
    Exited { status: String },
    #[error("policy: no answer within {} ms", .budget.as_millis())]
    Slow { budget: Duration },
    #[error("policy: answered `{line}`, not {{\"v\", \"w\"}} nor {{\"left\", \"right\"}} ({why})")]
    Garbage { line: String, why: String },
    #[error("policy: answered a command not finite (NaN or infinite): `{line}`")]
    NotFinite { line: String },
    #[error("policy: a line longer than {MAX_LINE} bytes")]
    TooLong,
}

/// What the policy is told first.
#[derive(Debug, Clone, Serialize)]
pub struct Hello {
    pub flowgate: &'static str,
    pub scenario: String,
    pub limits: Limits,
    pub room: RoomOutlines,
}

/// The robot's limits, in metres and seconds.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Limits {
    /// The robot's centre's speed limit, m/s.
    pub max_speed: f64,
    /// Each wheel's rim speed limit, m/s.
    pub max_wheel_speed: f64,
    /// Between the wheels, m.
    pub wheel_base: f64,
    /// The robot's radius, m.
    pub radius: f64,
    /// The control period, s: one observation each.
    pub period: f64,
    /// The goal counts as reached within this, m.
    pub goal_tolerance: f64,
}

/// The room as polygons (each a list of `[x, y]`, m): walls open, furniture and the view's
/// edge closed by their last edge.
#[derive(Debug, Clone, Default, Serialize)]
pub struct RoomOutlines {
    pub walls: Vec<Vec<[f64; 2]>>,
    pub furniture: Vec<Vec<[f64; 2]>>,
    pub view: Vec<Vec<[f64; 2]>>,
}

/// One cycle's observation.
#[derive(Debug, Clone, Serialize)]
pub struct Observation {
    pub t: f64,
    pub robot: RobotObservation,
    pub goal: [f64; 2],
    pub obstacles: Vec<ObstacleObservation>,
}

/// The robot as the gateway estimates it: `heading` in radians, `v` m/s and `w` rad/s (from
/// its last two poses).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct RobotObservation {
    pub x: f64,
    pub y: f64,
    pub heading: f64,
    pub v: f64,
    pub w: f64,
}

/// An obstacle as the gateway tracks it.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ObstacleObservation {
    pub x: f64,
    pub y: f64,
    pub vx: f64,
    pub vy: f64,
    pub radius: f64,
}

/// A policy's answer (a NaN or an infinity, as Python's `json` writes them, read as not
/// finite).
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(untagged, deny_unknown_fields)]
enum Answer {
    Twist {
        #[serde(deserialize_with = "number_or_nan")]
        v: f64,
        #[serde(deserialize_with = "number_or_nan")]
        w: f64,
    },
    Wheels {
        #[serde(deserialize_with = "number_or_nan")]
        left: f64,
        #[serde(deserialize_with = "number_or_nan")]
        right: f64,
    },
}

impl Answer {
    fn read(line: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(line).or_else(|e| match non_finite_as_null(line) {
            Some(lenient) => serde_json::from_str(&lenient).map_err(|_| e),
            None => Err(e),
        })
    }
}

/// The last line.
#[derive(Debug, Clone, Serialize)]
pub struct Ending {
    pub outcome: String,
    pub contact: bool,
    pub stop: Option<String>,
}

/// A policy's process, spoken to a line at a time.
#[derive(Debug)]
pub struct PolicyProcess {
    child: Child,
    stdin: ChildStdin,
    lines: mpsc::Receiver<Result<String, PolicyError>>,
    budget: Duration,
}

impl PolicyProcess {
    /// Start `command` (run by `sh -c`), its answers awaited at most `budget` each.
    pub fn start(command: &str, budget: Duration) -> Result<Self, PolicyError> {
        let start = |why: String| PolicyError::Start { command: command.into(), why };
        // A group of its own: ending it ends what it started (`sh -c` runs CMD as a child).
        let mut child = Command::new("sh")
            .args(["-c", command])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .process_group(0)
            .spawn()
            .map_err(|e| start(e.to_string()))?;
        let stdin = child.stdin.take().ok_or_else(|| start("no stdin".into()))?;
        let stdout = child.stdout.take().ok_or_else(|| start("no stdout".into()))?;
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            let mut reader = BufReader::new(stdout);
            loop {
                let mut line = Vec::new();
                let read = (&mut reader).take(MAX_LINE as u64 + 1).read_until(b'\n', &mut line);
                let item = match read {
                    Ok(0) | Err(_) => break,
                    Ok(_) if line.len() > MAX_LINE => Err(PolicyError::TooLong),
                    Ok(_) => Ok(String::from_utf8_lossy(&line).trim_end().to_owned()),
                };
                let last = item.is_err();
                if tx.send(item).is_err() || last {
                    break;
                }
            }
        });
        Ok(Self { child, stdin, lines, budget })
    }

    /// Send one line.
    fn send(&mut self, message: &impl Serialize) -> Result<(), PolicyError> {
        let mut line = serde_json::to_vec(message).expect("the protocol's messages serialise");
        line.push(b'\n');
        self.stdin.write_all(&line).and_then(|()| self.stdin.flush()).map_err(|_| self.exited())
    }

    pub fn hello(&mut self, hello: &Hello) -> Result<(), PolicyError> {
        self.send(hello)
    }

    /// One observation, and the policy's command.
    pub fn ask(&mut self, observation: &Observation) -> Result<OutsideCommand, PolicyError> {
        self.send(observation)?;
        let line = match self.lines.recv_timeout(self.budget) {
            Ok(line) => line?,
            Err(mpsc::RecvTimeoutError::Timeout) => return Err(PolicyError::Slow { budget: self.budget }),
            Err(mpsc::RecvTimeoutError::Disconnected) => return Err(self.exited()),
        };
        let answer =
            Answer::read(&line).map_err(|e| PolicyError::Garbage { line: shorten(&line), why: e.to_string() })?;
        let command = match answer {
            Answer::Twist { v, w } => OutsideCommand::Twist { v, w },
            Answer::Wheels { left, right } => OutsideCommand::Wheels { left, right },
        };
        if command.is_finite() {
            Ok(command)
        } else {
            Err(PolicyError::NotFinite { line: shorten(&line) })
        }
    }

    /// The episode's last line.
    pub fn end_episode(&mut self, ending: &Ending) {
        let _ = self.send(ending);
    }

    /// Close its input, and end the process (killed if it lingers).
    pub fn close(mut self) {
        drop(self.stdin);
        for _ in 0..50 {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(2)); // its exit, awaited briefly
        }
        if let Some(group) = rustix::process::Pid::from_raw(self.child.id() as i32) {
            let _ = rustix::process::kill_process_group(group, rustix::process::Signal::KILL);
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// The process is gone: how it ended.
    fn exited(&mut self) -> PolicyError {
        let status = match self.child.wait() {
            Ok(s) => s.to_string(),
            Err(e) => e.to_string(),
        };
        PolicyError::Exited { status }
    }
}

fn shorten(line: &str) -> String {
    let mut s: String = line.chars().take(80).collect();
    if s.len() < line.len() {
        s.push_str("...");
    }
    s
}

/// The hello for `scenario`, its vehicle driven as `gateway` says.
pub fn hello(scenario: &Scenario, gateway: &crate::config::Rig) -> Hello {
    let control = &gateway.control;
    let mut room = RoomOutlines::default();
    if let Some(r) = &control.room {
        for (kind, points) in r.shape().outlines() {
            let polygon = points.iter().map(|p| [p.re, p.im]).collect();
            match kind {
                OutlineKind::Wall => room.walls.push(polygon),
                OutlineKind::StaticObstacle => room.furniture.push(polygon),
                OutlineKind::View => room.view.push(polygon),
            }
        }
    }
    Hello {
        flowgate: env!("CARGO_PKG_VERSION"),
        scenario: scenario.name.clone(),
        limits: Limits {
            max_speed: control.planner.max_speed,
            max_wheel_speed: control.drive.max_wheel_speed,
            wheel_base: control.drive.wheel_base,
            radius: control.robot_radius,
            period: gateway.sample_period.as_secs_f64(),
            goal_tolerance: scenario.goal.tolerance,
        },
        room,
    }
}

/// The observation now: what the gateway believes (before its first cycle, the robot at
/// rest at the origin).
fn observe(rig: &VirtualRig, goal: [f64; 2]) -> Observation {
    let scene = rig.scene();
    let [x, y, heading] = scene.pose;
    let [v, w] = scene.twist;
    let obstacles = scene
        .obstacles()
        .iter()
        .map(|o| ObstacleObservation {
            x: f64::from(o.position[0]),
            y: f64::from(o.position[1]),
            vx: f64::from(o.velocity[0]),
            vy: f64::from(o.velocity[1]),
            radius: f64::from(o.radius),
        })
        .collect();
    Observation { t: rig.time(), robot: RobotObservation { x, y, heading, v, w }, goal, obstacles }
}

/// `scenario` with its commands from outside (`planner.method = "socket"`, the virtual
/// rig's requests its socket).
pub fn driven_from_outside(scenario: &Scenario) -> Scenario {
    let mut scenario = scenario.clone();
    scenario.planner.method = PlannerMethod::Socket;
    scenario
}

/// A policy's process kept across episodes (a sweep's worker): started at the first
/// episode, and again after an episode it failed.
#[derive(Debug)]
pub struct Worker {
    command: String,
    budget: Duration,
    process: Option<PolicyProcess>,
}

impl Worker {
    pub fn new(command: &str, budget: Duration) -> Self {
        Self { command: command.into(), budget, process: None }
    }

    /// Run `scenario` through the whole stack with the policy as its planner, the gateway's
    /// supervisor between them. The policy's failure ends the episode: the robot is stopped
    /// in order, and the failure comes back beside the run.
    pub fn episode(&mut self, scenario: &Scenario, options: Options) -> (VirtualRun, Option<PolicyError>) {
        let scenario = driven_from_outside(scenario);
        let mut rig = VirtualRig::new(&scenario, options);
        let opened = self.begin(&scenario, &rig);
        let (goal, tolerance) = (scenario.goal.position, scenario.goal.tolerance);
        let period = rig.core().rig().sample_period.as_secs_f64();
        if let Err(e) = opened {
            let _ = rig.request(&Request::Stop);
            return (rig.run_driven(scenario.time_limit, goal, tolerance, period, |_| Ok::<(), ()>(())).0, Some(e));
        }
        let (run, failure) = rig.run_driven(scenario.time_limit, goal, tolerance, period, |rig| self.turn(rig, goal));
        self.end(&run, failure.as_ref());
        (run, failure)
    }

    /// An episode begins on `rig`: the process started if it is not, and the hello.
    pub fn begin(&mut self, scenario: &Scenario, rig: &VirtualRig) -> Result<(), PolicyError> {
        self.open(&hello(scenario, rig.core().rig()))
    }

    /// An episode begins: the process started if it is not, and `hello` sent.
    pub fn open(&mut self, hello: &Hello) -> Result<(), PolicyError> {
        let mut process = match self.process.take() {
            Some(p) => p,
            None => PolicyProcess::start(&self.command, self.budget)?,
        };
        process.hello(hello)?;
        self.process = Some(process);
        Ok(())
    }

    /// One observation, and the policy's command.
    pub fn ask(&mut self, observation: &Observation) -> Result<OutsideCommand, PolicyError> {
        match self.process.as_mut() {
            Some(process) => process.ask(observation),
            None => Err(PolicyError::Exited { status: "not running".into() }),
        }
    }

    /// The policy's turn: it observes `rig` and its command goes in as a request.
    pub fn turn(&mut self, rig: &mut VirtualRig, goal: [f64; 2]) -> Result<(), PolicyError> {
        let command = self.ask(&observe(rig, goal))?;
        let request = match command {
            OutsideCommand::Twist { v, w } => Request::Drive { v, w },
            OutsideCommand::Wheels { left, right } => Request::Wheels { left, right },
        };
        let _ = rig.request(&request);
        Ok(())
    }

    /// The episode's end: its last line; a process that failed it ends, and starts afresh
    /// for the next.
    pub fn end(&mut self, run: &VirtualRun, failure: Option<&PolicyError>) {
        let stop = failure.map(|e| e.to_string()).or_else(|| run.report.stop_reason.map(|r| r.to_string()));
        let ending = Ending { outcome: run.outcome.to_string(), contact: run.truth.summary.contact.is_some(), stop };
        self.finish(&ending, failure.is_some());
    }

    /// The episode's last line, `ending`; a process that `failed` it ends, and starts afresh
    /// for the next.
    pub fn finish(&mut self, ending: &Ending, failed: bool) {
        if let Some(mut p) = self.process.take() {
            p.end_episode(ending);
            if !failed {
                self.process = Some(p);
            } else {
                p.close();
            }
        }
    }

    /// End the process.
    pub fn close(mut self) {
        if let Some(p) = self.process.take() {
            p.close();
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        if let Some(p) = self.process.take() {
            p.close();
        }
    }
}
