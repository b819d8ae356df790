//! CiA 301, the CANopen communication profile: the predefined connection
//! set's COB-IDs, network management, SYNC, emergencies, heartbeats,
//! expedited SDO transfers and PDOs with their mapping. Every multi-byte
//! value is little-endian.

use crate::{CanError, Frame};

/// A CANopen node ID, 1 to 127.
pub type NodeId = u8;

/// The predefined connection set.
pub mod cob_id {
    use super::NodeId;

    pub const NMT: u16 = 0x000;
    pub const SYNC: u16 = 0x080;
    const EMCY: u16 = 0x080;
    const TPDO: [u16; 4] = [0x180, 0x280, 0x380, 0x480];
    const RPDO: [u16; 4] = [0x200, 0x300, 0x400, 0x500];
    const SDO_RESPONSE: u16 = 0x580;
    const SDO_REQUEST: u16 = 0x600;
    const HEARTBEAT: u16 = 0x700;

    pub fn emcy(node: NodeId) -> u16 {
        EMCY + u16::from(node)
    }
    /// TPDO `n` (1 to 4): sent by the node.
    pub(crate) fn tpdo(n: u8, node: NodeId) -> u16 {
        TPDO[usize::from(n.clamp(1, 4) - 1)] + u16::from(node)
    }
    /// RPDO `n` (1 to 4): received by the node.
    pub(crate) fn rpdo(n: u8, node: NodeId) -> u16 {
        RPDO[usize::from(n.clamp(1, 4) - 1)] + u16::from(node)
    }
    /// Client → server (the node receives).
    pub(crate) fn sdo_request(node: NodeId) -> u16 {
        SDO_REQUEST + u16::from(node)
    }
    /// Server → client (the node answers).
    pub fn sdo_response(node: NodeId) -> u16 {
        SDO_RESPONSE + u16::from(node)
    }
    pub fn heartbeat(node: NodeId) -> u16 {
        HEARTBEAT + u16::from(node)
    }

    /// What a standard identifier means in the predefined connection set.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Function {
        Nmt,
        Sync,
        Emcy(NodeId),
        Tpdo(u8, NodeId),
        Rpdo(u8, NodeId),
        SdoResponse(NodeId),
        SdoRequest(NodeId),
        Heartbeat(NodeId),
        /// Outside the predefined set (a PDO remapped to another ID, a
        /// foreign protocol).
        Other,
    }

    pub fn function(id: u16) -> Function {
        let node = (id & 0x7F) as NodeId;
        if id == NMT {
            return Function::Nmt;
        }
        if id == SYNC {
            return Function::Sync;
        }
        if node == 0 {
            return Function::Other;
        }
        match id & 0x780 {
            0x080 => Function::Emcy(node),
            0x180 => Function::Tpdo(1, node),
            0x280 => Function::Tpdo(2, node),
            0x380 => Function::Tpdo(3, node),
            0x480 => Function::Tpdo(4, node),
            0x200 => Function::Rpdo(1, node),
            0x300 => Function::Rpdo(2, node),
            0x400 => Function::Rpdo(3, node),
            0x500 => Function::Rpdo(4, node),
            0x580 => Function::SdoResponse(node),
            0x600 => Function::SdoRequest(node),
            0x700 => Function::Heartbeat(node),
            _ => Function::Other,
        }
    }
}

/// NMT commands (COB-ID 0x000, `[command, node]`, node 0 = all nodes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmtCommand {
    Start = 0x01,
    Stop = 0x02,
    EnterPreOperational = 0x80,
    ResetNode = 0x81,
    ResetCommunication = 0x82,
}

pub fn nmt(command: NmtCommand, node: u8) -> Frame {
    frame(cob_id::NMT, &[command as u8, node & 0x7F])
}

/// The command and its node (0 = all).
pub(crate) fn decode_nmt(frame: &Frame) -> Result<(NmtCommand, u8), CanError> {
    if frame.id != u32::from(cob_id::NMT) || frame.is_extended() {
        return Err(CanError::NotA {
            cob_id: frame.id,
            what: "NMT",
        });
    }
    let data = frame.expect_len(2, "NMT")?;
    let command = match data[0] {
        0x01 => NmtCommand::Start,
        0x02 => NmtCommand::Stop,
        0x80 => NmtCommand::EnterPreOperational,
        0x81 => NmtCommand::ResetNode,
        0x82 => NmtCommand::ResetCommunication,
        other => return Err(malformed(frame, "NMT", format!("unknown command {other:#04x}"))),
    };
    Ok((command, data[1]))
}

