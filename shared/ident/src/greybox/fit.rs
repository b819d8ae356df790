//! Fitting the grey-box model: output-error least squares on the estimation
//! segment, part by part, with a robust (Huber) loss so that the moments a
//! pressure sits at tank or supply do not steer the fit.

use rayon::prelude::*;
use std::collections::BTreeMap;
use std::ops::Range;

use hydractl_plant::effects::Effects;
use hydractl_plant::{Effect, EffectKind, EffectsConfig, PlantParams};

use serde::Serialize;

use super::{HistoryStep, Model, ModelError, Part, Prediction, Signals};
use crate::lm::{self, LmOptions};

/// Iterations spent on each start of an effect before the best goes on.
const SCREENING_ITERATIONS: usize = 3;

#[derive(Debug, Clone, Copy)]
pub struct FitOptions {
    /// The first fraction of the record estimates; the rest validates.
    pub estimation_fraction: f64,
    /// The most Levenberg–Marquardt iterations of one fit; it stops sooner
    /// once three iterations in a row gain under 1e-4 of the cost. The
    /// baseline and every candidate get the same.
    pub max_iterations: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            estimation_fraction: 0.7,
            max_iterations: 40,
        }
    }
}

/// A parameter the fit may move.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Knob {
    BulkModulus,
    FlowGain,
    FlowPressureCoefficient,
    Leakage,
    ValveNaturalFrequency,
    ValveDamping,
    Inertia,
    ViscousFriction,
    LoadTorque,
    Effect(EffectKind, &'static str),
}

impl Knob {
    /// The parameter's name in the model file.
    fn name(self) -> String {
        match self {
            Knob::BulkModulus => "bulk_modulus".to_owned(),
            Knob::FlowGain => "flow_gain".to_owned(),
            Knob::FlowPressureCoefficient => "flow_pressure_coefficient".to_owned(),
            Knob::Leakage => "leakage".to_owned(),
            Knob::ValveNaturalFrequency => "valve_natural_frequency".to_owned(),
            Knob::ValveDamping => "valve_damping".to_owned(),
            Knob::Inertia => "inertia".to_owned(),
            Knob::ViscousFriction => "viscous_friction".to_owned(),
            Knob::LoadTorque => "load_torque".to_owned(),
            Knob::Effect(kind, key) => format!("{}.{key}", kind.name()),
        }
    }
}

/// How a knob is scaled for the optimizer: by its logarithm (positive
/// quantities spanning decades) or divided by a typical size.
#[derive(Debug, Clone, Copy)]
enum Scale {
    Log { min: f64, max: f64 },
    Linear { unit: f64, min: f64, max: f64 },
}

#[derive(Debug, Clone, Copy)]
struct Free {
    knob: Knob,
    scale: Scale,
}

const fn log(knob: Knob, min: f64, max: f64) -> Free {
    Free {
        knob,
        scale: Scale::Log { min, max },
    }
}

const fn linear(knob: Knob, unit: f64, min: f64, max: f64) -> Free {
    Free {
        knob,
        scale: Scale::Linear { unit, min, max },
    }
}

/// The baseline's free parameters of each part. Displacement, volumes and
/// supply pressure are the data sheet's and stay fixed: they set the scale
/// that the data alone cannot (only β/V, D/J and the like are observable).
fn baseline_knobs(part: Part, signals: &Signals) -> Vec<Free> {
    match part {
        Part::Hydraulic => vec![
            log(Knob::BulkModulus, 1e7, 1e11),
            log(Knob::FlowGain, 1e-7, 1e-2),
            log(Knob::FlowPressureCoefficient, 1e-16, 1e-9),
            log(Knob::Leakage, 1e-16, 1e-9),
            log(Knob::ValveNaturalFrequency, 2.0, 2000.0),
            log(Knob::ValveDamping, 0.02, 5.0),
        ],
        Part::Mechanical if fits_load_torque(signals) => vec![
            log(Knob::Inertia, 1e-3, 1e5),
            log(Knob::ViscousFriction, 1e-3, 1e5),
            linear(Knob::LoadTorque, 10.0, -1e6, 1e6),
        ],
        Part::Mechanical => vec![log(Knob::Inertia, 1e-3, 1e5), log(Knob::ViscousFriction, 1e-3, 1e5)],
        // From the command to the angle alone, the flow gain sets the
        // speed, inertia against the (data sheet's) oil stiffness the
        // hydraulic mode, and viscous friction with the valve's bandwidth
        // and damping its damping; the pressures' own coefficients are not
        // observable. Without the valve's damping, a foreign valve's phase
        // went to a false delay (clean plant 1000011: 5.5 ms, t 6.1).
        Part::Whole => vec![
            log(Knob::FlowGain, 1e-7, 1e-2),
            log(Knob::ValveNaturalFrequency, 2.0, 2000.0),
            log(Knob::ValveDamping, 0.02, 5.0),
            log(Knob::Inertia, 1e-3, 1e5),
            log(Knob::ViscousFriction, 1e-3, 1e5),
        ],
    }
}

/// Whether the rigid body's constant load torque is fitted: where the
/// torque is measured. A torque or force sensor's zero offset, or a drive's,
/// is the rule there, and a model without it takes it out on the friction
/// (on a measured linear axis, a 3 N offset of 150 N hid its Coulomb
/// friction: t 0.5 against 3.4, 6.5 with it). From the pressures it is
/// not fitted: on the foreign plants, whose transducers have no offset, it
/// slowed diagnose by 4–29 % and traded two plants' Coulomb friction for an
/// offset.
fn fits_load_torque(signals: &Signals) -> bool {
    signals.tau.is_some()
}

