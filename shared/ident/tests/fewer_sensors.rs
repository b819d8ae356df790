//! `diagnose` on machines with fewer sensors, from foreign plants
//! (`hydractl_sim::foreign`, simulated apart from the model): no pressure
//! transducers (valve command → angle, the `whole` part), data at 50 Hz,
//! and an axis whose torque is measured (the mechanical part alone). What
//! was fitted and what could not be judged is said in `parts` and
//! `not_judged`.

mod common;

use hydractl_ident::greybox::{diagnose, Diagnosis, FitOptions, Part, Signals};
use hydractl_ident::Dataset;
use hydractl_sim::foreign::{foreign_plant, Hidden, Sensors};

fn diagnosed(seed: u64, hidden: Option<Hidden>, sensors: Sensors, every: usize) -> Diagnosis {
    let data = foreign_plant(seed, hidden.as_slice(), 60.0);
    let description = data.description.clone();
    let dataset = Dataset::from_columns("foreign", data.record(sensors, every));
    let signals = Signals::from_dataset(&dataset).expect("valid signals");
    let diagnosis = diagnose(&signals, None, FitOptions::default()).expect("diagnoses");
    common::no_null_effect_beats_the_baseline(&diagnosis, &description);
    diagnosis
}

/// The hidden effect first and significant, its main parameter within
/// 25 %; the first three of the ranking when not.
fn named_first(diagnosis: &Diagnosis, hidden: Hidden) -> Result<(), String> {
    common::named_first_within(diagnosis, hidden, 0.25)
}

/// Without pressures, nothing significant on the plant of `seed` with no
/// effect hidden, every `every`-th reading kept.
fn names_nothing(seed: u64, every: usize) {
    let clean = diagnosed(seed, None, Sensors::Motion, every);
    let named = common::significant(&clean);
    assert!(named.is_empty(), "seed {seed}, nothing hidden: {named:?}");
}

/// Without pressures, a torque (friction, a load) is seen only through the
/// data sheet's displacement and oil stiffness, which the foreign plants
/// miss by up to 40 %: its size is known no better than they are.
fn torque_tolerance(hidden: Hidden) -> f64 {
    match hidden {
        Hidden::CoulombFriction { .. } | Hidden::GravityLoad { .. } => 0.5,
        _ => 0.25,
    }
}

#[test]
fn without_pressures_nothing_is_found_where_nothing_is_hidden_and_the_record_says_what_it_cannot_show() {
    let diagnosis = diagnosed(11, None, Sensors::Motion, 1);
    assert_eq!(diagnosis.parts, [Part::Whole]);
    let not_judged: Vec<&str> = diagnosis.not_judged.iter().map(|n| n.effect.as_str()).collect();
    assert_eq!(not_judged, ["orifice_flow", "load_flexibility"]);
    assert!(diagnosis.not_judged.iter().all(|n| !n.reason.is_empty()));
    assert!(
        common::significant(&diagnosis).is_empty(),
        "{:?}",
        common::significant(&diagnosis)
    );
    // The overall error is the angle's, the one output measured.
    assert!(diagnosis.baseline.validation_nrmse_by_output.keys().eq(["theta"]));
    // Each fitted parameter's value beside its deviation: what a fleet follows.
    assert!(diagnosis
        .baseline
        .params
        .keys()
        .eq(diagnosis.baseline.uncertainty.std.keys()));
    assert_eq!(
        diagnosis.baseline.params.get("inertia"),
        Some(&diagnosis.baseline_model.plant.inertia)
    );
}

/// A valve whose dead band is centred off zero: the null offset is fitted
/// with the width, from command and angle alone.
#[test]
fn without_pressures_an_off_centre_deadzone_is_named_with_its_offset() {
    let hidden = Hidden::Deadzone {
        width: 0.1,
        offset: 0.03,
    };
    let diagnosis = diagnosed(21, Some(hidden), Sensors::Motion, 1);
    named_first(&diagnosis, hidden).unwrap_or_else(|e| panic!("{e}"));
    let offset = diagnosis.candidates[0].params["offset"];
    assert!((offset - 0.03).abs() < 0.01, "offset {offset}");
}

