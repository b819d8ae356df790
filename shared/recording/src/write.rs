use std::collections::{BTreeMap, VecDeque};
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
    /// The writer closes each chunk itself, so that it knows exactly which
    /// messages reached the file when a write fails.
    pub chunk_bytes: u64,
    pub zstd_level: u32,
    /// Written as the metadata record `hydractl` at the start of each file:
    /// the config, the software version.
    pub metadata: BTreeMap<String, String>,
    /// When splitting: keep at most this many bytes of parts, deleting the
    /// oldest before a new part would pass it (a flight recorder's ring).
    pub keep_bytes: Option<u64>,
    /// Earlier recordings in the same ring, oldest first: deleted before
    /// this one's parts.
    pub adopt: Vec<PathBuf>,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            split_bytes: None,
            split_seconds: None,
            chunk_bytes: 512 * 1024,
            zstd_level: 3,
            metadata: BTreeMap::new(),
            keep_bytes: None,
            adopt: Vec::new(),
        }
    }
}

impl RecordOptions {
    fn splits(&self) -> bool {
        self.split_bytes.is_some() || self.split_seconds.is_some()
    }
}

/// Something the writer did on its own that its owner should say: it
/// returns no error for it, so that a recorder never stops on a full disk.
#[derive(Debug, Clone, PartialEq)]
pub enum WriterNews {
    /// The disk was full: `lost` samples since `since_ns` never reached a
    /// file, and writing stopped; later samples are counted, not written.
    Stopped {
        path: PathBuf,
        lost: u64,
        since_ns: u64,
        why: String,
    },
    /// The disk was full: `lost` samples since `since_ns` never reached a
    /// file; the oldest parts were deleted and recording goes on in `path`.
    Rotated {
        path: PathBuf,
        lost: u64,
        since_ns: u64,
        deleted: Vec<PathBuf>,
    },
    /// Parts deleted to keep the recording within its limit.
    Deleted(Vec<PathBuf>),
}

/// What the writer received and could not put in a file.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Unrecorded {
    pub samples: u64,
    /// The first of them, by its log time.
    pub since_ns: Option<u64>,
    /// Times the disk was full.
    pub disk_full: u32,
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
    writer: mcap::Writer<PartFile>,
    /// The current file's length, shared with its [`GuardedFile`].
    file_len: Arc<AtomicU64>,
    path: PathBuf,
    files: Vec<PathBuf>,
    channels: Vec<Channel>,
    /// The log time of the current file's first message.
    file_start_ns: Option<u64>,
    message: Vec<u8>,
    /// A sample with text, encoded field by field.
    encoded: Vec<u8>,
    /// Messages in the files (or in the chunk being filled).
    messages: u64,
    bytes_in_closed_files: u64,
    /// Messages that reached a file in a closed chunk: what survives.
    durable_messages: u64,
    /// Messages before the current part.
    part_start_messages: u64,
    /// The log time of the first message after them.
    pending_since_ns: Option<u64>,
    /// Uncompressed bytes in the chunk being filled.
    chunk_fill: u64,
    /// File bytes per uncompressed byte in the last closed chunk: what the
    /// chunk being filled will take once it reaches the file.
    compression: f64,
    unrecorded: Unrecorded,
    /// The log time of the first message received.
    first_ns: Option<u64>,
    /// Writing stopped for good: the disk was full and nothing could be freed.
    stopped: bool,
    /// Closed parts still on disk, oldest first, with their sizes.
    kept: VecDeque<(PathBuf, u64)>,
    deleted_files: u32,
    news: Vec<WriterNews>,
}

/// A part's file as the mcap writer sees it.
type PartFile = BufWriter<GuardedFile>;

/// Whether a write failed for want of room: a full disk, a quota, a file
/// size limit.
fn is_disk_full(error: &mcap::McapError) -> bool {
    use std::io::ErrorKind::{FileTooLarge, QuotaExceeded, StorageFull};
    matches!(error, mcap::McapError::Io(e) if matches!(e.kind(), StorageFull | QuotaExceeded | FileTooLarge))
}

