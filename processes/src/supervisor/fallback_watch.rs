//! A fault's restart into a fallback variant, judged by the tracking that
//! follows it as a swap is ([`super::swaps`]). A fallback that tracks far
//! worse than the loop did before the fault falls further back, to the
//! papers' PID (the variant that failed, when it was the PID: its fault
//! may have been garbage from elsewhere, and a limit cycle of its own is
//! caught again and waited out as `on_limit_cycle` says), and is not
//! fallen back to again in the run. When the PID tracks far worse too, the
//! stage is left down with the valve neutral, for a person to look.

use std::time::{Duration, Instant};

use anyhow::Result;
use hydractl_config::SupervisorConfig;

use super::child::Supervised;
use super::swaps::{SwapJudge, Swaps};
use super::tracking::{worse_enough, TrackingLog};

/// The variant every stage has: the papers' PID.
const BASELINE: &str = "pid";

/// One stage's fallbacks: the one under watch, and the one judged worse.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct StageFallbacks {
    pub(super) watch: Option<FallbackWatch>,
    /// A fallback variant that tracked far worse: not fallen back to again.
    pub(super) ruled_out: Option<&'static str>,
}

impl StageFallbacks {
    /// The configured fallback, unless it was ruled out.
    pub(super) fn allowed(&self, configured: Option<&'static str>) -> Option<&'static str> {
        configured.filter(|&v| Some(v) != self.ruled_out)
    }
}

/// One stage's fallback under watch.
#[derive(Debug, Clone, Copy)]
pub(super) struct FallbackWatch {
    /// The variant whose fault caused the fallback.
    pub(super) failed: &'static str,
    /// The variant running now, being judged.
    pub(super) variant: &'static str,
    /// The tracking's rms over the judged window before the fault.
    rms_before: f64,
    /// The newest reading when the fault was handled: the fallback's own
    /// answers are to later ones.
    fault_seq: u64,
    /// The readings judged, from the settle after the fallback's first
    /// answer; `None` until it answers.
    window: Option<(u64, u64)>,
    since: Instant,
}

/// What a watch found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Verdict {
    /// The fallback tracks well enough: it stays.
    Kept { rms_after: f64, rms_before: f64 },
    /// It tracks far worse: the stage goes on with `to`.
    FallFurther {
        to: &'static str,
        rms_after: f64,
        rms_before: f64,
    },
    /// It is the baseline: nothing is left to fall back to.
    LeaveDown { rms_after: f64, rms_before: f64 },
}

impl FallbackWatch {
    /// Watches `variant`, started after `failed` faulted at reading
    /// `fault_seq` (`first_rejected` the first reading of the fault). `None`
    /// when fallbacks are not judged (`swap_judge_ms = 0`) or the loop's
    /// tracking before the fault is unknown.
    pub(super) fn new(
        failed: &'static str,
        variant: &'static str,
        (first_rejected, fault_seq): (u64, u64),
        tracking: &TrackingLog,
        judge: &SwapJudge,
        now: Instant,
    ) -> Option<Self> {
        if judge.readings == 0 {
            return None;
        }
        let (rms_before, _) = tracking.rms_between(first_rejected.saturating_sub(judge.readings), first_rejected)?;
        Some(Self {
            failed,
            variant,
            rms_before,
            fault_seq,
            window: None,
            since: now,
        })
    }

    /// The same baseline and the same failed variant, now judging `variant`.
    pub(super) fn next(self, variant: &'static str, fault_seq: u64, now: Instant) -> Self {
        Self {
            variant,
            fault_seq,
            window: None,
            since: now,
            ..self
        }
    }

    /// The running process of the stage answered reading `seq`.
    pub(super) fn answered(&mut self, seq: u64, judge: &SwapJudge) {
        if self.window.is_none() && seq > self.fault_seq {
            let from = seq + judge.fallback_settle_readings;
            self.window = Some((from, from + judge.readings));
        }
    }

