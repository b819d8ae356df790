//! `[log]` and `[recording]`: what a run on the vehicle writes, and where.

use serde::{Deserialize, Serialize};

/// `[log]`: the processes' log lines.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct LogConfig {
    /// A `tracing` filter (`info`, `warn,hydractl=debug`); `RUST_LOG` and
    /// `hydractl --log-level` come before it. None: `info`.
    pub level: Option<String>,
    pub output: LogOutput,
}

/// Where log lines go.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum LogOutput {
    /// The systemd journal, with fields, when stderr is connected to it
    /// (a service); else stderr as text.
    #[default]
    Auto,
    /// stderr as text, also under systemd.
    Terminal,
    /// The journal; stderr as text where there is none.
    Journald,
}

/// `[recording]`: a run's recording, when it records.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct RecordingConfig {
    /// Record every run to this MCAP file (its parts beside it), as the
    /// vehicle's flight recorder does; `hydractl run --record` comes first.
    pub out: Option<std::path::PathBuf>,
    /// Start a new part every this many MB (`--split-size-mb` comes first).
    pub split_size_mb: Option<f64>,
    /// Start a new part every this many seconds (`--split-duration-s` comes first).
    pub split_duration_s: Option<f64>,
    /// Keep at most this many MB of split files: the oldest part is
    /// deleted before a new one would pass it, as a flight recorder does.
    /// Needs a split (`split_size_mb` or `split_duration_s`); `hydractl
    /// run --keep-mb` comes before it. None: keep everything.
    pub keep_mb: Option<f64>,
}

/// `[shadow]`: a fitted model run beside the machine, watching it drift.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShadowConfig {
    /// The model file (`hydractl model fit`/`add`), relative to this
    /// config's folder. None: no shadow process.
    pub model: Option<std::path::PathBuf>,
    /// Where the model the shadow goes on with after a named drift is
    /// written, each time, for `hydractl model compensate`; relative to
    /// this config's folder. None: kept in the process only.
    pub learned: Option<std::path::PathBuf>,
    /// The sliding window the model is compared over, s.
    pub window_s: f64,
    /// How often it is compared, s (a multiple of the 0.5 s segment).
    pub every_s: f64,
    /// After a drift alarm, seconds of data the diagnosis of what changed
    /// is run on, all from after the alarm.
    pub diagnose_s: f64,
}

impl Default for ShadowConfig {
    fn default() -> Self {
        Self {
            model: None,
            learned: None,
            window_s: 5.0,
            every_s: 1.0,
            diagnose_s: 15.0,
        }
    }
}
