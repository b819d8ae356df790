//! can-utils' log format, as `candump -l` writes and `canplayer` reads it:
//! `(1436509052.249713) can0 181#2A366C2A`. Standard IDs have three hex
//! digits, extended eight; `ID#R` is a remote request (`ID#R3` for three
//! bytes); error frames carry the `CAN_ERR_FLAG` (0x20000000) in their ID.

use crate::Frame;

/// SocketCAN's error frame flag in a logged ID.
const CAN_ERR_FLAG: u32 = 0x2000_0000;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("candump line {line}: {reason}: {text:?}")]
pub struct CandumpError {
    pub line: usize,
    pub reason: String,
    pub text: String,
}

/// One logged frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoggedFrame {
    /// Since the Unix epoch.
    pub time_ns: u64,
    pub interface: String,
    pub frame: Frame,
}

/// `ID#DATA` as can-utils writes it.
pub(crate) fn frame_text(frame: &Frame) -> String {
    let id = if frame.is_error() {
        format!("{:08X}", frame.id | CAN_ERR_FLAG)
    } else if frame.is_extended() {
        format!("{:08X}", frame.id)
    } else {
        format!("{:03X}", frame.id)
    };
    if frame.is_remote() {
        return if frame.len == 0 {
            format!("{id}#R")
        } else {
            format!("{id}#R{}", frame.len)
        };
    }
    let mut text = id;
    text.push('#');
    for byte in frame.data() {
        text.push_str(&format!("{byte:02X}"));
    }
    text
}

/// A whole `candump -l` line, microseconds as can-utils writes them.
pub fn line(time_ns: u64, interface: &str, frame: &Frame) -> String {
    format!(
        "({}.{:06}) {interface} {}",
        time_ns / 1_000_000_000,
        time_ns % 1_000_000_000 / 1000,
        frame_text(frame)
    )
}

/// Reads one line; `number` (from 1) names it in an error. Lines that do
/// not start with `(` are comments to `canplayer`: `Ok(None)`.
pub(crate) fn parse_line(number: usize, text: &str) -> Result<Option<LoggedFrame>, CandumpError> {
    let trimmed = text.trim();
    if !trimmed.starts_with('(') {
        return Ok(None);
    }
    let fail = |reason: &str| CandumpError {
        line: number,
        reason: reason.to_string(),
        text: text.to_string(),
    };
    let close = trimmed.find(')').ok_or_else(|| fail("no `)` after the time stamp"))?;
    let time_ns = parse_time(&trimmed[1..close]).ok_or_else(|| fail("the time stamp is not SECONDS.FRACTION"))?;
    let mut fields = trimmed[close + 1..].split_whitespace();
    let interface = fields.next().ok_or_else(|| fail("no interface"))?;
    let frame_field = fields.next().ok_or_else(|| fail("no frame"))?;
    let frame = parse_frame(frame_field).map_err(|reason| fail(&reason))?;
    Ok(Some(LoggedFrame {
        time_ns,
        interface: interface.to_string(),
        frame,
    }))
}

/// Every frame of a log, or the first bad line.
pub fn parse(text: &str) -> Result<Vec<LoggedFrame>, CandumpError> {
    let mut frames = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if let Some(frame) = parse_line(i + 1, line)? {
            frames.push(frame);
        }
    }
    Ok(frames)
}

fn parse_time(text: &str) -> Option<u64> {
    let (seconds, fraction) = text.split_once('.')?;
    if fraction.is_empty() || fraction.len() > 9 || !fraction.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let seconds: u64 = seconds.parse().ok()?;
    let scale = 10u64.pow(9 - fraction.len() as u32);
    let fraction: u64 = fraction.parse().ok()?;
    seconds.checked_mul(1_000_000_000)?.checked_add(fraction * scale)
}