/// A node's NMT state as its heartbeat reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmtState {
    BootUp = 0x00,
    Stopped = 0x04,
    Operational = 0x05,
    PreOperational = 0x7F,
}

impl NmtState {
    pub fn name(self) -> &'static str {
        match self {
            Self::BootUp => "boot-up",
            Self::Stopped => "stopped",
            Self::Operational => "operational",
            Self::PreOperational => "pre-operational",
        }
    }
}

pub fn heartbeat(node: NodeId, state: NmtState) -> Frame {
    frame(cob_id::heartbeat(node), &[state as u8])
}

/// The node and the state its heartbeat reports.
pub fn decode_heartbeat(frame: &Frame) -> Result<(NodeId, NmtState), CanError> {
    let node = match cob_id::function(standard_id(frame)) {
        cob_id::Function::Heartbeat(node) if !frame.is_remote() => node,
        _ => {
            return Err(CanError::NotA {
                cob_id: frame.id,
                what: "heartbeat",
            })
        }
    };
    let data = frame.expect_len(1, "heartbeat")?;
    // Bit 7 is node guarding's toggle bit; a heartbeat sends it as 0.
    let state = match data[0] & 0x7F {
        0x00 => NmtState::BootUp,
        0x04 => NmtState::Stopped,
        0x05 => NmtState::Operational,
        0x7F => NmtState::PreOperational,
        other => {
            return Err(malformed(
                frame,
                "heartbeat",
                format!("node {node}: unknown state {other:#04x}"),
            ))
        }
    };
    Ok((node, state))
}

/// SYNC on `cob_id` (0x080 unless configured), with the optional counter
/// (1 to 240) of CiA 301's synchronous counter overflow value.
pub fn sync(cob_id: u16, counter: Option<u8>) -> Frame {
    match counter {
        Some(c) => frame(cob_id, &[c]),
        None => frame(cob_id, &[]),
    }
}

/// Whether `frame` is the SYNC on `cob_id`: a data frame of at most one byte.
pub fn is_sync(frame: &Frame, cob_id: u16) -> bool {
    frame.id == u32::from(cob_id) && !frame.is_extended() && !frame.is_error() && !frame.is_remote() && frame.len <= 1
}

/// An emergency message (COB-ID 0x080 + node).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Emergency {
    /// 0x0000 = error reset (the node is free of errors again).
    pub code: u16,
    /// Object 0x1001.
    pub register: u8,
    pub vendor: [u8; 5],
}

/// Emergency codes this stack's devices send (CiA 301 and the valve's).
pub mod emcy_code {
    pub(crate) const NO_ERROR: u16 = 0x0000;
    pub(crate) const CAN_OVERRUN: u16 = 0x8110;
    pub(crate) const CAN_ERROR_PASSIVE: u16 = 0x8120;
    pub(crate) const HEARTBEAT_LOST: u16 = 0x8130;
    pub(crate) const BUS_OFF_RECOVERED: u16 = 0x8140;
    pub(crate) const PDO_LENGTH: u16 = 0x8210;
    pub(crate) const RPDO_TIMEOUT: u16 = 0x8250;
    /// Danfoss PVED-CC: "RPDO not received within timeout".
    pub const VALVE_RPDO_TIMEOUT: u16 = 0x81FF;
}

impl Emergency {
    pub fn new(code: u16, register: u8) -> Self {
        Self {
            code,
            register,
            vendor: [0; 5],
        }
    }

    pub fn to_frame(&self, node: NodeId) -> Frame {
        let mut data = [0u8; 8];
        data[..2].copy_from_slice(&self.code.to_le_bytes());
        data[2] = self.register;
        data[3..].copy_from_slice(&self.vendor);
        frame(cob_id::emcy(node), &data)
    }

    /// The node and its emergency.
    pub fn decode(frame: &Frame) -> Result<(NodeId, Self), CanError> {
        let node = match cob_id::function(standard_id(frame)) {
            cob_id::Function::Emcy(node) => node,
            _ => {
                return Err(CanError::NotA {
                    cob_id: frame.id,
                    what: "EMCY",
                })
            }
        };
        let data = frame.expect_len(8, "EMCY")?;
        let mut vendor = [0u8; 5];
        vendor.copy_from_slice(&data[3..8]);
        Ok((
            node,
            Self {
                code: u16::from_le_bytes([data[0], data[1]]),
                register: data[2],
                vendor,
            },
        ))
    }

