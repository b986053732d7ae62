//! Consistent Overhead Byte Stuffing (Cheshire & Baker, 1999).
//!
//! COBS removes every 0x00 from a frame so that 0x00 can delimit frames on a byte stream.
//! The encoded frame is at most `n + ceil(n / 254) + 1` bytes long for `n` input bytes
//! ([`max_encoded_len`]). A receiver that loses sync simply waits for the next 0x00.
//!
//! Neither function writes the 0x00 delimiter; the frame layer adds it.

/// Why a COBS frame could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CobsError {
    /// The output buffer cannot hold the result.
    #[error("output buffer too small")]
    BufferTooSmall,
    /// A 0x00 byte inside an encoded frame (COBS never emits one).
    #[error("zero byte inside a COBS frame at offset {0}")]
    ZeroByte(usize),
    /// A code byte points past the end of the frame.
    #[error("COBS code byte at offset {0} runs past the end of the frame")]
    Truncated(usize),
    /// An empty encoded frame (a valid frame is at least one code byte).
    #[error("empty COBS frame")]
    Empty,
}

/// The largest encoded size of `n` input bytes (without the delimiter).
pub const fn max_encoded_len(n: usize) -> usize {
    n + n / 254 + 1
}

/// Encode `src` into `dst`, returning the encoded length.
pub fn encode(src: &[u8], dst: &mut [u8]) -> Result<usize, CobsError> {
    let mut code_at = 0; // where the current block's code byte goes
    let mut out = 1;
    let mut code: u8 = 1;
    if dst.is_empty() {
        return Err(CobsError::BufferTooSmall);
    }
    for &b in src {
        if b == 0 {
            dst[code_at] = code;
            code_at = out;
            out += 1;
            code = 1;
        } else {
            *dst.get_mut(out).ok_or(CobsError::BufferTooSmall)? = b;
            out += 1;
            code += 1;
            if code == 0xFF {
                dst[code_at] = code;
                code_at = out;
                out += 1;
                code = 1;
            }
        }
        if code_at >= dst.len() {
            return Err(CobsError::BufferTooSmall);
        }
    }
    dst[code_at] = code;
    Ok(out)
}

/// Decode one encoded frame `src` (delimiter already removed) into `dst`,
/// returning the decoded length.
pub fn decode(src: &[u8], dst: &mut [u8]) -> Result<usize, CobsError> {
    if src.is_empty() {
        return Err(CobsError::Empty);
    }
    let mut i = 0;
    let mut out = 0;
    while i < src.len() {
        let code = src[i];
        if code == 0 {
            return Err(CobsError::ZeroByte(i));
        }
        let block_end = i + usize::from(code);
        if block_end > src.len() {
            return Err(CobsError::Truncated(i));
        }
        for (k, &b) in src[i + 1..block_end].iter().enumerate() {
            if b == 0 {
                return Err(CobsError::ZeroByte(i + 1 + k));
            }
            *dst.get_mut(out).ok_or(CobsError::BufferTooSmall)? = b;
            out += 1;
        }
        i = block_end;
        // A block shorter than 255 is followed by a zero, except at the very end.
        if code != 0xFF && i < src.len() {
            *dst.get_mut(out).ok_or(CobsError::BufferTooSmall)? = 0;
            out += 1;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Examples from the COBS paper / Wikipedia, both directions.
    #[test]
    fn golden_vectors() {
        let cases: &[(&[u8], &[u8])] = &[
            (&[0x00], &[0x01, 0x01]),
            (&[0x00, 0x00], &[0x01, 0x01, 0x01]),
            (&[0x00, 0x11, 0x00], &[0x01, 0x02, 0x11, 0x01]),
            (&[0x11, 0x22, 0x00, 0x33], &[0x03, 0x11, 0x22, 0x02, 0x33]),
            (&[0x11, 0x22, 0x33, 0x44], &[0x05, 0x11, 0x22, 0x33, 0x44]),
            (&[0x11, 0x00, 0x00, 0x00], &[0x02, 0x11, 0x01, 0x01, 0x01]),
            (&[], &[0x01]),
        ];
        for (raw, enc) in cases {
            let mut buf = [0u8; 16];
            let n = encode(raw, &mut buf).unwrap();
            assert_eq!(&buf[..n], *enc, "encode {raw:02x?}");
            let n = decode(enc, &mut buf).unwrap();
            assert_eq!(&buf[..n], *raw, "decode {enc:02x?}");
        }
    }

    #[test]
    fn long_block_of_254_non_zero_bytes() {
        let raw: [u8; 254] = core::array::from_fn(|i| (i + 1) as u8);
        let mut enc = [0u8; 300];
        let n = encode(&raw, &mut enc).unwrap();
        assert_eq!(n, 256);
        assert_eq!(enc[0], 0xFF);
        assert_eq!(enc[255], 0x01);
        let mut dec = [0u8; 300];
        let m = decode(&enc[..n], &mut dec).unwrap();
        assert_eq!(&dec[..m], &raw[..]);
    }

    #[test]
    fn rejects_malformed() {
        let mut buf = [0u8; 16];
        assert_eq!(decode(&[], &mut buf), Err(CobsError::Empty));
        assert_eq!(decode(&[0x03, 0x11], &mut buf), Err(CobsError::Truncated(0)));
        assert_eq!(decode(&[0x03, 0x00, 0x11], &mut buf), Err(CobsError::ZeroByte(1)));
        assert_eq!(decode(&[0x05, 1, 2, 3, 4], &mut [0u8; 2]), Err(CobsError::BufferTooSmall));
        assert_eq!(encode(&[1, 2, 3], &mut [0u8; 3]), Err(CobsError::BufferTooSmall));
    }

    proptest! {
        #[test]
        fn round_trip(raw in proptest::collection::vec(any::<u8>(), 0..700)) {
            let mut enc = vec![0u8; max_encoded_len(raw.len())];
            let n = encode(&raw, &mut enc).unwrap();
            prop_assert!(n <= max_encoded_len(raw.len()));
            prop_assert!(!enc[..n].contains(&0));
            let mut dec = vec![0u8; raw.len()];
            let m = decode(&enc[..n], &mut dec).unwrap();
            prop_assert_eq!(&dec[..m], &raw[..]);
        }

        #[test]
        fn encode_never_panics_on_small_buffers(raw in proptest::collection::vec(any::<u8>(), 0..64), cap in 0usize..70) {
            let mut enc = vec![0u8; cap];
            if let Ok(n) = encode(&raw, &mut enc) {
                let mut dec = vec![0u8; raw.len()];
                let m = decode(&enc[..n], &mut dec).unwrap();
                prop_assert_eq!(&dec[..m], &raw[..]);
            }
        }

        #[test]
        fn decode_never_panics(enc in proptest::collection::vec(any::<u8>(), 0..300), cap in 0usize..300) {
            let mut dec = vec![0u8; cap];
            let _ = decode(&enc, &mut dec);
        }
    }
}
