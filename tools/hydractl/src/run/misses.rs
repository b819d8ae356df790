//! Each deadline miss with the evidence of where its time went: the
//! chain's own stamps of the readings it missed, hop by hop, and whether
//! this monitor, which runs on another CPU than the loop, was kept from
//! running at the same time, which only a stall of the whole computer
//! does.

use std::collections::VecDeque;

use serde::Serialize;

use hydractl_samples::service::STAGES;

/// Readings whose stamps are kept: a second of the loop, more than a
/// miss's evidence takes to arrive.
const RING: usize = 1024;
/// Misses described one by one; the rest are counted.
const KEPT: usize = 100;
/// How long after a miss is seen its readings' stamps are awaited (the
/// late command itself arrives after the miss was counted).
const SETTLE_NS: u64 = 50_000_000;
/// The monitor's own tick: a gap between two of its wake-ups longer than
/// this and [`STALLED_NS`] more is time the computer took from it too.
const TICK_NS: u64 = 10_000_000;
const STALLED_NS: u64 = 5_000_000;
/// Monitor gaps kept, with when they ended.
const GAPS: usize = 64;

/// One stretch of deadline misses, and where its time went.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(super) struct MissEvidence {
    /// Seconds into the run the misses were counted.
    pub(super) at_s: f64,
    /// The readings of the stretch, first and last.
    pub(super) readings: (u64, u64),
    /// Cycles the plant counted late in it.
    pub(super) cycles: u64,
    /// The chain's slowest hop over its readings (`reading→sensor`,
    /// `torque→valve`, …), and how long it took, µs; none when no stage
    /// answered any of them.
    pub(super) slowest_hop: Option<&'static str>,
    pub(super) slowest_hop_us: Option<f64>,
    /// Readings of the stretch the valve never answered: no stage did, or
    /// a stage took a newer reading before it was done.
    pub(super) unanswered_readings: u64,
    /// The longest this monitor, on another CPU, waited beyond its own
    /// tick around the misses, ms.
    pub(super) monitor_stalled_ms: f64,
    /// In words: `computer stalled` (the monitor was kept from running
    /// too) or `chain late` (the time went to the named hop alone).
    pub(super) cause: &'static str,
}

/// When each stage answered one reading: ns, 0 for not seen.
#[derive(Debug, Clone, Copy, Default)]
struct Stamps {
    seq: u64,
    reading_ns: u64,
    stage_ns: [u64; STAGES.len()],
}

/// The names of the hops, from the reading to each stage.
const HOPS: [&str; STAGES.len()] = [
    "reading→sensor",
    "sensor→friction",
    "friction→position",
    "position→torque",
    "torque→valve",
];

#[derive(Debug)]
pub(super) struct Misses {
    ring: Box<[Stamps; RING]>,
    /// The late count seen last, the newest reading answered, and the
    /// newest at the last count: a miss lies between the last two.
    late: u64,
    newest_seq: u64,
    checked_seq: u64,
    last_tick_ns: Option<u64>,
    /// (ended at, gap beyond the tick), ns.
    gaps: [(u64, u64); GAPS],
    next_gap: usize,
    /// Misses counted, not yet described: (counted at ns, first reading,
    /// last reading, cycles).
    pending: VecDeque<(u64, u64, u64, u64)>,
    pub(super) described: Vec<MissEvidence>,
    /// Stretches beyond the [`KEPT`] described.
    pub(super) not_described: u64,
    started_ns: u64,
}

impl Misses {
    pub(super) fn new(started_ns: u64) -> Self {
        Self {
            ring: Box::new([Stamps::default(); RING]),
            late: 0,
            newest_seq: 0,
            checked_seq: 0,
            last_tick_ns: None,
            gaps: [(0, 0); GAPS],
            next_gap: 0,
            pending: VecDeque::new(),
            described: Vec::new(),
            not_described: 0,
            started_ns,
        }
    }

    /// Stage `stage` (its index in [`STAGES`]) answered reading `seq`.
    pub(super) fn stamp(&mut self, stage: usize, seq: u64, reading_ns: u64, stage_ns: u64) {
        let slot = &mut self.ring[(seq % RING as u64) as usize];
        if slot.seq != seq {
            *slot = Stamps {
                seq,
                reading_ns,
                ..Stamps::default()
            };
        }
        slot.stage_ns[stage] = stage_ns;
        self.newest_seq = self.newest_seq.max(seq);
    }

    /// The plant's count of late commands, as its newest reading says:
    /// a rise is a stretch of misses among the readings answered since the
    /// count was last looked at (and the one before, counted a reading
    /// later).
    pub(super) fn on_late(&mut self, late: u64, now_ns: u64) {
        if late > self.late {
            let first = self.checked_seq.saturating_sub(1);
            self.pending
                .push_back((now_ns, first, self.newest_seq.max(first), late - self.late));
            self.late = late;
        }
        self.checked_seq = self.newest_seq;
    }

    /// One wake-up of the monitor: its gap since the last, and the misses
    /// whose stamps have had time to arrive described.
    pub(super) fn tick(&mut self, now_ns: u64) {
        if let Some(last) = self.last_tick_ns {
            let beyond = now_ns.saturating_sub(last).saturating_sub(TICK_NS);
            self.gaps[self.next_gap] = (now_ns, beyond);
            self.next_gap = (self.next_gap + 1) % GAPS;
        }
        self.last_tick_ns = Some(now_ns);
        while let Some(&(at, first, last, cycles)) = self.pending.front() {
            if now_ns < at + SETTLE_NS {
                break;
            }
            self.pending.pop_front();
            let evidence = self.describe(at, (first, last), cycles);
            if self.described.len() < KEPT {
                self.described.push(evidence);
            } else {
                self.not_described += 1;
            }
        }
    }

