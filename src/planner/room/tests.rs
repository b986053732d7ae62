//! The room's panels and flow, held to their exact values and walked by streamlines.

use super::*;
use crate::planner::{Field, Sink};
use std::sync::Arc;

fn p(x: f64, y: f64) -> Point {
    Point::new(x, y)
}

/// A 2 m square view, a table and a wall with a bend, a 7 cm robot.
fn furnished() -> RoomShape {
    RoomShape {
        walls: vec![vec![p(-0.3, -1.0), p(-0.3, -0.2), p(0.1, -0.2)]],
        obstacles: vec![vec![p(0.3, 0.3), p(0.7, 0.3), p(0.7, 0.6), p(0.3, 0.6)]],
        view: Some(vec![p(-1.0, -1.0), p(1.0, -1.0), p(1.0, 1.0), p(-1.0, 1.0)]),
    }
}

/// Just beyond `FAR` lengths a panel's series is within 3.1e-6 of its flow, all round
/// (the series' next term, `(L/r)⁴/80`, is 3.05e-6 there); nearer, and at every
/// distance with `FarField::Exact`, the flow is the log's.
#[test]
fn a_far_panel_flows_as_its_series() {
    let (a, b) = (p(0.1, 0.2), p(0.13, 0.22));
    let normal = (b - a) / (b - a).norm() * p(0.0, -1.0);
    let log = |z: Point| ((z - a) / (z - b)).ln() * ((b - a).conj() / (b - a).norm());
    let error = |panel: &Panel, z: Point| (panel.source_flow(z) - log(z)).norm() / log(z).norm();
    let [series, exact] = [FarField::Series, FarField::Exact].map(|f| Panel::new(a, b, normal, [normal; 2], f));
    let round = |r: f64| (0..64).map(move |k| series.mid() + Point::from_polar(r, f64::from(k) * 0.1));
    let worst = round(FAR * series.length() * 1.000_001).map(|z| error(&series, z)).fold(0.0, f64::max);
    assert!((3.0e-6..3.1e-6).contains(&worst), "{worst:e}");
    for z in round(0.5 * FAR * series.length()).chain(round(3.0 * FAR * series.length())) {
        let near = (z - series.mid()).norm() < FAR * series.length();
        if near {
            assert!(error(&series, z) < 1e-14, "the log's own, nearer, at {z}");
        }
        assert!(error(&exact, z) < 1e-14, "the log's own, exact, at {z}");
    }
}

/// Runs of panels far from the point flow as their expansions: against every panel
/// taken by itself, for the same densities, within the bound of `tree::THETA` and
/// `tree::ORDER` (1.85e-6 a unit of density and length over the distance to the run's
/// centre, so 2.7e-6 over the distance to the panel's midpoint), at random free points
/// of random rooms, for a random goal.
#[test]
fn far_runs_of_panels_flow_as_their_expansions() {
    let mut rng = Random(11);
    let mut worst: f64 = 0.0;
    for _ in 0..4 {
        let room = Room::new(&random_room(&mut rng), 0.07, 0.03).unwrap().unwrap();
        let goal = free_point(&mut rng, &room, 0.1);
        let mut sink = RoomSink::for_room(&room);
        room.sink_flow(goal, &mut sink);
        for _ in 0..500 {
            let z = free_point(&mut rng, &room, 0.0);
            let each = room.panels.iter().zip(&sink.densities);
            let alone: Point = each.clone().map(|(q, s)| q.source_flow(z) * s).sum();
            let scale: f64 = each.map(|(q, s)| s.abs() * q.length() / (z - q.mid()).norm()).sum();
            let error = (room.tree.flow(&room.panels, &sink.densities, &sink.moments, z) - alone).norm() / scale;
            assert!(error < 2.7e-6, "{error:e} at {z}");
            worst = worst.max(error);
        }
    }
    assert!(worst > 1e-12, "some runs were far enough to be expanded: {worst:e}");
    eprintln!("worst error of the expansions over the densities' scale: {worst:e}");
}

