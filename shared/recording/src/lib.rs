//! MCAP recordings of the live stack. Each iceoryx2 service is one channel;
//! each message is the CDR header followed by the sample's own bytes, with
//! the sample's `ros2msg` schema, so Foxglove and PlotJuggler decode it by
//! reflection. This crate knows files and bytes, not IPC: the recorder
//! process feeds it what it receives.
//!
//! What it holds: MCAP recordings of samples, knowing files and bytes, not
//! IPC: the writer (one channel per service, CDR messages with `ros2msg`
//! schemas, a CAN bus's frames as ROS 2 `can_msgs/msg/Frame` (`can`), zstd
//! chunks in the writer's own thread, closed by the writer itself, metadata,
//! splitting by size or duration, a ring of parts within `keep_bytes`
//! spanning earlier runs, a full disk met without an error: what never
//! reached a file read back and counted, writing stopped or the oldest part
//! deleted), the reader (up to the last whole chunk of a cut file, every bad
//! message named), `mcap info`'s summary, and the model tools' rows
//! (`export-csv`) with the one join of readings and valve commands
//! (`CommandJoin`) the shadow uses too.

mod can;
mod export;
mod info;
mod join;
mod read;
mod write;

pub use can::{decode_frame, encode_frame, is_can_frame, RecordedFrame, CAN_FRAME_KIND};
pub use export::{export_rows, export_rows_in, write_csv, Export, ModelRow, MODEL_COLUMNS, SIGNAL_COLUMNS};
pub use info::{summarize, ChannelSummary, RecordingSummary};
pub use join::CommandJoin;
pub use read::{decode, read_messages, read_messages_in, ReadOutcome, RecordedMessage, Window};
pub use write::{ChannelHandle, RecordOptions, RecordingWriter, Unrecorded, WriterNews};

use std::path::PathBuf;

/// The message encoding of every channel.
pub const MESSAGE_ENCODING: &str = "cdr";
/// The schema encoding of every schema.
pub const SCHEMA_ENCODING: &str = "ros2msg";

#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: MCAP: {source}")]
    Mcap { path: PathBuf, source: mcap::McapError },
    #[error("{path}: channel `{topic}` has schema `{schema}`, which hydractl does not know")]
    UnknownSchema {
        path: PathBuf,
        topic: String,
        schema: String,
    },
    #[error("{path}: {at} has {got} bytes after the CDR header, `{schema}` needs {want}")]
    BadSize {
        path: PathBuf,
        at: Box<MessageAt>,
        schema: String,
        got: usize,
        want: usize,
    },
    /// A sample that could not be encoded for writing.
    #[error("{path}: `{topic}`: {source}")]
    Cdr {
        path: PathBuf,
        topic: String,
        source: hydractl_samples::cdr::CdrError,
    },
    /// A recorded message that could not be decoded.
    #[error("{path}: {at}: {source}")]
    CdrAt {
        path: PathBuf,
        at: Box<MessageAt>,
        source: hydractl_samples::cdr::CdrError,
    },
    #[error("{path}: {at} is not a can_msgs/msg/Frame: {reason}")]
    BadFrame {
        path: PathBuf,
        at: Box<MessageAt>,
        reason: String,
    },
    #[error("{path}: {at} does not start with the little-endian CDR header")]
    BadHeader { path: PathBuf, at: Box<MessageAt> },
    #[error("{path}: no channel `{topic}`; the recording has: {have}")]
    MissingChannel { path: PathBuf, topic: String, have: String },
    #[error("{path}: no sample of `{topic}` matches a sensor reading; nothing to export")]
    NothingToExport { path: PathBuf, topic: String },
    #[error(
        "{path}: the valve never drove the machine in this recording (held neutral throughout: a fault latched before \
         the run, or the stack stopping); nothing to fit"
    )]
    NeverDriven { path: PathBuf },
    #[error("{path}: a sample of {got} bytes was written to channel `{topic}`, whose `{schema}` has {want}")]
    WrongPayload {
        path: PathBuf,
        topic: String,
        schema: String,
        got: usize,
        want: usize,
    },
    #[error("{path}: cannot write CSV: {source}")]
    Csv { path: PathBuf, source: csv::Error },
}

/// Where a message that could not be read sits, in the terms `mcap cat`
/// and a reader of the file use: its channel, its place among that
/// channel's messages, its log time and its MCAP sequence.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MessageAt {
    pub topic: String,
    pub index: u64,
    pub log_time_ns: u64,
    pub sequence: u32,
}

impl std::fmt::Display for MessageAt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "message {} on `{}` (log time {} ns, sequence {})",
            self.index, self.topic, self.log_time_ns, self.sequence
        )
    }
}
