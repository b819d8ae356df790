use serde::{Deserialize, Serialize};

use crate::{require_finite, require_non_negative, require_positive, ControlError};

/// A static map by linear interpolation between points with strictly
/// increasing abscissae; held constant beyond the ends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StaticMap {
    pub velocity: Vec<f64>,
    pub output: Vec<f64>,
}

impl StaticMap {
    pub fn validate(&self, name: &'static str) -> Result<(), ControlError> {
        let fail = |reason: String| Err(ControlError::InvalidTable { name, reason });
        if self.velocity.len() != self.output.len() {
            return fail(format!(
                "`velocity` has {} points but `output` has {}",
                self.velocity.len(),
                self.output.len()
            ));
        }
        if self.velocity.len() < 2 {
            return fail("needs at least two points".into());
        }
        if let Some(i) = self.velocity.iter().chain(&self.output).position(|v| !v.is_finite()) {
            return fail(format!("point {i} is not finite"));
        }
        if let Some(i) = self.velocity.windows(2).position(|w| w[1] <= w[0]) {
            return fail(format!(
                "`velocity` must increase strictly; point {} ({}) is not above point {i} ({})",
                i + 1,
                self.velocity[i + 1],
                self.velocity[i]
            ));
        }
        Ok(())
    }

    /// A straight line through the origin, `output = slope * velocity`, over ±`span`.
    pub fn linear(slope: f64, span: f64) -> Self {
        Self {
            velocity: vec![-span, span],
            output: vec![-slope * span, slope * span],
        }
    }

    /// The map at `velocity`; a non-finite velocity reads as standing still.
    pub fn eval(&self, velocity: f64) -> f64 {
        let velocity = if velocity.is_finite() { velocity } else { 0.0 };
        let v = &self.velocity;
        let n = v.len();
        if velocity <= v[0] {
            return self.output[0];
        }
        if velocity >= v[n - 1] {
            return self.output[n - 1];
        }
        let upper = v.partition_point(|&x| x <= velocity).min(n - 1);
        let lower = upper - 1;
        let fraction = (velocity - v[lower]) / (v[upper] - v[lower]);
        self.output[lower] + fraction * (self.output[upper] - self.output[lower])
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrictionCompensatorParams {
    /// Half-width of the bell α(ṙ), rad/s: α(0) = 1 and α(±width) = 0.01.
    /// The crane paper: "smoothly drops to zero outside [-0.1, 0.1] rad/s".
    #[serde(default = "default_alpha_width")]
    pub alpha_width: f64,
    /// μ of eq. (1), rad/s: the push in the valve current's direction when
    /// the link rests. The crane paper: "a small value, such as 0.001".
    #[serde(default = "default_mu")]
    pub mu: f64,
    /// The static pseudo-friction map, velocity (rad/s) → compensation, in
    /// valve command: added to the outer loop's output in position-only
    /// control, to the torque loop's in the cascade (the rotary paper's
    /// "PID with friction compensation").
    pub map: StaticMap,
    /// What the load takes, answered ahead of the outer loop.
    #[serde(default)]
    pub load: LoadFeedforward,
}

/// The torque the load takes, answered ahead of the loop rather than by
/// its integrator: the Coulomb friction, gravity load and constant load a
/// fitted model found (`hydractl model compensate`). In the units of the
/// outer loop's output: N·m of torque reference in the cascade, where the
/// torque loop then makes it, and valve command in position-only control.
/// Zero: none.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoadFeedforward {
    /// The Coulomb level, pushed in the blended velocity's direction
    /// (eq. 1's `v`): `coulomb · clamp(v / coulomb_band, −1, 1)`.
    pub coulomb: f64,
    /// rad/s. Below it the push fades to zero: at rest the blended velocity
    /// is μ in the valve's direction, and a full push there would rock a
    /// resting load from side to side.
    pub coulomb_band: f64,
    /// Gravity: `gravity_amplitude · sin(θ − gravity_offset)` at the
    /// measured angle θ (rad), as the plant's `gravity_load` writes it.
    pub gravity_amplitude: f64,
    pub gravity_offset: f64,
    /// A constant load against positive rotation (the plant's
    /// `load_torque`: a hose's drag, a load's mean).
    pub constant: f64,
}

impl Default for LoadFeedforward {
    fn default() -> Self {
        Self {
            coulomb: 0.0,
            coulomb_band: 0.01,
            gravity_amplitude: 0.0,
            gravity_offset: 0.0,
            constant: 0.0,
        }
    }
}

impl LoadFeedforward {
    fn validate(&self) -> Result<(), ControlError> {
        require_non_negative("load.coulomb", self.coulomb)?;
        require_positive("load.coulomb_band", self.coulomb_band)?;
        require_finite("load.gravity_amplitude", self.gravity_amplitude)?;
        require_finite("load.gravity_offset", self.gravity_offset)?;
        require_finite("load.constant", self.constant)
    }

