//! Two effects that are significant only together. Each alone leaves the
//! other's error in every segment, and a refit of the body absorbs part of
//! it: beside a gravity load, Coulomb friction took the angle's NRMSE
//! 0.0425 → 0.0394 (z = 2.3 against 3.4) and the load alone → 0.0356 (t =
//! 1.3 against 4.1), where both together took it to 0.0018. When nothing
//! is significant alone, the three nearest misses of each part are fitted
//! two by two, and the nearest also with every other miss that lowers its
//! output's error, and each pair judged as one, at the family's α shared by
//! every pair the diagnosis could have chosen.

use super::*;

/// Two effects added together: the model with both, and what each did.
#[derive(Debug, Clone)]
pub struct Together {
    /// The model with both, its history a step for each.
    pub model: Model,
    /// The output both were judged on.
    pub output: String,
    /// The one the pair was fitted from first (the model's history adds it
    /// first): its name and the output's validation NRMSE before it, with
    /// it alone, and with both.
    pub first: String,
    pub second: String,
    pub nrmse_before: f64,
    pub nrmse_first_alone: f64,
    pub nrmse_after: f64,
    /// The joint test's name, statistic and threshold.
    pub test: &'static str,
    pub statistic: f64,
    pub threshold: f64,
}

/// A miss that may be one of a pair: it stands in for nothing the catalog
/// lacks, and is not the encoder's staircase (which its readings show or
/// do not, whatever else is missing).
fn a_miss_to_pair(candidate: &Candidate) -> bool {
    !candidate.significant && candidate.stands_in.is_none() && candidate.effect != EffectKind::Quantization.name()
}

/// A near miss worth pairing with the other near misses: it lowers its
/// output's error.
fn pairable(candidate: &Candidate) -> bool {
    a_miss_to_pair(candidate)
        && candidate.statistic > 0.0
        && candidate.validation_nrmse_after < candidate.validation_nrmse_before
}

/// A miss whose segment test passed though its output's validation error
/// rose: it took something in most segments and lost more elsewhere.
fn segments_passed_error_rose(candidate: &Candidate) -> bool {
    a_miss_to_pair(candidate)
        && candidate.statistic >= candidate.threshold
        && candidate.validation_nrmse_after >= candidate.validation_nrmse_before
}

/// When `diagnosis` found nothing significant: of the pairs of each part's
/// nearest misses fitted together, the one that passes the segment tests
/// by the widest share, beats each alone, and in which each earns its
/// place beside the other. `None` otherwise.
pub fn together(signals: &Signals, diagnosis: &Diagnosis, options: FitOptions) -> Result<Option<Together>, ModelError> {
    if diagnosis.candidates.iter().any(|c| c.significant) {
        return Ok(None);
    }
    // Every pair the diagnosis could have chosen shares the α: choosing
    // the nearest on the same data costs nothing under Bonferroni.
    let pairs: usize = diagnosis
        .parts
        .iter()
        .map(|part| {
            let n = diagnosis
                .candidates
                .iter()
                .filter(|c| c.part == *part && c.effect != EffectKind::Quantization.name())
                .count();
            n * n.saturating_sub(1) / 2
        })
        .sum();
    let mut near: Vec<&Candidate> = diagnosis.candidates.iter().filter(|c| pairable(c)).collect();
    near.sort_by(|a, b| b.share_of_threshold().total_cmp(&a.share_of_threshold()));
    // The nearest misses of each part, paired every way: the two nearest
    // alone need not be the two present (beside a gravity load the play
    // came nearer than the load).
    let mut tried: Vec<(&Candidate, &Candidate)> = Vec::new();
    for part in &diagnosis.parts {
        let of_part: Vec<&Candidate> = near
            .iter()
            .filter(|c| c.part == *part)
            .take(PAIRED_NEAREST)
            .copied()
            .collect();
        for (i, first) in of_part.iter().enumerate() {
            tried.extend(of_part[i + 1..].iter().map(|second| (*first, *second)));
        }
        // The nearest with each further miss: beside a spool stop, Coulomb
        // friction came nearest from the angle alone and the stop fifth.
        if let Some(nearest) = of_part.first() {
            tried.extend(
                near.iter()
                    .filter(|c| c.part == *part)
                    .skip(PAIRED_NEAREST)
                    .map(|second| (*nearest, *second)),
            );
        }
    }
    // A miss whose segments passed while the whole record's error rose has
    // met an effect it cannot fit alone: beside a dead band whose segments
    // passed (t 4.1 against 3.7) a spool stop fitted to nothing, and the
    // band alone took the pressures' NRMSE 0.52 → 0.76. It is paired with
    // each other effect of its part, whatever that one did alone.
    for first in diagnosis.candidates.iter().filter(|c| segments_passed_error_rose(c)) {
        let others = diagnosis
            .candidates
            .iter()
            .filter(|c| c.part == first.part && c.effect != first.effect && a_miss_to_pair(c));
        for second in others {
            let known = tried.iter().any(|(a, b)| {
                (a.effect == first.effect && b.effect == second.effect)
                    || (a.effect == second.effect && b.effect == first.effect)
            });
            if !known {
                tried.push((first, second));
            }
        }
    }
    let alpha = FAMILY_ALPHA / pairs.max(1) as f64;
    let judged: Vec<Option<Together>> = tried
        .into_par_iter()
        .map(|(first, second)| judge_pair(signals, diagnosis, options, first, second, alpha))
        .collect::<Result<_, _>>()?;
    Ok(judged.into_iter().flatten().max_by(|a, b| {
        share_of_threshold(a.statistic, a.threshold).total_cmp(&share_of_threshold(b.statistic, b.threshold))
    }))
}

