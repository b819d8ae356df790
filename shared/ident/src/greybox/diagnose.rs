//! Diagnosis: try every effect of the catalog, refit, and rank the effects
//! by the validation error they remove, penalized for the parameters they add.

use std::collections::BTreeMap;

use hydractl_plant::EffectKind;
use serde::Serialize;

use super::fit::{fit, fit_baseline, FitOptions};
use super::{Model, ModelError, Part, Signals};

/// An effect must remove at least this fraction of its output's validation
/// NRMSE, after the penalty, to be called significant.
pub const SIGNIFICANT_REDUCTION: f64 = 0.15;
/// ... and at least this much of it in absolute terms: an encoder's own
/// resolution, for instance, halves a near-perfect model's tiny angle error
/// without being a missing effect.
pub const SIGNIFICANT_ABSOLUTE_REDUCTION: f64 = 0.005;
/// The penalty per parameter the effect adds, as a fraction of the NRMSE.
pub const PENALTY_PER_PARAMETER: f64 = 0.01;

#[derive(Debug, Clone, Serialize)]
pub struct Baseline {
    /// The RMS of the outputs' validation NRMSEs (`p_a`, `p_b`, `theta`).
    pub validation_nrmse: f64,
    /// Fit per output, percent: 100 (1 − NRMSE).
    pub fit_percent: BTreeMap<String, f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Candidate {
    pub effect: String,
    pub output: String,
    pub validation_nrmse_before: f64,
    pub validation_nrmse_after: f64,
    pub params: BTreeMap<String, f64>,
    pub significant: bool,
    pub evidence: String,
    /// Fraction of the output's NRMSE removed, less the parameter penalty: the rank.
    pub score: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    pub baseline: Baseline,
    pub candidates: Vec<Candidate>,
    /// One sentence: the effect to add, or that none helps significantly.
    pub verdict: String,
    #[serde(skip)]
    pub baseline_model: Model,
    #[serde(skip)]
    pub fitted: BTreeMap<String, Model>,
}

pub(crate) const OUTPUTS: [&str; 3] = ["p_a", "p_b", "theta"];

/// Diagnoses `model` (or a baseline fitted here when `None`) on `signals`.
pub fn diagnose(signals: &Signals, model: Option<&Model>, options: FitOptions) -> Result<Diagnosis, ModelError> {
    let base = match model {
        Some(m) => m.clone(),
        None => fit_baseline(signals, &hydractl_plant::PlantParams::default(), options)?,
    };
    let base_effects = base.effects()?;
    let validation = signals.split(options.estimation_fraction)..signals.len();
    let before = super::fit::validation_nrmse(&base.plant, &base_effects, signals, validation.clone());
    let fit_percent: BTreeMap<String, f64> = OUTPUTS
        .iter()
        .map(|o| ((*o).to_owned(), 100.0 * (1.0 - before[*o])))
        .collect();
    let overall = (OUTPUTS.iter().map(|o| before[*o].powi(2)).sum::<f64>() / OUTPUTS.len() as f64).sqrt();
    let mut candidates = Vec::new();
    let mut fitted = BTreeMap::new();
    for kind in EffectKind::ALL {
        if base.effects.0.contains_key(kind.name()) {
            continue;
        }
        let output = Part::of(kind).output();
        let refit = fit(signals, &base, kind, options)?;
        let after_all = refit
            .history
            .last()
            .map(|s| s.validation_nrmse.clone())
            .unwrap_or_default();
        let nrmse_before = before[output];
        let nrmse_after = after_all.get(output).copied().unwrap_or(f64::NAN);
        let parameters = kind.params().len() as f64;
        let score = if nrmse_before > 0.0 && nrmse_after.is_finite() {
            1.0 - nrmse_after / nrmse_before - PENALTY_PER_PARAMETER * parameters
        } else {
            f64::NEG_INFINITY
        };
        let params = refit.effects.0.get(kind.name()).cloned().unwrap_or_default();
        let significant =
            score >= SIGNIFICANT_REDUCTION && nrmse_before - nrmse_after >= SIGNIFICANT_ABSOLUTE_REDUCTION;
        let evidence = evidence(kind, &params, signals, &refit, nrmse_before, nrmse_after, significant);
        candidates.push(Candidate {
            effect: kind.name().to_owned(),
            output: output.to_owned(),
            validation_nrmse_before: nrmse_before,
            validation_nrmse_after: nrmse_after,
            params,
            significant,
            evidence,
            score,
        });
        fitted.insert(kind.name().to_owned(), refit);
    }
    candidates.sort_by(|a, b| b.significant.cmp(&a.significant).then(b.score.total_cmp(&a.score)));
    let verdict = match candidates.first() {
        Some(best) if best.significant => format!(
            "add `{}`: it removes {:.0}% of the {} error ({:.4} → {:.4})",
            best.effect,
            100.0 * (1.0 - best.validation_nrmse_after / best.validation_nrmse_before),
            best.output,
            best.validation_nrmse_before,
            best.validation_nrmse_after
        ),
        _ => "no effect of the catalog helps significantly: the model explains this data as well as it can".to_owned(),
    };
    Ok(Diagnosis {
        baseline: Baseline {
            validation_nrmse: overall,
            fit_percent,
        },
        candidates,
        verdict,
        baseline_model: base,
        fitted,
    })
}

/// The evidence for an effect in plain words, from the data and the fit.
fn evidence(
    kind: EffectKind,
    params: &BTreeMap<String, f64>,
    signals: &Signals,
    refit: &Model,
    before: f64,
    after: f64,
    significant: bool,
) -> String {
    let get = |key: &str| params.get(key).copied().unwrap_or(f64::NAN);
    let change = format!(
        "; with it the {} validation NRMSE goes {before:.4} → {after:.4}",
        Part::of(kind).output()
    );
    let what = match kind {
        EffectKind::Deadzone => {
            let width = get("width");
            let share = share(&signals.u, |u| u.abs() < width);
            format!(
                "the pressures do not build while |u| < {width:.3} ({:.0}% of the samples) though the baseline says they should: valve dead-zone",
                100.0 * share
            )
        }
        EffectKind::Saturation => {
            let limit = get("limit");
            let share = share(&signals.u, |u| u.abs() > limit);
            format!(
                "beyond |u| = {limit:.3} ({:.0}% of the samples) the pressures change no faster as the command grows: the spool is at its stop",
                100.0 * share
            )
        }
        EffectKind::TimeDelay => format!(
            "the pressures answer the command {:.1} ms later than the valve's own dynamics explain: a pure delay",
            1e3 * get("delay_s")
        ),
        EffectKind::AsymmetricGain => format!(
            "the pressures move {:.0}% as fast for negative commands as for positive ones: asymmetric flow gain",
            100.0 * get("ratio")
        ),
        EffectKind::OrificeFlow => {
            "the flow, and so the pressure rate, falls as the chamber pressure nears supply or tank: turbulent orifice flow (√Δp)".to_owned()
        }
        EffectKind::CoulombFriction => format!(
            "the load rests while the measured torque builds to {:.0} N·m, and moving costs {:.0} N·m more than viscous friction: Coulomb friction",
            get("breakaway"),
            get("coulomb")
        ),
        EffectKind::GravityLoad => format!(
            "the torque needed to hold the load follows sin(θ − {:.2}) with {:.0} N·m amplitude: a gravity load",
            get("offset"),
            get("amplitude")
        ),
        EffectKind::Backlash => format!(
            "after each velocity reversal the encoder stands still for {:.4} rad of the actuator's motion: backlash",
            get("width")
        ),
        EffectKind::Quantization => format!(
            "the angle moves in steps of {:.4} rad ({:.2}°) and no finer: a coarse encoder",
            get("step"),
            get("step").to_degrees()
        ),
        EffectKind::LoadFlexibility => {
            let inertia = refit.plant.inertia;
            let fraction = get("load_fraction");
            let stiffness = get("stiffness");
            let mode = (stiffness * (1.0 / (inertia * fraction) + 1.0 / (inertia * (1.0 - fraction)))).sqrt();
            format!(
                "the angle rings at {mode:.0} rad/s against the torque, which a rigid body cannot: a flexible load ({stiffness:.0} N·m/rad)"
            )
        }
    };
    if significant {
        format!("{what}{change}")
    } else if after > before {
        format!(
            "not significant: fitted, it makes the {} validation NRMSE worse, {before:.4} → {after:.4}",
            Part::of(kind).output()
        )
    } else {
        format!(
            "not significant: fitted, it changes the {} validation NRMSE only {before:.4} → {after:.4}",
            Part::of(kind).output()
        )
    }
}

fn share(x: &[f64], predicate: impl Fn(f64) -> bool) -> f64 {
    x.iter().filter(|v| predicate(**v)).count() as f64 / x.len().max(1) as f64
}
