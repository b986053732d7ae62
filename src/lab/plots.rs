//! Reports a person reads: the trajectory and history plots of a run (SVG).

use std::fmt::Write as _;

use crate::Point;

use crate::lab::planner_only::{Run, Summary, TraceRow};
use crate::lab::Outcome;
use crate::lab::Scenario;
use crate::planner::{streamlines, Field, ObstacleEstimate, PlanInput, Planner};
use crate::svg::{Axes, Svg};
use flowgate_sim::scenario::vehicles::Role;

const ROBOT: &str = "#1f77b4";
const OBSTACLE: &str = "#d62728";
const STREAM: &str = "#9ecae1";
const COMMAND: &str = "#ff7f0e";

/// The field at the start of a scenario, as the planner would see it with perfect sensing.
pub fn start_field(s: &Scenario) -> Option<Field> {
    let config = s.rig().control;
    let obstacles: Vec<ObstacleEstimate> = flowgate_sim::world::people::ways(s)
        .iter()
        .zip(&s.obstacles)
        .map(|(path, o)| ObstacleEstimate::exact(path.position(0.0), path.velocity(0.0), o.radius))
        .collect();
    let input = PlanInput {
        position: s.robot_start(),
        goal: s.goal(),
        robot_radius: s.robot.radius,
        obstacles: &obstacles,
        delay: s.sensing.delay + s.sensing.sample_time,
    };
    Planner::in_room(config.planner, config.room).field(&input).ok().map(|(f, _)| f)
}

/// The scenario's walls, and its static obstacles closed by their last edge, as lines to
/// draw.
fn room_outlines(s: &Scenario) -> Vec<Vec<Point>> {
    let points = |p: &[[f64; 2]]| p.iter().map(|&[x, y]| Point::new(x, y)).collect::<Vec<_>>();
    let walls = s.walls.iter().map(|w| points(&w.points));
    let polygons = s.static_obstacles.iter().map(|o| {
        let mut outline = points(&o.points);
        outline.extend(outline.first().copied());
        outline
    });
    walls.chain(polygons).collect()
}

/// How a run ended, as a plot's title says it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ending {
    pub outcome: Outcome,
    /// Smallest true gap to an obstacle, m.
    pub min_obstacle_clearance: Option<f64>,
    pub end_time: f64,
}

impl From<&Summary> for Ending {
    fn from(s: &Summary) -> Self {
        Self { outcome: s.outcome, min_obstacle_clearance: s.min_obstacle_clearance, end_time: s.end_time }
    }
}

/// `trajectory.svg`: walls, streamlines at the start, obstacles' paths with their circles at
/// intervals, the robot's path and the goal.
pub fn trajectory_svg(s: &Scenario, trace: &[TraceRow], ending: Ending) -> String {
    let mut pts: Vec<Point> = trace.iter().map(|r| r.pose.position).collect();
    pts.extend(trace.iter().flat_map(|r| r.obstacles.iter().copied()));
    pts.push(s.goal());
    pts.push(s.robot_start());
    let room = room_outlines(s);
    pts.extend(room.iter().flatten().copied());
    let pad = 0.1 + s.obstacles.iter().map(|o| o.radius).fold(s.robot.radius, f64::max);
    let (mut lo, mut hi) = bounds(&pts, pad);
    if let Some(lane) = s.lane {
        lo.im = lo.im.min(-lane.half_width - 0.05);
        hi.im = hi.im.max(lane.half_width + 0.05);
    }
    let mut svg = Svg::new(760.0, 560.0);
    let ax = Axes::equal(&svg, lo, hi, (60.0, 40.0, 20.0, 50.0));
    ax.frame(&mut svg, "x (m)", "y (m)");
    let title = format!(
        "{} | outcome: {} | min clearance {} | t = {:.1} s",
        s.name,
        ending.outcome,
        ending.min_obstacle_clearance.map_or("-".into(), |c| format!("{:.1} mm", c * 1e3)),
        ending.end_time
    );
    svg.text(svg.width / 2.0, 22.0, &title, "middle", 14.0, "#000");

    if let Some(field) = start_field(s) {
        let to_goal = s.goal() - s.robot_start();
        let across = Point::i() * to_goal / to_goal.norm().max(1e-9);
        let span = (hi - lo).norm() * 0.5;
        let seeds: Vec<Point> = (-12..=12).map(|k| s.robot_start() + across * (span * f64::from(k) / 12.0)).collect();
        for line in streamlines(&field, &seeds, 0.004, 2000, (lo, hi)) {
            ax.polyline(&mut svg, &line, STREAM, 1.0, None);
        }
    }
    if let Some(lane) = s.lane {
        for y in [lane.half_width, -lane.half_width] {
            ax.polyline(&mut svg, &[Point::new(lo.re, y), Point::new(hi.re, y)], "#444", 3.0, None);
        }
    }
    for outline in &room {
        ax.polyline(&mut svg, outline, "#444", 3.0, None);
    }
    // Obstacles: path, and circles about every second (solid: true radius).
    let every = (1.0 / s.sensing.sample_time).round().max(1.0) as usize;
    for (k, o) in s.obstacles.iter().enumerate() {
        let path: Vec<Point> = trace.iter().map(|r| r.obstacles[k]).collect();
        ax.polyline(&mut svg, &path, OBSTACLE, 1.5, Some("4 3"));
        for (i, row) in trace.iter().enumerate().filter(|(i, _)| i % every == 0) {
            ax.circle(&mut svg, row.obstacles[k], o.radius, OBSTACLE, 0.8, 0.08);
            if i % (5 * every) == 0 {
                ax.label(&mut svg, row.obstacles[k], &format!("{:.0}s", row.t), OBSTACLE);
            }
        }
    }
    let path: Vec<Point> = trace.iter().map(|r| r.pose.position).collect();
    ax.polyline(&mut svg, &path, ROBOT, 2.0, None);
    for (_, row) in trace.iter().enumerate().filter(|(i, _)| i % (5 * every) == 0) {
        ax.circle(&mut svg, row.pose.position, s.robot.radius, ROBOT, 0.8, 0.05);
        ax.label(&mut svg, row.pose.position, &format!("{:.0}s", row.t), ROBOT);
    }
    ax.marker(&mut svg, s.robot_start(), ROBOT, "start");
    ax.marker(&mut svg, s.goal(), "#2ca02c", "goal");
    let legend = [
        (ROBOT, "robot path (circles every 5 s)"),
        (OBSTACLE, "obstacles (circles every 1 s)"),
        (STREAM, "field streamlines at t = 0"),
    ];
    for (i, (color, text)) in legend.iter().enumerate() {
        let y = svg.height - 30.0 + 0.0 * i as f64;
        let x = 70.0 + 230.0 * i as f64;
        svg.rect(x, y - 8.0, 14.0, 4.0, color);
        svg.text(x + 20.0, y, text, "start", 11.0, "#333");
    }
    svg.finish()
}

