//! A CiA 402 drive in profile velocity mode, one a wheel, as a state machine: CAN frames in,
//! CAN frames out, time an argument. Its axis is one of the world's wheels; its velocity
//! unit is one pulse (microstep) a second, its position unit one pulse.
//!
//! What it plays of CiA 301 and CiA 402 (protocol/src/canopen.rs, protocol/cia402-drive.eds):
//!
//! - NMT: the boot-up message, then pre-operational; start, stop, enter pre-operational,
//!   reset node and reset communication (both a reboot here: every object to its default).
//! - An expedited SDO server over the objects of the EDS. A write of the wrong size, to a
//!   read-only object, of a value out of range, or to a PDO's mapping while the PDO is
//!   valid aborts with the CiA 301 code; so does a read or write of an object it lacks.
//! - PDOs as mapped (RPDO1, TPDO1, TPDO2; every mappable object of the EDS may be mapped),
//!   taken and sent only when operational. TPDOs are event-driven (transmission type 255):
//!   TPDO1 on a change of the statusword, each on its event timer (sub 5).
//! - The state machine by the controlword ([`DriveCommand::decode`]); profile velocity on
//!   the profile acceleration and deceleration, clamped to the max profile velocity; a
//!   quick stop on the quick-stop deceleration, then switch on disabled (option code 2).
//! - The heartbeat producer (0x1017) and consumer (0x1016 sub 1): a consumed heartbeat
//!   missing past its time, while the drive is enabled, is a fault (EMCY 0x8130).
//!
//! The faults of the plan happen to the left wheel's drive only: it stops its heartbeat
//! (`heartbeat_stop_at`), reboots (`board_reboot_at`), loses its DC link (`drive_undervoltage`,
//! EMCY 0x3220, resets refused while it lasts), has its wheel blocked (`drive_blocked`: a
//! following error, EMCY 0x8611, once a target has stayed unreached for 50 ms) or never
//! answers an SDO on one object (`drive_ignores_object`).

use flowgate_protocol::canopen::{
    self, object, CanOpenMessage, DriveCommand, DriveState, Emcy, NmtCommand, NmtState, NmtTarget, NodeId, PdoData,
    PdoDirection, SdoData, SdoRequest, SdoResponse,
};
use flowgate_protocol::CanFrame;

use crate::faults::FaultPlan;
use crate::world::{AxisConfig, World};

/// Device type (0x1000): CiA 402, a drive.
const DEVICE_TYPE: u32 = 0x0004_0192;
/// Supported drive modes (0x6502): bit 2, profile velocity, only.
const SUPPORTED_DRIVE_MODES: u16 = 0x6502;
const PROFILE_VELOCITY_SUPPORTED: u32 = 1 << 2;
/// How long a target may stay unreached on a blocked wheel before the following error.
pub const FOLLOWING_ERROR_TIMEOUT: f64 = 0.05;
/// A max profile velocity no axis reaches before one is written, pulses/s.
const UNLIMITED: u32 = 1_000_000;

/// Error codes (CiA 301, CiA 402) and the error register's bits with them.
const UNDER_VOLTAGE: (u16, u8) = (0x3220, 0x05);
const FOLLOWING_ERROR: (u16, u8) = (0x8611, 0x21);
const HEARTBEAT_ERROR: (u16, u8) = (0x8130, 0x11);

/// CiA 301 SDO abort codes.
mod abort {
    pub const UNSUPPORTED_ACCESS: u32 = 0x0601_0000;
    pub const READ_ONLY: u32 = 0x0601_0002;
    pub const NO_OBJECT: u32 = 0x0602_0000;
    pub const NOT_MAPPABLE: u32 = 0x0604_0041;
    pub const PDO_LENGTH: u32 = 0x0604_0042;
    pub const LENGTH: u32 = 0x0607_0010;
    pub const NO_SUBINDEX: u32 = 0x0609_0011;
    pub const RANGE: u32 = 0x0609_0030;
    pub const DEVICE_STATE: u32 = 0x0800_0022;
}

