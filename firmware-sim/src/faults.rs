//! Seeded, reproducible faults, set from the scenario's `[faults]` table or the command
//! line (`--fault key=value`). Every fault is off by default.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Deserialize;

/// What goes wrong, and when (times in seconds since the simulator started).
#[derive(Debug, Clone, Default, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FaultPlan {
    /// Seed of every random fault.
    #[serde(default)]
    pub seed: u64,
    /// Probability that a byte the controller sends is dropped.
    #[serde(default)]
    pub serial_drop: f64,
    /// Probability that a byte the controller sends is corrupted (one bit flipped).
    #[serde(default)]
    pub serial_corrupt: f64,
    /// Corrupt only between these times `[from_s, to_s]` (default: the whole run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial_corrupt_during: Option<[f64; 2]>,
    /// Probability that a packet the controller sends goes out twice in a row.
    #[serde(default)]
    pub serial_duplicate: f64,
    /// Probability that, after a packet, one of the eight before it is sent again (a replay).
    #[serde(default)]
    pub serial_replay: f64,
    /// Duplicate and replay only between these times `[from_s, to_s]` (default: the whole run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial_repeat_during: Option<[f64; 2]>,
    /// At these times the controller's line emits a burst of `serial_burst_len` garbage bytes.
    #[serde(default)]
    pub serial_burst_at: Vec<f64>,
    #[serde(default = "default_burst")]
    pub serial_burst_len: usize,
    /// The PSD controller's clock runs fast by this much, parts per million (negative: slow).
    #[serde(default)]
    pub clock_drift_ppm: f64,
    /// Extra delay of every sample before it is sent, ms.
    #[serde(default)]
    pub sample_delay_ms: f64,
    /// Uniform jitter added to that delay, ± ms.
    #[serde(default)]
    pub sample_jitter_ms: f64,
    /// LED occlusions: `[led, from_s, to_s]`; the LED reads as a weak signal meanwhile.
    #[serde(default)]
    pub occlusions: Vec<[f64; 3]>,
    /// The PSD controller reports a fault `[at_s, code, detail]` (codes 2-5: overrun, LED
    /// driver, ambient saturation, internal).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controller_fault: Option<[f64; 3]>,
    /// The PSD controller resets (schedule lost, streaming stops, Fault::Reset sent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controller_reset_at: Option<f64>,
    /// The PSD controller's serial device vanishes (its pty closes, as when a USB adapter
    /// is pulled) and comes back `serial_vanish_s` later on a new pty behind the same link,
    /// with the controller freshly booted. Needs a pty endpoint with a link.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial_vanish_at: Option<f64>,
    #[serde(default = "default_vanish")]
    pub serial_vanish_s: f64,
    /// Other traffic on the bus: every 100 ms, a status frame from node 9, a frame on an id
    /// no motor message uses, and an undecodable (short) frame on the board's own status id.
    #[serde(default)]
    pub foreign_frames: bool,
    /// Probability that a CAN frame (either direction) is lost.
    #[serde(default)]
    pub can_loss: f64,
    /// The motor board stops sending heartbeats (it keeps working otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heartbeat_stop_at: Option<f64>,
    /// The motor board's driver faults: axes stop, state Fault.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board_fault_at: Option<f64>,
    /// The motor board reboots (power glitch): axes stop, boot-up heartbeat, Disabled.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board_reboot_at: Option<f64>,
    /// From this time another device on the bus sends velocity commands to node 1 every
    /// 20 ms (a second master).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_master_at: Option<f64>,
    /// The motor board goes bus-off at this time for `bus_off_s` seconds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bus_off_at: Option<f64>,
    #[serde(default = "default_bus_off")]
    pub bus_off_s: f64,
}

fn default_burst() -> usize {
    64
}
fn default_bus_off() -> f64 {
    1.0
}
fn default_vanish() -> f64 {
    0.5
}

impl FaultPlan {
    /// Parse `key=value` settings (the command line) over this plan.
    pub fn with_settings(&self, settings: &[String]) -> Result<Self, String> {
        if settings.is_empty() {
            return Ok(self.clone());
        }
        let mut table: toml::Table = toml::Table::try_from(self).map_err(|e| e.to_string())?;
        for s in settings {
            let (key, value) = s.split_once('=').ok_or_else(|| format!("fault `{s}`: expected key=value"))?;
            let parsed: toml::Table =
                toml::from_str(&format!("v = {value}")).map_err(|e| format!("fault `{s}`: {e}"))?;
            table.insert(key.trim().to_string(), parsed["v"].clone());
        }
        table.try_into().map_err(|e: toml::de::Error| format!("faults: {e}"))
    }

    /// Whether LED `led` is occluded at `t`.
    pub fn occluded(&self, led: u8, t: f64) -> bool {
        self.occlusions.iter().any(|o| o[0] as u8 == led && t >= o[1] && t < o[2])
    }

    /// Whether the board is bus-off at `t`.
    pub fn bus_off(&self, t: f64) -> bool {
        self.bus_off_at.is_some_and(|at| t >= at && t < at + self.bus_off_s)
    }
}

/// The random part of a fault plan: one seeded generator per link, so that the faults on
/// one link do not change when traffic on another does.
#[derive(Debug)]
pub struct SerialFaults {
    rng: ChaCha8Rng,
    drop: f64,
    corrupt: f64,
    corrupt_during: Option<[f64; 2]>,
    duplicate: f64,
    replay: f64,
    repeat_during: Option<[f64; 2]>,
    /// The last packets sent, for replays.
    history: [Option<flowgate_protocol::psd::Packet>; 8],
    next: usize,
    /// Packets sent twice, packets replayed so far.
    pub duplicated: u64,
    pub replayed: u64,
    /// Bytes dropped, bytes corrupted so far.
    pub dropped: u64,
    pub corrupted: u64,
}

