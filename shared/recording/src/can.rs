//! CAN frames in a recording: one channel per bus, each frame the ROS 2
//! message `can_msgs/msg/Frame` (ros2_socketcan's), so that Foxglove and
//! PlotJuggler show the bus by reflection. Unlike a sample, whose memory is
//! its CDR encoding, a frame carries a string (the header's `frame_id`,
//! the interface's name): it is encoded field by field here.

use hydractl_can::Frame;
use hydractl_samples::{CanFrameSample, SampleKind};

/// The CAN frame channel's schema; `size` 0: its messages vary in length.
pub const CAN_FRAME_KIND: SampleKind = SampleKind {
    type_name: "hydractl::CanFrameSample",
    schema_name: "can_msgs/msg/Frame",
    ros2msg: "std_msgs/Header header
uint32 id
bool is_rtr
bool is_extended
bool is_error
uint8 dlc
uint8[8] data
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
",
    size: 0,
    time_offset: 8,
    text: &[],
};

/// Whether a channel's kind is the CAN frame's.
pub fn is_can_frame(kind: &SampleKind) -> bool {
    kind.schema_name == CAN_FRAME_KIND.schema_name
}

/// A frame read back from a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedFrame {
    /// When its last bit crossed the bus (the monotonic clock), ns.
    pub time_ns: u64,
    /// The interface it was on.
    pub interface: String,
    pub frame: Frame,
}

/// Appends the CDR encoding (without the encapsulation header) of `sample`
/// as `can_msgs/msg/Frame` on `interface` to `out`.
pub fn encode_frame(sample: &CanFrameSample, interface: &str, out: &mut Vec<u8>) {
    let start = out.len();
    let sec = (sample.time_ns / 1_000_000_000).min(i32::MAX as u64) as i32;
    let nanosec = (sample.time_ns % 1_000_000_000) as u32;
    out.extend_from_slice(&sec.to_le_bytes());
    out.extend_from_slice(&nanosec.to_le_bytes());
    // A CDR string: its length with the terminating NUL, its bytes, the NUL.
    out.extend_from_slice(&(interface.len() as u32 + 1).to_le_bytes());
    out.extend_from_slice(interface.as_bytes());
    out.push(0);
    // `id` is 4-aligned from the start of the message.
    while !(out.len() - start).is_multiple_of(4) {
        out.push(0);
    }
    out.extend_from_slice(&sample.id.to_le_bytes());
    out.push(u8::from(sample.flags & Frame::REMOTE != 0));
    out.push(u8::from(sample.flags & Frame::EXTENDED != 0));
    out.push(u8::from(sample.flags & Frame::ERROR != 0));
    out.push(sample.len.min(8));
    out.extend_from_slice(&sample.data);
}

/// Reads a `can_msgs/msg/Frame` CDR payload back; an error says what is
/// wrong with it.
pub fn decode_frame(payload: &[u8]) -> Result<RecordedFrame, String> {
    let u32_at = |at: usize| -> Result<u32, String> {
        payload
            .get(at..at + 4)
            .and_then(|b| b.try_into().ok())
            .map(u32::from_le_bytes)
            .ok_or_else(|| format!("{} bytes, cut short at byte {at}", payload.len()))
    };
    let sec = u32_at(0)? as i32;
    let nanosec = u32_at(4)?;
    let len = u32_at(8)? as usize;
    let name_end = 12 + len;
    let name = payload
        .get(12..name_end)
        .ok_or_else(|| format!("frame_id of {len} bytes runs past the message's {}", payload.len()))?;
    let interface = String::from_utf8_lossy(name.strip_suffix(&[0]).unwrap_or(name)).into_owned();
    let at = name_end.next_multiple_of(4);
    let id = u32_at(at)?;
    let rest = payload
        .get(at + 4..at + 16)
        .ok_or_else(|| format!("{} bytes, cut short after the id", payload.len()))?;
    let mut flags = 0;
    if rest[0] != 0 {
        flags |= Frame::REMOTE;
    }
    if rest[1] != 0 {
        flags |= Frame::EXTENDED;
    }
    if rest[2] != 0 {
        flags |= Frame::ERROR;
    }
    let mut data = [0u8; 8];
    data.copy_from_slice(&rest[4..12]);
    Ok(RecordedFrame {
        time_ns: u64::try_from(sec).unwrap_or(0) * 1_000_000_000 + u64::from(nanosec),
        interface,
        frame: Frame {
            id,
            flags,
            len: rest[3].min(8),
            reserved: [0; 2],
            data,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_round_trips_with_its_interface_and_flags() {
        for interface in ["vcan0", "can1", "x"] {
            let sample = CanFrameSample {
                seq: 7,
                time_ns: 12_345_678_901,
                id: 0x18FE_F100,
                flags: Frame::EXTENDED,
                len: 3,
                data: [1, 2, 3, 0, 0, 0, 0, 0],
                ..CanFrameSample::default()
            };
            let mut out = Vec::new();
            encode_frame(&sample, interface, &mut out);
            let back = decode_frame(&out).expect("decodes");
            assert_eq!(back.interface, interface);
            assert_eq!(back.time_ns, sample.time_ns);
            assert_eq!(back.frame.id, sample.id);
            assert_eq!(back.frame.flags, Frame::EXTENDED);
            assert_eq!(back.frame.len, 3);
            assert_eq!(back.frame.data, sample.data);
            assert!(decode_frame(&out[..out.len() - 1]).is_err(), "cut short");
        }
    }

    #[test]
    fn the_encoding_is_the_cdr_layout_ros2_gives_can_msgs_frame() {
        // sec 1, nanosec 2, "vcan0": 4 + 4 + 4 + 6 bytes, 2 of padding,
        // then id, the three flags, dlc and 8 data bytes.
        let sample = CanFrameSample {
            time_ns: 1_000_000_002,
            id: 0x181,
            len: 2,
            data: [0xAA, 0xBB, 0, 0, 0, 0, 0, 0],
            ..CanFrameSample::default()
        };
        let mut out = Vec::new();
        encode_frame(&sample, "vcan0", &mut out);
        let expected: Vec<u8> = [
            &[1, 0, 0, 0, 2, 0, 0, 0, 6, 0, 0, 0][..],
            b"vcan0\0",
            &[0, 0],
            &[0x81, 0x01, 0, 0, 0, 0, 0, 2],
            &[0xAA, 0xBB, 0, 0, 0, 0, 0, 0],
        ]
        .concat();
        assert_eq!(out, expected);
    }
}
