//! H∞ loop-shaping design (McFarlane and Glover): the plant is shaped by a
//! weight `W₁` into the open loop one wants, and the controller `K∞` that
//! robustly stabilizes the shaped plant's normalized coprime factors is
//! found from two Riccati equations; the controller on the machine is
//! `K = W₁ K∞`. The achieved `γ` bounds how far the loop can move from the
//! shaped one and still be stable (`ε = 1/γ`, the coprime-factor
//! uncertainty it tolerates). The crane paper designed its force loop so.

mod margins;
#[cfg(test)]
mod tests;

use hydractl_lti::{solve_care, LtiError, StateSpace, TransferFunction};
use nalgebra::DMatrix;

use margins::loop_margins;
pub use margins::{coprime_robustness, LoopMargins};

#[derive(Debug, thiserror::Error)]
pub enum LoopShapingError {
    #[error(transparent)]
    Lti(#[from] LtiError),
    #[error("{0}")]
    Invalid(String),
}

/// The controller of a Glover–McFarlane design for a shaped plant.
#[derive(Debug, Clone)]
pub(crate) struct CoprimeDesign {
    /// `K∞`, for negative feedback on the error: `u = K∞ (r − y)`.
    pub controller: StateSpace,
    /// The optimum, `√(1 + ρ(X Z))`.
    pub gamma_min: f64,
    /// The `γ` the controller was built for (`gamma_factor × gamma_min`).
    pub gamma: f64,
}

/// `K∞` for the strictly proper SISO `shaped` plant at `γ = gamma_factor ×
/// γ_min` (`gamma_factor > 1`; 1.1 is the usual choice, a controller a
/// little short of the optimum and better conditioned). With `X` and `Z`
/// the stabilizing solutions of the control and filter Riccati equations
/// `AᵀX + XA − XBBᵀX + CᵀC = 0` and `AZ + ZAᵀ − ZCᵀCZ + BBᵀ = 0`,
/// `L = (1 − γ²) I + XZ` and (for positive feedback)
/// `K = [A − BBᵀX + γ² L⁻ᵀ Z CᵀC | γ² L⁻ᵀ Z Cᵀ ; BᵀX | 0]`
/// (Skogestad and Postlethwaite, eq. 9.66–9.70, with `D = 0`).
pub(crate) fn glover_mcfarlane(shaped: &StateSpace, gamma_factor: f64) -> Result<CoprimeDesign, LoopShapingError> {
    if shaped.b.ncols() != 1 || shaped.c.nrows() != 1 || shaped.d[(0, 0)] != 0.0 {
        return Err(LoopShapingError::Invalid(
            "the shaped plant must be SISO and strictly proper".into(),
        ));
    }
    if !(gamma_factor.is_finite() && gamma_factor > 1.0) {
        return Err(LoopShapingError::Invalid(format!(
            "gamma_factor must be above 1, got {gamma_factor}"
        )));
    }
    let (a, b, c) = (&shaped.a, &shaped.b, &shaped.c);
    let n = a.nrows();
    let bb = b * b.transpose();
    let cc = c.transpose() * c;
    let x = solve_care(a, &bb, &cc)?;
    let z = solve_care(&a.transpose(), &cc, &bb)?;
    let xz = &x * &z;
    let spectral_radius = xz.complex_eigenvalues().iter().fold(0.0_f64, |m, e| m.max(e.norm()));
    let gamma_min = (1.0 + spectral_radius).sqrt();
    let gamma = gamma_factor * gamma_min;
    let l = DMatrix::<f64>::identity(n, n) * (1.0 - gamma * gamma) + &xz;
    let l_transposed_inverse = l
        .transpose()
        .try_inverse()
        .ok_or_else(|| LoopShapingError::Invalid("(1 − γ²) I + XZ is singular".into()))?;
    let gain = &l_transposed_inverse * &z * c.transpose() * (gamma * gamma);
    let ak = a - &bb * &x + &gain * c;
    // Negative feedback: the positive-feedback controller's output negated.
    let ck = -(b.transpose() * &x);
    let controller = StateSpace::new(ak, gain, ck, DMatrix::zeros(1, 1))?;
    Ok(CoprimeDesign {
        controller,
        gamma_min,
        gamma,
    })
}

/// A weight's pole and a plant's zero (or the reverse) closer than this,
/// relative to their size, cancel in the shaped plant.
const CANCELLATION_TOLERANCE: f64 = 1e-6;

/// A design for the machine: its controller `K = W₁ K∞`, the weight, `γ`,
/// and how the loop closed around the plant model behaves.
#[derive(Debug, Clone)]
pub struct LoopShapingDesign {
    /// `K`, for negative feedback on the error, strictly proper.
    pub controller: StateSpace,
    pub weight: TransferFunction,
    pub gamma_min: f64,
    pub gamma: f64,
    /// The loop `P K` around the plant model.
    pub margins: LoopMargins,
}

/// The loop-shaping design of `plant` (strictly proper) with the weight
/// `weight` (proper).
pub fn design(
    plant: &TransferFunction,
    weight: &TransferFunction,
    gamma_factor: f64,
) -> Result<LoopShapingDesign, LoopShapingError> {
    if plant.num().len() >= plant.den().len() {
        return Err(LoopShapingError::Invalid(
            "the plant model must be strictly proper (fewer zeros than poles)".into(),
        ));
    }
    let plant_ss = plant.to_state_space();
    let weight_ss = weight.to_state_space();
    // Minimal: a weight that cancels some of the plant's poles and zeros
    // (`target_loop_weight` cancels them all) would leave modes neither
    // Riccati equation can move. Otherwise the series of the two
    // realizations, the plant's balanced: its companion form's
    // coefficients run from 1 to 10⁸.
    let product = TransferFunction::new(
        hydractl_lti::poly_mul(weight.num(), plant.num()),
        hydractl_lti::poly_mul(weight.den(), plant.den()),
    )?;
    let minimal = product.minimal(CANCELLATION_TOLERANCE);
    let shaped = if minimal.order() < product.order() {
        minimal.to_state_space().balanced()
    } else {
        weight_ss.series(&plant_ss.balanced())?
    };
    let coprime = glover_mcfarlane(&shaped, gamma_factor)?;
    let controller = coprime.controller.series(&weight_ss)?;
    let margins = loop_margins(&plant_ss, &controller)?;
    Ok(LoopShapingDesign {
        controller,
        weight: weight.clone(),
        gamma_min: coprime.gamma_min,
        gamma: coprime.gamma,
        margins,
    })
}

/// The weights of a torque loop: a PI, `k (s + ω_i) / s`, for integral
/// action below `ω_i`, and a roll-off `1 / (s/ω_r + 1)` for the sensor
/// noise above `ω_r`, with `k` such that the shaped loop `P W₁` crosses 1 at
/// `ω_c`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PiWeight {
    pub crossover_rad_s: f64,
    pub integral_corner_rad_s: f64,
    pub roll_off_rad_s: f64,
}

