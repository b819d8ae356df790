//! Each deadline miss with the evidence of where its time went: the
//! chain's own stamps of the readings it missed, hop by hop; whether the
//! loop's own timers fired late (the plant's period, the virtual wire's
//! frames), which, with every reading answered (no stage spinning), means
//! its CPU ran nothing of the loop meanwhile; and
//! whether this monitor, which runs on another CPU than the loop, was kept
//! from running at the same time, which only a stall of the whole computer
//! does.

use std::collections::VecDeque;

use serde::Serialize;

use hydractl_samples::service::STAGES;

/// Readings whose stamps are kept: a second of the loop, more than a
/// miss's evidence takes to arrive.
const RING: usize = 1024;
/// Misses described one by one; the rest are counted.
const KEPT: usize = 100;
/// How long after a miss is seen its evidence is awaited: the late
/// command arrives after the miss was counted, the wire's status every
/// 100 ms.
const SETTLE_NS: u64 = 150_000_000;
/// A timer of the loop's CPU this late means the CPU was taken from the
/// loop: a stage's work takes tens of µs, a SCHED_FIFO task is preempted
/// by nothing of this system.
const CPU_HELD_NS: u64 = 200_000;
/// The wire's late deliveries kept, with when they were due.
const WIRE_LATE: usize = 64;
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
    /// The most a reading of the stretch came after its period's start
    /// (beyond one period after the reading before it), µs: the plant's
    /// own timer, on the loop's CPU, fired that late.
    pub(super) reading_late_us: Option<f64>,
    /// On the virtual CAN bus, the most the wire delivered a frame after
    /// its last bit crossed, around the stretch, µs: the wire's own timer,
    /// on the loop's CPU, fired that late.
    pub(super) wire_late_us: Option<f64>,
    /// Readings of the stretch the valve never answered: no stage did, or
    /// a stage took a newer reading before it was done.
    pub(super) unanswered_readings: u64,
    /// The longest this monitor, on another CPU, waited beyond its own
    /// tick around the misses, ms.
    pub(super) monitor_stalled_ms: f64,
    /// In words: `computer stalled` (the monitor was kept from running
    /// too), `loop CPU held` (the loop CPU's timers above fired
    /// [`CPU_HELD_NS`] or more late together while every stage answered
    /// every reading: nothing of the loop ran) or
    /// `chain late` (the time went to the named hop alone).
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
    /// (due at, late by), ns.
    wire_late: [(u64, u64); WIRE_LATE],
    next_wire_late: usize,
    period_ns: u64,
    /// Misses counted, not yet described: (counted at ns, first reading,
    /// last reading, cycles).
    pending: VecDeque<(u64, u64, u64, u64)>,
    described: Vec<MissEvidence>,
    /// Stretches beyond the [`KEPT`] described.
    not_described: u64,
    started_ns: u64,
}

