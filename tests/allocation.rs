//! The per-sample path allocates nothing. The whole stack in virtual time (the gateway
//! core, and the simulated controller, adapter, motor board, wires and world around it)
//! runs four seconds of cycles with the robot driving round its obstacle, and a global
//! allocator counts every heap allocation the thread makes meanwhile: there must be none.
//! Its own test binary, so that the counting allocator serves nothing else.

// The counting allocator below implements `GlobalAlloc`, an unsafe trait: it hands every call
// to the system allocator unchanged.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use flowgate::gateway::core::State;
use flowgate::lab::virtual_rig::{CanTransport, Options, VirtualRig};
use flowgate::lab::Scenario;

thread_local! {
    /// Allocations (and reallocations) made by this thread. Const-initialised and without a
    /// destructor, so the allocator can reach it at any time without allocating itself.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count_one() {
    let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
}

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

struct Counting;

// SAFETY: every call goes to the system allocator with its arguments unchanged; counting
// touches only a thread-local `Cell` that needs no allocation.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count_one();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn load(name: &str) -> Scenario {
    Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(name)).unwrap()
}

/// Run `scenario` until 2 s in (armed, started, driving, its buffers at their size), then
/// count allocations until 6 s, the robot still on its way; returns them, the cycles run
/// meanwhile and the cycles four seconds hold at the scenario's period.
fn steady_seconds(scenario: &str, options: Options) -> (u64, u64, u64) {
    let mut rig = VirtualRig::new(&load(scenario), options);
    rig.run_until(2.0);
    assert_eq!(rig.core().state(), State::Running, "{scenario}: not running at 2 s");
    let (cycles, before) = (rig.core().counters().cycles, allocations());
    rig.run_until(6.0);
    let made = allocations() - before;
    assert_eq!(rig.core().state(), State::Running, "{scenario}: not running at 6 s");
    let due = (4.0 / rig.core().rig().sample_period.as_secs_f64()) as u64;
    (made, rig.core().counters().cycles - cycles, due)
}

/// The counter counts: a run from its start allocates (the rig, the core, their buffers).
#[test]
fn the_counter_sees_allocations() {
    let before = allocations();
    let mut rig = VirtualRig::new(&load("e1-standing-obstacle.toml"), Options::default());
    rig.run_until(0.5);
    assert!(allocations() - before > 10, "{} allocations", allocations() - before);
}

/// Free space (E1) and the lane (E2, whose field keeps its fit's workspace), over SLCAN and
/// SocketCAN, with CiA 402 drives, and with the low-latency mode's rehearsal at every event:
/// four seconds of cycles, every one of them run, not one allocation.
#[test]
fn four_seconds_of_cycles_allocate_nothing() {
    let runs = [
        ("e1-standing-obstacle.toml", "SLCAN", Options::default()),
        ("e1-standing-obstacle.toml", "SocketCAN", Options { can: CanTransport::SocketCan, ..Options::default() }),
        ("e1-standing-obstacle.toml", "CiA 402", Options { cia402: true, ..Options::default() }),
        ("e1-standing-obstacle.toml", "rehearsing", Options { rehearse: true, ..Options::default() }),
        ("e2-lane-head-on.toml", "SLCAN", Options::default()),
        ("rooms/warehouse-aisle.toml", "SLCAN, in a room", Options::default()),
    ];
    for (scenario, how, options) in runs {
        let (made, cycles, due) = steady_seconds(scenario, options);
        eprintln!("{scenario} ({how}): {cycles} cycles, {made} allocations");
        assert!(cycles + 1 >= due, "{scenario} ({how}): {cycles} cycles in four seconds, {due} due");
        assert_eq!(made, 0, "{scenario} ({how}): {made} allocations in {cycles} cycles");
    }
}
