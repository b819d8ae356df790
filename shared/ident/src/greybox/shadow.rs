//! The model beside the machine: the shadow compares a fitted model with
//! the live samples over a sliding window, as `compare` does, and watches
//! each part's residual for a change the model's own validation did not
//! show (a valve wearing, friction rising in the cold).
//!
//! The statistic is each 0.5 s shooting segment's residual RMS (Pa for the
//! hydraulic part, rad for the angle), on a log scale, standardized by the
//! spread the same segments showed on the model's validation data
//! ([`SegmentSpread`], kept in the model file). A one-sided CUSUM on it
//! (Page's) alarms on a lasting rise: the thresholds come from the fit; the
//! slack and the decision interval are the textbook's for a shift of one
//! standard deviation, the interval set high enough that the model's own
//! validation residual would alarm once in tens of hours.

use std::collections::BTreeMap;
use std::ops::Range;

use hydractl_plant::effects::Effects;
use hydractl_plant::PlantParams;
use serde::{Deserialize, Serialize};

use super::compare::{compare, residuals, Comparison};
use super::{predict, segments, Diagnosis, Model, ModelError, Part, Prediction, Signals};
use hydractl_plant::EffectKind;

/// How one part's segment residual spread on the model's validation data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentSpread {
    /// Validation segments it was measured on.
    pub segments: usize,
    /// Mean and standard deviation of ln(segment residual RMS), the RMS in
    /// Pa (hydraulic part) or rad (angle).
    pub mean_log_rms: f64,
    pub std_log_rms: f64,
}

/// The smallest spread the test assumes: a model whose validation segments
/// happened to agree to within 5 % would otherwise alarm on noise.
const MIN_STD_LOG_RMS: f64 = 0.05;

/// Segments of live data an adopted model is calibrated on before the test
/// judges it (30 s): the few validation segments of a diagnosis window
/// show one stretch of the machine's work, and a spread measured on them
/// alone alarmed on a residual only 17 % above it.
pub const CALIBRATION_SEGMENTS: usize = 60;

/// The residual RMS of each part over each shooting segment of `range`.
pub(crate) fn segment_rms(signals: &Signals, prediction: &Prediction, range: Range<usize>) -> BTreeMap<Part, Vec<f64>> {
    let mut out: BTreeMap<Part, Vec<f64>> = BTreeMap::new();
    for segment in segments(signals, range) {
        let n = segment.len().max(1) as f64;
        let mut pressure = 0.0;
        let mut angle = 0.0;
        for k in segment {
            let [(_, a), (_, b), (_, t)] = residuals(signals, prediction, k);
            pressure += (a * a + b * b) / 2.0;
            angle += t * t;
        }
        for part in signals.parts() {
            let sum = if part == Part::Hydraulic { pressure } else { angle };
            out.entry(part).or_default().push((sum / n).sqrt());
        }
    }
    out
}

/// Each part's [`SegmentSpread`] on `range` of `signals`: what `fit` and
/// `add` keep in the model's history for the shadow.
pub fn validation_spread(
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
) -> BTreeMap<String, SegmentSpread> {
    let prediction = predict(plant, effects, signals, range.clone());
    segment_rms(signals, &prediction, range)
        .into_iter()
        .filter_map(|(part, rms)| {
            let logs: Vec<f64> = rms
                .iter()
                .filter(|r| **r > 0.0 && r.is_finite())
                .map(|r| r.ln())
                .collect();
            Some((part.name().to_owned(), spread_of(&logs)?))
        })
        .collect()
}

/// The mean and spread of log segment residuals; none from fewer than two.
fn spread_of(logs: &[f64]) -> Option<SegmentSpread> {
    if logs.len() < 2 {
        return None;
    }
    let mean = logs.iter().sum::<f64>() / logs.len() as f64;
    let var = logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / (logs.len() - 1) as f64;
    Some(SegmentSpread {
        segments: logs.len(),
        mean_log_rms: mean,
        std_log_rms: var.sqrt(),
    })
}

/// The CUSUM's design, in standard deviations of the validation spread.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftTest {
    /// Half the shift to detect quickly (one standard deviation).
    pub slack: f64,
    /// The decision interval: with the slack, an in-control run length of
    /// about 1.4 × 10⁵ segments (Siegmund's approximation), 20 h.
    pub threshold: f64,
}

impl Default for DriftTest {
    fn default() -> Self {
        Self {
            slack: 0.5,
            threshold: 10.0,
        }
    }
}

