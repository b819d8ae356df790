//! The mechanical half of the rotator as free functions: the rigid body of
//! eq. (5) with viscous friction, and the catalog's Coulomb friction,
//! gravity load and flexible load. The plant drives them with its simulated
//! pressures; model identification drives them with measured torque, so
//! that an angle residual points at the mechanics alone.

use nalgebra::{Matrix4, SMatrix, Vector4};

use crate::effects::Effects;
use crate::PlantParams;

/// Actuator and load motion: angle, velocity, load angle, load velocity.
/// Without `load_flexibility` the load moves with the actuator.
pub type Motion = [f64; 4];
pub const ANGLE: usize = 0;
pub const VELOCITY: usize = 1;
pub(crate) const LOAD_ANGLE: usize = 2;
pub(crate) const LOAD_VELOCITY: usize = 3;

/// Everything acting on the actuator's rotor except Coulomb friction, N·m,
/// given the hydraulic torque D (p_a − p_b): less viscous friction, the
/// load (coupled or hanging) and the constant load torque.
#[inline]
pub fn net_torque(params: &PlantParams, effects: &Effects, motion: &Motion, hydraulic_torque: f64) -> f64 {
    let viscous = params.viscous_friction * motion[VELOCITY];
    let load = match effects.load_flexibility {
        Some(flex) => flex.coupling_torque(
            motion[ANGLE] - motion[LOAD_ANGLE],
            motion[VELOCITY] - motion[LOAD_VELOCITY],
        ),
        None => effects.gravity_load.map_or(0.0, |g| g.torque(motion[ANGLE])),
    };
    hydraulic_torque - viscous - load - params.load_torque
}

/// The motion's rates; `direction` is the friction direction frozen for the
/// step (+1 or −1 while sliding, 0 while stuck).
#[inline]
pub fn motion_rates(
    params: &PlantParams,
    effects: &Effects,
    motion: &Motion,
    hydraulic_torque: f64,
    direction: f64,
) -> Motion {
    let mut rates = [0.0; 4];
    let stuck = effects.coulomb_friction.is_some() && direction == 0.0;
    let friction = match effects.coulomb_friction {
        Some(f) if !stuck => direction * f.sliding_level(motion[VELOCITY].abs()),
        _ => 0.0,
    };
    let net = net_torque(params, effects, motion, hydraulic_torque);
    let rotor_inertia = match effects.load_flexibility {
        Some(flex) => {
            let load_inertia = params.inertia * flex.load_fraction;
            let coupling = flex.coupling_torque(
                motion[ANGLE] - motion[LOAD_ANGLE],
                motion[VELOCITY] - motion[LOAD_VELOCITY],
            );
            let gravity = effects.gravity_load.map_or(0.0, |g| g.torque(motion[LOAD_ANGLE]));
            rates[LOAD_ANGLE] = motion[LOAD_VELOCITY];
            rates[LOAD_VELOCITY] = (coupling - gravity) / load_inertia;
            params.inertia * (1.0 - flex.load_fraction)
        }
        None => params.inertia,
    };
    if !stuck {
        rates[ANGLE] = motion[VELOCITY];
        rates[VELOCITY] = (net - friction) / rotor_inertia;
    }
    if effects.load_flexibility.is_none() {
        rates[LOAD_ANGLE] = rates[ANGLE];
        rates[LOAD_VELOCITY] = rates[VELOCITY];
    }
    rates
}

/// One sample's exact step of the mechanics where they are linear (viscous
/// friction, a flexible load, the constant load torque; no Coulomb friction
/// and no gravity), the hydraulic torque a ramp between samples: one matrix
/// product in place of an integrator's evaluations of [`motion_rates`], and
/// no stability limit from a stiff coupling. Built from [`motion_rates`]
/// itself, which is affine in the motion and the torque there.
#[derive(Debug, Clone, Copy)]
pub struct LinearStep {
    transition: Matrix4<f64>,
    from_start_torque: Vector4<f64>,
    from_end_torque: Vector4<f64>,
    constant: Vector4<f64>,
}

impl LinearStep {
    /// `None` where the mechanics are not linear, or the step is not finite.
    pub fn new(params: &PlantParams, effects: &Effects, dt: f64) -> Option<Self> {
        if effects.coulomb_friction.is_some() || effects.gravity_load.is_some() || !dt.is_finite() || dt <= 0.0 {
            return None;
        }
        // The state [motion, torque, torque's slope, 1]: the motion's rates
        // are A·motion + B·torque + c, the torque a ramp.
        let rates = |motion: &Motion, torque: f64| Vector4::from(motion_rates(params, effects, motion, torque, 0.0));
        let at_rest = rates(&[0.0; 4], 0.0);
        let mut generator = SMatrix::<f64, 7, 7>::zeros();
        for i in 0..4 {
            let mut unit = [0.0; 4];
            unit[i] = 1.0;
            generator
                .fixed_view_mut::<4, 1>(0, i)
                .copy_from(&(rates(&unit, 0.0) - at_rest));
        }
        generator
            .fixed_view_mut::<4, 1>(0, 4)
            .copy_from(&(rates(&[0.0; 4], 1.0) - at_rest));
        generator[(4, 5)] = 1.0;
        generator.fixed_view_mut::<4, 1>(0, 6).copy_from(&at_rest);
        let exact = (generator * dt).exp();
        let from_torque = exact.fixed_view::<4, 1>(0, 4).into_owned();
        let from_slope = exact.fixed_view::<4, 1>(0, 5).into_owned();
        let step = Self {
            transition: exact.fixed_view::<4, 4>(0, 0).into_owned(),
            from_start_torque: from_torque - from_slope / dt,
            from_end_torque: from_slope / dt,
            constant: exact.fixed_view::<4, 1>(0, 6).into_owned(),
        };
        step.transition.iter().all(|v| v.is_finite()).then_some(step)
    }

