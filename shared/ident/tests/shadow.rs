//! The shadow's drift test on closed-loop data: the model of the simulated
//! plant, judged against its own validation spread, raises nothing on a
//! run it was not calibrated on, alarms on a valve whose dead-zone opened,
//! an adopted model is judged only after calibrating on live data, and a
//! drift of an effect the model already has is named by its refit. The
//! same on a plant the project did not shape (`hydractl_sim::foreign`),
//! with the model fitted from its own data.

use std::collections::BTreeMap;

use hydractl_config::Config;
use hydractl_ident::greybox::{
    diagnose, fit_baseline, moved_effect, validation_spread, DriftTest, FitOptions, HistoryStep, Model, Shadow,
    Signals, CALIBRATION_SEGMENTS,
};
use hydractl_ident::Dataset;
use hydractl_plant::effects::Effects;
use hydractl_plant::Effect;
use hydractl_plant::PlantParams;
use hydractl_sim::foreign::{foreign_plant, Hidden, Sensors};
use hydractl_sim::simulate;

const WINDOW_S: f64 = 5.0;
const EVERY_S: f64 = 1.0;

/// `duration` s of `hydractl sim`, with `effect` hidden, from `seed`.
fn closed_loop(effect: Option<&str>, seed: u64, duration: f64) -> Vec<[f64; 5]> {
    let mut config = Config::default_sim().expect("built-in config");
    config.simulation.seed = seed;
    let effects: Vec<Effect> = effect.map(|e| Effect::parse(e).expect("effect")).into_iter().collect();
    let run = simulate(&config, &effects, duration).expect("simulates");
    run.records.iter().map(|r| [r.t, r.u, r.p_a, r.p_b, r.theta]).collect()
}

fn signals(rows: &[[f64; 5]]) -> Signals {
    let column = |i: usize| rows.iter().map(|r| r[i]).collect::<Vec<f64>>();
    let data = Dataset::from_columns(
        "simulated",
        vec![
            ("t", column(0)),
            ("u", column(1)),
            ("p_a", column(2)),
            ("p_b", column(3)),
            ("theta", column(4)),
        ],
    );
    Signals::from_dataset(&data).expect("signals")
}

/// The simulated plant's own model, with the spread its segments showed on
/// a run of another seed as its validation.
fn true_model() -> Model {
    let config = Config::default_sim().expect("built-in config");
    let validation = signals(&closed_loop(None, 101, 20.0));
    let spread = validation_spread(&config.plant, &Effects::none(), &validation, 0..validation.len());
    let mut model = Model::new(config.plant, Effects::none());
    let mut baseline = HistoryStep::of("baseline", &config.plant, &model.effects, BTreeMap::new());
    baseline.validation_spread = spread;
    model.history.push(baseline);
    model
}

/// Each window's assessment as the shadow makes them, live: the window
/// ending at each `EVERY_S`; the times at which one alarmed.
fn watch(shadow: &mut Shadow, rows: &[[f64; 5]], mut each: impl FnMut(&Shadow, f64)) -> Vec<f64> {
    let period = rows[1][0] - rows[0][0];
    let (window, every) = (
        (WINDOW_S / period).round() as usize,
        (EVERY_S / period).round() as usize,
    );
    let new_segments = (EVERY_S / hydractl_ident::greybox::SEGMENT_S).round() as usize;
    let mut alarms = Vec::new();
    let mut end = window;
    while end <= rows.len() {
        let assessment = shadow.assess(&signals(&rows[end - window..end]), new_segments);
        let t = rows[end - 1][0];
        if !assessment.alarms.is_empty() {
            alarms.push(t);
            shadow.restart();
        }
        each(shadow, t);
        end += every;
    }
    alarms
}

#[test]
fn the_true_model_raises_nothing_on_a_run_of_its_own_and_alarms_on_a_wider_deadzone() {
    let mut shadow = Shadow::new(true_model(), DriftTest::default()).expect("shadow");
    let unchanged = watch(&mut shadow, &closed_loop(None, 7, 60.0), |_, _| {});
    assert!(unchanged.is_empty(), "alarms on the unchanged plant at {unchanged:?} s");
    let mut shadow = Shadow::new(true_model(), DriftTest::default()).expect("shadow");
    let worn = watch(
        &mut shadow,
        &closed_loop(Some("deadzone:width=0.06"), 7, 30.0),
        |_, _| {},
    );
    let first = worn.first().copied().expect("the dead-zone alarms");
    assert!(first <= 15.0, "first alarm at {first} s");
}

