//! The gateway's side of two CiA 402 drives (one a wheel), as a state machine of the core:
//! frames and time in, frames out, a deadline. docs/cia402.md says what it writes and why.
//!
//! At the arm, for each drive at once: NMT enter pre-operational; the configuration by
//! expedited SDO, one write at a time, each answered within `cia402.sdo_timeout_ms`
//! ([`configuration`]); NMT start. Then the drive's statusword (TPDO1) is answered by the
//! controlword that takes it one step towards operation enabled, with a zero target, until
//! both drives are there, within `cia402.enable_timeout_ms` of the arm. Each cycle sends
//! one RPDO1 a drive (controlword enable operation, target velocity); there is no SYNC.
//! An e-stop sends quick stop; at rest after an orderly stop, shutdown (the motor
//! unpowered). The drives consume the gateway's heartbeat (0x1016) and stop by
//! themselves when it stops; the core watches theirs.

use std::time::Duration;

use flowgate_protocol::canopen::{
    self, object, CanOpenMessage, DriveCommand, DriveState, NmtCommand, NmtState, NmtTarget, NodeId, PdoData,
    PdoDirection, SdoData, SdoRequest, SdoResponse, VelocityCommand, VelocityReport,
};
use flowgate_protocol::CanFrame;

use crate::config::Cia402Settings;
use crate::gateway::core::safety::StopReason;
use crate::time::HostTime;

/// How long a drive may miss the gateway's heartbeat before it stops by itself (0x1016): three
/// of the gateway's periods.
pub const CONSUMER_TIME_MS: u32 = crate::config::CIA402_CONSUMER_TIME_MS;

/// How recent a drive's report of its velocity must be to say its wheel turns now (ten of
/// its report periods at the default 10 ms).
pub const MOTION_REPORT_FRESH: std::time::Duration = std::time::Duration::from_millis(100);

/// One configuration write.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SdoWrite {
    pub index: u16,
    pub sub: u8,
    pub data: SdoData,
}

/// A PDO as the gateway maps it on a drive.
struct PdoLayout {
    communication: u16,
    mapping: u16,
    /// The COB-ID less the node id.
    cob: u16,
    /// Each mapped object and its size in bits, in order.
    entries: &'static [(u16, u8)],
    /// A TPDO: sent on the drive's event timer (`cia402.report_ms`) as well.
    event_timer: bool,
}

/// RPDO1 (controlword, target velocity), TPDO1 (statusword, velocity actual), TPDO2
/// (position actual): the layout of protocol/cia402-drive.eds.
const PDOS: [PdoLayout; 3] = [
    PdoLayout {
        communication: object::RPDO1_COMMUNICATION,
        mapping: object::RPDO1_MAPPING,
        cob: canopen::cob::RPDO1,
        entries: &[(object::CONTROLWORD, 16), (object::TARGET_VELOCITY, 32)],
        event_timer: false,
    },
    PdoLayout {
        communication: object::TPDO1_COMMUNICATION,
        mapping: object::TPDO1_MAPPING,
        cob: canopen::cob::TPDO1,
        entries: &[(object::STATUSWORD, 16), (object::VELOCITY_ACTUAL, 32)],
        event_timer: true,
    },
    PdoLayout {
        communication: object::TPDO2_COMMUNICATION,
        mapping: object::TPDO2_MAPPING,
        cob: canopen::cob::TPDO2,
        entries: &[(object::POSITION_ACTUAL, 32)],
        event_timer: true,
    },
];

