//! The user's loop in one call: diagnose, add the effect the diagnosis
//! names, diagnose the new model, and so on until nothing of the catalog
//! helps significantly.
//!
//! Each step adds exactly what one `diagnose` would recommend and takes the
//! candidate's own fit (the model the test judged), so `learn` is the
//! chain of `diagnose` and `add` a person would type, with nothing decided
//! that they could not see.

use std::collections::BTreeMap;

use serde::Serialize;

use super::diagnose::{diagnose_with, together, Diagnosis, Together};
use super::{FitOptions, HistoryStep, Model, ModelError, Progress, Signals};

/// One effect added: what it did and the test that decided.
#[derive(Debug, Clone, Serialize)]
pub struct LearnStep {
    pub effect: String,
    /// The output it was judged on (`p_a`, `p_b`, `pressures` or `theta`).
    pub output: String,
    /// That output's validation NRMSE before and after the effect.
    pub nrmse_before: f64,
    pub nrmse_after: f64,
    /// Its fitted parameters, in the catalog's keys.
    pub params: BTreeMap<String, f64>,
    /// The segment test that decided, its statistic and threshold.
    pub test: &'static str,
    pub statistic: f64,
    pub threshold: f64,
    /// Effects that remove the error alike, which the record cannot tell
    /// from this one (it was taken as the one with the fewest parameters).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub indistinguishable_from: Vec<String>,
    /// The effect added in the same step, where neither was significant
    /// alone: the test is the pair's, against the model without either.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub together_with: Option<String>,
}

/// Why the loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stop {
    /// The last diagnosis found nothing significant.
    NothingSignificant,
    /// `max_steps` effects were added; a further diagnosis was not run.
    MaxSteps,
}

/// The model learned, every step, and the last diagnosis.
#[derive(Debug, Clone)]
pub struct Learned {
    pub model: Model,
    pub steps: Vec<LearnStep>,
    pub stop: Stop,
    /// The last diagnosis's verdict (with [`Stop::MaxSteps`], the one that
    /// named the last step's effect).
    pub last_verdict: String,
    /// The last diagnosis run: what nothing helped against, or the step
    /// before [`Stop::MaxSteps`].
    pub last_diagnosis: Diagnosis,
}

impl Learned {
    /// One sentence: why the loop stopped.
    pub fn stopped_because(&self, max_steps: usize) -> String {
        match self.stop {
            Stop::NothingSignificant => self.last_verdict.clone(),
            Stop::MaxSteps => format!(
                "stopped after {max_steps} step(s) (--max-steps): `hydractl model diagnose` on the model tells whether more helps"
            ),
        }
    }
}

/// What the loop tells as it goes: each diagnosis's fits (through
/// [`Progress`]) and each step once taken.
pub trait LearnProgress: Progress {
    /// Step `index` (from 0) is being diagnosed.
    fn diagnosing(&self, index: usize);
    /// Step `index` added `step`.
    fn added(&self, index: usize, step: &LearnStep);
}

/// Learns from `signals`, starting at `start` (else a baseline fitted from
/// the default prior), adding at most `max_steps` effects.
pub fn learn(
    signals: &Signals,
    start: Option<&Model>,
    options: FitOptions,
    max_steps: usize,
    progress: &dyn LearnProgress,
) -> Result<Learned, ModelError> {
    let mut model = start.cloned();
    let mut steps = Vec::new();
    loop {
        progress.diagnosing(steps.len());
        let diagnosis = diagnose_with(signals, model.as_ref(), options, progress)?;
        let first = diagnosis.candidates.first().filter(|c| c.significant);
        let Some(first) = first else {
            if steps.len() + 2 <= max_steps {
                if let Some(pair) = together(signals, &diagnosis, options)? {
                    let added = pair_steps(&pair);
                    let mut next = pair.model;
                    // The history's last two entries are the pair's, in order.
                    let n = next.history.len();
                    for (entry, step) in next.history[n.saturating_sub(2)..].iter_mut().zip(&added) {
                        step.record_in(entry);
                    }
                    for step in added {
                        progress.added(steps.len(), &step);
                        steps.push(step);
                    }
                    model = Some(next);
                    continue;
                }
            }
            return Ok(Learned {
                model: diagnosis.baseline_model.clone(),
                steps,
                stop: Stop::NothingSignificant,
                last_verdict: diagnosis.verdict.clone(),
                last_diagnosis: diagnosis,
            });
        };
        // Of effects the record cannot tell apart, the one with the fewest
        // parameters: the simpler explanation of the same fall, and the
        // others stay named in the step.
        let tied = std::iter::once(first).chain(
            first
                .indistinguishable_from
                .iter()
                .filter_map(|name| diagnosis.candidates.iter().find(|c| &c.effect == name)),
        );
        let best = tied.clone().min_by_key(|c| c.params.len()).unwrap_or(first);
        let alternatives: Vec<String> = tied
            .filter(|c| c.effect != best.effect)
            .map(|c| c.effect.clone())
            .collect();
        let mut next = diagnosis
            .fitted
            .get(&best.effect)
            .cloned()
            .ok_or_else(|| ModelError::Fit(format!("the diagnosis kept no fit of `{}`", best.effect)))?;
        let step = LearnStep {
            effect: best.effect.clone(),
            output: best.output.clone(),
            nrmse_before: best.validation_nrmse_before,
            nrmse_after: best.validation_nrmse_after,
            params: best.params.clone(),
            test: best.test,
            statistic: best.statistic,
            threshold: best.threshold,
            indistinguishable_from: alternatives,
            together_with: None,
        };
        if let Some(last) = next.history.last_mut() {
            step.record_in(last);
        }
        progress.added(steps.len(), &step);
        steps.push(step);
        if steps.len() >= max_steps {
            return Ok(Learned {
                model: next,
                steps,
                stop: Stop::MaxSteps,
                last_verdict: diagnosis.verdict.clone(),
                last_diagnosis: diagnosis,
            });
        }
        model = Some(next);
    }
}

impl LearnStep {
    /// The test that decided this step, and the effect added with it, in
    /// its entry of the model file's history.
    fn record_in(&self, entry: &mut HistoryStep) {
        entry.test = Some(self.test.to_owned());
        entry.statistic = Some(self.statistic);
        entry.threshold = Some(self.threshold);
        entry.together_with = self.together_with.clone();
    }
}

/// The two steps of a pair added together: each with its own parameters
/// and the output's NRMSE it moved, the pair's test on both.
fn pair_steps(pair: &Together) -> [LearnStep; 2] {
    let params = |name: &str| pair.model.effects.0.get(name).cloned().unwrap_or_default();
    let step = |effect: &str, other: &str, before: f64, after: f64| LearnStep {
        effect: effect.to_owned(),
        output: pair.output.clone(),
        nrmse_before: before,
        nrmse_after: after,
        params: params(effect),
        test: pair.test,
        statistic: pair.statistic,
        threshold: pair.threshold,
        indistinguishable_from: Vec::new(),
        together_with: Some(other.to_owned()),
    };
    [
        step(&pair.first, &pair.second, pair.nrmse_before, pair.nrmse_first_alone),
        step(&pair.second, &pair.first, pair.nrmse_first_alone, pair.nrmse_after),
    ]
}

impl LearnProgress for super::Silent {
    fn diagnosing(&self, _index: usize) {}
    fn added(&self, _index: usize, _step: &LearnStep) {}
}
