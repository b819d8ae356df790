//! A controller process's part in a hot swap. The supervisor starts the new
//! variant as a standby: it computes every period and tracks the running
//! controller's output (bumpless), publishing on the stage's standby service.
//! A handover names the reading from which the new process answers; from
//! that reading on, the old one stays silent. Both decide on the same
//! sequence number, so exactly one of them answers each reading.

use anyhow::Result;
use hydractl_bus::{clock, Bus, Outlet, Reader};
use hydractl_samples::{service, Handover, HandoverAck};

/// Handovers a process may have waiting: far more than the supervisor ever
/// has in flight (one swap and one plant switch at a time).
const HANDOVER_QUEUE: usize = 64;

/// The handovers for one process's stage, none lost: every handover
/// published since its last look is read in order (not only the newest, as
/// when plant and controller handovers overtook each other on the one
/// service), and each one naming this stage is acknowledged on
/// `hydractl/control/handover/ack`. Handovers from before this process
/// started are old news (the service keeps the last one for late joiners).
pub struct HandoverInbox {
    handovers: Reader<Handover>,
    acks: Outlet<HandoverAck>,
    stage: u32,
    pid: u32,
    started_ns: u64,
}

impl HandoverInbox {
    pub fn open(bus: &Bus, stage: u32) -> Result<Self> {
        Ok(Self {
            handovers: Reader::open(bus, service::HANDOVER, HANDOVER_QUEUE)?,
            acks: Outlet::open(bus, service::HANDOVER_ACK)?,
            stage,
            pid: std::process::id(),
            started_ns: clock::now_ns(),
        })
    }

    pub fn pid(&self) -> u32 {
        self.pid
    }

    /// The next handover for this stage, acknowledged; `None` when none waits.
    pub fn next_handover(&mut self) -> Result<Option<Handover>> {
        while let Some(h) = self.handovers.next()? {
            if h.stage != self.stage || h.stage_time_ns <= self.started_ns {
                continue;
            }
            self.acks.publish(HandoverAck {
                handover_seq: h.seq,
                stage_time_ns: clock::now_ns(),
                at_seq: h.at_seq,
                pid: self.pid,
                taking: u32::from(h.new_pid == self.pid),
            })?;
            return Ok(Some(h));
        }
        Ok(None)
    }
}

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
    standby: bool,
    take_over_at: Option<u64>,
    retire_at: Option<u64>,
}

impl Role {
    pub fn new(standby: bool) -> Self {
        Self {
            standby,
            take_over_at: None,
            retire_at: None,
        }
    }