/// Counters of what the drive saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DriveCounters {
    pub frames_in: u64,
    pub rpdos: u64,
    pub sdo_requests: u64,
    pub sdo_aborts: u64,
}

/// One PDO's communication and mapping parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Pdo {
    cob_id: u32,
    transmission: u8,
    event_ms: u16,
    mapping: [u32; 4],
    count: u8,
}

impl Pdo {
    fn new(cob_id: u32, mapped: &[u32]) -> Self {
        let mut mapping = [0; 4];
        mapping[..mapped.len()].copy_from_slice(mapped);
        Self { cob_id, transmission: canopen::TRANSMISSION_EVENT, event_ms: 0, mapping, count: mapped.len() as u8 }
    }
    fn valid(&self) -> bool {
        self.cob_id & canopen::PDO_INVALID == 0
    }
    fn mapped(&self) -> impl Iterator<Item = (u16, u8)> + '_ {
        self.mapping[..usize::from(self.count)].iter().map(|&m| ((m >> 16) as u16, (m & 0xFF) as u8))
    }
}

/// Objects a PDO may carry, with their size in bits, and whether a drive receives them.
fn mappable(index: u16) -> Option<(u8, bool)> {
    match index {
        object::CONTROLWORD => Some((16, true)),
        object::TARGET_VELOCITY => Some((32, true)),
        object::STATUSWORD => Some((16, false)),
        object::VELOCITY_ACTUAL | object::POSITION_ACTUAL => Some((32, false)),
        _ => None,
    }
}

/// One CiA 402 drive.
#[derive(Debug)]
pub struct Cia402Drive {
    node: NodeId,
    axis: usize,
    /// The plan's faults happen to this drive (the left wheel's).
    plan: Option<FaultPlan>,
    nmt: NmtState,
    state: DriveState,
    controlword: u16,
    target: i32,
    mode: i8,
    max_velocity: u32,
    accel: u32,
    decel: u32,
    quick_stop_decel: u32,
    quick_stop_option: i16,
    producer_ms: u16,
    consumer: u32,
    gateway_seen: Option<f64>,
    error_code: u16,
    error_register: u8,
    rpdo: Pdo,
    tpdo: [Pdo; 2],
    next_heartbeat: f64,
    next_tpdo: [f64; 2],
    statusword_sent: Option<u16>,
    /// Since when a target has gone unreached on the blocked wheel.
    lag_since: Option<f64>,
    reboot_done: bool,
    /// When `poll` last ran: the plan's times before it were acted on.
    last_poll: f64,
    pub counters: DriveCounters,
}

impl Cia402Drive {
    /// The drive of world axis `axis` (0 left, 1 right), at `node`; `plan` for the one drive
    /// the faults happen to.
    pub fn new(node: NodeId, axis: usize, plan: Option<FaultPlan>) -> Self {
        let n = u32::from(node.get());
        Self {
            node,
            axis,
            plan,
            nmt: NmtState::BootUp,
            state: DriveState::NotReadyToSwitchOn,
            controlword: 0,
            target: 0,
            mode: 0,
            max_velocity: UNLIMITED,
            accel: 0,
            decel: 0,
            quick_stop_decel: 0,
            quick_stop_option: canopen::QUICK_STOP_THEN_DISABLE,
            producer_ms: 0,
            consumer: 0,
            gateway_seen: None,
            error_code: 0,
            error_register: 0,
            rpdo: Pdo::new(u32::from(canopen::cob::RPDO1) + n, &RPDO1_DEFAULT),
            tpdo: [
                Pdo::new(u32::from(canopen::cob::TPDO1) + n, &TPDO1_DEFAULT),
                Pdo::new((u32::from(canopen::cob::TPDO2) + n) | canopen::PDO_INVALID, &TPDO2_DEFAULT),
            ],
            next_heartbeat: f64::INFINITY,
            next_tpdo: [f64::INFINITY; 2],
            statusword_sent: None,
            lag_since: None,
            reboot_done: false,
            last_poll: f64::NEG_INFINITY,
            counters: DriveCounters::default(),
        }
    }

