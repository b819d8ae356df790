//! Diagnosis: try every effect of the catalog, refit, and judge each by a
//! paired test on held-out data.
//!
//! The baseline and every candidate of a part are fitted alike: from the
//! same starts, under the same loss, to convergence. An effect is called
//! significant when, segment by segment of the validation data (the 0.5 s
//! shooting segments, each started afresh from the measurements, so that
//! their errors are close to independent), it lowers its output's error by
//! more than [`MIN_ERROR_REMOVED`], by more than chance would: a one-sided
//! paired t-test or signed-rank test of each segment's fall, or a t-test
//! of the fall of the summed error (the effect's α split among them; no
//! signed-rank test under 20 effective segments), at α = 0.01 shared among
//! the effects tried (Bonferroni), scale-free by construction. A coarse encoder is also called by its
//! readings, every one on its step's lattice, where a model without
//! pressures is too far off to gain from its staircase.

use std::collections::{BTreeMap, BTreeSet};
use std::ops::Range;

use hydractl_plant::EffectKind;
use rayon::prelude::*;
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, Normal, StudentsT};

use super::fit::{fit_baseline, fit_effect, part_loss, refit_part, FitOptions, Uncertainty};
use super::{Model, ModelError, Part, Prediction, Signals, STEP_DELAY_MIN_S};

mod pairs;
mod plausibility;
mod stats;
mod steps;
#[cfg(test)]
mod tests;
mod ties;
mod verdict;

pub use pairs::{together, Together};
use plausibility::*;
use stats::*;
use steps::*;
use ties::*;
use verdict::*;

/// The family-wise false-alarm rate of a diagnosis: the chance that an
/// effect is called significant on data that lacks all of them.
pub const FAMILY_ALPHA: f64 = 0.01;

/// The level at which a fall the diagnosis turned down is still worth
/// naming as the nearest: what one effect tested alone, at the usual 5 %,
/// would pass.
const NEAR_MISS_ALPHA: f64 = 0.05;

/// The least share of an output's error an effect must remove to be named.
/// No machine is exactly the model, and 18 s of 1 kHz data resolve a
/// consistent sliver: on a foreign plant with nothing hidden a flexible
/// load took 0.1 % of the angle's error in every segment (t = 6.2 against
/// 3.3). The test's null is therefore a fall of at most this share, not of
/// none; the effects hidden in the foreign plants removed 27-99 %.
pub const MIN_ERROR_REMOVED: f64 = 0.02;

/// An encoder whose step is under this share of the angle's spread is the
/// sensor's resolution, not a missing effect: modelling its staircase
/// removes a consistent, and so statistically significant, sliver of a
/// good model's angle error, and changes nothing a control engineer would
/// act on.
pub const RESOLUTION_SHARE: f64 = 0.05;

#[derive(Debug, Clone, Serialize)]
pub struct Baseline {
    /// The RMS of the measured outputs' validation NRMSEs (`p_a`, `p_b`,
    /// `theta`, or `theta` alone without pressures): one figure for the
    /// model as a whole. `model fit` prints each output's; they are in
    /// `validation_nrmse_by_output`.
    pub validation_nrmse: f64,
    /// Validation NRMSE per output (`theta`, and `p_a`, `p_b`, `pressures`
    /// where measured).
    pub validation_nrmse_by_output: BTreeMap<String, f64>,
    /// Fit per output, percent: 100 (1 − NRMSE).
    pub fit_percent: BTreeMap<String, f64>,
    /// Its fitted parameters, named as in `uncertainty.std` (`inertia`,
    /// `coulomb_friction.coulomb`): what a fleet follows over a machine's life.
    pub params: BTreeMap<String, f64>,
    /// Its parameters' standard deviations, and the pairs the data cannot separate.
    pub uncertainty: Uncertainty,
}