/// What the gateway writes to a drive at each arm, in order: heartbeats, the mode and its
/// ramps, then each PDO's mapping (invalidated, cleared, entries, count, transmission,
/// valid again).
pub fn configuration(settings: &Cia402Settings, node: NodeId) -> Vec<SdoWrite> {
    let n = u32::from(node.get());
    let w = |index, sub, data| SdoWrite { index, sub, data };
    let consumer = u32::from(settings.gateway.get()) << 16 | CONSUMER_TIME_MS;
    let mut writes = vec![
        w(object::PRODUCER_HEARTBEAT_TIME, 0, SdoData::u16(settings.heartbeat_ms)),
        w(object::CONSUMER_HEARTBEAT_TIME, 1, SdoData::u32(consumer)),
        w(object::MODES_OF_OPERATION, 0, SdoData::i8(canopen::PROFILE_VELOCITY_MODE)),
        w(object::MAX_PROFILE_VELOCITY, 0, SdoData::u32(settings.max_velocity)),
        w(object::PROFILE_ACCELERATION, 0, SdoData::u32(settings.accel)),
        w(object::PROFILE_DECELERATION, 0, SdoData::u32(settings.accel)),
        w(object::QUICK_STOP_DECELERATION, 0, SdoData::u32(settings.quick_stop_decel)),
        w(object::QUICK_STOP_OPTION, 0, SdoData::i16(canopen::QUICK_STOP_THEN_DISABLE)),
    ];
    for pdo in &PDOS {
        let cob_id = u32::from(pdo.cob) + n;
        writes.push(w(pdo.communication, 1, SdoData::u32(cob_id | canopen::PDO_INVALID)));
        writes.push(w(pdo.mapping, 0, SdoData::u8(0)));
        for (k, &(index, bits)) in pdo.entries.iter().enumerate() {
            writes.push(w(pdo.mapping, k as u8 + 1, SdoData::u32(canopen::mapping_entry(index, 0, bits))));
        }
        writes.push(w(pdo.mapping, 0, SdoData::u8(pdo.entries.len() as u8)));
        writes.push(w(pdo.communication, 2, SdoData::u8(canopen::TRANSMISSION_EVENT)));
        if pdo.event_timer {
            writes.push(w(pdo.communication, 5, SdoData::u16(settings.report_ms)));
        }
        writes.push(w(pdo.communication, 1, SdoData::u32(cob_id)));
    }
    writes
}

/// Where the drives are in the gateway's eyes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Not armed: nothing is sent but heartbeats.
    Idle,
    /// Configuring and enabling, since the arm.
    Enabling { since: HostTime },
    /// Both in operation enabled: cycles command them.
    Enabled,
    /// Quick stop sent (an e-stop).
    QuickStop,
}

/// What the gateway knows of one drive.
#[derive(Debug, Clone)]
struct Drive {
    node: NodeId,
    writes: Vec<SdoWrite>,
    /// The next configuration write, and when the one outstanding was sent.
    step: usize,
    sent: Option<HostTime>,
    heard: Option<HostTime>,
    /// When it last reported its state and velocity (TPDO1).
    reported: Option<HostTime>,
    /// Its last heartbeat was its boot-up: alive, but silent until configured again (a
    /// rebooted drive's heartbeat period is back at its default, off).
    booted: bool,
    statusword: Option<u16>,
    velocity: i32,
    position: Option<i32>,
    /// The last controlword sent (a fault reset needs bit 7's rising edge).
    controlword: u16,
}

impl Drive {
    fn state(&self) -> Option<DriveState> {
        self.statusword.map(DriveState::from_statusword)
    }
    fn enabled(&self) -> bool {
        self.state().is_some_and(DriveState::is_enabled)
    }
    fn configured(&self) -> bool {
        self.step >= self.writes.len()
    }
}

/// The gateway's side of the two drives.
#[derive(Debug, Clone)]
pub struct Cia402Master {
    settings: Cia402Settings,
    drives: [Drive; 2],
    phase: Phase,
}

/// What a frame from the bus was, for the core's counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Heard {
    /// From one of our drives (or our own kind of traffic): taken.
    Ours,
    /// A CANopen frame of another node.
    Foreign,
    /// Not CANopen.
    Undecodable,
}

