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
    #[error("node {node:#04x}, object {index:#06x}:{sub} ({what}) = {value}: {reason}")]
    Setting {
        node: u8,
        index: u16,
        sub: u8,
        what: &'static str,
        value: String,
        reason: String,
    },
}

/// SocketCAN's error classes (`linux/can/error.h`): the ID bits of an
/// error frame.
pub mod error_class {
    /// `CAN_ERR_CRTL`: the controller's state; `data[1]` says which.
    pub const CONTROLLER: u32 = 0x0004;
    /// `CAN_ERR_PROT`: a protocol violation (a corrupted transmission).
    pub const PROTOCOL: u32 = 0x0008;
    /// `CAN_ERR_ACK`: nobody acknowledged a transmission.
    pub const NO_ACK: u32 = 0x0020;
    /// `CAN_ERR_BUSOFF`: the controller left the bus.
    pub const BUS_OFF: u32 = 0x0040;
    /// `CAN_ERR_RESTARTED`: the controller is back after bus-off.
    pub const RESTARTED: u32 = 0x0100;
    /// `data[1]` of [`CONTROLLER`]: error-passive on receive, on transmit.
    pub const CONTROLLER_RX_PASSIVE: u8 = 0x10;
    pub const CONTROLLER_TX_PASSIVE: u8 = 0x20;
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
    pub(crate) fn extended(id: u32, data: &[u8]) -> Result<Self, CanError> {
        if id > Self::MAX_EXTENDED_ID {
            return Err(CanError::IdOutOfRange { id, bits: 29 });
        }
        Self::with_flags(id, Self::EXTENDED, data)
    }

    /// A remote request for `len` bytes.
    pub(crate) fn remote(id: u16, len: u8) -> Result<Self, CanError> {
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

    /// What an error frame says of the bus, when it is more than a
    /// corrupted transmission the controller sends again (which CAN does
    /// by design): the controller off the bus, error-passive, or no other
    /// node acknowledging. The code is CiA 301's EMCY code for it.
    pub fn bus_fault(&self) -> Option<(u16, &'static str)> {
        if !self.is_error() {
            return None;
        }
        let passive = error_class::CONTROLLER_RX_PASSIVE | error_class::CONTROLLER_TX_PASSIVE;
        if self.id & error_class::BUS_OFF != 0 {
            Some((0x8140, "the CAN controller went bus-off"))
        } else if self.id & error_class::CONTROLLER != 0 && self.data[1] & passive != 0 {
            Some((0x8120, "the CAN controller is error-passive"))
        } else if self.id & error_class::NO_ACK != 0 {
            Some((
                0x8100,
                "no node acknowledged a transmission (a cut bus, or nobody on it)",
            ))
        } else {
            None
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
    pub(crate) fn expect_len(&self, expected: usize, what: &'static str) -> Result<&[u8], CanError> {
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

    #[test]
    fn error_frames_that_are_bus_faults_are_told_from_a_retried_transmission() {
        assert_eq!(Frame::error(error_class::PROTOCOL, [0; 8]).bus_fault(), None);
        assert_eq!(
            Frame::error(error_class::BUS_OFF, [0; 8]).bus_fault().map(|f| f.0),
            Some(0x8140)
        );
        let passive = [0, error_class::CONTROLLER_TX_PASSIVE, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            Frame::error(error_class::CONTROLLER, passive).bus_fault().map(|f| f.0),
            Some(0x8120)
        );
        assert_eq!(
            Frame::error(error_class::CONTROLLER, [0; 8]).bus_fault(),
            None,
            "a warning only"
        );
        assert_eq!(
            Frame::error(error_class::NO_ACK, [0; 8]).bus_fault().map(|f| f.0),
            Some(0x8100)
        );
        assert_eq!(Frame::new(0x40, &[]).expect("data frame").bus_fault(), None);
    }
}
