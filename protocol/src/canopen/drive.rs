//! The CiA 402 drive profile: the state machine as the statusword shows it, the controlword's
//! commands, and the velocity PDOs.

use super::PdoData;
use crate::wire::{Reader, Writer};

/// The states of the CiA 402 drive state machine, as the statusword shows them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DriveState {
    NotReadyToSwitchOn,
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    QuickStopActive,
    FaultReactionActive,
    Fault,
}

/// Statusword bits beside the state's.
pub mod statusword {
    pub const VOLTAGE_ENABLED: u16 = 1 << 4;
    pub const WARNING: u16 = 1 << 7;
    pub const REMOTE: u16 = 1 << 9;
    pub const TARGET_REACHED: u16 = 1 << 10;
    pub const INTERNAL_LIMIT_ACTIVE: u16 = 1 << 11;
    /// In profile velocity mode: the speed is zero (bit 12); in position modes the
    /// following error (bit 13) is set when it exceeds its window.
    pub const SPEED_ZERO: u16 = 1 << 12;
    pub const FOLLOWING_ERROR: u16 = 1 << 13;
}

impl DriveState {
    /// The state a statusword shows (CiA 402 table of bits 0-3, 5 and 6). Every statusword
    /// maps to one of the eight states.
    pub const fn from_statusword(sw: u16) -> Self {
        match (sw & 0x4F, sw & 0x6F) {
            (0x00, _) => Self::NotReadyToSwitchOn,
            (0x40, _) => Self::SwitchOnDisabled,
            (0x0F, _) => Self::FaultReactionActive,
            (0x08, _) => Self::Fault,
            (_, 0x21) => Self::ReadyToSwitchOn,
            (_, 0x23) => Self::SwitchedOn,
            (_, 0x27) => Self::OperationEnabled,
            (_, 0x07) => Self::QuickStopActive,
            // Bit patterns the table leaves undefined read as the nearest safe state: not
            // yet ready, so the gateway commands nothing.
            _ => Self::NotReadyToSwitchOn,
        }
    }

    /// The statusword's state bits for this state (a simulated drive's report).
    pub const fn statusword_bits(self) -> u16 {
        match self {
            Self::NotReadyToSwitchOn => 0x00,
            Self::SwitchOnDisabled => 0x40,
            Self::ReadyToSwitchOn => 0x21,
            Self::SwitchedOn => 0x23,
            Self::OperationEnabled => 0x27,
            Self::QuickStopActive => 0x07,
            Self::FaultReactionActive => 0x0F,
            Self::Fault => 0x08,
        }
    }

    /// The command that takes a drive one step towards operation enabled from here, or
    /// `None` where there is nothing to send: already there, or a state the drive leaves
    /// by itself (not ready to switch on, fault reaction active). A fault is reset; a quick
    /// stop is left through switch on disabled, as CiA 402 requires.
    pub const fn towards_operation(self) -> Option<DriveCommand> {
        match self {
            Self::SwitchOnDisabled => Some(DriveCommand::Shutdown),
            Self::ReadyToSwitchOn => Some(DriveCommand::SwitchOn),
            Self::SwitchedOn => Some(DriveCommand::EnableOperation),
            Self::QuickStopActive => Some(DriveCommand::DisableVoltage),
            Self::Fault => Some(DriveCommand::FaultReset),
            Self::OperationEnabled | Self::NotReadyToSwitchOn | Self::FaultReactionActive => None,
        }
    }

    /// Whether the drive follows a target (and so holds power on the motor).
    pub const fn is_enabled(self) -> bool {
        matches!(self, Self::OperationEnabled)
    }

    /// The state's name as CiA 402 gives it.
    pub const fn name(self) -> &'static str {
        match self {
            Self::NotReadyToSwitchOn => "not ready to switch on",
            Self::SwitchOnDisabled => "switch on disabled",
            Self::ReadyToSwitchOn => "ready to switch on",
            Self::SwitchedOn => "switched on",
            Self::OperationEnabled => "operation enabled",
            Self::QuickStopActive => "quick stop active",
            Self::FaultReactionActive => "fault reaction active",
            Self::Fault => "fault",
        }
    }
}

/// A controlword command (CiA 402 device control).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DriveCommand {
    /// To ready to switch on.
    Shutdown,
    /// To switched on.
    SwitchOn,
    /// To operation enabled (from switched on, or from ready to switch on in one step).
    EnableOperation,
    /// Back to switched on, the motor held without following.
    DisableOperation,
    /// To switch on disabled: power off the motor.
    DisableVoltage,
    /// Brake on the quick stop deceleration, then (by the quick stop option code) to switch
    /// on disabled.
    QuickStop,
    /// From fault to switch on disabled (bit 7; it acts on the rising edge, so the command
    /// sent before it must not have had bit 7 set).
    FaultReset,
}