    /// The verdict, once the window's tracking is in; `Err` when the watch
    /// is given up (the fallback never answered, or the loop stopped
    /// giving its tracking), `Ok(None)` while it waits.
    pub(super) fn tick(
        &self,
        tracking: &TrackingLog,
        judge: &SwapJudge,
        period: Duration,
        now: Instant,
    ) -> Result<Option<Verdict>, ()> {
        // Ample for a restart's back-off, the settle and the window.
        let patience = period * (2 * (judge.fallback_settle_readings + judge.readings)) as u32 + Duration::from_secs(5);
        let waited_long = now.saturating_duration_since(self.since) > patience;
        let Some((from, until)) = self.window else {
            return if waited_long { Err(()) } else { Ok(None) };
        };
        if tracking.newest().is_none_or(|newest| newest < until) && !waited_long {
            return Ok(None);
        }
        let Some((rms_after, _)) = tracking.rms_between(from, until) else {
            return Err(());
        };
        let rms_before = self.rms_before;
        Ok(Some(
            match (
                worse_enough(rms_before, rms_after, judge.factor, judge.floor_rad),
                self.variant != BASELINE,
            ) {
                (false, _) => Verdict::Kept { rms_after, rms_before },
                (true, true) => Verdict::FallFurther {
                    to: BASELINE,
                    rms_after,
                    rms_before,
                },
                (true, false) => Verdict::LeaveDown { rms_after, rms_before },
            },
        ))
    }
}

/// Judges the stage's fallback under `watch` once its window is in, and
/// acts: keeps it, restarts the stage as the baseline (watched in turn), or
/// leaves it down. Each verdict is an event with both figures. Returns
/// whether a process was stopped, its resources to be cleaned.
pub(super) fn judge_fallback(
    stage: &mut StageFallbacks,
    child: &mut Supervised,
    swaps: &mut Swaps,
    policy: &SupervisorConfig,
    at_seq: u64,
    now: Instant,
) -> Result<bool> {
    let Some(current) = stage.watch else {
        return Ok(false);
    };
    // A person swapped the stage meanwhile: theirs to judge.
    if child.variant != Some(current.variant) {
        stage.watch = None;
        return Ok(false);
    }
    let (tracking, judge, period) = swaps.tracking();
    let verdict = match current.tick(tracking, judge, period, now) {
        Ok(None) => return Ok(false),
        Err(()) => {
            stage.watch = None;
            return Ok(false);
        }
        Ok(Some(verdict)) => verdict,
    };
    stage.watch = None;
    let (name, variant) = (child.name, current.variant);
    let (next, (rms_after, rms_before)) = match verdict {
        Verdict::Kept { rms_after, rms_before } => (variant, (rms_after, rms_before)),
        Verdict::FallFurther {
            to,
            rms_after,
            rms_before,
        } => (to, (rms_after, rms_before)),
        Verdict::LeaveDown { rms_after, rms_before } => ("", (rms_after, rms_before)),
    };
    let figures = format!("{rms_after:.4} rad rms against {rms_before:.4} before the fault");
    let mut stopped = false;
    match verdict {
        Verdict::Kept { .. } => {
            tracing::info!("{name} keeps its fallback {variant}: tracking {figures}");
        }
        Verdict::FallFurther { to, .. } => {
            tracing::warn!("{name}'s fallback {variant} tracks {figures}: restarting it as {to}");
            child.kill_hung();
            child.variant = Some(to);
            stage.ruled_out = Some(variant);
            if child.after_stop(now, policy) {
                stage.watch = Some(current.next(to, at_seq, now));
            }
            stopped = true;
        }
        Verdict::LeaveDown { .. } => {
            tracing::error!(
                "{name}'s fallback {variant} tracks {figures} ({} failed before it), and nothing is left to fall back to: {name} is left down, the valve neutral",
                current.failed
            );
            child.kill_hung();
            child.give_up(format!(
                "its fallback {variant} tracked {figures}, and nothing is left to fall back to"
            ));
            stopped = true;
        }
    }
    swaps.publish_judged_fallback(name, (variant, next), at_seq, (rms_before, rms_after))?;
    Ok(stopped)
}

