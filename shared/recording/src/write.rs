use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use hydractl_samples::{Recordable, SampleKind, CDR_HEADER};
use mcap::records::MessageHeader;

use crate::{RecordingError, MESSAGE_ENCODING, SCHEMA_ENCODING};

/// How a recording is written.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordOptions {
    /// Start a new file once the current one holds this many bytes.
    pub split_bytes: Option<u64>,
    /// Start a new file once the current one spans this many seconds.
    pub split_seconds: Option<f64>,
    /// Uncompressed bytes per chunk: a killed recorder loses at most the
    /// chunk being filled (and the recorder also closes one every second).
    pub chunk_bytes: u64,
    pub zstd_level: u32,
    /// Written as the metadata record `hydractl` at the start of each file:
    /// the config, the software version.
    pub metadata: BTreeMap<String, String>,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            split_bytes: None,
            split_seconds: None,
            chunk_bytes: 512 * 1024,
            zstd_level: 3,
            metadata: BTreeMap::new(),
        }
    }
}

impl RecordOptions {
    fn splits(&self) -> bool {
        self.split_bytes.is_some() || self.split_seconds.is_some()
    }
}

/// A channel added to a [`RecordingWriter`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelHandle(usize);

struct Channel {
    topic: String,
    kind: &'static SampleKind,
    /// The channel's id in the current file.
    id: u16,
}

/// Writes samples to one MCAP file, or to numbered parts when splitting.
pub struct RecordingWriter {
    base: PathBuf,
    options: RecordOptions,
    writer: mcap::Writer<CountingFile>,
    /// The current file's length, shared with its [`CountingFile`].
    file_len: Arc<AtomicU64>,
    path: PathBuf,
    files: Vec<PathBuf>,
    channels: Vec<Channel>,
    /// The log time of the current file's first message.
    file_start_ns: Option<u64>,
    message: Vec<u8>,
    /// A sample with text, encoded field by field.
    encoded: Vec<u8>,
    messages: u64,
    bytes_in_closed_files: u64,
}

impl RecordingWriter {
    /// Creates the recording at `path`; when splitting, its parts are
    /// `STEM_000.mcap`, `STEM_001.mcap`, … beside it.
    pub fn create(path: &Path, options: RecordOptions) -> Result<Self, RecordingError> {
        let first = part_path(path, &options, 0);
        let (writer, file_len) = open_part(&first, &options)?;
        Ok(Self {
            base: path.to_path_buf(),
            options,
            writer,
            file_len,
            path: first.clone(),
            files: vec![first],
            channels: Vec::new(),
            file_start_ns: None,
            message: Vec::with_capacity(4096),
            encoded: Vec::with_capacity(4096),
            messages: 0,
            bytes_in_closed_files: 0,
        })
    }

    /// Adds a channel for samples of `kind` on `topic` (the service name).
    pub fn add_channel(&mut self, topic: &str, kind: &'static SampleKind) -> Result<ChannelHandle, RecordingError> {
        let id = add_to_file(&mut self.writer, &self.path, topic, kind)?;
        self.channels.push(Channel {
            topic: topic.to_owned(),
            kind,
            id,
        });
        Ok(ChannelHandle(self.channels.len() - 1))
    }

    /// Writes one sample: its bytes as they are in memory (its text as
    /// strings, [`hydractl_samples::cdr`]).
    pub fn write_sample<T: Recordable>(&mut self, channel: ChannelHandle, sample: &T) -> Result<(), RecordingError> {
        self.write(channel, bytemuck::bytes_of(sample))
    }

    /// Writes one sample's bytes; its log time is the sample's own
    /// timestamp, its MCAP sequence the low 32 bits of its sequence number.
    pub fn write(&mut self, channel: ChannelHandle, payload: &[u8]) -> Result<(), RecordingError> {
        let Some(entry) = self.channels.get(channel.0) else {
            return Err(RecordingError::MissingChannel {
                path: self.path.clone(),
                topic: format!("#{}", channel.0),
                have: self.topics(),
            });
        };
        let kind = entry.kind;
        let (Some(sequence), Some(time_ns)) = (kind.sequence(payload), kind.timestamp_ns(payload)) else {
            return Err(RecordingError::WrongPayload {
                path: self.path.clone(),
                topic: entry.topic.clone(),
                schema: kind.schema_name.to_owned(),
                got: payload.len(),
                want: kind.size,
            });
        };
        if kind.text.is_empty() {
            return self.write_encoded(channel, sequence, time_ns, payload);
        }
        let mut encoded = std::mem::take(&mut self.encoded);
        encoded.clear();
        let written = hydractl_samples::cdr::to_cdr(kind, payload, &mut encoded)
            .map_err(|source| RecordingError::Cdr {
                path: self.path.clone(),
                topic: self.channels[channel.0].topic.clone(),
                source,
            })
            .and_then(|()| self.write_encoded(channel, sequence, time_ns, &encoded));
        self.encoded = encoded;
        written
    }