/// An effect's free parameters. The encoder step is not among them: a
/// staircase has no useful derivative, so it is read off the data instead.
fn effect_knobs(kind: EffectKind) -> Vec<Free> {
    let k = |key| Knob::Effect(kind, key);
    match kind {
        EffectKind::Deadzone => vec![linear(k("width"), 0.01, 0.0, 0.6), linear(k("offset"), 0.01, -0.3, 0.3)],
        EffectKind::Saturation => vec![linear(k("limit"), 0.01, 0.02, 1.0)],
        EffectKind::TimeDelay => vec![linear(k("delay_s"), 0.001, 0.0, 0.3)],
        EffectKind::AsymmetricGain => vec![log(k("ratio"), 0.1, 10.0)],
        EffectKind::OrificeFlow | EffectKind::Quantization => vec![],
        EffectKind::CoulombFriction => vec![
            log(k("coulomb"), 1e-2, 1e4),
            log(k("breakaway"), 1e-2, 1e4),
            // A Stribeck velocity is a creep speed, the data sheet's 0.05
            // rad/s. Allowed up to the rotator's working speeds (2 rad/s),
            // it made the breakaway excess a falling friction curve over
            // them, and fits settled with the sliding level at its floor
            // (4 of 20 foreign plants' 60 N·m missed, against 2 at 0.3).
            log(k("stribeck_velocity"), 1e-4, 0.3),
        ],
        EffectKind::GravityLoad => vec![
            linear(k("amplitude"), 10.0, -1e5, 1e5),
            linear(k("offset"), 0.01, -std::f64::consts::PI, std::f64::consts::PI),
        ],
        EffectKind::Backlash => vec![linear(k("width"), 0.001, 0.0, 0.5)],
        EffectKind::LoadFlexibility => vec![
            log(k("stiffness"), 1.0, 1e6),
            log(k("damping"), 1e-3, 1e6),
            linear(k("load_fraction"), 0.01, 0.02, 0.98),
        ],
    }
}

/// Whether an effect's main parameter sits at an edge of the range the fit
/// allows it, in words: an effect pressed against its range is standing in
/// for something else. (A secondary parameter at its edge, a Stribeck
/// velocity the data cannot resolve, says only that it is not identified.)
pub(crate) fn at_edge(kind: EffectKind, params: &BTreeMap<String, f64>) -> Option<String> {
    param_at_edge(kind, kind.main_param()?, params)
}

/// Whether the effect's parameter `key` sits at an edge of the range the
/// fit allows it, in words.
pub(crate) fn param_at_edge(kind: EffectKind, key: &str, params: &BTreeMap<String, f64>) -> Option<String> {
    effect_knobs(kind).into_iter().find_map(|free| {
        let Knob::Effect(_, knob_key) = free.knob else {
            return None;
        };
        if knob_key != key {
            return None;
        }
        let value = *params.get(key)?;
        let (lower, upper) = free.bounds();
        let scaled = free.scaled(value);
        let near = 1e-6 * (upper - lower);
        let edge = if scaled <= lower + near {
            "lower"
        } else if scaled >= upper - near {
            "upper"
        } else {
            return None;
        };
        Some(format!("{key} = {value:.4} is at the {edge} edge of its range"))
    })
}

/// A model under fit: parameters and effects as plain maps, so that any
/// knob can be set and the catalog validates the result.
#[derive(Debug, Clone)]
struct Working {
    plant: PlantParams,
    effects: EffectsConfig,
}

impl Working {
    fn value(&self, knob: Knob) -> f64 {
        let p = &self.plant;
        match knob {
            Knob::BulkModulus => p.bulk_modulus,
            Knob::FlowGain => p.flow_gain,
            Knob::FlowPressureCoefficient => p.flow_pressure_coefficient,
            Knob::Leakage => p.leakage,
            Knob::ValveNaturalFrequency => p.valve_natural_frequency,
            Knob::ValveDamping => p.valve_damping,
            Knob::Inertia => p.inertia,
            Knob::ViscousFriction => p.viscous_friction,
            Knob::LoadTorque => p.load_torque,
            Knob::Effect(kind, key) => self
                .effects
                .0
                .get(kind.name())
                .and_then(|params| params.get(key))
                .copied()
                .or_else(|| kind.params().iter().find(|s| s.key == key).map(|s| s.default))
                .unwrap_or(0.0),
        }
    }

    fn set(&mut self, knob: Knob, value: f64) {
        let p = &mut self.plant;
        match knob {
            Knob::BulkModulus => p.bulk_modulus = value,
            Knob::FlowGain => p.flow_gain = value,
            Knob::FlowPressureCoefficient => p.flow_pressure_coefficient = value,
            Knob::Leakage => p.leakage = value,
            Knob::ValveNaturalFrequency => p.valve_natural_frequency = value,
            Knob::ValveDamping => p.valve_damping = value,
            Knob::Inertia => p.inertia = value,
            Knob::ViscousFriction => p.viscous_friction = value,
            Knob::LoadTorque => p.load_torque = value,
            Knob::Effect(kind, key) => {
                self.effects
                    .0
                    .entry(kind.name().to_owned())
                    .or_default()
                    .insert(key.to_owned(), value);
            }
        }
    }

