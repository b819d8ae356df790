//! Limit-cycle detection on a command signal.
//!
//! A limit cycle is a sustained, regular oscillation: the command swings
//! through a large part of its range and back, again and again, each half
//! cycle about as short as the last. A controller tracking a rich reference
//! also reverses its command, but irregularly: on the papers' sum-of-sines
//! runs the H∞ torque loop swings half its range four times in a second,
//! yet never more than three swings in a row come within 150 ms of one
//! another, while an over-tuned PID's limit cycle does so without end. So
//! the detector counts consecutive quick reversals, not reversals per
//! window.
//!
//! A reversal is a swing of at least `swing` from the last extreme in the
//! opposite direction (hysteresis, so noise and small corrections are not
//! counted); it is quick when it comes within `half_period` samples of the
//! previous reversal.

use crate::{require, require_positive, ControlError};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LimitCycleParams {
    /// The smallest swing counted, peak to peak, in command units.
    pub swing: f64,
    /// A reversal within this many samples of the previous one is quick.
    pub half_period: u64,
    /// This many quick reversals in a row make a limit cycle (0: never).
    pub reversals: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Heading {
    /// No swing seen yet: the extremes since the start.
    Unknown {
        low: f64,
        high: f64,
    },
    /// Rising since a low; `high` is the highest since.
    Up {
        high: f64,
    },
    Down {
        low: f64,
    },
}

#[derive(Debug, Clone)]
pub struct LimitCycleDetector {
    params: LimitCycleParams,
    heading: Option<Heading>,
    last_reversal: Option<u64>,
    quick_in_a_row: u64,
}

impl LimitCycleDetector {
    pub fn new(params: LimitCycleParams) -> Result<Self, ControlError> {
        require_positive("swing", params.swing)?;
        require(
            "half_period",
            params.half_period as f64,
            params.half_period > 0,
            "must be at least one sample",
        )?;
        Ok(Self {
            params,
            heading: None,
            last_reversal: None,
            quick_in_a_row: 0,
        })
    }

    /// Forgets the signal: a new source of commands starts afresh.
    pub fn reset(&mut self) {
        self.heading = None;
        self.last_reversal = None;
        self.quick_in_a_row = 0;
    }

    /// Feeds sample `value` at sample index `at` (increasing; gaps allowed).
    /// Returns whether the signal is now in a limit cycle.
    pub fn update(&mut self, at: u64, value: f64) -> bool {
        if !value.is_finite() {
            return self.in_limit_cycle();
        }
        let swing = self.params.swing;
        let (heading, reversed) = match self.heading {
            None => (
                Heading::Unknown {
                    low: value,
                    high: value,
                },
                false,
            ),
            Some(Heading::Unknown { low, high }) => {
                if high - value >= swing {
                    (Heading::Down { low: value }, true)
                } else if value - low >= swing {
                    (Heading::Up { high: value }, true)
                } else {
                    (
                        Heading::Unknown {
                            low: low.min(value),
                            high: high.max(value),
                        },
                        false,
                    )
                }
            }
            Some(Heading::Up { high }) => {
                if high - value >= swing {
                    (Heading::Down { low: value }, true)
                } else {
                    (Heading::Up { high: high.max(value) }, false)
                }
            }
            Some(Heading::Down { low }) => {
                if value - low >= swing {
                    (Heading::Up { high: value }, true)
                } else {
                    (Heading::Down { low: low.min(value) }, false)
                }
            }
        };
        self.heading = Some(heading);
        if reversed {
            let quick = self
                .last_reversal
                .is_some_and(|last| at.saturating_sub(last) <= self.params.half_period);
            self.quick_in_a_row = if quick { self.quick_in_a_row + 1 } else { 0 };
            self.last_reversal = Some(at);
        } else if self
            .last_reversal
            .is_some_and(|last| at.saturating_sub(last) > self.params.half_period)
        {
            // The oscillation stopped: a slow reversal later starts a new run.
            self.quick_in_a_row = 0;
        }
        self.in_limit_cycle()
    }

    pub fn in_limit_cycle(&self) -> bool {
        self.params.reversals > 0 && self.quick_in_a_row >= self.params.reversals
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn detector() -> LimitCycleDetector {
        LimitCycleDetector::new(LimitCycleParams {
            swing: 1.0,
            half_period: 150,
            reversals: 12,
        })
        .expect("valid")
    }

    /// A square-ish wave of `amplitude` and `period` samples, rate-limited
    /// like the valve's command.
    fn wave(amplitude: f64, period: u64, at: u64) -> f64 {
        let phase = (at % period) as f64 / period as f64;
        (amplitude * (2.0 * std::f64::consts::PI * phase).sin() * 3.0).clamp(-amplitude, amplitude)
    }

    #[test]
    fn a_sustained_large_fast_oscillation_is_a_limit_cycle() {
        let mut d = detector();
        // 5 Hz at 1 kHz: a reversal every 100 samples.
        let first = (0..3000).find(|&at| d.update(at, wave(0.9, 200, at)));
        let first = first.expect("detected");
        // The 12th quick reversal after the first: about 13 half periods.
        assert!((1100..=1500).contains(&first), "detected at {first}");
    }

    #[test]
    fn small_or_slow_oscillations_are_not() {
        let mut small = detector();
        assert!(!(0..10_000).any(|at| small.update(at, wave(0.45, 200, at))));
        let mut slow = detector();
        // 2 Hz: reversals 250 samples apart.
        assert!(!(0..10_000).any(|at| slow.update(at, wave(0.9, 500, at))));
    }

    #[test]
    fn a_pause_in_the_oscillation_starts_the_count_again() {
        let mut d = detector();
        let mut detected = false;
        for burst in 0..5 {
            let start = burst * 2000;
            // Ten half periods of oscillation, then a long rest.
            for at in start..start + 1000 {
                detected |= d.update(at, wave(0.9, 200, at));
            }
            for at in start + 1000..start + 2000 {
                detected |= d.update(at, 0.0);
            }
        }
        assert!(!detected);
    }

    #[test]
    fn reset_forgets_and_zero_reversals_never_detects() {
        let mut d = detector();
        let at = (0..3000)
            .find(|&at| d.update(at, wave(0.9, 200, at)))
            .expect("detected");
        d.reset();
        assert!(!d.update(at + 1, wave(0.9, 200, at + 1)));
        let mut off = LimitCycleDetector::new(LimitCycleParams {
            reversals: 0,
            ..LimitCycleParams {
                swing: 1.0,
                half_period: 150,
                reversals: 12,
            }
        })
        .expect("valid");
        assert!(!(0..5000).any(|at| off.update(at, wave(0.9, 200, at))));
    }

    #[test]
    fn nan_is_ignored_and_bad_parameters_are_refused() {
        let mut d = detector();
        assert!(!d.update(0, f64::NAN));
        assert!(LimitCycleDetector::new(LimitCycleParams {
            swing: 0.0,
            half_period: 150,
            reversals: 12
        })
        .is_err());
        assert!(LimitCycleDetector::new(LimitCycleParams {
            swing: 1.0,
            half_period: 0,
            reversals: 12
        })
        .is_err());
    }
}
