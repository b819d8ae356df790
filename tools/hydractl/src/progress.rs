//! How far long work is, on a terminal: a bar on stderr while the model is
//! fitted, and nothing at all when stderr is not a terminal or the output
//! is JSON, so that scripts and logs see only the result.

use std::io::IsTerminal;
use std::time::Duration;

use hydractl_ident::greybox;
use indicatif::{ProgressBar, ProgressStyle};

/// A progress bar that draws only where a person watches.
pub struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// A bar for `task` (`diagnose`, `fit`, …); hidden under `--json` or
    /// when stderr is not a terminal.
    pub fn new(task: &str, json: bool) -> Self {
        if json || !std::io::stderr().is_terminal() {
            return Self {
                bar: ProgressBar::hidden(),
            };
        }
        let bar = ProgressBar::new(0);
        let style = ProgressStyle::with_template("{spinner} {prefix} [{bar:24}] {pos}/{len} {msg} ({elapsed})")
            .map(|s| s.progress_chars("=> "))
            .unwrap_or_else(|_| ProgressStyle::default_bar());
        bar.set_style(style);
        bar.set_prefix(task.to_owned());
        bar.enable_steady_tick(Duration::from_millis(120));
        Self { bar }
    }

    /// Steps the tool itself drives: `done` of `total`, now doing `what`.
    pub fn step(&self, what: &str, done: usize, total: usize) {
        self.bar.set_length(total as u64);
        self.bar.set_position(done as u64);
        self.bar.set_message(what.to_owned());
    }
}

impl Progress {
    /// Prints `line` on stdout, the bar set aside while it is written.
    pub fn println(&self, line: &str) {
        self.bar.suspend(|| {
            // stdout closed by the reader: the result still goes to the file.
            let _ = crate::emit(&format!("{line}\n"));
        });
    }
}

impl greybox::Progress for Progress {
    fn fitted(&self, what: &str, done: usize, total: usize) {
        let message = if done == 0 {
            format!("fitting {what}")
        } else {
            format!("{what} fitted")
        };
        self.step(&message, done, total);
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}
