//! A fault's account: what stopped or misbehaved, when it was found, and
//! the judgements behind it (hung, and who is blamed for garbage).

use std::time::{Duration, Instant};

/// A process that crashed, hung or misbehaved, until it is back.
#[derive(Debug, Clone, Copy)]
pub(super) struct Fault {
    pub(super) kind: u32,
    pub(super) pid: u32,
    pub(super) detected_at: Instant,
    /// From its last output to the detection.
    pub(super) silent_for: Duration,
    /// The last reading it answered.
    pub(super) last_seq: Option<u64>,
    /// A controller restarted for misbehaving: its variant, and the one it
    /// was restarted into.
    pub(super) variants: Option<(&'static str, &'static str)>,
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

/// The pipeline index of the controller blamed when the valve keeps
/// rejecting commands: the outer loop (3) when its own output is garbage or
/// it drives the valve (the torque stage bypassed), else the torque stage
/// (4), which feeds the valve.
pub(super) fn blamed_for_rejections(position_output_finite: bool, torque_bypassed: bool) -> usize {
    if !position_output_finite || torque_bypassed {
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
    fn garbage_is_blamed_on_the_stage_that_made_it() {
        assert_eq!(
            blamed_for_rejections(true, false),
            4,
            "cascade: the torque loop feeds the valve"
        );
        assert_eq!(
            blamed_for_rejections(false, false),
            3,
            "the outer loop's own output is garbage"
        );
        assert_eq!(
            blamed_for_rejections(true, true),
            3,
            "position-only: the outer loop drives the valve"
        );
    }
}
