use hydractl_lti::{DiscreteSiso, StateSpace, TransferFunction};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::{require_non_negative, require_positive, ControlError};

/// Numerator of the crane paper's H∞ loop-shaping controller (its eq. 8),
/// c4…c0, descending powers of s.
pub const PAPER_HINF_NUM: [f64; 5] = [0.02579, 0.4043, 16.69, 222.7, 606.7];
/// Denominator of eq. (8), l5…l0.
pub const PAPER_HINF_DEN: [f64; 6] = [1.0, 4308.0, 8.373e5, 1.133e7, 3.854e7, 3.594e7];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HInfinityParams {
    /// Numerator and denominator of C(s), descending powers of s. Empty:
    /// the crane paper's eq. (8), designed for the crane, not this machine.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub num: Vec<f64>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub den: Vec<f64>,
    /// Or C(s) as a state space, `x' = A x + B e`, `u = C x` (rows of `A`):
    /// what `hydractl ident hinf` writes, better conditioned than the
    /// polynomials of a 7th-order controller. Used when given.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub a: Vec<Vec<f64>>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub b: Vec<f64>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub c: Vec<f64>,
    /// Multiplies the torque error (N·m) into the units the paper's
    /// controller was designed for. The paper's plant (its eq. 7) has a DC
    /// gain of 26 337 force units per unit current; dividing that by the
    /// rotator's DC gain in N·m per unit command keeps the paper's loop gain
    /// (`hydractl linearize` prints it; 33.7 for the default rotator, so
    /// `config/sim.toml` has 782).
    pub error_scale: f64,
    /// Output limit, valve command units.
    pub output_limit: f64,
    /// Where the feedforward added beside the controller (the friction
    /// compensation, the reference's rate) rolls off, rad/s; 0 passes it
    /// as it is. The design's weight rolls the controller off above its
    /// crossover to keep the encoder's noise off the valve; the
    /// feedforward, computed from the same differenced counts, carries
    /// that noise around the design unless it rolls off too.
    pub feedforward_roll_off_rad_s: f64,
    /// How the controller was designed, and for which plant model: what
    /// makes it a controller for this machine. None for the paper's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub design: Option<HInfinityDesign>,
}

/// The record of a loop-shaping design, as `hydractl ident hinf` wrote it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HInfinityDesign {
    /// The measurements the plant model was identified from.
    pub data: String,
    /// The plant model, N·m of torque per unit of the controller's own
    /// command, descending powers of s, and its fit on validation data, %.
    pub plant_num: Vec<f64>,
    pub plant_den: Vec<f64>,
    pub plant_fit_percent: f64,
    /// The shaping weight W₁ (the controller is W₁ K∞).
    pub weight_num: Vec<f64>,
    pub weight_den: Vec<f64>,
    /// The robustness the design reached and its optimum: the loop stays
    /// stable for normalized coprime-factor errors up to ε = 1/γ.
    pub gamma: f64,
    pub gamma_min: f64,
    /// The loop around the plant model: crossover and bandwidth (rad/s),
    /// phase margin (°), gain margin (dB, none when the phase never
    /// reaches −180°), peak sensitivity.
    pub crossover_rad_s: f64,
    pub bandwidth_rad_s: f64,
    pub phase_margin_deg: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gain_margin_db: Option<f64>,
    pub peak_sensitivity: f64,
}

impl HInfinityParams {
    /// C(s) as a continuous state space: the given one, else the
    /// polynomials', else the crane paper's.
    pub fn state_space(&self) -> Result<StateSpace, ControlError> {
        let invalid = |reason: String| ControlError::InvalidTable { name: "hinf", reason };
        if !self.a.is_empty() {
            let n = self.a.len();
            if self.a.iter().any(|row| row.len() != n) || self.b.len() != n || self.c.len() != n {
                return Err(invalid(format!(
                    "a must be {n} rows of {n}, b and c {n} long; got rows of {:?}, b {}, c {}",
                    self.a.iter().map(Vec::len).collect::<Vec<_>>(),
                    self.b.len(),
                    self.c.len()
                )));
            }
            return StateSpace::new(
                DMatrix::from_fn(n, n, |i, j| self.a[i][j]),
                DMatrix::from_column_slice(n, 1, &self.b),
                DMatrix::from_row_slice(1, n, &self.c),
                DMatrix::zeros(1, 1),
            )
            .map_err(|e| invalid(e.to_string()));
        }
        let (num, den) = if self.num.is_empty() && self.den.is_empty() {
            (PAPER_HINF_NUM.to_vec(), PAPER_HINF_DEN.to_vec())
        } else {
            (self.num.clone(), self.den.clone())
        };
        let transfer_function = TransferFunction::new(num, den)?;
        // Strictly proper, so the output is the state's alone and a bumpless
        // start can set it exactly.
        if transfer_function.num().len() >= transfer_function.den().len() {
            return Err(invalid(
                "the controller must be strictly proper (numerator degree below the denominator's)".into(),
            ));
        }
        Ok(transfer_function.to_state_space())
    }

