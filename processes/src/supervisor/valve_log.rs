//! What a hot swap did to the valve: the supervisor keeps the valve's
//! recent samples and judges the switch from them.

use std::collections::VecDeque;

/// The valve's recent samples: `(sensor_seq, command, faults)`.
#[derive(Debug)]
pub(crate) struct ValveLog {
    entries: VecDeque<(u64, f64, u32)>,
    capacity: usize,
}

/// How the valve went through a switch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SwitchQuality {
    /// Readings around the switch with no fresh command at the valve: a
    /// sequence number missing, or the valve's stale/invalid guard tripped.
    pub missed_cycles: u64,
    /// The largest |command − command one reading before| over the
    /// command's range, 2, from the switch through the next
    /// [`TRANSIENT`] − 1 readings: the switch and its transient.
    pub command_step: f64,
    /// The largest such step in the `usual` readings before the switch, and
    /// from the end of the transient to the end of the window: the old and
    /// the new controller's own period-to-period variation, to judge the
    /// switch against.
    pub loop_step_before: f64,
    pub loop_step_after: f64,
}

/// Commands the valve rejected as garbage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rejected {
    pub count: u64,
    /// The newest rejected command's reading.
    pub newest: Option<u64>,
    /// The garbage flags they were rejected for, together.
    pub why: u32,
}

/// Readings from the switch counted as its transient.
pub const TRANSIENT: u64 = 5;