/// The effects that motion alone shows clearly (backlash, a delay and an
/// encoder's step show weakly without the pressures: the bench's table
/// gives how often); at most one miss of four, torques within 50 %.
#[test]
fn without_pressures_the_motion_effects_are_named_first() {
    let missed: Vec<String> = Hidden::all()
        .into_iter()
        .filter(|h| {
            matches!(
                h,
                Hidden::Saturation { .. }
                    | Hidden::AsymmetricGain { .. }
                    | Hidden::CoulombFriction { .. }
                    | Hidden::GravityLoad { .. }
            )
        })
        .filter_map(|h| {
            common::named_first_within(&diagnosed(21, Some(h), Sensors::Motion, 1), h, torque_tolerance(h)).err()
        })
        .collect();
    assert!(missed.len() <= 1, "missed {} of 4: {missed:#?}", missed.len());
}

/// Without pressures the motion model is too far off (angle NRMSE
/// 0.06-0.25) to gain from modelling a 2° staircase, but the readings
/// show it themselves: every one on the encoder's lattice.
#[test]
fn without_pressures_a_coarse_encoder_is_named_from_its_readings() {
    let hidden = Hidden::all()
        .into_iter()
        .find(|h| matches!(h, Hidden::Quantization { .. }))
        .expect("a quantization case");
    let diagnosis = diagnosed(21, Some(hidden), Sensors::Motion, 1);
    named_first(&diagnosis, hidden).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        diagnosis.candidates[0]
            .evidence
            .starts_with("all 60000 readings of the angle lie on multiples of 0.03491 rad"),
        "{}",
        diagnosis.candidates[0].evidence
    );
}

/// 50 Hz data: segments are half a second whatever the rate.
#[test]
fn at_fifty_hertz_a_deadzone_is_named_and_nothing_else() {
    let hidden = Hidden::Deadzone {
        width: 0.1,
        offset: 0.0,
    };
    let diagnosis = diagnosed(22, Some(hidden), Sensors::Motion, 20);
    named_first(&diagnosis, hidden).unwrap_or_else(|e| panic!("{e}"));
    names_nothing(12, 20);
}

/// An axis driven by a measured torque: the mechanical part alone, every
/// valve effect not judged, with the reason.
#[test]
fn with_a_measured_torque_the_mechanical_part_alone_is_fitted() {
    let hidden = Hidden::CoulombFriction {
        sliding: 60.0,
        breakaway: 90.0,
    };
    let diagnosis = diagnosed(23, Some(hidden), Sensors::Torque, 1);
    assert_eq!(diagnosis.parts, [Part::Mechanical]);
    let not_judged: Vec<&str> = diagnosis.not_judged.iter().map(|n| n.effect.as_str()).collect();
    for valve_effect in [
        "deadzone",
        "saturation",
        "time_delay",
        "asymmetric_gain",
        "orifice_flow",
    ] {
        assert!(
            not_judged.contains(&valve_effect),
            "{valve_effect} judged: {not_judged:?}"
        );
    }
    assert!(diagnosis.not_judged.iter().all(|n| n.reason.contains("`u`")));
    named_first(&diagnosis, hidden).unwrap_or_else(|e| panic!("{e}"));
}

/// Without pressures, the delay's gain lives at the command's steps too:
/// between them the baseline's slower valve takes it up. Bench plants
/// 1003009 and 1003011, which the segment tests missed (t 2.4 and 2.8
/// against 3.8 and 3.6), named by the angle's error in the steps' windows;
/// the same plants without the delay name nothing.
#[test]
fn without_pressures_a_delay_is_named_at_the_command_steps_bench_plants_1003009_and_11() {
    let hidden = Hidden::TimeDelay { seconds: 0.02 };
    for seed in [1_003_009, 1_003_011] {
        let diagnosis = diagnosed(seed, Some(hidden), Sensors::Motion, 1);
        named_first(&diagnosis, hidden).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(diagnosis.candidates[0].test, "step_windows", "seed {seed}");
        names_nothing(seed, 1);
    }
}

/// A rule fixed before it was run, on plants nobody picked: the first four
/// seeds from 6 000 000, without pressures, a 20 ms delay named first on
/// at least two (the bench names it on 11 of 20), and nothing named on any
/// of them without it.
#[test]
fn without_pressures_a_delay_is_named_on_plants_nobody_picked() {
    let hidden = Hidden::TimeDelay { seconds: 0.02 };
    let seeds = 6_000_000..6_000_004;
    let named = seeds
        .clone()
        .filter(|&seed| named_first(&diagnosed(seed, Some(hidden), Sensors::Motion, 1), hidden).is_ok())
        .count();
    assert!(named >= 2, "named on {named} of 4");
    for seed in seeds {
        names_nothing(seed, 1);
    }
}