#[test]
fn a_bad_room_is_refused_naming_the_item() {
    let mut shape = furnished();
    shape.walls.push(vec![p(0.0, 0.0), p(0.0, 0.0), p(0.5, 0.0)]);
    let e = shape.check().unwrap_err().to_string();
    assert_eq!(e, "`walls[1].points`: the edge from point 0 to point 1 has no length");
    let mut shape = furnished();
    shape.obstacles.push(vec![p(0.0, 0.0), p(0.4, 0.4), p(0.4, 0.0), p(0.0, 0.4)]);
    let e = shape.check().unwrap_err().to_string();
    assert_eq!(e, "`static_obstacles[1].points`: the polygon is not simple: two of its edges cross");
    let mut shape = furnished();
    shape.obstacles[0].truncate(2);
    assert!(shape.check().unwrap_err().to_string().contains("needs at least 3 points, has 2"));
    let mut shape = furnished();
    shape.walls[0][1] = p(f64::NAN, 0.0);
    assert!(shape.check().unwrap_err().to_string().contains("`walls[0].points`: point 1 is not finite"));
    assert!(furnished().check().is_ok());
    // A ring of walls closes where it began; one that crosses itself on the way is refused.
    let mut shape = furnished();
    shape.walls.push(vec![p(0.0, 0.0), p(0.2, 0.0), p(0.2, 0.2), p(0.0, 0.2), p(0.0, 0.0)]);
    assert!(shape.check().is_ok());
    shape.walls[1] = vec![p(0.0, 0.0), p(0.2, 0.0), p(0.2, 0.2), p(0.1, -0.1)];
    assert_eq!(shape.check().unwrap_err().to_string(), "`walls[1].points`: the wall crosses itself");
}

/// The clearance is the robot centre's distance to the grown room; the free region's
/// parts say what can be reached: a wall across the view cuts it in two, a doorway in it
/// joins them again.
#[test]
fn reachability_follows_the_walls_and_the_doorways() {
    let view = vec![p(-1.0, -1.0), p(1.0, -1.0), p(1.0, 1.0), p(-1.0, 1.0)];
    let cut = RoomShape { walls: vec![vec![p(0.0, -1.2), p(0.0, 1.2)]], obstacles: vec![], view: Some(view.clone()) };
    let room = Room::new(&cut, 0.07, 0.05).unwrap().unwrap();
    assert!((room.clearance(p(0.5, 0.0)) - 0.43).abs() < 1e-12, "{}", room.clearance(p(0.5, 0.0)));
    assert!(room.clearance(p(0.05, 0.0)) < 0.0);
    assert!(room.reachable(p(0.5, 0.0), p(0.5, 0.8)));
    assert!(!room.reachable(p(-0.5, 0.0), p(0.5, 0.0)));
    let door = RoomShape {
        walls: vec![vec![p(0.0, -1.2), p(0.0, -0.2)], vec![p(0.0, 0.2), p(0.0, 1.2)]],
        obstacles: vec![],
        view: Some(view),
    };
    let room = Room::new(&door, 0.07, 0.05).unwrap().unwrap();
    assert!(room.reachable(p(-0.5, 0.0), p(0.5, 0.0)), "a 40 cm doorway passes a 14 cm robot");
    assert!(room.closed_at(p(0.5, 0.0)));
    let narrow = RoomShape {
        walls: vec![vec![p(0.0, -1.2), p(0.0, -0.06)], vec![p(0.0, 0.06), p(0.0, 1.2)]],
        obstacles: vec![],
        view: door.view.clone(),
    };
    let room = Room::new(&narrow, 0.07, 0.05).unwrap().unwrap();
    assert!(!room.reachable(p(-0.5, 0.0), p(0.5, 0.0)), "a 12 cm doorway does not");
}

/// The panels' densities make a unit sink's flow tangent at every panel's midpoint, in
/// a closed room whose uniform source balances the sink's flux (to rounding: the system
/// takes each panel's flow as the field evaluates it, by itself or in a run's
/// expansion).
#[test]
fn the_sink_flow_is_tangent_at_every_panel() {
    for (far_field, within) in [(FarField::Series, 2e-8), (FarField::Multipole, 2e-8)] {
        let panels = Panels { spacing: 0.04, corner_turn: None, far_field };
        let room = Room::with_panels(&furnished(), 0.07, panels).unwrap().unwrap();
        let goal = p(0.5, -0.6);
        assert!(room.closed_at(goal));
        let mut sink = RoomSink::default();
        room.sink_flow(goal, &mut sink);
        let mut worst: f64 = 0.0;
        let mut flux = 0.0;
        for panel in room.panels() {
            let at = panel.mid() - panel.normal * (1e-9 * panel.length());
            let f = room.eval_sink(&sink, at);
            worst = worst.max((f * panel.normal).re.abs() / f.norm());
            // The sink's and the closure's flux through the boundary, without the panels.
            let (center, density) = sink.closure.unwrap();
            let bare = Space::Free.sink(at, goal) + closure_flow(center, at) * density;
            flux += (bare * panel.normal).re * panel.length();
        }
        eprintln!("{far_field:?}: the normal flow at the midpoints, at most {worst:e} of the speed");
        assert!(worst < within, "{far_field:?}: {worst}");
        assert!(flux.abs() < 0.02 * std::f64::consts::TAU, "the closure balances the sink: {flux}");
    }
}

