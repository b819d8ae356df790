//! `hydractl record`, `replay`, `mcap info`, `mcap export-csv`, and the
//! model tools' reading of a recording.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use hydractl_bus::{quiet_ipc_logging, Bus, RunScope, PREFIX_ENV};
use hydractl_ident::Dataset;
use hydractl_processes::recording::{republisher, Republisher};
use hydractl_recording::{export_rows, read_messages, summarize, write_csv, MODEL_COLUMNS, SIGNAL_COLUMNS};

#[derive(clap::Args)]
pub struct RecordArgs {
    /// The MCAP file to write.
    file: PathBuf,
    /// Seconds to record; without it, until Ctrl-C or the run stops.
    #[arg(long)]
    duration: Option<f64>,
    /// The run's config, kept in the recording's metadata [default: the built-in config/sim.toml].
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    split: hydractl_processes::SplitArgs,
}

#[derive(clap::Args)]
pub struct ReplayArgs {
    /// The MCAP file to replay.
    file: PathBuf,
    /// Playback speed: 1 is as recorded, 2 twice as fast.
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Only these services (comma-separated) [default: every one recorded].
    #[arg(long, value_delimiter = ',')]
    topics: Vec<String>,
    /// Publish even though a run is alive under this prefix: its loop takes
    /// the replayed samples as its own (a bench rig, never a machine).
    #[arg(long)]
    into_live_run: bool,
}

