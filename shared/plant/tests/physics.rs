//! The plant against analytic truth.

use hydractl_plant::{
    baseline_linear_model, Effect, Effects, Plant, PlantParams, SensorModel, SensorParams, TORQUE_OUTPUT,
};
use proptest::prelude::*;

const STEP: f64 = 1e-4;
const PER_MS: usize = 10;

fn plant_with(effects: &[&str]) -> Plant {
    let mut set = Effects::none();
    for spec in effects {
        set.insert(Effect::parse(spec).expect("valid effect"));
    }
    Plant::new(PlantParams::default(), set, STEP).expect("valid plant")
}

fn run(plant: &mut Plant, command: f64, seconds: f64) {
    plant.advance(command, (seconds / STEP).round() as usize);
}

#[test]
fn neutral_pressures_match_hand_derivation() {
    let p = PlantParams::default();
    let mut plant = plant_with(&[]);
    run(&mut plant, 0.0, 2.0);
    // ṗ = 0 with x_s = 0, θ̇ = 0 in eqs. (8)–(9): p = K_c p_s / (C_em + 2 K_c).
    let expected = p.flow_pressure_coefficient * p.supply_pressure / (p.leakage + 2.0 * p.flow_pressure_coefficient);
    let s = plant.state();
    assert!((s.p_a - expected).abs() < 1.0, "{} vs {expected}", s.p_a);
    assert!((s.p_b - expected).abs() < 1.0);
    assert_eq!(s.velocity, 0.0);
}

#[test]
fn steady_velocity_and_pressures_match_hand_derivation() {
    let p = PlantParams::default();
    let x = 0.3;
    let mut plant = plant_with(&[]);
    // The slowest pole is near 1.7 rad/s: settle for 20 s.
    run(&mut plant, x, 20.0);
    // Steady state of eqs. (5), (7)–(10) at spool x: b ω = D Δp and
    // (C_em + 2K_c) Δp = 4 K_q x − 2 D ω, so ω = 4 D K_q x / (b (C_em + 2K_c) + 2 D²).
    let c = p.leakage + 2.0 * p.flow_pressure_coefficient;
    let omega = 4.0 * p.displacement * p.flow_gain * x / (p.viscous_friction * c + 2.0 * p.displacement.powi(2));
    let p_a = (2.0 * p.flow_gain * x + p.flow_pressure_coefficient * p.supply_pressure - p.displacement * omega) / c;
    let p_b = (-2.0 * p.flow_gain * x + p.flow_pressure_coefficient * p.supply_pressure + p.displacement * omega) / c;
    let s = plant.state();
    assert!(
        (s.velocity - omega).abs() < 1e-6 * omega.abs().max(1.0),
        "{} vs {omega}",
        s.velocity
    );
    assert!((s.p_a - p_a).abs() < 10.0, "{} vs {p_a}", s.p_a);
    assert!((s.p_b - p_b).abs() < 10.0, "{} vs {p_b}", s.p_b);
    assert!((plant.torque() - p.viscous_friction * omega).abs() < 1e-3);
}

#[test]
fn linear_model_matches_finite_differences_of_the_nonlinear_plant() {
    let plant = plant_with(&[]);
    let mut state = plant.state();
    state.spool = 0.2;
    state.velocity = 0.5;
    state.p_a = 100e5;
    state.p_b = 60e5;
    let numeric = plant.linearize(&state, 0.2).expect("linearize");
    let analytic = baseline_linear_model(plant.params()).expect("model");
    for i in 0..6 {
        for j in 0..6 {
            let (a, n) = (analytic.a[(i, j)], numeric.a[(i, j)]);
            assert!((a - n).abs() <= 1e-6 * a.abs().max(1.0), "A[{i},{j}] {a} vs {n}");
        }
        let (a, n) = (analytic.b[(i, 0)], numeric.b[(i, 0)]);
        assert!((a - n).abs() <= 1e-6 * a.abs().max(1.0), "B[{i}] {a} vs {n}");
    }
}

#[test]
fn command_to_torque_has_a_lightly_damped_pair_between_25_and_40_rad_s() {
    let model = baseline_linear_model(&PlantParams::default()).expect("model");
    let tf = model.transfer_function(0, TORQUE_OUTPUT).expect("tf");
    let pairs = tf.resonances();
    assert!(
        pairs
            .iter()
            .any(|&(wn, zeta)| (25.0..=40.0).contains(&wn) && zeta < 0.35),
        "resonances {pairs:?}"
    );
}

#[test]
fn linear_step_response_matches_its_transfer_function() {
    let model = baseline_linear_model(&PlantParams::default()).expect("model");
    let tf = model.transfer_function(0, TORQUE_OUTPUT).expect("tf");
    let ts = 1e-3;
    let simulated = model.step_response(0, TORQUE_OUTPUT, ts, 2000).expect("step");
    let times: Vec<f64> = (0..2000).map(|k| k as f64 * ts).collect();
    let analytic = tf.step_response_analytic(&times);
    let scale = analytic.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    for (k, (s, a)) in simulated.iter().zip(&analytic).enumerate() {
        assert!((s - a).abs() < 1e-6 * scale, "t={} {s} vs {a}", k as f64 * ts);
    }
}

