//! Starting values read from the data's own equations: the rigid body's
//! inertia and friction by equation error, the pressures' lag behind the
//! motion.

use super::*;

/// How long the measured pressures lag the motion they drive, s: the shift
/// of the torque D (p_a − p_b) that best fits J ω̇ + b ω + F tanh(ω/ω_s) + c
/// by equation error on `range`, searched up to `longest` (parabolic
/// between samples). The friction's sign term keeps a machine's Coulomb
/// friction from biasing the lag (without it, 2.1 ms of transducer lag
/// beside 60 N·m of friction read as too little, and passed for a delay).
/// A lag of the valve delays pressures and motion alike and leaves this
/// near zero; a lag of the pressure transducers shows here and nowhere
/// else. Every signal is filtered by zero-phase windows, so no filter
/// shifts one against another. `None` without measured pressures.
pub(crate) fn pressure_lag_behind_motion(
    signals: &Signals,
    plant: &PlantParams,
    range: Range<usize>,
    longest: f64,
) -> Option<f64> {
    if !signals.has_pressures || signals.tau.is_some() {
        return None;
    }
    let torque: Vec<f64> = (0..signals.len()).map(|k| signals.torque(plant, k)).collect();
    let torque = crate::greybox::signals::moving_average(&torque, PRESSURE_LAG_SMOOTHING_S, signals.dt);
    let most = ((longest / signals.dt).ceil() as usize).max(2);
    let end = range.end.min(signals.len().saturating_sub(most + 1));
    if end <= range.start + 10 * most {
        return None;
    }
    // The regressors do not move with the shift: their normal matrix is
    // factored once, and each shift costs two passes over the data.
    // Where the rotator slides, clear of the speeds at which friction
    // holds it: stuck, its torque moves with no motion to lag.
    let rows: Vec<usize> = (range.start..end)
        .filter(|k| signals.velocity[*k].abs() > 2.0 * COULOMB_SIGN_VELOCITY)
        .collect();
    if rows.len() < 10 * most {
        return None;
    }
    let sign = |v: f64| (v / COULOMB_SIGN_VELOCITY).tanh();
    let regressors = |k: usize| {
        nalgebra::Vector4::new(
            signals.acceleration[k],
            signals.velocity[k],
            sign(signals.velocity[k]),
            1.0,
        )
    };
    let mut normal = nalgebra::Matrix4::zeros();
    for &k in &rows {
        let x = regressors(k);
        normal += x * x.transpose();
    }
    let factored = normal.lu();
    let residual = |shift: usize| -> f64 {
        let mut projected = nalgebra::Vector4::zeros();
        for &k in &rows {
            projected += regressors(k) * torque[k + shift];
        }
        let Some(solution) = factored.solve(&projected) else {
            return f64::INFINITY;
        };
        rows.iter()
            .map(|&k| (torque[k + shift] - regressors(k).dot(&solution)).powi(2))
            .sum()
    };
    let costs: Vec<f64> = (0..=most).map(residual).collect();
    let best = (0..costs.len()).min_by(|i, j| costs[*i].total_cmp(&costs[*j]))?;
    let offset = if best > 0 && best < most {
        let (l, c, r) = (costs[best - 1], costs[best], costs[best + 1]);
        let curvature = l - 2.0 * c + r;
        if curvature > 0.0 {
            0.5 * (l - r) / curvature
        } else {
            0.0
        }
    } else {
        0.0
    };
    Some((best as f64 + offset) * signals.dt)
}

/// The speed over which [`pressure_lag_behind_motion`]'s friction term
/// changes sign, rad/s: the data sheet's Stribeck velocity.
const COULOMB_SIGN_VELOCITY: f64 = 0.05;

/// Half-width of the torque's smoothing for [`pressure_lag_behind_motion`],
/// s: the velocity's own (its acceleration is smoothed as much).
pub(super) const PRESSURE_LAG_SMOOTHING_S: f64 = 0.02;

/// Half-width of the equation error's moving average, s: its first null is
/// at 5 Hz, below a flexible load's mode.
pub(super) const LOW_PASS_HALF_WIDTH_S: f64 = 0.1;

/// The rigid body by equation error, J ω̇ + b ω + T = D (p_a − p_b) (or the
/// measured torque), on the smoothed velocity and its smoothed derivative:
/// a start for the mechanical part that depends on the data only, not on
/// the prior's guess. With `coulomb`, F_c sign(ω) is a regressor too, as in
/// the inverse-dynamics identification of robots and machine tools
/// (IDIM-LS). `None` when the data does not give a positive J and b.
pub(super) fn rigid_body_by_equation_error(
    signals: &Signals,
    plant: &PlantParams,
    range: Range<usize>,
    coulomb: bool,
) -> Option<RigidBody> {
    // All through the same low-pass: the equation holds for the filtered
    // signals too, and the filter keeps out what a rigid body cannot
    // explain (a flexible load's ringing, the encoder's steps).
    let low_pass = |x: &[f64]| crate::greybox::signals::moving_average(x, LOW_PASS_HALF_WIDTH_S, signals.dt);
    let velocity = low_pass(&signals.velocity);
    let acceleration = low_pass(&crate::greybox::signals::smoothed_slope(&signals.velocity, signals.dt));
    let torque: Vec<f64> = (0..signals.len()).map(|k| signals.torque(plant, k)).collect();
    let torque = low_pass(&torque);
    // A regressor left out has an empty row and column: its unknown is
    // pinned at zero. Without a fitted load torque, no constant: the
    // start's J and b are then those of the model that is fitted.
    let used = [true, true, coulomb, fits_load_torque(signals)];
    let mut normal = nalgebra::Matrix4::zeros();
    let mut projected = nalgebra::Vector4::zeros();
    for k in range {
        let v = velocity[k];
        let regressors = [acceleration[k], v, v.signum(), 1.0];
        let x = nalgebra::Vector4::from(std::array::from_fn(|i| if used[i] { regressors[i] } else { 0.0 }));
        if x.iter().all(|v| v.is_finite()) && torque[k].is_finite() {
            normal += x * x.transpose();
            projected += x * torque[k];
        }
    }
    for (i, used) in used.iter().enumerate() {
        if !used {
            normal[(i, i)] = 1.0;
        }
    }
    let solution = normal.lu().solve(&projected)?;
    (solution[0] > 0.0 && solution[1] > 0.0 && solution.iter().all(|v| v.is_finite())).then_some(RigidBody {
        inertia: solution[0],
        viscous_friction: solution[1],
        coulomb: solution[2],
        load_torque: solution[3],
    })
}

/// The rigid body's parameters by equation error.
pub(super) struct RigidBody {
    pub(super) inertia: f64,
    pub(super) viscous_friction: f64,
    /// F_c, where it was a regressor (else 0).
    pub(super) coulomb: f64,
    pub(super) load_torque: f64,
}

impl RigidBody {
    /// `start` with this body's parameters.
    pub(super) fn applied(&self, start: &Working, signals: &Signals) -> Working {
        let mut fresh = start.clone();
        fresh.plant.inertia = self.inertia;
        fresh.plant.viscous_friction = self.viscous_friction;
        if fits_load_torque(signals) {
            fresh.plant.load_torque = self.load_torque;
        }
        fresh
    }
}