#[cfg(test)]
mod tests {
    use super::*;

    const JUDGE: SwapJudge = SwapJudge {
        readings: 100,
        factor: 2.0,
        floor_rad: 0.1,
        fallback_settle_readings: 50,
    };
    const PERIOD: Duration = Duration::from_millis(1);

    /// The tracking error `before` up to reading 1000, `after` from then.
    fn tracking(before: f64, after: f64, newest: u64) -> TrackingLog {
        let mut log = TrackingLog::with_capacity(2000);
        for seq in 800..=newest {
            log.push(seq, if seq < 1000 { before } else { after });
        }
        log
    }

    fn verdict(failed: &'static str, variant: &'static str, before: f64, after: f64) -> Option<Verdict> {
        let now = Instant::now();
        let log = tracking(before, after, 1000);
        let mut watch = FallbackWatch::new(failed, variant, (990, 1000), &log, &JUDGE, now).expect("judged");
        // Its first answer is to reading 1003: judged on 1053..1153.
        watch.answered(1003, &JUDGE);
        assert_eq!(watch.tick(&log, &JUDGE, PERIOD, now), Ok(None), "waits for its window");
        let log = tracking(before, after, 1160);
        watch.tick(&log, &JUDGE, PERIOD, now).expect("judged")
    }

    #[test]
    fn a_fallback_far_worse_falls_to_the_baseline_then_is_left_down() {
        // Errors whose squares and roots are exact in binary.
        assert_eq!(
            verdict("pid", "hinf", 0.25, 0.5),
            Some(Verdict::Kept {
                rms_after: 0.5,
                rms_before: 0.25
            }),
            "worse, but not by the factor"
        );
        assert_eq!(
            verdict("mfc", "hinf", 0.125, 0.5),
            Some(Verdict::FallFurther {
                to: "pid",
                rms_after: 0.5,
                rms_before: 0.125
            })
        );
        // Back to the PID even when it was the one that failed.
        assert!(matches!(
            verdict("pid", "hinf", 0.125, 0.5),
            Some(Verdict::FallFurther { to: "pid", .. })
        ));
        // The baseline itself tracks far worse.
        assert_eq!(
            verdict("hinf", "pid", 0.125, 0.5),
            Some(Verdict::LeaveDown {
                rms_after: 0.5,
                rms_before: 0.125
            })
        );
        // Far worse by the factor, but within the floor: kept.
        assert!(matches!(
            verdict("mfc", "hinf", 0.015625, 0.0625),
            Some(Verdict::Kept { .. })
        ));
    }

    #[test]
    fn a_fallback_ruled_out_is_not_fallen_back_to_again() {
        let mut stage = StageFallbacks::default();
        assert_eq!(stage.allowed(Some("hinf")), Some("hinf"));
        stage.ruled_out = Some("hinf");
        assert_eq!(stage.allowed(Some("hinf")), None);
        assert_eq!(stage.allowed(Some("pid")), Some("pid"));
    }

    #[test]
    fn a_fallback_that_never_answers_is_given_up_and_answers_before_the_fault_do_not_count() {
        let now = Instant::now();
        let log = tracking(0.01, 0.01, 1000);
        let mut watch = FallbackWatch::new("pid", "hinf", (990, 1000), &log, &JUDGE, now).expect("judged");
        watch.answered(1000, &JUDGE);
        assert_eq!(watch.window, None, "an answer the failed process gave");
        let late = now + Duration::from_secs(6);
        assert_eq!(watch.tick(&log, &JUDGE, PERIOD, late), Err(()));
        let off = SwapJudge { readings: 0, ..JUDGE };
        assert!(FallbackWatch::new("pid", "hinf", (990, 1000), &log, &off, now).is_none());
    }
}