    fn insert(&mut self, effect: Effect) {
        self.effects.0.insert(
            effect.kind().name().to_owned(),
            effect.params().into_iter().map(|(k, v)| (k.to_owned(), v)).collect(),
        );
    }

    fn of(model: &Model) -> Self {
        Self {
            plant: model.plant,
            effects: model.effects.clone(),
        }
    }

    fn has(&self, kind: EffectKind) -> bool {
        self.effects.0.contains_key(kind.name())
    }

    fn build(&self) -> Option<Effects> {
        self.plant.validate().ok()?;
        self.effects.build().ok()
    }
}

impl Free {
    fn bounds(&self) -> (f64, f64) {
        match self.scale {
            Scale::Log { min, max } => (min.ln(), max.ln()),
            Scale::Linear { unit, min, max } => (min / unit, max / unit),
        }
    }

    fn scaled(self, value: f64) -> f64 {
        let (lower, upper) = self.bounds();
        let scaled = match self.scale {
            Scale::Log { min, .. } => value.max(min).ln(),
            Scale::Linear { unit, .. } => value / unit,
        };
        scaled.clamp(lower, upper)
    }

    fn unscaled(self, scaled: f64) -> f64 {
        match self.scale {
            Scale::Log { .. } => scaled.exp(),
            Scale::Linear { unit, .. } => scaled * unit,
        }
    }
}

/// The loss a part is fitted under: each output's residual divided by its
/// spread (so that pressures and angle weigh alike), through the Huber loss.
/// It is set once, from the model a fit starts from; a diagnosis fits the
/// baseline and every candidate of a part under the same one, so that they
/// minimize the same thing.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Loss {
    spreads: [f64; 2],
    /// Huber threshold on the normalized residual; infinite for plain least squares.
    threshold: f64,
}

impl Loss {
    /// From the residuals of `start` on `range`: the threshold at 1.345
    /// robust standard deviations of them (Huber's 95%-efficiency choice).
    fn from_model(part: Part, start: &Working, signals: &Signals, range: Range<usize>) -> Result<Self, ModelError> {
        let spreads = output_spreads(part, signals, range.clone());
        let plain = Loss {
            spreads,
            threshold: f64::INFINITY,
        };
        let effects = start
            .build()
            .ok_or_else(|| ModelError::Fit("the starting model is not valid".to_owned()))?;
        let initial = plain.residuals(
            part,
            signals,
            &predict_part(part, &start.plant, &effects, signals, range.clone()),
            range,
        );
        // The pressures sit at tank or supply now and then, where the
        // model's linear flow is wrong: Huber keeps those from steering the
        // fit. The angle has no such moments, and a missing friction shows
        // as a few large errors while the load sticks: least squares.
        let threshold = match part {
            Part::Hydraulic => 1.345 * 1.4826 * median_abs(&initial).max(1e-9),
            Part::Mechanical | Part::Whole => f64::INFINITY,
        };
        Ok(Loss { spreads, threshold })
    }

    fn residuals(&self, part: Part, signals: &Signals, prediction: &Prediction, range: Range<usize>) -> Vec<f64> {
        let mut out = Vec::with_capacity(2 * range.len());
        let scales = [self.spreads[0].recip(), self.spreads[1].recip()];
        let mut push = |r: f64| {
            let a = r.abs();
            // √(2 ρ(r)) with the sign of r: least squares on these is Huber on r.
            let robust = if a <= self.threshold {
                r
            } else {
                r.signum() * (2.0 * self.threshold * a - self.threshold * self.threshold).sqrt()
            };
            out.push(robust);
        };
        match part {
            Part::Hydraulic => {
                for k in range {
                    push((signals.p_a[k] - prediction.p_a[k]) * scales[0]);
                    push((signals.p_b[k] - prediction.p_b[k]) * scales[1]);
                }
            }
            Part::Mechanical | Part::Whole => {
                for k in range {
                    push((signals.theta[k] - prediction.theta[k]) * scales[0]);
                }
            }
        }
        out
    }
}

/// The spread of each output a part predicts, on `range`.
fn output_spreads(part: Part, signals: &Signals, range: Range<usize>) -> [f64; 2] {
    match part {
        Part::Hydraulic => [spread(&signals.p_a[range.clone()]), spread(&signals.p_b[range])],
        Part::Mechanical | Part::Whole => [spread(&signals.theta[range]), 1.0],
    }
}

pub(crate) fn spread(x: &[f64]) -> f64 {
    let n = x.len().max(1) as f64;
    let mean = x.iter().sum::<f64>() / n;
    (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n)
        .sqrt()
        .max(1e-12)
}

fn predict_part(
    part: Part,
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
) -> Prediction {
    let mut prediction = Prediction::new(signals.len());
    super::predict_part_into(part, plant, effects, signals, range, &mut prediction);
    prediction
}

/// How well the data pins a fit's parameters down.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Uncertainty {
    /// One standard deviation of each fitted parameter, in its own units
    /// (`inertia`, `deadzone.width`, …), from JᵀJ at the optimum with the
    /// residuals' variance, widened for their autocorrelation.
    pub std: BTreeMap<String, f64>,
    /// Pairs the data cannot separate: |correlation| above 0.95, with it.
    pub inseparable: Vec<String>,
}