    /// What the code means, by CiA 301's classes and the codes above.
    pub fn describe(&self) -> &'static str {
        match self.code {
            emcy_code::NO_ERROR => "error reset or no error",
            emcy_code::CAN_OVERRUN => "CAN overrun (objects lost)",
            emcy_code::CAN_ERROR_PASSIVE => "CAN in error passive mode",
            emcy_code::HEARTBEAT_LOST => "life guard or heartbeat error",
            emcy_code::BUS_OFF_RECOVERED => "recovered from bus off",
            emcy_code::PDO_LENGTH => "PDO not processed due to length error",
            emcy_code::RPDO_TIMEOUT => "RPDO timeout",
            emcy_code::VALVE_RPDO_TIMEOUT => "RPDO not received within timeout",
            code => match code & 0xF000 {
                0x1000 => "generic error",
                0x2000 => "current",
                0x3000 => "voltage",
                0x4000 => "temperature",
                0x5000 => "device hardware",
                0x6000 => "device software",
                0x7000 => "additional modules",
                0x8000 => "monitoring (communication)",
                0x9000 => "external error",
                0xF000 if code & 0xFF00 == 0xFF00 => "device specific",
                0xF000 => "additional functions",
                _ => "unknown error class",
            },
        }
    }
}

/// An SDO client's request (COB-ID 0x600 + node). Only expedited
/// transfers: every object this stack reads or writes fits in 4 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoRequest {
    /// Write 1 to 4 bytes.
    Download {
        index: u16,
        sub: u8,
        value: [u8; 4],
        len: u8,
    },
    /// Read.
    Upload { index: u16, sub: u8 },
}

/// An SDO server's answer (COB-ID 0x580 + node).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoResponse {
    Downloaded {
        index: u16,
        sub: u8,
    },
    Uploaded {
        index: u16,
        sub: u8,
        value: [u8; 4],
        len: u8,
    },
    Aborted {
        index: u16,
        sub: u8,
        code: u32,
    },
}

impl SdoRequest {
    /// Writes `bytes` (1 to 4, little-endian) to `index:sub`.
    pub fn download(index: u16, sub: u8, bytes: &[u8]) -> Result<Self, CanError> {
        if bytes.is_empty() || bytes.len() > 4 {
            return Err(CanError::Malformed {
                cob_id: 0,
                what: "SDO download",
                reason: format!(
                    "{index:#06x}:{sub}: {} bytes, an expedited transfer carries 1 to 4",
                    bytes.len()
                ),
            });
        }
        let mut value = [0u8; 4];
        value[..bytes.len()].copy_from_slice(bytes);
        Ok(Self::Download {
            index,
            sub,
            value,
            len: bytes.len() as u8,
        })
    }

    pub fn to_frame(&self, node: NodeId) -> Frame {
        let (command, index, sub, value) = match *self {
            Self::Download { index, sub, value, len } => (0x23 | ((4 - len.clamp(1, 4)) << 2), index, sub, value),
            Self::Upload { index, sub } => (0x40, index, sub, [0; 4]),
        };
        sdo_frame(cob_id::sdo_request(node), command, index, sub, value)
    }

    pub fn decode(frame: &Frame) -> Result<(NodeId, Self), CanError> {
        let node = match cob_id::function(standard_id(frame)) {
            cob_id::Function::SdoRequest(node) => node,
            _ => {
                return Err(CanError::NotA {
                    cob_id: frame.id,
                    what: "SDO request",
                })
            }
        };
        let (command, index, sub, value) = sdo_fields(frame, "SDO request")?;
        let request = match command {
            0x40 => Self::Upload { index, sub },
            c if c & 0xE3 == 0x23 => Self::Download {
                index,
                sub,
                value,
                len: 4 - ((c >> 2) & 3),
            },
            0x22 => Self::Download {
                index,
                sub,
                value,
                len: 4,
            },
            c => {
                return Err(malformed(
                    frame,
                    "SDO request",
                    format!("{index:#06x}:{sub}: command {c:#04x} is not an expedited transfer"),
                ))
            }
        };
        Ok((node, request))
    }
}