    pub fn node(&self) -> NodeId {
        self.node
    }
    pub fn state(&self) -> DriveState {
        self.state
    }
    pub fn nmt(&self) -> NmtState {
        self.nmt
    }

    /// Power on (or a reset): every object to its default, the boot-up message, then
    /// pre-operational with the motor unpowered.
    pub fn boot(&mut self, t: f64, world: &mut World, out: &mut Vec<CanFrame>) {
        world.stop_axis(self.axis);
        let (node, axis, plan) = (self.node, self.axis, self.plan.take());
        let (reboot_done, last_poll, counters) = (self.reboot_done, self.last_poll, self.counters);
        *self = Self::new(node, axis, plan);
        (self.reboot_done, self.last_poll, self.counters) = (reboot_done, last_poll, counters);
        send(out, CanOpenMessage::Heartbeat { node, state: NmtState::BootUp });
        self.nmt = NmtState::PreOperational;
        self.state = if self.under_voltage(t) { DriveState::Fault } else { DriveState::SwitchOnDisabled };
        if self.state == DriveState::Fault {
            (self.error_code, self.error_register) = UNDER_VOLTAGE;
        }
        self.apply_axis(world);
    }

    fn under_voltage(&self, t: f64) -> bool {
        self.plan.as_ref().and_then(|p| p.drive_undervoltage).is_some_and(|[from, to]| (from..to).contains(&t))
    }

    fn blocked(&self, t: f64) -> bool {
        self.plan.as_ref().and_then(|p| p.drive_blocked).is_some_and(|[from, to]| (from..to).contains(&t))
    }

    fn silent(&self, t: f64) -> bool {
        self.plan.as_ref().is_some_and(|p| p.heartbeat_stopped(t))
    }

    /// The statusword: the state's bits, voltage enabled (unless under-voltage), remote,
    /// target reached and speed zero as the axis is.
    pub fn statusword(&self, world: &World) -> u16 {
        use canopen::statusword as bit;
        let a = &world.axes()[self.axis];
        let mut sw = self.state.statusword_bits() | bit::REMOTE;
        if self.error_code != UNDER_VOLTAGE.0 {
            sw |= bit::VOLTAGE_ENABLED;
        }
        if a.rate() == 0.0 {
            sw |= bit::SPEED_ZERO;
        }
        if self.state.is_enabled() && a.rate() == a.target() {
            sw |= bit::TARGET_REACHED;
        }
        if self.lag_since.is_some() || self.error_code == FOLLOWING_ERROR.0 {
            sw |= bit::FOLLOWING_ERROR;
        }
        sw
    }

    /// Enter the fault state with `error`: the axis brakes on the quick-stop deceleration
    /// (at once on a lost DC link), the EMCY is sent.
    fn fault(&mut self, error: (u16, u8), world: &mut World, out: &mut Vec<CanFrame>) {
        if self.state == DriveState::Fault {
            return;
        }
        (self.error_code, self.error_register) = error;
        self.state = DriveState::Fault;
        self.lag_since = None;
        if error == UNDER_VOLTAGE {
            world.stop_axis(self.axis);
        }
        self.apply_axis(world);
        let emcy = Emcy { error_code: error.0, error_register: error.1, vendor: [0; 5] };
        send(out, CanOpenMessage::Emcy { node: self.node, emcy });
    }

    /// Set the axis as the state asks: follow the target when enabled, brake otherwise.
    fn apply_axis(&self, world: &mut World) {
        let following = self.state.is_enabled() && self.mode == canopen::PROFILE_VELOCITY_MODE;
        let limit = self.max_velocity.min(i32::MAX as u32) as i32;
        let target = if following { self.target.clamp(-limit, limit) } else { 0 };
        let braking =
            matches!(self.state, DriveState::QuickStopActive | DriveState::Fault | DriveState::FaultReactionActive);
        let rate = world.axes()[self.axis].rate();
        let ramp = if braking {
            self.quick_stop_decel
        } else if f64::from(target).abs() < rate.abs() {
            self.decel
        } else {
            self.accel
        };
        // A ramp never written brakes at once (a drive's own default would be its limit).
        let accel = if ramp == 0 { f64::INFINITY } else { f64::from(ramp) };
        world.configure_axis(self.axis, AxisConfig { accel, max_rate: f64::from(self.max_velocity) });
        world.command_axis(self.axis, target);
    }