#[derive(clap::Subcommand)]
pub enum McapCommand {
    /// Summarize a recording: channels, schemas, counts, rates, gaps, metadata.
    Info {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Write the columns the model tools read: t,u,p_a,p_b,theta,theta_ref.
    ExportCsv {
        file: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
    /// Write the recording's CAN frames as a can-utils `candump -l` log, in
    /// the order they crossed the bus (times on the run's monotonic clock).
    ExportCandump {
        file: PathBuf,
        /// The log to write [default: standard output].
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// Attaches a recorder to the run already alive under this prefix.
pub fn record(args: RecordArgs) -> Result<()> {
    if args.duration.is_some_and(|d| !(d.is_finite() && d > 0.0)) {
        bail!("--duration must be a positive number of seconds");
    }
    quiet_ipc_logging();
    let scope = RunScope::from_env()?;
    let bus = Bus::open(&scope, "record")?;
    if !run_alive(&scope)? {
        bail!(
            "no run with prefix `{}` is alive: start one with `hydractl run` (or set {PREFIX_ENV})",
            scope.prefix()
        );
    }
    let binary = hydractl_bus::process_dir()?.join("recorder");
    let mut command = Command::new(&binary);
    if let Some(config) = &args.config {
        command.arg("--config").arg(config);
    }
    let mut recorder = command
        .args(args.split.recorder_args(&args.file)?)
        .env(PREFIX_ENV, scope.prefix())
        .stdin(Stdio::null())
        .spawn()
        .with_context(|| format!("starting {}", binary.display()))?;
    let started = Instant::now();
    let mut last_check = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(20));
        if recorder.try_wait()?.is_some() {
            bail!("the recorder stopped by itself; see its message above");
        }
        if bus.termination_requested() || args.duration.is_some_and(|d| started.elapsed().as_secs_f64() >= d) {
            break;
        }
        if last_check.elapsed() >= Duration::from_millis(500) {
            last_check = Instant::now();
            if !run_alive(&scope)? {
                tracing::info!("the run stopped; finishing the recording");
                break;
            }
        }
    }
    crate::run::stop_child(&mut recorder, "the recorder", Duration::from_secs(10))?;
    crate::emit(&format!(
        "recorded {:.1} s to {}\n",
        started.elapsed().as_secs_f64(),
        args.file.display()
    ))
}

fn run_alive(scope: &RunScope) -> Result<bool> {
    Ok(scope.live_node_names()?.iter().any(|n| n == "supervisor"))
}

/// Republishes a recording's samples on their services, paced by their
/// log times.
pub fn replay(args: ReplayArgs) -> Result<()> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        bail!("--speed must be a positive number, got {}", args.speed);
    }
    struct Entry {
        channel: usize,
        log_time_ns: u64,
        payload: Vec<u8>,
    }
    let mut topics: Vec<(String, &'static str)> = Vec::new();
    let mut entries = Vec::new();
    let outcome = read_messages(&args.file, |m| {
        if !args.topics.is_empty() && !args.topics.iter().any(|t| t == m.topic) {
            return Ok(());
        }
        let channel = match topics.iter().position(|(t, _)| t == m.topic) {
            Some(i) => i,
            None => {
                topics.push((m.topic.to_owned(), m.kind.type_name));
                topics.len() - 1
            }
        };
        entries.push(Entry {
            channel,
            log_time_ns: m.log_time_ns,
            payload: m.payload.to_vec(),
        });
        Ok(())
    })?;
    if let Some(why) = &outcome.truncated {
        tracing::warn!("{}: {why}", args.file.display());
    }
    for wanted in &args.topics {
        if !topics.iter().any(|(t, _)| t == wanted) {
            bail!("{}: no channel `{wanted}` to replay", args.file.display());
        }
    }
    // Files are ordered by chunk; playback is by log time.
    entries.sort_by_key(|e| e.log_time_ns);
    quiet_ipc_logging();
    let scope = RunScope::from_env()?;
    if run_alive(&scope)? && !args.into_live_run {
        bail!(
            "a run is alive under the prefix `{}`: replaying into it would feed its loop old samples as its own \
             (set {} to a prefix of the replay's own, or pass --into-live-run on a bench rig)",
            scope.prefix(),
            hydractl_bus::PREFIX_ENV
        );
    }
    let bus = Bus::open(&scope, "replay")?;
    let outlets: Vec<Box<dyn Republisher>> = topics
        .iter()
        .map(|(topic, type_name)| {
            republisher(&bus, topic, type_name)
                .with_context(|| format!("no sample type for {topic}"))?
                .with_context(|| format!("publishing on {topic}"))
        })
        .collect::<Result<_>>()?;
    let Some(first) = entries.first().map(|e| e.log_time_ns) else {
        return crate::emit("nothing to replay\n");
    };
    let started = Instant::now();
    let mut published = 0u64;
    for entry in &entries {
        let due = Duration::from_secs_f64(entry.log_time_ns.saturating_sub(first) as f64 * 1e-9 / args.speed);
        let wait = due.saturating_sub(started.elapsed());
        if !wait.is_zero() && bus.node().wait(wait).is_err() {
            break;
        }
        outlets[entry.channel].publish(&entry.payload)?;
        published += 1;
    }
    crate::emit(&format!(
        "replayed {published} messages on {} services in {:.2} s (prefix `{}`)\n",
        topics.len(),
        started.elapsed().as_secs_f64(),
        scope.prefix()
    ))
}

pub fn mcap(command: McapCommand) -> Result<()> {
    match command {
        McapCommand::Info { file, json } => {
            let summary = summarize(&file)?;
            if json {
                return crate::emit(&(serde_json::to_string_pretty(&summary)? + "\n"));
            }
            let mut text = format!(
                "{}: {} messages, {:.3} s, {} bytes{}\n",
                summary.path,
                summary.messages,
                summary.duration_s,
                summary.bytes,
                summary
                    .truncated
                    .as_deref()
                    .map(|t| format!("\n  cut short: {t}"))
                    .unwrap_or_default()
            );
            for (key, value) in &summary.metadata {
                let first_line = value.lines().next().unwrap_or_default();
                let more = if value.lines().count() > 1 { " …" } else { "" };
                text += &format!("  metadata {key}: {first_line}{more}\n");
            }
            text += &format!(
                "  {:<32} {:<32} {:>9} {:>9} {:>8}\n",
                "channel", "schema", "messages", "rate Hz", "missing"
            );
            for c in &summary.channels {
                text += &format!(
                    "  {:<32} {:<32} {:>9} {:>9.1} {:>8}\n",
                    c.topic, c.schema, c.messages, c.rate_hz, c.missing
                );
            }
            crate::emit(&text)
        }
        McapCommand::ExportCandump { file, out } => export_candump(&file, out.as_deref()),
        McapCommand::ExportCsv { file, out } => {
            let export = exported(&file)?;
            write_csv(&export.rows, &out)?;
            crate::emit(&format!(
                "{} rows of {} (and the stages' {}) to {}\n",
                export.rows.len(),
                MODEL_COLUMNS.join(","),
                SIGNAL_COLUMNS.join(","),
                out.display()
            ))
        }
    }
}

fn export_candump(file: &Path, out: Option<&Path>) -> Result<()> {
    let mut frames = Vec::new();
    let read = hydractl_recording::read_messages(file, |m| {
        if hydractl_recording::is_can_frame(m.kind) {
            // The reader checked every frame's encoding.
            if let Ok(f) = hydractl_recording::decode_frame(m.payload) {
                frames.push(f);
            }
        }
        Ok(())
    })?;
    if let Some(why) = &read.truncated {
        tracing::warn!("{}: {why}", file.display());
    }
    if frames.is_empty() {
        bail!(
            "{}: no CAN frames recorded (no can_msgs/msg/Frame channel)",
            file.display()
        );
    }
    frames.sort_by_key(|f| f.time_ns);
    let mut log = String::new();
    for f in &frames {
        log += &hydractl_can::candump::line(f.time_ns, &f.interface, &f.frame);
        log.push('\n');
    }
    match out {
        Some(path) => {
            std::fs::write(path, &log).with_context(|| format!("cannot write {}", path.display()))?;
            tracing::info!("{} frames to {}", frames.len(), path.display());
            Ok(())
        }
        None => crate::emit(&log),
    }
}

/// The model tools' rows of a recording, saying on stderr what was made up.
fn exported(path: &Path) -> Result<hydractl_recording::Export> {
    let export = export_rows(path)?;
    if let Some(why) = &export.read.truncated {
        tracing::warn!("{}: {why}", path.display());
    }
    if export.after_loop > 0 {
        tracing::info!(
            "{}: the last {} reading(s) came after the loop last drove the valve (the stack stopping, or the valve held neutral to the end by a fault) and are left out",
            path.display(),
            export.after_loop
        );
    }
    if export.held > 0 {
        tracing::warn!(
            "{}: {} of {} readings have no recorded command or reference (the stage skipped them); the previous one is held",
            path.display(),
            export.held,
            export.rows.len()
        );
    }
    Ok(export)
}

/// Measured data for the model and identification tools: a CSV, or a
/// recording (`.mcap`), read as the columns `mcap export-csv` writes.
pub fn load_dataset(path: &Path, required: &[&str]) -> Result<Dataset> {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mcap")) {
        let rows = exported(path)?.rows;
        let values: Vec<_> = rows.iter().map(hydractl_recording::ModelRow::values).collect();
        let mut columns: Vec<(&str, Vec<f64>)> = MODEL_COLUMNS
            .iter()
            .chain(SIGNAL_COLUMNS.iter())
            .enumerate()
            .map(|(i, name)| (*name, values.iter().map(|v| v[i]).collect()))
            .collect();
        // A stage the run did not have is not a column of its data.
        columns.retain(|(_, c)| c.iter().any(|v| v.is_finite()));
        // A stage whose first sample came after the first reading leaves
        // the rows before it without a value (later ones carry the last):
        // the data starts where every required column has one.
        let required_columns: Vec<&Vec<f64>> = columns
            .iter()
            .filter(|(name, _)| required.contains(name))
            .map(|(_, c)| c)
            .collect();
        let first = (0..values.len())
            .find(|&k| required_columns.iter().all(|c| c[k].is_finite()))
            .unwrap_or(0);
        if first > 0 {
            tracing::info!(
                "{}: the first {first} reading(s) precede a required column's first value; the data starts after them",
                path.display()
            );
            for (_, column) in &mut columns {
                column.drain(..first);
            }
        }
        keep_longest_measured_stretch(path, &mut columns);
        let data = Dataset::from_columns(&path.display().to_string(), columns);
        for name in required {
            data.column(name)?;
        }
        return Ok(data);
    }
    Ok(Dataset::from_csv(path, required)?)
}

