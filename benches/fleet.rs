//! What one cycle of a fleet's control costs (`cargo bench --bench fleet`;
//! docs/performance.md, "A fleet's cycle"): the 8-vehicle swap round the table
//! (`scenarios/fleet/swap-8-table.toml`) with five obstacles crossing the room besides, so
//! that every vehicle plans on 7 vehicles and 5 obstacles among the table and two shelves.
//! Timed: [`FleetControl::cycle`], every vehicle's obstacles, field, supervisor and wheel
//! speeds, in priority order, on one thread; the world's step is not. Five obstacles and
//! eight vehicles take 21 LEDs, more than the simulated controller drives (16): the scenario is built here,
//! past the load-time check, to time the control a larger controller would feed.

use std::path::Path;
use std::time::Instant;

use flowgate::lab::fleet::{FleetControl, FleetOptions};
use flowgate::lab::Scenario;
use flowgate_sim::scenario::{Motion, ObstacleSpec};
use flowgate_sim::world::fleet::Fleet;
use hdrhistogram::Histogram;

const EPISODES: u64 = 20;

fn main() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/fleet/swap-8-table.toml");
    let base = Scenario::load(&path).expect("scenario");
    let crossing = [
        ([-0.6, 0.6], [0.03, -0.02]),
        ([0.6, 0.6], [-0.03, -0.02]),
        ([0.0, -0.7], [0.0, 0.03]),
        ([-0.6, -0.6], [0.03, 0.02]),
        ([0.6, -0.6], [-0.03, 0.02]),
    ];
    let mut histogram = Histogram::<u64>::new(3).expect("histogram");
    let mut cycles = 0u64;
    for i in 0..EPISODES {
        let mut s = base.clone();
        s.sim = base.sim.swap_episode(1, i);
        s.sim.obstacles = crossing
            .iter()
            .map(|&(start, velocity)| ObstacleSpec::scripted(0.05, start, Motion::Constant { velocity }))
            .collect();
        let mut fleet = Fleet::new(&s.sim);
        let mut control = FleetControl::new(&s, FleetOptions::default());
        while fleet.time() < s.time_limit && control.running(fleet.time()) {
            let start = Instant::now();
            control.cycle(&mut fleet);
            let _ = histogram.record(start.elapsed().as_nanos() as u64);
            cycles += 1;
            fleet.step(s.sensing.sample_time);
        }
    }
    let us = |q: f64| histogram.value_at_quantile(q) as f64 / 1e3;
    println!(
        "a fleet's cycle, 8 vehicles each planning on 7 vehicles and 5 obstacles in a furnished room ({cycles} cycles, {EPISODES} episodes): p50 {:.0} µs, p99 {:.0} µs, p99.9 {:.0} µs, max {:.0} µs; T = {:.0} ms",
        us(0.5),
        us(0.99),
        us(0.999),
        histogram.max() as f64 / 1e3,
        base.sensing.sample_time * 1e3
    );
}