/// Correlation above which two parameters are said to move as one.
const INSEPARABLE_CORRELATION: f64 = 0.95;

/// One part fitted: the model, its cost under the part's loss, and how
/// well the data fixes each knob.
#[derive(Debug, Clone)]
pub(crate) struct PartFit {
    working: Working,
    /// Sum of squared (Huber) residuals per residual.
    pub cost: f64,
    pub uncertainty: Uncertainty,
}

/// Fits one part's knobs on `range` under `loss`, until it converges or
/// spends `options.max_iterations`, with the parameters' uncertainty.
fn fit_part(
    part: Part,
    start: &Working,
    knobs: &[Free],
    signals: &Signals,
    range: Range<usize>,
    options: FitOptions,
    loss: Loss,
) -> Result<PartFit, ModelError> {
    let (working, result) = minimize_part(part, start, knobs, signals, range, options, loss)?;
    let stride = match part {
        Part::Hydraulic => 2,
        Part::Mechanical | Part::Whole => 1,
    };
    let uncertainty = uncertainty(knobs, &working, &result, &result.residuals, stride);
    Ok(PartFit {
        working,
        cost: result.cost / result.residuals.len().max(1) as f64,
        uncertainty,
    })
}

/// [`fit_part`]'s search alone: the fitted model and the optimizer's end.
/// A screened start needs no more (its uncertainty's autocorrelation would
/// cost a pass over every lag, never read).
fn minimize_part(
    part: Part,
    start: &Working,
    knobs: &[Free],
    signals: &Signals,
    range: Range<usize>,
    options: FitOptions,
    loss: Loss,
) -> Result<(Working, lm::LmResult), ModelError> {
    let theta0: Vec<f64> = knobs.iter().map(|f| f.scaled(start.value(f.knob))).collect();
    let (lower, upper): (Vec<f64>, Vec<f64>) = knobs.iter().map(Free::bounds).unzip();
    let apply = |theta: &[f64]| -> Working {
        let mut w = start.clone();
        for (f, t) in knobs.iter().zip(theta) {
            w.set(f.knob, f.unscaled(*t));
        }
        w
    };
    let residuals = |theta: &[f64]| -> Option<Vec<f64>> {
        let w = apply(theta);
        let effects = w.build()?;
        let prediction = predict_part(part, &w.plant, &effects, signals, range.clone());
        let r = loss.residuals(part, signals, &prediction, range.clone());
        r.iter().all(|v| v.is_finite()).then_some(r)
    };
    let result = lm::minimize(
        &theta0,
        &lower,
        &upper,
        residuals,
        LmOptions {
            max_iterations: options.max_iterations,
            ..LmOptions::default()
        },
    )
    .ok_or_else(|| ModelError::Fit(format!("the {part:?} part does not simulate from its start")))?;
    Ok((apply(&result.params), result))
}

/// The knobs' standard deviations and inseparable pairs at a fit's optimum:
/// σ² (JᵀJ)⁻¹ with σ² the residuals' variance, times N / N_eff for their
/// autocorrelation (output-error residuals are far from white).
fn uncertainty(
    knobs: &[Free],
    working: &Working,
    result: &lm::LmResult,
    residuals: &[f64],
    stride: usize,
) -> Uncertainty {
    let p = knobs.len();
    let n = residuals.len();
    if p == 0 || n <= p {
        return Uncertainty::default();
    }
    let Some(inverse) = result.normal_matrix.clone().try_inverse() else {
        return Uncertainty {
            std: BTreeMap::new(),
            inseparable: vec!["the parameters are not all identifiable from this data (JᵀJ is singular)".to_owned()],
        };
    };
    let variance = lm::sum_of_squares(residuals) / (n - p) as f64;
    let widen = n as f64 / effective_sample_size(residuals, stride).max(1.0);
    let covariance = inverse * (variance * widen);
    let mut std = BTreeMap::new();
    for (i, free) in knobs.iter().enumerate() {
        let scaled_std = covariance[(i, i)].max(0.0).sqrt();
        // Back to the parameter's units: a log knob's σ is relative.
        let value = working.value(free.knob);
        let sigma = match free.scale {
            Scale::Log { .. } => value.abs() * scaled_std,
            Scale::Linear { unit, .. } => unit * scaled_std,
        };
        std.insert(free.knob.name(), sigma);
    }
    let mut inseparable = Vec::new();
    for i in 0..p {
        for j in i + 1..p {
            let denominator = (covariance[(i, i)] * covariance[(j, j)]).sqrt();
            let correlation = covariance[(i, j)] / denominator;
            if denominator > 0.0 && correlation.abs() > INSEPARABLE_CORRELATION {
                inseparable.push(format!(
                    "{} and {} (correlation {correlation:+.3}): the data fixes a combination of them, not each",
                    knobs[i].knob.name(),
                    knobs[j].knob.name()
                ));
            }
        }
    }
    Uncertainty { std, inseparable }
}