    /// A frame from the bus.
    pub fn handle(&mut self, t: f64, frame: &CanFrame, world: &mut World, out: &mut Vec<CanFrame>) {
        let Ok(message) = CanOpenMessage::parse(frame) else { return };
        self.counters.frames_in += 1;
        match message {
            CanOpenMessage::Nmt { command, target }
                if target == NmtTarget::All || target == NmtTarget::Node(self.node) =>
            {
                match command {
                    NmtCommand::Start => self.nmt = NmtState::Operational,
                    NmtCommand::Stop => self.nmt = NmtState::Stopped,
                    NmtCommand::EnterPreOperational => self.nmt = NmtState::PreOperational,
                    NmtCommand::ResetNode | NmtCommand::ResetCommunication => self.boot(t, world, out),
                }
                self.schedule(t);
            }
            CanOpenMessage::Heartbeat { node, .. }
                if self.consumer != 0 && u32::from(node.get()) == (self.consumer >> 16) & 0x7F =>
            {
                self.gateway_seen = Some(t);
            }
            CanOpenMessage::SdoRequest { node, request } if node == self.node => {
                if self.nmt == NmtState::Stopped {
                    return;
                }
                if self.plan.as_ref().and_then(|p| p.drive_ignores_object) == Some(request.object().0) {
                    return;
                }
                self.counters.sdo_requests += 1;
                let response = self.sdo(t, request, world);
                if matches!(response, SdoResponse::Abort { .. }) {
                    self.counters.sdo_aborts += 1;
                }
                send(out, CanOpenMessage::SdoResponse { node, response });
            }
            CanOpenMessage::Pdo { direction: PdoDirection::Receive, number: 1, node, data }
                if node == self.node && self.nmt == NmtState::Operational && self.rpdo.valid() =>
            {
                self.counters.rpdos += 1;
                self.receive(t, data, world, out);
            }
            _ => {}
        }
    }

    /// RPDO1 as mapped: its objects written in order.
    fn receive(&mut self, t: f64, data: PdoData, world: &mut World, out: &mut Vec<CanFrame>) {
        let bytes = data.bytes();
        let mut at = 0;
        let mut controlword = None;
        for (index, bits) in self.rpdo.mapped() {
            let n = usize::from(bits / 8);
            let Some(field) = bytes.get(at..at + n) else { return }; // too short: not taken
            at += n;
            let mut raw = [0u8; 4];
            raw[..n].copy_from_slice(field);
            match index {
                object::CONTROLWORD => controlword = Some(u16::from_le_bytes([raw[0], raw[1]])),
                object::TARGET_VELOCITY => self.target = i32::from_le_bytes(raw),
                _ => {}
            }
        }
        if let Some(cw) = controlword {
            self.control(t, cw, world, out);
        }
        self.apply_axis(world);
    }

    /// A controlword written: the transition it asks for, if CiA 402 allows one from here.
    fn control(&mut self, t: f64, cw: u16, world: &mut World, out: &mut Vec<CanFrame>) {
        let before = self.controlword;
        self.controlword = cw;
        let Some(command) = DriveCommand::decode(cw, self.state) else { return };
        use DriveState as S;
        self.state = match command {
            // Bit 7's rising edge only; refused while the cause lasts.
            DriveCommand::FaultReset if before & 0x80 == 0 && !self.under_voltage(t) && !self.blocked(t) => {
                (self.error_code, self.error_register) = (0, 0);
                self.lag_since = None;
                send(
                    out,
                    CanOpenMessage::Emcy {
                        node: self.node,
                        emcy: Emcy { error_code: 0, error_register: 0, vendor: [0; 5] },
                    },
                );
                S::SwitchOnDisabled
            }
            DriveCommand::FaultReset => self.state,
            DriveCommand::Shutdown => S::ReadyToSwitchOn,
            DriveCommand::SwitchOn | DriveCommand::DisableOperation => S::SwitchedOn,
            DriveCommand::EnableOperation => S::OperationEnabled,
            DriveCommand::DisableVoltage => S::SwitchOnDisabled,
            DriveCommand::QuickStop => S::QuickStopActive,
        };
        self.apply_axis(world);
    }

