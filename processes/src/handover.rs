//! A controller process's part in a hot swap. The supervisor starts the new
//! variant as a standby: it computes every period and tracks the running
//! controller's output (bumpless), publishing on the stage's standby service.
//! A handover names the reading from which the new process answers; from
//! that reading on, the old one stays silent. Both decide on the same
//! sequence number, so exactly one of them answers each reading.

use anyhow::Result;
use hydractl_bus::{clock, Reader};
use hydractl_samples::Handover;

/// What to do with this period's output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Duty {
    /// In charge: publish on the stage's service.
    Publish,
    /// Standby: publish on the standby service and track the running one.
    Track,
    /// Handed over: publish nothing; the supervisor stops this process.
    Silent,
}

pub struct Role {
    stage: u32,
    pid: u32,
    started_ns: u64,
    standby: bool,
    take_over_at: Option<u64>,
    retire_at: Option<u64>,
}

impl Role {
    pub fn new(stage: u32, standby: bool) -> Self {
        Self {
            stage,
            pid: std::process::id(),
            started_ns: clock::now_ns(),
            standby,
            take_over_at: None,
            retire_at: None,
        }
    }

    /// Reads the newest handover and says what to do with the output for
    /// reading `seq`. Handovers from before this process started are old
    /// news (the service keeps the last one for late joiners).
    pub fn duty(&mut self, handovers: &Reader<Handover>, seq: u64) -> Result<Duty> {
        if let Some(h) = handovers.latest()? {
            if h.stage == self.stage && h.stage_time_ns > self.started_ns {
                if h.new_pid == self.pid {
                    self.take_over_at = Some(h.at_seq);
                } else {
                    self.retire_at = Some(h.at_seq);
                }
            }
        }
        Ok(Self::decide(&mut self.standby, self.take_over_at, self.retire_at, seq))
    }

    fn decide(standby: &mut bool, take_over_at: Option<u64>, retire_at: Option<u64>, seq: u64) -> Duty {
        if *standby {
            if take_over_at.is_some_and(|at| seq >= at) {
                *standby = false;
            } else {
                return Duty::Track;
            }
        }
        if retire_at.is_some_and(|at| seq >= at) {
            Duty::Silent
        } else {
            Duty::Publish
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exactly_one_of_old_and_new_answers_each_reading() {
        let (mut old_standby, mut new_standby) = (false, true);
        for seq in 90..110 {
            let old = Role::decide(&mut old_standby, None, Some(100), seq);
            let new = Role::decide(&mut new_standby, Some(100), None, seq);
            let publishers = [old, new].iter().filter(|d| **d == Duty::Publish).count();
            assert_eq!(publishers, 1, "reading {seq}: {old:?} {new:?}");
            assert_eq!(new == Duty::Track, seq < 100);
        }
        // A standby with no handover tracks forever.
        let mut standby = true;
        assert_eq!(Role::decide(&mut standby, None, None, 5), Duty::Track);
    }
}

/// Pairs the running controller's output with the inputs this standby
/// processed for the same reading, so that tracking is exact: the standby
/// is initialized from the running output for reading k with reading k's
/// inputs, then computes reading k + 1 itself, as if it had been running.
/// The two processes wake on the same input in either order, so the match
/// is looked for both before and after this period's computation.
pub struct Tracker<I: Copy> {
    inputs: Option<(u64, I)>,
    running: Option<(u64, f64)>,
    tracked: Option<u64>,
}

impl<I: Copy> Default for Tracker<I> {
    fn default() -> Self {
        Self {
            inputs: None,
            running: None,
            tracked: None,
        }
    }
}

impl<I: Copy> Tracker<I> {
    /// Takes the running controller's newest output (reading, output), and
    /// returns what to track from, once per reading, when they match.
    pub fn matched(&mut self, running: Option<(u64, f64)>) -> Option<(f64, I)> {
        if running.is_some() {
            self.running = running;
        }
        let (seq, inputs) = self.inputs?;
        let (running_seq, output) = self.running?;
        if running_seq != seq || self.tracked == Some(seq) {
            return None;
        }
        self.tracked = Some(seq);
        Some((output, inputs))
    }

    /// This standby computed reading `seq` from `inputs`.
    pub fn processed(&mut self, seq: u64, inputs: I) {
        self.inputs = Some((seq, inputs));
    }
}

#[cfg(test)]
mod tracker_tests {
    use super::*;

    #[test]
    fn tracks_once_per_reading_whichever_process_ran_first() {
        let mut t: Tracker<u8> = Tracker::default();
        // The running one answered reading 1 before the standby computed it.
        assert_eq!(t.matched(Some((1, 10.0))), None);
        t.processed(1, 1);
        assert_eq!(t.matched(None), Some((10.0, 1)));
        assert_eq!(t.matched(None), None, "once per reading");
        // Reading 2: the standby ran first; the match comes on the next wake.
        assert_eq!(t.matched(None), None);
        t.processed(2, 2);
        assert_eq!(t.matched(None), None);
        assert_eq!(t.matched(Some((2, 20.0))), Some((20.0, 2)));
        // A running output for an older reading never matches newer inputs.
        t.processed(3, 3);
        assert_eq!(t.matched(Some((2, 20.0))), None);
    }
}