/// The effective number of independent residuals, N / (1 + 2 Σ ρ_k), the
/// autocorrelations ρ_k at lags of whole samples (`stride` residuals per
/// sample) summed while positive (Geyer's initial positive sequence).
pub(crate) fn effective_sample_size(residuals: &[f64], stride: usize) -> f64 {
    let n = residuals.len();
    let stride = stride.max(1);
    if n < 4 * stride {
        return n as f64;
    }
    let mean = residuals.iter().sum::<f64>() / n as f64;
    let centred: Vec<f64> = residuals.iter().map(|r| r - mean).collect();
    let variance = centred.iter().map(|r| r * r).sum::<f64>();
    if variance <= 0.0 {
        return n as f64;
    }
    let lagged = lagged_products(&centred);
    let mut sum = 0.0;
    for lag in (stride..n / 2).step_by(stride) {
        let rho = lagged[lag] / variance;
        if rho <= 0.0 {
            break;
        }
        sum += rho;
    }
    n as f64 / (1.0 + 2.0 * sum)
}

/// Σ_k x[k + lag]·x[k] for every lag, through the FFT, zero-padded so it
/// does not wrap around: output-error residuals stay correlated over
/// thousands of lags, and the direct sums cost N per lag.
fn lagged_products(x: &[f64]) -> Vec<f64> {
    use rustfft::num_complex::Complex;
    let size = (2 * x.len()).next_power_of_two();
    let mut planner = rustfft::FftPlanner::new();
    let mut buffer: Vec<Complex<f64>> = x
        .iter()
        .map(|&v| Complex::new(v, 0.0))
        .chain(std::iter::repeat(Complex::new(0.0, 0.0)))
        .take(size)
        .collect();
    planner.plan_fft_forward(size).process(&mut buffer);
    for c in &mut buffer {
        *c = Complex::new(c.norm_sqr(), 0.0);
    }
    planner.plan_fft_inverse(size).process(&mut buffer);
    buffer.iter().take(x.len()).map(|c| c.re / size as f64).collect()
}

fn median_abs(x: &[f64]) -> f64 {
    let mut a: Vec<f64> = x.iter().map(|v| v.abs()).filter(|v| v.is_finite()).collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f64::total_cmp);
    a[a.len() / 2]
}

/// One part's cost under `loss` on `range`, per residual.
fn part_cost(part: Part, w: &Working, signals: &Signals, range: Range<usize>, loss: Loss) -> f64 {
    let Some(effects) = w.build() else {
        return f64::INFINITY;
    };
    let prediction = predict_part(part, &w.plant, &effects, signals, range.clone());
    let r = loss.residuals(part, signals, &prediction, range);
    let cost = lm::sum_of_squares(&r) / r.len().max(1) as f64;
    if cost.is_finite() {
        cost
    } else {
        f64::INFINITY
    }
}

/// Starting values to try for an effect: its main parameter over the range
/// it can plausibly take, the others at the catalog's defaults.
fn starts(kind: EffectKind, signals: &Signals) -> Vec<Effect> {
    let with = |pairs: &[(&str, f64)]| -> Option<Effect> {
        let given: BTreeMap<String, f64> = pairs.iter().map(|(k, v)| ((*k).to_owned(), *v)).collect();
        Effect::from_params(kind, &given).ok()
    };
    let values: Vec<Vec<(&str, f64)>> = match kind {
        EffectKind::Deadzone => [0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3]
            .iter()
            .map(|w| vec![("width", *w)])
            .collect(),
        EffectKind::Saturation => {
            let peak = signals.u.iter().fold(0.0_f64, |m, u| m.max(u.abs()));
            [0.3, 0.45, 0.6, 0.75, 0.9]
                .iter()
                .map(|f| vec![("limit", (f * peak).max(0.02))])
                .collect()
        }
        EffectKind::TimeDelay => [0.002, 0.005, 0.01, 0.02, 0.035, 0.05, 0.08]
            .iter()
            .map(|d| vec![("delay_s", *d)])
            .collect(),
        EffectKind::AsymmetricGain => [0.4, 0.55, 0.7, 0.85, 1.2, 1.5, 2.0]
            .iter()
            .map(|r| vec![("ratio", *r)])
            .collect(),
        EffectKind::OrificeFlow => vec![vec![]],
        EffectKind::CoulombFriction => [3.0, 10.0, 25.0, 50.0, 100.0, 200.0]
            .iter()
            .map(|c| vec![("coulomb", *c), ("breakaway", 1.5 * c)])
            .collect(),
        EffectKind::GravityLoad => [-300.0, -100.0, -30.0, 30.0, 100.0, 300.0]
            .iter()
            .map(|a| vec![("amplitude", *a)])
            .collect(),
        EffectKind::Backlash => [0.002, 0.005, 0.01, 0.02, 0.04, 0.08]
            .iter()
            .map(|w| vec![("width", *w)])
            .collect(),
        EffectKind::Quantization => {
            let step = encoder_step(&signals.theta);
            [0.98, 1.0, 1.02].iter().map(|f| vec![("step", f * step)]).collect()
        }
        EffectKind::LoadFlexibility => [1000.0, 2500.0, 5000.0, 10000.0, 25000.0]
            .iter()
            .map(|s| vec![("stiffness", *s), ("damping", 0.005 * s)])
            .collect(),
    };
    values.iter().filter_map(|pairs| with(pairs)).collect()
}

/// The encoder's step as the data shows it: the smallest change of the
/// angle between samples that is not noise (the 2nd percentile of the
/// nonzero changes).
pub(crate) fn encoder_step(theta: &[f64]) -> f64 {
    let mut changes: Vec<f64> = theta
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 1e-12)
        .collect();
    if changes.is_empty() {
        return 1e-3;
    }
    changes.sort_by(f64::total_cmp);
    changes[changes.len() / 50]
}

