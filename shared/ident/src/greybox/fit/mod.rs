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

mod knobs;
mod rigid_body;
mod sheet;
mod uncertainty;

use knobs::*;
pub(crate) use knobs::{at_edge, encoder_step, param_at_edge};
pub(crate) use rigid_body::pressure_lag_behind_motion;
use rigid_body::*;
use sheet::*;
pub(crate) use uncertainty::effective_sample_size;
pub use uncertainty::Uncertainty;
use uncertainty::*;

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
    let (working, result) = minimize_part(part, start, knobs, signals, range.clone(), options, loss)?;
    let stride = match part {
        Part::Hydraulic => 2,
        Part::Mechanical | Part::Whole => 1,
    };
    let uncertainty = uncertainty(knobs, &working, &result, &result.residuals, stride);
    // Steered by the shaft, the fit is scored by the encoder's reading, as
    // every other model's cost is.
    let cost = match working.build() {
        Some(effects) if steers_by_the_shaft(part, &effects) => part_cost(part, &working, signals, range, loss),
        _ => result.cost / result.residuals.len().max(1) as f64,
    };
    Ok(PartFit {
        working,
        cost,
        uncertainty,
    })
}

/// Whether the optimizer steers `part` by the shaft's angle rather than
/// the encoder's reading of it. A coarse encoder's reading is a staircase
/// in every parameter: a small change moves no reading, the Jacobian is
/// zero, and the fit ends where it started (a load's torque added beside a
/// 2° encoder stayed at its start, 100 N·m of 150, on both plants of the
/// foreign bench). The shaft's angle is smooth in the parameters, and the
/// reading's rounding is noise about it of a step's width.
fn steers_by_the_shaft(part: Part, effects: &Effects) -> bool {
    part != Part::Hydraulic && effects.quantization.is_some()
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
        let mut effects = w.build()?;
        if steers_by_the_shaft(part, &effects) {
            effects.quantization = None;
        }
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

/// The value of a parameter named as [`Uncertainty::std`] names it: a
/// `[plant]` key, or `effect.key`.
pub(crate) fn param_value(model: &Model, name: &str) -> Option<f64> {
    let working = Working::of(model);
    let knob = match name.split_once('.') {
        Some((effect, key)) => {
            let kind = EffectKind::from_name(effect).ok()?;
            Knob::Effect(kind, kind.params().iter().find(|s| s.key == key)?.key)
        }
        None => *[
            Knob::BulkModulus,
            Knob::FlowGain,
            Knob::FlowPressureCoefficient,
            Knob::Leakage,
            Knob::ValveNaturalFrequency,
            Knob::ValveDamping,
            Knob::Inertia,
            Knob::ViscousFriction,
            Knob::LoadTorque,
        ]
        .iter()
        .find(|k| k.name() == name)?,
    };
    Some(working.value(knob))
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
    let fitted = match from_the_data_sheet(part, &start, kind, &knobs, signals, &fitted, options, loss) {
        Some(other) if other.cost < fitted.cost => other,
        _ => fitted,
    };
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

/// Where a part's fit starts: the model as it is, and for the mechanical
/// part also the rigid body by equation error (inertia, viscous friction and
/// load torque from the data alone), and the data sheet's rigid body where
/// the model's inertia ran to its bound. A flexible load's data, from the
/// observer loop, drove the rigid baseline there (its inertia locked to
/// its viscous friction); from it the spring's fit stalled on 5 of 8
/// seeds (the angle's NRMSE 0.208 down to 0.080–0.127, against 0.046–0.047
/// from the data sheet's body on all 8).
fn bases(part: Part, start: &Working, signals: &Signals, estimation: Range<usize>) -> Vec<Working> {
    let mut bases = vec![start.clone()];
    if part == Part::Mechanical {
        if let Some(body) = rigid_body_by_equation_error(signals, &start.plant, estimation, false) {
            bases.push(body.applied(start, signals));
        }
        if start.plant.inertia >= 0.99 * INERTIA_MAX {
            let sheet = PlantParams::default();
            let mut body = start.clone();
            body.plant.inertia = sheet.inertia;
            body.plant.viscous_friction = sheet.viscous_friction;
            bases.push(body);
        }
    }
    bases
}
