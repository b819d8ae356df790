use std::collections::BTreeMap;
use std::path::Path;

use serde::Serialize;

use crate::{read_messages, RecordingError};

/// What `hydractl mcap info` shows of one channel.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ChannelSummary {
    pub topic: String,
    pub schema: String,
    pub messages: u64,
    pub first_seq: u64,
    pub last_seq: u64,
    /// Sequence numbers missing between the first and the last.
    pub missing: u64,
    /// Messages per second over the channel's own span.
    pub rate_hz: f64,
    #[serde(skip)]
    first_ns: u64,
    #[serde(skip)]
    last_ns: u64,
}

/// What `hydractl mcap info` shows of a recording.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecordingSummary {
    pub path: String,
    pub bytes: u64,
    pub messages: u64,
    pub duration_s: f64,
    /// Set when the file was not read whole: why (see
    /// [`crate::ReadOutcome::truncated`]).
    pub truncated: Option<String>,
    pub metadata: BTreeMap<String, String>,
    pub channels: Vec<ChannelSummary>,
}

/// Reads the whole recording: counts, rates and gaps per channel.
pub fn summarize(path: &Path) -> Result<RecordingSummary, RecordingError> {
    let mut channels: BTreeMap<String, ChannelSummary> = BTreeMap::new();
    let mut span: Option<(u64, u64)> = None;
    let outcome = read_messages(path, |m| {
        // A CAN frame's channel has no sequence in its payload: the
        // header's (32 bits, enough within a recording's span of gaps).
        let seq = m.kind.sequence(m.payload).unwrap_or(u64::from(m.mcap_sequence));
        let c = channels.entry(m.topic.to_owned()).or_insert_with(|| ChannelSummary {
            topic: m.topic.to_owned(),
            schema: m.kind.schema_name.to_owned(),
            first_seq: seq,
            last_seq: seq,
            first_ns: m.log_time_ns,
            last_ns: m.log_time_ns,
            ..ChannelSummary::default()
        });
        if c.messages > 0 && seq > c.last_seq + 1 {
            c.missing += seq - c.last_seq - 1;
        }
        c.messages += 1;
        c.last_seq = c.last_seq.max(seq);
        c.last_ns = c.last_ns.max(m.log_time_ns);
        span = Some(match span {
            None => (m.log_time_ns, m.log_time_ns),
            Some((a, b)) => (a.min(m.log_time_ns), b.max(m.log_time_ns)),
        });
        Ok(())
    })?;
    let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let channels = channels
        .into_values()
        .map(|mut c| {
            let seconds = c.last_ns.saturating_sub(c.first_ns) as f64 * 1e-9;
            c.rate_hz = if seconds > 0.0 {
                (c.messages - 1) as f64 / seconds
            } else {
                0.0
            };
            c
        })
        .collect();
    Ok(RecordingSummary {
        path: path.display().to_string(),
        bytes,
        messages: outcome.messages,
        duration_s: span.map_or(0.0, |(a, b)| b.saturating_sub(a) as f64 * 1e-9),
        truncated: outcome.truncated,
        metadata: outcome.metadata,
        channels,
    })
}