/// Validation NRMSE per output: ‖y − ŷ‖ / ‖y − mean(y)‖ on `range`, for
/// `theta`, and where the record has them `p_a`, `p_b` and `pressures`
/// (both chambers together).
pub fn validation_nrmse(
    model_plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
) -> BTreeMap<String, f64> {
    let prediction = super::predict(model_plant, effects, signals, range.clone());
    nrmse_by_output(signals, &prediction, range)
}

pub(crate) fn nrmse_by_output(
    signals: &Signals,
    prediction: &Prediction,
    range: Range<usize>,
) -> BTreeMap<String, f64> {
    let sums = |y: &[f64], yhat: &[f64]| -> (f64, f64) {
        let n = range.len().max(1) as f64;
        let mean = y[range.clone()].iter().sum::<f64>() / n;
        let error = range.clone().map(|k| (y[k] - yhat[k]).powi(2)).sum::<f64>();
        let total = range.clone().map(|k| (y[k] - mean).powi(2)).sum::<f64>().max(1e-30);
        (error, total)
    };
    let t = sums(&signals.theta, &prediction.theta);
    let mut out = BTreeMap::from([("theta".to_owned(), (t.0 / t.1).sqrt())]);
    // The pressures are outputs only where the hydraulic part is fitted.
    if signals.parts().contains(&Part::Hydraulic) {
        let a = sums(&signals.p_a, &prediction.p_a);
        let b = sums(&signals.p_b, &prediction.p_b);
        out.insert("p_a".to_owned(), (a.0 / a.1).sqrt());
        out.insert("p_b".to_owned(), (b.0 / b.1).sqrt());
        out.insert("pressures".to_owned(), ((a.0 + b.0) / (a.1 + b.1)).sqrt());
    }
    out
}

/// Fits the baseline (no effects) from the prior's parameters: each part
/// to convergence, under the loss of its own first fit.
pub fn fit_baseline(signals: &Signals, prior: &PlantParams, options: FitOptions) -> Result<Model, ModelError> {
    let mut model = Model::new(*prior, Effects::none());
    for part in signals.parts() {
        // The prior's residuals are the model error of a wrong prior: a
        // first fit under its loss, then to convergence under the fitted one's.
        let first = refit_part(signals, &model, part, options, None)?.0;
        model = refit_part(signals, &first, part, options, None)?.0;
    }
    let effects = model.effects()?;
    let validation = signals.split(options.estimation_fraction)..signals.len();
    let errors = validation_nrmse(&model.plant, &effects, signals, validation.clone());
    let mut step = HistoryStep::of("baseline", &model.plant, &model.effects, errors);
    step.validation_spread = super::validation_spread(&model.plant, &effects, signals, validation);
    model.history.push(step);
    Ok(model)
}

/// The loss a diagnosis fits `part` of `model` and its candidates under.
pub(crate) fn part_loss(signals: &Signals, model: &Model, part: Part, options: FitOptions) -> Result<Loss, ModelError> {
    let estimation = 0..signals.split(options.estimation_fraction);
    Loss::from_model(part, &Working::of(model), signals, estimation)
}

/// Refits `part` of `model` with the effects it has, from the same starts
/// a candidate gets (the model as it is, and for the mechanical part the
/// rigid body by equation error), under `loss` (else the model's own), to
/// convergence. The history is kept as it was.
pub(crate) fn refit_part(
    signals: &Signals,
    model: &Model,
    part: Part,
    options: FitOptions,
    loss: Option<Loss>,
) -> Result<(Model, PartFit), ModelError> {
    let start = Working::of(model);
    let estimation = 0..signals.split(options.estimation_fraction);
    let loss = match loss {
        Some(l) => l,
        None => Loss::from_model(part, &start, signals, estimation.clone())?,
    };
    let knobs = part_knobs(part, &start, None, signals);
    let mut best: Option<PartFit> = None;
    for base in bases(part, &start, signals, estimation.clone()) {
        let Ok(fitted) = fit_part(part, &base, &knobs, signals, estimation.clone(), options, loss) else {
            continue;
        };
        if best.as_ref().is_none_or(|b| fitted.cost < b.cost) {
            best = Some(fitted);
        }
    }
    let fitted = best.ok_or_else(|| ModelError::Fit(format!("the {part:?} part does not simulate from its start")))?;
    let out = Model {
        plant: fitted.working.plant,
        effects: fitted.working.effects.clone(),
        history: model.history.clone(),
    };
    Ok((out, fitted))
}

/// Adds `kind` to `model` and refits the part it acts on: the effect's
/// parameters from the best of several starts, then all of that part's
/// parameters together. The history gains a step.
pub fn fit(signals: &Signals, model: &Model, kind: EffectKind, options: FitOptions) -> Result<Model, ModelError> {
    let part = signals.part_for(kind).map_err(|reason| ModelError::NotJudged {
        effect: kind.name(),
        reason,
    })?;
    let loss = part_loss(signals, model, part, options)?;
    Ok(fit_effect(signals, model, kind, options, loss)?.0)
}

