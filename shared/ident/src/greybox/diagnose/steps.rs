//! A delay told from a lag at the command's steps. Between steps a valve
//! or oil lag takes up a pure delay's phase (a loop that limit-cycles is
//! nearly one frequency, where any lag matches any delay), so the gain of
//! a delay lives in the few segments after the command's steps, too few
//! for the segment tests (5 of 36 can carry a paired t to 2.4 at most).
//! Here the validation's segments start just before each large step, and
//! the share of their summed error that the delay removes is judged sample
//! by sample: the pressures' where they are measured, else the angle's.

use hydractl_plant::effects::Effects;
use hydractl_plant::PlantParams;

use super::*;

/// The least change of the command within [`STEP_LEAD_S`] that counts as a
/// step: a quarter of the valve's travel.
const STEP_SIZE: f64 = 0.25;

/// How far before a step its window starts, s: the step itself inside it.
const STEP_LEAD_S: f64 = 0.005;

/// Steps the test needs: fewer are too little evidence of a delay.
const MIN_STEPS: usize = 3;

/// The longest sample period at which a step's first milliseconds show.
const MAX_STEP_DT_S: f64 = 0.002;

/// The share of the delay's α the step test takes; the segment tests share
/// the rest.
pub(super) const STEP_ALPHA_SHARE: f64 = 0.25;

/// The validation's segments re-anchored at the command's large steps.
pub(super) struct StepWindows {
    /// The part predicted: the hydraulic (pressures) or the whole (angle).
    part: Part,
    windows: Vec<Range<usize>>,
    /// The windows' starts and each stretch's first sample, ascending:
    /// where a prediction starts from the measured state.
    starts: Vec<usize>,
}

impl StepWindows {
    /// For a delay on the hydraulic or the whole part of a record sampled
    /// finely enough with [`MIN_STEPS`] steps in `validation`; `None`
    /// otherwise.
    pub(super) fn find(kind: EffectKind, part: Part, signals: &Signals, validation: Range<usize>) -> Option<Self> {
        let predicts_the_valve = matches!(part, Part::Hydraulic | Part::Whole);
        if kind != EffectKind::TimeDelay || !predicts_the_valve || signals.dt > MAX_STEP_DT_S {
            return None;
        }
        let windows = step_windows(signals, validation.clone());
        if windows.len() < MIN_STEPS {
            return None;
        }
        let mut starts: Vec<usize> = windows
            .iter()
            .map(|w| w.start)
            .chain(signals.stretches().map(|s| s.start.max(validation.start)))
            .collect();
        starts.sort_unstable();
        starts.dedup();
        Some(Self { part, windows, starts })
    }

    /// The part's outputs predicted over `validation`, each window starting
    /// from the measured state.
    pub(super) fn predict(
        &self,
        plant: &PlantParams,
        effects: &Effects,
        signals: &Signals,
        validation: Range<usize>,
    ) -> Prediction {
        let mut out = Prediction::new(signals.len());
        if self.part == Part::Whole {
            crate::greybox::predict_whole_from(plant, effects, signals, validation, &self.starts, &mut out);
        } else {
            crate::greybox::predict_hydraulic_from(plant, effects, signals, validation, &self.starts, &mut out);
        }
        out
    }

    /// The error-share t of `after` against `before` over the windows'
    /// samples, at `alpha`.
    pub(super) fn test(
        &self,
        signals: &Signals,
        plant: &PlantParams,
        before: &Prediction,
        after: &Prediction,
        alpha: f64,
    ) -> PairedTest {
        let samples = self.windows.iter().flat_map(|w| w.clone());
        let errors: Vec<(f64, f64)> = if self.part == Part::Whole {
            samples
                .filter(|&k| before.theta[k].is_finite() && after.theta[k].is_finite())
                .map(|k| {
                    let y = signals.theta[k];
                    ((y - before.theta[k]).powi(2), (y - after.theta[k]).powi(2))
                })
                .collect()
        } else {
            samples
                .filter_map(|k| pressure_errors(signals, plant, before, after, k))
                .collect()
        };
        // The test counts the steps; its effective number is the samples'.
        PairedTest {
            kind: SegmentTest::StepWindows,
            segments: self.windows.len(),
            ..error_share(&errors, alpha)
        }
    }
}