impl Cia402Master {
    pub fn new(settings: Cia402Settings) -> Self {
        let drive = |node| Drive {
            node,
            writes: configuration(&settings, node),
            step: 0,
            sent: None,
            heard: None,
            booted: false,
            reported: None,
            statusword: None,
            velocity: 0,
            position: None,
            controlword: 0,
        };
        Self { drives: [drive(settings.left), drive(settings.right)], settings, phase: Phase::Idle }
    }

    /// The drives' node ids, left then right.
    /// Whether `frame` is one of these drives' (from them, or to them).
    pub fn addresses(&self, frame: &CanFrame) -> bool {
        CanOpenMessage::parse(frame)
            .ok()
            .and_then(|m| message_node(&m))
            .is_some_and(|n| self.drives.iter().any(|d| d.node == n))
    }

    pub fn nodes(&self) -> [NodeId; 2] {
        [self.drives[0].node, self.drives[1].node]
    }

    /// Both drives follow their targets: cycles may command them.
    pub fn ready(&self) -> bool {
        self.phase == Phase::Enabled
    }

    /// Both drives report zero velocity.
    pub fn at_rest(&self) -> bool {
        self.drives.iter().all(|d| d.velocity == 0)
    }

    /// The drives' actual velocities (pulses a second) and positions, as last reported.
    pub fn actual(&self) -> [(i32, Option<i32>); 2] {
        self.drives
            .each_ref()
            .map(|d| ((f64::from(d.velocity) / self.settings.velocity_scale).round() as i32, d.position))
    }

    /// A drive that reports its wheel turning now, if any (its node): powered (in operation
    /// enabled or its quick stop), with a report within [`MOTION_REPORT_FRESH`]. A drive
    /// gone silent is not taken as turning on an old report: the arm, configuring it by SDO,
    /// finds it or names it.
    pub fn moving(&self, now: HostTime) -> Option<u8> {
        let powered = |d: &&Drive| d.state().is_none_or(|s| s.is_enabled() || s == DriveState::QuickStopActive);
        let fresh = |d: &&Drive| d.reported.is_some_and(|at| now < at + MOTION_REPORT_FRESH);
        self.drives.iter().filter(powered).filter(fresh).find(|d| d.velocity != 0).map(|d| d.node.get())
    }

    /// When each drive was last heard (heartbeat or boot-up).
    pub fn heard(&self) -> [Option<HostTime>; 2] {
        self.drives.each_ref().map(|d| d.heard)
    }

    /// Every drive heard within `timeout` of `now`, or booted since and silent until
    /// configured.
    pub fn alive_within(&self, now: HostTime, timeout: std::time::Duration) -> bool {
        self.drives.iter().all(|d| d.booted || d.heard.is_some_and(|h| now < h + timeout))
    }

    /// Arm: configure both drives afresh and take them to operation enabled.
    pub fn arm(&mut self, now: HostTime, send: &mut impl FnMut(CanFrame)) {
        self.phase = Phase::Enabling { since: now };
        for d in &mut self.drives {
            d.step = 0;
            d.statusword = None;
            let nmt = CanOpenMessage::Nmt { command: NmtCommand::EnterPreOperational, target: NmtTarget::Node(d.node) };
            emit(send, nmt);
            Self::next_write(d, now, send);
        }
    }

    fn next_write(d: &mut Drive, now: HostTime, send: &mut impl FnMut(CanFrame)) {
        match d.writes.get(d.step) {
            Some(&SdoWrite { index, sub, data }) => {
                d.sent = Some(now);
                emit(
                    send,
                    CanOpenMessage::SdoRequest { node: d.node, request: SdoRequest::Download { index, sub, data } },
                );
            }
            None => {
                d.sent = None;
                emit(send, CanOpenMessage::Nmt { command: NmtCommand::Start, target: NmtTarget::Node(d.node) });
            }
        }
    }