impl SdoResponse {
    pub fn to_frame(&self, node: NodeId) -> Frame {
        let (command, index, sub, value) = match *self {
            Self::Downloaded { index, sub } => (0x60, index, sub, [0; 4]),
            Self::Uploaded { index, sub, value, len } => (0x43 | ((4 - len.clamp(1, 4)) << 2), index, sub, value),
            Self::Aborted { index, sub, code } => (0x80, index, sub, code.to_le_bytes()),
        };
        sdo_frame(cob_id::sdo_response(node), command, index, sub, value)
    }

    pub fn decode(frame: &Frame) -> Result<(NodeId, Self), CanError> {
        let node = match cob_id::function(standard_id(frame)) {
            cob_id::Function::SdoResponse(node) => node,
            _ => {
                return Err(CanError::NotA {
                    cob_id: frame.id,
                    what: "SDO response",
                })
            }
        };
        let (command, index, sub, value) = sdo_fields(frame, "SDO response")?;
        let response = match command {
            0x60 => Self::Downloaded { index, sub },
            0x80 => Self::Aborted {
                index,
                sub,
                code: u32::from_le_bytes(value),
            },
            c if c & 0xE3 == 0x43 => Self::Uploaded {
                index,
                sub,
                value,
                len: 4 - ((c >> 2) & 3),
            },
            0x42 => Self::Uploaded { index, sub, value, len: 4 },
            c => {
                return Err(malformed(
                    frame,
                    "SDO response",
                    format!("{index:#06x}:{sub}: command {c:#04x} is not an expedited answer (segmented transfers are not supported)"),
                ))
            }
        };
        Ok((node, response))
    }
}

/// CiA 301's SDO abort codes, in words.
pub(crate) fn abort_description(code: u32) -> &'static str {
    match code {
        0x0503_0000 => "toggle bit not alternated",
        0x0504_0000 => "SDO protocol timed out",
        0x0504_0001 => "client/server command specifier not valid or unknown",
        0x0504_0005 => "out of memory",
        0x0601_0000 => "unsupported access to an object",
        0x0601_0001 => "attempt to read a write-only object",
        0x0601_0002 => "attempt to write a read-only object",
        0x0602_0000 => "object does not exist in the object dictionary",
        0x0604_0041 => "object cannot be mapped to the PDO",
        0x0604_0042 => "the number and length of the objects to be mapped would exceed the PDO length",
        0x0604_0043 => "general parameter incompatibility",
        0x0604_0047 => "general internal incompatibility in the device",
        0x0606_0000 => "access failed due to a hardware error",
        0x0607_0010 => "data type does not match, length of service parameter does not match",
        0x0607_0012 => "data type does not match, length of service parameter too high",
        0x0607_0013 => "data type does not match, length of service parameter too low",
        0x0609_0011 => "sub-index does not exist",
        0x0609_0030 => "invalid value for parameter",
        0x0609_0031 => "value of parameter written too high",
        0x0609_0032 => "value of parameter written too low",
        0x0609_0036 => "maximum value is less than minimum value",
        0x0800_0000 => "general error",
        0x0800_0020 => "data cannot be transferred or stored to the application",
        0x0800_0021 => "data cannot be transferred or stored because of local control",
        0x0800_0022 => "data cannot be transferred or stored because of the present device state",
        0x0800_0023 => "object dictionary dynamic generation fails or no object dictionary is present",
        0x0800_0024 => "no data available",
        _ => "unknown abort code",
    }
}

/// One object mapped into a PDO (the 32-bit value of objects
/// 0x1600.. and 0x1A00..: index, sub-index, length in bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MapEntry {
    pub index: u16,
    pub sub: u8,
    pub bits: u8,
}

impl MapEntry {
    pub const fn new(index: u16, sub: u8, bits: u8) -> Self {
        Self { index, sub, bits }
    }

    pub(crate) const fn from_u32(mapping: u32) -> Self {
        Self {
            index: (mapping >> 16) as u16,
            sub: (mapping >> 8) as u8,
            bits: mapping as u8,
        }
    }

    pub(crate) const fn to_u32(self) -> u32 {
        ((self.index as u32) << 16) | ((self.sub as u32) << 8) | self.bits as u32
    }
}

/// A PDO's mapping: up to eight byte-aligned objects, 64 bits in all.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PdoMapping {
    entries: [MapEntry; 8],
    count: u8,
}