    /// An SDO request served.
    fn sdo(&mut self, t: f64, request: SdoRequest, world: &mut World) -> SdoResponse {
        let (index, sub) = request.object();
        let abort = |code| SdoResponse::Abort { index, sub, code };
        match request {
            SdoRequest::Abort { .. } => abort(abort::UNSUPPORTED_ACCESS),
            SdoRequest::Upload { .. } => match self.read(index, sub, world) {
                Ok(data) => SdoResponse::Uploaded { index, sub, data },
                Err(code) => abort(code),
            },
            SdoRequest::Download { data, .. } => match self.write(t, index, sub, data, world) {
                Ok(()) => SdoResponse::Downloaded { index, sub },
                Err(code) => abort(code),
            },
        }
    }

    fn pdo_mut(&mut self, index: u16) -> Option<(&mut Pdo, bool)> {
        match index {
            object::RPDO1_COMMUNICATION | object::RPDO1_MAPPING => Some((&mut self.rpdo, true)),
            object::TPDO1_COMMUNICATION | object::TPDO1_MAPPING => Some((&mut self.tpdo[0], false)),
            object::TPDO2_COMMUNICATION | object::TPDO2_MAPPING => Some((&mut self.tpdo[1], false)),
            _ => None,
        }
    }

    fn read(&mut self, index: u16, sub: u8, world: &World) -> Result<SdoData, u32> {
        let a = &world.axes()[self.axis];
        let plain = |data: SdoData| if sub == 0 { Ok(data) } else { Err(abort::NO_SUBINDEX) };
        match index {
            0x1000 => plain(SdoData::u32(DEVICE_TYPE)),
            SUPPORTED_DRIVE_MODES => plain(SdoData::u32(PROFILE_VELOCITY_SUPPORTED)),
            object::ERROR_REGISTER => plain(SdoData::u8(self.error_register)),
            object::PRODUCER_HEARTBEAT_TIME => plain(SdoData::u16(self.producer_ms)),
            object::CONSUMER_HEARTBEAT_TIME => match sub {
                0 => Ok(SdoData::u8(1)),
                1 => Ok(SdoData::u32(self.consumer)),
                _ => Err(abort::NO_SUBINDEX),
            },
            object::ERROR_CODE => plain(SdoData::u16(self.error_code)),
            object::CONTROLWORD => plain(SdoData::u16(self.controlword)),
            object::STATUSWORD => plain(SdoData::u16(self.statusword(world))),
            object::QUICK_STOP_OPTION => plain(SdoData::i16(self.quick_stop_option)),
            object::MODES_OF_OPERATION => plain(SdoData::i8(self.mode)),
            object::MODES_OF_OPERATION_DISPLAY => plain(SdoData::i8(self.mode)),
            object::POSITION_ACTUAL => plain(SdoData::i32(a.position() as i32)),
            object::VELOCITY_ACTUAL => plain(SdoData::i32(a.rate().round() as i32)),
            object::MAX_PROFILE_VELOCITY => plain(SdoData::u32(self.max_velocity)),
            object::PROFILE_ACCELERATION => plain(SdoData::u32(self.accel)),
            object::PROFILE_DECELERATION => plain(SdoData::u32(self.decel)),
            object::QUICK_STOP_DECELERATION => plain(SdoData::u32(self.quick_stop_decel)),
            object::TARGET_VELOCITY => plain(SdoData::i32(self.target)),
            _ => {
                let mapping = matches!(index, 0x1600..=0x17FF | 0x1A00..=0x1BFF);
                let (pdo, _) = self.pdo_mut(index).ok_or(abort::NO_OBJECT)?;
                match (mapping, sub) {
                    (true, 0) => Ok(SdoData::u8(pdo.count)),
                    (true, 1..=4) => Ok(SdoData::u32(pdo.mapping[usize::from(sub - 1)])),
                    (false, 0) => Ok(SdoData::u8(5)),
                    (false, 1) => Ok(SdoData::u32(pdo.cob_id)),
                    (false, 2) => Ok(SdoData::u8(pdo.transmission)),
                    (false, 5) => Ok(SdoData::u16(pdo.event_ms)),
                    _ => Err(abort::NO_SUBINDEX),
                }
            }
        }
    }

