//! A fault's account: what stopped or misbehaved, when it was found, and
//! the judgements behind it (hung, and who is blamed for garbage).

use hydractl_samples::code::EventKind;
use std::time::{Duration, Instant};

use hydractl_config::OnLimitCycle;

/// A process that crashed, hung or misbehaved, until it is back.
#[derive(Debug, Clone, Copy)]
pub(super) struct Fault {
    pub(super) kind: EventKind,
    pub(super) pid: u32,
    pub(super) detected_at: Instant,
    /// From its last output to the detection.
    pub(super) silent_for: Duration,
    /// The last reading it answered.
    pub(super) last_seq: Option<u64>,
    /// A controller restarted for misbehaving: its variant, and the one it
    /// was restarted into.
    pub(super) variants: Option<(&'static str, &'static str)>,
    /// Periods the valve held its last command, once known.
    pub(super) valve_safe_after: Option<u64>,
}

/// What the supervisor knows of a running process when it judges a hang.
#[derive(Debug, Clone, Copy)]
pub(super) struct Liveness {
    pub(super) uptime: Duration,
    /// Its input flows: its producer answered within half of `hung_after`
    /// (the plant paces itself, so its input always flows).
    pub(super) input_flowing: bool,
    /// Since its last output, or since its input came back after a pause,
    /// whichever is later.
    pub(super) quiet_for: Duration,
}

/// A process is hung when it has had its start-up grace, its input flows
/// and it has said nothing for `hung_after`. A process whose input paused
/// is waiting, not hung: the quiet is counted from the input's return.
pub(super) fn is_hung(liveness: Liveness, startup_grace: Duration, hung_after: Duration) -> bool {
    liveness.uptime > startup_grace && liveness.input_flowing && liveness.quiet_for > hung_after
}

/// What the kernel counts of a process's main thread since it started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct CpuTimes {
    /// On its CPU, ns (`/proc/PID/schedstat`).
    pub(super) run_ns: u64,
    /// Runnable and waiting for the CPU, ns.
    pub(super) wait_ns: u64,
    /// Times it gave up the CPU to sleep (`voluntary_ctxt_switches`).
    pub(super) sleeps: u64,
}

/// A process's [`CpuTimes`]; `None` once it is gone.
pub(super) fn cpu_times(pid: u32) -> Option<CpuTimes> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/schedstat")).ok()?;
    let mut fields = text.split_ascii_whitespace().map(|f| f.parse::<u64>().ok());
    let (run_ns, wait_ns) = (fields.next()??, fields.next()??);
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let sleeps = status
        .lines()
        .find_map(|line| line.strip_prefix("voluntary_ctxt_switches:"))?
        .trim()
        .parse()
        .ok()?;
    Some(CpuTimes {
        run_ns,
        wait_ns,
        sleeps,
    })
}

/// How a process used its CPU over the supervisor's last rounds: a stage
/// of the loop needs a few per cent of it; one that takes more than its
/// share for long, never sleeping, spins (a busy loop at the loop's
/// priority starves every process beside it, and only the CPU time says
/// which one it is); one that wanted the CPU and did not get it is starved,
/// not hung. A process that slept in a round is not spinning, whatever its
/// time: without the kernel's interrupt time accounting, the interrupts
/// served while it ran are counted as its own.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct CpuWatch {
    last: Option<(u32, Instant, CpuTimes)>,
    /// How long it has used more than its share, without a break.
    pub(super) busy_for: Duration,
    /// How long it has waited for the CPU more than half the time.
    pub(super) starved_for: Duration,
}