/// A part whose residual rose beyond the model's validation spread.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriftAlarm {
    pub part: Part,
    /// The regime where the part's residual is largest in the window.
    pub regime: String,
    /// Mean standardized log residual of the segments since the CUSUM last
    /// stood at zero: how far the residual rose, in validation spreads.
    pub size: f64,
    /// The segment residual RMS now against the validation's (a ratio).
    pub rms_ratio: f64,
}

/// One window's assessment.
#[derive(Debug, Clone)]
pub struct Assessment {
    pub comparison: Comparison,
    /// Each part's residual RMS over the window (Pa, rad).
    pub residual_rms: BTreeMap<Part, f64>,
    /// Each part's standardized log residual over the new segments.
    pub normalized: BTreeMap<Part, f64>,
    /// Each part's CUSUM sum; none while an adopted model is calibrated.
    pub cusum: BTreeMap<Part, f64>,
    pub alarms: Vec<DriftAlarm>,
}

/// A part's CUSUM and what it has summed.
#[derive(Debug, Clone, Copy, Default)]
struct Cusum {
    sum: f64,
    /// Segments and their standardized values since the sum left zero.
    run: usize,
    run_total: f64,
}

/// The shadow model and its drift test.
#[derive(Debug, Clone)]
pub struct Shadow {
    model: Model,
    plant: PlantParams,
    effects: Effects,
    reference: BTreeMap<Part, SegmentSpread>,
    /// An adopted model's log segment residuals so far, by part, until
    /// there are [`CALIBRATION_SEGMENTS`]: then they are its reference.
    calibration: Option<BTreeMap<Part, Vec<f64>>>,
    test: DriftTest,
    cusum: BTreeMap<Part, Cusum>,
}

impl Shadow {
    /// The shadow of `model`, which must carry its validation spread (a
    /// model fitted or added to by this version of `hydractl model`).
    pub fn new(model: Model, test: DriftTest) -> Result<Self, ModelError> {
        let reference = reference_of(&model)?;
        let effects = model.effects()?;
        Ok(Self {
            plant: model.plant,
            effects,
            model,
            reference,
            calibration: None,
            test,
            cusum: BTreeMap::new(),
        })
    }

    pub fn model(&self) -> &Model {
        &self.model
    }

    pub fn test(&self) -> DriftTest {
        self.test
    }

    /// Compares the model with the window `signals`, and runs the drift
    /// test over its last `new_segments` segments (those not yet judged).
    pub fn assess(&mut self, signals: &Signals, new_segments: usize) -> Assessment {
        let comparison = compare(&self.plant, &self.effects, signals, 0.0);
        let range = comparison.validation.clone();
        let rms = segment_rms(signals, &comparison.prediction, range.clone());
        let mut residual_rms = BTreeMap::new();
        let mut normalized = BTreeMap::new();
        let mut alarms = Vec::new();
        for (part, segment_rms) in &rms {
            let whole = (segment_rms.iter().map(|r| r * r).sum::<f64>() / segment_rms.len().max(1) as f64).sqrt();
            residual_rms.insert(*part, whole);
        }
        if self.calibrate(&rms, new_segments) {
            return Assessment {
                comparison,
                residual_rms,
                normalized,
                cusum: BTreeMap::new(),
                alarms,
            };
        }
        for (part, segment_rms) in &rms {
            let Some(reference) = self.reference.get(part) else {
                continue;
            };
            let std = reference.std_log_rms.max(MIN_STD_LOG_RMS);
            let fresh = &segment_rms[segment_rms.len().saturating_sub(new_segments)..];
            let cusum = self.cusum.entry(*part).or_default();
            let mut total = 0.0;
            for r in fresh.iter().filter(|r| **r > 0.0 && r.is_finite()) {
                let z = (r.ln() - reference.mean_log_rms) / std;
                total += z;
                cusum.sum = (cusum.sum + z - self.test.slack).max(0.0);
                if cusum.sum == 0.0 {
                    (cusum.run, cusum.run_total) = (0, 0.0);
                } else {
                    cusum.run += 1;
                    cusum.run_total += z;
                }
            }
            normalized.insert(*part, total / fresh.len().max(1) as f64);
            if cusum.sum > self.test.threshold {
                let size = cusum.run_total / cusum.run.max(1) as f64;
                alarms.push(DriftAlarm {
                    part: *part,
                    regime: worst_regime(&comparison, *part),
                    size,
                    rms_ratio: (size * std).exp(),
                });
            }
        }
        let cusum = self.cusum.iter().map(|(p, c)| (*p, c.sum)).collect();
        Assessment {
            comparison,
            residual_rms,
            normalized,
            cusum,
            alarms,
        }
    }