impl PiWeight {
    pub fn for_plant(&self, plant: &TransferFunction) -> Result<TransferFunction, LoopShapingError> {
        for (name, value) in [
            ("crossover", self.crossover_rad_s),
            ("integral corner", self.integral_corner_rad_s),
            ("roll-off", self.roll_off_rad_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(LoopShapingError::Invalid(format!(
                    "the weight's {name} must be a positive frequency, got {value}"
                )));
            }
        }
        let num = vec![1.0, self.integral_corner_rad_s];
        let den = vec![1.0 / self.roll_off_rad_s, 1.0, 0.0];
        let unscaled = TransferFunction::new(num.clone(), den.clone())?;
        let at_crossover =
            (unscaled.frequency_response(self.crossover_rad_s) * plant.frequency_response(self.crossover_rad_s)).norm();
        if !(at_crossover.is_finite() && at_crossover > 0.0) {
            return Err(LoopShapingError::Invalid(format!(
                "the plant has no finite, non-zero gain at the crossover {} rad/s",
                self.crossover_rad_s
            )));
        }
        let k = 1.0 / at_crossover;
        Ok(TransferFunction::new(num.iter().map(|c| c * k).collect(), den)?)
    }
}

/// The weight that makes the shaped plant a target loop, `W₁ = L_d / P`, as
/// MATLAB's `loopsyn` and the crane paper chose it. Only for a minimum-phase
/// plant (its zeros become the weight's poles) and a target whose relative
/// degree is at least the plant's, so that the weight is proper.
pub fn target_loop_weight(
    plant: &TransferFunction,
    target: &TransferFunction,
) -> Result<TransferFunction, LoopShapingError> {
    if let Some(zero) = plant.zeros().iter().find(|z| z.re >= 0.0) {
        return Err(LoopShapingError::Invalid(format!(
            "the plant has a zero at {:.3}{:+.3}i: inverting it would make the weight unstable",
            zero.re, zero.im
        )));
    }
    let num = hydractl_lti::poly_mul(target.num(), plant.den());
    let den = hydractl_lti::poly_mul(target.den(), plant.num());
    Ok(TransferFunction::new(num, den)?)
}