impl CpuWatch {
    /// Takes process `pid`'s CPU times at `now`; a new pid starts afresh.
    pub(super) fn update(&mut self, pid: u32, now: Instant, times: Option<CpuTimes>, share: f64) {
        let Some(times) = times else {
            *self = Self::default();
            return;
        };
        if let Some((_, at, last)) = self.last.filter(|l| l.0 == pid) {
            let elapsed = now.saturating_duration_since(at);
            let elapsed_ns = elapsed.as_nanos().max(1) as f64;
            let ran = times.run_ns.saturating_sub(last.run_ns) as f64 / elapsed_ns;
            let waited = times.wait_ns.saturating_sub(last.wait_ns) as f64 / elapsed_ns;
            let slept = times.sleeps > last.sleeps;
            self.busy_for = if ran > share && !slept {
                self.busy_for + elapsed
            } else {
                Duration::ZERO
            };
            self.starved_for = if waited > 0.5 {
                self.starved_for + elapsed
            } else {
                Duration::ZERO
            };
        } else {
            self.busy_for = Duration::ZERO;
            self.starved_for = Duration::ZERO;
        }
        self.last = Some((pid, now, times));
    }
}

/// How a controller stopped for limit-cycling comes back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Comeback {
    /// Restarted into `variant`, no sooner than `after` (beyond the usual
    /// restart back-off).
    Restart {
        variant: &'static str,
        after: Duration,
    },
    LeaveDown,
}

/// The papers' baseline: PID, in both loops.
const BASELINE: &str = "pid";

/// A controller running `running` limit-cycled for the `bursts`-th time:
/// the configured fallback variant if it is another; else, by
/// `on_limit_cycle`, the baseline PID, the same variant after a wait
/// doubled at every burst (also when the baseline itself limit-cycles), or
/// nothing. Never the same behaviour again at once.
pub(super) fn after_limit_cycle(
    on_limit_cycle: OnLimitCycle,
    running: &'static str,
    fallback: Option<&'static str>,
    bursts: u32,
    backoff: Duration,
) -> Comeback {
    let backing_off = Comeback::Restart {
        variant: running,
        after: backoff.saturating_mul(1 << bursts.saturating_sub(1).min(16)),
    };
    match (fallback.filter(|&f| f != running), on_limit_cycle) {
        (Some(variant), _) => Comeback::Restart {
            variant,
            after: Duration::ZERO,
        },
        (None, OnLimitCycle::Stop) => Comeback::LeaveDown,
        (None, OnLimitCycle::Baseline) if running != BASELINE => Comeback::Restart {
            variant: BASELINE,
            after: Duration::ZERO,
        },
        (None, OnLimitCycle::Baseline | OnLimitCycle::Backoff) => backing_off,
    }
}

