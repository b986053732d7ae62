//! What one cycle of a fleet's control costs (`cargo bench --bench fleet`;
//! docs/performance.md, "A fleet's cycle"): the 8-vehicle swap round the table
//! (`scenarios/fleet/swap-8-table.toml`) with five obstacles crossing the room besides, so
//! that every vehicle plans on 7 vehicles and 5 obstacles among the table and two shelves.
//! Timed: [`FleetControl::cycle`], every vehicle's obstacles, field, supervisor and wheel
//! speeds, in priority order, on one thread; the world's step is not. Five obstacles and
//! eight vehicles take 21 LEDs, more than the simulated controller drives (16): the scenario is built here,
//! past the load-time check, to time the control a larger controller would feed.
//!
//! Then the same fleet through the whole stack ([`VirtualRig`]), the simulated controller
//! driving 21 LEDs: timed, each handling of the controller's bytes that ran a cycle, the
//! gateway core's decode of them and its cycle of every vehicle (tracking, each vehicle's
//! field, supervisor and command frame), on one thread; the firmware and the world are not.

use std::path::Path;
use std::time::Instant;

use flowgate::gateway::core::State;
use flowgate::lab::fleet::{FleetControl, FleetOptions};
use flowgate::lab::virtual_rig::{Options, VirtualRig};
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
    let episode = |i: u64| {
        let mut s = base.clone();
        s.sim = base.sim.swap_episode(1, i);
        s.sim.obstacles = crossing
            .iter()
            .map(|&(start, velocity)| ObstacleSpec::scripted(0.05, start, Motion::Constant { velocity }))
            .collect();
        s
    };
    let mut histogram = Histogram::<u64>::new(3).expect("histogram");
    let mut cycles = 0u64;
    for i in 0..EPISODES {
        let s = episode(i);
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
    row("a fleet's cycle", &histogram, cycles, base.sensing.sample_time);

    let mut histogram = Histogram::<u64>::new(3).expect("histogram");
    let mut cycles = 0u64;
    for i in 0..EPISODES {
        let s = episode(i);
        let options = Options { controller_leds: Some(21), time_cycles: true, ..Options::default() };
        let mut rig = VirtualRig::new(&s, options);
        let running = |rig: &VirtualRig| {
            let core = rig.core();
            (0..core.vehicle_count()).filter(|&k| core.vehicle_state(k) == Some(State::Running)).count()
        };
        while rig.time() < s.time_limit && running(&rig) + usize::from(rig.time() < 1.0) > 0 {
            let (before, all) = (rig.cycle_ns().len(), running(&rig) == 8);
            rig.step();
            if all {
                for &ns in &rig.cycle_ns()[before..] {
                    let _ = histogram.record(ns);
                    cycles += 1;
                }
            }
        }
    }
    row("the gateway core's cycle", &histogram, cycles, base.sensing.sample_time);
}

fn row(what: &str, histogram: &Histogram<u64>, cycles: u64, t: f64) {
    let us = |q: f64| histogram.value_at_quantile(q) as f64 / 1e3;
    println!(
        "{what}, 8 vehicles each planning on 7 vehicles and 5 obstacles in a furnished room ({cycles} cycles, {EPISODES} episodes): p50 {:.0} µs, p99 {:.0} µs, p99.9 {:.0} µs, max {:.0} µs; T = {:.0} ms",
        us(0.5),
        us(0.99),
        us(0.999),
        histogram.max() as f64 / 1e3,
        t * 1e3
    );
}