/// How many of each part's nearest misses are paired: three pairs a part.
const PAIRED_NEAREST: usize = 3;

/// `first` and `second` fitted together, from each one's fit alone, judged
/// against the diagnosis's baseline at `alpha`.
fn judge_pair(
    signals: &Signals,
    diagnosis: &Diagnosis,
    options: FitOptions,
    first: &Candidate,
    second: &Candidate,
    alpha: f64,
) -> Result<Option<Together>, ModelError> {
    let (Ok(first_kind), Ok(second_kind)) = (
        EffectKind::from_name(&first.effect),
        EffectKind::from_name(&second.effect),
    ) else {
        return Ok(None);
    };
    let part = first.part;
    let base = &diagnosis.baseline_model;
    let loss = part_loss(signals, base, part, options)?;
    // From each one's fit alone, the other added: the lower estimation
    // cost stays. Either alone may settle where the other's error is taken
    // up by the body or the valve, and the other's fit from there stays in
    // that valley: beside a spool stop, Coulomb friction alone fitted 15 N·m
    // of 60 (the viscous friction at 7 × the data sheet's), and the stop
    // added to it left the friction at 37 N·m and the angle's NRMSE at
    // 0.030; from the stop alone, the friction fitted 55 N·m and the NRMSE
    // 0.021.
    let mut fits = Vec::with_capacity(2);
    for (alone, added) in [(first, second_kind), (second, first_kind)] {
        let Some(with_alone) = diagnosis.fitted.get(&alone.effect) else {
            continue;
        };
        match fit_effect(signals, with_alone, added, options, loss) {
            Ok((model, fit)) => fits.push((model, fit.cost, alone)),
            Err(ModelError::Fit(_)) => {}
            Err(other) => return Err(other),
        }
    }
    let Some((both, _, from)) = fits.into_iter().min_by(|a, b| a.1.total_cmp(&b.1)) else {
        return Ok(None);
    };
    let then = if from.effect == first.effect { second } else { first };
    let validation = signals.split(options.estimation_fraction)..signals.len();
    let before = crate::greybox::predict(&base.plant, &base.effects()?, signals, validation.clone());
    let after = crate::greybox::predict(&both.plant, &both.effects()?, signals, validation.clone());
    let test = paired_test_at(signals, part, &before, &after, validation.clone(), alpha);
    let output = part.output();
    let nrmse_after = crate::greybox::fit::nrmse_by_output(signals, &after, validation.clone())[output];
    // Together they must beat each alone by the share that counts: a pair
    // in which one rides on the other's fall is that one, not a pair.
    let alone = first.validation_nrmse_after.min(second.validation_nrmse_after);
    if !test.passed() || nrmse_after > (1.0 - MIN_ERROR_REMOVED) * alone {
        return Ok(None);
    }
    // Each must earn its place beside the other, and be the effect it names.
    for kind in [first_kind, second_kind] {
        let params = both.effects.0.get(kind.name()).cloned().unwrap_or_default();
        if at_null_value(kind, &params) || not_itself(kind, &params, signals, &both).is_some() {
            return Ok(None);
        }
        let without = refit_without_effect(signals, &both, kind, part, &after, validation.clone(), alpha, None)?;
        if without.is_some() {
            return Ok(None);
        }
    }
    Ok(Some(Together {
        model: both,
        output: output.to_owned(),
        first: from.effect.clone(),
        second: then.effect.clone(),
        nrmse_before: from.validation_nrmse_before,
        nrmse_first_alone: from.validation_nrmse_after,
        nrmse_after,
        test: test.kind.name(),
        statistic: test.statistic,
        threshold: test.threshold,
    }))
}
