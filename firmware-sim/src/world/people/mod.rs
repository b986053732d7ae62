//! People who walk: obstacles whose way is not scripted but walked, each to its goals,
//! avoiding the others, the walls and the furniture, by optimal reciprocal collision
//! avoidance ([`orca`]) or by social forces (`flowgate_protocol::plane::social_force`).
//!
//! The robot is invisible to them by default (CrowdNav's setting), so what they do does not
//! depend on it: their ways are walked once, when the world is made, in steps of [`STEP`],
//! into the timed legs of constant velocity a scripted obstacle has
//! ([`ObstaclePath::walked`]). People who see the robot (`sees_robot`) walk as the world
//! runs instead, a step at a time, seeing the robot where it is at each step's start. The
//! camera, the judge and the truth downstream are those of any obstacle, exact between the
//! steps. Deterministic: the same scenario (and seed, for new goals) walks the same ways.

use rand::{Rng, SeedableRng};
use std::f64::consts::TAU;

use super::{ObstaclePath, Room};
use crate::scenario::people::SPEED_CAP;
use crate::scenario::{Behaviour, ObstacleSpec, OnArrival, PeopleWalk, SimScenario, Walk};
use crate::Point;
use flowgate_protocol::plane::nearest_on_segment;
use flowgate_protocol::plane::orca::{self, length};
use flowgate_protocol::plane::polygon_edges;
use flowgate_protocol::plane::social_force;
use grid::Grid;

/// The people's time step, s: a twentieth of a second, five times finer than CrowdNav's
/// 0.25 s at its speeds (a step is a fifth of a body at the rig's fastest people).
pub const STEP: f64 = 0.05;
/// How far ahead ORCA keeps people apart, in the time a person takes to walk this many of
/// their own radii: CrowdNav's 5 s at 1 m/s and 0.3 m radius.
pub const HORIZON_RADII: f64 = 5.0 / 0.3;
/// How long beyond the scenario's time limit people's ways are walked, s (a fault swarm's
/// episode runs on past it while the operator restarts the robot).
const WALK_BEYOND: f64 = 30.0;
/// How many rounds people's velocities are corrected to keep them apart before a pair
/// still closing stands.
const KEEP_APART_ROUNDS: usize = 8;
/// How far aside a person held back by someone coming steps, rad (to the right).
const KEEP_RIGHT: f64 = 0.5;
/// Held back: its velocity this far from the one it prefers, as a share of its speed.
const BLOCKED: f64 = 0.05;
/// Walking, not standing: faster than this share of its preferred speed.
const WALKING: f64 = 0.25;
/// How far a person's preferred velocity sways from step to step, as a share of its speed.
const PERTURBATION: f64 = 3e-2;
/// The nearest neighbours each person avoids.
const MAX_NEIGHBOURS: usize = 10;
/// The berth a person who sees the robot leaves it, beyond their bodies, in the robot's
/// radii.
const ROBOT_BERTH: f64 = 0.1;

/// One person walking.
#[derive(Debug, Clone)]
struct Walker {
    obstacle: usize,
    walk: Walk,
    radius: f64,
    position: Point,
    velocity: Point,
    /// Which of `walk.goals` it walks to now.
    next: usize,
    /// Its last leg (when it began, where, and its velocity); every leg is in
    /// [`Crowd::legs`].
    last_leg: Option<(f64, Point, Point)>,
    /// Draws new goals (`on_arrival = "new_goal"`).
    rng: rand_chacha::ChaCha8Rng,
    /// Its group (the index of the group's first member), if it walks in one.
    group: Option<usize>,
    /// The speed it walks at when nothing is in its way: its preferred speed, or in a group
    /// the slowest member's (a group walks at its slowest member's pace).
    pace: f64,
}

impl Walker {
    fn goal(&self) -> Point {
        self.walk.goals[self.next.min(self.walk.goals.len() - 1)]
    }

