//! What `hydractl run` makes of the loop's samples: latency histograms,
//! the tracking error over the last second and since the start, the
//! processes' pids and restarts, and the live line that shows them.

use std::fmt::Write as _;

use hydractl_samples::{name_str, SupervisorStatus, UNKNOWN};

use super::{LatencySummary, ProcessSummary};

/// Sensor-to-valve latency, counted in 1 µs bins up to 100 ms: fixed
/// memory however long the run.
pub(super) struct LatencyHistogram {
    bins: Vec<u64>,
    count: u64,
    max_ns: u64,
}

impl LatencyHistogram {
    const BINS: usize = 100_000;

    pub(super) fn new() -> Self {
        Self {
            bins: vec![0; Self::BINS + 1],
            count: 0,
            max_ns: 0,
        }
    }

    pub(super) fn record_between(&mut self, from_ns: u64, to_ns: u64) {
        let ns = to_ns.saturating_sub(from_ns);
        let us = (ns / 1000) as usize;
        self.bins[us.min(Self::BINS)] += 1;
        self.count += 1;
        self.max_ns = self.max_ns.max(ns);
    }

    pub(super) fn summary(&self) -> LatencySummary {
        LatencySummary {
            p50: self.quantile_us(0.5),
            p99: self.quantile_us(0.99),
            p999: self.quantile_us(0.999),
            max: self.max_ns as f64 / 1000.0,
        }
    }

    /// The quantile in µs (upper edge of its bin).
    pub(super) fn quantile_us(&self, q: f64) -> f64 {
        if self.count == 0 {
            return f64::NAN;
        }
        let target = ((q * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (us, &n) in self.bins.iter().enumerate() {
            seen += n;
            if seen >= target {
                return (us + 1) as f64;
            }
        }
        self.max_ns as f64 / 1000.0
    }
}

/// The tracking error since the start and over the last second: fixed
/// memory (one second of samples) however long the run.
pub(super) struct Tracking {
    count: u64,
    sum_squares: f64,
    max_abs: f64,
    /// The last second's errors, a ring.
    recent: Vec<f64>,
    next: usize,
    filled: usize,
}

/// rms and max of a tracking error, rad.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct ErrorStats {
    pub(super) rms: f64,
    pub(super) max_abs: f64,
}

impl Tracking {
    /// `per_second`: the samples in one second (the control rate).
    pub(super) fn new(per_second: usize) -> Self {
        Self {
            count: 0,
            sum_squares: 0.0,
            max_abs: 0.0,
            recent: vec![0.0; per_second.max(1)],
            next: 0,
            filled: 0,
        }
    }

    pub(super) fn push(&mut self, error: f64) {
        self.count += 1;
        self.sum_squares += error * error;
        self.max_abs = self.max_abs.max(error.abs());
        self.recent[self.next] = error;
        self.next = (self.next + 1) % self.recent.len();
        self.filled = (self.filled + 1).min(self.recent.len());
    }

    /// Errors pushed since the start.
    pub(super) fn count(&self) -> u64 {
        self.count
    }

    pub(super) fn since_start(&self) -> ErrorStats {
        ErrorStats {
            rms: (self.sum_squares / self.count.max(1) as f64).sqrt(),
            max_abs: self.max_abs,
        }
    }

    pub(super) fn last_second(&self) -> ErrorStats {
        let recent = &self.recent[..self.filled];
        ErrorStats {
            rms: (recent.iter().map(|e| e * e).sum::<f64>() / recent.len().max(1) as f64).sqrt(),
            max_abs: recent.iter().fold(0.0, |m, e| m.max(e.abs())),
        }
    }
}

/// What the live line shows, twice a second.
pub(super) struct LiveLine {
    pub(super) elapsed_s: f64,
    pub(super) loop_hz: f64,
    pub(super) misses: u64,
    pub(super) p99_us: f64,
    pub(super) last_second: ErrorStats,
    pub(super) since_start: ErrorStats,
    pub(super) restarts: u32,
    /// With a machine expected: whether the loop now runs on the simulated
    /// plant instead. `None`: no machine, the simulated plant is the plant.
    pub(super) on_simulation: Option<bool>,
    /// With a shadow model: its worst output's fit over the last window,
    /// percent (NaN before the first window).
    pub(super) model_fit: Option<f64>,
}

impl LiveLine {
    /// The two header lines, printed once before the first live line.
    pub(super) fn header(machine_expected: bool, shadow: bool) -> String {
        let plant = match (machine_expected, shadow) {
            (true, true) => "  plant     ",
            (true, false) => "  plant",
            (false, _) => "",
        };
        let model = if shadow { " fit %" } else { "" };
        format!(
            "{:<35}{:^35}\n{:>8}{:>9}{:>8}{:>8}  {:>8}{:>9}{:>9}{:>9}{:>10}{plant}{model}",
            "",
            "tracking error, rad",
            "time s",
            "loop Hz",
            "misses",
            "p99 µs",
            "rms 1 s",
            "max 1 s",
            "rms all",
            "max all",
            "restarts"
        )
    }