impl DriveCommand {
    pub const fn controlword(self) -> u16 {
        match self {
            Self::Shutdown => 0x0006,
            Self::SwitchOn | Self::DisableOperation => 0x0007,
            Self::EnableOperation => 0x000F,
            Self::DisableVoltage => 0x0000,
            Self::QuickStop => 0x0002,
            Self::FaultReset => 0x0080,
        }
    }

    /// The command a controlword gives a drive in `state`, by the transitions CiA 402
    /// allows from there; `None`: none applies, the drive stays.
    pub const fn decode(controlword: u16, state: DriveState) -> Option<Self> {
        use DriveState as S;
        let (bits, reset) = (controlword & 0x0F, controlword & 0x80 != 0);
        // Bit 7 acts in a fault only; elsewhere the other bits say what to do.
        if matches!(state, S::Fault) {
            return if reset { Some(Self::FaultReset) } else { None };
        }
        match (bits & 0x02 == 0, bits & 0x06 == 0x02, state) {
            // Bit 1 (enable voltage) clear: disable voltage, from any powered state.
            (true, _, S::ReadyToSwitchOn | S::SwitchedOn | S::OperationEnabled | S::QuickStopActive) => {
                Some(Self::DisableVoltage)
            }
            // Bit 2 (quick stop) clear with bit 1 set: quick stop.
            (false, true, S::OperationEnabled) => Some(Self::QuickStop),
            (false, true, S::ReadyToSwitchOn | S::SwitchedOn) => Some(Self::DisableVoltage),
            _ => match (bits, state) {
                (0x6 | 0xE, S::SwitchOnDisabled | S::SwitchedOn | S::OperationEnabled) => Some(Self::Shutdown),
                (0x7, S::ReadyToSwitchOn) => Some(Self::SwitchOn),
                (0x7, S::OperationEnabled) => Some(Self::DisableOperation),
                (0xF, S::ReadyToSwitchOn | S::SwitchedOn | S::QuickStopActive) => Some(Self::EnableOperation),
                _ => None,
            },
        }
    }
}

/// The RPDO1 flowgate maps on a drive: controlword (0x6040, u16) then target velocity
/// (0x60FF, i32), six bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct VelocityCommand {
    pub controlword: u16,
    pub target_velocity: i32,
}

/// The TPDO1 flowgate maps on a drive: statusword (0x6041, u16) then velocity actual
/// (0x606C, i32), six bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct VelocityReport {
    pub statusword: u16,
    pub velocity_actual: i32,
}

/// The layout both velocity PDOs share: a 16-bit word (controlword or statusword), then a
/// signed 32-bit velocity.
pub(super) const WORD_AND_VELOCITY_LEN: usize = 6;

pub(super) fn word_and_velocity(word: u16, velocity: i32) -> PdoData {
    let mut bytes = [0u8; 8];
    let mut w = Writer::new(&mut bytes);
    // Six bytes into eight: cannot fail.
    let _ = w.u16(word).and_then(|()| w.i32(velocity));
    PdoData { bytes, len: WORD_AND_VELOCITY_LEN as u8 }
}

/// `None` unless exactly six bytes.
pub(super) fn parse_word_and_velocity(data: &PdoData) -> Option<(u16, i32)> {
    (usize::from(data.len) == WORD_AND_VELOCITY_LEN).then_some(())?;
    let mut r = Reader::new(data.bytes());
    Some((r.u16()?, r.i32()?))
}

impl VelocityCommand {
    pub const LEN: usize = WORD_AND_VELOCITY_LEN;
    pub fn data(&self) -> PdoData {
        word_and_velocity(self.controlword, self.target_velocity)
    }
    /// `None` unless exactly six bytes.
    pub fn parse(data: &PdoData) -> Option<Self> {
        parse_word_and_velocity(data).map(|(controlword, target_velocity)| Self { controlword, target_velocity })
    }
}

impl VelocityReport {
    pub const LEN: usize = WORD_AND_VELOCITY_LEN;
    pub fn data(&self) -> PdoData {
        word_and_velocity(self.statusword, self.velocity_actual)
    }
    /// `None` unless exactly six bytes.
    pub fn parse(data: &PdoData) -> Option<Self> {
        parse_word_and_velocity(data).map(|(statusword, velocity_actual)| Self { statusword, velocity_actual })
    }
}