impl PdoMapping {
    pub fn new(entries: &[MapEntry]) -> Result<Self, CanError> {
        if entries.len() > 8 {
            return Err(CanError::Mapping {
                reason: format!("{} objects, a PDO maps at most 8", entries.len()),
            });
        }
        let bits: u32 = entries.iter().map(|e| u32::from(e.bits)).sum();
        if bits > 64 {
            return Err(CanError::Mapping {
                reason: format!("{bits} bits, a PDO holds at most 64"),
            });
        }
        if let Some(e) = entries.iter().find(|e| e.bits == 0 || !e.bits.is_multiple_of(8)) {
            return Err(CanError::Mapping {
                reason: format!(
                    "{:#06x}:{} is {} bits; only whole bytes are supported",
                    e.index, e.sub, e.bits
                ),
            });
        }
        let mut all = [MapEntry::default(); 8];
        all[..entries.len()].copy_from_slice(entries);
        Ok(Self {
            entries: all,
            count: entries.len() as u8,
        })
    }

    pub fn entries(&self) -> &[MapEntry] {
        &self.entries[..usize::from(self.count)]
    }

    /// The PDO's data length.
    pub fn len(&self) -> usize {
        self.entries().iter().map(|e| usize::from(e.bits / 8)).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Where `index:sub` sits: byte offset and bits.
    pub fn locate(&self, index: u16, sub: u8) -> Option<(usize, u8)> {
        let mut offset = 0;
        for e in self.entries() {
            if e.index == index && e.sub == sub {
                return Some((offset, e.bits));
            }
            offset += usize::from(e.bits / 8);
        }
        None
    }

    /// A PDO frame carrying `values`, one raw (two's complement) value per
    /// entry, each truncated to its entry's width.
    pub(crate) fn pack(&self, cob_id: u16, values: &[u64]) -> Result<Frame, CanError> {
        if values.len() != self.entries().len() {
            return Err(CanError::Mapping {
                reason: format!("{} values for {} mapped objects", values.len(), self.count),
            });
        }
        let mut data = [0u8; 8];
        let mut offset = 0;
        for (e, value) in self.entries().iter().zip(values) {
            let n = usize::from(e.bits / 8);
            data[offset..offset + n].copy_from_slice(&value.to_le_bytes()[..n]);
            offset += n;
        }
        Frame::new(cob_id, &data[..offset])
    }

    /// The raw value of each entry; a frame of any other length than the
    /// mapping's is refused (CiA 301: "PDO not processed due to length
    /// error").
    pub fn unpack(&self, frame: &Frame, what: &'static str) -> Result<[u64; 8], CanError> {
        let data = frame.expect_len(self.len(), what)?;
        let mut values = [0u64; 8];
        let mut offset = 0;
        for (e, value) in self.entries().iter().zip(values.iter_mut()) {
            let n = usize::from(e.bits / 8);
            let mut bytes = [0u8; 8];
            bytes[..n].copy_from_slice(&data[offset..offset + n]);
            *value = u64::from_le_bytes(bytes);
            offset += n;
        }
        Ok(values)
    }
}

/// A raw value of `bits` width read as two's complement.
pub fn signed(raw: u64, bits: u8) -> i64 {
    let shift = 64 - u32::from(bits.clamp(1, 64));
    ((raw << shift) as i64) >> shift
}

fn frame(id: u16, data: &[u8]) -> Frame {
    // Every caller passes at most 8 bytes and an 11-bit ID.
    Frame::with_flags(u32::from(id & 0x7FF), 0, &data[..data.len().min(8)]).unwrap_or_default()
}

fn standard_id(frame: &Frame) -> u16 {
    if frame.is_extended() || frame.is_error() {
        // No CANopen function has an extended ID.
        0x7FF
    } else {
        (frame.id & 0x7FF) as u16
    }
}

fn malformed(frame: &Frame, what: &'static str, reason: String) -> CanError {
    CanError::Malformed {
        cob_id: frame.id,
        what,
        reason,
    }
}

fn sdo_frame(id: u16, command: u8, index: u16, sub: u8, value: [u8; 4]) -> Frame {
    let i = index.to_le_bytes();
    frame(id, &[command, i[0], i[1], sub, value[0], value[1], value[2], value[3]])
}

fn sdo_fields(frame: &Frame, what: &'static str) -> Result<(u8, u16, u8, [u8; 4]), CanError> {
    let d = frame.expect_len(8, what)?;
    Ok((d[0], u16::from_le_bytes([d[1], d[2]]), d[3], [d[4], d[5], d[6], d[7]]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::candump;

    /// A frame as can-utils writes it, `ID#DATA`.
    fn text(frame: &Frame) -> String {
        candump::frame_text(frame)
    }

    #[test]
    fn nmt_sync_heartbeat_and_emcy_frames_are_the_standards() {
        assert_eq!(text(&nmt(NmtCommand::Start, 0)), "000#0100");
        assert_eq!(text(&nmt(NmtCommand::Start, 0x20)), "000#0120");
        assert_eq!(text(&nmt(NmtCommand::EnterPreOperational, 5)), "000#8005");
        assert_eq!(text(&nmt(NmtCommand::ResetCommunication, 0)), "000#8200");
        assert_eq!(decode_nmt(&nmt(NmtCommand::Stop, 7)), Ok((NmtCommand::Stop, 7)));
        assert_eq!(text(&sync(cob_id::SYNC, None)), "080#");
        assert_eq!(text(&sync(cob_id::SYNC, Some(3))), "080#03");
        assert!(is_sync(&sync(0x081, None), 0x081));
        assert!(!is_sync(&sync(0x081, None), cob_id::SYNC));
        assert!(!is_sync(&Frame::remote(0x080, 0).expect("frame"), cob_id::SYNC));
        assert_eq!(text(&heartbeat(0x20, NmtState::Operational)), "720#05");
        assert_eq!(text(&heartbeat(0x20, NmtState::PreOperational)), "720#7F");
        assert_eq!(text(&heartbeat(1, NmtState::BootUp)), "701#00");
        for state in [
            NmtState::BootUp,
            NmtState::Stopped,
            NmtState::Operational,
            NmtState::PreOperational,
        ] {
            assert_eq!(decode_heartbeat(&heartbeat(0x31, state)), Ok((0x31, state)));
        }
        let emcy = Emergency::new(emcy_code::RPDO_TIMEOUT, 0x11);
        assert_eq!(text(&emcy.to_frame(0x20)), "0A0#5082110000000000");
        assert_eq!(Emergency::decode(&emcy.to_frame(0x20)), Ok((0x20, emcy)));
        assert_eq!(emcy.describe(), "RPDO timeout");
        assert_eq!(Emergency::new(0x4210, 0x09).describe(), "temperature");
    }

    #[test]
    fn the_predefined_connection_set_is_classified() {
        use cob_id::{function, Function};
        assert_eq!(function(0x000), Function::Nmt);
        assert_eq!(function(0x080), Function::Sync);
        assert_eq!(function(0x0A0), Function::Emcy(0x20));
        assert_eq!(function(0x1A0), Function::Tpdo(1, 0x20));
        assert_eq!(function(0x4A0), Function::Tpdo(4, 0x20));
        assert_eq!(function(0x220), Function::Rpdo(1, 0x20));
        assert_eq!(function(0x520), Function::Rpdo(4, 0x20));
        assert_eq!(function(0x5A0), Function::SdoResponse(0x20));
        assert_eq!(function(0x620), Function::SdoRequest(0x20));
        assert_eq!(function(0x720), Function::Heartbeat(0x20));
        assert_eq!(function(0x180), Function::Other);
        assert_eq!(function(0x7E5), Function::Other);
        assert_eq!(cob_id::tpdo(3, 0x10), 0x390);
        assert_eq!(cob_id::rpdo(2, 0x10), 0x310);
    }

    #[test]
    fn expedited_sdo_frames_are_the_standards() {
        // Device mode 0x6042:0 = 1 (one byte) to node 0x20.
        let write = SdoRequest::download(0x6042, 0, &[1]).expect("request");
        assert_eq!(text(&write.to_frame(0x20)), "620#2F42600001000000");
        // Heartbeat producer time 0x1017:0 = 100 ms (two bytes).
        let hb = SdoRequest::download(0x1017, 0, &100u16.to_le_bytes()).expect("request");
        assert_eq!(text(&hb.to_frame(0x20)), "620#2B17100064000000");
        // Four bytes: 0x23.
        let four = SdoRequest::download(0x6003, 0, &0x1234_5678u32.to_le_bytes()).expect("request");
        assert_eq!(text(&four.to_frame(0x30)), "630#2303600078563412");
        let read = SdoRequest::Upload { index: 0x6041, sub: 0 };
        assert_eq!(text(&read.to_frame(0x20)), "620#4041600000000000");
        // Status word 0x000F, two bytes: 0x4B.
        let answer = SdoResponse::Uploaded {
            index: 0x6041,
            sub: 0,
            value: [0x0F, 0, 0, 0],
            len: 2,
        };
        assert_eq!(text(&answer.to_frame(0x20)), "5A0#4B4160000F000000");
        let ack = SdoResponse::Downloaded { index: 0x6042, sub: 0 };
        assert_eq!(text(&ack.to_frame(0x20)), "5A0#6042600000000000");
        let abort = SdoResponse::Aborted {
            index: 0x6300,
            sub: 3,
            code: 0x0609_0011,
        };
        assert_eq!(text(&abort.to_frame(0x20)), "5A0#8000630311000906");
        for request in [write, hb, four, read] {
            assert_eq!(SdoRequest::decode(&request.to_frame(9)), Ok((9, request)));
        }
        for response in [answer, ack, abort] {
            assert_eq!(SdoResponse::decode(&response.to_frame(9)), Ok((9, response)));
        }
        assert_eq!(abort_description(0x0609_0011), "sub-index does not exist");
        assert!(SdoRequest::download(0x6042, 0, &[0; 5]).is_err());
    }

    #[test]
    fn segmented_and_malformed_sdo_frames_are_named() {
        let segmented = Frame::new(0x5A0, &[0x41, 0x08, 0x10, 0, 20, 0, 0, 0]).expect("frame");
        let error = SdoResponse::decode(&segmented).expect_err("segmented");
        assert!(error.to_string().contains("0x5a0"), "{error}");
        assert!(error.to_string().contains("0x1008:0"), "{error}");
        let short = Frame::new(0x5A0, &[0x60, 0x42, 0x60]).expect("frame");
        assert!(matches!(
            SdoResponse::decode(&short),
            Err(CanError::WrongLength {
                expected: 8,
                got: 3,
                ..
            })
        ));
        assert!(matches!(
            SdoResponse::decode(&heartbeat(5, NmtState::Operational)),
            Err(CanError::NotA { .. })
        ));
        let bad_state = Frame::new(0x705, &[0x03]).expect("frame");
        assert!(decode_heartbeat(&bad_state)
            .expect_err("state")
            .to_string()
            .contains("node 5"));
    }

    #[test]
    fn pdos_pack_and_unpack_their_mapping() {
        // The valve's TPDO1: status word, then the spool's actual value.
        let mapping =
            PdoMapping::new(&[MapEntry::from_u32(0x6041_0010), MapEntry::from_u32(0x6301_0110)]).expect("mapping");
        assert_eq!(mapping.len(), 4);
        assert_eq!(mapping.entries()[1], MapEntry::new(0x6301, 1, 16));
        assert_eq!(MapEntry::new(0x6004, 0, 32).to_u32(), 0x6004_0020);
        assert_eq!(mapping.locate(0x6301, 1), Some((2, 16)));
        let actual = -8192i16;
        let frame = mapping.pack(0x1A0, &[0x000F, actual as u16 as u64]).expect("pack");
        assert_eq!(text(&frame), "1A0#0F0000E0");
        let raw = mapping.unpack(&frame, "TPDO1").expect("unpack");
        assert_eq!(raw[0], 0x000F);
        assert_eq!(signed(raw[1], 16), -8192);
        let short = Frame::new(0x1A0, &[0x0F, 0, 0]).expect("frame");
        assert_eq!(
            mapping.unpack(&short, "valve TPDO1").expect_err("short").to_string(),
            "COB-ID 0x1a0 (valve TPDO1): 3 data bytes, expected 4"
        );
        assert!(PdoMapping::new(&[MapEntry::new(0x6004, 0, 32); 3]).is_err());
        assert!(PdoMapping::new(&[MapEntry::new(0x6004, 0, 12)]).is_err());
    }

    #[test]
    fn signed_values_of_any_width() {
        assert_eq!(signed(0xFFFF, 16), -1);
        assert_eq!(signed(0x7FFF, 16), 32767);
        assert_eq!(signed(0xFFFF_FFFF, 32), -1);
        assert_eq!(signed(0x80, 8), -128);
    }
}
