//! Log lines through `tracing`, one set-up per process at its start: text
//! on stderr for a terminal, the systemd journal with its fields for a
//! service. Nothing logs on a loop's cycle: what happens in a cycle is
//! counted and published, and the supervisor or `hydractl run` logs it.

use std::io::IsTerminal;

use hydractl_config::{LogConfig, LogOutput};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{EnvFilter, Layer};

/// The filter of a process's lines: `explicit` (`hydractl --log-level`),
/// else `RUST_LOG`, else the config's `[log] level`, else `info`. An
/// invalid filter is an error that names where it came from.
pub fn filter(explicit: Option<&str>, config: &LogConfig) -> Result<EnvFilter, String> {
    let from_env = std::env::var("RUST_LOG").ok().filter(|v| !v.trim().is_empty());
    let (text, source) = match (explicit, from_env, &config.level) {
        (Some(level), _, _) => (level.to_owned(), "--log-level"),
        (None, Some(level), _) => (level, "RUST_LOG"),
        (None, None, Some(level)) => (level.clone(), "[log] level"),
        (None, None, None) => ("info".to_owned(), "the default"),
    };
    EnvFilter::builder()
        .parse(&text)
        .map_err(|e| format!("{source} = {text:?} is not a log filter: {e}"))
}

/// Whether stderr is the journal's stream: systemd sets `JOURNAL_STREAM`
/// to its device and inode for a service whose output goes there.
fn stderr_is_journal() -> bool {
    let Some(stream) = std::env::var_os("JOURNAL_STREAM") else {
        return false;
    };
    let Some((dev, ino)) = stream.to_str().and_then(|s| s.split_once(':')) else {
        return false;
    };
    match nix::sys::stat::fstat(std::io::stderr()) {
        Ok(stat) => dev.parse() == Ok(stat.st_dev) && ino.parse() == Ok(stat.st_ino),
        Err(_) => false,
    }
}

/// Sets up the process's logging; `process` names it in every line (on
/// the journal as its `SYSLOG_IDENTIFIER`, beside the journal's own
/// `_PID`). Returns the span every line of the process is in.
pub fn init(process: &str, filter: EnvFilter, config: &LogConfig) -> tracing::span::EnteredSpan {
    let journal = match config.output {
        LogOutput::Terminal => None,
        LogOutput::Auto if !stderr_is_journal() => None,
        LogOutput::Auto | LogOutput::Journald => tracing_journald::layer().ok(),
    };
    let wanted_journal = config.output == LogOutput::Journald;
    let on_journal = journal.is_some();
    let journal = journal.map(|layer| layer.with_syslog_identifier(process.to_owned()).with_field_prefix(None));
    let text = (!on_journal).then(|| {
        tracing_subscriber::fmt::layer()
            .with_writer(std::io::stderr)
            .with_ansi(std::io::stderr().is_terminal())
            .with_target(false)
            .without_time()
    });
    // Only the first set-up of a process takes; there is only one.
    let _ = tracing_subscriber::registry()
        .with(filter)
        .with(journal.map(|j| j.boxed()))
        .with(text.map(|t| t.boxed()))
        .try_init();
    if wanted_journal && !on_journal {
        tracing::warn!("[log] output = \"journald\", but the journal's socket cannot be opened: logging to stderr");
    }
    tracing::info_span!("hydractl", process = %process, pid = std::process::id()).entered()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_filter_names_where_it_came_from_when_it_is_not_one() {
        let config = LogConfig {
            level: Some("debug".into()),
            output: LogOutput::Auto,
        };
        assert!(filter(Some("warn,hydractl=debug"), &config).is_ok());
        let error = filter(Some("warn,["), &config).expect_err("not a filter");
        assert!(error.starts_with("--log-level = \"warn,[\""), "{error}");
    }
}