    pub(super) fn render(&self) -> String {
        let mut line = format!(
            "{:>8.1}{:>9.0}{:>8}{:>8.0}  {:>8.4}{:>9.4}{:>9.4}{:>9.4}{:>10}",
            self.elapsed_s,
            self.loop_hz,
            self.misses,
            self.p99_us,
            self.last_second.rms,
            self.last_second.max_abs,
            self.since_start.rms,
            self.since_start.max_abs,
            self.restarts
        );
        if let Some(on_simulation) = self.on_simulation {
            let plant = if on_simulation { "SIMULATION" } else { "machine" };
            // Padded only when a column follows it.
            let width = if self.model_fit.is_some() { 10 } else { 0 };
            let _ = write!(line, "  {plant:<width$}");
        }
        if let Some(fit) = self.model_fit {
            let _ = write!(line, "{fit:>6.1}");
        }
        line
    }
}

/// Adds newly seen pids and the restart counts from a status sample.
pub(super) fn merge_status(processes: &mut Vec<ProcessSummary>, status: &SupervisorStatus) {
    for entry in status.processes.iter().take(status.process_count as usize) {
        let name = name_str(&entry.name);
        if name == "supervisor" {
            continue;
        }
        let index = match processes.iter().position(|p| p.name == name) {
            Some(i) => i,
            None => {
                processes.push(ProcessSummary {
                    name: name.to_owned(),
                    ..ProcessSummary::default()
                });
                processes.len() - 1
            }
        };
        let p = &mut processes[index];
        if entry.pid != 0 && p.pids.last() != Some(&entry.pid) {
            p.pids.push(entry.pid);
        }
        p.restarts = entry.restarts;
        if entry.pid != 0 && entry.page_faults_after_start != UNKNOWN {
            let count = (
                entry.pid,
                u64::from(entry.page_faults_after_start),
                entry.memory_locked != 0,
            );
            match p.faults_by_pid.iter_mut().find(|(pid, _, _)| *pid == entry.pid) {
                Some(known) => *known = count,
                None => p.faults_by_pid.push(count),
            }
            p.page_faults_after_start = Some(p.faults_by_pid.iter().map(|(_, n, _)| n).sum());
            p.memory_locked = Some(p.faults_by_pid.iter().all(|(_, _, locked)| *locked));
        }
    }
}

/// The supervisor's own liveness, by its status (published every 100 ms):
/// while it is silent, its rounds (restarts, the fault account, swaps)
/// have stopped and the loop runs on unwatched. As a service, systemd's
/// watchdog acts on that; under `hydractl run`, the run says so.
#[derive(Debug, Default)]
pub(super) struct SupervisorSilence {
    /// The newest status's own timestamp; none before the first.
    last_status_ns: Option<u64>,
    /// The silence said on the terminal, not yet over.
    said: bool,
    pub(super) longest_ns: u64,
}

/// Silent this long, the supervisor is said to have stopped.
const SUPERVISOR_SILENT_NS: u64 = 1_000_000_000;

impl SupervisorSilence {
    /// A status sample, stamped `stage_time_ns`.
    pub(super) fn status(&mut self, stage_time_ns: u64, now_ns: u64) {
        if self.last_status_ns.is_some_and(|last| stage_time_ns > last) && self.said {
            tracing::info!(
                "the supervisor reports again, after {} ms",
                now_ns.saturating_sub(self.last_status_ns.unwrap_or(now_ns)) / 1_000_000
            );
            self.said = false;
        }
        if let Some(last) = self.last_status_ns {
            self.longest_ns = self.longest_ns.max(stage_time_ns.saturating_sub(last));
        }
        self.last_status_ns = Some(
            self.last_status_ns
                .map_or(stage_time_ns, |last| last.max(stage_time_ns)),
        );
    }

