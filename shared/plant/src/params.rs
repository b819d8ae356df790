//! Physical parameters of the rotator, in SI units. Every default says where
//! it comes from; the papers give the structure (eqs. 5, 7–10 of the rotary
//! paper) and some values, and the rest are sized for a forestry rotator.

use serde::{Deserialize, Serialize};

use crate::PlantError;

/// The baseline plant: valve spool, linearized valve flow, chamber pressures
/// with internal leakage, torque, rigid body with viscous friction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlantParams {
    /// Supply pressure p_s, Pa. Both papers: a constant 180 bar.
    pub supply_pressure: f64,
    /// Tank pressure, Pa (gauge). The papers' eq. (9) takes it as zero.
    pub tank_pressure: f64,
    /// Volumetric displacement D_a, m³/rad (eq. 7). Sized for a rotator of
    /// about 0.31 L/rev: 900 N·m at the full 180 bar.
    pub displacement: f64,
    /// Effective bulk modulus β, Pa (eq. 8): oil at 1.5e9 softened by the
    /// long hoses to the crane tip.
    pub bulk_modulus: f64,
    /// Volume of chamber A with its hose to the crane tip, m³ (V_1 of eq. 8).
    pub volume_a: f64,
    /// Volume of chamber B with its hose, m³ (V_2 of eq. 8).
    pub volume_b: f64,
    /// Leakage coefficient C_em, m³/(s·Pa) (eq. 8): 0.27 L/min at 90 bar.
    pub leakage: f64,
    /// Flow gain K_q, m³/s per unit spool opening (eq. 9): 2 K_q = 6 L/min
    /// at full opening and no load, about 2 rad/s of rotation.
    pub flow_gain: f64,
    /// Flow-pressure coefficient K_c, m³/(s·Pa) (eq. 9): small, so a
    /// stalled valve builds pressure fast (the pressures stay bounded by tank
    /// and supply).
    pub flow_pressure_coefficient: f64,
    /// Valve spool natural frequency ω_n, rad/s (eq. 10). The rotary paper
    /// identified its valve's resonance near 32 rad/s (eq. 18).
    pub valve_natural_frequency: f64,
    /// Valve spool damping ratio ξ (eq. 10): lightly damped, as eq. (18)'s
    /// pair (33 rad/s, ζ = 0.27).
    pub valve_damping: f64,
    /// Moment of inertia J of rotator, grapple and load, kg·m² (eq. 5).
    /// With D, β and the volumes it sets the hydraulic-mechanical mode,
    /// √(2 D² β / (V J)) = 13 rad/s: below the valve, so that pressure
    /// feedback can damp it, as the papers' cascades do.
    pub inertia: f64,
    /// Viscous friction b, N·m·s/rad (eq. 5). Small enough to leave the
    /// hydraulic-mechanical mode lightly damped (ζ ≈ 0.1): the oscillation
    /// both papers measure under position-only control.
    pub viscous_friction: f64,
    /// A constant torque against positive rotation, N·m: a hose's drag, the
    /// mean of a load hanging off-centre, or the zero offset of the torque
    /// the model is driven by (a pressure transducer's, a torque sensor's).
    /// Zero on the data sheet; model identification fits it with the rigid
    /// body where the torque is measured, as a real axis seldom has none.
    pub load_torque: f64,
}

impl Default for PlantParams {
    fn default() -> Self {
        Self {
            supply_pressure: 180e5,
            tank_pressure: 0.0,
            displacement: 5.0e-5,
            bulk_modulus: 7.0e8,
            volume_a: 1.0e-3,
            volume_b: 1.0e-3,
            leakage: 5.0e-13,
            flow_gain: 5.0e-5,
            flow_pressure_coefficient: 1.0e-12,
            valve_natural_frequency: 32.0,
            valve_damping: 0.3,
            inertia: 20.0,
            viscous_friction: 17.0,
            load_torque: 0.0,
        }
    }
}

impl PlantParams {
    pub fn validate(&self) -> Result<(), PlantError> {
        let positive = [
            ("supply_pressure", self.supply_pressure),
            ("displacement", self.displacement),
            ("bulk_modulus", self.bulk_modulus),
            ("volume_a", self.volume_a),
            ("volume_b", self.volume_b),
            ("flow_gain", self.flow_gain),
            ("valve_natural_frequency", self.valve_natural_frequency),
            ("valve_damping", self.valve_damping),
            ("inertia", self.inertia),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(PlantError::invalid(name, value, "must be positive and finite"));
            }
        }
        let non_negative = [
            ("leakage", self.leakage),
            ("flow_pressure_coefficient", self.flow_pressure_coefficient),
            ("viscous_friction", self.viscous_friction),
            ("tank_pressure", self.tank_pressure),
        ];
        for (name, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(PlantError::invalid(name, value, "must be non-negative and finite"));
            }
        }
        if !self.load_torque.is_finite() {
            return Err(PlantError::invalid("load_torque", self.load_torque, "must be finite"));
        }
        if self.tank_pressure >= self.supply_pressure {
            return Err(PlantError::invalid(
                "tank_pressure",
                self.tank_pressure,
                "must be below supply_pressure",
            ));
        }
        Ok(())
    }
}

/// Sensors as the rotary paper's lab has them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorParams {
    /// Encoder counts per turn. The crane paper's encoders have 4000
    /// pulses/turn; the rotary paper's 36-magnet disc is the `quantization`
    /// effect's default (a 10° step).
    pub encoder_counts_per_turn: f64,
    /// Pressure transducer range, Pa: [0, 200] bar (HD 3403 in both papers).
    pub pressure_min: f64,
    pub pressure_max: f64,
    /// Standard deviation of the transducers' white noise, Pa (0.1 bar).
    pub pressure_noise_std: f64,
}

impl Default for SensorParams {
    fn default() -> Self {
        Self {
            encoder_counts_per_turn: 4000.0,
            pressure_min: 0.0,
            pressure_max: 200e5,
            pressure_noise_std: 0.1e5,
        }
    }
}

impl SensorParams {
    pub fn validate(&self) -> Result<(), PlantError> {
        if !(self.encoder_counts_per_turn.is_finite() && self.encoder_counts_per_turn >= 1.0) {
            return Err(PlantError::invalid(
                "encoder_counts_per_turn",
                self.encoder_counts_per_turn,
                "must be at least 1",
            ));
        }
        if !(self.pressure_min.is_finite() && self.pressure_max.is_finite() && self.pressure_min < self.pressure_max) {
            return Err(PlantError::invalid(
                "pressure_max",
                self.pressure_max,
                "must be finite and above pressure_min",
            ));
        }
        if !(self.pressure_noise_std.is_finite() && self.pressure_noise_std >= 0.0) {
            return Err(PlantError::invalid(
                "pressure_noise_std",
                self.pressure_noise_std,
                "must be non-negative and finite",
            ));
        }
        Ok(())
    }

    pub fn encoder_step(&self) -> f64 {
        std::f64::consts::TAU / self.encoder_counts_per_turn
    }
}
