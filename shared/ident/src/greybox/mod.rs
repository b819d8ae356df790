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
//! through the whole record unbroken.

mod compare;
mod diagnose;
mod fit;
mod shadow;
mod signals;

pub use compare::{compare, measured_outputs, Comparison, CorrelationTest, OutputScore, RegimeScore, REGIMES};
pub use diagnose::{diagnose, diagnose_with, Candidate, Diagnosis, NotJudged};
pub use fit::{fit, fit_baseline, validation_nrmse, FitOptions, Uncertainty};
pub use shadow::{
    moved_effect, segment_rms, validation_spread, Assessment, DriftAlarm, DriftTest, SegmentSpread, Shadow,
    CALIBRATION_SEGMENTS,
};
pub use signals::{part_showing, parts_measured, Signals, COLUMNS, REQUIRED_COLUMNS};

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;

use hydractl_plant::effects::{Effects, Quantization};
use hydractl_plant::{hydraulics, mechanics, EffectKind, EffectsConfig, PlantError, PlantParams};
use serde::{Deserialize, Serialize};

/// Length of one shooting segment, s.
pub const SEGMENT_S: f64 = 0.5;

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
/// driven by the (delayed) command.
pub fn predict_whole(
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
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
    let segment_starts: Vec<usize> = segments(signals, range.clone()).map(|s| s.start).collect();
    let mut next_start = 0;
    let mut follower = 0.0;
    for k in 0..range.end {
        if next_start < segment_starts.len() && k == segment_starts[next_start] {
            next_start += 1;
            let now = machine.state();
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

/// The segments of `range`, each at most one shooting segment long.
pub fn segments(signals: &Signals, range: Range<usize>) -> impl Iterator<Item = Range<usize>> {
    let length = ((SEGMENT_S / signals.dt).round() as usize).max(2);
    let end = range.end;
    range.step_by(length).map(move |start| start..(start + length).min(end))
}

/// The valve input after the `time_delay` effect: the command `delay_s`
/// earlier, interpolated between samples so that the delay is continuous.
fn delayed_command(signals: &Signals, effects: &Effects, k: usize) -> f64 {
    let Some(delay) = effects.time_delay else {
        return signals.u[k];
    };
    let shift = delay.delay_s / signals.dt;
    let whole = shift.floor();
    let fraction = shift - whole;
    let at = |back: f64| {
        let index = k as f64 - back;
        if index < 0.0 {
            0.0
        } else {
            signals.u[index as usize]
        }
    };
    (1.0 - fraction) * at(whole) + fraction * at(whole + 1.0)
}

/// Command and measured motion → pressures, segment by segment, each
/// segment starting from the measured pressures; the spool runs unbroken
/// from the start of the record.
pub fn predict_hydraulic(
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
    out: &mut Prediction,
) {
    let h = signals.dt;
    let exact = HydraulicSteps::new(plant, effects, h);
    let travel_limit = effects.saturation.map(|s| s.limit);
    let inside = |p: f64| p > plant.tank_pressure && p < plant.supply_pressure;
    let free = |spool: f64| travel_limit.is_none_or(|limit| spool.abs() < limit);
    let mut spool = [0.0_f64; 2];
    let mut pressures = [signals.p_a[0], signals.p_b[0]];
    let segment_starts: Vec<usize> = segments(signals, range.clone()).map(|s| s.start).collect();
    let mut next_start = 0;
    for k in 0..range.end {
        if next_start < segment_starts.len() && k == segment_starts[next_start] {
            pressures = [signals.p_a[k], signals.p_b[k]];
            next_start += 1;
        }
        if k >= range.start {
            out.p_a[k] = pressures[0];
            out.p_b[k] = pressures[1];
        }
        if k + 1 >= range.end {
            break;
        }
        let input = delayed_command(signals, effects, k);
        let (v0, v1) = (signals.velocity[k], signals.velocity[k + 1]);
        // Before the range only the spool matters.
        let in_segment = k + 1 >= range.start;
        let x = [spool[0], spool[1], pressures[0], pressures[1]];
        // Exactly where the valve and chambers are linear: the spool clear
        // of its stops and the pressures clear of tank and supply, at the
        // step's start and end.
        if let Some(steps) = exact.as_ref().filter(|_| free(x[0])) {
            if !in_segment {
                let next = steps.spool(&x, input);
                if free(next[0]) {
                    spool = next;
                    continue;
                }
            } else if inside(x[2]) && inside(x[3]) {
                let piece = steps.piece(x[0]);
                if let Some(step) = &steps.pieces[piece] {
                    let next = step.apply(&x, input, v0, v1);
                    if free(next[0]) && inside(next[2]) && inside(next[3]) && steps.piece(next[0]) == piece {
                        spool = [next[0], next[1]];
                        pressures = [next[2], next[3]];
                        continue;
                    }
                }
            }
        }
        // RK4 over one sample, the command held and the velocity linear.
        let rates = |x: &[f64; 4], velocity: f64| -> [f64; 4] {
            let (ds, dr) = hydraulics::spool_rates(plant, effects, x[0], x[1], input);
            let (da, db) = if in_segment {
                hydraulics::pressure_rates(plant, effects, x[0], x[2], x[3], velocity)
            } else {
                (0.0, 0.0)
            };
            [ds, dr, da, db]
        };
        let vm = 0.5 * (v0 + v1);
        let k1 = rates(&x, v0);
        let k2 = rates(&add(&x, &k1, 0.5 * h), vm);
        let k3 = rates(&add(&x, &k2, 0.5 * h), vm);
        let k4 = rates(&add(&x, &k3, h), v1);
        let mut next = x;
        for i in 0..4 {
            next[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
        let (mut s, mut r) = (next[0], next[1]);
        hydraulics::limit_spool(effects, &mut s, &mut r);
        spool = [s, r];
        pressures = [
            hydraulics::bound_pressure(plant, next[2]),
            hydraulics::bound_pressure(plant, next[3]),
        ];
    }
}

/// The valve and chambers over one sample where they are linear by
/// pieces, exactly: the spool driven by the held command, the pressures by
/// the spool and by a velocity that moves linearly over the sample (as the
/// RK4 step takes it). Without orifice flow the rates are affine in the
/// state, the command and the velocity on each side of the valve's dead
/// band and inside it (an asymmetric gain's pieces are the opening's
/// signs); a step that stays on one piece is the exponential of a
/// generator whose columns are differences of [`hydraulics::spool_rates`]
/// and [`hydraulics::pressure_rates`], so the physics stays defined in one
/// place. A spool at its stop, a pressure at tank or supply or a step that
/// changes piece is not linear: the caller steps those by RK4.
struct HydraulicSteps {
    /// Below the dead band, inside it (or everywhere, without one), above.
    pieces: [Option<LinearHydraulicStep>; 3],
    band: Option<hydractl_plant::effects::Deadzone>,
}

impl HydraulicSteps {
    /// `None` where the valve and chambers are not linear by pieces.
    fn new(plant: &PlantParams, effects: &Effects, h: f64) -> Option<Self> {
        if effects.orifice_flow.is_some() {
            return None;
        }
        // Clear of its stops the spool moves as if it had none.
        let mut free = *effects;
        free.saturation = None;
        let band = effects.valve_band();
        let pieces = hydractl_plant::effects::valve_piece_probes(band)
            .map(|probe| probe.and_then(|(spool, delta)| LinearHydraulicStep::about(plant, &free, spool, delta, h)));
        pieces.iter().any(Option::is_some).then_some(Self { pieces, band })
    }

    /// The piece the spool is on: 0 below the dead band, 1 inside (or
    /// everywhere, without one), 2 above.
    #[inline]
    fn piece(&self, spool: f64) -> usize {
        hydractl_plant::effects::valve_piece(self.band, spool)
    }

    /// The spool alone one sample on (the pressures not yet simulated):
    /// the same on every piece, since the flows do not act on it.
    #[inline]
    fn spool(&self, x: &[f64; 4], input: f64) -> [f64; 2] {
        let step = self.pieces.iter().flatten().next();
        step.map_or([x[0], x[1]], |step| step.spool(x, input))
    }
}

struct LinearHydraulicStep {
    transition: nalgebra::Matrix4<f64>,
    from_input: nalgebra::Vector4<f64>,
    from_velocity: nalgebra::Vector4<f64>,
    /// Per unit of the velocity's change over the sample.
    from_velocity_change: nalgebra::Vector4<f64>,
    constant: nalgebra::Vector4<f64>,
}

impl LinearHydraulicStep {
    /// The step of the rates about a spool at `spool`, which must lie on
    /// the piece, moving it by `spool_delta` within the piece; the
    /// pressures about mid-way between tank and supply, where no rate is
    /// held.
    fn about(plant: &PlantParams, effects: &Effects, spool: f64, spool_delta: f64, h: f64) -> Option<Self> {
        let neutral = 0.5 * (plant.tank_pressure + plant.supply_pressure);
        let room = 0.5 * (plant.supply_pressure - plant.tank_pressure);
        if !room.is_finite() || room <= 0.0 || !spool_delta.is_finite() || spool_delta == 0.0 {
            return None;
        }
        // z = [spool, spool rate, p_a, p_b, velocity, its slope, command, 1].
        let rates = |z: &nalgebra::SVector<f64, 8>| -> nalgebra::SVector<f64, 8> {
            let (ds, dr) = hydraulics::spool_rates(plant, effects, z[0], z[1], z[6]);
            let (da, db) = hydraulics::pressure_rates(plant, effects, z[0], z[2], z[3], z[4]);
            nalgebra::SVector::<f64, 8>::from([ds, dr, da, db, z[5], 0.0, 0.0, 0.0])
        };
        let reference = nalgebra::SVector::<f64, 8>::from([spool, 0.0, neutral, neutral, 0.0, 0.0, 0.0, 1.0]);
        let delta = |i: usize| match i {
            0 => spool_delta,
            2 | 3 => 0.1 * room,
            _ => 1.0,
        };
        let exact = hydractl_plant::affine_step(rates, reference, delta, h);
        let step = Self {
            transition: exact.fixed_view::<4, 4>(0, 0).into_owned(),
            from_velocity: exact.fixed_view::<4, 1>(0, 4).into_owned(),
            from_velocity_change: exact.fixed_view::<4, 1>(0, 5).into_owned() / h,
            from_input: exact.fixed_view::<4, 1>(0, 6).into_owned(),
            constant: exact.fixed_view::<4, 1>(0, 7).into_owned(),
        };
        (step.transition.iter().all(|v| v.is_finite()) && step.constant.iter().all(|v| v.is_finite())).then_some(step)
    }

    /// The state one sample on, from `v0` to `v1` linearly.
    #[inline]
    fn apply(&self, x: &[f64; 4], input: f64, v0: f64, v1: f64) -> [f64; 4] {
        (self.transition * nalgebra::Vector4::from(*x)
            + self.from_input * input
            + self.from_velocity * v0
            + self.from_velocity_change * (v1 - v0)
            + self.constant)
            .into()
    }

    /// The spool alone one sample on (the pressures not yet simulated).
    #[inline]
    fn spool(&self, x: &[f64; 4], input: f64) -> [f64; 2] {
        let t = &self.transition;
        [
            t[(0, 0)] * x[0] + t[(0, 1)] * x[1] + self.from_input[0] * input + self.constant[0],
            t[(1, 0)] * x[0] + t[(1, 1)] * x[1] + self.from_input[1] * input + self.constant[1],
        ]
    }
}

fn add<const N: usize>(x: &[f64; N], k: &[f64; N], h: f64) -> [f64; N] {
    let mut out = *x;
    for i in 0..N {
        out[i] += h * k[i];
    }
    out
}

/// Measured torque → angle → encoder, segment by segment.
pub fn predict_mechanical(
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
    out: &mut Prediction,
) {
    let mut shaft = Vec::new();
    let mut best = Vec::new();
    let model = Mechanics {
        plant,
        effects,
        linear: mechanics::LinearStep::new(plant, effects, signals.dt),
    };
    for segment in segments(signals, range) {
        let start = segment.start;
        // Where the actuator sits in the play, from the data before the
        // segment: half the play ahead of the encoder, on the side of its
        // last motion (a load that stopped stays where it was pushed). A
        // model with a play chooses nothing on the segment it is judged on
        // that the baseline may not.
        let play = effects
            .backlash
            .map_or(0.0, |b| 0.5 * b.width * signals.last_motion[start]);
        let mut initial_angle = signals.theta_smooth[start];
        let mut initial_velocity = signals.velocity[start];
        if let Some(friction) = effects.coulomb_friction {
            if initial_velocity.abs() < friction.stribeck_velocity {
                initial_velocity = 0.0;
            }
        }
        // From the smoothed measurement, then from the initial state that
        // least squares says fits the segment better; the better one stays
        // (with backlash or friction the correction's linear view can miss).
        let mut best_error = f64::INFINITY;
        best.clear();
        let measured = &signals.theta[segment.clone()];
        let staircase = effects.quantization.map(|q| Staircase::of(q.step, measured));
        // Simulates the segment from an initial state (and a position in the
        // play) into `shaft`, and keeps it in `best` when it fits better.
        let mut try_start = |initial: (f64, f64), shaft: &mut Vec<f64>| {
            simulate_segment(&model, signals, segment.clone(), initial, play, shaft);
            keep_if_better(effects, staircase.as_ref(), measured, shaft, &mut best, &mut best_error);
        };
        // Without a mechanical effect the correction is exact: two passes
        // do. A coarse encoder reads the shaft and does not move it, and the
        // correction fits the shaft before its reading: exact as well.
        let passes = if nonlinear_mechanics(effects) { 3 } else { 2 };
        for pass in 0..passes {
            try_start((initial_angle, initial_velocity), &mut shaft);
            if pass + 1 == passes {
                break;
            }
            let (d_angle, d_velocity) = initial_state_correction(plant, signals, segment.clone(), &shaft);
            initial_angle += d_angle;
            initial_velocity += d_velocity;
        }
        if let Some(staircase) = &staircase {
            refine_on_staircase(plant, signals.dt, staircase, measured, &mut best);
        }
        // A diverged simulation leaves NaN, which the fit refuses.
        best.resize(segment.len(), f64::NAN);
        for (i, k) in segment.clone().enumerate() {
            out.theta[k] = encoder_reading(effects, best[i]);
        }
    }
}

/// Scores a simulated segment against the measurement, at its best shift
/// within a quantization step, and keeps it (shifted) in `best` when it
/// beats `best_error`.
fn keep_if_better(
    effects: &Effects,
    staircase: Option<&Staircase>,
    measured: &[f64],
    shaft: &[f64],
    best: &mut Vec<f64>,
    best_error: &mut f64,
) {
    let offset = staircase.map_or(0.0, |staircase| best_quantized_offset(staircase, shaft));
    let error = segment_error(effects, measured, shaft, offset);
    if error < *best_error {
        *best_error = error;
        best.clear();
        best.extend(shaft.iter().map(|s| s + offset));
    }
}

fn nonlinear_mechanics(effects: &Effects) -> bool {
    effects.coulomb_friction.is_some()
        || effects.gravity_load.is_some()
        || effects.backlash.is_some()
        || effects.load_flexibility.is_some()
}

fn encoder_reading(effects: &Effects, shaft: f64) -> f64 {
    match effects.quantization {
        Some(q) => q.quantize(shaft),
        None => shaft,
    }
}

fn segment_error(effects: &Effects, measured: &[f64], shaft: &[f64], offset: f64) -> f64 {
    measured
        .iter()
        .zip(shaft)
        .map(|(m, s)| (m - encoder_reading(effects, s + offset)).powi(2))
        .sum()
}

/// A staircase's squared error in counts of its step (step² times the
/// angle's), the path shifted by `shift(i)` counts at sample i, one shift
/// at a time (see [`staircase_errors`] for a grid of them): each sample
/// costs a rounding, not the quantizer's division, in the searches that
/// take most of a coarse encoder's fit. Given up (infinite) once it reaches
/// `bound`: its terms only add, so a search that keeps the smallest is
/// unchanged by it, and most of its tries are out of the race after a few
/// samples.
fn staircase_error_below(
    measured_counts: &[f64],
    path_counts: &[f64],
    shift: impl Fn(usize) -> f64,
    bound: f64,
) -> f64 {
    // The terms are whole numbers, so their sum is exact in any order: a
    // block's terms are computed and added together, and a sum that only
    // grows reaches the bound within a block if and only if at its end.
    // (Sample by sample, each rounding and check waited for the sum.)
    const BLOCK: usize = 8;
    let n = measured_counts.len().min(path_counts.len());
    let term = |i: usize, measured: f64, path: f64| (measured - Quantization::nearest_count(path + shift(i))).powi(2);
    // Blocks spread over the segment first: a shift that misses the
    // staircase misses it somewhere, and its error reaches the bound
    // sooner when every part of the segment is sampled early.
    const SPREAD: usize = 8;
    let blocks = n / BLOCK;
    let mut sum = 0.0;
    for b in (0..SPREAD).flat_map(|phase| (phase..blocks).step_by(SPREAD)) {
        let first = b * BLOCK;
        let (measured, path) = (
            &measured_counts[first..first + BLOCK],
            &path_counts[first..first + BLOCK],
        );
        let t: [f64; BLOCK] = std::array::from_fn(|j| term(first + j, measured[j], path[j]));
        sum += ((t[0] + t[1]) + (t[2] + t[3])) + ((t[4] + t[5]) + (t[6] + t[7]));
        if sum >= bound {
            return f64::INFINITY;
        }
    }
    for i in n - n % BLOCK..n {
        sum += term(i, measured_counts[i], path_counts[i]);
    }
    if sum >= bound {
        return f64::INFINITY;
    }
    sum
}

/// A staircase's squared errors for a grid of shifts at once: the path
/// shifted by `angles[j] + velocities[k] · sensitivity[i]` counts at sample
/// i, against the measured staircase in whole counts. `errors[k · angles.len() + j]` is the sum of
/// (measured − rounded path)² over the samples: whole numbers, exact in any
/// order, so it is the same as scoring the shifts one by one.
///
/// The angles and velocities are ascending and the sensitivity is not
/// negative, so a sample's rounded count only grows along a row of the
/// grid: it is rounded at the grid's corners, and where they differ at each
/// row's ends, and the row's few steps are found by bisection. A sample
/// whose count the whole grid leaves alone (most, once the grid is fine)
/// costs two roundings, where scoring the shifts one by one cost one per
/// shift. `None` where the path is not finite, or so far from the
/// measurement that its squares would not be exact.
fn staircase_errors(
    measured_counts: &[f64],
    path_counts: &[f64],
    sensitivity: &[f64],
    angles: &[f64],
    velocities: &[f64],
) -> Option<Vec<f64>> {
    // Counts apart beyond which a square loses whole numbers in a sum.
    const FARTHEST: f64 = 1e6;
    let (columns, rows) = (angles.len(), velocities.len());
    if columns == 0 || rows == 0 {
        return Some(Vec::new());
    }
    let mut common = 0.0;
    // Per row, the change of the error from each column to the next.
    let mut steps = vec![0.0; rows * columns];
    for ((&measured, &path), &g) in measured_counts.iter().zip(path_counts).zip(sensitivity) {
        let count = |j: usize, k: usize| Quantization::nearest_count(path + (angles[j] + velocities[k] * g));
        let term = |count: f64| (measured - count).powi(2);
        let (lowest, highest) = (count(0, 0), count(columns - 1, rows - 1));
        if !((measured - lowest).abs() <= FARTHEST && (measured - highest).abs() <= FARTHEST) {
            return None;
        }
        if lowest == highest {
            common += term(lowest);
            continue;
        }
        for (k, row) in steps.chunks_exact_mut(columns).enumerate() {
            let (mut j, mut current) = (0, count(0, k));
            let last = count(columns - 1, k);
            row[0] += term(current);
            while current < last {
                // The first column past j where the count grows.
                let (mut below, mut above) = (j, columns - 1);
                while above - below > 1 {
                    let middle = (below + above) / 2;
                    if count(middle, k) > current {
                        above = middle;
                    } else {
                        below = middle;
                    }
                }
                let next = count(above, k);
                row[above] += term(next) - term(current);
                (j, current) = (above, next);
            }
        }
    }
    for row in steps.chunks_exact_mut(columns) {
        let mut error = common;
        for cell in row {
            error += *cell;
            *cell = error;
        }
    }
    Some(steps)
}

/// A segment's measured angles in whole counts of a coarse encoder's
/// step, once for every search of the segment.
struct Staircase {
    step: f64,
    measured_counts: Vec<f64>,
}

impl Staircase {
    fn of(step: f64, measured: &[f64]) -> Self {
        Self {
            step,
            measured_counts: measured.iter().map(|m| Quantization::nearest_count(m / step)).collect(),
        }
    }

    /// A path in counts of the step.
    fn in_counts(&self, path: &[f64]) -> Vec<f64> {
        path.iter().map(|p| p / self.step).collect()
    }
}

/// With a coarse encoder, least squares on the staircase leaves the initial
/// angle uncertain by up to half a step; this picks, within half a step, the
/// shift of the segment that reproduces the measured staircase best (the
/// first of the least, from −half a step up).
fn best_quantized_offset(staircase: &Staircase, shaft: &[f64]) -> f64 {
    const TRIES: usize = 21;
    let (measured_counts, shaft_counts) = (&staircase.measured_counts, staircase.in_counts(shaft));
    let offset = |i: usize| i as f64 / (TRIES - 1) as f64 - 0.5;
    let errors = nearest_first(
        TRIES,
        |i| i.abs_diff(TRIES / 2),
        |i, bound| staircase_error_below(measured_counts, &shaft_counts, |_| offset(i), bound),
    );
    let least = errors.iter().copied().fold(f64::INFINITY, f64::min);
    errors
        .iter()
        .position(|&e| e == least)
        .map_or(0.0, |i| offset(i) * staircase.step)
}

/// The errors of `count` candidates, scored nearest the likely best first
/// (by `distance`): the least so far bounds the rest, which are given up
/// (infinite) once they exceed it. The path comes from least squares on the
/// staircase, so shifts near none are likely best, and a bound from them
/// leaves most others after a few samples. Every candidate that ties the
/// least keeps its exact error.
fn nearest_first(count: usize, distance: impl Fn(usize) -> usize, error: impl Fn(usize, f64) -> f64) -> Vec<f64> {
    let mut order: Vec<usize> = (0..count).collect();
    order.sort_by_key(|&i| distance(i));
    let mut errors = vec![f64::INFINITY; count];
    let mut least = f64::INFINITY;
    for i in order {
        errors[i] = error(i, least.next_up());
        least = least.min(errors[i]);
    }
    errors
}

/// With a coarse encoder a segment's staircase holds only a few steps, and
/// least squares on it leaves the initial velocity uncertain as well as the
/// angle: over a 0.5 s segment a 10° encoder cannot tell velocities apart
/// by less than a step per segment. This searches the initial angle (within
/// half a step) and velocity (within a step per segment) together, on a
/// coarse grid and then a finer one around its best, for the shift of the
/// segment that reproduces the measured staircase best; the velocity
/// shifts the path by the rigid body's sensitivity.
fn refine_on_staircase(plant: &PlantParams, dt: f64, staircase: &Staircase, measured: &[f64], path: &mut [f64]) {
    const GRID: i32 = 6;
    const SIDE: usize = 2 * GRID as usize + 1;
    let n = path.len().min(measured.len());
    // A staircase that steps at least every tenth sample pins the path
    // down already (a fine encoder on a moving load): no search needed.
    let steps_taken = measured[..n].windows(2).filter(|w| w[0] != w[1]).count();
    if n < 2 || steps_taken * 10 >= n {
        return;
    }
    let sensitivity: Vec<f64> = velocity_sensitivity(plant, dt).take(n).collect();
    let span_t = sensitivity[n - 1].max(dt);
    let (measured_counts, path_counts) = (&staircase.measured_counts[..n], staircase.in_counts(&path[..n]));
    // In counts: half a step of angle, two steps per segment of velocity.
    let (mut angle_span, mut velocity_span) = (0.5, 2.0 / span_t);
    let (mut centre_angle, mut centre_velocity) = (0.0, 0.0);
    for level in 0..3 {
        let around = |centre: f64, span: f64| -> [f64; SIDE] {
            std::array::from_fn(|i| centre + span * f64::from(i as i32 - GRID) / f64::from(GRID))
        };
        let (angles, velocities) = (around(centre_angle, angle_span), around(centre_velocity, velocity_span));
        // The coarse grid spans a whole step of angle, which moves every
        // sample's count: its shifts are scored one by one, most given up
        // after a few samples. The finer grids move few samples' counts
        // and are scored at once.
        let errors = if level == 0 {
            let ring = |i: usize| (i % SIDE).abs_diff(SIDE / 2).max((i / SIDE).abs_diff(SIDE / 2));
            nearest_first(SIDE * SIDE, ring, |cell, bound| {
                let (a, v) = (cell % SIDE, cell / SIDE);
                let shift = |i: usize| angles[a] + velocities[v] * sensitivity[i];
                staircase_error_below(measured_counts, &path_counts, shift, bound)
            })
        } else {
            match staircase_errors(measured_counts, &path_counts, &sensitivity, &angles, &velocities) {
                Some(errors) => errors,
                None => return,
            }
        };
        // The centre stays unless a shift does better; among the better,
        // the first by angle, then velocity.
        let error = |a: usize, v: usize| errors[v * SIDE + a];
        let centre = GRID as usize;
        let mut best = (error(centre, centre), centre, centre);
        for a in 0..SIDE {
            for v in 0..SIDE {
                if error(a, v) < best.0 {
                    best = (error(a, v), a, v);
                }
            }
        }
        (centre_angle, centre_velocity) = (angles[best.1], velocities[best.2]);
        angle_span /= f64::from(GRID);
        velocity_span /= f64::from(GRID);
    }
    for (p, g) in path.iter_mut().zip(&sensitivity) {
        *p += (centre_angle + centre_velocity * g) * staircase.step;
    }
}

/// How far the rigid body's angle moves per unit of initial velocity after
/// each sample, (1 − e^(−b t / J)) J / b: the sensitivity that corrects a
/// segment's initial velocity. The exponential advances by one product per
/// sample (an exp per sample cost diagnose a tenth of its time).
fn velocity_sensitivity(plant: &PlantParams, dt: f64) -> impl Iterator<Item = f64> {
    let decay = plant.viscous_friction / plant.inertia;
    let ratio = (-decay * dt).exp();
    (0..).scan(1.0_f64, move |decayed, i: u32| {
        let t = f64::from(i) * dt;
        let g = if decay * t > 1e-9 { (1.0 - *decayed) / decay } else { t };
        *decayed *= ratio;
        Some(g)
    })
}

/// The least-squares change of a segment's initial angle and velocity that
/// best fits the measured angle, with the rigid body's sensitivities: 1 for
/// the angle, (J/b)(1 − e^(−b t / J)) for the velocity.
fn initial_state_correction(
    plant: &PlantParams,
    signals: &Signals,
    segment: Range<usize>,
    shaft: &[f64],
) -> (f64, f64) {
    let (mut s11, mut s12, mut s22, mut r1, mut r2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for ((i, k), g) in segment.enumerate().zip(velocity_sensitivity(plant, signals.dt)) {
        let e = signals.theta[k] - shaft[i];
        s11 += 1.0;
        s12 += g;
        s22 += g * g;
        r1 += e;
        r2 += g * e;
    }
    let det = s11 * s22 - s12 * s12;
    if det.abs() < 1e-12 {
        return (if s11 > 0.0 { r1 / s11 } else { 0.0 }, 0.0);
    }
    ((s22 * r1 - s12 * r2) / det, (s11 * r2 - s12 * r1) / det)
}

/// The mechanical part's model as one segment's simulation uses it: with
/// the exact step of linear mechanics, where they are linear.
struct Mechanics<'a> {
    plant: &'a PlantParams,
    effects: &'a Effects,
    linear: Option<mechanics::LinearStep>,
}

/// One segment of the mechanical part from a given initial state (the
/// encoder's angle and the velocity); writes the encoder shaft's angle
/// (before quantization) into `shaft`. With backlash, the actuator starts
/// `lag` ahead of the encoder within the play.
fn simulate_segment(
    model: &Mechanics,
    signals: &Signals,
    segment: Range<usize>,
    (initial_angle, initial_velocity): (f64, f64),
    lag: f64,
    shaft: &mut Vec<f64>,
) {
    let Mechanics { plant, effects, linear } = model;
    shaft.clear();
    let h = signals.dt;
    let angle = initial_angle + lag;
    let mut motion: mechanics::Motion = [angle, initial_velocity, angle, initial_velocity];
    let mut follower = initial_angle;
    let mut stuck = effects.coulomb_friction.is_some() && initial_velocity == 0.0;
    for k in segment.clone() {
        follower = match effects.backlash {
            Some(b) => b.follow(motion[mechanics::ANGLE], follower),
            None => motion[mechanics::ANGLE],
        };
        shaft.push(follower);
        if k + 1 >= segment.end {
            break;
        }
        let (t0, t1) = (signals.torque(plant, k), signals.torque(plant, k + 1));
        if let Some(linear) = linear {
            motion = linear.step(&motion, t0, t1);
            continue;
        }
        let (direction, now_stuck) = mechanics::friction_direction(plant, effects, &motion, t0, stuck);
        stuck = now_stuck;
        let rates = |m: &mechanics::Motion, torque: f64| mechanics::motion_rates(plant, effects, m, torque, direction);
        let mut next = motion;
        let k1 = rates(&motion, t0);
        if effects.load_flexibility.is_some() {
            // A stiff coupling's mode needs RK4's wider stability region.
            let tm = 0.5 * (t0 + t1);
            let k2 = rates(&add(&motion, &k1, 0.5 * h), tm);
            let k3 = rates(&add(&motion, &k2, 0.5 * h), tm);
            let k4 = rates(&add(&motion, &k3, h), t1);
            for i in 0..4 {
                next[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        } else {
            // A rigid body's one mode, −B/J, is real and slow against the
            // sample (a rotator's about 1/s; Heun is stable to 2000/s, RK4
            // to 2780/s): Heun's two evaluations follow it to far below the
            // encoder's noise, at half RK4's cost (diagnose 30 % faster).
            let k2 = rates(&add(&motion, &k1, h), t1);
            for i in 0..4 {
                next[i] += 0.5 * h * (k1[i] + k2[i]);
            }
        }
        stuck = mechanics::settle_friction(plant, effects, &motion, &mut next, t1, stuck, direction);
        motion = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hydraulic_exact_step_is_a_fine_integration_on_each_piece_of_the_valve() {
        use hydractl_plant::effects::{AsymmetricGain, Deadzone};
        let plant = PlantParams::default();
        let mut effects = Effects::none();
        effects.deadzone = Some(Deadzone {
            width: 0.05,
            offset: 0.01,
        });
        effects.asymmetric_gain = Some(AsymmetricGain { ratio: 0.7 });
        let h = 1e-3;
        let steps = HydraulicSteps::new(&plant, &effects, h).expect("linear by pieces");
        // RK4 on a hundred substeps, the velocity linear over the sample.
        let fine = |x: [f64; 4], input: f64, v0: f64, v1: f64| -> [f64; 4] {
            let n = 100;
            let dt = h / n as f64;
            let rates = |x: &[f64; 4], t: f64| -> [f64; 4] {
                let velocity = v0 + (v1 - v0) * t / h;
                let (ds, dr) = hydraulics::spool_rates(&plant, &effects, x[0], x[1], input);
                let (da, db) = hydraulics::pressure_rates(&plant, &effects, x[0], x[2], x[3], velocity);
                [ds, dr, da, db]
            };
            let mut x = x;
            for i in 0..n {
                let t = i as f64 * dt;
                let k1 = rates(&x, t);
                let k2 = rates(&add(&x, &k1, 0.5 * dt), t + 0.5 * dt);
                let k3 = rates(&add(&x, &k2, 0.5 * dt), t + 0.5 * dt);
                let k4 = rates(&add(&x, &k3, dt), t + dt);
                for j in 0..4 {
                    x[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
                }
            }
            x
        };
        // Below the band, inside it and above it, each step staying there.
        for (spool, input) in [(-0.3, -0.35), (0.02, 0.03), (0.4, 0.5)] {
            let x = [spool, 0.01, 90e5, 70e5];
            let piece = steps.piece(spool);
            let exact = steps.pieces[piece]
                .as_ref()
                .expect("a piece")
                .apply(&x, input, 0.1, -0.05);
            let reference = fine(x, input, 0.1, -0.05);
            assert_eq!(steps.piece(exact[0]), piece);
            for j in 0..4 {
                let scale = x[j].abs().max(1e-3);
                assert!(
                    (exact[j] - reference[j]).abs() <= 1e-9 * scale,
                    "piece {piece}, state {j}: {} against {}",
                    exact[j],
                    reference[j]
                );
            }
            let spool_alone = steps.spool(&x, input);
            assert!((spool_alone[0] - exact[0]).abs() < 1e-12 && (spool_alone[1] - exact[1]).abs() < 1e-12);
        }
        // The √Δp valve law is not linear by pieces.
        effects.orifice_flow = Some(hydractl_plant::effects::OrificeFlow);
        assert!(HydraulicSteps::new(&plant, &effects, h).is_none());
    }

    #[test]
    fn the_staircase_search_moves_nothing_but_the_initial_angle_and_velocity() {
        // A coarse encoder on a slow swing: the least-squares path is off
        // the true shaft by a third of a step and a slip in velocity, which
        // its staircase shows. The search may take back just those two: the
        // same initial state every model gets, chosen by the model's own
        // error, and nothing more.
        let plant = PlantParams::default();
        let (dt, n) = (1e-3, 500);
        let step = 0.01;
        let sensitivity: Vec<f64> = velocity_sensitivity(&plant, dt).take(n).collect();
        let shaft: Vec<f64> = (0..n).map(|i| 0.05 * (2.0 * i as f64 * dt).sin()).collect();
        let measured: Vec<f64> = shaft.iter().map(|a| Quantization { step }.quantize(*a)).collect();
        let (angle_slip, velocity_slip) = (0.35 * step, 0.6 * step / (n as f64 * dt));
        let start: Vec<f64> = shaft
            .iter()
            .zip(&sensitivity)
            .map(|(a, g)| a - angle_slip - velocity_slip * g)
            .collect();
        let mut path = start.clone();
        refine_on_staircase(&plant, dt, &Staircase::of(step, &measured), &measured, &mut path);
        let moved: Vec<f64> = path.iter().zip(&start).map(|(p, s)| p - s).collect();
        let (angle, velocity) = (moved[0], (moved[n - 1] - moved[0]) / sensitivity[n - 1]);
        for (m, g) in moved.iter().zip(&sensitivity) {
            assert!(
                (m - (angle + velocity * g)).abs() < 1e-12,
                "a change of the initial state alone"
            );
        }
        assert!(
            (angle - angle_slip).abs() < 0.1 * step,
            "angle {angle} for {angle_slip}"
        );
        assert!(
            (velocity - velocity_slip).abs() < 0.2 * velocity_slip,
            "velocity {velocity} for {velocity_slip}"
        );
        let error = |path: &[f64]| -> f64 {
            path.iter()
                .zip(&measured)
                .map(|(p, m)| (Quantization { step }.quantize(*p) - m).powi(2))
                .sum()
        };
        assert!(
            error(&path) < 0.1 * error(&start),
            "{} against {}",
            error(&path),
            error(&start)
        );
    }

    #[test]
    fn a_grid_of_staircase_shifts_scores_as_each_shift_alone() {
        // A slow path over a few steps, a measured staircase off it by a
        // shift and a slip, and a grid that moves many samples' counts.
        let n = 500;
        let sensitivity: Vec<f64> = (0..n).map(|i| 0.002 * i as f64).collect();
        let path: Vec<f64> = (0..n)
            .map(|i| 3.0 * (0.01 * i as f64).sin() + 0.013 * i as f64)
            .collect();
        let measured: Vec<f64> = path
            .iter()
            .enumerate()
            .map(|(i, p)| Quantization::nearest_count(p + 0.3 + if i % 97 == 0 { 1.0 } else { 0.0 }))
            .collect();
        let angles: Vec<f64> = (0..13).map(|j| -0.5 + j as f64 / 12.0).collect();
        let velocities: Vec<f64> = (0..9).map(|k| -0.4 + 0.1 * k as f64).collect();
        let errors = staircase_errors(&measured, &path, &sensitivity, &angles, &velocities)
            .expect("a finite path near the staircase is scored");
        for (k, v) in velocities.iter().enumerate() {
            for (j, a) in angles.iter().enumerate() {
                let alone = staircase_error_below(&measured, &path, |i| a + v * sensitivity[i], f64::INFINITY);
                assert_eq!(errors[k * angles.len() + j], alone, "angle {a}, velocity {v}");
            }
        }
        // A bound gives up exactly the shifts that reach it.
        let least = errors.iter().copied().fold(f64::INFINITY, f64::min);
        let nearest = nearest_first(
            errors.len(),
            |_| 0,
            |cell, bound| {
                let (a, v) = (angles[cell % angles.len()], velocities[cell / angles.len()]);
                staircase_error_below(&measured, &path, |i| a + v * sensitivity[i], bound)
            },
        );
        for (e, n) in errors.iter().zip(&nearest) {
            assert!(if *e == least { n == e } else { n.is_infinite() || n == e });
        }
        // A path that diverged scores nothing.
        let mut diverged = path.clone();
        diverged[n / 2] = f64::NAN;
        assert!(staircase_errors(&measured, &diverged, &sensitivity, &angles, &velocities).is_none());
    }
}