/// The summed squared errors of both chambers at sample `k`, before and
/// after; `None` where no chamber counts. A chamber that both predictions
/// hold at the same tank or supply bound is left out: the two models agree
/// on it by construction, so it carries no evidence between them.
fn pressure_errors(
    signals: &Signals,
    plant: &PlantParams,
    before: &Prediction,
    after: &Prediction,
    k: usize,
) -> Option<(f64, f64)> {
    let tolerance = 1e-9 * plant.supply_pressure.abs().max(1.0);
    let bound = |p: f64| {
        if (p - plant.tank_pressure).abs() <= tolerance {
            Some(false)
        } else if (p - plant.supply_pressure).abs() <= tolerance {
            Some(true)
        } else {
            None
        }
    };
    let chambers = [
        (&signals.p_a, &before.p_a, &after.p_a),
        (&signals.p_b, &before.p_b, &after.p_b),
    ];
    let (mut error_before, mut error_after, mut counted) = (0.0, 0.0, 0);
    for (y, b, a) in &chambers {
        let both_bound = bound(b[k]).is_some() && bound(b[k]) == bound(a[k]);
        if b[k].is_finite() && a[k].is_finite() && !both_bound {
            error_before += (y[k] - b[k]).powi(2);
            error_after += (y[k] - a[k]).powi(2);
            counted += 1;
        }
    }
    (counted > 0).then_some((error_before, error_after))
}