fn parse_frame(text: &str) -> Result<Frame, String> {
    let (id_text, data_text) = text.split_once('#').ok_or_else(|| format!("`{text}` is not ID#DATA"))?;
    if data_text.starts_with('#') {
        return Err("CAN FD frames (ID##…) are not supported".to_string());
    }
    let id = u32::from_str_radix(id_text, 16).map_err(|_| format!("`{id_text}` is not a hex CAN ID"))?;
    let remote_len = match data_text.strip_prefix('R') {
        Some("") => Some(0u8),
        Some(len) => Some(
            len.parse::<u8>()
                .ok()
                .filter(|n| *n <= 8)
                .ok_or_else(|| format!("`R{len}` is not a remote request length"))?,
        ),
        None => None,
    };
    let frame = match id_text.len() {
        3 => {
            if id > Frame::MAX_STANDARD_ID {
                return Err(format!("standard ID {id:#x} is above 0x7FF"));
            }
            let id = id as u16;
            match remote_len {
                Some(len) => Frame::remote(id, len).map_err(|e| e.to_string())?,
                None => Frame::new(id, &hex_bytes(data_text)?).map_err(|e| e.to_string())?,
            }
        }
        8 if id & CAN_ERR_FLAG != 0 => {
            let bytes = hex_bytes(data_text)?;
            let mut data = [0u8; 8];
            let n = bytes.len().min(8);
            data[..n].copy_from_slice(&bytes[..n]);
            Frame::error(id & !CAN_ERR_FLAG, data)
        }
        8 => match remote_len {
            Some(len) => {
                let mut frame = Frame::extended(id, &[]).map_err(|e| e.to_string())?;
                frame.flags |= Frame::REMOTE;
                frame.len = len;
                frame
            }
            None => Frame::extended(id, &hex_bytes(data_text)?).map_err(|e| e.to_string())?,
        },
        n => return Err(format!("a CAN ID has 3 or 8 hex digits, `{id_text}` has {n}")),
    };
    Ok(frame)
}

fn hex_bytes(text: &str) -> Result<Vec<u8>, String> {
    // can-utils accepts `.` between bytes.
    let digits: String = text.chars().filter(|&c| c != '.').collect();
    if !digits.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!("`{text}` is not hex data"));
    }
    if !digits.len().is_multiple_of(2) {
        return Err(format!("`{text}`: an odd number of hex digits"));
    }
    if digits.len() > 16 {
        return Err(format!("`{text}`: more than 8 data bytes"));
    }
    (0..digits.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&digits[i..i + 2], 16).map_err(|_| format!("`{text}` is not hex data")))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_can_utils_example_round_trips() {
        let logged = parse_line(1, "(1436509052.249713) can0 181#2A366C2A")
            .expect("line")
            .expect("frame");
        assert_eq!(logged.time_ns, 1_436_509_052_249_713_000);
        assert_eq!(logged.interface, "can0");
        assert_eq!(
            logged.frame,
            Frame::new(0x181, &[0x2A, 0x36, 0x6C, 0x2A]).expect("frame")
        );
        assert_eq!(
            line(logged.time_ns, "can0", &logged.frame),
            "(1436509052.249713) can0 181#2A366C2A"
        );
    }

    #[test]
    fn remote_extended_empty_and_error_frames() {
        for text in [
            "(0.000001) vcan0 123#R",
            "(0.000001) vcan0 123#R4",
            "(0.000001) vcan0 12345678#DEADBEEF",
            "(0.000001) vcan0 12345678#R",
            "(0.000001) vcan0 12345678#R2",
            "(0.000001) vcan0 080#",
            "(0.000001) vcan0 20000004#0004000000000000",
        ] {
            let logged = parse_line(1, text).expect("line").expect("frame");
            assert_eq!(line(logged.time_ns, &logged.interface, &logged.frame), text);
        }
        let error = parse_line(1, "(0.000001) vcan0 20000004#0004000000000000")
            .expect("line")
            .expect("frame");
        assert!(error.frame.is_error());
        assert_eq!(error.frame.id, 4);
    }

    #[test]
    fn nanosecond_stamps_and_comments() {
        let logged = parse_line(3, "(1.123456789) can1 7FF#01")
            .expect("line")
            .expect("frame");
        assert_eq!(logged.time_ns, 1_123_456_789);
        assert_eq!(parse_line(4, "# a comment").expect("comment"), None);
        assert_eq!(parse_line(5, "").expect("blank"), None);
    }

    #[test]
    fn bad_lines_are_named_by_number() {
        let text = "(1.000001) can0 181#2A36\n(1.000002) can0 181#2A3\n";
        let error = parse(text).expect_err("odd digits");
        assert_eq!(error.line, 2);
        assert!(
            error
                .to_string()
                .starts_with("candump line 2: `2A3`: an odd number of hex digits"),
            "{error}"
        );
        for bad in [
            "(1.x) can0 181#00",
            "(1.000001 can0 181#00",
            "(1.000001) can0",
            "(1.000001) can0 1812#00",
            "(1.000001) can0 800#00",
            "(1.000001) can0 181#000102030405060708",
            "(1.000001) can0 181##100",
            "(1.000001) can0 181#ZZ",
            "(1.000001) can0 181#a€",
            "(1.000001) can0 181#R9",
        ] {
            let error = parse_line(9, bad).expect_err(bad);
            assert_eq!(error.line, 9, "{bad}");
        }
    }
}
