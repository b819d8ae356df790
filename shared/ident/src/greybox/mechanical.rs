//! The mechanical part's prediction: the shaft driven by the measured
//! torque, segment by segment from the measured state.

use super::*;

/// Measured torque → angle → encoder, segment by segment.
pub(super) fn predict_mechanical(
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
    out: &mut Prediction,
) {
    let mut shaft = Vec::new();
    let mut best = Vec::new();
    let model = Mechanics {
        plant,
        effects,
        linear: mechanics::LinearStep::new(plant, effects, signals.dt),
    };
    for segment in segments(signals, range) {
        let start = segment.start;
        // Where the actuator sits in the play, from the data before the
        // segment: half the play ahead of the encoder, on the side of its
        // last motion (a load that stopped stays where it was pushed). A
        // model with a play chooses nothing on the segment it is judged on
        // that the baseline may not.
        let play = effects
            .backlash
            .map_or(0.0, |b| 0.5 * b.width * signals.last_motion[start]);
        let mut initial_angle = signals.theta_smooth[start];
        let mut initial_velocity = signals.velocity[start];
        if let Some(friction) = effects.coulomb_friction {
            if initial_velocity.abs() < friction.stribeck_velocity {
                initial_velocity = 0.0;
            }
        }
        // From the smoothed measurement, then from the initial state that
        // least squares says fits the segment better; the better one stays
        // (with backlash or friction the correction's linear view can miss).
        let mut best_error = f64::INFINITY;
        best.clear();
        let measured = &signals.theta[segment.clone()];
        let staircase = effects.quantization.map(|q| Staircase::of(q.step, measured));
        // Simulates the segment from an initial state (and a position in the
        // play) into `shaft`, and keeps it in `best` when it fits better.
        let mut try_start = |initial: (f64, f64), shaft: &mut Vec<f64>| {
            simulate_segment(&model, signals, segment.clone(), initial, play, shaft);
            keep_if_better(effects, staircase.as_ref(), measured, shaft, &mut best, &mut best_error);
        };
        // Without a mechanical effect the correction is exact: two passes
        // do. A coarse encoder reads the shaft and does not move it, and the
        // correction fits the shaft before its reading: exact as well.
        let passes = if nonlinear_mechanics(effects) { 3 } else { 2 };
        for pass in 0..passes {
            try_start((initial_angle, initial_velocity), &mut shaft);
            if pass + 1 == passes {
                break;
            }
            let (d_angle, d_velocity) = initial_state_correction(plant, signals, segment.clone(), &shaft);
            initial_angle += d_angle;
            initial_velocity += d_velocity;
        }
        if let Some(staircase) = &staircase {
            refine_on_staircase(plant, signals.dt, staircase, measured, &mut best);
        }
        // A diverged simulation leaves NaN, which the fit refuses.
        best.resize(segment.len(), f64::NAN);
        for (i, k) in segment.clone().enumerate() {
            out.theta[k] = encoder_reading(effects, best[i]);
        }
    }
}

/// Scores a simulated segment against the measurement, at its best shift
/// within a quantization step, and keeps it (shifted) in `best` when it
/// beats `best_error`.
pub(super) fn keep_if_better(
    effects: &Effects,
    staircase: Option<&Staircase>,
    measured: &[f64],
    shaft: &[f64],
    best: &mut Vec<f64>,
    best_error: &mut f64,
) {
    let offset = staircase.map_or(0.0, |staircase| best_quantized_offset(staircase, shaft));
    let error = segment_error(effects, measured, shaft, offset);
    if error < *best_error {
        *best_error = error;
        best.clear();
        best.extend(shaft.iter().map(|s| s + offset));
    }
}

pub(super) fn nonlinear_mechanics(effects: &Effects) -> bool {
    effects.coulomb_friction.is_some()
        || effects.gravity_load.is_some()
        || effects.backlash.is_some()
        || effects.load_flexibility.is_some()
}

pub(super) fn encoder_reading(effects: &Effects, shaft: f64) -> f64 {
    match effects.quantization {
        Some(q) => q.quantize(shaft),
        None => shaft,
    }
}

pub(super) fn segment_error(effects: &Effects, measured: &[f64], shaft: &[f64], offset: f64) -> f64 {
    measured
        .iter()
        .zip(shaft)
        .map(|(m, s)| (m - encoder_reading(effects, s + offset)).powi(2))
        .sum()
}