/// The sensors' columns: a reading without one of them (a CAN PDO past its
/// deadline, a node stopping) has nothing to compare the model with.
const MEASURED_COLUMNS: [&str; 3] = ["theta", "p_a", "p_b"];

/// A recording's readings where a measured sensor has no value (NaN) are
/// left out: the data keeps its longest stretch in which every measured
/// sensor has one, and says how many readings that left out and where.
/// (The model tools need evenly spaced samples; a record too short after
/// this is refused by them, naming its length.)
fn keep_longest_measured_stretch(path: &Path, columns: &mut [(&str, Vec<f64>)]) {
    let measured: Vec<&Vec<f64>> = columns
        .iter()
        .filter(|(name, _)| MEASURED_COLUMNS.contains(name))
        .map(|(_, c)| c)
        .collect();
    let Some(n) = measured.first().map(|c| c.len()) else {
        return;
    };
    let complete = |k: usize| measured.iter().all(|c| c[k].is_finite());
    let missing: Vec<usize> = (0..n).filter(|&k| !complete(k)).collect();
    if missing.is_empty() {
        return;
    }
    // The stretches between missing readings; the longest is kept.
    let mut best = 0..0;
    let mut from = 0;
    for &k in missing.iter().chain(std::iter::once(&n)) {
        if k - from > best.len() {
            best = from..k;
        }
        from = k + 1;
    }
    let t = columns.iter().find(|(name, _)| *name == "t").map(|(_, c)| c.clone());
    let at = |k: usize| t.as_ref().map_or(f64::NAN, |t| t[k.min(n - 1)]);
    let shown: Vec<String> = missing.iter().take(5).map(|&k| format!("{:.3} s", at(k))).collect();
    tracing::warn!(
        "{}: {} reading(s) have no value from a sensor (at {}{}); the data keeps the longest stretch without one, \
         {:.3} s to {:.3} s ({} of {} readings)",
        path.display(),
        missing.len(),
        shown.join(", "),
        if missing.len() > shown.len() { ", …" } else { "" },
        at(best.start),
        at(best.end.saturating_sub(1)),
        best.len(),
        n
    );
    for (_, column) in columns.iter_mut() {
        column.truncate(best.end);
        column.drain(..best.start);
    }
}