/// A small deterministic generator for the random rooms (xorshift64*).
/// The depth's pass that skips far panels finds, to the bit, what a pass over every
/// panel finds: at random points of random rooms, on panels' ends and midpoints, and
/// beyond the boundary.
#[test]
fn the_depth_skips_only_panels_that_cannot_be_nearest() {
    let every = |room: &Room, z: Point| {
        let mut best = (f64::INFINITY, 0usize, 0.5);
        for (k, panel) in room.panels.iter().enumerate() {
            let (d, t) = panel.nearest(z);
            if d < best.0 {
                best = (d, k, t);
            }
        }
        room.panels[best.1].depth_and_inward(z, best.0, best.2)
    };
    let mut rng = Random(7);
    for _ in 0..4 {
        let room = Room::new(&random_room(&mut rng), 0.07, 0.03).unwrap().unwrap();
        let on = room.panels.iter().flat_map(|q| [q.a, q.b, q.mid]);
        let points: Vec<Point> = on.chain((0..2000).map(|_| rng.point(1.1))).collect();
        for z in points {
            let (depth, normal) = every(&room, z);
            let (got, inward) = room.depth_and_inward(z);
            assert_eq!((got.to_bits(), inward), (depth.to_bits(), normal), "at {z}");
        }
    }
}

struct Random(u64);