/// `history.svg`: speed and azimuth against time, commanded and realised (the paper's
/// figures 6-9 (a) and (b)).
pub fn history_svg(s: &Scenario, run: &Run) -> String {
    let mut svg = Svg::new(760.0, 560.0);
    svg.text(svg.width / 2.0, 22.0, &format!("{}: speed and azimuth", s.name), "middle", 14.0, "#000");
    let t_end = run.trace.last().map_or(1.0, |r| r.t).max(1e-3);
    let commanded: Vec<Point> = run.trace.iter().map(|r| Point::new(r.t, r.command.norm() * 1e3)).collect();
    let realised: Vec<Point> = run.trace.iter().map(|r| Point::new(r.t, r.speed * 1e3)).collect();
    let v_max = commanded.iter().chain(&realised).map(|p| p.im).fold(10.0, f64::max) * 1.1;
    let top = Axes::new(&svg, Point::new(0.0, 0.0), Point::new(t_end, v_max), (60.0, 40.0, 290.0, 20.0));
    top.frame(&mut svg, "time (s)", "speed (mm/s)");
    top.polyline(&mut svg, &commanded, COMMAND, 1.5, Some("5 3"));
    top.polyline(&mut svg, &realised, ROBOT, 1.5, None);

    let unwrap = |angles: &mut Vec<Point>| {
        for i in 1..angles.len() {
            let d = crate::wrap_angle((angles[i].im - angles[i - 1].im).to_radians()).to_degrees();
            angles[i].im = angles[i - 1].im + d;
        }
    };
    let mut cmd_az: Vec<Point> = run
        .trace
        .iter()
        .filter(|r| r.command.norm() > 1e-6)
        .map(|r| Point::new(r.t, r.command.arg().to_degrees()))
        .collect();
    let mut real_az: Vec<Point> = run.trace.iter().map(|r| Point::new(r.t, r.pose.heading.to_degrees())).collect();
    unwrap(&mut cmd_az);
    unwrap(&mut real_az);
    let (a_lo, a_hi) = cmd_az
        .iter()
        .chain(&real_az)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p.im), hi.max(p.im)));
    let (a_lo, a_hi) = if a_lo.is_finite() { (a_lo - 10.0, a_hi + 10.0) } else { (-90.0, 90.0) };
    let bottom = Axes::new(&svg, Point::new(0.0, a_lo), Point::new(t_end, a_hi), (60.0, 300.0, 40.0, 20.0));
    bottom.frame(&mut svg, "time (s)", "azimuth (deg)");
    bottom.polyline(&mut svg, &cmd_az, COMMAND, 1.5, Some("5 3"));
    bottom.polyline(&mut svg, &real_az, ROBOT, 1.5, None);
    for (i, (color, text)) in [(COMMAND, "commanded"), (ROBOT, "realised")].iter().enumerate() {
        let x = 80.0 + 140.0 * i as f64;
        svg.rect(x, 36.0, 14.0, 4.0, color);
        svg.text(x + 20.0, 42.0, text, "start", 11.0, "#333");
    }
    svg.finish()
}