    /// Reads every waiting handover for this stage and says what to do
    /// with the output for reading `seq`.
    pub fn duty(&mut self, inbox: &mut HandoverInbox, seq: u64) -> Result<Duty> {
        while let Some(h) = inbox.next_handover()? {
            if h.new_pid == inbox.pid() {
                self.take_over_at = Some(h.at_seq);
            } else {
                self.retire_at = Some(h.at_seq);
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
pub(crate) struct Tracker<I: Copy> {
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

/// A plant process's part in the plant seat: the machine and the
/// simulated plant both may publish the loop's readings, exactly one at a
/// time, and the sequence goes on from one to the other without a reading
/// published twice. The supervisor's handover names the plant to take the
/// seat and the reading from which it does; the one leaving stops before
/// that reading, the one coming starts from it once the stream has reached
/// it, or, when the stream has stopped (a lost machine), after a short
/// deadline.
#[derive(Debug)]
pub(crate) struct PlantSeat {
    pid: u32,
    started_ns: u64,
    in_charge: bool,
    seen_handover: Option<u64>,
    leave_at: Option<u64>,
    take: Option<PendingTake>,
}

#[derive(Debug, Clone, Copy)]
struct PendingTake {
    at_seq: u64,
    deadline_ns: u64,
}

/// What a plant does this period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum SeatChange {
    /// Take the seat: publish readings from `at_seq` on.
    Take { at_seq: u64 },
    /// Leave it: publish no more loop readings.
    Leave,
}

impl PlantSeat {
    pub fn new(in_charge: bool) -> Self {
        Self::with_identity(std::process::id(), clock::now_ns(), in_charge)
    }

    fn with_identity(pid: u32, started_ns: u64, in_charge: bool) -> Self {
        Self {
            pid,
            started_ns,
            in_charge,
            seen_handover: None,
            leave_at: None,
            take: None,
        }
    }

    pub fn in_charge(&self) -> bool {
        self.in_charge
    }

    /// Called once per period with the newest handover, the newest reading
    /// on the loop's plant service (from whichever plant), the sequence
    /// number this plant would publish next, the time and the period.
    pub fn update(
        &mut self,
        handover: Option<Handover>,
        stream_seq: Option<u64>,
        next_seq: u64,
        now_ns: u64,
        period_ns: u64,
    ) -> Option<SeatChange> {
        if let Some(h) = handover.filter(|h| {
            h.stage == hydractl_samples::code::STAGE_PLANT
                && h.stage_time_ns > self.started_ns
                && self.seen_handover != Some(h.seq)
        }) {
            self.seen_handover = Some(h.seq);
            if h.new_pid == self.pid {
                self.leave_at = None;
                if !self.in_charge {
                    // The plant leaving has readings still to publish; given
                    // twice their time (its clock may lag ours under load)
                    // and two periods more, it is gone. For a lost machine
                    // none are to come: two periods.
                    let to_come = h.at_seq.saturating_sub(stream_seq.map_or(0, |s| s + 1));
                    self.take = Some(PendingTake {
                        at_seq: h.at_seq,
                        deadline_ns: now_ns + (2 * to_come + 2) * period_ns,
                    });
                }
            } else {
                self.take = None;
                if self.in_charge {
                    self.leave_at = Some(h.at_seq);
                }
            }
        }
        // Someone else published the reading this plant was about to: it
        // has the seat, whatever this plant missed (a stopped process).
        let overtaken = stream_seq.is_some_and(|s| s >= next_seq);
        if self.in_charge && (overtaken || self.leave_at.is_some_and(|at| next_seq >= at)) {
            self.in_charge = false;
            self.leave_at = None;
            return Some(SeatChange::Leave);
        }
        let take = self.take?;
        let reached = stream_seq.is_some_and(|s| s + 1 >= take.at_seq);
        if reached || now_ns >= take.deadline_ns {
            self.take = None;
            self.in_charge = true;
            let at_seq = take.at_seq.max(stream_seq.map_or(0, |s| s + 1));
            return Some(SeatChange::Take { at_seq });
        }
        None
    }
}

#[cfg(test)]
mod seat_tests {
    use super::*;
    use hydractl_samples::code;

    const PERIOD: u64 = 1_000_000;

    fn handover(seq: u64, at_seq: u64, new_pid: u32) -> Option<Handover> {
        Some(Handover {
            seq,
            stage_time_ns: 10,
            at_seq,
            new_pid,
            stage: code::STAGE_PLANT,
            ..Handover::default()
        })
    }

    #[test]
    fn a_live_switch_hands_the_sequence_on_without_a_gap_or_a_repeat() {
        let (mut machine, mut sim) = (
            PlantSeat::with_identity(1, 0, true),
            PlantSeat::with_identity(2, 0, false),
        );
        let h = handover(0, 105, 2);
        let mut published = Vec::new();
        let (mut machine_next, mut sim_next, mut stream) = (100u64, 0u64, Some(99u64));
        for period in 0..20u64 {
            let now = 100 + period * PERIOD;
            if machine.update(h, stream, machine_next, now, PERIOD).is_none() && machine.in_charge() {
                published.push(machine_next);
                stream = Some(machine_next);
                machine_next += 1;
            }
            if let Some(SeatChange::Take { at_seq }) = sim.update(h, stream, sim_next, now, PERIOD) {
                sim_next = at_seq;
            }
            if sim.in_charge() {
                published.push(sim_next);
                stream = Some(sim_next);
                sim_next += 1;
            }
        }
        assert!(
            !machine.in_charge() && sim.in_charge(),
            "{machine:?} {sim:?} {published:?}"
        );
        let expected: Vec<u64> = (100..100 + published.len() as u64).collect();
        assert_eq!(published, expected);
    }

    #[test]
    fn a_lost_machine_is_replaced_after_the_deadline() {
        let mut sim = PlantSeat::with_identity(2, 0, false);
        // The stream stopped at 500 and the handover names 501: at once.
        assert_eq!(
            sim.update(handover(3, 501, 2), Some(500), 0, 100, PERIOD),
            Some(SeatChange::Take { at_seq: 501 })
        );
        assert!(sim.in_charge());
        // A live switch whose leaving plant dies half-way: the deadline.
        let mut sim = PlantSeat::with_identity(2, 0, false);
        assert_eq!(sim.update(handover(3, 520, 2), Some(500), 0, 100, PERIOD), None);
        assert_eq!(sim.update(None, Some(505), 0, 100 + 30 * PERIOD, PERIOD), None);
        assert_eq!(
            sim.update(None, Some(505), 0, 100 + 40 * PERIOD, PERIOD),
            Some(SeatChange::Take { at_seq: 520 })
        );
    }

    #[test]
    fn a_machine_that_wakes_up_after_the_fallback_leaves_at_once() {
        // Stopped before it saw the handover: on waking, the stream is past it.
        let mut machine = PlantSeat::with_identity(1, 0, true);
        assert_eq!(
            machine.update(None, Some(520), 501, 100, PERIOD),
            Some(SeatChange::Leave)
        );
        // Old handovers (from before it started) are old news.
        let mut late = PlantSeat::with_identity(1, 50, false);
        assert_eq!(late.update(handover(4, 10, 1), Some(5), 0, 100, PERIOD), None);
    }
}
