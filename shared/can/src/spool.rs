//! The valve's spool against its set point: the spool position the valve
//! reports (0x6301:1, in its status TPDO) must follow the set point the
//! master sends. A spool that stays away from it (stuck, jammed by dirt, a
//! broken pilot stage) or moves the other way (a wrong sign in wiring or
//! parameters) for longer than the spool's own dynamics explain is a
//! fault. Plain state driven by the statuses; the caller says when the
//! valve was following a set point (Active and driven).

/// A set point this far from neutral has a sign the spool must share.
pub(crate) const SIGNED_SET_POINT: f64 = 0.1;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SpoolFault {
    /// Away from the set point for the hold time.
    Stuck { set_point: f64, actual: f64, hold_ms: u64 },
    /// On the other side of neutral, near the set point's mirror, for the
    /// hold time.
    WrongSign { set_point: f64, actual: f64, hold_ms: u64 },
}

impl std::fmt::Display for SpoolFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Short: it is a latched fault's meaning, 128 bytes at most.
        let (what, set_point, actual, hold_ms) = match *self {
            Self::Stuck {
                set_point,
                actual,
                hold_ms,
            } => ("stuck", set_point, actual, hold_ms),
            Self::WrongSign {
                set_point,
                actual,
                hold_ms,
            } => ("wrong sign", set_point, actual, hold_ms),
        };
        write!(
            f,
            "spool {what}: at {:.0} % for {hold_ms} ms, set point {:.0} %",
            actual * 100.0,
            set_point * 100.0
        )
    }
}

/// The spool's own lag is inside the tolerance, and its settling (a
/// lightly damped spool rings for a few hundred ms after a step) inside
/// the hold time: `[can.valve] spool_tolerance`, `spool_hold_ms`.
#[derive(Debug, Clone, Copy)]
pub struct SpoolWatch {
    tolerance: f64,
    hold_ns: u64,
    away_since_ns: Option<u64>,
    wrong_since_ns: Option<u64>,
}

impl SpoolWatch {
    pub fn new(tolerance: f64, hold_ms: u32) -> Self {
        Self {
            tolerance,
            hold_ns: u64::from(hold_ms) * 1_000_000,
            away_since_ns: None,
            wrong_since_ns: None,
        }
    }

    /// A status reporting the spool at `actual` while the valve followed
    /// `set_point` (both in [-1, 1]); `None` for a status of a valve that
    /// was not following one (not Active, or neutral by the master's
    /// choice), which starts the watch afresh.
    pub fn on_status(&mut self, following: Option<f64>, actual: f64, now_ns: u64) -> Option<SpoolFault> {
        let Some(set_point) = following.filter(|_| actual.is_finite()) else {
            self.away_since_ns = None;
            self.wrong_since_ns = None;
            return None;
        };
        // A wrong sign follows the set point's mirror; a spool that stays
        // put while the set point crosses to the other side is stuck.
        let wrong = set_point.abs() >= SIGNED_SET_POINT
            && actual * set_point < 0.0
            && actual.abs() >= SIGNED_SET_POINT / 2.0
            && (actual + set_point).abs() <= self.tolerance;
        let away = (actual - set_point).abs() > self.tolerance;
        let hold_ns = self.hold_ns;
        let held = |since: &mut Option<u64>, now: bool| {
            if !now {
                *since = None;
                return false;
            }
            now_ns.saturating_sub(*since.get_or_insert(now_ns)) >= hold_ns
        };
        let wrong_held = held(&mut self.wrong_since_ns, wrong);
        let away_held = held(&mut self.away_since_ns, away);
        let hold_ms = hold_ns / 1_000_000;
        if wrong_held {
            Some(SpoolFault::WrongSign {
                set_point,
                actual,
                hold_ms,
            })
        } else if away_held {
            Some(SpoolFault::Stuck {
                set_point,
                actual,
                hold_ms,
            })
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn fresh() -> SpoolWatch {
        SpoolWatch::new(0.25, 100)
    }

    #[test]
    fn a_spool_that_lags_is_fine_one_that_stays_away_or_goes_the_other_way_is_not() {
        let mut watch = fresh();
        // Lagging by a few periods at the rate limit: fine.
        for k in 0..200u64 {
            let set_point = (k as f64 * 0.01).min(0.8);
            let actual = (set_point - 0.05).max(0.0);
            assert_eq!(watch.on_status(Some(set_point), actual, k * MS), None);
        }
        // Stuck at 10 % while the set point is at 80 %.
        let mut stuck = None;
        for k in 200..400u64 {
            stuck = stuck.or(watch.on_status(Some(0.8), 0.1, k * MS).map(|f| (k, f)));
        }
        let (at, fault) = stuck.expect("stuck");
        assert_eq!(at, 300, "after the hold time");
        assert!(matches!(fault, SpoolFault::Stuck { .. }));
        assert_eq!(fault.to_string(), "spool stuck: at 10 % for 100 ms, set point 80 %");

        let mut watch = fresh();
        let mut wrong = None;
        for k in 0..200u64 {
            wrong = wrong.or(watch.on_status(Some(0.3), -0.2, k * MS));
        }
        assert!(matches!(wrong, Some(SpoolFault::WrongSign { .. })), "{wrong:?}");
    }

    #[test]
    fn a_spool_stuck_on_one_side_while_the_set_point_crosses_is_stuck() {
        let mut watch = SpoolWatch::new(0.3, 500);
        // Stuck at 15 %; the set point goes from 0 to −100 % in 300 ms and
        // stays there: on the other side, but nowhere near the mirror.
        let mut fault = None;
        for k in 0..1500u64 {
            let set_point = -(k as f64 / 300.0).min(1.0);
            fault = fault.or(watch.on_status(Some(set_point), 0.15, k * MS));
        }
        assert!(matches!(fault, Some(SpoolFault::Stuck { .. })), "{fault:?}");
    }

    #[test]
    fn the_watch_starts_afresh_when_the_valve_stops_following() {
        let mut watch = fresh();
        for k in 0..90u64 {
            assert_eq!(watch.on_status(Some(0.8), 0.0, k * MS), None);
        }
        assert_eq!(watch.on_status(None, 0.0, 90 * MS), None);
        for k in 91..180u64 {
            assert_eq!(watch.on_status(Some(0.8), 0.0, k * MS), None, "{k}");
        }
    }
}