#[derive(Debug, Clone, Serialize)]
pub struct Candidate {
    pub effect: String,
    pub output: String,
    pub validation_nrmse_before: f64,
    pub validation_nrmse_after: f64,
    pub params: BTreeMap<String, f64>,
    pub significant: bool,
    /// The statistic and its threshold, then what the data shows, in words.
    pub evidence: String,
    /// Fraction of the output's validation NRMSE removed: the rank among
    /// the significant, then among the rest.
    pub score: f64,
    /// The test over the validation segments that decided: `paired_t`, else
    /// `signed_rank` or `error_share`, the first of them that passed where
    /// the t did not.
    pub test: &'static str,
    /// Its statistic: the paired t, the signed-rank test's z, or the t of
    /// the share of the error removed.
    pub statistic: f64,
    /// The one-sided quantile it must pass (α shared by the effects tried
    /// and the tests run).
    pub threshold: f64,
    /// Validation segments compared.
    pub segments: usize,
    /// Their effective number, for their autocorrelation: the test's n.
    pub effective_segments: f64,
    /// The fitted parameters' standard deviations and inseparable pairs.
    pub uncertainty: Uncertainty,
    /// For the first: the other significant effects the record cannot
    /// tell from it (the first does not beat them by the share that counts).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub indistinguishable_from: Vec<String>,
    /// The part it was fitted and judged on.
    #[serde(skip)]
    part: Part,
    /// The encoder's step, where every reading of the angle lies on its
    /// lattice and the candidate is significant: shown by the readings
    /// themselves, it ranks before what a test makes likely.
    #[serde(skip)]
    read_off_step: Option<f64>,
    /// Why a fit that the test would pass is not the effect it names: it
    /// stands in for something the catalog lacks.
    #[serde(skip)]
    stands_in: Option<String>,
}

impl Candidate {
    /// How near its test came to passing (see [`share_of_threshold`]).
    fn share_of_threshold(&self) -> f64 {
        share_of_threshold(self.statistic, self.threshold)
    }

    /// Its test's figures for a verdict: "t = 2.7 against 3.6 over 36 segments".
    fn test_figures(&self) -> String {
        let over = if self.test == SegmentTest::StepWindows.name() {
            "steps' windows"
        } else {
            "segments"
        };
        format!(
            "{} = {:.1} against {:.1} over {} {over}",
            self.statistic_symbol(),
            self.statistic,
            self.threshold,
            self.segments
        )
    }

    /// The symbol of the statistic that decided, for a verdict.
    fn statistic_symbol(&self) -> &'static str {
        if self.test == SegmentTest::SignedRank.name() {
            "signed-rank z"
        } else if self.test == SegmentTest::ErrorShare.name() {
            "error-share t"
        } else if self.test == SegmentTest::StepWindows.name() {
            "error-share t at the command's steps"
        } else {
            "t"
        }
    }
}

/// An effect the record cannot show, and why.
#[derive(Debug, Clone, Serialize)]
pub struct NotJudged {
    pub effect: String,
    pub reason: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    /// The parts of the model the record's signals let it fit.
    pub parts: Vec<Part>,
    /// The catalog's effects it could not judge, with why.
    pub not_judged: Vec<NotJudged>,
    pub baseline: Baseline,
    pub candidates: Vec<Candidate>,
    /// One sentence: the effect to add, or that none helps significantly.
    pub verdict: String,
    #[serde(skip)]
    pub baseline_model: Model,
    #[serde(skip)]
    pub fitted: BTreeMap<String, Model>,
}

/// Diagnoses `model` (or a baseline fitted here from the default prior
/// when `None`) on `signals`.
pub fn diagnose(signals: &Signals, model: Option<&Model>, options: FitOptions) -> Result<Diagnosis, ModelError> {
    diagnose_with(signals, model, options, &super::Silent)
}