    fn write(&mut self, t: f64, index: u16, sub: u8, data: SdoData, world: &mut World) -> Result<(), u32> {
        let size = |n: usize| if data.size() == n { Ok(data.value()) } else { Err(abort::LENGTH) };
        let plain = |n: usize| if sub == 0 { size(n) } else { Err(abort::NO_SUBINDEX) };
        match index {
            0x1000 | SUPPORTED_DRIVE_MODES | object::ERROR_REGISTER | object::ERROR_CODE | object::STATUSWORD => {
                Err(abort::READ_ONLY)
            }
            object::MODES_OF_OPERATION_DISPLAY | object::POSITION_ACTUAL | object::VELOCITY_ACTUAL => {
                Err(abort::READ_ONLY)
            }
            object::PRODUCER_HEARTBEAT_TIME => {
                self.producer_ms = plain(2)? as u16;
                self.next_heartbeat = if self.producer_ms == 0 { f64::INFINITY } else { t };
                Ok(())
            }
            object::CONSUMER_HEARTBEAT_TIME => match sub {
                1 => {
                    self.consumer = size(4)?;
                    self.gateway_seen = None;
                    Ok(())
                }
                0 => Err(abort::READ_ONLY),
                _ => Err(abort::NO_SUBINDEX),
            },
            object::CONTROLWORD => {
                let cw = plain(2)? as u16;
                let mut out = Vec::new();
                self.control(t, cw, world, &mut out);
                Ok(())
            }
            object::QUICK_STOP_OPTION => match plain(2)? as u16 as i16 {
                v @ 0..=2 | v @ 5..=6 => {
                    self.quick_stop_option = v;
                    Ok(())
                }
                _ => Err(abort::RANGE),
            },
            object::MODES_OF_OPERATION => {
                // Profile velocity is the one mode this drive runs.
                if plain(1)? as u8 as i8 != canopen::PROFILE_VELOCITY_MODE {
                    return Err(abort::RANGE);
                }
                self.mode = canopen::PROFILE_VELOCITY_MODE;
                self.apply_axis(world);
                Ok(())
            }
            object::MAX_PROFILE_VELOCITY
            | object::PROFILE_ACCELERATION
            | object::PROFILE_DECELERATION
            | object::QUICK_STOP_DECELERATION => {
                let v = plain(4)?;
                if v == 0 {
                    return Err(abort::RANGE);
                }
                match index {
                    object::MAX_PROFILE_VELOCITY => self.max_velocity = v,
                    object::PROFILE_ACCELERATION => self.accel = v,
                    object::PROFILE_DECELERATION => self.decel = v,
                    _ => self.quick_stop_decel = v,
                }
                self.apply_axis(world);
                Ok(())
            }
            object::TARGET_VELOCITY => {
                self.target = plain(4)? as i32;
                self.apply_axis(world);
                Ok(())
            }
            _ => self.write_pdo(t, index, sub, data),
        }
    }

