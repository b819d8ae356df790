//! What the diagnosis tests share. Each test binary uses part of it.

#![allow(dead_code)]

use hydractl_ident::greybox::Diagnosis;
use hydractl_sim::foreign::Hidden;

/// Whether `diagnosis` ranks the hidden effect first and significant, with
/// its main parameter within `tolerance` (a share) of the truth; the first
/// three of the ranking when not.
pub fn named_first_within(diagnosis: &Diagnosis, hidden: Hidden, tolerance: f64) -> Result<(), String> {
    let first = &diagnosis.candidates[0];
    let fitted = hidden.main().and_then(|(key, _)| first.params.get(key).copied());
    if first.effect == hidden.name() && first.significant && hidden.within(fitted, tolerance) {
        return Ok(());
    }
    let ranking: Vec<String> = diagnosis
        .candidates
        .iter()
        .take(3)
        .map(|c| {
            format!(
                "{} ({} {:.1} / {:.1}, {:?})",
                c.effect, c.test, c.statistic, c.threshold, c.params
            )
        })
        .collect();
    Err(format!("{}: {}", hidden.name(), ranking.join("; ")))
}

/// The effects a diagnosis calls significant, each with its evidence.
pub fn significant(diagnosis: &Diagnosis) -> Vec<(&str, &str)> {
    diagnosis
        .candidates
        .iter()
        .filter(|c| c.significant)
        .map(|c| (c.effect.as_str(), c.evidence.as_str()))
        .collect()
}

/// An effect fitted at its null value is the baseline: it may not remove
/// any error, let alone be called significant.
pub fn no_null_effect_beats_the_baseline(diagnosis: &Diagnosis, plant: &str) {
    for c in &diagnosis.candidates {
        let main = |key: &str| c.params.get(key).copied().unwrap_or(f64::NAN);
        let null = match c.effect.as_str() {
            // A band of no width centred off zero is still a valve's null
            // offset, not the baseline.
            "deadzone" => main("width") < 1e-6 && main("offset").abs() < 1e-6,
            "backlash" => main("width") < 1e-6,
            "time_delay" => main("delay_s") < 1e-7,
            "asymmetric_gain" => (main("ratio") - 1.0).abs() < 1e-6,
            "saturation" => main("limit") >= 1.0 - 1e-9,
            _ => false,
        };
        if null {
            assert!(
                !c.significant && c.score <= 1e-6,
                "{plant}: `{}` at its null value ({:?}) beats the baseline: {} → {}",
                c.effect,
                c.params,
                c.validation_nrmse_before,
                c.validation_nrmse_after
            );
        }
    }
}