/// The pipeline index of the controller blamed when the valve keeps
/// rejecting commands: the outer loop (3) when its own output is garbage,
/// limit-cycles itself (the inner loop only follows its reference), or
/// drives the valve (the torque stage bypassed), else the torque stage (4),
/// which feeds the valve.
pub(super) fn blamed_for_rejections(
    position_output_finite: bool,
    position_output_limit_cycling: bool,
    torque_bypassed: bool,
) -> usize {
    if !position_output_finite || position_output_limit_cycling || torque_bypassed {
        3
    } else {
        4
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GRACE: Duration = Duration::from_millis(500);
    const HUNG: Duration = Duration::from_millis(50);

    fn alive(uptime_ms: u64, input_flowing: bool, quiet_ms: u64) -> Liveness {
        Liveness {
            uptime: Duration::from_millis(uptime_ms),
            input_flowing,
            quiet_for: Duration::from_millis(quiet_ms),
        }
    }

    #[test]
    fn a_process_is_hung_only_past_its_grace_with_its_input_flowing_and_quiet_too_long() {
        assert!(is_hung(alive(1000, true, 51), GRACE, HUNG));
        assert!(
            !is_hung(alive(1000, true, 50), GRACE, HUNG),
            "exactly hung_after is not yet"
        );
        assert!(!is_hung(alive(400, true, 400), GRACE, HUNG), "still starting");
        assert!(
            !is_hung(alive(1000, false, 400), GRACE, HUNG),
            "waiting for an input that stopped is not a hang"
        );
    }

    #[test]
    fn a_process_over_its_cpu_share_without_a_break_spins_and_one_kept_waiting_is_starved() {
        let t0 = Instant::now();
        let ms = |n: u64| t0 + Duration::from_millis(n);
        let times = |run_ns: u64, wait_ns: u64, sleeps: u64| {
            Some(CpuTimes {
                run_ns,
                wait_ns,
                sleeps,
            })
        };
        let mut watch = CpuWatch::default();
        watch.update(7, ms(0), times(0, 0, 10), 0.5);
        // 5 ms rounds: 4.5 ms on the CPU in each, never sleeping.
        for k in 1..=4u64 {
            watch.update(7, ms(5 * k), times(k * 4_500_000, 0, 10), 0.5);
        }
        assert_eq!(watch.busy_for, Duration::from_millis(20));
        // A round at its usual few per cent: the streak ends.
        watch.update(7, ms(25), times(18_100_000, 0, 15), 0.5);
        assert_eq!(watch.busy_for, Duration::ZERO);
        // Runnable but kept off the CPU.
        watch.update(7, ms(30), times(18_100_000, 4_000_000, 15), 0.5);
        assert_eq!(watch.starved_for, Duration::from_millis(5));
        // A new process in its place starts afresh; a gone one has nothing.
        watch.update(8, ms(35), times(90_000_000, 0, 0), 0.5);
        assert_eq!((watch.busy_for, watch.starved_for), (Duration::ZERO, Duration::ZERO));
        watch.update(8, ms(40), None, 0.5);
        assert!(watch.last.is_none());
    }

    #[test]
    fn a_process_that_sleeps_every_period_is_not_spinning_whatever_time_it_is_charged() {
        let t0 = Instant::now();
        let ms = |n: u64| t0 + Duration::from_millis(n);
        let mut watch = CpuWatch::default();
        // Interrupts served while it ran count as its time: 4.5 ms of each
        // 5 ms round, while it slept once a period as a stage does.
        for k in 0..=8u64 {
            let times = CpuTimes {
                run_ns: k * 4_500_000,
                wait_ns: 0,
                sleeps: k * 5,
            };
            watch.update(7, ms(5 * k), Some(times), 0.5);
            assert_eq!(watch.busy_for, Duration::ZERO, "round {k}");
        }
    }

    #[test]
    fn the_supervisors_own_process_has_cpu_times() {
        let times = cpu_times(std::process::id()).expect("times");
        assert!(times.run_ns > 0);
    }

    #[test]
    fn garbage_is_blamed_on_the_stage_that_made_it() {
        assert_eq!(
            blamed_for_rejections(true, false, false),
            4,
            "cascade: the torque loop feeds the valve"
        );
        assert_eq!(
            blamed_for_rejections(false, false, false),
            3,
            "the outer loop's own output is garbage"
        );
        assert_eq!(
            blamed_for_rejections(true, true, false),
            3,
            "the outer loop's reference limit-cycles; the inner loop follows it"
        );
        assert_eq!(
            blamed_for_rejections(true, false, true),
            3,
            "position-only: the outer loop drives the valve"
        );
    }

    #[test]
    fn a_limit_cycling_controller_never_comes_back_as_it_was_at_once() {
        let second = Duration::from_secs(1);
        let restart = |variant, after| Comeback::Restart { variant, after };
        assert_eq!(
            after_limit_cycle(OnLimitCycle::Baseline, "hinf", Some("hinf"), 1, second),
            restart("pid", Duration::ZERO),
            "a fallback naming the same variant is no fallback"
        );
        assert_eq!(
            after_limit_cycle(OnLimitCycle::Stop, "pid", Some("hinf"), 1, second),
            restart("hinf", Duration::ZERO),
            "the configured fallback first"
        );
        assert_eq!(
            after_limit_cycle(OnLimitCycle::Baseline, "pid", None, 3, second),
            restart("pid", Duration::from_secs(4)),
            "the baseline itself limit-cycles: backing off, doubled per burst"
        );
        assert_eq!(
            after_limit_cycle(OnLimitCycle::Backoff, "mfc", None, 1, second),
            restart("mfc", second)
        );
        assert_eq!(
            after_limit_cycle(OnLimitCycle::Stop, "pid", None, 1, second),
            Comeback::LeaveDown
        );
    }
}
