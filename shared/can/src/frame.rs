/// One classic CAN frame (CAN 2.0A/B), plain data so that it can be sent
/// as it is over shared memory and recorded byte for byte.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct Frame {
    /// 11-bit identifier, or 29-bit with [`Frame::EXTENDED`]; for an error
    /// frame, SocketCAN's error class bits.
    pub id: u32,
    pub flags: u8,
    /// Data length, 0 to 8.
    pub len: u8,
    pub reserved: [u8; 2],
    pub data: [u8; 8],
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CanError {
    #[error("CAN ID {id:#x} does not fit {bits} bits")]
    IdOutOfRange { id: u32, bits: u32 },
    #[error("COB-ID {cob_id:#05x}: {len} data bytes, a classic CAN frame holds at most 8")]
    TooLong { cob_id: u32, len: usize },
    #[error("COB-ID {cob_id:#05x} ({what}): {got} data bytes, expected {expected}")]
    WrongLength {
        cob_id: u32,
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("COB-ID {cob_id:#05x} is not a {what} frame")]
    NotA { cob_id: u32, what: &'static str },
    #[error("COB-ID {cob_id:#05x} ({what}): {reason}")]
    Malformed {
        cob_id: u32,
        what: &'static str,
        reason: String,
    },
    #[error("node {node}: CANopen node IDs are 1 to 127")]
    BadNode { node: u8 },
    #[error("PDO mapping: {reason}")]
    Mapping { reason: String },
}

impl Frame {
    pub const EXTENDED: u8 = 1;
    pub const REMOTE: u8 = 2;
    pub const ERROR: u8 = 4;
    pub const MAX_STANDARD_ID: u32 = 0x7FF;
    pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

    /// A data frame with an 11-bit identifier.
    pub fn new(id: u16, data: &[u8]) -> Result<Self, CanError> {
        if u32::from(id) > Self::MAX_STANDARD_ID {
            return Err(CanError::IdOutOfRange {
                id: id.into(),
                bits: 11,
            });
        }
        Self::with_flags(u32::from(id), 0, data)
    }

    /// A data frame with a 29-bit identifier.
    pub fn extended(id: u32, data: &[u8]) -> Result<Self, CanError> {
        if id > Self::MAX_EXTENDED_ID {
            return Err(CanError::IdOutOfRange { id, bits: 29 });
        }
        Self::with_flags(id, Self::EXTENDED, data)
    }

    /// A remote request for `len` bytes.
    pub fn remote(id: u16, len: u8) -> Result<Self, CanError> {
        let mut frame = Self::new(id, &[])?;
        if len > 8 {
            return Err(CanError::TooLong {
                cob_id: id.into(),
                len: len.into(),
            });
        }
        frame.flags |= Self::REMOTE;
        frame.len = len;
        Ok(frame)
    }

    /// An error frame as SocketCAN reports it: `class` is the error class
    /// (`CAN_ERR_*` bits of the ID), `data` its details.
    pub fn error(class: u32, data: [u8; 8]) -> Self {
        Self {
            id: class & Self::MAX_EXTENDED_ID,
            flags: Self::ERROR,
            len: 8,
            reserved: [0; 2],
            data,
        }
    }

    pub(crate) fn with_flags(id: u32, flags: u8, data: &[u8]) -> Result<Self, CanError> {
        if data.len() > 8 {
            return Err(CanError::TooLong {
                cob_id: id,
                len: data.len(),
            });
        }
        let mut bytes = [0u8; 8];
        bytes[..data.len()].copy_from_slice(data);
        Ok(Self {
            id,
            flags,
            len: data.len() as u8,
            reserved: [0; 2],
            data: bytes,
        })
    }

    /// The data bytes actually sent.
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len.min(8))]
    }

    pub fn is_extended(&self) -> bool {
        self.flags & Self::EXTENDED != 0
    }

    pub fn is_remote(&self) -> bool {
        self.flags & Self::REMOTE != 0
    }

    pub fn is_error(&self) -> bool {
        self.flags & Self::ERROR != 0
    }

    /// Demands exactly `expected` data bytes, naming the frame otherwise.
    pub fn expect_len(&self, expected: usize, what: &'static str) -> Result<&[u8], CanError> {
        if usize::from(self.len) != expected {
            return Err(CanError::WrongLength {
                cob_id: self.id,
                what,
                expected,
                got: self.len.into(),
            });
        }
        Ok(self.data())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_hold_at_most_eight_bytes_and_eleven_bit_ids() {
        assert!(Frame::new(0x7FF, &[1; 8]).is_ok());
        assert_eq!(
            Frame::new(0x800, &[]),
            Err(CanError::IdOutOfRange { id: 0x800, bits: 11 })
        );
        assert_eq!(
            Frame::new(0x181, &[0; 9]),
            Err(CanError::TooLong { cob_id: 0x181, len: 9 })
        );
        let f = Frame::new(0x181, &[0x2A, 0x36]).expect("frame");
        assert_eq!(f.data(), &[0x2A, 0x36]);
        assert_eq!(
            f.expect_len(4, "TPDO1").expect_err("short").to_string(),
            "COB-ID 0x181 (TPDO1): 2 data bytes, expected 4"
        );
    }
}
