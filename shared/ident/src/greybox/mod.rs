//! The grey-box model of the rotator and its comparison with measurements.
//!
//! The model is the papers' structure (spool, linearized flow, chamber
//! pressures, rigid body with viscous friction) plus any effects of the
//! catalog, with the parameters in the plant's own units. It is split into
//! two parts, each driven by the measured coupling signal, so that a
//! residual points at one part:
//!
//! - **hydraulic**: valve command and measured motion → chamber pressures;
//! - **mechanical**: measured torque D (p_a − p_b) → angle, and the encoder
//!   (the `backlash` and `quantization` effects) → measured angle.
//!
//! The plant integrates (the angle is the integral of the velocity) and the
//! data is closed-loop, so a free-run simulation would drift. Both parts are
//! compared by **multiple shooting**: the record is cut into 0.5 s segments;
//! each pressure segment starts from the measured pressures, and each angle
//! segment from an initial angle and velocity estimated on that segment
//! (MATLAB `compare`'s `'estimate'` initial condition, per segment). Every
//! model gets those two values and no more, chosen by its own squared error
//! on the segment (least squares, or a search on a coarse encoder's
//! staircase): validation gives no model a freedom another lacks. The play's
//! position comes from the data before the segment, and the spool runs
//! through the whole record unbroken. Where readings were left out (a gap
//! in the time stamps) a segment starts, and the spool starts settled on
//! the command.

mod compare;
mod diagnose;
mod fit;
mod hydraulic;
mod learn;
mod mechanical;
mod shadow;
mod signals;
mod staircase;
#[cfg(test)]
mod tests;

pub use compare::{compare, measured_outputs, Comparison, CorrelationTest, OutputScore, RegimeScore, REGIMES};
pub use diagnose::{diagnose, diagnose_with, together, Candidate, Diagnosis, NotJudged, Together};
pub use fit::{fit, fit_baseline, validation_nrmse, FitOptions, Uncertainty};
pub use learn::{learn, LearnProgress, LearnStep, Learned, Stop};
pub use shadow::{
    moved_effect, validation_spread, Assessment, DriftAlarm, DriftTest, SegmentSpread, Shadow, CALIBRATION_SEGMENTS,
};
pub use signals::{part_showing, parts_measured, Signals, COLUMNS, REQUIRED_COLUMNS};

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;

use hydractl_plant::effects::{Effects, Quantization};
use hydractl_plant::{hydraulics, mechanics, EffectKind, EffectsConfig, PlantError, PlantParams};
use serde::{Deserialize, Serialize};

use hydraulic::*;
use mechanical::*;
use staircase::*;

/// Length of one shooting segment, s.
pub const SEGMENT_S: f64 = 0.5;

/// A validation NRMSE above which an output is not explained (a fit under
/// 80 %): the clean plants, ours and the foreign ones, fit their pressures
/// to 0.003–0.016 and their angle to 0.001–0.004.
pub(crate) const UNEXPLAINED_NRMSE: f64 = 0.2;

/// The shortest delay the command's steps may name, and the shortest also
/// fitted from the data sheet's valve, s. A first-order lag of τ looks like
/// a delay of τ at a step, and the pressures alone cannot tell them apart:
/// on clean plants the candidate fits the transducers' 1–3.5 ms lag as a
/// delay, which the motion's guard does not always catch. Shorter delays
/// are left to the segment tests.
pub(crate) const STEP_DELAY_MIN_S: f64 = 0.005;

/// What a long fit reports as it goes, for a progress display: the
/// library prints nothing itself.
pub trait Progress: Sync {
    /// `done` of `total` fits are finished; `what` was the last to finish
    /// or, with `done` 0, the first to begin.
    fn fitted(&self, what: &str, done: usize, total: usize);
}

/// No progress display.
pub struct Silent;