#[test]
fn an_adopted_model_is_judged_only_after_calibrating_on_live_data() {
    let mut shadow = Shadow::new(true_model(), DriftTest::default()).expect("shadow");
    shadow.adopt(true_model()).expect("adopts");
    let mut calibrated_at = None;
    let alarms = watch(&mut shadow, &closed_loop(None, 9, 50.0), |shadow, t| {
        if calibrated_at.is_none() && !shadow.calibrating() {
            calibrated_at = Some(t);
        }
    });
    // Each window brings two segments the test has not seen.
    let expected = WINDOW_S + (CALIBRATION_SEGMENTS / 2 - 1) as f64 * EVERY_S;
    let at = calibrated_at.expect("calibrated");
    assert!((at - expected).abs() <= 1.01, "calibrated at {at} s, not {expected} s");
    assert!(alarms.is_empty(), "alarms at {alarms:?} s");
}

/// The model's own Coulomb friction on data whose friction doubled: no
/// effect the model lacks explains it, the refit of its own does.
#[test]
fn friction_that_rose_is_named_as_the_models_own_effect_moved() {
    let config = Config::default_sim().expect("built-in config");
    let rows = closed_loop(Some("coulomb_friction:coulomb=60,breakaway=60"), 13, 20.0);
    let signals = signals(&rows);
    let with_friction = |level: f64| {
        let effect = Effect::parse(&format!("coulomb_friction:coulomb={level},breakaway={level}")).expect("effect");
        let mut effects = Effects::none();
        effects.insert(effect);
        Model::new(config.plant, effects)
    };
    let cold = with_friction(30.0);
    let diagnosis = diagnose(&signals, Some(&cold), FitOptions::default()).expect("diagnoses");
    let (effect, params) = moved_effect(&cold, &diagnosis).expect("the friction moved");
    assert_eq!(effect, "coulomb_friction");
    let coulomb = params["coulomb"];
    assert!((coulomb - 60.0).abs() <= 0.25 * 60.0, "coulomb refitted to {coulomb}");
    let true_model = with_friction(60.0);
    let diagnosis = diagnose(&signals, Some(&true_model), FitOptions::default()).expect("diagnoses");
    assert_eq!(moved_effect(&true_model, &diagnosis), None, "nothing moved");
}

/// `duration` s of the foreign plant of `seed`, with `hidden`, as rows.
fn foreign(seed: u64, hidden: &[Hidden], duration: f64) -> Vec<[f64; 5]> {
    let record = foreign_plant(seed, hidden, duration).record(Sensors::Full, 1);
    let column = |name: &str| &record.iter().find(|(n, _)| *n == name).expect("recorded").1;
    let (t, u, p_a, p_b, theta) = (column("t"), column("u"), column("p_a"), column("p_b"), column("theta"));
    (0..t.len()).map(|k| [t[k], u[k], p_a[k], p_b[k], theta[k]]).collect()
}

/// The baseline fitted from a foreign plant's first minute, from the data
/// sheet's prior as `hydractl model fit` does, raises nothing on its next
/// minute (a reference it was not fitted on) and alarms once the plant's
/// valve has a dead band. The plant's own laws (quadratic friction, the
/// transducers' lag, supply ripple) are not the model's: its validation
/// spread is what holds them.
#[test]
fn on_foreign_plants_the_fitted_model_raises_nothing_on_the_next_minute_and_alarms_on_a_dead_band() {
    for seed in [1, 5, 31] {
        let rows = foreign(seed, &[], 120.0);
        let (fitted_on, watched) = rows.split_at(rows.len() / 2);
        let model = fit_baseline(&signals(fitted_on), &PlantParams::default(), FitOptions::default()).expect("fits");
        let mut shadow = Shadow::new(model.clone(), DriftTest::default()).expect("shadow");
        let unchanged = watch(&mut shadow, watched, |_, _| {});
        assert!(
            unchanged.is_empty(),
            "seed {seed}: alarms on the unchanged plant at {unchanged:?} s"
        );
        let mut shadow = Shadow::new(model, DriftTest::default()).expect("shadow");
        let dead_band = Hidden::Deadzone {
            width: 0.1,
            offset: 0.0,
        };
        let alarms = watch(&mut shadow, &foreign(seed, &[dead_band], 30.0), |_, _| {});
        let first = alarms.first().copied();
        assert!(
            first.is_some_and(|t| t <= 10.0),
            "seed {seed}: first alarm at {first:?} s"
        );
    }
}