    /// A PDO's communication or mapping parameter. The mapping changes only while the PDO is
    /// invalid, and only to objects it can carry in its direction, eight bytes at most.
    fn write_pdo(&mut self, t: f64, index: u16, sub: u8, data: SdoData) -> Result<(), u32> {
        let mapping = matches!(index, 0x1600..=0x17FF | 0x1A00..=0x1BFF);
        let tpdo = index >= 0x1800;
        let Some((pdo, receive)) = self.pdo_mut(index) else { return Err(abort::NO_OBJECT) };
        let size = |n: usize| if data.size() == n { Ok(data.value()) } else { Err(abort::LENGTH) };
        if mapping {
            if pdo.valid() {
                return Err(abort::DEVICE_STATE);
            }
            match sub {
                0 => {
                    let count = size(1)? as u8;
                    if count > 4 {
                        return Err(abort::PDO_LENGTH);
                    }
                    let bits: u32 = pdo.mapping[..usize::from(count)].iter().map(|m| m & 0xFF).sum();
                    if bits > 64 {
                        return Err(abort::PDO_LENGTH);
                    }
                    pdo.count = count;
                }
                1..=4 => {
                    if pdo.count != 0 {
                        return Err(abort::DEVICE_STATE);
                    }
                    let entry = size(4)?;
                    let (object, bits) = ((entry >> 16) as u16, (entry & 0xFF) as u8);
                    match mappable(object) {
                        Some((b, r)) if b == bits && r == receive && (entry >> 8) & 0xFF == 0 => {}
                        _ => return Err(abort::NOT_MAPPABLE),
                    }
                    pdo.mapping[usize::from(sub - 1)] = entry;
                }
                _ => return Err(abort::NO_SUBINDEX),
            }
            return Ok(());
        }
        match sub {
            1 => {
                let cob = size(4)?;
                // Only the predefined COB-ID, valid or not (no remapping of identifiers).
                let own = pdo.cob_id & !canopen::PDO_INVALID;
                if cob & !canopen::PDO_INVALID != own {
                    return Err(abort::RANGE);
                }
                pdo.cob_id = cob;
            }
            2 => {
                let kind = size(1)? as u8;
                if kind != canopen::TRANSMISSION_EVENT && kind != 254 {
                    return Err(abort::RANGE); // synchronous types: this drive has no SYNC
                }
                pdo.transmission = kind;
            }
            5 if tpdo => pdo.event_ms = size(2)? as u16,
            0 => return Err(abort::READ_ONLY),
            _ => return Err(abort::NO_SUBINDEX),
        }
        self.schedule(t);
        Ok(())
    }

    /// The TPDOs' next event-timer times, from `t`.
    fn schedule(&mut self, t: f64) {
        for (k, pdo) in self.tpdo.iter().enumerate() {
            let runs = self.nmt == NmtState::Operational && pdo.valid() && pdo.event_ms > 0;
            self.next_tpdo[k] = if runs { t } else { f64::INFINITY };
        }
    }

    /// When [`Cia402Drive::poll`] next has something to do.
    pub fn next_event(&self) -> f64 {
        let mut next = self.next_heartbeat.min(self.next_tpdo[0]).min(self.next_tpdo[1]);
        if let Some(plan) = &self.plan {
            let reboot = plan.board_reboot_at.filter(|_| !self.reboot_done);
            let edges = plan.drive_undervoltage.into_iter().chain(plan.drive_blocked).flatten();
            for at in reboot.into_iter().chain(edges) {
                if at > self.last_poll {
                    next = next.min(at);
                }
            }
        }
        if let Some(since) = self.lag_since {
            next = next.min(since + FOLLOWING_ERROR_TIMEOUT);
        }
        let consumer_ms = self.consumer & 0xFFFF;
        if let (Some(seen), true) = (self.gateway_seen, self.state.is_enabled() && consumer_ms > 0) {
            next = next.min(seen + f64::from(consumer_ms) * 1e-3);
        }
        next
    }