    /// Goes on with `model` (the drift named and added): its reference is
    /// its own residual on the next [`CALIBRATION_SEGMENTS`] of live data,
    /// which it was not fitted on, and the test judges it from then on.
    pub fn adopt(&mut self, model: Model) -> Result<(), ModelError> {
        self.effects = model.effects()?;
        self.plant = model.plant;
        self.model = model;
        self.calibration = Some(BTreeMap::new());
        self.restart();
        Ok(())
    }

    /// True while an adopted model is being calibrated: the new segments
    /// are kept, and once there are enough, their spread is the reference.
    fn calibrate(&mut self, rms: &BTreeMap<Part, Vec<f64>>, new_segments: usize) -> bool {
        let Some(calibration) = &mut self.calibration else {
            return false;
        };
        for (part, segment_rms) in rms {
            let fresh = &segment_rms[segment_rms.len().saturating_sub(new_segments)..];
            calibration
                .entry(*part)
                .or_default()
                .extend(fresh.iter().filter(|r| **r > 0.0 && r.is_finite()).map(|r| r.ln()));
        }
        if calibration.values().any(|logs| logs.len() < CALIBRATION_SEGMENTS) {
            return true;
        }
        self.reference = calibration
            .iter()
            .filter_map(|(part, logs)| Some((*part, spread_of(logs)?)))
            .collect();
        self.calibration = None;
        false
    }

    /// True while an adopted model is calibrated on live data.
    pub fn calibrating(&self) -> bool {
        self.calibration.is_some()
    }

    /// Starts the drift test afresh (after an alarm was handled).
    pub fn restart(&mut self) {
        self.cusum.clear();
    }
}

/// How far an effect's main parameter must move, relative to its value,
/// to be called a change of the machine and not the scatter of a refit.
const MOVED_RELATIVE: f64 = 0.25;
/// …and in standard deviations of its refit on the drifted data.
const MOVED_STDS: f64 = 3.0;

/// An effect the model already has whose main parameter the drifted data
/// moved (friction rising in the cold, a dead-zone wearing wider): the
/// diagnosis tries only effects the model lacks, but refits the model's
/// own on the same data first. The one that moved most, relative to its
/// value, by more than a quarter and three standard deviations; with its
/// refitted parameters.
pub fn moved_effect(model: &Model, diagnosis: &Diagnosis) -> Option<(String, BTreeMap<String, f64>)> {
    let refitted = &diagnosis.baseline_model.effects.0;
    model
        .effects
        .0
        .iter()
        .filter_map(|(name, params)| {
            let main = EffectKind::from_name(name).ok()?.main_param()?;
            let before = *params.get(main)?;
            let after_params = refitted.get(name)?;
            let after = *after_params.get(main)?;
            let moved = (after - before).abs();
            let std = diagnosis
                .baseline
                .uncertainty
                .std
                .get(&format!("{name}.{main}"))
                .copied();
            let relative = moved / before.abs().max(f64::MIN_POSITIVE);
            (relative > MOVED_RELATIVE && std.is_none_or(|s| moved > MOVED_STDS * s))
                .then(|| (relative, name.clone(), after_params.clone()))
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, name, params)| (name, params))
}

/// The validation spread the model's last history step kept, by part.
fn reference_of(model: &Model) -> Result<BTreeMap<Part, SegmentSpread>, ModelError> {
    let last = model.history.last().ok_or_else(|| ModelError::Shadow {
        reason: "the model has no history: fit it with `hydractl model fit`".to_owned(),
    })?;
    let mut reference = BTreeMap::new();
    for (name, spread) in &last.validation_spread {
        let part = [Part::Hydraulic, Part::Mechanical, Part::Whole]
            .into_iter()
            .find(|p| p.name() == name)
            .ok_or_else(|| ModelError::Shadow {
                reason: format!("validation_spread names no part `{name}`"),
            })?;
        reference.insert(part, *spread);
    }
    if reference.is_empty() {
        return Err(ModelError::Shadow {
            reason: format!(
                "its last step (`{}`) keeps no validation spread: refit it with this version's `hydractl model fit` or `model add`",
                last.step
            ),
        });
    }
    Ok(reference)
}

/// The regime in which `part`'s output has its largest residual.
fn worst_regime(comparison: &Comparison, part: Part) -> String {
    let output = match part {
        Part::Hydraulic => ["p_a", "p_b"].as_slice(),
        Part::Mechanical | Part::Whole => ["theta"].as_slice(),
    };
    comparison
        .regimes
        .iter()
        .map(|r| {
            let value = output
                .iter()
                .filter_map(|o| r.nrmse.get(*o))
                .map(|v| v * v)
                .sum::<f64>()
                .sqrt();
            (r.regime.clone(), value)
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map_or_else(|| "all".to_owned(), |(regime, _)| regime)
}
