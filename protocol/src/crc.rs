//! CRC-16/IBM-3740 (also known as CRC-16/CCITT-FALSE, CRC-16/AUTOSAR).
//!
//! Polynomial 0x1021, initial value 0xFFFF, no reflection, no final XOR.
//! The catalogue check value: `crc16_ibm3740(b"123456789") == 0x29B1`.

const POLY: u16 = 0x1021;

const TABLE: [u16; 256] = build_table();

const fn build_table() -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ POLY } else { crc << 1 };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
}

/// CRC-16/IBM-3740 of `data`.
pub fn crc16_ibm3740(data: &[u8]) -> u16 {
    data.iter().fold(0xFFFF, |crc, &b| (crc << 8) ^ TABLE[usize::from((crc >> 8) as u8 ^ b)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn catalogue_check_value() {
        assert_eq!(crc16_ibm3740(b"123456789"), 0x29B1);
        assert_eq!(crc16_ibm3740(b""), 0xFFFF);
    }

    /// The table-driven CRC equals the bit-by-bit definition.
    #[test]
    fn table_matches_bitwise_definition() {
        fn bitwise(data: &[u8]) -> u16 {
            let mut crc: u16 = 0xFFFF;
            for &b in data {
                crc ^= u16::from(b) << 8;
                for _ in 0..8 {
                    crc = if crc & 0x8000 != 0 { (crc << 1) ^ POLY } else { crc << 1 };
                }
            }
            crc
        }
        let data: [u8; 64] = core::array::from_fn(|i| (i * 37 + 11) as u8);
        for n in 0..data.len() {
            assert_eq!(crc16_ibm3740(&data[..n]), bitwise(&data[..n]));
        }
    }
}