    /// The velocity it would walk at alone: to its goal at its preferred speed, slowing so as
    /// to stop on it. Arrived (within its radius, as CrowdNav counts it), on to the next
    /// goal, a new one, or standing.
    fn preferred(&mut self, area: &Area, room: &Room) -> Point {
        if (self.goal() - self.position).norm_sqr() < self.radius * self.radius {
            if self.next + 1 < self.walk.goals.len() {
                self.next += 1;
            } else if self.walk.on_arrival == OnArrival::NewGoal {
                let goal = area.draw(&mut self.rng, self.radius, room);
                self.walk.goals.push(goal);
                self.next = self.walk.goals.len() - 1;
            }
        }
        let to = self.goal() - self.position;
        let d = length(to);
        if d < 1e-9 {
            return Point::default();
        }
        // A little sway, as people have: perfect symmetry (a ring of people all bound for
        // its centre) would otherwise hold every one where it stands.
        let sway = Point::from_polar(PERTURBATION * self.pace, self.rng.random_range(0.0..TAU));
        to / d * self.pace.min(d / STEP) + sway
    }

    fn top_speed(&self) -> f64 {
        self.walk.preferred_speed * SPEED_CAP
    }
}

/// Where new goals are drawn: the box every person's start and goals span.
#[derive(Debug, Clone, Copy)]
struct Area {
    min: Point,
    max: Point,
}

impl Area {
    /// A point of the area clear of the furniture and the walls by `radius` (the area's
    /// centre when a thousand draws find none).
    fn draw(&self, rng: &mut rand_chacha::ChaCha8Rng, radius: f64, room: &Room) -> Point {
        for _ in 0..1000 {
            let p =
                Point::new(rng.random_range(self.min.re..=self.max.re), rng.random_range(self.min.im..=self.max.im));
            if room.gap(p, radius).is_none_or(|g| g.gap > 0.0) {
                return p;
            }
        }
        (self.min + self.max) * 0.5
    }
}

/// Each obstacle's way in `scenario`: walked for people, as scripted for the others.
pub fn ways(scenario: &SimScenario) -> Vec<ObstaclePath> {
    let room = Room::new(scenario);
    let mut crowd = Crowd::new(&scenario.obstacles, room, scenario.sensing.seed);
    if crowd.walkers.is_empty() {
        return crowd.paths;
    }
    crowd.reserve(((scenario.time_limit + WALK_BEYOND) / STEP).ceil() as usize + 1);
    while crowd.time() < scenario.time_limit + WALK_BEYOND {
        crowd.step();
    }
    crowd.into_ways()
}

/// Each obstacle's way in `scenario` at time 0, and the crowd still to walk when its people
/// walk as the world runs ([`Crowd::step_beside`]), each way growing by a leg a step: when
/// some of them see the robot (what they do then depends on where it goes), or when the
/// scenario says `people_walk = "as_needed"`. Otherwise [`ways`], walked once, and no crowd.
pub fn start(scenario: &SimScenario) -> (Vec<ObstaclePath>, Option<Crowd>) {
    let walkers = scenario.obstacles.iter().filter(|o| o.behaviour.walks());
    let mut walkers = walkers.peekable();
    let as_needed = scenario.people_walk == PeopleWalk::AsNeeded && walkers.peek().is_some();
    if !as_needed && !walkers.any(|o| o.sees_robot) {
        return (ways(scenario), None);
    }
    let crowd = Crowd::new(&scenario.obstacles, Room::new(scenario), scenario.sensing.seed);
    let mut paths = crowd.paths.clone();
    for w in &crowd.walkers {
        paths[w.obstacle] = ObstaclePath::walking(w.position, w.top_speed());
    }
    (paths, Some(crowd))
}

/// People walking among scripted obstacles, in a room, one [`STEP`] at a time.
#[derive(Debug, Clone)]
pub struct Crowd {
    /// Every obstacle's way: the scripted ones' as they are, the people's filled in by
    /// [`Crowd::into_ways`].
    paths: Vec<ObstaclePath>,
    walkers: Vec<Walker>,
    /// Every person's legs as walked, in the order walked: (the person's index in
    /// `walkers`, when the leg began, where, its velocity). One record for all, so that a
    /// step writes on into one buffer rather than a hundred (each touching a new page of
    /// memory at the same step).
    legs: Vec<(usize, f64, Point, Point)>,
    /// The scripted obstacles (index, radius).
    scripted: Vec<(usize, f64)>,
    room: Room,
    area: Area,
    steps: u64,
    /// Everyone as the people see them at this step's start: the people (in their order),
    /// the scripted obstacles, then the vehicles.
    bodies: Vec<orca::Body>,
    velocities: Vec<Point>,
    /// Where the people stand at this step's start, bucketed.
    grid: Grid,
    /// The farthest apart two people can be and touch within a step: the grid's least cell.
    touch_reach: f64,
    scratch: Scratch,
}

