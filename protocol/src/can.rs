//! A classic CAN 2.0 frame as a plain value, independent of any driver.
//!
//! The gateway converts it to and from `socketcan` frames and SLCAN lines; the protocol
//! modules build and read it. CAN FD is out of scope: the motor boards speak CAN 2.0.

/// Largest standard (11-bit) identifier.
pub const MAX_STANDARD_ID: u16 = 0x7FF;
/// Largest extended (29-bit) identifier.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

/// A node id type on a bus, `$min..=$max`: made only through `new`, which refuses the rest.
macro_rules! node_id {
    ($(#[$m:meta])* $name:ident, $min:literal..=$max:literal) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub struct $name(u8);

        impl $name {
            pub const MIN: u8 = $min;
            pub const MAX: u8 = $max;
            #[doc = concat!("A node id, or `None` outside ", stringify!($min), "..=", stringify!($max), ".")]
            pub const fn new(id: u8) -> Option<Self> {
                if id >= Self::MIN && id <= Self::MAX {
                    Some(Self(id))
                } else {
                    None
                }
            }
            pub const fn get(self) -> u8 {
                self.0
            }
        }
    };
}
pub(crate) use node_id;

/// A standard identifier a device on the bus sends or listens on, and what it carries there:
/// the rows of a protocol's identifier table, for checking that the devices sharing one bus
/// keep apart (two devices on one identifier would each take the other's frames as their own).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IdUse {
    pub id: u16,
    pub what: &'static str,
}

/// A CAN identifier: 11-bit standard or 29-bit extended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CanId {
    Standard(u16),
    Extended(u32),
}

impl CanId {
    /// A standard id, or `None` above 0x7FF.
    pub const fn standard(id: u16) -> Option<Self> {
        if id <= MAX_STANDARD_ID {
            Some(Self::Standard(id))
        } else {
            None
        }
    }
    /// An extended id, or `None` above 0x1FFF_FFFF.
    pub const fn extended(id: u32) -> Option<Self> {
        if id <= MAX_EXTENDED_ID {
            Some(Self::Extended(id))
        } else {
            None
        }
    }
    /// The raw identifier bits.
    pub const fn raw(self) -> u32 {
        match self {
            Self::Standard(id) => id as u32,
            Self::Extended(id) => id,
        }
    }
    pub const fn is_extended(self) -> bool {
        matches!(self, Self::Extended(_))
    }
}

/// Why a [`CanFrame`] could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CanFrameError {
    #[error("CAN identifier 0x{0:X} out of range")]
    IdOutOfRange(u32),
    #[error("CAN data length {0} exceeds 8")]
    TooLong(usize),
}

/// A classic CAN data or remote frame.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: CanId,
    remote: bool,
    len: u8,
    data: [u8; 8],
}

impl CanFrame {
    /// The most bit times this frame can take on the bus: its fields, the most stuff bits
    /// its contents can need, and the 3-bit interframe space, `g + 8s + 13 + ⌊(g + 8s - 1) /
    /// 4⌋` with `g` = 34 (standard) or 54 (extended) and `s` data bytes (Davis, Burns, Bril
    /// and Lukkien, 2007). A remote frame carries no data.
    pub const fn worst_case_bits(&self) -> u32 {
        let g = if self.id.is_extended() { 54 } else { 34 };
        let s = if self.remote { 0 } else { self.len as u32 };
        g + 8 * s + 13 + (g + 8 * s - 1) / 4
    }

    /// A data frame. The id must be in range for its kind, the data at most 8 bytes.
    pub fn new(id: CanId, data: &[u8]) -> Result<Self, CanFrameError> {
        check_id(id)?;
        if data.len() > 8 {
            return Err(CanFrameError::TooLong(data.len()));
        }
        let mut buf = [0u8; 8];
        buf[..data.len()].copy_from_slice(data);
        Ok(Self { id, remote: false, len: data.len() as u8, data: buf })
    }

    /// A remote (RTR) frame requesting `len` bytes.
    pub fn remote(id: CanId, len: u8) -> Result<Self, CanFrameError> {
        check_id(id)?;
        if len > 8 {
            return Err(CanFrameError::TooLong(len.into()));
        }
        Ok(Self { id, remote: true, len, data: [0; 8] })
    }

    /// A standard data frame; for builders whose id and length are known to be valid.
    pub(crate) fn standard(id: u16, data: &[u8]) -> Self {
        debug_assert!(id <= MAX_STANDARD_ID && data.len() <= 8);
        let mut buf = [0u8; 8];
        buf[..data.len()].copy_from_slice(data);
        Self { id: CanId::Standard(id & MAX_STANDARD_ID), remote: false, len: data.len() as u8, data: buf }
    }

    pub const fn id(&self) -> CanId {
        self.id
    }
    pub const fn is_remote(&self) -> bool {
        self.remote
    }
    /// The data length code (0..=8). For a remote frame, the requested length.
    pub const fn dlc(&self) -> u8 {
        self.len
    }
    /// The data bytes (empty for a remote frame).
    pub fn data(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            &self.data[..usize::from(self.len)]
        }
    }
}

fn check_id(id: CanId) -> Result<(), CanFrameError> {
    match id {
        CanId::Standard(v) if v > MAX_STANDARD_ID => Err(CanFrameError::IdOutOfRange(v.into())),
        CanId::Extended(v) if v > MAX_EXTENDED_ID => Err(CanFrameError::IdOutOfRange(v)),
        _ => Ok(()),
    }
}

impl core::fmt::Debug for CanFrame {
    /// candump style: `123#DEADBEEF`, `12345678#`, `123#R2`.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.id {
            CanId::Standard(id) => write!(f, "{id:03X}#")?,
            CanId::Extended(id) => write!(f, "{id:08X}#")?,
        }
        if self.remote {
            write!(f, "R{}", self.len)
        } else {
            self.data().iter().try_for_each(|b| write!(f, "{b:02X}"))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Worked values of the worst-case length: 8 bytes standard 135 bit times, none 55,
    /// 8 bytes extended 160.
    #[test]
    fn worst_case_lengths_match_worked_values() {
        assert_eq!(CanFrame::new(CanId::Standard(0x123), &[0; 8]).unwrap().worst_case_bits(), 135);
        assert_eq!(CanFrame::new(CanId::Standard(0x123), &[]).unwrap().worst_case_bits(), 55);
        assert_eq!(CanFrame::new(CanId::Extended(0x123), &[0; 8]).unwrap().worst_case_bits(), 160);
    }

    #[test]
    fn validates_ids_and_length() {
        assert!(CanFrame::new(CanId::Standard(0x7FF), &[1; 8]).is_ok());
        assert_eq!(CanFrame::new(CanId::Standard(0x800), &[]), Err(CanFrameError::IdOutOfRange(0x800)));
        assert_eq!(CanFrame::new(CanId::Extended(0x2000_0000), &[]), Err(CanFrameError::IdOutOfRange(0x2000_0000)));
        assert_eq!(CanFrame::new(CanId::Standard(1), &[0; 9]), Err(CanFrameError::TooLong(9)));
        assert_eq!(CanFrame::remote(CanId::Standard(1), 9), Err(CanFrameError::TooLong(9)));
        let r = CanFrame::remote(CanId::Extended(0x1234), 4).unwrap();
        assert!(r.data().is_empty());
        assert_eq!(r.dlc(), 4);
    }
}