impl ValveLog {
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            entries: VecDeque::with_capacity(capacity),
            capacity,
        }
    }

    pub fn push(&mut self, seq: u64, command: f64, faults: u32) {
        if self.entries.len() == self.capacity {
            self.entries.pop_front();
        }
        self.entries.push_back((seq, command, faults));
    }

    /// The first reading after `seq` at which the valve was made safe (a
    /// fault flag, neutral).
    pub fn first_fault_after(&self, seq: u64) -> Option<u64> {
        self.entries.iter().find_map(|&(at, _, faults)| {
            // A valve stopping drives neutral for the reading after the
            // newest it knew.
            let effective = if faults & hydractl_samples::fault::OFF != 0 {
                at + 1
            } else {
                at
            };
            (effective > seq && faults != 0).then_some(effective)
        })
    }

    /// How many periods the valve held its last command after a process
    /// last answered reading `last_seq`, before it went safe; `None` when
    /// the log shows no fault after it. The command for reading
    /// `last_seq + 1` was due when reading `last_seq + 2` came: the fault
    /// shows from there, and until the guard trips the valve holds its last
    /// command.
    pub fn valve_safe_after_periods(&self, last_seq: u64) -> Option<u64> {
        self.first_fault_after(last_seq)
            .map(|at| at.saturating_sub(last_seq + 2))
    }

    /// Among the valve's samples for the last `window` readings, and after
    /// reading `after`, those whose command the valve rejected as garbage
    /// (`garbage` flags).
    pub fn rejected(&self, garbage: u32, window: u64, after: Option<u64>) -> Rejected {
        let mut rejected = Rejected::default();
        let Some(newest) = self.newest_seq() else {
            return rejected;
        };
        for &(seq, _, faults) in self.entries.iter().rev() {
            if seq + window <= newest || after.is_some_and(|a| seq <= a) {
                break;
            }
            if faults & garbage != 0 {
                rejected.count += 1;
                rejected.newest = rejected.newest.or(Some(seq));
                rejected.why |= faults & garbage;
            }
        }
        rejected
    }

    /// The valve drove a command without a fault: the loop answers.
    pub fn answered_any(&self) -> bool {
        self.entries.iter().any(|&(_, _, faults)| faults == 0)
    }

    pub fn newest_seq(&self) -> Option<u64> {
        self.entries.back().map(|e| e.0)
    }

    /// Judges the switch at reading `at`: missed cycles over the `around`
    /// readings either side of it (a reading skipped long after is the
    /// machine's load, not the switch), the command's steps from it to `at +
    /// after`, the loop's own steps over the `usual` readings before it;
    /// `None` until the log reaches `at + after`.
    pub fn judge(&self, at: u64, around: u64, after: u64, usual: u64) -> Option<SwitchQuality> {
        if self.newest_seq()? < at + after.max(around) {
            return None;
        }
        let window = at.saturating_sub(around)..at + around;
        let mut fresh = 0;
        let (mut command_step, mut loop_step_before, mut loop_step_after) = (None, 0.0f64, 0.0f64);
        let mut previous: Option<(u64, f64)> = None;
        for &(seq, command, faults) in &self.entries {
            if window.contains(&seq) && faults == 0 {
                fresh += 1;
            }
            if let Some((_, p_command)) = previous.filter(|(p_seq, _)| p_seq + 1 == seq) {
                let step = (command - p_command).abs() / 2.0;
                if seq < at && seq + usual >= at {
                    loop_step_before = loop_step_before.max(step);
                } else if seq >= at && seq < at + TRANSIENT {
                    command_step = Some(command_step.unwrap_or(0.0f64).max(step));
                } else if seq >= at + TRANSIENT && seq < at + after {
                    loop_step_after = loop_step_after.max(step);
                }
            }
            previous = Some((seq, command));
        }
        let expected = window.end - window.start;
        Some(SwitchQuality {
            missed_cycles: expected.saturating_sub(fresh),
            // No command around the switch at all is a full-range worst case.
            command_step: command_step.unwrap_or(1.0),
            loop_step_before,
            loop_step_after,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clean_switch_misses_nothing_and_measures_its_step() {
        let mut log = ValveLog::with_capacity(64);
        for seq in 0..60 {
            log.push(seq, if seq < 30 { 0.10 } else { 0.12 }, 0);
        }
        assert_eq!(log.judge(30, 10, 40, 20), None, "not yet reached the end of the window");
        let q = log.judge(30, 10, 20, 20).expect("judged");
        assert_eq!(q.missed_cycles, 0);
        assert!((q.command_step - 0.01).abs() < 1e-12);
        assert_eq!(
            (q.loop_step_before, q.loop_step_after),
            (0.0, 0.0),
            "the command was flat before and after"
        );
    }

    #[test]
    fn a_gap_or_a_tripped_guard_is_a_missed_cycle() {
        let mut log = ValveLog::with_capacity(64);
        for seq in (0..60).filter(|&s| s != 31) {
            log.push(seq, 0.0, u32::from(seq == 35));
        }
        let q = log.judge(30, 10, 20, 20).expect("judged");
        assert_eq!(q.missed_cycles, 2);
        assert_eq!(log.first_fault_after(30), Some(35));
        assert_eq!(log.first_fault_after(35), None);
    }

    #[test]
    fn a_reading_skipped_long_after_the_switch_is_not_the_switch_s() {
        let mut log = ValveLog::with_capacity(64);
        for seq in (0..60).filter(|&s| s != 50) {
            log.push(seq, 0.0, 0);
        }
        let q = log.judge(30, 10, 25, 20).expect("judged");
        assert_eq!(q.missed_cycles, 0);
    }

    #[test]
    fn rejected_commands_are_counted_over_the_recent_readings() {
        let mut log = ValveLog::with_capacity(16);
        for (seq, faults) in [(1, 0), (2, 2), (3, 1), (4, 2), (5, 4)] {
            log.push(seq, 0.0, faults);
        }
        let seen = |r: Rejected| (r.count, r.newest, r.why);
        assert_eq!(seen(log.rejected(2 | 4, 10, None)), (3, Some(5), 2 | 4));
        assert_eq!(
            seen(log.rejected(2 | 4, 2, None)),
            (2, Some(5), 2 | 4),
            "readings 4 and 5"
        );
        assert_eq!(
            seen(log.rejected(2 | 4, 10, Some(4))),
            (1, Some(5), 4),
            "after the one acted on"
        );
        log.push(6, 0.1, 0);
        assert_eq!(seen(log.rejected(2 | 4, 1, None)), (0, None, 0));
    }

    #[test]
    fn the_log_keeps_only_its_capacity() {
        let mut log = ValveLog::with_capacity(4);
        for seq in 0..10 {
            log.push(seq, 0.0, 0);
        }
        assert_eq!(log.entries.len(), 4);
        assert_eq!(log.newest_seq(), Some(9));
    }

    #[test]
    fn the_valve_is_safe_from_the_first_fault_after_the_command_that_did_not_come() {
        let mut log = ValveLog::with_capacity(16);
        for seq in 10..=12 {
            log.push(seq, 0.3, 0);
        }
        // The process answered reading 10 last; the valve held 0.3 for
        // readings 11 and 12 (the guard's 3 periods) and went safe at 13.
        for seq in 13..=14 {
            log.push(seq, 0.0, 1);
        }
        assert_eq!(log.valve_safe_after_periods(10), Some(1));
        assert_eq!(log.valve_safe_after_periods(14), None, "no fault seen after it yet");
    }
}