    /// One cycle's command: an RPDO1 a drive, `pulses` a second each (left, right). Only
    /// once [`Cia402Master::ready`]: before, the state machine's controlwords alone go out.
    pub fn command(&self, pulses: [i32; 2]) -> [Option<CanFrame>; 2] {
        let cw = DriveCommand::EnableOperation.controlword();
        [0, 1].map(|k| {
            let v = (f64::from(pulses[k]) * self.settings.velocity_scale).round() as i32;
            rpdo(self.drives[k].node, cw, v)
        })
    }

    /// An e-stop: quick stop on both drives (their quick-stop deceleration, then switch on
    /// disabled).
    pub fn quick_stop(&mut self, send: &mut impl FnMut(CanFrame)) {
        self.phase = Phase::QuickStop;
        for d in &mut self.drives {
            d.controlword = DriveCommand::QuickStop.controlword();
            if let Some(f) = rpdo(d.node, d.controlword, 0) {
                send(f);
            }
        }
    }

    /// At rest after an orderly stop: shutdown (ready to switch on, the motor unpowered). When
    /// the gateway is ending (`stop_nodes`), NMT stop too: no PDO reaches the drives after it.
    pub fn disable(&mut self, stop_nodes: bool, send: &mut impl FnMut(CanFrame)) {
        self.phase = Phase::Idle;
        for d in &mut self.drives {
            d.controlword = DriveCommand::Shutdown.controlword();
            if let Some(f) = rpdo(d.node, d.controlword, 0) {
                send(f);
            }
            if stop_nodes {
                emit(send, CanOpenMessage::Nmt { command: NmtCommand::Stop, target: NmtTarget::Node(d.node) });
            }
        }
    }

    /// The gateway's heartbeat (operational: it is the master). After an e-stop, with each
    /// heartbeat the quick stop again to every drive not yet seen out of operation enabled:
    /// a drive has no command timeout, so a lost quick stop must not leave it running while
    /// the heartbeat it watches goes on. Until every drive is seen out of it, the heartbeat
    /// itself is withheld: on a lossy bus the repeats may all be lost, and the drives' own
    /// heartbeat consumer (0x1016) then stops them within its time, whatever the loss. On a
    /// bus with several vehicles' drives the heartbeat is the gateway's one (`beat`: this
    /// master sends it), withheld while any of them is unconfirmed.
    pub fn heartbeat(&mut self, beat: bool, send: &mut impl FnMut(CanFrame)) {
        if beat && !self.withholds_heartbeat() {
            emit(send, CanOpenMessage::Heartbeat { node: self.settings.gateway, state: NmtState::Operational });
        }
        if self.phase == Phase::QuickStop {
            for d in &self.drives {
                if d.state().is_none_or(DriveState::is_enabled) {
                    if let Some(f) = rpdo(d.node, DriveCommand::QuickStop.controlword(), 0) {
                        send(f);
                    }
                }
            }
        }
    }

    /// After an e-stop, a drive not yet seen out of operation enabled: the gateway's
    /// heartbeat is withheld until none is ([`Cia402Master::heartbeat`]).
    pub fn withholds_heartbeat(&self) -> bool {
        self.phase == Phase::QuickStop && self.drives.iter().any(|d| d.state().is_none_or(DriveState::is_enabled))
    }

    /// When [`Cia402Master::tick`] next has something to do.
    pub fn deadline(&self) -> HostTime {
        let mut next = HostTime::NEVER;
        if let Phase::Enabling { since } = self.phase {
            next = next.min(since + self.settings.enable_timeout);
            for d in &self.drives {
                if let Some(sent) = d.sent {
                    next = next.min(sent + self.settings.sdo_timeout);
                }
            }
        }
        next
    }