    /// Once a round: whether the silence is new and long enough to say.
    pub(super) fn check(&mut self, now_ns: u64) -> Option<u64> {
        let silent_ns = now_ns.saturating_sub(self.last_status_ns?);
        self.longest_ns = self.longest_ns.max(silent_ns);
        (silent_ns >= SUPERVISOR_SILENT_NS && !std::mem::replace(&mut self.said, true)).then_some(silent_ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_the_upper_edges_of_their_microsecond_bins() {
        let mut h = LatencyHistogram::new();
        for us in 1..=100u64 {
            h.record_between(0, us * 1000 - 500);
        }
        assert_eq!(h.quantile_us(0.5), 50.0);
        assert_eq!(h.quantile_us(0.99), 99.0);
        assert!(
            LatencyHistogram::new().quantile_us(0.5).is_nan(),
            "no sample, no quantile"
        );
    }

    #[test]
    fn the_last_second_forgets_what_the_whole_run_remembers() {
        let mut t = Tracking::new(4);
        t.push(1.0);
        for _ in 0..4 {
            t.push(0.5);
        }
        assert_eq!(t.last_second(), ErrorStats { rms: 0.5, max_abs: 0.5 });
        assert_eq!(t.since_start().max_abs, 1.0);
        assert!((t.since_start().rms - (2.0f64 / 5.0).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn the_live_line_fits_100_columns_and_sits_under_its_header() {
        let worst = LiveLine {
            elapsed_s: 86_399.9,
            loop_hz: 1000.0,
            misses: 9_999_999,
            p99_us: 99_999.0,
            last_second: ErrorStats {
                rms: 9.9999,
                max_abs: 9.9999,
            },
            since_start: ErrorStats {
                rms: 9.9999,
                max_abs: 9.9999,
            },
            restarts: 999_999,
            on_simulation: Some(true),
            model_fit: None,
        };
        let line = worst.render();
        assert!(line.chars().count() <= 100, "{} columns: {line}", line.chars().count());
        assert!(line.ends_with("SIMULATION"));
        let header = LiveLine::header(true, false);
        for h in header.lines() {
            assert!(h.chars().count() <= 100, "{h}");
        }
        assert_eq!(
            header.lines().nth(1).map(|h| h.chars().count()),
            Some(line.chars().count() - "SIMULATION".len() + "plant".len()),
            "each value under its label"
        );
        let shadowed = LiveLine {
            model_fit: Some(-100.0),
            ..worst
        };
        let with_fit = shadowed.render();
        let header = LiveLine::header(true, true);
        assert!(with_fit.chars().count() <= 100, "{with_fit}");
        assert_eq!(
            header.lines().nth(1).map(|h| h.chars().count()),
            Some(with_fit.chars().count()),
            "the fit under its label: {with_fit}"
        );
        let plain = LiveLine {
            on_simulation: None,
            ..worst
        };
        assert!(
            !plain.render().contains("SIMULATION"),
            "no machine expected: nothing to warn of"
        );
    }

    #[test]
    fn a_silence_is_said_once_and_its_longest_kept() {
        let ms = 1_000_000;
        let mut silence = SupervisorSilence::default();
        assert_eq!(silence.check(5_000 * ms), None, "nothing before the first status");
        silence.status(100 * ms, 100 * ms);
        assert_eq!(silence.check(900 * ms), None);
        assert_eq!(silence.check(1_200 * ms), Some(1_100 * ms));
        assert_eq!(silence.check(1_300 * ms), None, "said once");
        silence.status(1_400 * ms, 1_400 * ms);
        assert_eq!(silence.check(1_450 * ms), None);
        assert_eq!(silence.longest_ns, 1_300 * ms, "from status to status");
    }
}
