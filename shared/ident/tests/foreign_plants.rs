//! The model tools on plants that are not the model: data from
//! `hydractl_sim::foreign`, a rotator simulated apart from our plant code
//! (its own integrator, parameters ±40 % from the prior the diagnosis
//! starts from, transducer lag and noise of their own, supply ripple,
//! quadratic friction, its own P controller and reference), with one hidden
//! effect or none. A fixed subset of `hydractl bench foreign`, from seeds
//! chosen before the tests were run: nothing significant where nothing is
//! hidden (alone or two together), the hidden effect named first with its
//! main parameter within 25 % (all but one of the nine), another valve law
//! named, added and then nothing missing, and on every data set no effect
//! at its null value beating the baseline.

mod common;

use hydractl_ident::greybox::{self, diagnose, Diagnosis, FitOptions, Model, Signals};
use hydractl_ident::Dataset;
use hydractl_plant::{EffectKind, PlantParams};
use hydractl_sim::foreign::{foreign_plant, ForeignData, Hidden, Sensors};

fn signals(data: &ForeignData) -> Signals {
    Signals::from_dataset(&Dataset::from_columns("foreign", data.record(Sensors::Full, 1))).expect("valid signals")
}

fn diagnosed(seed: u64, hidden: Option<Hidden>) -> Diagnosis {
    diagnosed_from(seed, hidden).1
}

/// The record's signals and their diagnosis.
fn diagnosed_from(seed: u64, hidden: Option<Hidden>) -> (Signals, Diagnosis) {
    let data = foreign_plant(seed, hidden.as_slice(), 60.0);
    let signals = signals(&data);
    let diagnosis = diagnose(&signals, None, FitOptions::default()).expect("diagnoses");
    common::no_null_effect_beats_the_baseline(&diagnosis, &data.description);
    (signals, diagnosis)
}