    /// Timeouts due by `now`: an unanswered SDO, names its node and object; drives not
    /// enabled in time, the first such and its state.
    pub fn tick(&mut self, now: HostTime) -> Option<StopReason> {
        let Phase::Enabling { since } = self.phase else { return None };
        for d in &self.drives {
            if let (Some(sent), Some(w)) = (d.sent, d.writes.get(d.step)) {
                if now >= sent + self.settings.sdo_timeout {
                    return Some(StopReason::DriveSdoTimeout { node: d.node.get(), index: w.index, sub: w.sub });
                }
            }
        }
        if now >= since + self.settings.enable_timeout {
            let d = self.drives.iter().find(|d| !d.enabled())?;
            let state = d.state().unwrap_or(DriveState::NotReadyToSwitchOn);
            return Some(StopReason::DriveNotEnabled { node: d.node.get(), state });
        }
        None
    }

    /// A frame from the bus at `now`. `active`: the gateway is armed, running or stopping
    /// (a drive's fault then stops it). Returns what it was and the stop it calls for.
    pub fn frame(
        &mut self,
        now: HostTime,
        frame: &CanFrame,
        active: bool,
        send: &mut impl FnMut(CanFrame),
    ) -> (Heard, Option<StopReason>) {
        let Ok(message) = CanOpenMessage::parse(frame) else { return (Heard::Undecodable, None) };
        let Some(k) = message_node(&message).and_then(|n| self.drives.iter().position(|d| d.node == n)) else {
            return match message {
                // The bus's master traffic (our own heartbeat's kind, another node's NMT, SYNC).
                CanOpenMessage::Nmt { .. } | CanOpenMessage::Sync => (Heard::Ours, None),
                _ => (Heard::Foreign, None),
            };
        };
        let node = self.drives[k].node.get();
        let stop = match message {
            CanOpenMessage::Heartbeat { state, .. } => {
                let d = &mut self.drives[k];
                d.heard = Some(now);
                d.booted = state == NmtState::BootUp;
                if d.booted {
                    // Rebooted: its motor unpowered, its last report void.
                    (d.velocity, d.statusword) = (0, None);
                }
                match (state, self.phase) {
                    // Booted while being configured (powered up with the gateway, or reset):
                    // nothing it was told holds, and nothing moves yet: configure it afresh.
                    (NmtState::BootUp, Phase::Enabling { .. }) => {
                        d.step = 0;
                        d.statusword = None;
                        Self::next_write(d, now, send);
                        None
                    }
                    (NmtState::BootUp, _) if active => Some(StopReason::DriveRebooted { node }),
                    _ => None,
                }
            }
            CanOpenMessage::Emcy { emcy, .. } => {
                (emcy.error_code != 0 && active).then_some(StopReason::DriveEmergency { node, code: emcy.error_code })
            }
            CanOpenMessage::SdoResponse { response, .. } => self.sdo_answer(now, k, response, send),
            CanOpenMessage::Pdo { direction: PdoDirection::Transmit, number: 1, data, .. } => {
                self.status(now, k, data, active, send)
            }
            CanOpenMessage::Pdo { direction: PdoDirection::Transmit, number: 2, data, .. } => {
                if let [a, b, c, d] = *data.bytes() {
                    self.drives[k].position = Some(i32::from_le_bytes([a, b, c, d]));
                }
                None
            }
            // Nobody else may command our drives: we never hear our own frames.
            CanOpenMessage::Pdo { direction: PdoDirection::Receive, .. } | CanOpenMessage::SdoRequest { .. } => {
                Some(StopReason::DriveSecondMaster { node })
            }
            _ => None,
        };
        (Heard::Ours, stop)
    }

