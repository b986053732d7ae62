//! The CAN traffic of a fleet on one bus: one vehicle's frames measured from the whole stack
//! in virtual time (E1 from arming to the goal, the gateway core against the simulated board
//! or drives), counted at their worst-case length on the bus and as SLCAN lines on the
//! adapter's serial line, and scaled to `n` vehicles (the gateway's heartbeat and NMT
//! broadcasts once, the rest once a vehicle).

use flowgate_protocol::{CanFrame, CanId};
use serde::Serialize;

use super::virtual_rig::{self, Options};
use super::Scenario;
use crate::gateway::core::input::RecordedInput;
use crate::gateway::core::CanEvent;

/// The bus and the serial line the figures are for.
pub const BITRATE: f64 = 1_000_000.0;
pub const SERIAL_BAUD: f64 = 921_600.0;
/// Bits a serial character takes (8N1).
const BITS_PER_CHAR: f64 = 10.0;

/// One vehicle's traffic, per second.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Traffic {
    pub frames: f64,
    /// Worst-case bit times on the bus.
    pub bus_bits: f64,
    /// SLCAN characters to the adapter (the gateway's frames) and from it (the bus's frames,
    /// and a `z` acknowledgement of each sent one).
    pub to_adapter: f64,
    pub from_adapter: f64,
}

impl std::ops::Add for Traffic {
    type Output = Traffic;
    fn add(self, o: Traffic) -> Traffic {
        Traffic {
            frames: self.frames + o.frames,
            bus_bits: self.bus_bits + o.bus_bits,
            to_adapter: self.to_adapter + o.to_adapter,
            from_adapter: self.from_adapter + o.from_adapter,
        }
    }
}

impl std::ops::Mul<f64> for Traffic {
    type Output = Traffic;
    fn mul(self, k: f64) -> Traffic {
        Traffic {
            frames: self.frames * k,
            bus_bits: self.bus_bits * k,
            to_adapter: self.to_adapter * k,
            from_adapter: self.from_adapter * k,
        }
    }
}

/// The traffic once a bus (the gateway's broadcasts) and once a vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Measured {
    pub shared: Traffic,
    pub per_vehicle: Traffic,
}

impl Measured {
    /// What `n` vehicles put on the bus.
    pub fn of(&self, n: usize) -> Traffic {
        self.shared + self.per_vehicle * n as f64
    }
}

/// The length of a frame's SLCAN line: `t`, the id, the length, two hex digits a byte, CR.
fn slcan_chars(f: &CanFrame) -> f64 {
    let id = if f.id().is_extended() { 8 } else { 3 };
    let data = if f.is_remote() { 0 } else { 2 * f.data().len() };
    (1 + id + 1 + data + 1) as f64
}

/// A frame the gateway sends once for the whole bus: its heartbeat, an NMT broadcast.
fn broadcast(f: &CanFrame) -> bool {
    matches!(f.id(), CanId::Standard(id) if id == 0 || (0x700..=0x77F).contains(&id))
}

/// One vehicle's traffic on E1, with the board (`cia402` false) or two CiA 402 drives.
pub fn measure(e1: &Scenario, cia402: bool) -> Measured {
    let options = Options { record_inputs: true, cia402, ..Options::default() };
    let run = virtual_rig::run(e1, options);
    let seconds = run.inputs.last().map_or(0.0, |r| r.at.secs()).max(f64::MIN_POSITIVE);
    let mut shared = Traffic::default();
    let mut vehicle = Traffic::default();
    for f in &run.can_sent {
        let t = Traffic {
            frames: 1.0,
            bus_bits: f64::from(f.worst_case_bits()),
            to_adapter: slcan_chars(f),
            from_adapter: 2.0,
        };
        if broadcast(f) {
            shared = shared + t;
        } else {
            vehicle = vehicle + t;
        }
    }
    for r in &run.inputs {
        if let RecordedInput::Can(CanEvent::Frame(f)) = &r.input {
            vehicle = vehicle
                + Traffic {
                    frames: 1.0,
                    bus_bits: f64::from(f.worst_case_bits()),
                    to_adapter: 0.0,
                    from_adapter: slcan_chars(f),
                };
        }
    }
    Measured { shared: shared * (1.0 / seconds), per_vehicle: vehicle * (1.0 / seconds) }
}

/// One row of the table: `n` vehicles' load on the bus and on each direction of the serial
/// line, as fractions.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Load {
    pub vehicles: usize,
    pub frames_per_s: f64,
    pub bus: f64,
    pub to_adapter: f64,
    pub from_adapter: f64,
}

impl Measured {
    pub fn load(&self, n: usize) -> Load {
        let t = self.of(n);
        Load {
            vehicles: n,
            frames_per_s: t.frames,
            bus: t.bus_bits / BITRATE,
            to_adapter: t.to_adapter * BITS_PER_CHAR / SERIAL_BAUD,
            from_adapter: t.from_adapter * BITS_PER_CHAR / SERIAL_BAUD,
        }
    }
}

/// The table docs/fleet.md carries: a row a backend and fleet size.
pub fn table(e1: &Scenario) -> String {
    let mut out = String::from(
        "| motors | vehicles | frames/s | bus at 1 Mbit/s | SLCAN line to adapter | from adapter |\n\
         |---|---|---|---|---|---|\n",
    );
    for (name, cia402) in [("board", false), ("CiA 402 drives", true)] {
        let m = measure(e1, cia402);
        for n in [1, 8] {
            let l = m.load(n);
            out += &format!(
                "| {name} | {n} | {:.0} | {:.1}% | {:.1}% | {:.1}% |\n",
                l.frames_per_s,
                100.0 * l.bus,
                100.0 * l.to_adapter,
                100.0 * l.from_adapter
            );
        }
    }
    out
}
