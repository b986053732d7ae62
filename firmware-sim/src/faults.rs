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
    /// Drop only between these times `[from_s, to_s]` (default: the whole run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial_drop_during: Option<[f64; 2]>,
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
    /// A delay that creeps in: `[from_s, to_s, extra_ms]`, growing linearly from nothing at
    /// `from_s` to `extra_ms` at `to_s` and staying there (a step when `from_s == to_s`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sample_delay_ramp: Option<[f64; 3]>,
    /// The ramp's extra delay is gone from this time on (default: it stays).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sample_delay_until: Option<f64>,
    /// The controller holds its time-sync replies back `[from_s, to_s, ms]`: round trips
    /// that long.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sync_reply_hold: Option<[f64; 3]>,
    /// The controller's line goes silent over `[from_s, to_s)`: nothing it sends arrives.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial_silence: Option<[f64; 2]>,
    /// LED occlusions: `[led, from_s, to_s]`; the LED reads as a weak signal meanwhile.
    #[serde(default)]
    pub occlusions: Vec<[f64; 3]>,
    /// LED reflections: `[led, from_s, to_s, dx_m]`; the LED reads `dx_m` off along the floor's
    /// x axis meanwhile, a valid sample in the wrong place.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub reflections: Vec<[f64; 4]>,
    /// The PSD controller reports a fault `[at_s, code, detail]` (codes 2-5: overrun, LED
    /// driver, ambient saturation, internal).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controller_fault: Option<[f64; 3]>,
    /// The first packet on the line from this time goes out twice: first with its sequence
    /// number 0x7FFF ahead and a valid CRC (a bit error the CRC missed), then as it is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seq_jump_at: Option<f64>,
    /// The first frame from this time carries its counter 2^31 - 1 ahead (its samples and
    /// its end); the frames after count on as before.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_jump_at: Option<f64>,
    /// `[at_s, ms]`: from `at_s` the controller's clock reads `ms` later (a clock that
    /// jumped; negative: earlier).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock_step: Option<[f64; 2]>,
    /// `[at_s, ms]`: the first time-sync reply from `at_s` carries the controller's time `ms`
    /// off (one odd reply; the clock itself is fine).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sync_reply_step: Option<[f64; 2]>,
    /// `[led, from_s, to_s]`: meanwhile each frame's first sample names this LED, which the
    /// schedule does not have in that slot.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unscheduled_led: Option<[f64; 3]>,
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
    /// ... and sends them again from this time (default: never).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heartbeat_resume_at: Option<f64>,
    /// The motor board's driver faults: axes stop, state Fault.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board_fault_at: Option<f64>,
    /// The motor board's own e-stop input is open over `[from_s, to_s)` (a stop button
    /// wired to the board, pressed and released): the board latches EStop, refuses fault
    /// resets while the input is open, and takes one once it has closed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board_estop: Option<[f64; 2]>,
    /// The motor board reboots (power glitch): axes stop, boot-up heartbeat, Disabled.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board_reboot_at: Option<f64>,
    /// From this time another device on the bus sends velocity commands to node 1 every
    /// 20 ms (a second master).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_master_at: Option<f64>,
    /// `can_loss` applies only over `[from_s, to_s)` (default: always).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub can_loss_during: Option<[f64; 2]>,
    /// The SLCAN adapter's own controller is bus-off over `[from_s, to_s)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adapter_bus_off: Option<[f64; 2]>,
    /// The motor board goes bus-off at this time for `bus_off_s` seconds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bus_off_at: Option<f64>,
    #[serde(default = "default_bus_off")]
    pub bus_off_s: f64,
    /// CiA 402 drives: the left wheel's drive loses its DC link over `[from_s, to_s)`:
    /// under-voltage (EMCY 0x3220), the wheel stops at once, fault resets refused meanwhile.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive_undervoltage: Option<[f64; 2]>,
    /// CiA 402 drives: the left wheel is blocked over `[from_s, to_s)`: a target it cannot
    /// reach for 50 ms is a following error (EMCY 0x8611), fault resets refused meanwhile.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive_blocked: Option<[f64; 2]>,
    /// CiA 402 drives: the left wheel's drive never answers an SDO on this object (its
    /// index, e.g. `0x6085`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive_ignores_object: Option<u16>,
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
    /// Check every value; on error, the key (under `faults.`) and why. Nothing a scenario or
    /// a `--fault` setting says may panic the simulator later.
    pub fn validate(&self) -> Result<(), (String, String)> {
        self.validate_rates_and_times()?;
        self.validate_windows()?;
        self.validate_events()
    }

    /// Probabilities, one-time events' times and spans.
    fn validate_rates_and_times(&self) -> Result<(), (String, String)> {
        let err = |key: &str, why: String| Err((format!("faults.{key}"), why));
        for (key, p) in [
            ("serial_drop", self.serial_drop),
            ("serial_corrupt", self.serial_corrupt),
            ("serial_duplicate", self.serial_duplicate),
            ("serial_replay", self.serial_replay),
            ("can_loss", self.can_loss),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return err(key, format!("is a probability, 0-1, is {p}"));
            }
        }
        let times = [
            ("controller_reset_at", self.controller_reset_at),
            ("serial_vanish_at", self.serial_vanish_at),
            ("heartbeat_stop_at", self.heartbeat_stop_at),
            ("heartbeat_resume_at", self.heartbeat_resume_at),
            ("sample_delay_until", self.sample_delay_until),
            ("board_fault_at", self.board_fault_at),
            ("board_reboot_at", self.board_reboot_at),
            ("second_master_at", self.second_master_at),
            ("bus_off_at", self.bus_off_at),
            ("seq_jump_at", self.seq_jump_at),
            ("frame_jump_at", self.frame_jump_at),
        ];
        let spans = [
            ("sample_delay_ms", self.sample_delay_ms),
            ("sample_jitter_ms", self.sample_jitter_ms),
            ("serial_vanish_s", self.serial_vanish_s),
            ("bus_off_s", self.bus_off_s),
        ];
        for (key, v) in times.iter().filter_map(|(k, v)| v.map(|v| (*k, v))).chain(spans) {
            if !(v.is_finite() && v >= 0.0) {
                return err(key, format!("must be a finite time >= 0, is {v}"));
            }
        }
        for (key, t) in self.serial_burst_at.iter().map(|t| ("serial_burst_at", *t)) {
            if !(t.is_finite() && t >= 0.0) {
                return err(key, format!("must be finite times >= 0, has {t}"));
            }
        }
        Ok(())
    }

    /// Windows `[from, to]` of time, and the held and ramped replies.
    fn validate_windows(&self) -> Result<(), (String, String)> {
        let err = |key: &str, why: String| Err((format!("faults.{key}"), why));
        for (key, w) in [
            ("serial_corrupt_during", self.serial_corrupt_during),
            ("serial_drop_during", self.serial_drop_during),
            ("serial_repeat_during", self.serial_repeat_during),
            ("serial_silence", self.serial_silence),
            ("adapter_bus_off", self.adapter_bus_off),
            ("can_loss_during", self.can_loss_during),
            ("board_estop", self.board_estop),
            ("drive_undervoltage", self.drive_undervoltage),
            ("drive_blocked", self.drive_blocked),
        ] {
            if let Some([from, to]) = w {
                if !(from.is_finite() && to.is_finite() && from >= 0.0 && from <= to) {
                    return err(key, format!("must be [from, to] with 0 <= from <= to, is [{from}, {to}]"));
                }
            }
        }
        if let Some([from, to, ms]) = self.sync_reply_hold {
            if !([from, to, ms].iter().all(|v| v.is_finite() && *v >= 0.0) && from <= to) {
                return err(
                    "sync_reply_hold",
                    format!("must be [from_s, to_s, ms], 0 <= from <= to, is [{from}, {to}, {ms}]"),
                );
            }
        }
        if let Some([from, to, ms]) = self.sample_delay_ramp {
            if !([from, to, ms].iter().all(|v| v.is_finite() && *v >= 0.0) && from <= to) {
                return err(
                    "sample_delay_ramp",
                    format!("must be [from_s, to_s, extra_ms], 0 <= from <= to, is [{from}, {to}, {ms}]"),
                );
            }
        }
        Ok(())
    }

    /// The clock's drift and steps, occlusions, reflections, stray LEDs, controller faults.
    fn validate_events(&self) -> Result<(), (String, String)> {
        let err = |key: &str, why: String| Err((format!("faults.{key}"), why));
        if !(self.clock_drift_ppm.is_finite() && self.clock_drift_ppm.abs() <= 100_000.0) {
            return err("clock_drift_ppm", format!("must be within ±100000, is {}", self.clock_drift_ppm));
        }
        for o in &self.occlusions {
            if !(o.iter().all(|v| v.is_finite()) && (1.0..=255.0).contains(&o[0]) && o[1] <= o[2]) {
                return err("occlusions", format!("each is [led 1-255, from_s, to_s], has {o:?}"));
            }
        }
        for r in &self.reflections {
            if !(r.iter().all(|v| v.is_finite()) && (1.0..=255.0).contains(&r[0]) && r[1] <= r[2]) {
                return err("reflections", format!("each is [led 1-255, from_s, to_s, dx_m], has {r:?}"));
            }
        }
        for (key, step) in [("clock_step", self.clock_step), ("sync_reply_step", self.sync_reply_step)] {
            if let Some([at, ms]) = step {
                if !(at.is_finite() && at >= 0.0 && ms.is_finite() && ms.abs() <= 1e9) {
                    return err(key, format!("must be [at_s >= 0, ms within ±1e9], is [{at}, {ms}]"));
                }
            }
        }
        if let Some(u) = self.unscheduled_led {
            if !(u.iter().all(|v| v.is_finite()) && (1.0..=255.0).contains(&u[0]) && 0.0 <= u[1] && u[1] <= u[2]) {
                return err("unscheduled_led", format!("must be [led 1-255, from_s, to_s], is {u:?}"));
            }
        }
        if let Some([at, code, _]) = self.controller_fault {
            if !(at.is_finite() && at >= 0.0 && (2.0..=5.0).contains(&code)) {
                return err(
                    "controller_fault",
                    format!("must be [at_s, code 2-5, detail], is {:?}", self.controller_fault),
                );
            }
        }
        Ok(())
    }

    /// The plan for a controller booted afresh at `t` (its device came back): the one-time
    /// events of the controller already past happened to the one before it, and are not
    /// played again.
    pub fn booted_at(&self, t: f64) -> Self {
        let future = |at: Option<f64>| at.filter(|&at| at > t);
        Self {
            controller_fault: self.controller_fault.filter(|f| f[0] > t),
            controller_reset_at: future(self.controller_reset_at),
            seq_jump_at: future(self.seq_jump_at),
            frame_jump_at: future(self.frame_jump_at),
            sync_reply_step: self.sync_reply_step.filter(|s| s[0] > t),
            ..self.clone()
        }
    }

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
        let plan: Self = table.try_into().map_err(|e: toml::de::Error| format!("faults: {e}"))?;
        plan.validate().map_err(|(key, why)| format!("`{key}` {why}"))?;
        Ok(plan)
    }

    /// How far LED `led` reads off at `t` (a reflection), m along x.
    pub fn reflected(&self, led: u8, t: f64) -> f64 {
        self.reflections.iter().filter(|r| r[0] as u8 == led && t >= r[1] && t < r[2]).map(|r| r[3]).sum()
    }

    /// Whether LED `led` is occluded at `t`.
    pub fn occluded(&self, led: u8, t: f64) -> bool {
        self.occlusions.iter().any(|o| o[0] as u8 == led && t >= o[1] && t < o[2])
    }

    /// The extra sample delay of `sample_delay_ramp` at `t`, s.
    pub fn ramp_delay(&self, t: f64) -> f64 {
        if self.sample_delay_until.is_some_and(|until| t >= until) {
            return 0.0;
        }
        match self.sample_delay_ramp {
            Some([from, _, _]) if t < from => 0.0,
            Some([from, to, ms]) if t < to => ms * 1e-3 * (t - from) / (to - from),
            Some([_, _, ms]) => ms * 1e-3,
            None => 0.0,
        }
    }

    /// How far the controller's clock has stepped by `t`, µs.
    pub fn clock_step_us(&self, t: f64) -> f64 {
        match self.clock_step {
            Some([at, ms]) if t >= at => ms * 1e3,
            _ => 0.0,
        }
    }

    /// The LED an unscheduled sample names at `t`, if any.
    pub fn unscheduled_led(&self, t: f64) -> Option<u8> {
        match self.unscheduled_led {
            Some([led, from, to]) if t >= from && t < to => Some(led as u8),
            _ => None,
        }
    }

    /// Whether the board's heartbeat is off at `t`.
    pub fn heartbeat_stopped(&self, t: f64) -> bool {
        self.heartbeat_stop_at.is_some_and(|at| t >= at) && !self.heartbeat_resume_at.is_some_and(|at| t >= at)
    }

    /// Whether the SLCAN adapter is bus-off at `t`.
    /// Whether the board's e-stop input is open at `t`.
    pub fn board_estop_open(&self, t: f64) -> bool {
        matches!(self.board_estop, Some([from, to]) if t >= from && t < to)
    }

    pub fn adapter_bus_off(&self, t: f64) -> bool {
        matches!(self.adapter_bus_off, Some([from, to]) if t >= from && t < to)
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
    drop_during: Option<[f64; 2]>,
    corrupt: f64,
    corrupt_during: Option<[f64; 2]>,
    silence: Option<[f64; 2]>,
    duplicate: f64,
    replay: f64,
    repeat_during: Option<[f64; 2]>,
    /// The last packets sent, for replays.
    history: [Option<flowgate_protocol::psd::Packet>; 8],
    /// When one packet goes out with its sequence number far ahead (then `None`).
    seq_jump_at: Option<f64>,
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
            drop_during: plan.serial_drop_during,
            corrupt: plan.serial_corrupt,
            corrupt_during: plan.serial_corrupt_during,
            silence: plan.serial_silence,
            duplicate: plan.serial_duplicate,
            replay: plan.serial_replay,
            repeat_during: plan.serial_repeat_during,
            history: [None; 8],
            seq_jump_at: plan.seq_jump_at,
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
        if self.seq_jump_at.is_some_and(|at| t >= at) {
            self.seq_jump_at = None;
            out(flowgate_protocol::psd::Packet { seq: packet.seq.wrapping_add(0x7FFF), ..packet });
        }
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
        if matches!(self.silence, Some([from, to]) if t >= from && t < to) {
            self.dropped += bytes.len() as u64;
            bytes.clear();
            return;
        }
        let within = |during: Option<[f64; 2]>, p: f64| match during {
            Some([from, to]) if t < from || t >= to => 0.0,
            _ => p,
        };
        let corrupt = within(self.corrupt_during, self.corrupt);
        let drop = within(self.drop_during, self.drop);
        if drop <= 0.0 && corrupt <= 0.0 {
            return;
        }
        let rng = &mut self.rng;
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
    during: Option<[f64; 2]>,
    pub lost: u64,
}

impl CanFaults {
    pub fn new(plan: &FaultPlan) -> Self {
        Self {
            rng: ChaCha8Rng::seed_from_u64(plan.seed ^ 0xca7),
            loss: plan.can_loss,
            during: plan.can_loss_during,
            lost: 0,
        }
    }
    /// Whether a frame sent at `t` is lost.
    pub fn lose(&mut self, t: f64) -> bool {
        let active = !matches!(self.during, Some([from, to]) if t < from || t >= to);
        let lost = active && self.loss > 0.0 && self.rng.random_bool(self.loss.min(1.0));
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
        for (bad, key) in [
            ("serial_drop=-0.1", "faults.serial_drop"),
            ("can_loss=2", "faults.can_loss"),
            ("serial_silence=[2.0, 1.0]", "faults.serial_silence"),
            ("sample_delay_ramp=[1.0, 2.0, nan]", "faults.sample_delay_ramp"),
            ("controller_fault=[1.0, 9, 0]", "faults.controller_fault"),
            ("bus_off_at=inf", "faults.bus_off_at"),
        ] {
            let e = FaultPlan::default().with_settings(&[bad.into()]).unwrap_err();
            assert!(e.contains(&format!("`{key}`")), "{bad}: {e}");
        }
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