    fn sdo_answer(
        &mut self,
        now: HostTime,
        k: usize,
        response: SdoResponse,
        send: &mut impl FnMut(CanFrame),
    ) -> Option<StopReason> {
        let d = &mut self.drives[k];
        let expected = d.sent.and(d.writes.get(d.step)).map(|w| (w.index, w.sub));
        if expected != Some(response.object()) || !matches!(self.phase, Phase::Enabling { .. }) {
            return None; // late, or not ours: the timeout judges the one outstanding
        }
        match response {
            SdoResponse::Downloaded { .. } => {
                d.step += 1;
                Self::next_write(d, now, send);
                None
            }
            SdoResponse::Abort { index, sub, code } => {
                d.sent = None;
                Some(StopReason::DriveSdoAbort { node: d.node.get(), index, sub, code })
            }
            SdoResponse::Uploaded { .. } => None,
        }
    }

    /// TPDO1: statusword and velocity. While enabling, answer with the next controlword; once
    /// enabled, a drive that leaves operation enabled stops the gateway.
    fn status(
        &mut self,
        now: HostTime,
        k: usize,
        data: PdoData,
        active: bool,
        send: &mut impl FnMut(CanFrame),
    ) -> Option<StopReason> {
        let report = VelocityReport::parse(&data)?;
        let d = &mut self.drives[k];
        d.statusword = Some(report.statusword);
        d.velocity = report.velocity_actual;
        d.reported = Some(now);
        let state = DriveState::from_statusword(report.statusword);
        match self.phase {
            // Configured means started: the NMT start follows the last write at once.
            Phase::Enabling { .. } if d.configured() => {
                if let Some(command) = state.towards_operation() {
                    let mut cw = command.controlword();
                    // A fault reset acts on bit 7's rising edge: clear it first if it was set.
                    if command == DriveCommand::FaultReset && d.controlword & 0x80 != 0 {
                        cw = DriveCommand::DisableVoltage.controlword();
                    }
                    d.controlword = cw;
                    if let Some(f) = rpdo(d.node, cw, 0) {
                        send(f);
                    }
                }
                if self.drives.iter().all(Drive::enabled) {
                    self.phase = Phase::Enabled;
                }
                None
            }
            Phase::Enabled if active && !state.is_enabled() => {
                Some(StopReason::DriveLeftOperation { node: d.node.get(), state })
            }
            _ => None,
        }
    }

    /// A frame like a cycle's, built and dropped (the low-latency mode's rehearsal).
    pub fn rehearse(&self) {
        let _ = std::hint::black_box(self.command([0, 0]));
    }

    /// The SDO timeout, for messages.
    pub fn sdo_timeout(&self) -> Duration {
        self.settings.sdo_timeout
    }
}

/// The node a drive's message is from (or to).
fn message_node(message: &CanOpenMessage) -> Option<NodeId> {
    match *message {
        CanOpenMessage::Heartbeat { node, .. }
        | CanOpenMessage::Emcy { node, .. }
        | CanOpenMessage::SdoRequest { node, .. }
        | CanOpenMessage::SdoResponse { node, .. }
        | CanOpenMessage::Pdo { node, .. } => Some(node),
        CanOpenMessage::Nmt { .. } | CanOpenMessage::Sync => None,
    }
}

fn rpdo(node: NodeId, controlword: u16, target_velocity: i32) -> Option<CanFrame> {
    let data = VelocityCommand { controlword, target_velocity }.data();
    CanOpenMessage::Pdo { direction: PdoDirection::Receive, number: 1, node, data }.to_frame()
}

