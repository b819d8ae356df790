//! How long a frame holds the bus. A classic frame is SOF, arbitration,
//! control, data and CRC (where the transmitter stuffs a complementary
//! bit after five equal ones), then CRC delimiter, ACK, end of frame and
//! the intermission, 13 bits never stuffed: 47 + 8n bits for a standard
//! frame of n bytes before stuffing, 67 + 8n extended. The bits are built
//! here exactly, CRC-15 included, so the stuffing is the frame's own.

use crate::Frame;

/// Bits after the CRC: delimiter, ACK slot and delimiter, 7 EOF, 3 IFS.
const UNSTUFFED_TAIL: u32 = 13;
const CRC15_POLYNOMIAL: u16 = 0x4599;

/// The bits the transmitter sends, stuffing included, intermission
/// included (the bus is not free before it ends).
pub fn frame_bits(frame: &Frame) -> u32 {
    let mut bits = BitString::default();
    bits.push(false, 1); // SOF
    let len = u64::from(frame.len.min(8));
    let remote = frame.is_remote();
    if frame.is_extended() {
        bits.push_value(u64::from(frame.id >> 18), 11);
        bits.push(true, 1); // SRR
        bits.push(true, 1); // IDE
        bits.push_value(u64::from(frame.id & 0x3FFFF), 18);
        bits.push(remote, 1);
        bits.push(false, 2); // r1, r0
    } else {
        bits.push_value(u64::from(frame.id & 0x7FF), 11);
        bits.push(remote, 1);
        bits.push(false, 2); // IDE, r0
    }
    bits.push_value(len, 4);
    if !remote {
        for &byte in frame.data() {
            bits.push_value(u64::from(byte), 8);
        }
    }
    let crc = bits.crc15();
    bits.push_value(u64::from(crc), 15);
    bits.stuffed_len() + UNSTUFFED_TAIL
}

/// The most bits a frame of `len` bytes can take: a stuff bit after the
/// first five bits and then every four.
pub(crate) fn worst_case_bits(len: u8, extended: bool) -> u32 {
    let stuffable = (if extended { 54 } else { 34 }) + 8 * u32::from(len.min(8));
    stuffable + (stuffable - 1) / 4 + UNSTUFFED_TAIL
}

/// The fewest: no stuffing.
pub(crate) fn unstuffed_bits(len: u8, extended: bool) -> u32 {
    (if extended { 67 } else { 47 }) + 8 * u32::from(len.min(8))
}

pub fn bus_time_ns(bits: u32, bitrate: u32) -> u64 {
    u64::from(bits) * 1_000_000_000 / u64::from(bitrate.max(1))
}

/// The frame's bits as the transmitter sends them, counted as they come
/// (nothing stored, nothing allocated): CRC-15 over the unstuffed bits,
/// and a stuff bit after five equal bits, counting toward the next run.
#[derive(Default)]
struct BitString {
    sent: u32,
    run: u32,
    last: Option<bool>,
    crc: u16,
}

impl BitString {
    fn push(&mut self, bit: bool, count: usize) {
        for _ in 0..count {
            self.push_bit(bit);
        }
    }

    fn push_value(&mut self, value: u64, width: u32) {
        for i in (0..width).rev() {
            self.push_bit((value >> i) & 1 == 1);
        }
    }

    fn push_bit(&mut self, bit: bool) {
        let feedback = bit ^ ((self.crc >> 14) & 1 == 1);
        self.crc = (self.crc << 1) & 0x7FFF;
        if feedback {
            self.crc ^= CRC15_POLYNOMIAL;
        }
        self.sent += 1;
        if Some(bit) == self.last {
            self.run += 1;
        } else {
            self.run = 1;
            self.last = Some(bit);
        }
        if self.run == 5 {
            self.sent += 1;
            self.last = Some(!bit);
            self.run = 1;
        }
    }

    fn crc15(&self) -> u16 {
        self.crc
    }