fn nothing_significant(seed: u64) {
    let (signals, diagnosis) = diagnosed_from(seed, None);
    let significant = common::significant(&diagnosis);
    assert!(significant.is_empty(), "seed {seed}: {significant:?}");
    assert!(diagnosis.verdict.starts_with("no effect"), "{}", diagnosis.verdict);
    // Nor two near misses together, the step `learn` takes next.
    let pair = greybox::together(&signals, &diagnosis, FitOptions::default()).expect("pairs judged");
    assert!(
        pair.is_none(),
        "seed {seed}: {:?}",
        pair.map(|p| (p.first, p.second, p.statistic, p.threshold))
    );
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
fn the_hidden_effect_is_named_first_on_eight_of_nine() {
    let missed: Vec<String> = Hidden::all()
        .into_iter()
        .filter_map(|h| named_first(21, h).err())
        .collect();
    assert!(missed.len() <= 1, "missed {} of 9: {missed:#?}", missed.len());
    if !missed.is_empty() {
        eprintln!("missed: {missed:?}");
    }
}

/// A valve law of the plant's own: the orifice equation with backflow and
/// its own smoothing near zero drop, metered against the rippled supply.
/// The model's `orifice_flow` is another law (no backflow, linear within 1 %
/// of the nominal drop, the data sheet's supply). Named first; added, it
/// takes most of the pressures' error; after it nothing of the catalog is
/// missing.
#[test]
fn another_valve_law_is_named_added_and_then_nothing_is_missing() {
    let hidden = Hidden::OrificeFlow;
    named_first(22, hidden).unwrap_or_else(|e| panic!("{e}"));
    let data = foreign_plant(22, &[hidden], 60.0);
    let signals = signals(&data);
    let options = FitOptions::default();
    let baseline = greybox::fit_baseline(&signals, &PlantParams::default(), options).expect("baseline fits");
    let with_orifice = greybox::fit(&signals, &baseline, EffectKind::OrificeFlow, options).expect("orifice fits");
    let validation = signals.split(options.estimation_fraction)..signals.len();
    let error = |model: &Model| {
        let effects = model.effects().expect("valid effects");
        greybox::validation_nrmse(&model.plant, &effects, &signals, validation.clone())["pressures"]
    };
    let (before, after) = (error(&baseline), error(&with_orifice));
    assert!(after < 0.5 * before, "pressures' NRMSE {before:.4} → {after:.4}");
    let again = diagnose(&signals, Some(&with_orifice), options).expect("diagnoses");
    common::no_null_effect_beats_the_baseline(&again, &data.description);
    let significant = common::significant(&again);
    assert!(
        significant.is_empty(),
        "{}: still significant: {significant:?}",
        data.description
    );
}

/// A machine's recording with readings left out (a sensor node lost for
/// 3 s, and again for 1.5 s): the rows are missing, the time stamps say
/// where, and the rest is diagnosed as a whole record is: the hidden dead
/// band named first, its width within 25 %.
#[test]
fn a_record_with_readings_left_out_is_diagnosed_from_what_is_left() {
    let hidden = Hidden::Deadzone {
        width: 0.1,
        offset: 0.0,
    };
    let data = foreign_plant(21, &[hidden], 60.0);
    let gaps = [15_000..18_000, 40_000..41_500];
    let kept = |k: &usize| !gaps.iter().any(|g| g.contains(k));
    let columns = data
        .record(Sensors::Full, 1)
        .into_iter()
        .map(|(name, column)| {
            let column = column.into_iter().enumerate().filter(|(k, _)| kept(k)).map(|(_, v)| v);
            (name, column.collect())
        })
        .collect();
    let signals = Signals::from_dataset(&Dataset::from_columns("foreign", columns)).expect("valid signals");
    assert_eq!(signals.breaks, vec![15_000, 37_000]);
    let diagnosis = diagnose(&signals, None, FitOptions::default()).expect("diagnoses");
    common::no_null_effect_beats_the_baseline(&diagnosis, &data.description);
    common::named_first_within(&diagnosis, hidden, 0.25).unwrap_or_else(|e| panic!("{}: {e}", data.description));
}

/// Bench plant 1003003, chosen because it was a miss: a slow valve (ω_v
/// 0.62 × the prior) whose P loop limit-cycles near 2 Hz, a chamber at tank
/// or supply a third of the time. Between the command's steps the
/// baseline's slower valve takes up the 20 ms delay; at the steps it
/// cannot.
#[test]
fn a_delay_beside_a_limit_cycling_slow_valve_is_named_at_the_steps_bench_plant_1003003() {
    named_first(1_003_003, Hidden::TimeDelay { seconds: 0.02 }).unwrap_or_else(|e| panic!("{e}"));
}

/// The same plant without the delay limit-cycles all the same; its
/// transducers' lag is no delay.
#[test]
fn the_same_slow_valve_without_a_delay_names_nothing_bench_plant_1003003() {
    nothing_significant(1_003_003);
}

/// Bench plant 1003007, the other slow valve the segment tests missed.
#[test]
fn a_delay_beside_a_limit_cycling_slow_valve_is_named_at_the_steps_bench_plant_1003007() {
    named_first(1_003_007, Hidden::TimeDelay { seconds: 0.02 }).unwrap_or_else(|e| panic!("{e}"));
}

#[test]
fn the_same_slow_valve_without_a_delay_names_nothing_bench_plant_1003007() {
    nothing_significant(1_003_007);
}

/// The valve's natural frequency a foreign plant drew, × the prior, read
/// from its description.
fn valve_frequency_ratio(seed: u64) -> f64 {
    let description = foreign_plant(seed, &[], 1.0).description;
    description
        .split(", ")
        .find_map(|field| field.strip_prefix("ω_v "))
        .and_then(|ratio| ratio.split_whitespace().next())
        .and_then(|ratio| ratio.parse().ok())
        .unwrap_or_else(|| panic!("seed {seed}: no ω_v in {description}"))
}

/// A rule fixed before it was run, on plants nobody picked: the first
/// three seeds from 5 000 000 whose valve is slow (ω_v ≤ 0.66 × the prior,
/// like the bench's misses), with a 20 ms delay named first on at least two
/// of them, and nothing named on the same plants without it. A slow valve
/// alone is not what hid the bench's delays (the segment tests pass here
/// too; it was the limit cycle beside it): this holds the steps' test to
/// no false alarm where the valve lags most.
#[test]
fn a_delay_beside_a_slow_valve_is_named_on_plants_nobody_picked() {
    let seeds: Vec<u64> = (5_000_000..)
        .filter(|&seed| valve_frequency_ratio(seed) <= 0.66)
        .take(3)
        .collect();
    let missed: Vec<String> = seeds
        .iter()
        .filter_map(|&seed| named_first(seed, Hidden::TimeDelay { seconds: 0.02 }).err())
        .collect();
    assert!(missed.len() <= 1, "{missed:?}");
    for seed in seeds {
        nothing_significant(seed);
    }
}

/// A stop the baseline absorbed into its valve and oil: bench plants
/// 1002015 and 1002016 with the spool stopped at a fifth of its travel,
/// well inside the command's range (35–40 % of the samples beyond it), and
/// the bench's plant 1002021 at half its travel. The baseline without the
/// stop lowers its flow gain until it fits the pressures at 16–31 %;
/// beside it no start of the stop screens better than none, so the stop is
/// fitted from the data sheet's valve and oil too.
#[test]
fn a_spool_stop_the_baseline_absorbed_is_named_bench_plants_1002015_16_and_21() {
    for (seed, limit) in [(1_002_015, 0.2), (1_002_016, 0.2), (1_002_021, 0.5)] {
        named_first(seed, Hidden::Saturation { limit }).unwrap_or_else(|e| panic!("{e}"));
    }
}