impl Misses {
    pub(super) fn new(started_ns: u64, period_ns: u64) -> Self {
        Self {
            ring: Box::new([Stamps::default(); RING]),
            late: 0,
            newest_seq: 0,
            checked_seq: 0,
            last_tick_ns: None,
            gaps: [(0, 0); GAPS],
            next_gap: 0,
            wire_late: [(0, 0); WIRE_LATE],
            next_wire_late: 0,
            period_ns,
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

    /// The virtual wire's status: its most belated delivery since the
    /// last, late by `late_ns`, due at `due_ns`.
    pub(super) fn on_wire(&mut self, due_ns: u64, late_ns: u64) {
        if late_ns > 0 {
            self.wire_late[self.next_wire_late] = (due_ns, late_ns);
            self.next_wire_late = (self.next_wire_late + 1) % WIRE_LATE;
        }
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
        self.describe_settled(now_ns);
    }

    /// The run is over: the misses still awaiting evidence are described
    /// with what came. Returns those described, and how many more there were.
    pub(super) fn finish(mut self) -> (Vec<MissEvidence>, u64) {
        self.describe_settled(u64::MAX);
        (self.described, self.not_described)
    }

    fn describe_settled(&mut self, now_ns: u64) {
        while let Some(&(at, first, last, cycles)) = self.pending.front() {
            if now_ns < at.saturating_add(SETTLE_NS) {
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
        let mut reading_late: Option<u64> = None;
        // When the stretch's readings were taken: its late timers are those
        // due from two periods before the first to two after the last (its
        // deadline, and the wire's frames after it).
        let mut window = (u64::MAX, 0u64);
        for seq in first..=last {
            let s = self.stamps(seq);
            if s.is_none_or(|s| s.stage_ns[HOPS.len() - 1] == 0) {
                unanswered += 1;
            }
            let Some(s) = s.filter(|s| s.reading_ns != 0) else {
                continue;
            };
            window = (window.0.min(s.reading_ns), window.1.max(s.reading_ns));
            if let Some(before) = seq
                .checked_sub(1)
                .and_then(|b| self.stamps(b))
                .filter(|b| b.reading_ns != 0)
            {
                let late = s.reading_ns.saturating_sub(before.reading_ns + self.period_ns);
                reading_late = reading_late.max(Some(late));
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
        let window = if window.0 <= window.1 {
            (
                window.0.saturating_sub(2 * self.period_ns),
                window.1 + 2 * self.period_ns,
            )
        } else {
            (at_ns.saturating_sub(SETTLE_NS), at_ns)
        };
        let wire_late = self
            .wire_late
            .iter()
            .filter(|(due, late)| *late > 0 && (window.0..=window.1).contains(due))
            .map(|(_, late)| *late)
            .max();
        // A late SYNC and a late frame after it add up against one deadline.
        // A stage that spins holds the timers back too, at the loop's own
        // priority, but never answers its readings.
        let held = reading_late.unwrap_or(0) + wire_late.unwrap_or(0) >= CPU_HELD_NS && unanswered == 0;
        MissEvidence {
            at_s: at_ns.saturating_sub(self.started_ns) as f64 * 1e-9,
            readings: (first, last),
            cycles,
            slowest_hop: slowest.map(|(hop, _)| HOPS[hop]),
            slowest_hop_us: slowest.map(|(_, ns)| ns as f64 * 1e-3),
            reading_late_us: reading_late.map(|ns| ns as f64 * 1e-3),
            wire_late_us: wire_late.map(|ns| ns as f64 * 1e-3),
            unanswered_readings: unanswered,
            monitor_stalled_ms: stalled_ns as f64 * 1e-6,
            cause: if stalled_ns >= STALLED_NS {
                "computer stalled"
            } else if held {
                "loop CPU held"
            } else {
                "chain late"
            },
        }
    }

    /// The stamps kept of reading `seq`, if they still are.
    fn stamps(&self, seq: u64) -> Option<&Stamps> {
        Some(&self.ring[(seq % RING as u64) as usize]).filter(|s| s.seq == seq)
    }
}

/// The run's closing line on its misses, when any were described.
pub(super) fn report(evidence: &[MissEvidence]) -> Option<String> {
    if evidence.is_empty() {
        return None;
    }
    let count = |cause: &str| evidence.iter().filter(|e| e.cause == cause).count();
    Some(format!(
        "deadline misses: {} stretch(es) described: {} while this monitor, on another CPU, was kept from running too (the computer stalled), {} while a timer of the loop's CPU fired late (the CPU held from the loop), {} with the chain's own hop slow (`deadline_miss_evidence`)",
        evidence.len(),
        count("computer stalled"),
        count("loop CPU held"),
        count("chain late"),
    ))
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
        let mut m = Misses::new(0, MS);
        feed(&mut m, 0..100, 0, Some((90, 3, 4 * MS)));
        for t in 0..=10 {
            m.tick(t * 10 * MS);
        }
        m.on_late(3, 100 * MS);
        for t in 11..=24 {
            m.tick(t * 10 * MS);
        }
        assert!(m.described.is_empty(), "awaits the late stamps");
        m.tick(100 * MS + SETTLE_NS);
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
        let mut m = Misses::new(0, MS);
        m.tick(0);
        feed(&mut m, 0..50, 0, None);
        // The monitor woke 30 ms late, and the plant counted 20 late; the
        // chain answered the readings after 49 only once it ran again.
        m.tick(40 * MS);
        m.on_late(20, 40 * MS);
        ticks(&mut m, 50 * MS, 40 * MS + SETTLE_NS);
        let e = &m.described[0];
        assert_eq!(e.cause, "computer stalled");
        assert_eq!(e.unanswered_readings, 0, "{e:?}");
        assert!((e.monitor_stalled_ms - 30.0).abs() < 1e-9, "{e:?}");
    }

    /// The monitor's ticks every 10 ms over `from..=to` ns.
    fn ticks(m: &mut Misses, from: u64, to: u64) {
        for t in (from..=to).step_by(10 * MS as usize) {
            m.tick(t);
        }
    }

    /// Readings 0 to 39 answered on time, and looked at: no miss yet.
    fn forty_readings_on_time() -> Misses {
        let mut m = Misses::new(0, MS);
        feed(&mut m, 0..40, 0, None);
        ticks(&mut m, 0, 40 * MS);
        m.on_late(0, 40 * MS);
        m
    }

    #[test]
    fn a_miss_while_the_wire_delivered_late_is_the_loop_cpu_held() {
        let mut m = forty_readings_on_time();
        feed(&mut m, 40..50, 0, Some((45, 0, 3 * MS)));
        // The wire's status: a frame due in reading 45's period came 3 ms
        // late; one long before the stretch is not its evidence.
        m.on_wire(45 * MS + 400_000, 3 * MS);
        m.on_wire(2 * MS, 9 * MS);
        m.on_late(1, 50 * MS);
        ticks(&mut m, 50 * MS, 50 * MS + SETTLE_NS);
        let e = &m.described[0];
        assert_eq!(e.cause, "loop CPU held", "{e:?}");
        assert_eq!(e.wire_late_us, Some(3000.0), "{e:?}");
        assert_eq!(e.reading_late_us, Some(0.0), "{e:?}");
    }

    #[test]
    fn a_reading_taken_late_for_its_period_is_the_loop_cpu_held() {
        let mut m = forty_readings_on_time();
        // The plant's timer for reading 40 fired 1.5 ms late.
        for stage in 0..STAGES.len() {
            m.stamp(stage, 40, 41_500_000, 41_500_000 + (stage as u64 + 1) * 10_000);
        }
        m.on_late(1, 42 * MS);
        ticks(&mut m, 50 * MS, 50 * MS + SETTLE_NS);
        let e = &m.described[0];
        assert_eq!(e.cause, "loop CPU held", "{e:?}");
        assert_eq!(e.reading_late_us, Some(1500.0), "{e:?}");
        assert_eq!(e.wire_late_us, None, "{e:?}");
    }

    #[test]
    fn a_reading_the_valve_never_answered_is_counted() {
        let mut m = Misses::new(0, MS);
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
        for t in 3..=17 {
            m.tick(t * 10 * MS);
        }
        assert_eq!(m.described[0].unanswered_readings, 2, "{:?}", m.described[0]);
    }

    #[test]
    fn a_stage_that_spins_holds_the_timers_back_but_is_the_chain_late() {
        let mut m = forty_readings_on_time();
        // The torque stage spun from reading 40 for 20 ms: the plant's
        // next reading came 19 ms late, and reading 40 was never answered.
        for stage in 0..STAGES.len() - 2 {
            m.stamp(stage, 40, 40 * MS, 40 * MS + (stage as u64 + 1) * 10_000);
        }
        feed(&mut m, 41..45, 19 * MS, None);
        m.on_late(2, 60 * MS);
        ticks(&mut m, 50 * MS, 60 * MS + SETTLE_NS);
        let e = &m.described[0];
        assert_eq!(e.reading_late_us, Some(19_000.0), "{e:?}");
        assert_eq!(e.cause, "chain late", "{e:?}");
    }

    #[test]
    fn a_miss_counted_just_before_the_end_is_described_with_what_came() {
        let mut m = Misses::new(0, MS);
        feed(&mut m, 0..20, 0, None);
        ticks(&mut m, 0, 20 * MS);
        m.on_late(1, 20 * MS);
        let (described, not_described) = m.finish();
        assert_eq!((described.len(), not_described), (1, 0), "{described:?}");
        assert_eq!(described[0].cause, "chain late");
    }

    #[test]
    fn beyond_the_kept_ones_misses_are_counted_not_described() {
        let mut m = Misses::new(0, MS);
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