    /// The feed-forward at the blended velocity and the measured angle; an
    /// angle the sensors flagged (not finite) leaves gravity out.
    pub fn eval(&self, blended_velocity: f64, angle: f64) -> f64 {
        let coulomb = if blended_velocity.is_finite() {
            self.coulomb * (blended_velocity / self.coulomb_band).clamp(-1.0, 1.0)
        } else {
            0.0
        };
        let gravity = if angle.is_finite() && self.gravity_amplitude != 0.0 {
            self.gravity_amplitude * (angle - self.gravity_offset).sin()
        } else {
            0.0
        };
        coulomb + gravity + self.constant
    }
}

fn default_alpha_width() -> f64 {
    0.1
}

fn default_mu() -> f64 {
    0.001
}

/// The crane paper's friction compensation (its eq. 1): the map evaluated
/// at a blended velocity
/// `v = (1 − α(ṙ)) θ̇ + α(ṙ) ṙ + μ sign(i)`,
/// which trusts the smooth reference velocity near zero, where the measured
/// velocity is noise, and uses the valve current's direction when at rest.
#[derive(Debug, Clone)]
pub struct FrictionCompensator {
    params: FrictionCompensatorParams,
    /// α(ṙ) = exp(−(ṙ/σ)²) with σ set so that α(alpha_width) = 0.01.
    inverse_sigma_squared: f64,
    blended_velocity: f64,
}

impl FrictionCompensator {
    pub fn new(params: FrictionCompensatorParams) -> Result<Self, ControlError> {
        require_positive("alpha_width", params.alpha_width)?;
        require_non_negative("mu", params.mu)?;
        params.map.validate("friction compensation map")?;
        params.load.validate()?;
        let sigma_squared = params.alpha_width.powi(2) / 100.0_f64.ln();
        Ok(Self {
            params,
            inverse_sigma_squared: 1.0 / sigma_squared,
            blended_velocity: 0.0,
        })
    }

    pub fn alpha(&self, reference_velocity: f64) -> f64 {
        (-reference_velocity * reference_velocity * self.inverse_sigma_squared).exp()
    }

    /// The compensation for the measured velocity estimate, the reference
    /// velocity and the valve current's last value.
    pub fn update(&mut self, velocity_estimate: f64, reference_velocity: f64, valve_current: f64) -> f64 {
        let alpha = self.alpha(reference_velocity);
        let direction = if valve_current > 0.0 {
            1.0
        } else if valve_current < 0.0 {
            -1.0
        } else {
            0.0
        };
        self.blended_velocity =
            (1.0 - alpha) * velocity_estimate + alpha * reference_velocity + self.params.mu * direction;
        self.params.map.eval(self.blended_velocity)
    }

    pub fn blended_velocity(&self) -> f64 {
        self.blended_velocity
    }

    /// The load's feed-forward (outer-loop units) at the last update's
    /// blended velocity and the measured `angle`.
    pub fn load_feedforward(&self, angle: f64) -> f64 {
        self.params.load.eval(self.blended_velocity, angle)
    }

