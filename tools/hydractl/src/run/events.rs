//! The supervisor's events as `hydractl run` hears them: each said as it
//! happens, above the live line, and kept for the run's summary.

use hydractl_samples::code::EventKind;
use hydractl_samples::{name_str, SupervisorEvent};

use super::monitor::Tracking;
use super::summary::{FallbackJudgedSummary, FaultSummary, PlantSwitchSummary, StrangerSummary, SwapSummary};

/// Every event of the run so far, by kind.
#[derive(Default)]
pub(super) struct EventsSeen {
    pub(super) swaps: Vec<SwapSummary>,
    pub(super) swap_failures: Vec<SwapSummary>,
    pub(super) faults: Vec<FaultSummary>,
    pub(super) strangers: Vec<StrangerSummary>,
    pub(super) plant_switches: Vec<PlantSwitchSummary>,
    pub(super) fallbacks_judged: Vec<FallbackJudgedSummary>,
    /// Faults whose second after is still being watched: (index, errors
    /// seen then).
    after_fault: Vec<(usize, u64)>,
}

impl EventsSeen {
    /// One event; `tracking_count` the tracking errors seen so far.
    pub(super) fn take(&mut self, e: &SupervisorEvent, live: bool, tracking_count: u64) {
        let swap = SwapSummary {
            stage: name_str(&e.process).to_owned(),
            from: name_str(&e.from).to_owned(),
            to: name_str(&e.to).to_owned(),
            at_seq: e.sensor_seq,
            missed_cycles: e.missed_cycles,
            command_step: e.command_step,
            loop_step_before: e.loop_step_before,
            loop_step_after: e.loop_step_after,
        };
        let kind = EventKind::from_code(e.kind);
        match kind {
            Some(EventKind::Fallback | EventKind::PlantSwitch) => {
                let lost = kind == Some(EventKind::Fallback);
                if lost {
                    super::above_live_line(live);
                    tracing::warn!(
                        event = "fallback",
                        seq = e.sensor_seq,
                        "the machine is lost: the loop now runs on the SIMULATED plant from reading {}",
                        e.sensor_seq
                    );
                }
                self.plant_switches.push(PlantSwitchSummary {
                    from: swap.from,
                    to: swap.to,
                    cause: if lost { "machine lost" } else { "asked" },
                    at_seq: e.sensor_seq,
                    detected_after_ms: e.detected_after_ns as f64 * 1e-6,
                });
            }
            Some(EventKind::Stranger) => {
                let stranger = StrangerSummary {
                    pid: e.pid,
                    service: name_str(&e.process).to_owned(),
                    at_seq: e.sensor_seq,
                };
                super::above_live_line(live);
                tracing::warn!(
                    event = "stranger",
                    seq = stranger.at_seq,
                    "a stranger, process {}, publishes on the run's {} (at reading {})",
                    stranger.pid,
                    stranger.service,
                    stranger.at_seq
                );
                self.strangers.push(stranger);
            }
            Some(EventKind::Swap) => {
                super::above_live_line(live);
                tracing::info!(
                    event = "swap",
                    stage = swap.stage.as_str(),
                    seq = swap.at_seq,
                    "{} now runs {} (was {}) from reading {}: {} missed cycles, command step {:.2} % of its range",
                    swap.stage,
                    swap.to,
                    swap.from,
                    swap.at_seq,
                    swap.missed_cycles,
                    swap.command_step * 100.0
                );
                self.swaps.push(swap);
            }
            Some(EventKind::SwapFailed) => {
                super::above_live_line(live);
                tracing::warn!(
                    event = "swap_failed",
                    stage = swap.stage.as_str(),
                    "{} did not change to {}: {} stays in charge",
                    swap.stage,
                    swap.to,
                    swap.from
                );
                self.swap_failures.push(swap);
            }
            Some(
                fault_kind @ (EventKind::Crash
                | EventKind::Hang
                | EventKind::Misbehaving
                | EventKind::LimitCycle
                | EventKind::Spin),
            ) => {
                let fault = FaultSummary {
                    process: name_str(&e.process).to_owned(),
                    kind: fault_kind.name(),
                    pid: e.pid,
                    last_seq: e.sensor_seq,
                    detected_after_ms: e.detected_after_ns as f64 * 1e-6,
                    valve_safe_after_periods: (e.valve_safe_after_periods != u64::MAX)
                        .then_some(e.valve_safe_after_periods),
                    restarted_after_ms: (e.restarted_after_ns != u64::MAX)
                        .then_some(e.restarted_after_ns as f64 * 1e-6),
                    restarted_as: Some(name_str(&e.to).to_owned()).filter(|v| !v.is_empty()),
                    tracking_error_max_after_rad: None,
                };
                self.after_fault.push((self.faults.len(), tracking_count));
                // Said as it happens, above the live line.
                super::above_live_line(live);
                tracing::warn!(
                    event = fault.kind,
                    child = fault.process.as_str(),
                    child_pid = fault.pid,
                    seq = fault.last_seq,
                    "{}",
                    fault.says()
                );
                self.faults.push(fault);
            }
            Some(EventKind::FallbackJudged) => {
                let judged = FallbackJudgedSummary::of(e);
                super::above_live_line(live);
                match judged.outcome {
                    "kept" => tracing::info!(
                        event = "fallback_judged",
                        stage = judged.stage.as_str(),
                        "{}",
                        judged.says()
                    ),
                    _ => tracing::warn!(
                        event = "fallback_judged",
                        stage = judged.stage.as_str(),
                        "{}",
                        judged.says()
                    ),
                }
                self.fallbacks_judged.push(judged);
            }
            _ => {}
        }
    }

    /// After each tracking error: a fault's second after, once complete.
    pub(super) fn on_tracking(&mut self, tracking: &Tracking, per_second: u64) {
        if self
            .after_fault
            .first()
            .is_some_and(|&(_, at)| tracking.count() >= at + per_second)
        {
            let (i, _) = self.after_fault.remove(0);
            self.faults[i].tracking_error_max_after_rad = Some(tracking.last_second().max_abs);
        }
    }
}
