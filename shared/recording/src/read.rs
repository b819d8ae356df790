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
    /// Set when the file was not read whole, why in words: it stops early
    /// (a killed recorder; read up to its last whole chunk), or a chunk is
    /// corrupt (skipped, named by its time; the chunks after it read).
    pub truncated: Option<String>,
    /// The `hydractl` metadata record: config, software version.
    pub metadata: BTreeMap<String, String>,
}

struct ChannelEntry {
    topic: String,
    kind: &'static SampleKind,
    count: u64,
}

/// A stretch of a recording, in seconds from its first message: what a
/// fleet's window of a long recording reads.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    pub from_s: f64,
    pub to_s: f64,
}

impl Window {
    /// The window's log times, for a recording whose first message came at `first_ns`.
    fn log_times(self, first_ns: u64) -> std::ops::Range<u64> {
        let at = |s: f64| first_ns.saturating_add((s.max(0.0) * 1e9) as u64);
        at(self.from_s)..at(self.to_s)
    }
}

/// Reads every message of a recording in file order and hands it to
/// `visit`. A file cut short is read up to its last whole chunk and
/// reported in [`ReadOutcome::truncated`]; a message that is not what its
/// schema says is an error naming the channel and the message.
pub fn read_messages(
    path: &Path,
    visit: impl FnMut(&RecordedMessage) -> Result<(), RecordingError>,
) -> Result<ReadOutcome, RecordingError> {
    read_messages_in(path, None, visit)
}

