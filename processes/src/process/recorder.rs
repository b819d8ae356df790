//! The recorder: writes every sample of the run to one MCAP file (or its
//! parts). It subscribes to the stack's services at start and to any other
//! service discovery finds later, drains them on its own 5 ms tick off the
//! loop's CPU, and never blocks a publisher: a sample it was too slow for
//! is counted as missed in its status. It closes a chunk every second, so a
//! killed recorder leaves a file readable up to that chunk.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use crate::recording::Recorder;
use anyhow::{Context, Result};
use hydractl_bus::{clock, run_loop, Outlet};
use hydractl_recording::{RecordOptions, RecordingWriter, WriterNews};
use hydractl_samples::{service, RecorderStatus};

const TICK: Duration = Duration::from_millis(5);
const DISCOVER_EVERY: Duration = Duration::from_millis(200);
const FLUSH_EVERY: Duration = Duration::from_secs(1);
const STATUS_EVERY: Duration = Duration::from_millis(100);

pub fn run() -> Result<()> {
    let started = crate::start("recorder")?;
    let record = &started.args.record;
    let out = record.out.clone().context("recorder: --out FILE is required")?;
    let mut metadata = BTreeMap::from([
        ("software".to_owned(), format!("hydractl {}", env!("CARGO_PKG_VERSION"))),
        ("config".to_owned(), started.config.to_toml()),
        ("ipc_prefix".to_owned(), started.bus.scope().prefix().to_owned()),
        // The log times are the monotonic clock's; the fleet needs the day.
        (
            "start_time".to_owned(),
            humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string(),
        ),
    ]);
    if let Some(id) = started.config.machine.as_ref().and_then(|m| m.id.clone()) {
        metadata.insert("machine_id".to_owned(), id);
    }
    let keep_mb = record.split.keep_mb.or(started.config.recording.keep_mb);
    if keep_mb.is_some() && !record.split.splits() {
        anyhow::bail!("recorder: keep_mb needs a split to delete: --split-size-mb or --split-duration-s");
    }
    let adopt = match (&record.ring, keep_mb) {
        (Some(ring), Some(_)) => earlier_in_ring(&out, ring),
        _ => Vec::new(),
    };
    let options = RecordOptions {
        split_bytes: record.split.split_size_mb.map(|mb| (mb * 1e6) as u64),
        split_seconds: record.split.split_duration_s,
        metadata,
        keep_bytes: keep_mb.map(|mb| (mb * 1e6) as u64),
        adopt,
        ..RecordOptions::default()
    };
    let writer = RecordingWriter::create(&out, options).with_context(|| format!("recorder: {}", out.display()))?;
    let bus = &started.bus;
    let mut recorder = Recorder::new(bus, writer)?;
    let status: Outlet<RecorderStatus> = Outlet::open(bus, service::RECORDER_STATUS)?;
    recorder.discover(bus)?;
    status.publish(recorder.status(clock::now_ns()))?;

    let mut last_discovery = Instant::now();
    let mut last_flush = Instant::now();
    let mut last_status = Instant::now();
    let mut failure = None;
    run_loop(&[], Some(TICK), bus, |_| {
        hydractl_bus::guarded(&mut failure, || -> Result<()> {
            recorder.drain()?;
            let now = Instant::now();
            if now.duration_since(last_discovery) >= DISCOVER_EVERY {
                last_discovery = now;
                recorder.discover(bus)?;
            }
            if now.duration_since(last_flush) >= FLUSH_EVERY {
                last_flush = now;
                recorder.flush()?;
            }
            for news in recorder.take_news() {
                say(&news, &recorder);
            }
            if now.duration_since(last_status) >= STATUS_EVERY {
                last_status = now;
                status.publish(recorder.status(clock::now_ns()))?;
            }
            Ok(())
        })
    })?;
    let last_status = recorder.status(clock::now_ns());
    let news = recorder.take_news();
    news.iter().for_each(|n| say(n, &recorder));
    // The run reads what was not recorded from the last status, which a
    // full disk kept out of the file.
    status.publish(last_status)?;
    let files = recorder.finish()?;
    for file in files {
        if last_status.unrecorded > 0 {
            tracing::warn!(
                unrecorded = last_status.unrecorded,
                "wrote {} up to its last whole chunk; {} samples were not recorded",
                file.display(),
                last_status.unrecorded
            );
        } else {
            tracing::info!("wrote {}", file.display());
        }
    }
    failure.map_or(Ok(()), Err)
}

/// Says, once, what the writer did on its own.
fn say(news: &WriterNews, recorder: &Recorder) {
    let since = |ns: u64| format!("{:.3} s into the recording", recorder.seconds_in(ns));
    // What the failure took with it: the samples of the chunk it broke.
    let lost_since = |lost: u64, ns: u64| match lost {
        0 => format!("nothing before {} is lost", since(ns)),
        _ => format!("{lost} samples since {} are lost", since(ns)),
    };
    match news {
        WriterNews::Stopped {
            path,
            lost,
            since_ns,
            why,
        } => tracing::error!(
            unrecorded = lost,
            "{}: {why}: the disk is full; recording STOPS here: {}, and every later sample is counted, not recorded",
            path.display(),
            lost_since(*lost, *since_ns)
        ),
        WriterNews::Rotated {
            path,
            lost,
            since_ns,
            deleted,
        } => tracing::warn!(
            unrecorded = lost,
            "the disk is full: {}; deleted the oldest part{} ({}) and recording goes on in {}",
            lost_since(*lost, *since_ns),
            if deleted.len() == 1 { "" } else { "s" },
            deleted
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
            path.display()
        ),
        WriterNews::Deleted(paths) => tracing::info!(
            "keeping the recording within keep_mb: deleted {}",
            paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Earlier runs' recordings beside `out` in the ring `ring` (`RING-*.mcap`),
/// oldest first: their names carry their start times.
fn earlier_in_ring(out: &std::path::Path, ring: &str) -> Vec<std::path::PathBuf> {
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    let this = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut earlier: Vec<std::path::PathBuf> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| {
                    let name = p
                        .file_name()
                        .map(|n| n.to_string_lossy().into_owned())
                        .unwrap_or_default();
                    name.starts_with(&format!("{ring}-")) && name.ends_with(".mcap") && !name.starts_with(&this)
                })
                .collect()
        })
        .unwrap_or_default();
    earlier.sort();
    earlier
}