impl Progress for Silent {
    fn fitted(&self, _what: &str, _done: usize, _total: usize) {}
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(transparent)]
    Data(#[from] crate::DataError),
    #[error("{source_name}: {reason}")]
    Signals { source_name: String, reason: String },
    #[error("{path}: cannot read the model: {reason}")]
    ReadModel { path: String, reason: String },
    #[error("{path}: cannot write the model: {reason}")]
    WriteModel { path: String, reason: String },
    #[error("model: {0}")]
    Plant(#[from] PlantError),
    #[error("effect `{0}` is already in the model")]
    AlreadyIn(&'static str),
    #[error("`{effect}` cannot be judged from this record: {reason}")]
    NotJudged { effect: &'static str, reason: String },
    #[error("the fit failed: {0}")]
    Fit(String),
    #[error("the model cannot shadow the machine: {reason}")]
    Shadow { reason: String },
}

/// The two parts of the model, and the outputs they predict.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Part {
    /// Command and motion → pressures.
    Hydraulic,
    /// Torque → angle, through the encoder.
    Mechanical,
    /// Command → angle, through valve, chambers, body and encoder: the
    /// model of a machine without pressure transducers.
    Whole,
}

impl Part {
    pub fn of(kind: EffectKind) -> Self {
        match kind {
            EffectKind::Deadzone
            | EffectKind::Saturation
            | EffectKind::TimeDelay
            | EffectKind::AsymmetricGain
            | EffectKind::OrificeFlow => Part::Hydraulic,
            EffectKind::CoulombFriction
            | EffectKind::GravityLoad
            | EffectKind::Backlash
            | EffectKind::Quantization
            | EffectKind::LoadFlexibility => Part::Mechanical,
        }
    }

    /// The part's name, as the JSON's `parts` gives it.
    pub fn name(self) -> &'static str {
        match self {
            Part::Hydraulic => "hydraulic",
            Part::Mechanical => "mechanical",
            Part::Whole => "whole",
        }
    }

    /// The output name the JSON and the report use for this part.
    pub fn output(self) -> &'static str {
        match self {
            Part::Hydraulic => "pressures",
            Part::Mechanical | Part::Whole => "theta",
        }
    }

    /// What the part maps, in words for the report.
    pub fn describe(self) -> &'static str {
        match self {
            Part::Hydraulic => "hydraulic: valve command and measured motion → chamber pressures",
            Part::Mechanical => "mechanical: measured torque → angle",
            Part::Whole => "whole: valve command → angle (no pressures measured)",
        }
    }
}

/// One step of a model's history: what was added and what it did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HistoryStep {
    /// `baseline` or the effect's name.
    pub step: String,
    /// Validation NRMSE per output after this step.
    pub validation_nrmse: BTreeMap<String, f64>,
    /// The model as this step left it, so that a report can show the
    /// residuals before and after each step (absent in older files).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plant: Option<PlantParams>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub effects: Option<EffectsConfig>,
    /// Each part's segment residual on the validation data, for the
    /// shadow's drift test (absent in older files).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub validation_spread: BTreeMap<String, SegmentSpread>,
    /// The segment test that decided to add it (`model learn`), its
    /// statistic and the threshold it passed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub statistic: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threshold: Option<f64>,
    /// The effect added with it, where neither was significant alone and
    /// the test was the pair's (`model learn`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub together_with: Option<String>,
}

impl HistoryStep {
    /// A step named `step` that left `model` with these validation errors.
    pub fn of(
        step: &str,
        plant: &PlantParams,
        effects: &EffectsConfig,
        validation_nrmse: BTreeMap<String, f64>,
    ) -> Self {
        Self {
            step: step.to_owned(),
            validation_nrmse,
            plant: Some(*plant),
            effects: Some(effects.clone()),
            validation_spread: BTreeMap::new(),
            test: None,
            statistic: None,
            threshold: None,
            together_with: None,
        }
    }

    /// The model this step left, when the file recorded it.
    pub fn model(&self) -> Option<(PlantParams, Effects)> {
        Some((self.plant?, self.effects.as_ref()?.build().ok()?))
    }
}

/// A fitted model: plant parameters, effects, and how it got there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Model {
    pub plant: PlantParams,
    #[serde(default)]
    pub effects: EffectsConfig,
    #[serde(default)]
    pub history: Vec<HistoryStep>,
}

impl Model {
    pub fn new(plant: PlantParams, effects: Effects) -> Self {
        Self {
            plant,
            effects: EffectsConfig::from_effects(&effects),
            history: Vec::new(),
        }
    }