    /// With a design: the loop closed around its plant model by the
    /// controller as it runs (its `error_scale` too) is stable. The config's
    /// validation calls it; a fallback variant needs it.
    pub fn check_design(&self) -> Result<(), ControlError> {
        let Some(design) = &self.design else {
            return Ok(());
        };
        let invalid = |reason: String| ControlError::InvalidTable {
            name: "hinf.design",
            reason,
        };
        let plant = TransferFunction::new(design.plant_num.clone(), design.plant_den.clone())?;
        if plant.num().len() >= plant.den().len() {
            return Err(invalid("plant_num must have fewer coefficients than plant_den".into()));
        }
        let mut controller = self.state_space()?;
        controller.b *= self.error_scale;
        let poles = plant
            .to_state_space()
            .negative_feedback_poles(&controller)
            .map_err(|e| invalid(e.to_string()))?;
        match poles.iter().find(|p| p.re >= 0.0) {
            Some(p) => Err(invalid(format!(
                "the loop of this controller (error_scale {}) around its own plant model is unstable (a pole at {:.3}{:+.3}i): the controller or its error_scale is not the one designed, or the design is wrong",
                self.error_scale, p.re, p.im
            ))),
            None => Ok(()),
        }
    }
}

impl Default for HInfinityParams {
    fn default() -> Self {
        Self {
            num: Vec::new(),
            den: Vec::new(),
            a: Vec::new(),
            b: Vec::new(),
            c: Vec::new(),
            error_scale: 782.0,
            output_limit: 1.0,
            feedforward_roll_off_rad_s: 0.0,
            design: None,
        }
    }
}

/// An H∞ loop-shaping torque controller (the crane paper's, or one designed
/// for this machine by `hydractl ident hinf`), realized as a discrete
/// state-space system by a zero-order hold at the loop rate. ZOH keeps the
/// paper's fast pole at −4104 rad/s stable at 1 kHz (e^{−4.1}), where a
/// forward-Euler realization would diverge.
#[derive(Debug, Clone)]
pub struct HInfinity {
    system: DiscreteSiso,
    error_scale: f64,
    output_limit: f64,
    output: f64,
}

impl HInfinity {
    pub fn new(params: HInfinityParams, ts: f64) -> Result<Self, ControlError> {
        require_positive("error_scale", params.error_scale)?;
        require_positive("output_limit", params.output_limit)?;
        require_non_negative("feedforward_roll_off_rad_s", params.feedforward_roll_off_rad_s)?;
        let system = DiscreteSiso::from_discrete_state_space(&params.state_space()?.discretize_zoh(ts)?)?;
        Ok(Self {
            system,
            error_scale: params.error_scale,
            output_limit: params.output_limit,
            output: 0.0,
        })
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
    fn a_negative_feedforward_roll_off_is_refused_by_name() {
        let params = HInfinityParams {
            feedforward_roll_off_rad_s: -300.0,
            ..HInfinityParams::default()
        };
        let error = HInfinity::new(params, 0.001).expect_err("refused").to_string();
        assert!(error.contains("feedforward_roll_off_rad_s"), "{error}");
    }

    #[test]
    fn bumpless_initialization() {
        let mut c = HInfinity::new(HInfinityParams::default(), 0.001).expect("valid");
        c.initialize_output(0.3);
        assert!((c.update(50.0) - 0.3).abs() < 1e-9);
    }

    #[test]
    fn paper_coefficients_are_the_default() {
        let c = HInfinityParams::default().state_space().expect("valid");
        assert_eq!(c.states(), 5);
        // DC gain c0 / l0.
        let dc = c.frequency_response(0.0).re;
        assert!((dc - 606.7 / 3.594e7).abs() < 1e-9 * dc, "{dc}");
    }
}