    fn describe(&self, at_ns: u64, (first, last): (u64, u64), cycles: u64) -> MissEvidence {
        let mut slowest: Option<(usize, u64)> = None;
        let mut unanswered = 0;
        for seq in first..=last {
            let s = &self.ring[(seq % RING as u64) as usize];
            if s.seq != seq || s.stage_ns[HOPS.len() - 1] == 0 {
                unanswered += 1;
            }
            if s.seq != seq || s.reading_ns == 0 {
                continue;
            }
            let mut before = s.reading_ns;
            for (hop, &at) in s.stage_ns.iter().enumerate() {
                if at == 0 {
                    continue;
                }
                let took = at.saturating_sub(before);
                if slowest.is_none_or(|(_, t)| took > t) {
                    slowest = Some((hop, took));
                }
                before = at;
            }
        }
        // The monitor's gaps that ended within a settle time either side
        // of the count: the misses were counted in the reading after them.
        let stalled_ns = self
            .gaps
            .iter()
            .filter(|(end, _)| end.abs_diff(at_ns) <= SETTLE_NS)
            .map(|(_, beyond)| *beyond)
            .max()
            .unwrap_or(0);
        MissEvidence {
            at_s: at_ns.saturating_sub(self.started_ns) as f64 * 1e-9,
            readings: (first, last),
            cycles,
            slowest_hop: slowest.map(|(hop, _)| HOPS[hop]),
            slowest_hop_us: slowest.map(|(_, ns)| ns as f64 * 1e-3),
            unanswered_readings: unanswered,
            monitor_stalled_ms: stalled_ns as f64 * 1e-6,
            cause: if stalled_ns >= STALLED_NS {
                "computer stalled"
            } else {
                "chain late"
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    /// Readings `seqs` every ms from `t0`, each stage 10 µs after the one
    /// before, but `slow` (stage, extra ns) at reading `at`.
    fn feed(m: &mut Misses, seqs: std::ops::Range<u64>, t0: u64, slow: Option<(u64, usize, u64)>) {
        for seq in seqs {
            let reading = t0 + seq * MS;
            let mut at = reading;
            for stage in 0..STAGES.len() {
                at += 10_000;
                if let Some((s, st, extra)) = slow {
                    if s == seq && st == stage {
                        at += extra;
                    }
                }
                m.stamp(stage, seq, reading, at);
            }
        }
    }

    #[test]
    fn a_miss_names_the_hop_that_took_its_time_when_the_monitor_ran() {
        let mut m = Misses::new(0);
        feed(&mut m, 0..100, 0, Some((90, 3, 4 * MS)));
        for t in 0..=10 {
            m.tick(t * 10 * MS);
        }
        m.on_late(3, 100 * MS);
        for t in 11..=14 {
            m.tick(t * 10 * MS);
        }
        assert!(m.described.is_empty(), "awaits the late stamps");
        m.tick(150 * MS);
        let e = &m.described[0];
        assert_eq!(e.cycles, 3);
        assert_eq!(e.slowest_hop, Some("position→torque"));
        assert!(e.slowest_hop_us.is_some_and(|us| (us - 4010.0).abs() < 1.0), "{e:?}");
        assert_eq!(e.cause, "chain late");
        assert_eq!(e.unanswered_readings, 0);
        assert!(e.readings.0 <= 90 && 90 <= e.readings.1, "{e:?}");
    }

    #[test]
    fn a_miss_while_the_monitor_was_kept_from_running_is_a_stall_of_the_computer() {
        let mut m = Misses::new(0);
        m.tick(0);
        feed(&mut m, 0..50, 0, None);
        // The monitor woke 30 ms late, and the plant counted 20 late; the
        // chain answered the readings after 49 only once it ran again.
        m.tick(40 * MS);
        m.on_late(20, 40 * MS);
        m.tick(100 * MS);
        let e = &m.described[0];
        assert_eq!(e.cause, "computer stalled");
        assert_eq!(e.unanswered_readings, 0, "{e:?}");
        assert!((e.monitor_stalled_ms - 30.0).abs() < 1e-9, "{e:?}");
    }

    #[test]
    fn a_reading_the_valve_never_answered_is_counted() {
        let mut m = Misses::new(0);
        feed(&mut m, 0..15, 0, None);
        // Reading 15 reaches the torque stage only; 16 no stage at all.
        for stage in 0..STAGES.len() - 1 {
            m.stamp(stage, 15, 15 * MS, 15 * MS + 10_000);
        }
        feed(&mut m, 17..20, 0, None);
        for t in 0..=2 {
            m.tick(t * 10 * MS);
        }
        m.on_late(2, 20 * MS);
        for t in 3..=8 {
            m.tick(t * 10 * MS);
        }
        assert_eq!(m.described[0].unanswered_readings, 2, "{:?}", m.described[0]);
    }

    #[test]
    fn beyond_the_kept_ones_misses_are_counted_not_described() {
        let mut m = Misses::new(0);
        for i in 0..(KEPT as u64 + 5) {
            let t = i * 100 * MS;
            m.tick(t);
            m.on_late(i + 1, t);
        }
        m.tick(u64::MAX / 2);
        assert_eq!(m.described.len(), KEPT);
        assert_eq!(m.not_described, 5);
    }
}