/// How far the rigid body's angle moves per unit of initial velocity after
/// each sample, (1 − e^(−b t / J)) J / b: the sensitivity that corrects a
/// segment's initial velocity. The exponential advances by one product per
/// sample (an exp per sample cost diagnose a tenth of its time).
pub(super) fn velocity_sensitivity(plant: &PlantParams, dt: f64) -> impl Iterator<Item = f64> {
    let decay = plant.viscous_friction / plant.inertia;
    let ratio = (-decay * dt).exp();
    (0..).scan(1.0_f64, move |decayed, i: u32| {
        let t = f64::from(i) * dt;
        let g = if decay * t > 1e-9 { (1.0 - *decayed) / decay } else { t };
        *decayed *= ratio;
        Some(g)
    })
}

/// The least-squares change of a segment's initial angle and velocity that
/// best fits the measured angle, with the rigid body's sensitivities: 1 for
/// the angle, (J/b)(1 − e^(−b t / J)) for the velocity.
pub(super) fn initial_state_correction(
    plant: &PlantParams,
    signals: &Signals,
    segment: Range<usize>,
    shaft: &[f64],
) -> (f64, f64) {
    let (mut s11, mut s12, mut s22, mut r1, mut r2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for ((i, k), g) in segment.enumerate().zip(velocity_sensitivity(plant, signals.dt)) {
        let e = signals.theta[k] - shaft[i];
        s11 += 1.0;
        s12 += g;
        s22 += g * g;
        r1 += e;
        r2 += g * e;
    }
    let det = s11 * s22 - s12 * s12;
    if det.abs() < 1e-12 {
        return (if s11 > 0.0 { r1 / s11 } else { 0.0 }, 0.0);
    }
    ((s22 * r1 - s12 * r2) / det, (s11 * r2 - s12 * r1) / det)
}

/// The mechanical part's model as one segment's simulation uses it: with
/// the exact step of linear mechanics, where they are linear.
pub(super) struct Mechanics<'a> {
    pub(super) plant: &'a PlantParams,
    pub(super) effects: &'a Effects,
    pub(super) linear: Option<mechanics::LinearStep>,
}

/// One segment of the mechanical part from a given initial state (the
/// encoder's angle and the velocity); writes the encoder shaft's angle
/// (before quantization) into `shaft`. With backlash, the actuator starts
/// `lag` ahead of the encoder within the play.
pub(super) fn simulate_segment(
    model: &Mechanics,
    signals: &Signals,
    segment: Range<usize>,
    (initial_angle, initial_velocity): (f64, f64),
    lag: f64,
    shaft: &mut Vec<f64>,
) {
    let Mechanics { plant, effects, linear } = model;
    shaft.clear();
    let h = signals.dt;
    let angle = initial_angle + lag;
    let mut motion: mechanics::Motion = [angle, initial_velocity, angle, initial_velocity];
    let mut follower = initial_angle;
    let mut stuck = effects.coulomb_friction.is_some() && initial_velocity == 0.0;
    for k in segment.clone() {
        follower = match effects.backlash {
            Some(b) => b.follow(motion[mechanics::ANGLE], follower),
            None => motion[mechanics::ANGLE],
        };
        shaft.push(follower);
        if k + 1 >= segment.end {
            break;
        }
        let (t0, t1) = (signals.torque(plant, k), signals.torque(plant, k + 1));
        if let Some(linear) = linear {
            motion = linear.step(&motion, t0, t1);
            continue;
        }
        let (direction, now_stuck) = mechanics::friction_direction(plant, effects, &motion, t0, stuck);
        stuck = now_stuck;
        let rates = |m: &mechanics::Motion, torque: f64| mechanics::motion_rates(plant, effects, m, torque, direction);
        let mut next = motion;
        let k1 = rates(&motion, t0);
        if effects.load_flexibility.is_some() {
            // A stiff coupling's mode needs RK4's wider stability region.
            let tm = 0.5 * (t0 + t1);
            let k2 = rates(&add(&motion, &k1, 0.5 * h), tm);
            let k3 = rates(&add(&motion, &k2, 0.5 * h), tm);
            let k4 = rates(&add(&motion, &k3, h), t1);
            for i in 0..4 {
                next[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        } else {
            // A rigid body's one mode, −B/J, is real and slow against the
            // sample (a rotator's about 1/s; Heun is stable to 2000/s, RK4
            // to 2780/s): Heun's two evaluations follow it to far below the
            // encoder's noise, at half RK4's cost (diagnose 30 % faster).
            let k2 = rates(&add(&motion, &k1, h), t1);
            for i in 0..4 {
                next[i] += 0.5 * h * (k1[i] + k2[i]);
            }
        }
        stuck = mechanics::settle_friction(plant, effects, &motion, &mut next, t1, stuck, direction);
        motion = next;
    }
}