impl Random {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn between(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
    fn point(&mut self, half: f64) -> Point {
        p(self.between(-half, half), self.between(-half, half))
    }
}

/// A 2 m square view with two pieces of furniture (a rectangle and a triangle, 15-50 cm)
/// and one or two walls (one or two legs of 30-80 cm), placed anywhere.
fn random_room(rng: &mut Random) -> RoomShape {
    let view = Some(vec![p(-1.0, -1.0), p(1.0, -1.0), p(1.0, 1.0), p(-1.0, 1.0)]);
    let c = rng.point(0.7);
    let (w, h) = (rng.between(0.15, 0.5), rng.between(0.15, 0.5));
    let rectangle = vec![c, c + p(w, 0.0), c + p(w, h), c + p(0.0, h)];
    let c = rng.point(0.7);
    let triangle = vec![
        c,
        c + Point::from_polar(rng.between(0.15, 0.5), rng.between(0.0, std::f64::consts::TAU)),
        c + Point::from_polar(rng.between(0.15, 0.5), rng.between(0.0, std::f64::consts::TAU)),
    ];
    let mut walls = Vec::new();
    for _ in 0..1 + usize::from(rng.next() < 0.5) {
        let a = rng.point(0.9);
        let b = a + Point::from_polar(rng.between(0.3, 0.8), rng.between(0.0, std::f64::consts::TAU));
        let mut wall = vec![a, b];
        if rng.next() < 0.5 {
            let turn = rng.between(0.6, 2.0) * if rng.next() < 0.5 { 1.0 } else { -1.0 };
            wall.push(b + (b - a) / (b - a).norm() * Point::from_polar(rng.between(0.3, 0.8), turn));
        }
        walls.push(wall);
    }
    RoomShape { walls, obstacles: vec![rectangle, triangle], view }
}

/// A free point at least `clear` inside the field's boundary.
fn free_point(rng: &mut Random, room: &Room, clear: f64) -> Point {
    loop {
        let z = rng.point(1.0);
        if room.depth(z) > clear {
            return z;
        }
    }
}

/// The navigation field in `room` toward `goal`, no circles: what the robot follows.
fn navigation(room: &Room, goal: Point) -> Field {
    let sink = Sink { goal, strength: 0.01, c1: 20.0, reference_radius: 0.1 };
    let mut field = Field::empty(Space::Free, sink);
    field.set_room(Some(&Arc::new(room.clone())));
    field.rebuild(Space::Free, sink, &[]).unwrap();
    field
}

/// Follow the field's streamline from `start` in steps of 5 mm (midpoint rule), sliding
/// along the boundary where a step would meet it (as the robot's supervisor keeps it
/// off): whether it reached within 2 cm of `goal`, and where and why it ended.
fn trace(room: &Room, field: &Field, goal: Point, start: Point) -> (bool, Point, &'static str, usize) {
    const STEP: f64 = 0.005;
    let direction = |z: Point| {
        let v = field.velocity(z).ok()?;
        (v.norm() > 1e-12).then(|| v / v.norm())
    };
    let mut z = start;
    for k in 0..3000 {
        if (z - goal).norm() < 0.02 {
            return (true, z, "goal", k);
        }
        let Some(d1) = direction(z) else { return (false, z, "still", k) };
        let Some(d2) = direction(z + d1 * (0.5 * STEP)) else { return (false, z, "still", k) };
        let mut next = z + d2 * STEP;
        if room.depth(next) < 0.002 {
            // Held 2 mm off the boundary, as the supervisor holds the robot off it: the
            // point is moved back along the depth's gradient (the boundary's normal), so
            // that the field slides it along the boundary.
            let g = |dz: Point| (room.depth(next + dz) - room.depth(next - dz)) / 2e-4;
            let n = p(g(p(1e-4, 0.0)), g(p(0.0, 1e-4)));
            let n = n / n.norm().max(1e-12);
            next += n * (0.002 - room.depth(next));
            if room.depth(next) < 0.0 {
                return (false, z, "into the boundary", k);
            }
        }
        z = next;
    }
    (false, z, "steps", 3000)
}

/// From 10,000 random free points of 100 random furnished rooms, each reachable from its
/// room's goal, the navigation field's streamline (the room's flow, kept off the
/// boundary as the planner keeps it), held 2 mm off the boundary, reaches the goal from
/// at least 9,990 (99.9%; the run is seeded and reaches 9,990). Those it does not stall against the boundary
/// (asserted: none more than twice `ROOM_HOLD` inside it), where the flow is slowest (a
/// corner of the view far from the goal, the wedge of a wall's bend, where a grown
/// obstacle meets the view's edge) and the discrete field's error exceeds it: the
/// exact field has no minimum (docs/planner.md).
#[test]
fn streamlines_from_random_points_of_random_rooms_reach_the_goal() {
    // The rooms' panels 1 cm, shorter in the free region's corners (`room.corner_turn`).
    let panels = Panels { spacing: 0.01, corner_turn: Some(0.03), far_field: FarField::default() };
    // Each room drawn from its own seed, so that the rooms (each factorised once, the
    // bulk of the work) are built and traced on every core, alike whatever their number.
    let one_room = |k: u64| {
        let mut rng = Random(0x9E37_79B9_7F4A_7C15 ^ (k + 1).wrapping_mul(0xD1B5_4A32_D192_ED03));
        let shape = random_room(&mut rng);
        let room = Room::with_panels(&shape, 0.07, panels).unwrap().unwrap();
        let goal = free_point(&mut rng, &room, 0.05);
        assert!(room.closed_at(goal), "every part of a room inside a view is closed");
        let field = navigation(&room, goal);
        let runs: Vec<_> = (0..100)
            .map(|_| {
                let start = loop {
                    let z = free_point(&mut rng, &room, 0.01);
                    if room.reachable(z, goal) {
                        break z;
                    }
                };
                (start, trace(&room, &field, goal, start))
            })
            .collect();
        (room, goal, runs)
    };
    let threads = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get) as u64;
    let mut rooms: Vec<(u64, _)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|t| {
                let one_room = &one_room;
                scope.spawn(move || (t..100).step_by(threads as usize).map(|k| (k, one_room(k))).collect::<Vec<_>>())
            })
            .collect();
        workers.into_iter().flat_map(|w| w.join().unwrap()).collect()
    });
    rooms.sort_by_key(|(k, _)| *k);
    let (mut starts, mut reached) = (0, 0);
    let (mut missed, mut inside) = (Vec::new(), Vec::new());
    for (k, (room, goal, runs)) in &rooms {
        for &(start, (ok, end, why, steps)) in runs {
            starts += 1;
            if !ok && room.depth(end) >= 2.0 * super::ROOM_HOLD {
                inside.push(format!("room {k}: from {start:.3}: {why} at {end:.3} (depth {:.4})", room.depth(end)));
            }
            if ok {
                reached += 1;
            } else if missed.len() < 10 {
                missed.push(format!(
                    "room {k}: from {start:.3} to {goal:.3}: {why} after {steps} at {end:.3} (depth {:.4})",
                    room.depth(end)
                ));
            }
        }
    }
    println!("{reached} of {starts} streamlines reached the goal");
    assert!(reached * 10_000 >= starts * 9_990, "{reached} of {starts}; missed:\n{}", missed.join("\n"));
    // None stalls inside the room, where the exact field has no minimum: every miss ends
    // held against the boundary, within twice the band where the field takes the room's
    // flow at the band's inner edge (`ROOM_HOLD`); the misses' attractors lie in it.
    assert!(inside.is_empty(), "stalled inside the room:\n{}", inside.join("\n"));
}
