//! The CDR encoding of a sample whose memory is not its CDR: one with text.
//! A name is NUL-padded bytes in the sample (fixed size, nothing to
//! allocate on the loop) but a ROS 2 `string` in the recording, so that
//! Foxglove and PlotJuggler show words, not arrays of numbers. The kind's
//! `ros2msg` says `string NAME` and its `text` gives each such field's
//! size in memory; every other field is copied as it is, aligned as CDR
//! aligns it. Runs in the recorder and the reader, never on the loop.

use std::collections::HashMap;

use crate::schema::SampleKind;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    #[error("`{schema}`: {reason}")]
    Schema { schema: &'static str, reason: String },
    #[error("`{schema}`: the message is cut short at byte {at} (of {len})")]
    Short {
        schema: &'static str,
        at: usize,
        len: usize,
    },
    #[error("`{schema}`: field `{field}` holds {got} bytes of text, at most {max} fit")]
    TextTooLong {
        schema: &'static str,
        field: String,
        got: usize,
        max: usize,
    },
}

/// One step of the walk: a run of primitives, or a text field.
#[derive(Debug, Clone, PartialEq)]
enum Op {
    Plain {
        memory_at: usize,
        size: usize,
        count: usize,
    },
    Text {
        memory_at: usize,
        len: usize,
        field: String,
    },
}

/// The kind's fields in order, each with where it sits in memory.
fn ops(kind: &SampleKind) -> Result<Vec<Op>, CdrError> {
    let error = |reason: String| CdrError::Schema {
        schema: kind.schema_name,
        reason,
    };
    let mut sections = kind
        .ros2msg
        .split("================================================================================\n");
    let main = sections.next().unwrap_or_default();
    let mut nested = HashMap::new();
    for section in sections {
        let (header, body) = section
            .split_once('\n')
            .ok_or_else(|| error("a nested message without a header".into()))?;
        let name = header.trim().rsplit('/').next().unwrap_or_default();
        nested.insert(name.to_owned(), body.to_owned());
    }
    let mut ops = Vec::new();
    let (end, align) = walk(kind, main, &nested, 0, &mut ops).map_err(error)?;
    if end.next_multiple_of(align) != kind.size {
        return Err(error(format!(
            "the fields end at byte {end}, the type has {}",
            kind.size
        )));
    }
    Ok(ops)
}

/// Lays `body` out from `offset` (repr(C): each field aligned to itself, a
/// nested struct to its widest field, padded at its end); returns where it
/// ends and its alignment.
fn walk(
    kind: &SampleKind,
    body: &str,
    nested: &HashMap<String, String>,
    mut offset: usize,
    ops: &mut Vec<Op>,
) -> Result<(usize, usize), String> {
    let mut align = 1;
    for line in body
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
    {
        let (ty, name) = line
            .split_once(' ')
            .ok_or_else(|| format!("`{line}` is not TYPE NAME"))?;
        let name = name.trim();
        let (base, count) = match ty.split_once('[') {
            Some((b, n)) => (
                b,
                n.trim_end_matches(']')
                    .parse::<usize>()
                    .map_err(|_| format!("`{ty}` is not a fixed-size array"))?,
            ),
            None => (ty, 1),
        };
        let size = match base {
            "uint8" | "int8" | "bool" => Some(1),
            "uint16" | "int16" => Some(2),
            "uint32" | "int32" | "float32" => Some(4),
            "uint64" | "int64" | "float64" => Some(8),
            _ => None,
        };
        if let Some(size) = size {
            offset = offset.next_multiple_of(size);
            align = align.max(size);
            ops.push(Op::Plain {
                memory_at: offset,
                size,
                count,
            });
            offset += size * count;
        } else if base == "string" {
            let len = kind
                .text
                .iter()
                .find(|(field, _)| *field == name)
                .map(|(_, len)| *len)
                .ok_or_else(|| format!("string `{name}` has no size in memory (SampleKind::text)"))?;
            for _ in 0..count {
                ops.push(Op::Text {
                    memory_at: offset,
                    len,
                    field: name.to_owned(),
                });
                offset += len;
            }
        } else {
            let inner = nested
                .get(base.rsplit('/').next().unwrap_or(base))
                .ok_or_else(|| format!("`{base}` is not defined in the schema"))?;
            // Its alignment first, from a dry walk.
            let (_, inner_align) = walk(kind, inner, nested, 0, &mut Vec::new())?;
            align = align.max(inner_align);
            for _ in 0..count {
                offset = offset.next_multiple_of(inner_align);
                let (end, _) = walk(kind, inner, nested, offset, ops)?;
                offset = end.next_multiple_of(inner_align);
            }
        }
    }
    Ok((offset, align))
}

/// Appends the CDR encoding (without the encapsulation header) of the
/// sample whose memory is `memory`.
pub fn to_cdr(kind: &SampleKind, memory: &[u8], out: &mut Vec<u8>) -> Result<(), CdrError> {
    let start = out.len();
    let short = |at| CdrError::Short {
        schema: kind.schema_name,
        at,
        len: memory.len(),
    };
    for op in ops(kind)? {
        match op {
            Op::Plain { memory_at, size, count } => {
                while !(out.len() - start).is_multiple_of(size) {
                    out.push(0);
                }
                let bytes = memory
                    .get(memory_at..memory_at + size * count)
                    .ok_or(short(memory_at))?;
                out.extend_from_slice(bytes);
            }
            Op::Text { memory_at, len, .. } => {
                let field = memory.get(memory_at..memory_at + len).ok_or(short(memory_at))?;
                let text = &field[..field.iter().position(|&b| b == 0).unwrap_or(len)];
                while !(out.len() - start).is_multiple_of(4) {
                    out.push(0);
                }
                out.extend_from_slice(&(text.len() as u32 + 1).to_le_bytes());
                out.extend_from_slice(text);
                out.push(0);
            }
        }
    }
    Ok(())
}