    /// Timeouts, faults and periodic frames due by `t`.
    pub fn poll(&mut self, t: f64, world: &mut World, out: &mut Vec<CanFrame>) {
        self.last_poll = t;
        if let Some(at) = self.plan.as_ref().and_then(|p| p.board_reboot_at) {
            if !self.reboot_done && t >= at {
                self.reboot_done = true;
                self.boot(t, world, out);
            }
        }
        if self.under_voltage(t) {
            self.fault(UNDER_VOLTAGE, world, out);
        }
        if self.blocked(t) {
            world.stop_axis(self.axis);
            let chasing = self.state.is_enabled() && self.target != 0;
            match (chasing, self.lag_since) {
                (true, None) => self.lag_since = Some(t),
                (true, Some(since)) if t >= since + FOLLOWING_ERROR_TIMEOUT => self.fault(FOLLOWING_ERROR, world, out),
                (false, _) => self.lag_since = None,
                _ => {}
            }
        } else {
            // Free again: no following error can come of the lag any more.
            self.lag_since = None;
        }
        let consumer_ms = self.consumer & 0xFFFF;
        if let (Some(seen), true) = (self.gateway_seen, self.state.is_enabled() && consumer_ms > 0) {
            if t > seen + f64::from(consumer_ms) * 1e-3 {
                self.fault(HEARTBEAT_ERROR, world, out);
            }
        }
        // Quick stop option 2: switch on disabled once at rest.
        if self.state == DriveState::QuickStopActive && world.axes()[self.axis].rate() == 0.0 {
            self.state = DriveState::SwitchOnDisabled;
        }
        let silent = self.silent(t);
        while self.next_heartbeat <= t {
            if !silent {
                send(out, CanOpenMessage::Heartbeat { node: self.node, state: self.nmt });
            }
            self.next_heartbeat += f64::from(self.producer_ms.max(1)) * 1e-3;
        }
        if self.nmt == NmtState::Operational {
            let sw = self.statusword(world);
            let changed = self.tpdo[0].valid() && self.statusword_sent != Some(sw);
            for k in 0..2 {
                let due = self.next_tpdo[k] <= t;
                if due || (k == 0 && changed) {
                    self.transmit(k, world, out);
                }
                while self.next_tpdo[k] <= t {
                    self.next_tpdo[k] += f64::from(self.tpdo[k].event_ms.max(1)) * 1e-3;
                }
            }
        }
    }

    /// TPDO `k` + 1 as mapped.
    fn transmit(&mut self, k: usize, world: &World, out: &mut Vec<CanFrame>) {
        let pdo = self.tpdo[k];
        if !pdo.valid() {
            return;
        }
        let a = &world.axes()[self.axis];
        let sw = self.statusword(world);
        let mut bytes = [0u8; 8];
        let mut at = 0;
        for (index, bits) in pdo.mapped() {
            let value: u32 = match index {
                object::STATUSWORD => u32::from(sw),
                object::VELOCITY_ACTUAL => a.rate().round() as i32 as u32,
                object::POSITION_ACTUAL => a.position() as i32 as u32,
                _ => 0,
            };
            let n = usize::from(bits / 8);
            bytes[at..at + n].copy_from_slice(&value.to_le_bytes()[..n]);
            at += n;
        }
        if k == 0 {
            self.statusword_sent = Some(sw);
        }
        if let Some(data) = PdoData::new(&bytes[..at]) {
            send(
                out,
                CanOpenMessage::Pdo { direction: PdoDirection::Transmit, number: k as u8 + 1, node: self.node, data },
            );
        }
    }
}

/// The default mappings, as the EDS gives them.
const RPDO1_DEFAULT: [u32; 2] =
    [canopen::mapping_entry(object::CONTROLWORD, 0, 16), canopen::mapping_entry(object::TARGET_VELOCITY, 0, 32)];
const TPDO1_DEFAULT: [u32; 2] =
    [canopen::mapping_entry(object::STATUSWORD, 0, 16), canopen::mapping_entry(object::VELOCITY_ACTUAL, 0, 32)];
const TPDO2_DEFAULT: [u32; 1] = [canopen::mapping_entry(object::POSITION_ACTUAL, 0, 32)];

fn send(out: &mut Vec<CanFrame>, message: CanOpenMessage) {
    if let Some(frame) = message.to_frame() {
        out.push(frame);
    }
}
