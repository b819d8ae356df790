//! What the diagnosis tests on foreign plants share.

use hydractl_ident::greybox::Diagnosis;
use hydractl_sim::foreign::Hidden;

/// Whether `diagnosis` ranks the hidden effect first and significant, with
/// its main parameter within `tolerance` (a share) of the truth; the first
/// three of the ranking when not.
pub fn named_first_within(diagnosis: &Diagnosis, hidden: Hidden, tolerance: f64) -> Result<(), String> {
    let first = &diagnosis.candidates[0];
    let (key, truth) = hidden.main();
    let fitted = first.params.get(key).copied().unwrap_or(f64::NAN);
    if first.effect == hidden.name() && first.significant && (fitted - truth).abs() <= tolerance * truth.abs() {
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