/// [`fit`] under a given loss, with the part's fit.
pub(crate) fn fit_effect(
    signals: &Signals,
    model: &Model,
    kind: EffectKind,
    options: FitOptions,
    loss: Loss,
) -> Result<(Model, PartFit), ModelError> {
    let start = Working::of(model);
    if start.has(kind) {
        return Err(ModelError::AlreadyIn(kind.name()));
    }
    let part = signals.part_for(kind).map_err(|reason| ModelError::NotJudged {
        effect: kind.name(),
        reason,
    })?;
    let estimation = 0..signals.split(options.estimation_fraction);
    let knobs = part_knobs(part, &start, Some(kind), signals);
    // Starts are screened on the first third of the estimation segment.
    // For the mechanical part, a few iterations from each start with all
    // of the part's parameters free: inertia and viscous friction absorb
    // much of a missing friction or load, and must give it back before a
    // start can be judged.
    let screening = estimation.start..estimation.start + estimation.len() / 3;
    let mut pairs: Vec<(Working, Effect)> = bases(part, &start, signals, estimation.clone())
        .into_iter()
        .flat_map(|b| starts(kind, signals).into_iter().map(move |e| (b.clone(), e)))
        .collect();
    // Coulomb friction also from the data alone, as inverse dynamics finds
    // it: on foreign plants a start from the catalog's levels settled at 4–13
    // N·m of 60 where the body took the rest.
    if kind == EffectKind::CoulombFriction && part == Part::Mechanical {
        if let Some(body) = rigid_body_by_equation_error(signals, &start.plant, estimation.clone(), true) {
            let given = BTreeMap::from([
                ("coulomb".to_owned(), body.coulomb),
                ("breakaway".to_owned(), 1.5 * body.coulomb),
            ]);
            if let Ok(effect) = Effect::from_params(kind, &given) {
                pairs.push((body.applied(&start, signals), effect));
            }
        }
    }
    // Each start is screened on its own: in parallel, the first of the
    // lowest kept (as in order).
    let screened: Vec<Option<(f64, Working)>> = pairs
        .into_par_iter()
        .map(|(base, effect)| {
            let mut candidate = base;
            candidate.insert(effect);
            let screened = match part {
                // The pressures' baseline absorbs little of a hydraulic
                // effect: judging each start as it is suffices.
                Part::Hydraulic => candidate,
                Part::Mechanical | Part::Whole => {
                    let quick = FitOptions {
                        max_iterations: SCREENING_ITERATIONS,
                        ..options
                    };
                    minimize_part(part, &candidate, &knobs, signals, screening.clone(), quick, loss)
                        .ok()?
                        .0
                }
            };
            Some((part_cost(part, &screened, signals, screening.clone(), loss), screened))
        })
        .collect();
    // The lowest first, the first of equals as in order; a start that
    // simulates its screening third may still diverge on the whole segment
    // (a lightly damped valve on a foreign plant did), and yields to the next.
    let mut ranked: Vec<(f64, Working)> = screened.into_iter().flatten().collect();
    ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
    let fitted = ranked
        .iter()
        .find_map(|(_, seeded)| fit_part(part, seeded, &knobs, signals, estimation.clone(), options, loss).ok())
        .ok_or_else(|| ModelError::Fit(format!("no start for `{kind}` simulates the {} part", part.name())))?;
    let mut out = Model {
        plant: fitted.working.plant,
        effects: fitted.working.effects.clone(),
        history: model.history.clone(),
    };
    let effects = out.effects()?;
    let validation = signals.split(options.estimation_fraction)..signals.len();
    let errors = validation_nrmse(&out.plant, &effects, signals, validation.clone());
    let mut step = HistoryStep::of(kind.name(), &out.plant, &out.effects, errors);
    step.validation_spread = super::validation_spread(&out.plant, &effects, signals, validation);
    out.history.push(step);
    Ok((out, fitted))
}

/// A part's knobs: the baseline's, and those of every effect of the part
/// the model has (and of `adding`).
fn part_knobs(part: Part, model: &Working, adding: Option<EffectKind>, signals: &Signals) -> Vec<Free> {
    let mut knobs = baseline_knobs(part, signals);
    for present in EffectKind::ALL {
        if signals.part_for(present) == Ok(part) && (model.has(present) || Some(present) == adding) {
            knobs.extend(effect_knobs(present));
        }
    }
    knobs
}

/// Where a part's fit starts: the model as it is, and for the mechanical
/// part also the rigid body by equation error (inertia, viscous friction and
/// load torque from the data alone).
fn bases(part: Part, start: &Working, signals: &Signals, estimation: Range<usize>) -> Vec<Working> {
    let mut bases = vec![start.clone()];
    if part == Part::Mechanical {
        if let Some(body) = rigid_body_by_equation_error(signals, &start.plant, estimation, false) {
            bases.push(body.applied(start, signals));
        }
    }
    bases
}