fn emit(send: &mut impl FnMut(CanFrame), message: CanOpenMessage) {
    if let Some(f) = message.to_frame() {
        send(f);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Cia402Section, Motors, RigFile};

    fn master() -> Cia402Master {
        let mut config = RigFile::from_toml(include_str!("../../../../rig.example.toml"), "rig").unwrap();
        config.use_cia402(Cia402Section::with_nodes(3, 4));
        let Motors::Cia402(settings) = config.validate().unwrap().motors else { panic!("not cia402") };
        Cia402Master::new(settings)
    }

    fn node(n: u8) -> NodeId {
        NodeId::new(n).unwrap()
    }

    fn answer(
        m: &mut Cia402Master,
        t: HostTime,
        n: u8,
        response: SdoResponse,
        out: &mut Vec<CanFrame>,
    ) -> Option<StopReason> {
        let frame = CanOpenMessage::SdoResponse { node: node(n), response }.to_frame().unwrap();
        m.frame(t, &frame, true, &mut |f| out.push(f)).1
    }

    fn requests(out: &[CanFrame]) -> Vec<(u8, u16, u8)> {
        out.iter()
            .filter_map(|f| match CanOpenMessage::parse(f).ok()? {
                CanOpenMessage::SdoRequest { node, request } => {
                    Some((node.get(), request.object().0, request.object().1))
                }
                _ => None,
            })
            .collect()
    }

    /// Each write goes once its predecessor is answered; a late or foreign answer moves
    /// nothing; an abort names the node, the object and the code.
    #[test]
    fn configuration_goes_write_by_write_and_an_abort_is_named() {
        let mut m = master();
        let mut out = Vec::new();
        let t = HostTime::from_nanos(1_000_000);
        m.arm(t, &mut |f| out.push(f));
        assert_eq!(requests(&out), [(3, 0x1017, 0), (4, 0x1017, 0)]);
        out.clear();
        // An answer for another object: ignored, the write stays outstanding.
        assert_eq!(answer(&mut m, t, 3, SdoResponse::Downloaded { index: 0x6060, sub: 0 }, &mut out), None);
        assert!(out.is_empty());
        assert_eq!(answer(&mut m, t, 3, SdoResponse::Downloaded { index: 0x1017, sub: 0 }, &mut out), None);
        assert_eq!(requests(&out), [(3, 0x1016, 1)]);
        let abort = SdoResponse::Abort { index: 0x1016, sub: 1, code: 0x0609_0030 };
        let reason = answer(&mut m, t, 3, abort, &mut out).unwrap();
        assert_eq!(reason, StopReason::DriveSdoAbort { node: 3, index: 0x1016, sub: 1, code: 0x0609_0030 });
        assert_eq!(
            reason.to_string(),
            "drive 3 refused SDO 0x1016:1: abort 0x06090030 (value range of parameter exceeded)"
        );
        // Drive 4's first write times out one SDO timeout after it was sent.
        assert_eq!(m.deadline(), t + m.sdo_timeout());
        assert_eq!(m.tick(t + m.sdo_timeout()), Some(StopReason::DriveSdoTimeout { node: 4, index: 0x1017, sub: 0 }));
    }

    /// The configuration a drive gets: heartbeats, mode, ramps, then the three PDOs mapped
    /// as protocol/cia402-drive.eds has them.
    #[test]
    fn the_configuration_maps_the_pdos_of_the_eds() {
        let m = master();
        let writes = &m.drives[0].writes;
        assert_eq!(writes.len(), 30);
        let find = |index, sub| writes.iter().filter(move |w| (w.index, w.sub) == (index, sub)).map(|w| w.data.value());
        assert_eq!(find(0x1016, 1).collect::<Vec<_>>(), [127 << 16 | CONSUMER_TIME_MS]);
        assert_eq!(find(0x6060, 0).collect::<Vec<_>>(), [3]);
        assert_eq!(find(0x1600, 1).collect::<Vec<_>>(), [0x6040_0010]);
        assert_eq!(find(0x1600, 2).collect::<Vec<_>>(), [0x60FF_0020]);
        assert_eq!(find(0x1A00, 2).collect::<Vec<_>>(), [0x606C_0020]);
        assert_eq!(find(0x1A01, 1).collect::<Vec<_>>(), [0x6064_0020]);
        // Each PDO invalid while mapped, valid (its predefined COB-ID) after.
        assert_eq!(find(0x1400, 1).collect::<Vec<_>>(), [0x8000_0203, 0x203]);
        assert_eq!(find(0x1801, 1).collect::<Vec<_>>(), [0x8000_0283, 0x283]);
    }

    /// A drive that boots while being configured (powered up with the gateway) is configured
    /// afresh; once enabled, a boot-up is a fault naming it.
    #[test]
    fn a_boot_up_restarts_the_configuration_until_enabled() {
        let mut m = master();
        let mut out = Vec::new();
        let t = HostTime::from_nanos(0);
        m.arm(t, &mut |f| out.push(f));
        answer(&mut m, t, 3, SdoResponse::Downloaded { index: 0x1017, sub: 0 }, &mut out);
        assert_eq!(m.drives[0].step, 1);
        out.clear();
        let boot = CanOpenMessage::Heartbeat { node: node(3), state: NmtState::BootUp }.to_frame().unwrap();
        assert_eq!(m.frame(t, &boot, true, &mut |f| out.push(f)).1, None);
        assert_eq!(requests(&out), [(3, 0x1017, 0)], "the first write again");
        m.phase = Phase::Enabled;
        assert_eq!(m.frame(t, &boot, true, &mut |f| out.push(f)).1, Some(StopReason::DriveRebooted { node: 3 }));
    }

    /// After an e-stop, each heartbeat repeats the quick stop to a drive still in operation
    /// enabled (its first may have been lost), and stops once it has left.
    #[test]
    fn the_quick_stop_is_repeated_until_the_drive_leaves_operation() {
        let mut m = master();
        let mut out = Vec::new();
        m.phase = Phase::Enabled;
        for d in &mut m.drives {
            d.statusword = Some(DriveState::OperationEnabled.statusword_bits());
        }
        m.quick_stop(&mut |f| out.push(f));
        let quick_stops = |out: &[CanFrame]| {
            out.iter()
                .filter_map(|f| match CanOpenMessage::parse(f).ok()? {
                    CanOpenMessage::Pdo { direction: PdoDirection::Receive, node, data, .. } => {
                        (VelocityCommand::parse(&data)?.controlword == 0x0002).then_some(node.get())
                    }
                    _ => None,
                })
                .collect::<Vec<u8>>()
        };
        assert_eq!(quick_stops(&out), [3, 4]);
        out.clear();
        m.drives[1].statusword = Some(DriveState::SwitchOnDisabled.statusword_bits());
        m.heartbeat(true, &mut |f| out.push(f));
        assert_eq!(quick_stops(&out), [3], "drive 4 has left operation enabled");
        out.clear();
        m.drives[0].statusword = Some(DriveState::QuickStopActive.statusword_bits());
        m.heartbeat(true, &mut |f| out.push(f));
        assert_eq!(quick_stops(&out), Vec::<u8>::new());
        assert_eq!(out.len(), 1, "the heartbeat alone");
    }

    /// From a fault, the reset goes out on bit 7's rising edge: a controlword with bit 7
    /// clear first if the last one had it set.
    #[test]
    fn a_fault_reset_is_an_edge() {
        let mut m = master();
        let mut out = Vec::new();
        let t = HostTime::from_nanos(0);
        m.arm(t, &mut |f| out.push(f));
        for d in &mut m.drives {
            d.step = d.writes.len();
        }
        let report = |sw| {
            let data = VelocityReport { statusword: sw, velocity_actual: 0 }.data();
            CanOpenMessage::Pdo { direction: PdoDirection::Transmit, number: 1, node: node(3), data }
                .to_frame()
                .unwrap()
        };
        let mut controlwords = Vec::new();
        for _ in 0..3 {
            out.clear();
            m.frame(t, &report(0x0008), true, &mut |f| out.push(f));
            let Ok(CanOpenMessage::Pdo { data, .. }) = CanOpenMessage::parse(&out[0]) else { panic!() };
            controlwords.push(VelocityCommand::parse(&data).unwrap().controlword);
        }
        assert_eq!(controlwords, [0x0080, 0x0000, 0x0080]);
    }
}