impl Crowd {
    /// `obstacles` at time 0 in `room`; `seed` draws new goals.
    pub fn new(obstacles: &[ObstacleSpec], room: Room, seed: u64) -> Self {
        let paths = obstacles.iter().map(ObstaclePath::new).collect();
        let walkers: Vec<Walker> = obstacles
            .iter()
            .enumerate()
            .filter_map(|(k, o)| {
                let walk = o.walk()?;
                let seed = seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x9E09;
                Some(Walker {
                    obstacle: k,
                    radius: o.radius,
                    position: crate::scenario::point(o.start),
                    velocity: Point::default(),
                    next: 0,
                    last_leg: None,
                    rng: rand_chacha::ChaCha8Rng::seed_from_u64(seed),
                    group: o.group.as_ref().and_then(|g| obstacles.iter().position(|p| p.group.as_ref() == Some(g))),
                    pace: walk.preferred_speed,
                    walk,
                })
            })
            .collect();
        let mut walkers = walkers;
        let paces: Vec<f64> = walkers
            .iter()
            .map(|w| {
                let members = walkers.iter().filter(|m| w.group.is_some() && m.group == w.group);
                members.map(|m| m.walk.preferred_speed).fold(w.walk.preferred_speed, f64::min)
            })
            .collect();
        for (w, pace) in walkers.iter_mut().zip(paces) {
            w.pace = pace;
        }
        let scripted =
            obstacles.iter().enumerate().filter(|(_, o)| !o.behaviour.walks()).map(|(k, o)| (k, o.radius)).collect();
        let area = area(&walkers);
        let touch_reach = walkers.iter().map(|w| 2.0 * (w.radius + w.top_speed() * STEP)).fold(0.0, f64::max);
        Self {
            paths,
            walkers,
            legs: Vec::new(),
            scripted,
            room,
            area,
            steps: 0,
            bodies: Vec::new(),
            velocities: Vec::new(),
            grid: Grid::default(),
            touch_reach,
            scratch: Scratch::default(),
        }
    }

    /// Whether anyone in the crowd sees the robot (or a fleet's vehicles): when nobody
    /// does, [`Crowd::step_beside`] needs no vehicles.
    pub fn sees_vehicles(&self) -> bool {
        self.walkers.iter().any(|w| w.walk.sees_robot)
    }

    /// How far the people have walked, s.
    pub fn time(&self) -> f64 {
        self.steps as f64 * STEP
    }