    pub fn effects(&self) -> Result<Effects, ModelError> {
        Ok(self.effects.build()?)
    }

    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let text = std::fs::read_to_string(path).map_err(|e| ModelError::ReadModel {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        let model: Model = toml::from_str(&text).map_err(|e| ModelError::ReadModel {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        model.plant.validate().map_err(|e| ModelError::ReadModel {
            path: path.display().to_string(),
            reason: format!("[plant]: {e}"),
        })?;
        model.effects.build().map_err(|e| ModelError::ReadModel {
            path: path.display().to_string(),
            reason: format!("[effects]: {e}"),
        })?;
        Ok(model)
    }

    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let body = toml::to_string_pretty(self).map_err(|e| ModelError::WriteModel {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        let text = format!(
            "# A grey-box model of the rotator, written by `hydractl model`.\n\
             # [plant]: SI units, as config/sim.toml; [effects]: the catalog's names and keys.\n\n{body}"
        );
        std::fs::write(path, text).map_err(|e| ModelError::WriteModel {
            path: path.display().to_string(),
            reason: e.to_string(),
        })
    }
}

/// The model's outputs over a range of samples (others hold NaN).
#[derive(Debug, Clone)]
pub struct Prediction {
    /// Pa.
    pub p_a: Vec<f64>,
    pub p_b: Vec<f64>,
    /// rad, as the encoder reports it.
    pub theta: Vec<f64>,
}

impl Prediction {
    pub fn new(len: usize) -> Self {
        Self {
            p_a: vec![f64::NAN; len],
            p_b: vec![f64::NAN; len],
            theta: vec![f64::NAN; len],
        }
    }
}

/// Predicts every part the record can test over `range`.
pub fn predict(plant: &PlantParams, effects: &Effects, signals: &Signals, range: Range<usize>) -> Prediction {
    let mut out = Prediction::new(signals.len());
    for part in signals.parts() {
        predict_part_into(part, plant, effects, signals, range.clone(), &mut out);
    }
    out
}

/// Predicts one part's outputs over `range` into `out`.
pub(crate) fn predict_part_into(
    part: Part,
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
    out: &mut Prediction,
) {
    match part {
        Part::Hydraulic => predict_hydraulic(plant, effects, signals, range, out),
        Part::Mechanical => predict_mechanical(plant, effects, signals, range, out),
        Part::Whole => predict_whole(plant, effects, signals, range, out),
    }
}

/// The longest integration step of the whole path, s: the valve and the
/// hydraulic mode need it at any sampling rate (50 Hz data is stepped at
/// 20 substeps per sample).
const MAX_WHOLE_STEP_S: f64 = 1e-3;

/// |λ| h for the spool's fastest mode: the spool answers the command alone,
/// so RK4's bound on the real axis, 2.79, holds for it; a tenth is kept.
/// (2.0 cost the dead-zone record below a fifth more time.)
const RK4_WHOLE_STEP_RATE: f64 = 2.5;

/// Substeps per sample at most: a valve faster than this resolves is left
/// to diverge, and the fit turns that start down.
const MAX_WHOLE_SUBSTEPS: usize = 64;

/// Command → angle, segment by segment. Each segment starts from a state
/// estimated from the measurement alone, the same for every model: the
/// smoothed angle and velocity, and the load pressure that the smoothed
/// acceleration asks of the model's body (the chambers' mean at the
/// neutral pressure). The spool runs through the whole record unbroken,
/// driven by the (delayed) command, settled on it after readings left
/// out.
fn predict_whole(plant: &PlantParams, effects: &Effects, signals: &Signals, range: Range<usize>, out: &mut Prediction) {
    let segment_starts: Vec<usize> = segments(signals, range.clone()).map(|s| s.start).collect();
    predict_whole_from(plant, effects, signals, range, &segment_starts, out);
}

/// [`predict_whole`] with the state estimated from the measurement at
/// `segment_starts` (ascending, each stretch's first within `range` among
/// them).
pub(crate) fn predict_whole_from(
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
    segment_starts: &[usize],
    out: &mut Prediction,
) {
    // The exact step leaves to RK4 every step that crosses a dead band's
    // edge or meets a nonlinear effect, and RK4 holds only while |λ| h stays
    // under about 2.8: a fitted valve may be fast and overdamped (913 rad/s
    // at ζ = 4.9, a mode at 8900/s, on a dead-zone's record without
    // pressures), and at 1 ms every such step diverged.
    let stable_step = RK4_WHOLE_STEP_RATE / hydraulics::spool_fastest_rate(plant);
    let substeps = ((signals.dt / MAX_WHOLE_STEP_S.min(stable_step)).ceil() as usize).clamp(1, MAX_WHOLE_SUBSTEPS);
    // The delay is applied here, interpolated between samples, so that the
    // fit sees it move continuously; the plant gets the delayed command.
    let mut undelayed = *effects;
    undelayed.time_delay = None;
    let Ok(mut machine) = hydractl_plant::Plant::new(*plant, undelayed, signals.dt / substeps as f64)
        .map(hydractl_plant::Plant::stepping_exactly_where_linear)
    else {
        return;
    };
    let neutral = machine.neutral_pressure();
    let mut next_start = 0;
    let mut follower = 0.0;
    for k in 0..range.end {
        if next_start < segment_starts.len() && k == segment_starts[next_start] {
            next_start += 1;
            let mut now = machine.state();
            if signals.breaks.binary_search(&k).is_ok() {
                [now.spool, now.spool_rate] = settled_spool(signals, effects, k);
            }
            let (angle, mut velocity) = (signals.theta_smooth[k], signals.velocity[k]);
            let stuck = effects
                .coulomb_friction
                .is_some_and(|f| velocity.abs() < f.stribeck_velocity);
            if stuck {
                velocity = 0.0;
            }
            // The encoder lags the actuator by half the play while moving.
            // (The mechanical part's rule, the last motion's side, named the
            // play first on 2 of 20 foreign plants without pressures where
            // this names it on 5: here the segment starts from the smoothed
            // state alone, with no least squares to correct it.)
            let lag = effects.backlash.map_or(0.0, |b| 0.5 * b.width * velocity.signum());
            let motion: mechanics::Motion = [angle + lag, velocity, angle + lag, velocity];
            let sliding = match effects.coulomb_friction {
                Some(f) if !stuck => velocity.signum() * f.sliding_level(velocity.abs()),
                _ => 0.0,
            };
            let hydraulic_torque =
                plant.inertia * signals.acceleration[k] - mechanics::net_torque(plant, effects, &motion, 0.0) + sliding;
            let load_pressure = hydraulic_torque / plant.displacement;
            machine.restart_from(hydractl_plant::PlantState {
                spool: now.spool,
                spool_rate: now.spool_rate,
                p_a: hydraulics::bound_pressure(plant, neutral + 0.5 * load_pressure),
                p_b: hydraulics::bound_pressure(plant, neutral - 0.5 * load_pressure),
                angle: angle + lag,
                velocity,
                load_angle: angle + lag,
                load_velocity: velocity,
                stuck,
            });
            follower = angle;
        }
        if k >= range.start {
            let shaft = machine.state().angle;
            follower = match effects.backlash {
                Some(b) => b.follow(shaft, follower),
                None => shaft,
            };
            out.theta[k] = encoder_reading(effects, follower);
            out.p_a[k] = machine.state().p_a;
            out.p_b[k] = machine.state().p_b;
        }
        if k + 1 >= range.end {
            break;
        }
        machine.advance(delayed_command(signals, effects, k), substeps);
    }
}

/// The segments of `range`, each at most one shooting segment long and
/// none across readings left out: each stretch of the record starts one.
pub fn segments(signals: &Signals, range: Range<usize>) -> impl Iterator<Item = Range<usize>> + '_ {
    let length = ((SEGMENT_S / signals.dt).round() as usize).max(2);
    signals.stretches().flat_map(move |stretch| {
        let (start, end) = (stretch.start.max(range.start), stretch.end.min(range.end));
        (start..end.max(start))
            .step_by(length)
            .map(move |first| first..(first + length).min(end))
    })
}
