//! The model tools on a real machine's measurements, which nothing of ours
//! shaped: the EMPS, a linear axis of a machine tool driven by a DC motor
//! through a ball screw, from the nonlinear system identification
//! benchmarks (Janot, Gautier and Brunot, 2019; see `data/emps/README.md`).
//! Its force is measured (the drive's gain times its voltage) and only its
//! position is sensed: the mechanical part alone. Its authors identified it
//! by inverse dynamics (IDIM-LS): mass 95.1 kg, viscous friction
//! 203.5 N·s/m, Coulomb friction 20.4 N and a constant force of −3.2 N. The
//! model tools fit output error over segments instead, from a prior made
//! for a hydraulic rotator: four orders of magnitude off in friction and
//! one in inertia.

mod common;

use std::path::PathBuf;

use hydractl_ident::greybox::{compare, diagnose, Diagnosis, FitOptions, Signals, REQUIRED_COLUMNS};
use hydractl_ident::Dataset;

/// The published IDIM-LS estimates (`Simulation_EMPS.m` of the benchmark).
const MASS: f64 = 95.1089;
const VISCOUS: f64 = 203.5034;
const COULOMB: f64 = 20.3935;
const OFFSET: f64 = -3.1648;

/// A record diagnosed from the default prior; no effect at its null value
/// may beat the baseline there.
fn diagnosed(signals: &Signals, name: &str) -> Diagnosis {
    let diagnosis = diagnose(signals, None, FitOptions::default()).expect("diagnoses");
    common::no_null_effect_beats_the_baseline(&diagnosis, name);
    diagnosis
}

fn record(name: &str) -> Signals {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/emps")
        .join(name);
    let data = Dataset::from_csv(&path, &REQUIRED_COLUMNS).expect("the EMPS record reads");
    Signals::from_dataset(&data).expect("valid signals")
}

fn within(value: f64, truth: f64, share: f64) -> bool {
    (value - truth).abs() <= share * truth.abs()
}

/// Coulomb friction is what the axis has and a rigid body lacks; a model
/// without the axis's constant force took that out on the friction, and no
/// effect was significant (t 0.5 against 3.4).
#[test]
fn a_measured_axis_is_found_to_lack_coulomb_friction_at_its_published_level() {
    let diagnosis = diagnosed(&record("estimation.csv"), "EMPS");
    let first = &diagnosis.candidates[0];
    assert!(
        first.effect == "coulomb_friction" && first.significant,
        "{}: {:?}",
        diagnosis.verdict,
        diagnosis
            .candidates
            .iter()
            .map(|c| (&c.effect, c.significant, c.statistic, c.threshold))
            .collect::<Vec<_>>()
    );
    let others: Vec<&str> = diagnosis.candidates[1..]
        .iter()
        .filter(|c| c.significant)
        .map(|c| c.effect.as_str())
        .collect();
    assert!(others.is_empty(), "significant besides: {others:?}");
    let coulomb = first.params["coulomb"];
    assert!(within(coulomb, COULOMB, 0.1), "Coulomb {coulomb} N against {COULOMB}");
    let plant = diagnosis.fitted["coulomb_friction"].plant;
    assert!(
        within(plant.inertia, MASS, 0.1),
        "mass {} kg against {MASS}",
        plant.inertia
    );
    assert!(
        within(plant.viscous_friction, VISCOUS, 0.1),
        "viscous {} N·s/m against {VISCOUS}",
        plant.viscous_friction
    );
    assert!(
        within(plant.load_torque, OFFSET, 0.25),
        "constant force {} N against {OFFSET}",
        plant.load_torque
    );
}

/// The friction fitted on one experiment predicts another (the benchmark's
/// validation run, with force pulses the controller rejects) better than
/// the rigid body does, over the whole of it.
#[test]
fn the_friction_fitted_on_one_experiment_predicts_another() {
    let diagnosis = diagnosed(&record("estimation.csv"), "EMPS");
    let other = record("validation.csv");
    let error = |model: &hydractl_ident::greybox::Model| {
        let effects = model.effects().expect("valid effects");
        compare(&model.plant, &effects, &other, 0.0).outputs[0].nrmse
    };
    let (before, after) = (
        error(&diagnosis.baseline_model),
        error(&diagnosis.fitted["coulomb_friction"]),
    );
    assert!(after < 0.5 * before, "theta NRMSE {before:.4} → {after:.4}");
}

/// The same record at 50 Hz, every twentieth sample, as a slower logger
/// would keep it: the segments are in seconds, and the friction is found
/// as well.
#[test]
fn at_fifty_hertz_the_measured_axis_still_lacks_its_coulomb_friction() {
    let full = record("estimation.csv");
    let every = |x: &[f64]| x.iter().step_by(20).copied().collect::<Vec<f64>>();
    let tau = full.tau.as_deref().expect("the record measures the force");
    let data = Dataset::from_columns(
        "EMPS at 50 Hz",
        vec![
            ("t", every(&full.t)),
            ("tau", every(tau)),
            ("theta", every(&full.theta)),
        ],
    );
    let signals = Signals::from_dataset(&data).expect("valid signals");
    let diagnosis = diagnosed(&signals, "EMPS at 50 Hz");
    let first = &diagnosis.candidates[0];
    assert!(
        first.effect == "coulomb_friction" && first.significant,
        "{}",
        diagnosis.verdict
    );
    let coulomb = first.params["coulomb"];
    assert!(within(coulomb, COULOMB, 0.1), "Coulomb {coulomb} N against {COULOMB}");
}
