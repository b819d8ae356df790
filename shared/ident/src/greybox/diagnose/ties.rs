//! Effects the record cannot tell apart: a significant candidate that the
//! first does not beat by more than the share of the error that counts,
//! segment by segment, explains the data as well. A dead band and stiction
//! seen from the angle alone, or a gravity load and a flexible coupling on
//! a slow reference, do the same to the output; the verdict names both
//! rather than pretend the data chose.

use super::*;

/// The significant candidates on the first's part that the record cannot
/// tell from it, by the same paired test that judged them against the
/// baseline (now with the first as the "after" and each other as the
/// "before"): their names, best first.
pub(super) fn indistinguishable(
    candidates: &[Candidate],
    fitted: &BTreeMap<String, Model>,
    signals: &Signals,
    validation: Range<usize>,
    tried: usize,
) -> Result<Vec<String>, ModelError> {
    let Some(first) = candidates.first() else {
        return Ok(Vec::new());
    };
    // What the readings themselves show needs no tie-break.
    if !first.significant || first.read_off_step.is_some() {
        return Ok(Vec::new());
    }
    let predicted = |effect: &str| -> Result<Option<Prediction>, ModelError> {
        let Some(model) = fitted.get(effect) else {
            return Ok(None);
        };
        Ok(Some(crate::greybox::predict(
            &model.plant,
            &model.effects()?,
            signals,
            validation.clone(),
        )))
    };
    let Some(first_prediction) = predicted(&first.effect)? else {
        return Ok(Vec::new());
    };
    let mut tied = Vec::new();
    for other in candidates[1..].iter().filter(|c| c.significant && c.part == first.part) {
        let Some(prediction) = predicted(&other.effect)? else {
            continue;
        };
        let first_better = paired_test(
            signals,
            first.part,
            &prediction,
            &first_prediction,
            validation.clone(),
            tried,
        );
        if !first_better.passed() {
            tied.push(other.effect.clone());
        }
    }
    Ok(tied)
}