/// The sample's memory from its CDR encoding (without the encapsulation
/// header); a string longer than its field is an error naming the field.
pub fn from_cdr(kind: &SampleKind, cdr: &[u8], memory: &mut Vec<u8>) -> Result<(), CdrError> {
    memory.clear();
    memory.resize(kind.size, 0);
    let short = |at| CdrError::Short {
        schema: kind.schema_name,
        at,
        len: cdr.len(),
    };
    let mut at = 0usize;
    for op in ops(kind)? {
        match op {
            Op::Plain { memory_at, size, count } => {
                at = at.next_multiple_of(size);
                let bytes = cdr.get(at..at + size * count).ok_or(short(at))?;
                memory[memory_at..memory_at + size * count].copy_from_slice(bytes);
                at += size * count;
            }
            Op::Text { memory_at, len, field } => {
                at = at.next_multiple_of(4);
                let n = cdr
                    .get(at..at + 4)
                    .and_then(|b| b.try_into().ok())
                    .map(u32::from_le_bytes)
                    .ok_or(short(at))? as usize;
                at += 4;
                let bytes = cdr.get(at..at + n).ok_or(short(at))?;
                let text = bytes.strip_suffix(&[0]).unwrap_or(bytes);
                if text.len() > len {
                    return Err(CdrError::TextTooLong {
                        schema: kind.schema_name,
                        field,
                        got: text.len(),
                        max: len,
                    });
                }
                memory[memory_at..memory_at + text.len()].copy_from_slice(text);
                at += n;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{fixed_name, ProcessStatus, Recordable, SupervisorEvent, SupervisorStatus, KINDS};

    #[test]
    fn every_kind_walks_to_its_size() {
        for kind in KINDS {
            let ops = ops(kind).unwrap_or_else(|e| panic!("{e}"));
            let end = ops
                .iter()
                .map(|op| match op {
                    Op::Plain { memory_at, size, count } => memory_at + size * count,
                    Op::Text { memory_at, len, .. } => memory_at + len,
                })
                .max()
                .unwrap_or(0);
            assert_eq!(end.next_multiple_of(8), kind.size, "{}", kind.schema_name);
        }
    }

    #[test]
    fn text_becomes_strings_and_comes_back() {
        let mut status = SupervisorStatus {
            seq: 3,
            stage_time_ns: 99,
            process_count: 2,
            plant_is_simulation: 1,
            ..SupervisorStatus::default()
        };
        status.processes[0] = ProcessStatus {
            name: fixed_name("position"),
            variant: fixed_name("mfc"),
            pid: 42,
            restarts: 1,
            healthy: 1,
            page_faults_after_start: 7,
            memory_locked: 1,
        };
        status.processes[1].name = fixed_name("a-sixteen-bytes!");
        let mut cdr = Vec::new();
        to_cdr(&SupervisorStatus::KIND, bytemuck::bytes_of(&status), &mut cdr).expect("encode");
        // seq, stamp, then the first name as a CDR string.
        assert_eq!(&cdr[16..20], &9u32.to_le_bytes());
        assert_eq!(&cdr[20..29], b"position\0");
        let mut memory = Vec::new();
        from_cdr(&SupervisorStatus::KIND, &cdr, &mut memory).expect("decode");
        assert_eq!(bytemuck::pod_read_unaligned::<SupervisorStatus>(&memory), status);
        assert!(from_cdr(&SupervisorStatus::KIND, &cdr[..cdr.len() - 1], &mut memory).is_err());

        let event = SupervisorEvent {
            seq: 1,
            kind: 2,
            process: fixed_name("torque"),
            from: fixed_name("pid"),
            to: fixed_name("hinf"),
            ..SupervisorEvent::default()
        };
        let mut cdr = Vec::new();
        to_cdr(&SupervisorEvent::KIND, bytemuck::bytes_of(&event), &mut cdr).expect("encode");
        from_cdr(&SupervisorEvent::KIND, &cdr, &mut memory).expect("decode");
        assert_eq!(bytemuck::pod_read_unaligned::<SupervisorEvent>(&memory), event);
    }

    #[test]
    fn a_string_too_long_for_its_field_is_named() {
        let status = SupervisorStatus::default();
        let mut cdr = Vec::new();
        to_cdr(&SupervisorStatus::KIND, bytemuck::bytes_of(&status), &mut cdr).expect("encode");
        // Replace the first (empty) name with 20 letters.
        let mut long = cdr[..16].to_vec();
        long.extend_from_slice(&21u32.to_le_bytes());
        long.extend_from_slice(b"abcdefghijklmnopqrst\0");
        long.extend_from_slice(&cdr[21..]);
        let e = from_cdr(&SupervisorStatus::KIND, &long, &mut Vec::new()).expect_err("too long");
        assert!(e.to_string().contains("`name`"), "{e}");
    }
}
