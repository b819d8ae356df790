//! The run's recording read back after it: its parts beside `--record`,
//! what they hold, and what is missing (a full disk, a restarted
//! recorder), which makes `hydractl run` exit 3.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use super::summary::{NotRecorded, RecordingReport};

/// The run went through, but its recording misses something: `hydractl
/// run` exits 3, after the summary that says what.
#[derive(Debug)]
pub struct RecordingIncomplete(pub(super) String);

impl std::fmt::Display for RecordingIncomplete {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the recording is INCOMPLETE: {}", self.0)
    }
}

impl std::error::Error for RecordingIncomplete {}

impl RecordingReport {
    pub(super) fn what_is_missing(&self) -> String {
        let mut missing = Vec::new();
        if let Some(n) = self.not_recorded {
            missing.push(format!(
                "{} samples from {:.3} s into the run on were not recorded (the disk was full {} time{})",
                n.samples,
                n.from_s,
                self.disk_full,
                if self.disk_full == 1 { "" } else { "s" }
            ));
        }
        if self.recorder_restarts > 0 {
            missing.push(format!(
                "the recorder was restarted {} time{}, and what it missed meanwhile is not counted",
                self.recorder_restarts,
                if self.recorder_restarts == 1 { "" } else { "s" }
            ));
        }
        if missing.is_empty() {
            missing.push("a file of it cannot be read, or the recorder never said what it wrote".to_owned());
        }
        missing.join("; ")
    }
}

/// The recorder as it said itself: its last status, read live (a full
/// disk keeps it out of the file), and its restarts.
#[derive(Default, Clone, Copy)]
pub(super) struct RecorderView {
    pub(super) last: Option<hydractl_samples::RecorderStatus>,
    pub(super) restarts: u32,
    /// The run's first reading, from which `not_recorded.from_s` counts.
    pub(super) first_reading_ns: u64,
}

/// The recording's parts beside `out`: `STEM.mcap` or `STEM_NNN.mcap`,
/// and a restarted recorder's `STEM_restartN[_NNN].mcap`, in order.
pub(super) fn recording_files(out: &Path) -> Result<Vec<PathBuf>> {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let is_part = |rest: &str| rest.len() == 3 && rest.bytes().all(|b| b.is_ascii_digit());
    let is_restart = |rest: &str| {
        rest.strip_prefix("restart").is_some_and(|r| {
            let (n, part) = r.split_once('_').unwrap_or((r, "000"));
            !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) && is_part(part)
        })
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("listing {}", dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            name == format!("{stem}.mcap")
                || name
                    .strip_prefix(&format!("{stem}_"))
                    .and_then(|rest| rest.strip_suffix(".mcap"))
                    .is_some_and(|rest| is_part(rest) || is_restart(rest))
        })
        .collect();
    // The first recorder's parts, then each restart's.
    files.sort_by_key(|p| {
        let name = p.to_string_lossy().into_owned();
        (name.contains("_restart"), name)
    });
    Ok(files)
}

/// Reads back the files the recorder wrote, and says what is missing.
pub(super) fn recording_report(out: &Path, recorder: RecorderView) -> Result<RecordingReport> {
    let mut report = RecordingReport {
        files: Vec::new(),
        messages: 0,
        channels: 0,
        dropped: 0,
        gaps: 0,
        complete: true,
        not_recorded: None,
        disk_full: 0,
        deleted_files: 0,
        recorder_restarts: recorder.restarts,
    };
    for file in recording_files(out)? {
        // A file a full disk or a killed recorder left unreadable is
        // reported, not fatal: the rest of the recording is still there.
        let summary = match hydractl_recording::summarize(&file) {
            Ok(summary) => summary,
            Err(e) => {
                tracing::warn!("{e}");
                report.complete = false;
                continue;
            }
        };
        report.messages += summary.messages;
        report.channels = report.channels.max(summary.channels.len());
        report.gaps += summary.channels.iter().map(|c| c.missing).sum::<u64>();
        report.files.push(file.display().to_string());
    }
    if let Some(last) = recorder.last {
        report.dropped = last.dropped;
        report.disk_full = last.disk_full;
        report.deleted_files = last.deleted_files;
        if last.unrecorded > 0 {
            report.not_recorded = Some(NotRecorded {
                samples: last.unrecorded,
                from_s: last.unrecorded_since_ns.saturating_sub(recorder.first_reading_ns) as f64 * 1e-9,
            });
        }
    }
    report.complete &= report.not_recorded.is_none() && recorder.restarts == 0 && recorder.last.is_some();
    Ok(report)
}

/// Whether a file can be written at `path`, without creating it: its
/// folder exists and takes a new file, and it is not itself a folder.
pub(super) fn check_writable(path: &Path, flag: &str) -> Result<()> {
    if path.is_dir() {
        bail!("{flag} {}: is a folder, not a file", path.display());
    }
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        bail!("{flag} {}: the folder {} does not exist", path.display(), dir.display());
    }
    let probe = dir.join(format!(".hydractl-write-check-{}", std::process::id()));
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .with_context(|| format!("{flag} {}: cannot write in {}", path.display(), dir.display()))?;
    std::fs::remove_file(&probe).with_context(|| format!("removing {}", probe.display()))?;
    Ok(())
}