    /// Each person's position now, in the order of the obstacles.
    pub fn positions(&self) -> impl Iterator<Item = Point> + '_ {
        self.walkers.iter().map(|w| w.position)
    }

    /// Room for `steps` more steps' legs of every person, so that walking them does not
    /// grow the record of legs (copying all of it, within one step).
    pub fn reserve(&mut self, steps: usize) {
        self.legs.reserve(steps.saturating_mul(self.walkers.len()));
    }

    /// Every person walks one step, on what each saw of the others at its start.
    pub fn step(&mut self) {
        self.step_beside(&[]);
    }

    /// Every person walks one step beside the robot, or a fleet's vehicles, each as it is
    /// at the step's start (position, velocity, radius): those who see them avoid them as
    /// they avoid a scripted obstacle, taking all the avoiding on themselves.
    pub fn step_beside(&mut self, vehicles: &[(Point, Point, f64)]) {
        let t = self.time();
        self.bodies.clear();
        let walking =
            self.walkers.iter().map(|w| orca::Body { position: w.position, velocity: w.velocity, radius: w.radius });
        self.bodies.extend(walking);
        for &(k, radius) in &self.scripted {
            let path = &self.paths[k];
            self.bodies.push(orca::Body { position: path.position(t), velocity: path.velocity(t), radius });
        }
        let unseen = self.bodies.len();
        for &(position, velocity, radius) in vehicles {
            // A person leaves a vehicle a berth: ORCA's solution may graze what it avoids,
            // and grazing a vehicle is touching it.
            self.bodies.push(orca::Body { position, velocity, radius: radius * (1.0 + ROBOT_BERTH) });
        }
        self.velocities.clear();
        self.grid.build(self.walkers.iter().map(|w| (w.position, w.radius, w.top_speed())), self.touch_reach);
        for i in 0..self.walkers.len() {
            let seen = if self.walkers[i].walk.sees_robot { &self.bodies[..] } else { &self.bodies[..unseen] };
            let v = velocity(&mut self.walkers, i, seen, &self.room, &self.area, &self.grid, &mut self.scratch);
            self.velocities.push(v);
        }
        self.keep_apart();
        for (k, (w, &v)) in self.walkers.iter_mut().zip(&self.velocities).enumerate() {
            w.velocity = v;
            if w.last_leg.is_none_or(|(_, _, last)| last != v) {
                w.last_leg = Some((t, w.position, v));
                self.legs.push((k, t, w.position, v));
            }
            w.position += v * STEP;
        }
        self.steps += 1;
    }

    /// No two people come closer than their bodies within the step: ORCA keeps them apart
    /// only where its program is feasible (in a dense jam it only violates the least), and
    /// social forces never promise to. A pair closing faster than its gap allows has the
    /// excess taken off their velocities along the line between them, half each (they may
    /// still slide past each other), each kept within its speed cap; a pair still closing
    /// after a few rounds stands for the step.
    fn keep_apart(&mut self) {
        let (walkers, v, pairs) = (&self.walkers, &mut self.velocities, &mut self.scratch.pairs);
        // The pairs that could meet within the step at their top speeds: at most a cell
        // apart, so in cells side by side. Taken in the order of their indices.
        pairs.clear();
        for (i, a) in walkers.iter().enumerate() {
            for k in 0..=1 {
                self.grid.ring(i, k, |b| {
                    let reach = a.radius + b.radius + (a.top_speed() + b.top_speed) * STEP;
                    if b.index > i && (b.position - a.position).norm_sqr() < reach * reach {
                        pairs.push((i, b.index));
                    }
                });
            }
        }
        pairs.sort_unstable();
        // Holding one pair may leave another closing on it: round until none is (each
        // round past the last correcting one stops at least one person, so this ends).
        for round in 0.. {
            let mut closing = false;
            for &(i, j) in pairs.iter() {
                let (a, b) = (&walkers[i], &walkers[j]);
                let Some(excess) = excess_closing(a.position, b.position, v[i] - v[j], a.radius + b.radius) else {
                    continue;
                };
                closing = true;
                let n = (b.position - a.position) / length(b.position - a.position);
                if round >= KEEP_APART_ROUNDS {
                    (v[i], v[j]) = (Point::default(), Point::default());
                } else {
                    v[i] -= n * (excess / 2.0);
                    v[j] += n * (excess / 2.0);
                    v[i] = capped(v[i], a.top_speed());
                    v[j] = capped(v[j], b.top_speed());
                }
            }
            if !closing {
                return;
            }
        }
    }

    /// Each person's last leg: its obstacle's index, when and where the leg began, and its
    /// velocity.
    pub fn last_legs(&self) -> impl Iterator<Item = (usize, f64, Point, Point)> + '_ {
        self.walkers.iter().filter_map(|w| w.last_leg.map(|(t, p, v)| (w.obstacle, t, p, v)))
    }

    /// Every obstacle's way: the people's as walked so far, standing where they got to.
    pub fn into_ways(mut self) -> Vec<ObstaclePath> {
        let end = self.time();
        let mut legs: Vec<Vec<(f64, Point, Point)>> = vec![Vec::new(); self.walkers.len()];
        for &(k, t, p, v) in &self.legs {
            legs[k].push((t, p, v));
        }
        for (w, legs) in self.walkers.iter().zip(legs) {
            let start = legs.first().map_or(w.position, |l| l.1);
            self.paths[w.obstacle] = ObstaclePath::walked(start, legs, end);
        }
        self.paths
    }
}