/// How long the measured pressures lag the motion they drive, s: the shift
/// of the torque D (p_a − p_b) that best fits J ω̇ + b ω + c by equation
/// error on `range`, searched up to `longest` (parabolic between samples).
/// A lag of the valve delays pressures and motion alike and leaves this
/// near zero; a lag of the pressure transducers shows here and nowhere
/// else. Every signal is filtered by zero-phase windows, so no filter
/// shifts one against another. `None` without measured pressures.
pub(crate) fn pressure_lag_behind_motion(
    signals: &Signals,
    plant: &PlantParams,
    range: Range<usize>,
    longest: f64,
) -> Option<f64> {
    if !signals.has_pressures || signals.tau.is_some() {
        return None;
    }
    let torque: Vec<f64> = (0..signals.len()).map(|k| signals.torque(plant, k)).collect();
    let torque = super::signals::moving_average(&torque, PRESSURE_LAG_SMOOTHING_S, signals.dt);
    let most = ((longest / signals.dt).ceil() as usize).max(2);
    let end = range.end.min(signals.len().saturating_sub(most + 1));
    if end <= range.start + 10 * most {
        return None;
    }
    // The regressors do not move with the shift: their normal matrix is
    // factored once, and each shift costs two passes over the data.
    let rows = range.start..end;
    let regressors = |k: usize| [signals.acceleration[k], signals.velocity[k], 1.0];
    let mut normal = nalgebra::Matrix3::zeros();
    for k in rows.clone() {
        let x = nalgebra::Vector3::from(regressors(k));
        normal += x * x.transpose();
    }
    let factored = normal.lu();
    let residual = |shift: usize| -> f64 {
        let mut projected = nalgebra::Vector3::zeros();
        for k in rows.clone() {
            projected += nalgebra::Vector3::from(regressors(k)) * torque[k + shift];
        }
        let Some(solution) = factored.solve(&projected) else {
            return f64::INFINITY;
        };
        rows.clone()
            .map(|k| (torque[k + shift] - nalgebra::Vector3::from(regressors(k)).dot(&solution)).powi(2))
            .sum()
    };
    let costs: Vec<f64> = (0..=most).map(residual).collect();
    let best = (0..costs.len()).min_by(|i, j| costs[*i].total_cmp(&costs[*j]))?;
    let offset = if best > 0 && best < most {
        let (l, c, r) = (costs[best - 1], costs[best], costs[best + 1]);
        let curvature = l - 2.0 * c + r;
        if curvature > 0.0 {
            0.5 * (l - r) / curvature
        } else {
            0.0
        }
    } else {
        0.0
    };
    Some((best as f64 + offset) * signals.dt)
}

/// Half-width of the torque's smoothing for [`pressure_lag_behind_motion`],
/// s: the velocity's own (its acceleration is smoothed as much).
const PRESSURE_LAG_SMOOTHING_S: f64 = 0.02;

/// Half-width of the equation error's moving average, s: its first null is
/// at 5 Hz, below a flexible load's mode.
const LOW_PASS_HALF_WIDTH_S: f64 = 0.1;

/// The rigid body by equation error, J ω̇ + b ω + T = D (p_a − p_b) (or the
/// measured torque), on the smoothed velocity and its smoothed derivative:
/// a start for the mechanical part that depends on the data only, not on
/// the prior's guess. With `coulomb`, F_c sign(ω) is a regressor too, as in
/// the inverse-dynamics identification of robots and machine tools
/// (IDIM-LS). `None` when the data does not give a positive J and b.
fn rigid_body_by_equation_error(
    signals: &Signals,
    plant: &PlantParams,
    range: Range<usize>,
    coulomb: bool,
) -> Option<RigidBody> {
    // All through the same low-pass: the equation holds for the filtered
    // signals too, and the filter keeps out what a rigid body cannot
    // explain (a flexible load's ringing, the encoder's steps).
    let low_pass = |x: &[f64]| super::signals::moving_average(x, LOW_PASS_HALF_WIDTH_S, signals.dt);
    let velocity = low_pass(&signals.velocity);
    let acceleration = low_pass(&super::signals::smoothed_slope(&signals.velocity, signals.dt));
    let torque: Vec<f64> = (0..signals.len()).map(|k| signals.torque(plant, k)).collect();
    let torque = low_pass(&torque);
    // A regressor left out has an empty row and column: its unknown is
    // pinned at zero. Without a fitted load torque, no constant: the
    // start's J and b are then those of the model that is fitted.
    let used = [true, true, coulomb, fits_load_torque(signals)];
    let mut normal = nalgebra::Matrix4::zeros();
    let mut projected = nalgebra::Vector4::zeros();
    for k in range {
        let v = velocity[k];
        let regressors = [acceleration[k], v, v.signum(), 1.0];
        let x = nalgebra::Vector4::from(std::array::from_fn(|i| if used[i] { regressors[i] } else { 0.0 }));
        if x.iter().all(|v| v.is_finite()) && torque[k].is_finite() {
            normal += x * x.transpose();
            projected += x * torque[k];
        }
    }
    for (i, used) in used.iter().enumerate() {
        if !used {
            normal[(i, i)] = 1.0;
        }
    }
    let solution = normal.lu().solve(&projected)?;
    (solution[0] > 0.0 && solution[1] > 0.0 && solution.iter().all(|v| v.is_finite())).then_some(RigidBody {
        inertia: solution[0],
        viscous_friction: solution[1],
        coulomb: solution[2],
        load_torque: solution[3],
    })
}

/// The rigid body's parameters by equation error.
struct RigidBody {
    inertia: f64,
    viscous_friction: f64,
    /// F_c, where it was a regressor (else 0).
    coulomb: f64,
    load_torque: f64,
}

impl RigidBody {
    /// `start` with this body's parameters.
    fn applied(&self, start: &Working, signals: &Signals) -> Working {
        let mut fresh = start.clone();
        fresh.plant.inertia = self.inertia;
        fresh.plant.viscous_friction = self.viscous_friction;
        if fits_load_torque(signals) {
            fresh.plant.load_torque = self.load_torque;
        }
        fresh
    }
}