#[test]
fn nonlinear_plant_follows_its_linearization_for_small_steps() {
    let mut plant = plant_with(&[]);
    let model = baseline_linear_model(plant.params()).expect("model");
    let tf = model.transfer_function(0, TORQUE_OUTPUT).expect("tf");
    let step = 0.05;
    let times: Vec<f64> = (1..=500).map(|k| k as f64 * 1e-3).collect();
    let expected = tf.step_response_analytic(&times);
    let scale = expected.iter().fold(0.0_f64, |m, v| m.max(v.abs())) * step;
    for (k, e) in expected.iter().enumerate() {
        plant.advance(step, PER_MS);
        let torque = plant.torque();
        assert!(
            (torque - step * e).abs() < 1e-3 * scale,
            "k={k} {torque} vs {}",
            step * e
        );
    }
}

#[test]
fn coulomb_friction_sticks_below_breakaway_without_flicker() {
    // Neutral command: no motion at all, velocity exactly zero.
    let mut plant = plant_with(&["coulomb_friction"]);
    for _ in 0..1000 {
        plant.advance(0.0, PER_MS);
        assert_eq!(plant.state().velocity, 0.0);
    }
    // A command that builds more than breakaway torque moves it, and once the
    // command is neutral again the actuator stops and stays stopped.
    plant.advance(0.3, 5000);
    assert!(plant.state().velocity > 0.1);
    plant.advance(0.0, 20_000);
    let rest = plant.state();
    assert!(rest.stuck, "came to rest");
    for _ in 0..2000 {
        plant.advance(0.0, PER_MS);
        let s = plant.state();
        assert_eq!(s.velocity, 0.0, "no flicker at rest");
        assert_eq!(s.angle, rest.angle);
    }
}

#[test]
fn coulomb_friction_gives_stick_slip_under_a_slow_ramp() {
    // A slowly rising command: pressure builds while stuck, then it breaks away.
    let mut plant = plant_with(&["coulomb_friction:coulomb=60,breakaway=120,stribeck_velocity=0.05"]);
    let mut broke_away_at = None;
    let mut max_torque_while_stuck: f64 = 0.0;
    for k in 0..3000 {
        let command = 0.3 * k as f64 / 3000.0;
        plant.advance(command, PER_MS);
        let s = plant.state();
        if s.stuck {
            max_torque_while_stuck = max_torque_while_stuck.max(plant.torque());
        } else if broke_away_at.is_none() {
            broke_away_at = Some(k);
        }
    }
    assert!(broke_away_at.is_some(), "it broke away");
    assert!(
        max_torque_while_stuck > 100.0 && max_torque_while_stuck <= 121.0,
        "{max_torque_while_stuck}"
    );
}

#[test]
fn deadzone_blocks_flow_inside_the_overlap() {
    let mut plant = plant_with(&["deadzone:width=0.1"]);
    let neutral = plant.state().p_a;
    // 0.06 rather than near 0.1: the lightly damped spool overshoots by half.
    run(&mut plant, 0.06, 1.0);
    let s = plant.state();
    assert!((s.p_a - neutral).abs() < 1.0 && s.velocity.abs() < 1e-9);
    run(&mut plant, 0.3, 20.0);
    let mut reference = plant_with(&[]);
    run(&mut reference, 0.2, 20.0);
    assert!((plant.state().velocity - reference.state().velocity).abs() < 1e-6);
}

#[test]
fn saturation_limits_spool_travel() {
    let mut plant = plant_with(&["saturation:limit=0.5"]);
    for _ in 0..20_000 {
        plant.advance(1.0, PER_MS);
        assert!(plant.state().spool <= 0.5 + 1e-12);
    }
    let mut reference = plant_with(&[]);
    run(&mut reference, 0.5, 20.0);
    assert!((plant.state().velocity - reference.state().velocity).abs() < 1e-3);
}

#[test]
fn time_delay_shifts_the_response() {
    let mut delayed = plant_with(&["time_delay:delay_s=0.02"]);
    let mut reference = plant_with(&[]);
    let mut history = Vec::new();
    for _ in 0..200 {
        reference.advance(0.2, PER_MS);
        history.push(reference.torque());
    }
    for k in 0..200 {
        delayed.advance(0.2, PER_MS);
        let expected = if k >= 20 { history[k - 20] } else { 0.0 };
        assert!((delayed.torque() - expected).abs() < 1e-6 * 100.0, "k={k}");
    }
}