/// One segment from [`STEP_LEAD_S`] before each step of the command by
/// [`STEP_SIZE`] or more within [`STEP_LEAD_S`], none overlapping another
/// and none across readings left out.
pub(super) fn step_windows(signals: &Signals, range: Range<usize>) -> Vec<Range<usize>> {
    let lead = ((STEP_LEAD_S / signals.dt).round() as usize).max(1);
    let length = ((crate::greybox::SEGMENT_S / signals.dt).round() as usize).max(2);
    let mut windows = Vec::new();
    for stretch in signals.stretches() {
        let (start, end) = (stretch.start.max(range.start), stretch.end.min(range.end));
        let mut k = start;
        while k + lead < end {
            if (signals.u[k + lead] - signals.u[k]).abs() >= STEP_SIZE {
                windows.push(k..(k + length).min(end));
                k += length;
            } else {
                k += 1;
            }
        }
    }
    windows
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Dataset;

    /// 20 s at 1 kHz, 100 bar in both chambers, the command ±0.5 stepping
    /// every 2 s; readings 14.2–14.3 s left out when `gap`.
    fn record(gap: bool) -> Signals {
        let n = 20_000;
        let keep: Vec<usize> = (0..n).filter(|&k| !gap || !(14_200..14_300).contains(&k)).collect();
        let column = |f: &dyn Fn(usize) -> f64| keep.iter().map(|&k| f(k)).collect::<Vec<f64>>();
        let columns = vec![
            ("t", column(&|k| k as f64 * 1e-3)),
            ("theta", column(&|k| 1e-3 * (k as f64 * 1e-3).sin())),
            ("u", column(&|k| if (k / 2000) % 2 == 0 { 0.5 } else { -0.5 })),
            ("p_a", column(&|_| 100.0)),
            ("p_b", column(&|_| 100.0)),
        ];
        Signals::from_dataset(&Dataset::from_columns("steps.csv", columns)).expect("a valid record")
    }

    #[test]
    fn a_window_starts_just_before_each_step_and_none_crosses_a_gap() {
        let whole = record(false);
        let starts: Vec<usize> = step_windows(&whole, 10_000..20_000).iter().map(|w| w.start).collect();
        // The step at 10.000 s is the validation's first sample: no step
        // shows within it.
        assert_eq!(starts, vec![11_995, 13_995, 15_995, 17_995]);
        // Readings left out 14.2–14.3 s end a stretch at 14.2 s: the step
        // at 14 s keeps its window, cut where the stretch ends.
        let gapped = record(true);
        let windows = step_windows(&gapped, 10_000..gapped.len());
        assert_eq!(windows.len(), 4);
        assert_eq!(windows[1], 13_995..14_200);
        assert!(windows
            .iter()
            .all(|w| gapped.stretch_start(w.start) == gapped.stretch_start(w.end - 1)));
    }

    fn delay_windows(signals: &Signals) -> StepWindows {
        StepWindows::find(EffectKind::TimeDelay, Part::Hydraulic, signals, 10_000..20_000).expect("four steps")
    }

    /// Before: 5 bar off for 150 ms after each window's start, a 0.1 bar
    /// ripple elsewhere; after, the first 150 ms's error scaled by `kept`.
    fn predictions(signals: &Signals, windows: &StepWindows, kept: f64) -> (Prediction, Prediction) {
        let (mut before, mut after) = (Prediction::new(signals.len()), Prediction::new(signals.len()));
        for w in &windows.windows {
            for k in w.clone() {
                let ripple = 0.1e5 * (k as f64 * 0.37).sin();
                let early = if k - w.start < 150 {
                    5e5 * (1.0 + 0.3 * (k as f64 * 0.11).cos())
                } else {
                    0.0
                };
                for (b, a, y) in [
                    (&mut before.p_a, &mut after.p_a, &signals.p_a),
                    (&mut before.p_b, &mut after.p_b, &signals.p_b),
                ] {
                    b[k] = y[k] + early + ripple;
                    a[k] = y[k] + kept * early + ripple;
                }
            }
        }
        (before, after)
    }

    #[test]
    fn a_fall_at_the_steps_passes_and_a_sliver_does_not() {
        let signals = record(false);
        let plant = PlantParams::default();
        let windows = delay_windows(&signals);
        let (before, after) = predictions(&signals, &windows, 0.45);
        let test = windows.test(&signals, &plant, &before, &after, 2.5e-4);
        assert!(test.passed(), "{test:?}");
        assert_eq!((test.kind, test.segments), (SegmentTest::StepWindows, 4));
        let (before, after) = predictions(&signals, &windows, 0.995);
        let test = windows.test(&signals, &plant, &before, &after, 2.5e-4);
        assert!(!test.passed(), "{test:?}");
        // Only a delay on the valve's path is judged at the steps: on the
        // pressures, or on the angle where no pressures are measured.
        assert!(StepWindows::find(EffectKind::Deadzone, Part::Hydraulic, &signals, 10_000..20_000).is_none());
        assert!(StepWindows::find(EffectKind::TimeDelay, Part::Mechanical, &signals, 10_000..20_000).is_none());
        assert!(StepWindows::find(EffectKind::TimeDelay, Part::Whole, &signals, 10_000..20_000).is_some());
    }

    #[test]
    fn a_chamber_both_models_hold_at_a_bound_carries_no_evidence() {
        let signals = record(false);
        let plant = PlantParams::default();
        let windows = delay_windows(&signals);
        let (before, after) = predictions(&signals, &windows, 0.45);
        let plain = windows.test(&signals, &plant, &before, &after, 2.5e-4);
        let (mut clamped_before, mut clamped_after) = (before.clone(), after.clone());
        for k in windows.windows[1].start + 200..windows.windows[1].start + 400 {
            clamped_before.p_a[k] = plant.supply_pressure;
            clamped_after.p_a[k] = plant.supply_pressure;
        }
        let clamped = windows.test(&signals, &plant, &clamped_before, &clamped_after, 2.5e-4);
        let mut unclamped = (before.clone(), after.clone());
        for k in windows.windows[1].start + 200..windows.windows[1].start + 400 {
            // The same samples with p_a's error nil on both: what the
            // mask must leave.
            unclamped.0.p_a[k] = signals.p_a[k];
            unclamped.1.p_a[k] = signals.p_a[k];
        }
        let reference = windows.test(&signals, &plant, &unclamped.0, &unclamped.1, 2.5e-4);
        assert!(plain.passed());
        assert!(
            (clamped.statistic - reference.statistic).abs() < 1e-9 * reference.statistic.abs(),
            "{clamped:?} against {reference:?}"
        );
    }

    #[test]
    fn without_pressures_the_angle_in_the_windows_is_judged() {
        let signals = record(false);
        let plant = PlantParams::default();
        let windows =
            StepWindows::find(EffectKind::TimeDelay, Part::Whole, &signals, 10_000..20_000).expect("four steps");
        let (mut before, mut after) = (Prediction::new(signals.len()), Prediction::new(signals.len()));
        for w in &windows.windows {
            for k in w.clone() {
                let early = if k - w.start < 150 { 2e-3 } else { 0.0 };
                let noise = 1e-5 * (k as f64 * 0.37).sin();
                before.theta[k] = signals.theta[k] + early + noise;
                after.theta[k] = signals.theta[k] + 0.3 * early + noise;
            }
        }
        let test = windows.test(&signals, &plant, &before, &after, 2.5e-4);
        assert!(test.passed(), "{test:?}");
        // A model no nearer the angle than the baseline gains nothing there.
        let test = windows.test(&signals, &plant, &before, &before, 2.5e-4);
        assert!(!test.passed(), "{test:?}");
    }
}