impl SerialFaults {
    pub fn new(plan: &FaultPlan) -> Self {
        Self {
            rng: ChaCha8Rng::seed_from_u64(plan.seed ^ 0x5e71a1),
            drop: plan.serial_drop,
            corrupt: plan.serial_corrupt,
            corrupt_during: plan.serial_corrupt_during,
            duplicate: plan.serial_duplicate,
            replay: plan.serial_replay,
            repeat_during: plan.serial_repeat_during,
            history: [None; 8],
            next: 0,
            duplicated: 0,
            replayed: 0,
            dropped: 0,
            corrupted: 0,
        }
    }

    /// The packets that go out for `packet` sent at `t`: itself, maybe twice, maybe followed
    /// by a replay of an earlier one.
    pub fn packets(
        &mut self,
        t: f64,
        packet: flowgate_protocol::psd::Packet,
        out: &mut impl FnMut(flowgate_protocol::psd::Packet),
    ) {
        out(packet);
        let active = !matches!(self.repeat_during, Some([from, to]) if t < from || t >= to);
        if active && self.duplicate > 0.0 && self.rng.random_bool(self.duplicate.min(1.0)) {
            self.duplicated += 1;
            out(packet);
        }
        if active && self.replay > 0.0 && self.rng.random_bool(self.replay.min(1.0)) {
            let k = self.rng.random_range(0..self.history.len());
            if let Some(old) = self.history[k] {
                self.replayed += 1;
                out(old);
            }
        }
        self.history[self.next] = Some(packet);
        self.next = (self.next + 1) % self.history.len();
    }
    /// Apply drop and corruption to bytes sent at time `t`, in place.
    pub fn apply(&mut self, t: f64, bytes: &mut Vec<u8>) {
        let corrupt = match self.corrupt_during {
            Some([from, to]) if t < from || t >= to => 0.0,
            _ => self.corrupt,
        };
        if self.drop <= 0.0 && corrupt <= 0.0 {
            return;
        }
        let rng = &mut self.rng;
        let drop = self.drop;
        let before = bytes.len();
        bytes.retain(|_| !rng.random_bool(drop.min(1.0)));
        self.dropped += (before - bytes.len()) as u64;
        for b in bytes.iter_mut() {
            if rng.random_bool(corrupt.min(1.0)) {
                *b ^= 1 << rng.random_range(0..8);
                self.corrupted += 1;
            }
        }
    }
    /// A burst of garbage bytes (no zero bytes, so the receiver sees one over-long run).
    pub fn burst(&mut self, len: usize) -> Vec<u8> {
        (0..len).map(|_| self.rng.random_range(1..=255u8)).collect()
    }
    /// Uniform in ±1.
    pub fn unit(&mut self) -> f64 {
        self.rng.random_range(-1.0..1.0)
    }
}

/// CAN frame loss.
#[derive(Debug)]
pub struct CanFaults {
    rng: ChaCha8Rng,
    loss: f64,
    pub lost: u64,
}

impl CanFaults {
    pub fn new(plan: &FaultPlan) -> Self {
        Self { rng: ChaCha8Rng::seed_from_u64(plan.seed ^ 0xca7), loss: plan.can_loss, lost: 0 }
    }
    /// Whether this frame is lost.
    pub fn lose(&mut self) -> bool {
        let lost = self.loss > 0.0 && self.rng.random_bool(self.loss.min(1.0));
        self.lost += u64::from(lost);
        lost
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_override_the_plan() {
        let plan = FaultPlan::default()
            .with_settings(&["serial_drop=0.1".into(), "occlusions=[[1, 2.0, 3.0]]".into(), "board_fault_at=4".into()])
            .unwrap();
        assert_eq!(plan.serial_drop, 0.1);
        assert!(plan.occluded(1, 2.5) && !plan.occluded(1, 3.5) && !plan.occluded(2, 2.5));
        assert_eq!(plan.board_fault_at, Some(4.0));
        assert!(FaultPlan::default().with_settings(&["nonsense=1".into()]).unwrap_err().contains("nonsense"));
        assert!(FaultPlan::default().with_settings(&["serial_drop".into()]).is_err());
    }

    #[test]
    fn corruption_keeps_to_its_window() {
        let plan = FaultPlan { serial_corrupt: 1.0, serial_corrupt_during: Some([1.0, 2.0]), ..FaultPlan::default() };
        let mut f = SerialFaults::new(&plan);
        let mut before = vec![0x55u8; 32];
        f.apply(0.5, &mut before);
        assert_eq!(before, vec![0x55u8; 32]);
        let mut during = vec![0x55u8; 32];
        f.apply(1.5, &mut during);
        assert!(during.iter().all(|&b| b != 0x55));
    }

    #[test]
    fn serial_faults_are_reproducible() {
        let plan = FaultPlan { serial_drop: 0.2, serial_corrupt: 0.1, seed: 7, ..FaultPlan::default() };
        let run = || {
            let mut f = SerialFaults::new(&plan);
            let mut bytes: Vec<u8> = (0..=255).collect();
            f.apply(0.0, &mut bytes);
            (bytes, f.dropped, f.corrupted)
        };
        let (a, dropped, corrupted) = run();
        assert_eq!(a, run().0);
        assert!(dropped > 20 && corrupted > 5, "{dropped} {corrupted}");
    }
}