/// [`read_messages`] of the messages inside `window` alone. A finished
/// recording is read through its summary's chunk index: only the chunks
/// the window overlaps are read from the disk. A file without a summary (a
/// killed recorder) is read from its start. A message's `index` counts
/// from the window's start.
pub fn read_messages_in(
    path: &Path,
    window: Option<Window>,
    mut visit: impl FnMut(&RecordedMessage) -> Result<(), RecordingError>,
) -> Result<ReadOutcome, RecordingError> {
    let io = |source| RecordingError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut decoder = Decoder::new(path);
    if let Some(window) = window {
        let file = std::fs::File::open(path).map_err(io)?;
        // Mapped, so that a window reads from the disk only the chunks it
        // needs. SAFETY: the map is read only, and no writer shrinks a
        // recording (a recorder still appending only adds bytes past the
        // length mapped).
        #[allow(unsafe_code)]
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(io)?;
        check_magic(&map, io)?;
        if let Ok(Some(summary)) = mcap::Summary::read(&map) {
            return decoder.read_indexed(&map, &summary, Some(window), visit);
        }
    }
    // The whole file in one read: faster than a map's page faults when
    // every byte is read anyway.
    let bytes = std::fs::read(path).map_err(io)?;
    check_magic(&bytes, io)?;
    // A finished recording is read chunk by chunk through its index, so
    // that a corrupt chunk loses only itself, not everything after it.
    if let Ok(Some(summary)) = mcap::Summary::read(&bytes) {
        if !summary.chunk_indexes.is_empty() {
            return decoder.read_indexed(&bytes, &summary, window, visit);
        }
    }
    let records = ChunkFlattener::new_with_options(&bytes, Options::IgnoreEndMagic.into()).map_err(|source| {
        RecordingError::Mcap {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let mut footer_seen = false;
    let mut wanted: Option<std::ops::Range<u64>> = None;
    for record in records {
        let record = match record {
            Ok(r) => r,
            Err(e) => {
                decoder.outcome.truncated =
                    Some(format!("the file is cut short ({e}); read up to the last whole chunk"));
                break;
            }
        };
        match record {
            Record::Schema { header, .. } => {
                decoder.schemas.insert(header.id, header.name);
            }
            Record::Channel(channel) => {
                let schema = decoder.schemas.get(&channel.schema_id).cloned().unwrap_or_default();
                decoder.add_channel(channel.id, channel.topic, &schema, &channel.message_encoding)?;
            }
            Record::Message { header, data } => {
                if let Some(window) = window {
                    let times = wanted.get_or_insert_with(|| window.log_times(header.log_time));
                    if !times.contains(&header.log_time) {
                        continue;
                    }
                }
                decoder.message(header.channel_id, header.log_time, header.sequence, &data, &mut visit)?;
            }
            Record::Metadata(m) if m.name == "hydractl" => decoder.outcome.metadata.extend(m.metadata),
            Record::Footer(_) => footer_seen = true,
            _ => {}
        }
    }
    if decoder.outcome.truncated.is_none() && !footer_seen {
        decoder.outcome.truncated = Some("the file ends without its summary (the recorder did not finish it)".into());
    }
    Ok(decoder.outcome)
}

/// A chunk that could not be decoded, named by its messages' times in
/// seconds from the recording's first.
fn corrupt_chunk(chunk: &mcap::records::ChunkIndex, first_ns: u64, error: &mcap::McapError) -> String {
    let s = |ns: u64| ns.saturating_sub(first_ns) as f64 * 1e-9;
    format!(
        "the chunk of {:.3}–{:.3} s (at byte {}) is corrupt ({error}): skipped",
        s(chunk.message_start_time),
        s(chunk.message_end_time),
        chunk.chunk_start_offset
    )
}

fn check_magic(bytes: &[u8], io: impl Fn(std::io::Error) -> RecordingError) -> Result<(), RecordingError> {
    if bytes.starts_with(mcap::MAGIC) {
        return Ok(());
    }
    Err(io(std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        "not an MCAP file (no magic bytes)",
    )))
}

/// The schemas and channels met so far, and each message checked against
/// its channel's schema on its way to the visitor.
struct Decoder<'p> {
    path: &'p Path,
    schemas: HashMap<u16, String>,
    channels: HashMap<u16, ChannelEntry>,
    outcome: ReadOutcome,
    memory: Vec<u8>,
}

impl<'p> Decoder<'p> {
    fn new(path: &'p Path) -> Self {
        Self {
            path,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            outcome: ReadOutcome::default(),
            memory: Vec::new(),
        }
    }

    fn add_channel(&mut self, id: u16, topic: String, schema: &str, encoding: &str) -> Result<(), RecordingError> {
        let kind = KINDS
            .into_iter()
            .chain([&crate::CAN_FRAME_KIND])
            .find(|k| k.schema_name == schema && encoding == crate::MESSAGE_ENCODING)
            .ok_or_else(|| RecordingError::UnknownSchema {
                path: self.path.to_path_buf(),
                topic: topic.clone(),
                schema: format!("{schema} ({encoding})"),
            })?;
        self.channels.insert(id, ChannelEntry { topic, kind, count: 0 });
        Ok(())
    }

    /// The messages of the chunks `window` overlaps (all without one), and
    /// the metadata, as the summary indexes them. A chunk that cannot be
    /// decoded is skipped and named in [`ReadOutcome::truncated`].
    fn read_indexed(
        mut self,
        bytes: &[u8],
        summary: &mcap::Summary,
        window: Option<Window>,
        mut visit: impl FnMut(&RecordedMessage) -> Result<(), RecordingError>,
    ) -> Result<ReadOutcome, RecordingError> {
        let mcap_error = |source| RecordingError::Mcap {
            path: self.path.to_path_buf(),
            source,
        };
        let mut ids: Vec<&u16> = summary.channels.keys().collect();
        ids.sort();
        for id in ids {
            let channel = &summary.channels[id];
            let schema = channel.schema.as_ref().map(|s| s.name.as_str()).unwrap_or_default();
            self.add_channel(*id, channel.topic.clone(), schema, &channel.message_encoding)?;
        }
        for index in summary.metadata_indexes.iter().filter(|m| m.name == "hydractl") {
            let metadata = mcap::read::metadata(bytes, index).map_err(mcap_error)?;
            self.outcome.metadata.extend(metadata.metadata);
        }
        let first_ns = summary
            .chunk_indexes
            .iter()
            .map(|c| c.message_start_time)
            .min()
            .unwrap_or(0);
        let times = window.map_or(0..u64::MAX, |w| w.log_times(first_ns));
        let mut chunks: Vec<_> = summary
            .chunk_indexes
            .iter()
            .filter(|c| c.message_end_time >= times.start && c.message_start_time < times.end)
            .collect();
        chunks.sort_by_key(|c| c.chunk_start_offset);
        let mut corrupt = Vec::new();
        for chunk in chunks {
            // The chunk's CRC is checked as its end is decoded, after the
            // garbage before it: so a first pass decodes it whole, and only
            // a chunk that passes is read.
            let whole = summary
                .stream_chunk(bytes, chunk)
                .and_then(|mut messages| messages.try_for_each(|m| m.map(drop)));
            if let Err(e) = whole {
                corrupt.push(corrupt_chunk(chunk, first_ns, &e));
                continue;
            }
            for message in summary.stream_chunk(bytes, chunk).map_err(mcap_error)? {
                let message = message.map_err(mcap_error)?;
                if times.contains(&message.log_time) {
                    self.message(
                        message.channel.id,
                        message.log_time,
                        message.sequence,
                        &message.data,
                        &mut visit,
                    )?;
                }
            }
        }
        if !corrupt.is_empty() {
            self.outcome.truncated = Some(format!("{}; the chunks around read", corrupt.join("; ")));
        }
        Ok(self.outcome)
    }

    /// One message: its channel's, checked against the schema, to `visit`.
    fn message(
        &mut self,
        channel_id: u16,
        log_time_ns: u64,
        mcap_sequence: u32,
        data: &[u8],
        visit: &mut impl FnMut(&RecordedMessage) -> Result<(), RecordingError>,
    ) -> Result<(), RecordingError> {
        let path = self.path;
        let Some(channel) = self.channels.get_mut(&channel_id) else {
            return Err(RecordingError::MissingChannel {
                path: path.to_path_buf(),
                topic: format!("id {channel_id}"),
                have: self
                    .channels
                    .values()
                    .map(|c| c.topic.clone())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        };
        let at = || {
            Box::new(crate::MessageAt {
                topic: channel.topic.clone(),
                index: channel.count,
                log_time_ns,
                sequence: mcap_sequence,
            })
        };
        let Some(payload) = data.strip_prefix(&CDR_HEADER[..]) else {
            return Err(RecordingError::BadHeader {
                path: path.to_path_buf(),
                at: at(),
            });
        };
        // A sample with text: back to its memory.
        let payload = if channel.kind.text.is_empty() {
            payload
        } else {
            hydractl_samples::cdr::from_cdr(channel.kind, payload, &mut self.memory).map_err(|source| {
                RecordingError::CdrAt {
                    path: path.to_path_buf(),
                    at: at(),
                    source,
                }
            })?;
            &self.memory[..]
        };
        if crate::is_can_frame(channel.kind) {
            crate::decode_frame(payload).map_err(|reason| RecordingError::BadFrame {
                path: path.to_path_buf(),
                at: at(),
                reason,
            })?;
        } else if payload.len() != channel.kind.size {
            return Err(RecordingError::BadSize {
                path: path.to_path_buf(),
                at: at(),
                schema: channel.kind.schema_name.to_owned(),
                got: payload.len(),
                want: channel.kind.size,
            });
        }
        let index = channel.count;
        channel.count += 1;
        self.outcome.messages += 1;
        visit(&RecordedMessage {
            topic: &channel.topic,
            kind: channel.kind,
            log_time_ns,
            payload,
            index,
            mcap_sequence,
        })
    }
}