/// How much faster than their gap allows two bodies `reach` apart (centre to centre) at
/// the least close along the line between them within a step, at relative velocity `dv`
/// (the first's less the second's); `None` when they do not. Closing no faster than the gap
/// over the step keeps them apart all through it: the gap along that line bounds the
/// distance from below, and it is linear in time.
fn excess_closing(a: Point, b: Point, dv: Point, reach: f64) -> Option<f64> {
    let dp = b - a;
    let d = length(dp);
    if d == 0.0 {
        return None;
    }
    let closing = (dv.re * dp.re + dv.im * dp.im) / d;
    let allowed = ((d - reach) / STEP).max(0.0);
    (closing > allowed + 1e-12).then_some(closing - allowed)
}

fn dot(a: Point, b: Point) -> f64 {
    a.re * b.re + a.im * b.im
}

fn capped(v: Point, cap: f64) -> Point {
    let s = length(v);
    if s > cap {
        v * (cap / s)
    } else {
        v
    }
}

fn area(walkers: &[Walker]) -> Area {
    let points = walkers.iter().flat_map(|w| std::iter::once(w.position).chain(w.walk.goals.iter().copied()));
    let (mut min, mut max) =
        (Point::new(f64::INFINITY, f64::INFINITY), Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY));
    for p in points {
        min = Point::new(min.re.min(p.re), min.im.min(p.im));
        max = Point::new(max.re.max(p.re), max.im.max(p.im));
    }
    Area { min, max }
}

/// What one person's step reuses.
#[derive(Debug, Clone, Default)]
struct Scratch {
    lines: Vec<orca::OrcaLine>,
    projected: Vec<orca::OrcaLine>,
    /// The nearest neighbours, nearest first, as keys: the squared distance's bits above
    /// the index (at most [`MAX_NEIGHBOURS`]).
    near: Vec<u128>,
    pairs: Vec<(usize, usize)>,
}

/// Walker `i`'s velocity for the next step, from everyone as they are now (`seen`: the
/// people in their order, then the obstacles and vehicles it sees).
fn velocity(
    walkers: &mut [Walker],
    i: usize,
    seen: &[orca::Body],
    room: &Room,
    area: &Area,
    grid: &Grid,
    s: &mut Scratch,
) -> Point {
    let mut preferred = walkers[i].preferred(area, room);
    if walkers[i].group.is_some() {
        preferred += cohesion(walkers, i);
    }
    let me = &walkers[i];
    let body = seen[i];
    let horizon = HORIZON_RADII * me.radius / me.walk.preferred_speed;
    nearest(walkers, i, &seen[walkers.len()..], grid, horizon, &mut s.near);
    // Another person avoids in turn; an obstacle or a vehicle does not.
    let neighbour = |j: usize| (seen[j], j < walkers.len());
    let walls = wall_points(room, me.position, me.radius + me.top_speed() * horizon);
    match me.walk.behaviour {
        Behaviour::Orca | Behaviour::Straight => {
            s.lines.clear();
            for nearest in walls {
                s.lines.extend(orca::line_off_wall(me.position, me.radius, nearest, horizon, STEP));
            }
            let hard = s.lines.len();
            for &k in &s.near {
                let (other, avoids) = neighbour(k as u64 as usize);
                let share = if avoids { 0.5 } else { 1.0 };
                s.lines.push(orca::line_to(body, other, share, horizon, STEP));
            }
            let v = orca::solve(&s.lines, hard, me.top_speed(), preferred, &mut s.projected);
            // Held back by someone walking towards it, a person steps to the right, as
            // everyone does, so that two meeting pass and a crowd bound for one place turns
            // about it rather than jams. (Not by people standing: along a row of them, a step
            // to the right may be into the row.)
            let oncoming = s.near.iter().any(|&k| {
                let (other, _) = neighbour(k as u64 as usize);
                length(other.velocity) > WALKING * me.walk.preferred_speed
                    && dot(other.position - me.position, other.velocity - me.velocity) < 0.0
            });
            if !oncoming || length(v - preferred) <= BLOCKED * me.walk.preferred_speed {
                return v;
            }
            let right = preferred * Point::from_polar(1.0, -KEEP_RIGHT);
            orca::solve(&s.lines, hard, me.top_speed(), right, &mut s.projected)
        }
        Behaviour::SocialForce => {
            let near = s.near.iter().map(|&k| neighbour(k as u64 as usize).0);
            social_force::velocity(body, preferred, me.walk.preferred_speed, me.top_speed(), near, walls, STEP)
        }
    }
}

