use hydractl_lti::{DiscreteSiso, TransferFunction};
use serde::{Deserialize, Serialize};

use crate::{require_positive, ControlError};

/// Numerator of the crane paper's H∞ loop-shaping controller (its eq. 8),
/// c4…c0, descending powers of s.
pub const PAPER_HINF_NUM: [f64; 5] = [0.02579, 0.4043, 16.69, 222.7, 606.7];
/// Denominator of eq. (8), l5…l0.
pub const PAPER_HINF_DEN: [f64; 6] = [1.0, 4308.0, 8.373e5, 1.133e7, 3.854e7, 3.594e7];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HInfinityParams {
    /// Numerator and denominator of C(s), descending powers of s. Defaults:
    /// the crane paper's eq. (8).
    pub num: Vec<f64>,
    pub den: Vec<f64>,
    /// Multiplies the torque error (N·m) into the units the paper's
    /// controller was designed for. The paper's plant (its eq. 7) has a DC
    /// gain of 26 337 force units per unit current; dividing that by the
    /// rotator's DC gain in N·m per unit command keeps the paper's loop gain
    /// (`hydractl linearize` prints it; 33.7 for the default rotator, so
    /// `config/sim.toml` has 782).
    pub error_scale: f64,
    /// Output limit, valve command units.
    pub output_limit: f64,
}

impl Default for HInfinityParams {
    fn default() -> Self {
        Self {
            num: PAPER_HINF_NUM.to_vec(),
            den: PAPER_HINF_DEN.to_vec(),
            error_scale: 782.0,
            output_limit: 1.0,
        }
    }
}

/// The H∞ loop-shaping torque controller of the crane paper, realized as a
/// discrete state-space system by a zero-order hold at the loop rate. ZOH
/// keeps the fast pole at −4104 rad/s stable at 1 kHz (e^{−4.1}), where a
/// forward-Euler realization would diverge.
#[derive(Debug, Clone)]
pub struct HInfinity {
    system: DiscreteSiso,
    transfer_function: TransferFunction,
    error_scale: f64,
    output_limit: f64,
    output: f64,
}

impl HInfinity {
    pub fn new(params: HInfinityParams, ts: f64) -> Result<Self, ControlError> {
        require_positive("error_scale", params.error_scale)?;
        require_positive("output_limit", params.output_limit)?;
        let transfer_function = TransferFunction::new(params.num, params.den)?;
        // Strictly proper, so the output is the state's alone and a bumpless
        // start can set it exactly.
        if transfer_function.num().len() >= transfer_function.den().len() {
            return Err(ControlError::InvalidTable {
                name: "hinf",
                reason: "the controller must be strictly proper (numerator degree below the denominator's)".into(),
            });
        }
        let system = DiscreteSiso::from_transfer_function_zoh(&transfer_function, ts)?;
        Ok(Self {
            system,
            transfer_function,
            error_scale: params.error_scale,
            output_limit: params.output_limit,
            output: 0.0,
        })
    }

    pub fn transfer_function(&self) -> &TransferFunction {
        &self.transfer_function
    }

    pub fn reset(&mut self) {
        self.system.reset();
        self.output = 0.0;
    }

    /// One period: the valve command for torque error `error` (N·m). A
    /// non-finite error holds the last output and spares the state.
    pub fn update(&mut self, error: f64) -> f64 {
        if !error.is_finite() {
            return self.output;
        }
        self.output = self
            .system
            .step(self.error_scale * error)
            .clamp(-self.output_limit, self.output_limit);
        self.output
    }

    /// The unclamped output for a scaled error, for frequency-response tests.
    pub fn raw_step(&mut self, scaled_error: f64) -> f64 {
        self.system.step(scaled_error)
    }

    /// Bumpless start: the state that gives `output` next, whatever the error
    /// (the controller is strictly proper, so the output is the state's).
    pub fn initialize_output(&mut self, output: f64) {
        self.system.initialize_output(output);
        self.output = output;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bumpless_initialization() {
        let mut c = HInfinity::new(HInfinityParams::default(), 0.001).expect("valid");
        c.initialize_output(0.3);
        assert!((c.update(50.0) - 0.3).abs() < 1e-9);
    }

    #[test]
    fn paper_coefficients_are_the_default() {
        let c = HInfinity::new(HInfinityParams::default(), 0.001).expect("valid");
        assert_eq!(c.transfer_function().den().len(), 6);
        // DC gain c0 / l0.
        assert!((c.transfer_function().dc_gain() - 606.7 / 3.594e7).abs() < 1e-12);
    }
}
