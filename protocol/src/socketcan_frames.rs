//! Conversions between [`CanFrame`] and `socketcan` frames (feature `socketcan`).

use crate::can::{CanFrame, CanId};
use socketcan::{EmbeddedFrame, ExtendedId, Id, StandardId};

impl From<CanFrame> for socketcan::CanFrame {
    fn from(f: CanFrame) -> Self {
        let id: Id = match f.id() {
            CanId::Standard(id) => StandardId::new(id).expect("CanFrame ids are in range").into(),
            CanId::Extended(id) => ExtendedId::new(id).expect("CanFrame ids are in range").into(),
        };
        let frame = if f.is_remote() {
            socketcan::CanFrame::new_remote(id, usize::from(f.dlc()))
        } else {
            socketcan::CanFrame::new(id, f.data())
        };
        frame.expect("CanFrame lengths are in range")
    }
}

/// Why a socketcan frame has no [`CanFrame`]: it is an error frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("CAN error frame (class 0x{0:08X})")]
pub struct ErrorFrame(pub u32);

impl TryFrom<&socketcan::CanFrame> for CanFrame {
    type Error = ErrorFrame;
    fn try_from(f: &socketcan::CanFrame) -> Result<Self, ErrorFrame> {
        if let socketcan::CanFrame::Error(e) = f {
            return Err(ErrorFrame(socketcan::Frame::id_word(e)));
        }
        let id = match f.id() {
            Id::Standard(id) => CanId::Standard(id.as_raw()),
            Id::Extended(id) => CanId::Extended(id.as_raw()),
        };
        let frame = if f.is_remote_frame() { CanFrame::remote(id, f.dlc() as u8) } else { CanFrame::new(id, f.data()) };
        Ok(frame.expect("socketcan frames are in range"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_data_and_remote_frames() {
        for f in [
            CanFrame::new(CanId::Standard(0x101), &[1, 2, 3]).unwrap(),
            CanFrame::new(CanId::Extended(0x1234_5678), &[]).unwrap(),
            CanFrame::remote(CanId::Standard(0x701), 1).unwrap(),
        ] {
            let s: socketcan::CanFrame = f.into();
            assert_eq!(CanFrame::try_from(&s).unwrap(), f);
        }
    }
}