impl RecordingWriter {
    /// Creates the recording at `path`; when splitting, its parts are
    /// `STEM_000.mcap`, `STEM_001.mcap`, … beside it.
    pub fn create(path: &Path, options: RecordOptions) -> Result<Self, RecordingError> {
        let first = part_path(path, &options, 0);
        let (writer, file_len) = open_part(&first, &options)?;
        let kept = options
            .adopt
            .iter()
            .filter_map(|p| Some((p.clone(), std::fs::metadata(p).ok()?.len())))
            .collect();
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
            durable_messages: 0,
            part_start_messages: 0,
            pending_since_ns: None,
            chunk_fill: 0,
            compression: 1.0,
            unrecorded: Unrecorded::default(),
            first_ns: None,
            stopped: false,
            kept,
            deleted_files: 0,
            news: Vec::new(),
        })
    }

    /// Adds a channel for samples of `kind` on `topic` (the service name).
    pub fn add_channel(&mut self, topic: &str, kind: &'static SampleKind) -> Result<ChannelHandle, RecordingError> {
        let id = if self.stopped {
            0
        } else {
            match add_to_file(&mut self.writer, &self.path, topic, kind) {
                Ok(id) => id,
                Err(e) => {
                    let time_ns = self.pending_since_ns.unwrap_or(0);
                    self.on_failure(e, 0, time_ns)?;
                    // Into the part that made room, or none: written no more.
                    if self.stopped {
                        0
                    } else {
                        add_to_file(&mut self.writer, &self.path, topic, kind)?
                    }
                }
            }
        };
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
        self.first_ns.get_or_insert(time_ns);
        if self.stopped {
            self.count_unrecorded(1, time_ns);
            return Ok(());
        }
        if self.split_due(time_ns) {
            if let Err(e) = self.next_part() {
                return self.on_failure(e, 1, time_ns);
            }
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
        let written = self.writer.write_to_known_channel(&header, &self.message);
        if let Err(source) = written {
            return self.on_failure(mcap_error(&self.path, source), 1, time_ns);
        }
        self.pending_since_ns.get_or_insert(time_ns);
        self.messages += 1;
        self.chunk_fill += self.message.len() as u64;
        if self.chunk_fill >= self.options.chunk_bytes {
            self.flush()?;
        }
        Ok(())
    }

    fn count_unrecorded(&mut self, samples: u64, since_ns: u64) {
        self.unrecorded.samples += samples;
        self.unrecorded.since_ns.get_or_insert(since_ns);
    }

    /// A write that failed: for want of room, everything since the last
    /// closed chunk (and `failing` samples more, from `time_ns`) is lost,
    /// the oldest parts make room when there are any, and otherwise
    /// writing stops; any other error is the caller's.
    fn on_failure(&mut self, error: RecordingError, failing: u64, time_ns: u64) -> Result<(), RecordingError> {
        let RecordingError::Mcap { source, .. } = &error else {
            return Err(error);
        };
        if !is_disk_full(source) {
            return Err(error);
        }
        let why = source.to_string();
        self.unrecorded.disk_full += 1;
        // What the failure left in the file is final: read it back. A
        // chunk may have reached it whole although the write that
        // followed it (its index) failed.
        let mut in_file = 0u64;
        let _ = crate::read_messages(&self.path, |_| {
            in_file += 1;
            Ok(())
        });
        let accepted = self.messages - self.part_start_messages;
        let (lost, since_ns) = if in_file >= accepted {
            (failing, time_ns)
        } else {
            (accepted - in_file + failing, self.pending_since_ns.unwrap_or(time_ns))
        };
        if lost > 0 {
            self.count_unrecorded(lost, since_ns);
        }
        self.messages = self.part_start_messages + in_file.min(accepted);
        self.durable_messages = self.messages;
        self.pending_since_ns = None;
        self.chunk_fill = 0;
        // The part is readable up to its last closed chunk; its end is lost.
        let broken = self.path.clone();
        if self.options.keep_bytes.is_some() && !self.kept.is_empty() {
            let deleted = self.delete_oldest(1);
            self.kept
                .push_back((broken.clone(), std::fs::metadata(&broken).map_or(0, |m| m.len())));
            match self.open_next_part() {
                Ok(()) => {
                    self.news.push(WriterNews::Rotated {
                        path: self.path.clone(),
                        lost,
                        since_ns,
                        deleted,
                    });
                    return Ok(());
                }
                // Not even a new file: nothing more can be written.
                Err(_) => {
                    self.kept.pop_back();
                }
            }
        }
        self.stopped = true;
        self.news.push(WriterNews::Stopped {
            path: broken,
            lost,
            since_ns,
            why,
        });
        Ok(())
    }

    /// What happened since the last call, for the owner to say.
    pub fn take_news(&mut self) -> Vec<WriterNews> {
        std::mem::take(&mut self.news)
    }

    pub fn unrecorded(&self) -> Unrecorded {
        self.unrecorded
    }

    /// The log time of the first message received, written or not.
    pub fn first_ns(&self) -> Option<u64> {
        self.first_ns
    }

    /// Parts deleted to stay within `keep_bytes`.
    pub fn deleted_files(&self) -> u32 {
        self.deleted_files
    }

    /// Deletes the oldest kept parts, at least `at_least` of them (when
    /// there are), and more while the parts and a new one would pass
    /// `keep_bytes`; the parts deleted.
    fn delete_oldest(&mut self, at_least: usize) -> Vec<PathBuf> {
        let Some(keep) = self.options.keep_bytes else {
            return Vec::new();
        };
        // A new part is as large as the largest so far, or the split's size.
        let next = self
            .kept
            .iter()
            .map(|(_, len)| *len)
            .chain(self.options.split_bytes)
            .max()
            .unwrap_or(0);
        let mut deleted = Vec::new();
        while let Some((_, len)) = self.kept.front() {
            let total: u64 = self.kept.iter().map(|(_, l)| l).sum::<u64>() + next;
            if deleted.len() >= at_least && total <= keep {
                break;
            }
            let len = *len;
            let Some((path, _)) = self.kept.pop_front() else { break };
            // A part already gone (removed by hand) frees its room all the same.
            let _ = std::fs::remove_file(&path);
            self.bytes_in_closed_files = self.bytes_in_closed_files.saturating_sub(len);
            self.deleted_files += 1;
            deleted.push(path);
        }
        deleted
    }

    /// Closes the chunk being filled, so that everything written so far
    /// survives the recorder being killed.
    pub fn flush(&mut self) -> Result<(), RecordingError> {
        if self.stopped {
            return Ok(());
        }
        let (fill, before) = (self.chunk_fill, self.writer_bytes());
        self.chunk_fill = 0;
        match self.writer.flush() {
            Ok(()) => {
                self.learn_compression(fill, before);
                self.durable_messages = self.messages;
                self.pending_since_ns = None;
                Ok(())
            }
            Err(source) => {
                let time_ns = self.pending_since_ns.unwrap_or(0);
                self.on_failure(mcap_error(&self.path, source), 0, time_ns)
            }
        }
    }

    /// Writes the summary and indexes and closes the file; the parts written.
    pub fn finish(mut self) -> Result<Vec<PathBuf>, RecordingError> {
        if !self.stopped {
            if let Err(source) = self.writer.finish() {
                let time_ns = self.pending_since_ns.unwrap_or(0);
                self.on_failure(mcap_error(&self.path, source), 0, time_ns)?;
            }
        }
        Ok(self.files.into_iter().filter(|f| f.exists()).collect())
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

    /// After a chunk of `fill` bytes closed with the file at `before`.
    fn learn_compression(&mut self, fill: u64, before: u64) {
        if fill > 0 {
            self.compression = self.writer_bytes().saturating_sub(before) as f64 / fill as f64;
        }
    }

    fn split_due(&self, time_ns: u64) -> bool {
        // A chunk reaches the file only when it closes, a second's worth
        // at a time: count the open one as it will be written, or a part
        // outgrows its size by that much (and a ring keeps one part).
        let part_bytes = self.writer_bytes() + (self.chunk_fill as f64 * self.compression) as u64;
        let too_big = self.options.split_bytes.is_some_and(|limit| part_bytes >= limit);
        let too_long = match (self.options.split_seconds, self.file_start_ns) {
            (Some(limit), Some(start)) => time_ns.saturating_sub(start) as f64 * 1e-9 >= limit,
            _ => false,
        };
        too_big || too_long
    }

    /// Closes the current part and starts the next, deleting the oldest
    /// parts first when the recording keeps only so many bytes.
    fn next_part(&mut self) -> Result<(), RecordingError> {
        let (fill, before) = (self.chunk_fill, self.writer_bytes());
        self.writer.finish().map_err(|source| mcap_error(&self.path, source))?;
        self.learn_compression(fill, before);
        self.durable_messages = self.messages;
        self.pending_since_ns = None;
        self.chunk_fill = 0;
        self.kept.push_back((self.path.clone(), self.writer_bytes()));
        let deleted = self.delete_oldest(0);
        if !deleted.is_empty() {
            self.news.push(WriterNews::Deleted(deleted));
        }
        self.open_next_part()
    }

    /// Opens the next part, with every channel; the current one is closed
    /// (or broken) and counted.
    fn open_next_part(&mut self) -> Result<(), RecordingError> {
        let path = part_path(&self.base, &self.options, self.files.len());
        let (mut writer, file_len) = open_part(&path, &self.options)?;
        for channel in &mut self.channels {
            channel.id = add_to_file(&mut writer, &path, &channel.topic, channel.kind)?;
        }
        // Finished above, or broken: its Drop's finish has nothing to add.
        drop(std::mem::replace(&mut self.writer, writer));
        self.bytes_in_closed_files += self.writer_bytes();
        self.file_len = file_len;
        self.path = path.clone();
        self.files.push(path);
        self.file_start_ns = None;
        self.part_start_messages = self.messages;
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

fn open_part(path: &Path, options: &RecordOptions) -> Result<(mcap::Writer<PartFile>, Arc<AtomicU64>), RecordingError> {
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
        // Closed by the writer at `chunk_bytes`, not by the mcap crate.
        .chunk_size(None)
        .profile("ros2")
        .library(concat!("hydractl ", env!("CARGO_PKG_VERSION")))
        .create(BufWriter::with_capacity(
            256 * 1024,
            GuardedFile::new(file, file_len.clone()),
        ))
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
    writer: &mut mcap::Writer<PartFile>,
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

/// A file that knows how long it is (for splitting by size) and that
/// takes no byte after a write of it failed: what a failure left in it is
/// final, and can be read back to know what was recorded.
struct GuardedFile {
    file: File,
    position: u64,
    len: Arc<AtomicU64>,
    failed: bool,
}

impl GuardedFile {
    fn new(file: File, len: Arc<AtomicU64>) -> Self {
        Self {
            file,
            position: 0,
            len,
            failed: false,
        }
    }
}

impl Write for GuardedFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.failed {
            return Err(std::io::Error::other("an earlier write to this file failed"));
        }
        match self.file.write(buf) {
            Ok(n) => {
                self.position += n as u64;
                self.len.fetch_max(self.position, Ordering::Relaxed);
                Ok(n)
            }
            Err(e) => {
                self.failed = true;
                Err(e)
            }
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl Seek for GuardedFile {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.position = self.file.seek(pos)?;
        Ok(self.position)
    }
}