fn bounds(pts: &[Point], pad: f64) -> (Point, Point) {
    let (lo, hi) = pts.iter().fold(
        (Point::new(f64::INFINITY, f64::INFINITY), Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY)),
        |(lo, hi), p| (Point::new(lo.re.min(p.re), lo.im.min(p.im)), Point::new(hi.re.max(p.re), hi.im.max(p.im))),
    );
    (lo - Point::new(pad, pad), hi + Point::new(pad, pad))
}

/// A one-line result for the terminal.
pub fn one_line(run: &Run) -> String {
    let s = &run.summary;
    let mut line = format!("{:<28} {:<9}", s.scenario, s.outcome.to_string());
    let _ = write!(
        line,
        " t={:>5.1}s clearance={:>7} path×{:.2} wheels≤{:.0}mm/s planner p99={:.1}µs",
        s.end_time,
        s.min_obstacle_clearance.map_or("-".into(), |c| format!("{:.1}mm", c * 1e3)),
        s.path_length_ratio,
        s.peak_wheel_speed[0].max(s.peak_wheel_speed[1]) * 1e3,
        s.planner_compute.p99_us
    );
    if let Some(reason) = &s.stop_reason {
        let _ = write!(line, " stop: {reason}");
    }
    line
}

/// The ring a fleet's plot marks each navigating vehicle's goal with, m.
const GOAL_RING: f64 = 0.012;

/// A colour a vehicle, the robot's first.
const VEHICLES: [&str; 8] = [ROBOT, "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22"];

/// How a fleet's run ended, as its plot says: the outcome and time in the title, each
/// vehicle's contact (the robot's first) by its path's end.
#[derive(Debug, Clone)]
pub struct FleetEnding {
    pub outcome: Outcome,
    pub end_time: f64,
    pub contacts: Vec<Option<super::fleet::VehicleContactReport>>,
}

impl FleetEnding {
    pub fn of(summary: &super::fleet::FleetSummary) -> Self {
        Self {
            outcome: summary.outcome,
            end_time: summary.end_time,
            contacts: summary.vehicles.iter().map(|v| v.contact.clone()).collect(),
        }
    }
}

/// `trajectory.svg` of a fleet: the room, each vehicle's path in its colour with its start,
/// its footprint where it ended and its goal, and the obstacles' paths.
pub fn fleet_svg(s: &Scenario, ending: &FleetEnding, trace: &super::fleet::FleetTrace) -> String {
    let mut pts: Vec<Point> = trace.vehicles.iter().chain(&trace.obstacles).flatten().copied().collect();
    let room = room_outlines(s);
    pts.extend(room.iter().flatten().copied());
    let (lo, hi) = bounds(&pts, 0.15);
    let mut svg = Svg::new(760.0, 560.0);
    let ax = Axes::equal(&svg, lo, hi, (60.0, 40.0, 20.0, 50.0));
    ax.frame(&mut svg, "x (m)", "y (m)");
    let title = format!(
        "{} | {} vehicles | outcome: {} | t = {:.1} s",
        s.name,
        ending.contacts.len(),
        ending.outcome,
        ending.end_time
    );
    svg.text(svg.width / 2.0, 22.0, &title, "middle", 14.0, "#000");
    if let Some(lane) = s.lane {
        for y in [lane.half_width, -lane.half_width] {
            ax.polyline(&mut svg, &[Point::new(lo.re, y), Point::new(hi.re, y)], "#444", 3.0, None);
        }
    }
    for outline in &room {
        ax.polyline(&mut svg, outline, "#444", 3.0, None);
    }
    // An obstacle's footprint where it ended: a standing one has no path to draw.
    for (path, o) in trace.obstacles.iter().zip(&s.obstacles) {
        ax.polyline(&mut svg, path, OBSTACLE, 1.5, Some("4 3"));
        if let Some(&last) = path.last() {
            ax.circle(&mut svg, last, o.radius, OBSTACLE, 0.8, 0.08);
        }
    }
    for (k, (path, ((name, body, role), contact))) in
        trace.vehicles.iter().zip(s.fleet().zip(&ending.contacts)).enumerate()
    {
        let color = VEHICLES[k % VEHICLES.len()];
        if role == Role::Navigate {
            ax.circle(&mut svg, s.vehicle_alone(k).goal(), GOAL_RING, color, 1.5, 0.0);
        }
        ax.polyline(&mut svg, path, color, 2.0, None);
        if let (Some(&first), Some(&last)) = (path.first(), path.last()) {
            ax.marker(&mut svg, first, color, name);
            ax.circle(&mut svg, last, body.radius, color, 1.0, 0.1);
        }
        if let Some(c) = contact {
            let at = path.last().copied().unwrap_or_default();
            ax.label(
                &mut svg,
                at,
                &format!("touched {} ({})", c.with, if c.active { "active" } else { "passive" }),
                "#000",
            );
        }
    }
    let legend = "name and dot: a vehicle's start; ring: its goal; dashed: obstacles, their footprint where they ended";
    svg.text(70.0, svg.height - 30.0, legend, "start", 11.0, "#333");
    svg.finish()
}