    /// The motion one sample on, the hydraulic torque going from
    /// `torque_start` to `torque_end` over the sample.
    #[inline]
    pub fn step(&self, motion: &Motion, torque_start: f64, torque_end: f64) -> Motion {
        let next = self.transition * Vector4::from(*motion)
            + self.from_start_torque * torque_start
            + self.from_end_torque * torque_end
            + self.constant;
        next.into()
    }
}

/// Decides breakaway before a step: the friction direction for the step and
/// whether the actuator stays stuck. Without Coulomb friction: (0, false).
#[inline]
pub fn friction_direction(
    params: &PlantParams,
    effects: &Effects,
    motion: &Motion,
    hydraulic_torque: f64,
    stuck: bool,
) -> (f64, bool) {
    let Some(friction) = effects.coulomb_friction else {
        return (0.0, false);
    };
    let velocity = motion[VELOCITY];
    if stuck || velocity == 0.0 {
        let net = net_torque(params, effects, motion, hydraulic_torque);
        if net.abs() > friction.breakaway {
            return (net.signum(), false);
        }
        return (0.0, true);
    }
    (velocity.signum(), false)
}

/// After a step from `before` to `after` with friction direction
/// `direction`: holds a stuck actuator still, and stops one whose velocity
/// reached or crossed zero, sticking if friction can hold the net torque.
/// Returns whether the actuator is stuck now.
#[inline]
pub fn settle_friction(
    params: &PlantParams,
    effects: &Effects,
    before: &Motion,
    after: &mut Motion,
    hydraulic_torque: f64,
    stuck: bool,
    direction: f64,
) -> bool {
    let Some(friction) = effects.coulomb_friction else {
        return false;
    };
    let mut now_stuck = stuck;
    if stuck {
        after[VELOCITY] = 0.0;
        after[ANGLE] = before[ANGLE];
    } else if after[VELOCITY] * direction <= 0.0 {
        after[VELOCITY] = 0.0;
        let net = net_torque(params, effects, after, hydraulic_torque);
        now_stuck = net.abs() <= friction.breakaway;
    }
    if effects.load_flexibility.is_none() {
        after[LOAD_ANGLE] = after[ANGLE];
        after[LOAD_VELOCITY] = after[VELOCITY];
    }
    now_stuck
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::{CoulombFriction, LoadFlexibility};

    /// RK4 on many substeps, the torque a ramp: the reference for one sample.
    fn integrated(params: &PlantParams, effects: &Effects, motion: &Motion, torques: (f64, f64), dt: f64) -> Motion {
        const SUBSTEPS: usize = 2000;
        let h = dt / SUBSTEPS as f64;
        let torque = |t: f64| torques.0 + (torques.1 - torques.0) * t / dt;
        let rates = |m: &Motion, t: f64| motion_rates(params, effects, m, torque(t), 0.0);
        let add = |m: &Motion, k: &Motion, a: f64| std::array::from_fn::<f64, 4, _>(|i| m[i] + a * k[i]);
        let mut m = *motion;
        for n in 0..SUBSTEPS {
            let t = n as f64 * h;
            let k1 = rates(&m, t);
            let k2 = rates(&add(&m, &k1, 0.5 * h), t + 0.5 * h);
            let k3 = rates(&add(&m, &k2, 0.5 * h), t + 0.5 * h);
            let k4 = rates(&add(&m, &k3, h), t + h);
            m = std::array::from_fn(|i| m[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]));
        }
        m
    }

    #[test]
    fn the_linear_step_is_the_mechanics_integrated_over_one_sample() {
        let params = PlantParams {
            load_torque: 7.0,
            ..PlantParams::default()
        };
        let flexible = Effects {
            load_flexibility: Some(LoadFlexibility {
                stiffness: 2.0e4,
                damping: 15.0,
                load_fraction: 0.6,
            }),
            ..Effects::default()
        };
        let dt = 1e-3;
        for effects in [Effects::default(), flexible] {
            let step = LinearStep::new(&params, &effects, dt).expect("linear mechanics");
            let start = [0.3, -0.8, 0.29, -0.5];
            let start = if effects.load_flexibility.is_some() {
                start
            } else {
                [start[0], start[1], start[0], start[1]]
            };
            let exact = step.step(&start, 120.0, -40.0);
            let reference = integrated(&params, &effects, &start, (120.0, -40.0), dt);
            for i in 0..4 {
                assert!(
                    (exact[i] - reference[i]).abs() < 1e-10,
                    "{exact:?} against {reference:?}"
                );
            }
        }
        let with_friction = Effects {
            coulomb_friction: Some(CoulombFriction {
                coulomb: 30.0,
                breakaway: 45.0,
                stribeck_velocity: 0.05,
            }),
            ..Effects::default()
        };
        assert!(LinearStep::new(&params, &with_friction, dt).is_none());
    }
}
