//! The hydraulic half of the rotator as free functions of its state: the
//! valve spool (eq. 10), the valve flows (eq. 9, or orifice flow) and the
//! chamber pressures (eq. 8). The plant integrates them coupled to the
//! mechanics; model identification integrates them driven by measured
//! motion, so that a pressure residual points at the hydraulics alone.

use crate::effects::{Effects, OrificeFlow};
use crate::PlantParams;

/// The spool's rate and acceleration for valve input `input` (eq. 10),
/// stopped at the travel limit when `saturation` is on.
pub fn spool_rates(params: &PlantParams, effects: &Effects, spool: f64, spool_rate: f64, input: f64) -> (f64, f64) {
    let wn = params.valve_natural_frequency;
    let mut rate = spool_rate;
    let mut acceleration = wn * wn * (input - spool) - 2.0 * params.valve_damping * wn * spool_rate;
    if let Some(saturation) = effects.saturation {
        let at_stop = spool.abs() >= saturation.limit;
        if at_stop && spool * acceleration > 0.0 {
            acceleration = 0.0;
        }
        if at_stop && spool * spool_rate > 0.0 {
            rate = 0.0;
        }
    }
    (rate, acceleration)
}

/// The spool's fastest mode, 1/s: the larger root of s² + 2ζω s + ω² in
/// size, ω (ζ + √(ζ² − 1)) when overdamped, ω when not. An explicit
/// integration step must stay well within its inverse.
pub fn spool_fastest_rate(params: &PlantParams) -> f64 {
    let (wn, zeta) = (params.valve_natural_frequency, params.valve_damping);
    wn * (zeta + (zeta * zeta - 1.0).max(0.0).sqrt())
}

/// Holds the spool within its travel limit after an integration step.
pub fn limit_spool(effects: &Effects, spool: &mut f64, spool_rate: &mut f64) {
    if let Some(saturation) = effects.saturation {
        if spool.abs() > saturation.limit {
            *spool = saturation.clamp(*spool);
            if *spool * *spool_rate > 0.0 {
                *spool_rate = 0.0;
            }
        }
    }
}

/// Flow into chamber A and out of chamber B, m³/s (eq. 9, or orifice flow).
pub(crate) fn chamber_flows(params: &PlantParams, effects: &Effects, spool: f64, p_a: f64, p_b: f64) -> (f64, f64) {
    let p = params;
    let mut opening = spool;
    if let Some(deadzone) = effects.deadzone {
        opening = deadzone.opening(opening);
    }
    let gain = p.flow_gain * effects.asymmetric_gain.map_or(1.0, |a| a.gain_factor(opening));
    let centre_a = 2.0 * p.flow_pressure_coefficient * (p_a - 0.5 * p.supply_pressure);
    let centre_b = 2.0 * p.flow_pressure_coefficient * (p_b - 0.5 * p.supply_pressure);
    let (metered_a, metered_b) = if effects.orifice_flow.is_some() {
        let nominal = 0.5 * (p.supply_pressure - p.tank_pressure);
        let drop = |high: f64, low: f64| OrificeFlow::drop_factor(high - low, nominal);
        if opening >= 0.0 {
            (
                2.0 * gain * opening * drop(p.supply_pressure, p_a),
                2.0 * gain * opening * drop(p_b, p.tank_pressure),
            )
        } else {
            (
                2.0 * gain * opening * drop(p_a, p.tank_pressure),
                2.0 * gain * opening * drop(p.supply_pressure, p_b),
            )
        }
    } else {
        (2.0 * gain * opening, 2.0 * gain * opening)
    };
    (metered_a - centre_a, metered_b + centre_b)
}

/// The chamber pressures' rates, Pa/s (eq. 8), for actuator velocity
/// `velocity`; a pressure at tank or supply does not move past it.
pub fn pressure_rates(
    params: &PlantParams,
    effects: &Effects,
    spool: f64,
    p_a: f64,
    p_b: f64,
    velocity: f64,
) -> (f64, f64) {
    let p = params;
    let (q_a, q_b) = chamber_flows(p, effects, spool, p_a, p_b);
    let motion_flow = p.displacement * velocity;
    let mut rate_a = p.bulk_modulus / p.volume_a * (-p.leakage * p_a - motion_flow + q_a);
    let mut rate_b = p.bulk_modulus / p.volume_b * (-p.leakage * p_b + motion_flow - q_b);
    let held = |x: f64, rate: f64| (x <= p.tank_pressure && rate < 0.0) || (x >= p.supply_pressure && rate > 0.0);
    if held(p_a, rate_a) {
        rate_a = 0.0;
    }
    if held(p_b, rate_b) {
        rate_b = 0.0;
    }
    (rate_a, rate_b)
}

/// Keeps a pressure between tank and supply.
pub fn bound_pressure(params: &PlantParams, pressure: f64) -> f64 {
    pressure.clamp(params.tank_pressure, params.supply_pressure)
}