    fn stuffed_len(&self) -> u32 {
        self.sent
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The stuffed bits themselves, to check the count against.
    fn stuff(bits: &[bool]) -> Vec<bool> {
        let mut out = Vec::with_capacity(bits.len() + bits.len() / 4);
        let mut run = 0;
        let mut last = None;
        for &bit in bits {
            out.push(bit);
            if Some(bit) == last {
                run += 1;
            } else {
                run = 1;
                last = Some(bit);
            }
            if run == 5 {
                out.push(!bit);
                last = Some(!bit);
                run = 1;
            }
        }
        out
    }

    fn destuff(bits: &[bool]) -> Vec<bool> {
        let mut out = Vec::new();
        let mut run = 0;
        let mut last = None;
        let mut skip = false;
        for &bit in bits {
            if skip {
                skip = false;
                last = Some(bit);
                run = 1;
                continue;
            }
            out.push(bit);
            if Some(bit) == last {
                run += 1;
            } else {
                run = 1;
                last = Some(bit);
            }
            if run == 5 {
                skip = true;
            }
        }
        out
    }

    #[test]
    fn crc15_of_a_known_sequence() {
        // CAN's CRC-15 of the ASCII "123456789" is 0x059E (the catalog of
        // parametrised CRCs, CRC-15/CAN).
        let mut bits = BitString::default();
        for byte in b"123456789" {
            bits.push_value(u64::from(*byte), 8);
        }
        assert_eq!(bits.crc15(), 0x059E);
    }

    #[test]
    fn a_frame_of_zeros_is_stuffed_every_five_bits() {
        // ID 0, no data: SOF, 11 ID, RTR, IDE, r0, DLC = 19 dominant bits,
        // then the CRC of nineteen zeros, which is zero: 34 zeros in all.
        // Each stuff bit (recessive) starts a new run, so a stuff bit
        // follows every five zeros: six of them.
        let frame = Frame::new(0, &[]).expect("frame");
        assert_eq!(frame_bits(&frame), 34 + 6 + 13);
        // The worst case is a stuff bit that joins the next run, every
        // four bits after the first five.
        assert_eq!(worst_case_bits(0, false), 34 + 8 + 13);
    }

    #[test]
    fn the_notes_period_fits_a_millisecond_at_one_megabit() {
        // SYNC, encoder (4 bytes), two transducers (2), the valve's set
        // point RPDO (4) and its TPDO (4).
        let frames = [
            Frame::new(0x080, &[]),
            Frame::new(0x1A0, &[0x12, 0x34, 0x00, 0x00]),
            Frame::new(0x1B0, &[0xD2, 0x04]),
            Frame::new(0x1B1, &[0x10, 0x02]),
            Frame::new(0x210, &[0, 0, 0x00, 0x20]),
            Frame::new(0x190, &[0x0F, 0, 0x00, 0x20]),
        ];
        let bits: u32 = frames.iter().map(|f| frame_bits(f.as_ref().expect("frame"))).sum();
        let plain: u32 = [0u8, 4, 2, 2, 4, 4].iter().map(|&n| unstuffed_bits(n, false)).sum();
        assert_eq!(plain, 410);
        assert!(bits >= plain && bits <= plain * 6 / 5, "{bits}");
        assert!(bus_time_ns(bits, 1_000_000) < 500_000);
        assert!(bus_time_ns(bits, 500_000) < 1_000_000);
        assert!(
            bus_time_ns(bits, 250_000) > 1_000_000,
            "too much for 1 kHz at 250 kbit/s"
        );
    }

    proptest! {
        #[test]
        fn stuffing_breaks_every_run_and_is_undone(raw in proptest::collection::vec(any::<bool>(), 0..200)) {
            let stuffed = stuff(&raw);
            prop_assert_eq!(destuff(&stuffed), raw.clone());
            let mut counted = BitString::default();
            raw.iter().for_each(|&bit| counted.push_bit(bit));
            prop_assert_eq!(counted.stuffed_len() as usize, stuffed.len());
            let longest = stuffed.chunk_by(|a, b| a == b).map(<[bool]>::len).max().unwrap_or(0);
            prop_assert!(longest <= 5);
        }

        #[test]
        fn every_frame_lies_between_no_stuffing_and_the_worst_case(
            id in 0u32..0x800, data in proptest::collection::vec(any::<u8>(), 0..=8), extended in any::<bool>()
        ) {
            let frame = if extended {
                Frame::extended(id * 0x3FFFF, &data)
            } else {
                Frame::new(id as u16, &data)
            };
            let frame = frame.map_err(|e| TestCaseError::fail(e.to_string()))?;
            let bits = frame_bits(&frame);
            prop_assert!(bits >= unstuffed_bits(frame.len, extended));
            prop_assert!(bits <= worst_case_bits(frame.len, extended));
        }
    }
}
