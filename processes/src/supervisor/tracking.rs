//! The loop's tracking error by reading, kept for a few seconds: what a
//! swap is judged by.

/// The tracking error (reference − measured angle, rad) of the newest
/// readings, by sequence number, in a ring.
pub(super) struct TrackingLog {
    entries: Vec<(u64, f64)>,
    next: usize,
    filled: usize,
}

impl TrackingLog {
    /// Room for `capacity` readings, allocated once.
    pub(super) fn with_capacity(capacity: usize) -> Self {
        Self {
            entries: vec![(0, 0.0); capacity.max(1)],
            next: 0,
            filled: 0,
        }
    }

    pub(super) fn push(&mut self, seq: u64, error: f64) {
        self.entries[self.next] = (seq, error);
        self.next = (self.next + 1) % self.entries.len();
        self.filled = (self.filled + 1).min(self.entries.len());
    }

    /// The rms of the finite errors of readings `from..to` and how many
    /// there were; `None` when there were none.
    pub(super) fn rms_between(&self, from: u64, to: u64) -> Option<(f64, usize)> {
        let (sum, count) = self.entries[..self.filled]
            .iter()
            .filter(|(seq, error)| (from..to).contains(seq) && error.is_finite())
            .fold((0.0, 0usize), |(sum, count), (_, error)| {
                (sum + error * error, count + 1)
            });
        (count > 0).then(|| ((sum / count as f64).sqrt(), count))
    }

    /// The newest reading logged.
    pub(super) fn newest(&self) -> Option<u64> {
        (self.filled > 0).then(|| self.entries[(self.next + self.entries.len() - 1) % self.entries.len()].0)
    }
}

/// Whether a swap made tracking worse enough to be undone: its rms over
/// the window after exceeds `factor` times the rms before, and `floor`.
pub(super) fn worse_enough(before: f64, after: f64, factor: f64, floor: f64) -> bool {
    after > factor * before && after > floor
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rms_is_over_the_readings_asked_for_and_the_ring_forgets_the_oldest() {
        let mut log = TrackingLog::with_capacity(4);
        assert_eq!(log.rms_between(0, 10), None);
        for (seq, error) in [(1, 3.0), (2, 4.0), (3, f64::NAN), (4, 0.0), (5, 0.0)] {
            log.push(seq, error);
        }
        assert_eq!(log.newest(), Some(5));
        // Reading 1 was overwritten; the NaN is left out.
        let (rms, count) = log.rms_between(0, 10).expect("readings");
        assert_eq!(count, 3);
        assert!((rms - (16.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(log.rms_between(2, 3).map(|(r, _)| r), Some(4.0));
    }

    #[test]
    fn a_variant_is_undone_only_when_it_is_both_worse_by_the_factor_and_above_the_floor() {
        // The crane paper's H∞ on this rotator: 0.18 rad rms against 0.004.
        assert!(worse_enough(0.004, 0.18, 3.0, 0.1));
        // The PID outer loop after a swap: twelve times worse, within 3°.
        assert!(!worse_enough(0.004, 0.05, 3.0, 0.1));
        // Worse, but not by the factor.
        assert!(!worse_enough(0.05, 0.12, 3.0, 0.1));
    }
}
