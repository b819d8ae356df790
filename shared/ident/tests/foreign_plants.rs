//! The model tools on plants that are not the model: data from
//! `hydractl_sim::foreign`, a rotator simulated apart from our plant code
//! (its own integrator, parameters ±40 % from the prior the diagnosis
//! starts from, transducer lag and noise of their own, supply ripple,
//! quadratic friction, its own P controller and reference), with one hidden
//! effect or none. A fixed subset of `hydractl bench foreign`, from seeds
//! chosen before the tests were run: nothing significant where nothing is
//! hidden, the hidden effect named first with its main parameter within
//! 25 % (all but one of the eight), and on every data set no effect at its null value beating the
//! baseline.

mod common;

use hydractl_ident::greybox::{diagnose, Diagnosis, FitOptions, Signals};
use hydractl_ident::Dataset;
use hydractl_sim::foreign::{foreign_plant, Hidden};

fn diagnosed(seed: u64, hidden: Option<Hidden>) -> Diagnosis {
    let data = foreign_plant(seed, hidden, 60.0);
    let dataset = Dataset::from_columns(
        "foreign",
        vec![
            ("t", data.t),
            ("u", data.u),
            ("p_a", data.p_a_bar),
            ("p_b", data.p_b_bar),
            ("theta", data.theta),
        ],
    );
    let signals = Signals::from_dataset(&dataset).expect("valid signals");
    let diagnosis = diagnose(&signals, None, FitOptions::default()).expect("diagnoses");
    common::no_null_effect_beats_the_baseline(&diagnosis, &data.description);
    diagnosis
}

fn nothing_significant(seed: u64) {
    let diagnosis = diagnosed(seed, None);
    let significant: Vec<(&str, &str)> = diagnosis
        .candidates
        .iter()
        .filter(|c| c.significant)
        .map(|c| (c.effect.as_str(), c.evidence.as_str()))
        .collect();
    assert!(significant.is_empty(), "seed {seed}: {significant:?}");
    assert!(diagnosis.verdict.starts_with("no effect"), "{}", diagnosis.verdict);
}

/// Whether the hidden effect comes first and significant, with its main
/// parameter within 25 % of the truth; the ranking when not.
fn named_first(seed: u64, hidden: Hidden) -> Result<(), String> {
    common::named_first_within(&diagnosed(seed, Some(hidden)), hidden, 0.25).map_err(|e| format!("seed {seed}: {e}"))
}

#[test]
fn no_effect_hidden_seed_11() {
    nothing_significant(11);
}

#[test]
fn no_effect_hidden_seed_12() {
    nothing_significant(12);
}

#[test]
fn no_effect_hidden_seed_13() {
    nothing_significant(13);
}

/// Chosen after the fact: the bench's clean plant on which a flexible load
/// removed 0.1 % of the angle's error, in 34 of 36 segments, and was
/// called significant (t = 6.2 against 3.3) until an effect had to remove
/// more than `MIN_ERROR_REMOVED` (2 %).
#[test]
fn a_consistent_sliver_of_the_error_is_not_an_effect_bench_plant_1000013() {
    nothing_significant(1_000_013);
}

/// The bench's goal is the hidden effect named first on at least 90 % of
/// 20 plants per effect; on this subset of one plant per effect (seed 21),
/// at most one miss.
#[test]
fn the_hidden_effect_is_named_first_on_seven_of_eight() {
    let missed: Vec<String> = Hidden::all()
        .into_iter()
        .filter_map(|h| named_first(21, h).err())
        .collect();
    assert!(missed.len() <= 1, "missed {} of 8: {missed:#?}", missed.len());
    if !missed.is_empty() {
        eprintln!("missed: {missed:?}");
    }
}