/// [`diagnose`], telling `progress` as each fit finishes: the baseline
/// from the prior (without a model), each part refitted, each candidate.
pub fn diagnose_with(
    signals: &Signals,
    model: Option<&Model>,
    options: FitOptions,
    progress: &dyn super::Progress,
) -> Result<Diagnosis, ModelError> {
    let parts = signals.parts();
    let candidates = EffectKind::ALL
        .iter()
        .filter(|k| model.is_none_or(|m| !m.effects.0.contains_key(k.name())) && signals.part_for(**k).is_ok())
        .count();
    let total = usize::from(model.is_none()) + parts.len() + candidates;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let finished = |what: &str| {
        let done = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress.fitted(what, done, total);
    };
    progress.fitted(
        if model.is_none() {
            "the baseline from the prior"
        } else {
            "the baseline"
        },
        0,
        total,
    );
    let start = match model {
        Some(m) => m.clone(),
        None => {
            let fitted = fit_baseline(signals, &hydractl_plant::PlantParams::default(), options)?;
            finished("the baseline from the prior");
            fitted
        }
    };
    // Each part refitted as hard as its candidates will be: the same
    // starts, the loss they share, to convergence.
    let losses = parts
        .iter()
        .map(|part| part_loss(signals, &start, *part, options))
        .collect::<Result<Vec<_>, _>>()?;
    let mut base = start.clone();
    let mut base_costs = vec![0.0; parts.len()];
    let mut uncertainty = Uncertainty::default();
    for (i, part) in parts.iter().enumerate() {
        let (refit, fitted) = refit_part(signals, &base, *part, options, Some(losses[i]))?;
        finished(&format!("the baseline's {} part", part.name()));
        base = refit;
        base_costs[i] = fitted.cost;
        uncertainty.extend(fitted.uncertainty);
    }
    let base_effects = base.effects()?;
    let validation = signals.split(options.estimation_fraction)..signals.len();
    let before_prediction = super::predict(&base.plant, &base_effects, signals, validation.clone());
    let before = super::fit::nrmse_by_output(signals, &before_prediction, validation.clone());
    // The measured outputs: each chamber and the angle, not their sum.
    let outputs: Vec<&str> = ["p_a", "p_b", "theta"]
        .into_iter()
        .filter(|o| before.contains_key(*o))
        .collect();
    let fit_percent: BTreeMap<String, f64> = outputs
        .iter()
        .map(|o| ((*o).to_owned(), 100.0 * (1.0 - before[*o])))
        .collect();
    let overall = (outputs.iter().map(|o| before[*o].powi(2)).sum::<f64>() / outputs.len().max(1) as f64).sqrt();
    let mut kinds = Vec::new();
    let mut not_judged = Vec::new();
    for kind in EffectKind::ALL {
        if base.effects.0.contains_key(kind.name()) {
            continue;
        }
        match signals.part_for(kind) {
            Ok(part) => kinds.push((kind, part)),
            Err(reason) => not_judged.push(NotJudged {
                effect: kind.name().to_owned(),
                reason,
            }),
        }
    }
    let tried = kinds.len().max(1);
    // Each candidate judged: fitted from the baseline under its part's
    // loss, then tested against it on the validation segments.
    let judge = |kind: &EffectKind, part: Part| -> Result<(Candidate, Model, bool), ModelError> {
        let i = parts.iter().position(|p| *p == part).unwrap_or(0);
        let (mut refit, fitted) = fit_effect(signals, &base, *kind, options, losses[i])?;
        finished(kind.name());
        // Under the same loss from the same starts, a candidate that
        // ends no lower than the baseline found nothing the baseline
        // lacks: it is the baseline, and can never beat it.
        let params = refit.effects.0.get(kind.name()).cloned().unwrap_or_default();
        // An effect fitted to its null value is the baseline itself: what
        // its fit gained, a refit of the part found, not the effect (a
        // zero delay from another start gained 4 % on a 50 Hz record).
        let at_null = at_null_value(*kind, &params);
        let found_nothing = at_null || fitted.cost >= base_costs[i];
        let after_prediction = if found_nothing {
            before_prediction.clone()
        } else {
            super::predict(&refit.plant, &refit.effects()?, signals, validation.clone())
        };
        let after = super::fit::nrmse_by_output(signals, &after_prediction, validation.clone());
        // A delay is also judged at the command's steps, where a lag cannot
        // take it up; the tests share its α.
        let effect_alpha = FAMILY_ALPHA / tried as f64;
        let steps = StepWindows::find(*kind, part, signals, validation.clone()).filter(|_| !found_nothing);
        let segment_alpha = match steps {
            Some(_) => effect_alpha * (1.0 - STEP_ALPHA_SHARE),
            None => effect_alpha,
        };
        let segment_test = paired_test_at(
            signals,
            part,
            &before_prediction,
            &after_prediction,
            validation.clone(),
            segment_alpha,
        );
        let at_steps = match &steps {
            Some(steps) if !segment_test.passed() && params.get("delay_s").is_some_and(|d| *d >= STEP_DELAY_MIN_S) => {
                let before = steps.predict(&base.plant, &base_effects, signals, validation.clone());
                let after = steps.predict(&refit.plant, &refit.effects()?, signals, validation.clone());
                let test = steps.test(signals, &base.plant, &before, &after, effect_alpha * STEP_ALPHA_SHARE);
                test.passed().then_some((steps, after, test))
            }
            _ => None,
        };
        let (test, alpha) = match &at_steps {
            Some((_, _, test)) => (*test, effect_alpha * STEP_ALPHA_SHARE),
            None => (segment_test, segment_alpha),
        };
        // The candidate's refit moves the part's other parameters too, from
        // starts of its own: what it gains may be a better fit of them, not
        // the effect (a gravity load of 0.007 N·m took 65 % of the angle's
        // error beside a Coulomb friction whose refit it improved). The
        // effect itself must remove the share that counts from its refit.
        let refit_alone = if found_nothing {
            None
        } else {
            refit_without_effect(
                signals,
                &refit,
                *kind,
                part,
                &after_prediction,
                validation.clone(),
                alpha,
                at_steps.as_ref().map(|(steps, after, _)| (*steps, after)),
            )?
        };
        if found_nothing {
            if let Some(last) = refit.history.last_mut() {
                last.validation_nrmse = before.clone();
            }
        }
        let output = part.output();
        let (nrmse_before, nrmse_after) = (before[output], after[output]);
        let score = if nrmse_before > 0.0 && nrmse_after.is_finite() {
            1.0 - nrmse_after / nrmse_before
        } else {
            f64::NEG_INFINITY
        };
        let resolution = resolution_share(*kind, &params, signals, validation.clone());
        let not_itself = not_itself(*kind, &params, signals, &refit);
        let on_lattice = (*kind == EffectKind::Quantization)
            .then(|| readings_on_lattice(&signals.theta, params.get("step").copied().unwrap_or(0.0)))
            .flatten();
        // The readings themselves can show a coarse encoder where a model
        // without pressures is too far off to gain from its staircase.
        let shown = (!found_nothing && test.passed() && nrmse_after < nrmse_before && refit_alone.is_none())
            || (on_lattice.is_some() && nrmse_after <= nrmse_before);
        // A fit that is not the effect it names, or finer than the data
        // resolves, is turned down whatever the test says.
        let plausible = resolution.is_none_or(|share| share >= RESOLUTION_SHARE) && not_itself.is_none();
        let significant = shown && plausible;
        let stands_in = not_itself.clone().filter(|_| shown);
        let evidence = evidence(
            *kind,
            part,
            &params,
            signals,
            &refit,
            Judgement {
                before: nrmse_before,
                after: nrmse_after,
                significant,
                test,
                found_nothing,
                at_null,
                resolution,
                not_itself,
                on_lattice,
                refit_alone,
            },
        );
        let prefix = format!("{}.", kind.name());
        let uncertainty = Uncertainty {
            std: fitted
                .uncertainty
                .std
                .iter()
                .filter_map(|(k, v)| k.strip_prefix(&prefix).map(|key| (key.to_owned(), *v)))
                .collect(),
            inseparable: fitted.uncertainty.inseparable,
            inseparable_pairs: fitted.uncertainty.inseparable_pairs,
        };
        Ok((
            Candidate {
                effect: kind.name().to_owned(),
                output: output.to_owned(),
                validation_nrmse_before: nrmse_before,
                validation_nrmse_after: nrmse_after,
                params,
                significant,
                evidence,
                score,
                test: test.kind.name(),
                statistic: test.statistic,
                threshold: test.threshold,
                segments: test.segments,
                effective_segments: test.effective,
                uncertainty,
                indistinguishable_from: Vec::new(),
                part,
                read_off_step: on_lattice.filter(|_| significant).map(|(_, step)| step),
                stands_in,
            },
            refit,
            plausible,
        ))
    };
    // The candidates are independent: one per core, the longest fits
    // first, each taken by the first core free, so that the last to end is
    // a short one (in the catalog's order, a flexible load's fit ended
    // alone for the last 1.5 s of 8).
    let mut order: Vec<usize> = (0..kinds.len()).collect();
    order.sort_by_key(|i| std::cmp::Reverse(expected_work(kinds[*i].0)));
    let mut judged: Vec<(usize, Result<_, _>)> = order
        .into_iter()
        .par_bridge()
        .map(|i| (i, judge(&kinds[i].0, kinds[i].1)))
        .collect();
    judged.sort_by_key(|(i, _)| *i);
    let mut candidates = Vec::new();
    let mut fitted = BTreeMap::new();
    let mut plausible_effects = BTreeSet::new();
    for (i, result) in judged {
        // A candidate that no start lets simulate is not judged, and says
        // so: one diverging fit on a real record must not cost the others.
        let (candidate, refit, plausible) = match result {
            Ok(judged) => judged,
            Err(ModelError::Fit(reason)) => {
                not_judged.push(NotJudged {
                    effect: kinds[i].0.name().to_owned(),
                    reason: format!("its fit failed: {reason}"),
                });
                continue;
            }
            Err(other) => return Err(other),
        };
        if plausible {
            plausible_effects.insert(candidate.effect.clone());
        }
        fitted.insert(candidate.effect.clone(), refit);
        candidates.push(candidate);
    }
    // What the readings show for certain (a coarse encoder's lattice)
    // comes before what a test makes likely: with the staircase in the
    // model, the dynamics' effects are judged against the right noise.
    let shown_by_readings = |c: &Candidate| c.read_off_step.is_some();
    candidates.sort_by(|a, b| {
        b.significant
            .cmp(&a.significant)
            .then(shown_by_readings(b).cmp(&shown_by_readings(a)))
            .then(b.score.total_cmp(&a.score))
    });
    let tied = indistinguishable(&candidates, &fitted, signals, validation.clone(), tried)?;
    if let Some(first) = candidates.first_mut() {
        first.indistinguishable_from = tied;
    }
    let verdict = match candidates.first() {
        Some(
            best @ Candidate {
                read_off_step: Some(step),
                ..
            },
        ) => format!(
            "add `{}`: every reading of the angle lies on multiples of {step:.5} rad, a coarse encoder (with it the {} validation NRMSE goes {})",
            best.effect,
            best.output,
            before_after(best.validation_nrmse_before, best.validation_nrmse_after),
        ),
        Some(best) if best.significant && !best.indistinguishable_from.is_empty() => tied_verdict(best, &candidates),
        Some(best) if best.significant => {
            format!(
            "add `{}`: it removes {:.0}% of the {} error ({}; {} = {:.1} over {} segments, threshold {:.1})",
            best.effect,
            100.0 * (1.0 - best.validation_nrmse_after / best.validation_nrmse_before),
            best.output,
            before_after(best.validation_nrmse_before, best.validation_nrmse_after),
            best.statistic_symbol(),
            best.statistic,
            best.segments,
            best.threshold
        )
        }
        _ => {
            let verdict = no_effect_verdict(&candidates, &plausible_effects, &before);
            let in_model: BTreeSet<String> = base.effects.0.keys().cloned().collect();
            match nearest(&candidates, &plausible_effects).and_then(|near| alike_in_the_model(near, &in_model)) {
                Some(alike) => format!("{verdict}; {alike}"),
                None => verdict,
            }
        }
    };
    Ok(Diagnosis {
        parts,
        not_judged,
        baseline: Baseline {
            validation_nrmse: overall,
            validation_nrmse_by_output: before,
            fit_percent,
            params: uncertainty
                .std
                .keys()
                .filter_map(|name| Some((name.clone(), super::fit::param_value(&base, name)?)))
                .collect(),
            uncertainty,
        },
        candidates,
        verdict,
        baseline_model: base,
        fitted,
    })
}

/// A candidate's fit's relative cost, for the order they are started in:
/// a mechanical effect's starts are screened by simulation, a hydraulic
/// effect's are judged as they are; measured on 60 s of foreign plants.
fn expected_work(kind: EffectKind) -> u8 {
    match kind {
        EffectKind::LoadFlexibility | EffectKind::Backlash | EffectKind::CoulombFriction => 3,
        EffectKind::GravityLoad | EffectKind::Deadzone | EffectKind::TimeDelay => 2,
        EffectKind::Quantization | EffectKind::OrificeFlow | EffectKind::AsymmetricGain => 1,
        EffectKind::Saturation => 0,
    }
}