    /// Writes one message already encoded as its channel's CDR (without
    /// the encapsulation header): a CAN frame ([`crate::encode_frame`]).
    pub fn write_encoded(
        &mut self,
        channel: ChannelHandle,
        sequence: u64,
        time_ns: u64,
        payload: &[u8],
    ) -> Result<(), RecordingError> {
        if channel.0 >= self.channels.len() {
            return Err(RecordingError::MissingChannel {
                path: self.path.clone(),
                topic: format!("#{}", channel.0),
                have: self.topics(),
            });
        }
        if self.split_due(time_ns) {
            self.next_part()?;
        }
        self.file_start_ns.get_or_insert(time_ns);
        self.message.clear();
        self.message.extend_from_slice(&CDR_HEADER);
        self.message.extend_from_slice(payload);
        let header = MessageHeader {
            channel_id: self.channels[channel.0].id,
            sequence: sequence as u32,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.writer
            .write_to_known_channel(&header, &self.message)
            .map_err(|source| mcap_error(&self.path, source))?;
        self.messages += 1;
        Ok(())
    }

    /// Closes the chunk being filled, so that everything written so far
    /// survives the recorder being killed.
    pub fn flush(&mut self) -> Result<(), RecordingError> {
        self.writer.flush().map_err(|source| mcap_error(&self.path, source))
    }

    /// Writes the summary and indexes and closes the file; the parts written.
    pub fn finish(mut self) -> Result<Vec<PathBuf>, RecordingError> {
        self.writer.finish().map_err(|source| mcap_error(&self.path, source))?;
        Ok(self.files)
    }

    pub fn messages(&self) -> u64 {
        self.messages
    }

    /// Bytes in files so far (chunks reach the file when they close).
    pub fn bytes(&self) -> u64 {
        self.bytes_in_closed_files + self.writer_bytes()
    }

    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    fn writer_bytes(&self) -> u64 {
        self.file_len.load(Ordering::Relaxed)
    }

    fn topics(&self) -> String {
        self.channels
            .iter()
            .map(|c| c.topic.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    }

    fn split_due(&self, time_ns: u64) -> bool {
        let too_big = self
            .options
            .split_bytes
            .is_some_and(|limit| self.writer_bytes() >= limit);
        let too_long = match (self.options.split_seconds, self.file_start_ns) {
            (Some(limit), Some(start)) => time_ns.saturating_sub(start) as f64 * 1e-9 >= limit,
            _ => false,
        };
        too_big || too_long
    }

    fn next_part(&mut self) -> Result<(), RecordingError> {
        let path = part_path(&self.base, &self.options, self.files.len());
        let (mut writer, file_len) = open_part(&path, &self.options)?;
        for channel in &mut self.channels {
            channel.id = add_to_file(&mut writer, &path, &channel.topic, channel.kind)?;
        }
        let mut old = std::mem::replace(&mut self.writer, writer);
        old.finish().map_err(|source| mcap_error(&self.path, source))?;
        drop(old);
        self.bytes_in_closed_files += self.writer_bytes();
        self.file_len = file_len;
        self.path = path.clone();
        self.files.push(path);
        self.file_start_ns = None;
        Ok(())
    }
}

fn part_path(base: &Path, options: &RecordOptions, index: usize) -> PathBuf {
    if !options.splits() {
        return base.to_path_buf();
    }
    let stem = base
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    base.with_file_name(format!("{stem}_{index:03}.mcap"))
}

fn open_part(
    path: &Path,
    options: &RecordOptions,
) -> Result<(mcap::Writer<CountingFile>, Arc<AtomicU64>), RecordingError> {
    let file = File::create(path).map_err(|source| RecordingError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let file_len = Arc::new(AtomicU64::new(0));
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_level(options.zstd_level)
        // Compress in the recorder's own thread: worker threads (one per
        // core by default) would compete with the control loop.
        .compression_threads(0)
        .chunk_size(Some(options.chunk_bytes))
        .profile("ros2")
        .library(concat!("hydractl ", env!("CARGO_PKG_VERSION")))
        .create(CountingFile::new(file, file_len.clone()))
        .map_err(|source| mcap_error(path, source))?;
    if !options.metadata.is_empty() {
        writer
            .write_metadata(&mcap::records::Metadata {
                name: "hydractl".into(),
                metadata: options.metadata.clone(),
            })
            .map_err(|source| mcap_error(path, source))?;
    }
    Ok((writer, file_len))
}

fn add_to_file(
    writer: &mut mcap::Writer<CountingFile>,
    path: &Path,
    topic: &str,
    kind: &SampleKind,
) -> Result<u16, RecordingError> {
    let schema = writer
        .add_schema(kind.schema_name, SCHEMA_ENCODING, kind.ros2msg.as_bytes())
        .map_err(|source| mcap_error(path, source))?;
    writer
        .add_channel(schema, topic, MESSAGE_ENCODING, &BTreeMap::new())
        .map_err(|source| mcap_error(path, source))
}

fn mcap_error(path: &Path, source: mcap::McapError) -> RecordingError {
    RecordingError::Mcap {
        path: path.to_path_buf(),
        source,
    }
}

/// A buffered file that knows how long it is, for splitting by size.
struct CountingFile {
    inner: BufWriter<File>,
    position: u64,
    len: Arc<AtomicU64>,
}

impl CountingFile {
    fn new(file: File, len: Arc<AtomicU64>) -> Self {
        Self {
            inner: BufWriter::with_capacity(256 * 1024, file),
            position: 0,
            len,
        }
    }
}

impl Write for CountingFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.position += n as u64;
        self.len.fetch_max(self.position, Ordering::Relaxed);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl Seek for CountingFile {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.position = self.inner.seek(pos)?;
        Ok(self.position)
    }
}
