//! `hydractl record`, `replay`, `mcap info`, `mcap export-csv`, and the
//! model tools' reading of a recording.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use hydractl_bus::{quiet_ipc_logging, Bus, RunScope, PREFIX_ENV};
use hydractl_ident::Dataset;
use hydractl_processes::recording::{republisher, Republisher};
use hydractl_recording::{export_rows_in, read_messages, summarize, write_csv, Window, MODEL_COLUMNS, SIGNAL_COLUMNS};

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
    /// Write the model tools' columns (t,u,p_a,p_b,theta,theta_ref) and the stages' signals.
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
                    .map(|t| format!("\n  not read whole: {t}"))
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
            let export = exported(&file, None)?;
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
fn exported(path: &Path, window: Option<Window>) -> Result<hydractl_recording::Export> {
    let export = export_rows_in(path, window)?;
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
    if let Some(from_s) = export.simulated_from_s {
        tracing::warn!(
            "{}: {} reading(s) from {from_s:.3} s on came from the simulated plant standing in for the machine and are left out: they are not the machine's",
            path.display(),
            export.simulated
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

/// Whether `path` names a recording (`.mcap`) rather than a CSV.
pub fn is_recording(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}

/// What the tools reading a recording do across its long gaps of
/// missing readings (short ones are bridged either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gaps {
    /// Keep the longest stretch without one: for the tools that simulate
    /// the record from end to end (`ident tf`, `ident hinf`).
    KeepLongestStretch,
    /// Leave the readings out, the time stamps telling where: for the
    /// grey-box model, whose shooting segments restart after each gap.
    LeaveOut,
}

/// Measured data for the identification tools: a CSV, or a recording
/// (`.mcap`), read as the columns `mcap export-csv` writes.
pub fn load_dataset(path: &Path, required: &[&str]) -> Result<Dataset> {
    load_dataset_in(path, required, None, Gaps::KeepLongestStretch)
}

/// [`load_dataset`] of a stretch of the record: a recording's through its
/// chunk index, reading only the chunks the window overlaps.
pub fn load_dataset_in(path: &Path, required: &[&str], window: Option<Window>, gaps: Gaps) -> Result<Dataset> {
    if is_recording(path) {
        let rows = exported(path, window)?.rows;
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
        mend_missing_readings(path, &mut columns, gaps);
        let data = Dataset::from_columns(&path.display().to_string(), columns);
        for name in required {
            data.column(name)?;
        }
        return Ok(data);
    }
    let data = Dataset::from_csv(path, required)?;
    Ok(match window {
        Some(w) => data.window(w.from_s, w.to_s)?,
        None => data,
    })
}

/// The sensors' columns: a reading without one of them (a CAN PDO past its
/// deadline, a node stopping) has nothing to compare the model with.
const MEASURED_COLUMNS: [&str; 3] = ["theta", "p_a", "p_b"];

/// A gap of missing readings this long or shorter (a PDO or two past its
/// deadline) is bridged; a longer one (a node lost) is not.
const MAX_BRIDGED_READINGS: usize = 20;

/// A recording's readings where a measured sensor has no value (NaN): a
/// gap of at most [`MAX_BRIDGED_READINGS`] between two readings with one is
/// bridged by linear interpolation (at 1 kHz a few milliseconds, far
/// shorter than anything the model resolves); the longer gaps are left
/// out or cut at, as `gaps` says. All of it is said, with where. (A record
/// too short after this is refused by the tools, naming its length.)
fn mend_missing_readings(path: &Path, columns: &mut [(&str, Vec<f64>)], gaps: Gaps) {
    let n = columns.first().map_or(0, |(_, c)| c.len());
    let missing = incomplete_readings(columns);
    if missing.is_empty() {
        return;
    }
    let t = columns.iter().find(|(name, _)| *name == "t").map(|(_, c)| c.clone());
    let at = |k: usize| t.as_ref().map_or(f64::NAN, |t| t[k.min(n - 1)]);
    let shown: Vec<String> = missing.iter().take(5).map(|&k| format!("{:.3} s", at(k))).collect();
    let bridged = bridge_short_gaps(columns);
    let missing = incomplete_readings(columns);
    let said = format!(
        "{}: {} reading(s) have no value from a sensor (at {}{})",
        path.display(),
        missing.len() + bridged,
        shown.join(", "),
        if missing.len() + bridged > shown.len() {
            ", …"
        } else {
            ""
        },
    );
    if missing.is_empty() {
        tracing::warn!(
            "{said}; each gap, at most {MAX_BRIDGED_READINGS} readings long, is bridged by linear interpolation"
        );
        return;
    }
    let bridged_said =
        format!("{bridged} in gaps of at most {MAX_BRIDGED_READINGS} readings are bridged by linear interpolation");
    match gaps {
        Gaps::LeaveOut => {
            let runs = runs_of(&missing);
            let listed: Vec<String> = runs
                .iter()
                .take(5)
                .map(|r| format!("{:.3}–{:.3} s", at(r.start), at(r.end - 1)))
                .collect();
            tracing::warn!(
                "{said}; {bridged_said}; the other {} are left out, in {} gap(s) ({}{}), and the model's segments restart after each",
                missing.len(),
                runs.len(),
                listed.join(", "),
                if runs.len() > listed.len() { ", …" } else { "" }
            );
            let mut left_out = vec![false; n];
            for &k in &missing {
                left_out[k] = true;
            }
            for (_, column) in columns.iter_mut() {
                let mut k = 0;
                column.retain(|_| {
                    k += 1;
                    !left_out[k - 1]
                });
            }
        }
        Gaps::KeepLongestStretch => {
            let mut best = 0..0;
            let mut from = 0;
            for &k in missing.iter().chain(std::iter::once(&n)) {
                if k - from > best.len() {
                    best = from..k;
                }
                from = k + 1;
            }
            tracing::warn!(
                "{said}; {bridged_said}; across the longer gaps the data keeps the longest stretch, {:.3} s to {:.3} s ({} of {} readings)",
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
    }
}

/// The readings where a measured sensor has no value.
fn incomplete_readings(columns: &[(&str, Vec<f64>)]) -> Vec<usize> {
    let measured: Vec<&Vec<f64>> = columns
        .iter()
        .filter(|(name, _)| MEASURED_COLUMNS.contains(name))
        .map(|(_, c)| c)
        .collect();
    let n = measured.first().map_or(0, |c| c.len());
    (0..n).filter(|&k| measured.iter().any(|c| !c[k].is_finite())).collect()
}

/// Ascending indices grouped into runs of consecutive ones.
fn runs_of(indices: &[usize]) -> Vec<std::ops::Range<usize>> {
    let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
    for &k in indices {
        match runs.last_mut() {
            Some(run) if run.end == k => run.end = k + 1,
            _ => runs.push(k..k + 1),
        }
    }
    runs
}

/// Fills each column's runs of NaN no longer than [`MAX_BRIDGED_READINGS`]
/// with a value on the line between its finite neighbours: the sensors'
/// and what the stages derived from the same readings (the torque, the
/// velocity estimate). Returns how many readings that completed.
fn bridge_short_gaps(columns: &mut [(&str, Vec<f64>)]) -> usize {
    let n = columns.first().map_or(0, |(_, c)| c.len());
    let before = incomplete_readings(columns).len();
    for (_, column) in columns.iter_mut().filter(|(name, _)| *name != "t") {
        let mut k = 0;
        while k < n {
            if column[k].is_finite() {
                k += 1;
                continue;
            }
            let end = (k..n).find(|&j| column[j].is_finite()).unwrap_or(n);
            if k > 0 && end < n && end - k <= MAX_BRIDGED_READINGS {
                let (a, b) = (column[k - 1], column[end]);
                let span = (end - k + 1) as f64;
                for (i, value) in column[k..end].iter_mut().enumerate() {
                    *value = a + (b - a) * (i + 1) as f64 / span;
                }
            }
            k = end;
        }
    }
    before - incomplete_readings(columns).len()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Readings around a short gap and before a long one.
    fn gappy_columns() -> Vec<(&'static str, Vec<f64>)> {
        let nan = f64::NAN;
        let mut theta = vec![0.0, 1.0, nan, nan, 4.0, 5.0];
        theta.extend(std::iter::repeat_n(nan, MAX_BRIDGED_READINGS + 1));
        theta.extend([9.0, 9.0]);
        let t: Vec<f64> = (0..theta.len()).map(|k| k as f64 * 0.001).collect();
        let torque = theta.iter().map(|v| 10.0 * v).collect();
        vec![("t", t), ("theta", theta), ("torque", torque), ("u", vec![0.5; 29])]
    }

    #[test]
    fn a_short_gap_is_bridged_and_a_long_one_cut_at() {
        let mut columns = gappy_columns();
        mend_missing_readings(Path::new("run.mcap"), &mut columns, Gaps::KeepLongestStretch);
        // The two readings between 1 and 4 lie on the line, and what was
        // derived from them too; the stretch before the long gap is the
        // longest kept.
        assert_eq!(columns[1].1, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
        assert_eq!(columns[2].1, vec![0.0, 10.0, 20.0, 30.0, 40.0, 50.0]);
        assert_eq!(columns[0].1.len(), 6);
    }

    #[test]
    fn a_long_gap_is_left_out_and_the_time_stamps_say_where() {
        let mut columns = gappy_columns();
        mend_missing_readings(Path::new("run.mcap"), &mut columns, Gaps::LeaveOut);
        assert_eq!(columns[1].1, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 9.0, 9.0]);
        assert_eq!(columns[3].1.len(), 8);
        let t = &columns[0].1;
        assert!((t[6] - t[5] - 0.022).abs() < 1e-12, "{t:?}");
    }

    #[test]
    fn consecutive_indices_make_one_run() {
        assert_eq!(runs_of(&[2, 3, 4, 9, 11, 12]), vec![2..5, 9..10, 11..13]);
    }
}
