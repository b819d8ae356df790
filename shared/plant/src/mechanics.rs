//! The mechanical half of the rotator as free functions: the rigid body of
//! eq. (5) with viscous friction, and the catalog's Coulomb friction,
//! gravity load and flexible load. The plant drives them with its simulated
//! pressures; model identification drives them with measured torque, so
//! that an angle residual points at the mechanics alone.

use crate::effects::Effects;
use crate::PlantParams;

/// Actuator and load motion: angle, velocity, load angle, load velocity.
/// Without `load_flexibility` the load moves with the actuator.
pub type Motion = [f64; 4];
pub const ANGLE: usize = 0;
pub const VELOCITY: usize = 1;
pub const LOAD_ANGLE: usize = 2;
pub const LOAD_VELOCITY: usize = 3;

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
