use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use hydractl_samples::{Recordable, SampleKind, CDR_HEADER, KINDS};
use mcap::read::{ChunkFlattener, Options};
use mcap::records::Record;

use crate::RecordingError;

/// One message as read back: the sample's bytes, without the CDR header.
#[derive(Debug, Clone, Copy)]
pub struct RecordedMessage<'a> {
    pub topic: &'a str,
    pub kind: &'static SampleKind,
    pub log_time_ns: u64,
    pub payload: &'a [u8],
    /// The message's index on its channel, from 0.
    pub index: u64,
    /// The MCAP header's sequence: the low 32 bits of the sample's.
    pub mcap_sequence: u32,
}

/// The sample in a message, if the message holds a `T`.
pub fn decode<T: Recordable>(message: &RecordedMessage) -> Option<T> {
    (message.kind.type_name == T::KIND.type_name && message.payload.len() == T::KIND.size)
        .then(|| bytemuck::pod_read_unaligned(message.payload))
}

/// What reading a file found besides its messages.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadOutcome {
    pub messages: u64,
    /// Set when the file stops early (a killed recorder): why, in words.
    /// Everything up to the last whole chunk was still read.
    pub truncated: Option<String>,
    /// The `hydractl` metadata record: config, software version.
    pub metadata: BTreeMap<String, String>,
}

struct ChannelEntry {
    topic: String,
    kind: &'static SampleKind,
    count: u64,
}

/// Reads every message of a recording in file order and hands it to
/// `visit`. A file cut short is read up to its last whole chunk and
/// reported in [`ReadOutcome::truncated`]; a message that is not what its
/// schema says is an error naming the channel and the message.
pub fn read_messages(
    path: &Path,
    mut visit: impl FnMut(&RecordedMessage) -> Result<(), RecordingError>,
) -> Result<ReadOutcome, RecordingError> {
    let bytes = std::fs::read(path).map_err(|source| RecordingError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(RecordingError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::InvalidData, "not an MCAP file (no magic bytes)"),
        });
    }
    let records = ChunkFlattener::new_with_options(&bytes, Options::IgnoreEndMagic.into()).map_err(|source| {
        RecordingError::Mcap {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let mut schemas: HashMap<u16, String> = HashMap::new();
    let mut channels: HashMap<u16, ChannelEntry> = HashMap::new();
    let mut outcome = ReadOutcome::default();
    let mut footer_seen = false;
    let mut memory = Vec::new();
    for record in records {
        let record = match record {
            Ok(r) => r,
            Err(e) => {
                outcome.truncated = Some(format!("the file is cut short ({e}); read up to the last whole chunk"));
                break;
            }
        };
        match record {
            Record::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            Record::Channel(channel) => {
                let schema = schemas.get(&channel.schema_id).cloned().unwrap_or_default();
                let kind = KINDS
                    .into_iter()
                    .chain([&crate::CAN_FRAME_KIND])
                    .find(|k| k.schema_name == schema && channel.message_encoding == crate::MESSAGE_ENCODING)
                    .ok_or_else(|| RecordingError::UnknownSchema {
                        path: path.to_path_buf(),
                        topic: channel.topic.clone(),
                        schema: format!("{schema} ({})", channel.message_encoding),
                    })?;
                channels.insert(
                    channel.id,
                    ChannelEntry {
                        topic: channel.topic,
                        kind,
                        count: 0,
                    },
                );
            }
            Record::Message { header, data } => {
                let Some(channel) = channels.get_mut(&header.channel_id) else {
                    return Err(RecordingError::MissingChannel {
                        path: path.to_path_buf(),
                        topic: format!("id {}", header.channel_id),
                        have: channels
                            .values()
                            .map(|c| c.topic.clone())
                            .collect::<Vec<_>>()
                            .join(", "),
                    });
                };
                let index = channel.count;
                channel.count += 1;
                let Some(payload) = data.strip_prefix(&CDR_HEADER[..]) else {
                    return Err(RecordingError::BadHeader {
                        path: path.to_path_buf(),
                        topic: channel.topic.clone(),
                        index,
                    });
                };
                // A sample with text: back to its memory.
                let payload = if channel.kind.text.is_empty() {
                    payload
                } else {
                    hydractl_samples::cdr::from_cdr(channel.kind, payload, &mut memory).map_err(|source| {
                        RecordingError::Cdr {
                            path: path.to_path_buf(),
                            topic: format!("{} message {index}", channel.topic),
                            source,
                        }
                    })?;
                    &memory[..]
                };
                if crate::is_can_frame(channel.kind) {
                    crate::decode_frame(payload).map_err(|reason| RecordingError::BadFrame {
                        path: path.to_path_buf(),
                        topic: channel.topic.clone(),
                        index,
                        reason,
                    })?;
                } else if payload.len() != channel.kind.size {
                    return Err(RecordingError::BadSize {
                        path: path.to_path_buf(),
                        topic: channel.topic.clone(),
                        schema: channel.kind.schema_name.to_owned(),
                        index,
                        got: payload.len(),
                        want: channel.kind.size,
                    });
                }
                outcome.messages += 1;
                visit(&RecordedMessage {
                    topic: &channel.topic,
                    kind: channel.kind,
                    log_time_ns: header.log_time,
                    payload,
                    index,
                    mcap_sequence: header.sequence,
                })?;
            }
            Record::Metadata(m) if m.name == "hydractl" => outcome.metadata.extend(m.metadata),
            Record::Footer(_) => footer_seen = true,
            _ => {}
        }
    }
    if outcome.truncated.is_none() && !footer_seen {
        outcome.truncated = Some("the file ends without its summary (the recorder did not finish it)".into());
    }
    Ok(outcome)
}
