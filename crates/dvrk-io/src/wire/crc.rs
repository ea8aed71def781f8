//! FireWire CRC-32 (reference §9): polynomial 0x04C11DB7, MSB first, initial value and final XOR
//! 0xFFFF_FFFF, no reflection (catalogue name CRC-32/BZIP2). Computed over the bytes as sent
//! (big-endian quadlets) and stored big-endian.

const POLY: u32 = 0x04C1_1DB7;

const fn make_table() -> [u32; 256] {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = (i as u32) << 24;
        let mut bit = 0;
        while bit < 8 {
            c = if c & 0x8000_0000 != 0 {
                (c << 1) ^ POLY
            } else {
                c << 1
            };
            bit += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
}

static TABLE: [u32; 256] = make_table();

/// CRC-32/BZIP2 of `data`, the FireWire header and data CRC (reference §1.1, §3.1, §9).
pub fn crc32_bzip2(data: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in data {
        let idx = ((crc >> 24) as u8 ^ b) as usize;
        crc = (crc << 8) ^ TABLE[idx];
    }
    !crc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn catalogue_check_value() {
        // CRC-32/BZIP2 check value over the ASCII digits 1..9.
        assert_eq!(crc32_bzip2(b"123456789"), 0xFC89_1918);
    }

    #[test]
    fn reference_section_9_vectors() {
        let q_write = [
            0xff, 0xff, 0x04, 0x00, 0xff, 0xd0, 0x00, 0x00, 0x00, 0x00, 0x00, 0x0b, 0x01, 0x00,
            0x00, 0x7f,
        ];
        assert_eq!(crc32_bzip2(&q_write), 0x11c0_36d8);
        let q_read = [
            0xff, 0xff, 0x08, 0x40, 0xff, 0xd0, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04,
        ];
        assert_eq!(crc32_bzip2(&q_read), 0x58ff_b182);
    }

    #[test]
    fn empty_input() {
        assert_eq!(crc32_bzip2(&[]), 0);
    }
}
