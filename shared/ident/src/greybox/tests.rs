use super::*;

#[test]
fn the_hydraulic_exact_step_is_a_fine_integration_on_each_piece_of_the_valve() {
    use hydractl_plant::effects::{AsymmetricGain, Deadzone};
    let plant = PlantParams::default();
    let mut effects = Effects::none();
    effects.deadzone = Some(Deadzone {
        width: 0.05,
        offset: 0.01,
    });
    effects.asymmetric_gain = Some(AsymmetricGain { ratio: 0.7 });
    let h = 1e-3;
    let steps = HydraulicSteps::new(&plant, &effects, h).expect("linear by pieces");
    // RK4 on a hundred substeps, the velocity linear over the sample.
    let fine = |x: [f64; 4], input: f64, v0: f64, v1: f64| -> [f64; 4] {
        let n = 100;
        let dt = h / n as f64;
        let rates = |x: &[f64; 4], t: f64| -> [f64; 4] {
            let velocity = v0 + (v1 - v0) * t / h;
            let (ds, dr) = hydraulics::spool_rates(&plant, &effects, x[0], x[1], input);
            let (da, db) = hydraulics::pressure_rates(&plant, &effects, x[0], x[2], x[3], velocity);
            [ds, dr, da, db]
        };
        let mut x = x;
        for i in 0..n {
            let t = i as f64 * dt;
            let k1 = rates(&x, t);
            let k2 = rates(&add(&x, &k1, 0.5 * dt), t + 0.5 * dt);
            let k3 = rates(&add(&x, &k2, 0.5 * dt), t + 0.5 * dt);
            let k4 = rates(&add(&x, &k3, dt), t + dt);
            for j in 0..4 {
                x[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
            }
        }
        x
    };
    // Below the band, inside it and above it, each step staying there.
    for (spool, input) in [(-0.3, -0.35), (0.02, 0.03), (0.4, 0.5)] {
        let x = [spool, 0.01, 90e5, 70e5];
        let piece = steps.piece(spool);
        let exact = steps.pieces[piece]
            .as_ref()
            .expect("a piece")
            .apply(&x, input, 0.1, -0.05);
        let reference = fine(x, input, 0.1, -0.05);
        assert_eq!(steps.piece(exact[0]), piece);
        for j in 0..4 {
            let scale = x[j].abs().max(1e-3);
            assert!(
                (exact[j] - reference[j]).abs() <= 1e-9 * scale,
                "piece {piece}, state {j}: {} against {}",
                exact[j],
                reference[j]
            );
        }
        let spool_alone = steps.spool(&x, input);
        assert!((spool_alone[0] - exact[0]).abs() < 1e-12 && (spool_alone[1] - exact[1]).abs() < 1e-12);
    }
    // The √Δp valve law is not linear by pieces.
    effects.orifice_flow = Some(hydractl_plant::effects::OrificeFlow);
    assert!(HydraulicSteps::new(&plant, &effects, h).is_none());
}

#[test]
fn the_staircase_search_moves_nothing_but_the_initial_angle_and_velocity() {
    // A coarse encoder on a slow swing: the least-squares path is off
    // the true shaft by a third of a step and a slip in velocity, which
    // its staircase shows. The search may take back just those two: the
    // same initial state every model gets, chosen by the model's own
    // error, and nothing more.
    let plant = PlantParams::default();
    let (dt, n) = (1e-3, 500);
    let step = 0.01;
    let sensitivity: Vec<f64> = velocity_sensitivity(&plant, dt).take(n).collect();
    let shaft: Vec<f64> = (0..n).map(|i| 0.05 * (2.0 * i as f64 * dt).sin()).collect();
    let measured: Vec<f64> = shaft.iter().map(|a| Quantization { step }.quantize(*a)).collect();
    let (angle_slip, velocity_slip) = (0.35 * step, 0.6 * step / (n as f64 * dt));
    let start: Vec<f64> = shaft
        .iter()
        .zip(&sensitivity)
        .map(|(a, g)| a - angle_slip - velocity_slip * g)
        .collect();
    let mut path = start.clone();
    refine_on_staircase(&plant, dt, &Staircase::of(step, &measured), &measured, &mut path);
    let moved: Vec<f64> = path.iter().zip(&start).map(|(p, s)| p - s).collect();
    let (angle, velocity) = (moved[0], (moved[n - 1] - moved[0]) / sensitivity[n - 1]);
    for (m, g) in moved.iter().zip(&sensitivity) {
        assert!(
            (m - (angle + velocity * g)).abs() < 1e-12,
            "a change of the initial state alone"
        );
    }
    assert!(
        (angle - angle_slip).abs() < 0.1 * step,
        "angle {angle} for {angle_slip}"
    );
    assert!(
        (velocity - velocity_slip).abs() < 0.2 * velocity_slip,
        "velocity {velocity} for {velocity_slip}"
    );
    let error = |path: &[f64]| -> f64 {
        path.iter()
            .zip(&measured)
            .map(|(p, m)| (Quantization { step }.quantize(*p) - m).powi(2))
            .sum()
    };
    assert!(
        error(&path) < 0.1 * error(&start),
        "{} against {}",
        error(&path),
        error(&start)
    );
}

#[test]
fn a_grid_of_staircase_shifts_scores_as_each_shift_alone() {
    // A slow path over a few steps, a measured staircase off it by a
    // shift and a slip, and a grid that moves many samples' counts.
    let n = 500;
    let sensitivity: Vec<f64> = (0..n).map(|i| 0.002 * i as f64).collect();
    let path: Vec<f64> = (0..n)
        .map(|i| 3.0 * (0.01 * i as f64).sin() + 0.013 * i as f64)
        .collect();
    let measured: Vec<f64> = path
        .iter()
        .enumerate()
        .map(|(i, p)| Quantization::nearest_count(p + 0.3 + if i % 97 == 0 { 1.0 } else { 0.0 }))
        .collect();
    let angles: Vec<f64> = (0..13).map(|j| -0.5 + j as f64 / 12.0).collect();
    let velocities: Vec<f64> = (0..9).map(|k| -0.4 + 0.1 * k as f64).collect();
    let errors = staircase_errors(&measured, &path, &sensitivity, &angles, &velocities)
        .expect("a finite path near the staircase is scored");
    for (k, v) in velocities.iter().enumerate() {
        for (j, a) in angles.iter().enumerate() {
            let alone = staircase_error_below(&measured, &path, |i| a + v * sensitivity[i], f64::INFINITY);
            assert_eq!(errors[k * angles.len() + j], alone, "angle {a}, velocity {v}");
        }
    }
    // A bound gives up exactly the shifts that reach it.
    let least = errors.iter().copied().fold(f64::INFINITY, f64::min);
    let nearest = nearest_first(
        errors.len(),
        |_| 0,
        |cell, bound| {
            let (a, v) = (angles[cell % angles.len()], velocities[cell / angles.len()]);
            staircase_error_below(&measured, &path, |i| a + v * sensitivity[i], bound)
        },
    );
    for (e, n) in errors.iter().zip(&nearest) {
        assert!(if *e == least { n == e } else { n.is_infinite() || n == e });
    }
    // A path that diverged scores nothing.
    let mut diverged = path.clone();
    diverged[n / 2] = f64::NAN;
    assert!(staircase_errors(&measured, &diverged, &sensitivity, &angles, &velocities).is_none());
}