    pub fn reset(&mut self) {
        self.blended_velocity = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map() -> StaticMap {
        StaticMap {
            velocity: vec![-1.0, -0.001, 0.0, 0.001, 1.0],
            output: vec![-0.5, -0.1, 0.0, 0.1, 0.5],
        }
    }

    #[test]
    fn map_interpolates_and_holds_at_the_ends() {
        let m = map();
        assert!((m.eval(0.5) - (0.1 + 0.4 * (0.5 - 0.001) / 0.999)).abs() < 1e-12);
        assert_eq!(m.eval(5.0), 0.5);
        assert_eq!(m.eval(-5.0), -0.5);
        assert_eq!(m.eval(0.0), 0.0);
        assert_eq!(m.eval(f64::NAN), 0.0);
    }

    #[test]
    fn map_validation_names_the_problem() {
        let bad = StaticMap {
            velocity: vec![0.0, 0.0],
            output: vec![1.0, 2.0],
        };
        let err = bad.validate("map").expect_err("not increasing");
        assert!(err.to_string().contains("increase strictly"));
        let bad = StaticMap {
            velocity: vec![0.0, 1.0],
            output: vec![1.0],
        };
        assert!(bad.validate("map").is_err());
    }

    #[test]
    fn alpha_is_a_bell_of_the_papers_width() {
        let c = FrictionCompensator::new(FrictionCompensatorParams {
            alpha_width: 0.1,
            mu: 0.001,
            map: map(),
            load: LoadFeedforward::default(),
        })
        .expect("valid");
        assert_eq!(c.alpha(0.0), 1.0);
        assert!((c.alpha(0.1) - 0.01).abs() < 1e-12);
        assert!((c.alpha(-0.1) - 0.01).abs() < 1e-12);
        assert!(c.alpha(0.2) < 1e-7);
    }

    #[test]
    fn equation_one_blends_as_the_paper_writes_it() {
        let mut c = FrictionCompensator::new(FrictionCompensatorParams {
            alpha_width: 0.1,
            mu: 0.001,
            map: map(),
            load: LoadFeedforward::default(),
        })
        .expect("valid");
        // At rest with a positive valve current: v = 0 + 0 + μ = 0.001 → 0.1.
        assert!((c.update(0.0, 0.0, 0.3) - 0.1).abs() < 1e-12);
        assert!((c.blended_velocity() - 0.001).abs() < 1e-15);
        // Noisy measured velocity at a resting reference is ignored.
        c.update(0.4, 0.0, 0.0);
        assert!(c.blended_velocity().abs() < 1e-15);
        // Far from zero reference velocity, the measurement is used.
        c.update(0.8, 0.5, 0.0);
        assert!((c.blended_velocity() - 0.8).abs() < 1e-9);
        // Reference computation in between.
        let r = 0.05;
        let alpha = c.alpha(r);
        c.update(0.2, r, -1.0);
        assert!((c.blended_velocity() - ((1.0 - alpha) * 0.2 + alpha * r - 0.001)).abs() < 1e-15);
    }

    #[test]
    fn the_load_feedforward_pushes_with_the_motion_and_holds_against_gravity() {
        let load = LoadFeedforward {
            coulomb: 40.0,
            coulomb_band: 0.01,
            gravity_amplitude: 300.0,
            gravity_offset: 0.2,
            constant: 0.0,
        };
        let mut c = FrictionCompensator::new(FrictionCompensatorParams {
            alpha_width: 0.1,
            mu: 0.001,
            map: map(),
            load,
        })
        .expect("valid");
        // Moving with the reference: the whole Coulomb level.
        c.update(0.5, 0.5, 0.2);
        assert!((c.load_feedforward(0.2) - 40.0).abs() < 1e-9);
        c.update(-0.5, -0.5, 0.2);
        assert!((c.load_feedforward(0.2) + 40.0).abs() < 1e-9);
        // At rest the valve's direction is only μ: a tenth of the level.
        c.update(0.0, 0.0, 0.3);
        assert!((c.load_feedforward(0.2) - 4.0).abs() < 1e-9);
        // Gravity at the angle, as the plant's gravity load.
        let gravity = 300.0 * (1.0_f64 - 0.2).sin();
        assert!((c.load_feedforward(1.0) - 4.0 - gravity).abs() < 1e-9);
        assert!(
            (c.load_feedforward(f64::NAN) - 4.0).abs() < 1e-9,
            "a flagged angle: no gravity"
        );
        let bad = LoadFeedforward {
            coulomb_band: 0.0,
            ..load
        };
        assert!(bad.validate().is_err());
        // A constant load adds itself, whatever the motion.
        let constant = LoadFeedforward {
            constant: -12.0,
            ..load
        };
        assert!((constant.eval(0.5, 1.0) - load.eval(0.5, 1.0) + 12.0).abs() < 1e-12);
        assert!(LoadFeedforward {
            constant: f64::NAN,
            ..load
        }
        .validate()
        .is_err());
    }
}