#[test]
fn asymmetric_gain_slows_negative_motion() {
    let mut plant = plant_with(&["asymmetric_gain:ratio=0.7"]);
    run(&mut plant, 0.2, 4.0);
    let forward = plant.state().velocity;
    run(&mut plant, -0.2, 4.0);
    let backward = plant.state().velocity;
    assert!((backward / forward + 0.7).abs() < 0.01, "{backward} / {forward}");
}

#[test]
fn orifice_flow_matches_linear_flow_at_mid_pressure_and_sags_near_stall() {
    let mut plant = plant_with(&["orifice_flow"]);
    let mut linear = plant_with(&[]);
    // Free motion at a small opening: drops near half the supply, similar flow.
    run(&mut plant, 0.1, 3.0);
    run(&mut linear, 0.1, 3.0);
    let ratio = plant.state().velocity / linear.state().velocity;
    assert!((0.85..1.15).contains(&ratio), "{ratio}");
}

#[test]
fn gravity_load_finds_equilibrium_where_torque_balances() {
    let mut plant = plant_with(&["gravity_load:amplitude=150,offset=0"]);
    run(&mut plant, 0.0, 20.0);
    let s = plant.state();
    // At rest the hydraulic torque carries the load torque.
    assert!(s.velocity.abs() < 1e-3);
    assert!((plant.torque() - 150.0 * s.angle.sin()).abs() < 1.0);
}

#[test]
fn load_flexibility_oscillates_near_its_coupling_frequency() {
    let mut plant = plant_with(&["load_flexibility"]);
    run(&mut plant, 0.2, 1.0);
    run(&mut plant, 0.0, 0.05);
    let mut twist = Vec::new();
    for _ in 0..2000 {
        plant.advance(0.0, PER_MS);
        let s = plant.state();
        twist.push(s.angle - s.load_angle);
    }
    let crossings = twist.windows(2).filter(|w| w[0].signum() != w[1].signum()).count();
    assert!(
        crossings >= 6,
        "the twist oscillates: {crossings} zero crossings in 2 s"
    );
}

#[test]
fn sensors_quantize_add_backlash_and_are_deterministic() {
    let mut effects = Effects::none();
    effects.insert(Effect::parse("backlash:width=0.02").expect("valid"));
    let mut a = SensorModel::new(SensorParams::default(), &effects, 7).expect("sensor");
    let mut b = SensorModel::new(SensorParams::default(), &effects, 7).expect("sensor");
    let mut plant = plant_with(&["backlash:width=0.02"]);
    run(&mut plant, 0.2, 0.5);
    let ra = a.read(&plant.state());
    let rb = b.read(&plant.state());
    assert_eq!(ra, rb);
    let step = SensorParams::default().encoder_step();
    assert!(((ra.angle / step).round() * step - ra.angle).abs() < 1e-12);
    assert!(
        (plant.state().angle - ra.angle - 0.01).abs() < step,
        "lags by half the play"
    );
    let q = Effect::parse("quantization").expect("valid");
    let mut coarse_effects = Effects::none();
    coarse_effects.insert(q);
    let coarse = SensorModel::new(SensorParams::default(), &coarse_effects, 1).expect("sensor");
    assert!((coarse.encoder_step() - std::f64::consts::PI / 18.0).abs() < 1e-12);
}

#[test]
fn pressure_readings_stay_in_the_transducer_range() {
    let mut sensor = SensorModel::new(SensorParams::default(), &Effects::none(), 3).expect("sensor");
    let mut plant = plant_with(&[]);
    run(&mut plant, 1.0, 0.5);
    for _ in 0..1000 {
        let r = sensor.read(&plant.state());
        assert!((0.0..=200e5).contains(&r.p_a) && (0.0..=200e5).contains(&r.p_b));
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn no_nan_or_infinity_for_any_bounded_input(
        commands in proptest::collection::vec(-5.0f64..5.0, 1..60),
        effect_mask in 0u16..1024,
    ) {
        let mut effects = Effects::none();
        for (i, kind) in hydractl_plant::EffectKind::ALL.iter().enumerate() {
            if effect_mask & (1 << i) != 0 {
                effects.insert(Effect::parse(kind.name()).expect("defaults"));
            }
        }
        let mut plant = Plant::new(PlantParams::default(), effects, STEP).expect("plant");
        let mut sensor = SensorModel::new(SensorParams::default(), &effects, 1).expect("sensor");
        for command in commands {
            plant.advance(command, 100);
            let s = plant.state();
            for v in [s.spool, s.spool_rate, s.p_a, s.p_b, s.angle, s.velocity, s.load_angle, s.load_velocity] {
                prop_assert!(v.is_finite());
            }
            prop_assert!(s.p_a >= 0.0 && s.p_a <= 180e5 && s.p_b >= 0.0 && s.p_b <= 180e5);
            let r = sensor.read(&s);
            prop_assert!(r.angle.is_finite() && r.p_a.is_finite() && r.p_b.is_finite());
        }
        plant.advance(f64::NAN, 10);
        prop_assert!(plant.state().p_a.is_finite());
    }
}