/// Walker `i`'s nearest neighbours, at most [`MAX_NEIGHBOURS`], nearest first, into
/// `near`: the people (from the grid) and `others` within what `horizon` can bring together.
fn nearest(walkers: &[Walker], i: usize, others: &[orca::Body], grid: &Grid, horizon: f64, near: &mut Vec<u128>) {
    let me = &walkers[i];
    // The nearest neighbours within what the horizon can bring together.
    let reach = |radius: f64, speed: f64| me.radius + radius + (me.top_speed() + speed) * horizon;
    // The nearest, in order: keyed by the square of the distance (which orders alike; a
    // non-negative float's bits order as the float does), the earlier person first among
    // equals.
    near.clear();
    let key = |d2: f64, j: usize| (u128::from(d2.to_bits()) << 64) | j as u128;
    for (j, o) in others.iter().enumerate() {
        let (d2, r) = ((o.position - me.position).norm_sqr(), reach(o.radius, length(o.velocity)));
        if d2 < r * r {
            keep_nearest(near, key(d2, walkers.len() + j));
        }
    }
    // The people ring by ring of cells about it, until nobody further could be within reach
    // or nearer than the farthest kept.
    let (largest, fastest) = grid.largest();
    let farthest_reach = reach(largest, fastest);
    for k in 0.. {
        grid.ring(i, k, |w| {
            let (d2, r) = ((w.position - me.position).norm_sqr(), reach(w.radius, w.top_speed));
            if w.index != i && d2 < r * r {
                keep_nearest(near, key(d2, w.index));
            }
        });
        let kept = near.get(MAX_NEIGHBOURS - 1).map(|&k| f64::from_bits((k >> 64) as u64));
        match grid.beyond(i, k) {
            Some(d) if d < farthest_reach && kept.is_none_or(|d2| d * d <= d2) => {}
            _ => break,
        }
    }
}

/// Keeps `key` among the [`MAX_NEIGHBOURS`] least of `near` (ascending) if it is one of them.
fn keep_nearest(near: &mut Vec<u128>, key: u128) {
    if near.len() == MAX_NEIGHBOURS {
        if near[MAX_NEIGHBOURS - 1] <= key {
            return;
        }
        near.pop();
    }
    // Insertion from the end: the list is short.
    let mut at = near.len();
    near.push(key);
    while at > 0 && near[at - 1] > key {
        near[at] = near[at - 1];
        at -= 1;
    }
    near[at] = key;
}

/// Walker `i`'s pull towards the rest of its group, added to the velocity it prefers: none
/// while it is within a body's width of them side by side (its radius times two and one for
/// each other member, from their centre), growing to its preferred speed at twice that. One
/// ahead is pulled back and waits; one behind catches up.
fn cohesion(walkers: &[Walker], i: usize) -> Point {
    let me = &walkers[i];
    let Some(group) = me.group else { return Point::default() };
    let (mut sum, mut n) = (Point::default(), 0usize);
    for (j, w) in walkers.iter().enumerate() {
        if j != i && w.group == Some(group) {
            sum += w.position;
            n += 1;
        }
    }
    let to = sum / n.max(1) as f64 - me.position;
    let (d, reach) = (length(to), me.radius * (2.0 + n as f64));
    if n == 0 || d <= reach {
        return Point::default();
    }
    to / d * (me.walk.preferred_speed * ((d - reach) / reach).min(1.0))
}

/// The nearest point of each wall segment and furniture edge within `range` of `centre`.
fn wall_points(room: &Room, centre: Point, range: f64) -> impl Iterator<Item = Point> + '_ {
    let walls = room.walls().iter().flat_map(|w| w.windows(2).map(|s| (s[0], s[1])));
    let edges = room.polygons().iter().flat_map(|p| polygon_edges(p));
    walls
        .chain(edges)
        .map(move |(a, b)| nearest_on_segment(centre, a, b))
        .filter(move |p| (p - centre).norm_sqr() < range * range)
}

mod grid;
#[cfg(test)]
mod tests;
