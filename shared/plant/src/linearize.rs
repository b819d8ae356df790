//! Linear models of the rotator at an operating point.

use hydractl_lti::StateSpace;
use nalgebra::{DMatrix, SMatrix, SVector};

use crate::plant::{ANGLE, P_A, P_B, SPOOL, SPOOL_RATE, STATES, VELOCITY};
use crate::{Plant, PlantError, PlantParams, PlantState};

/// Outputs of the linear models, in this order.
pub const LINEAR_OUTPUTS: [&str; 5] = ["torque", "angle", "velocity", "p_a", "p_b"];
/// Index of the torque output.
pub const TORQUE_OUTPUT: usize = 0;
/// States of the linear models: spool, spool rate, p_a, p_b, angle, velocity.
pub const LINEAR_STATES: [&str; 6] = ["spool", "spool_rate", "p_a", "p_b", "angle", "velocity"];
const MAP: [usize; 6] = [SPOOL, SPOOL_RATE, P_A, P_B, ANGLE, VELOCITY];

/// The exact one-step map, z ← Φ z, of a map that is affine where it is
/// taken, ż = rates(z), its last coordinate the constant 1 and any input
/// held over the step a coordinate of rate zero: Φ = exp(G h), G's columns
/// by differences of `rates` about `reference` (exact for an affine map,
/// whatever each coordinate's `delta`), its last column the offset that
/// makes G z = rates(z). `reference`'s last coordinate must be 1.
pub fn affine_step<const M: usize>(
    rates: impl Fn(&SVector<f64, M>) -> SVector<f64, M>,
    reference: SVector<f64, M>,
    delta: impl Fn(usize) -> f64,
    h: f64,
) -> SMatrix<f64, M, M>
where
    nalgebra::Const<M>: nalgebra::DimMin<nalgebra::Const<M>, Output = nalgebra::Const<M>>,
{
    let at_reference = rates(&reference);
    let mut generator = SMatrix::<f64, M, M>::zeros();
    for i in 0..M - 1 {
        let mut moved = reference;
        moved[i] += delta(i);
        generator.set_column(i, &((rates(&moved) - at_reference) / delta(i)));
    }
    let offset = at_reference - generator * reference;
    generator.set_column(M - 1, &offset);
    (generator * h).exp()
}

/// The baseline's linear model, written from eqs. (7)–(10) and (5): with the
/// linearized flow the baseline is linear wherever the pressures are inside
/// their bounds, so this holds at any such operating point. Input: valve
/// command. Outputs: [`LINEAR_OUTPUTS`].
pub fn baseline_linear_model(p: &PlantParams) -> Result<StateSpace, PlantError> {
    p.validate()?;
    let wn = p.valve_natural_frequency;
    let ka = p.bulk_modulus / p.volume_a;
    let kb = p.bulk_modulus / p.volume_b;
    let kc2 = 2.0 * p.flow_pressure_coefficient;
    let kq2 = 2.0 * p.flow_gain;
    #[rustfmt::skip]
    let a = DMatrix::from_row_slice(6, 6, &[
        0.0, 1.0, 0.0, 0.0, 0.0, 0.0,
        -wn * wn, -2.0 * p.valve_damping * wn, 0.0, 0.0, 0.0, 0.0,
        ka * kq2, 0.0, -ka * (p.leakage + kc2), 0.0, 0.0, -ka * p.displacement,
        -kb * kq2, 0.0, 0.0, -kb * (p.leakage + kc2), 0.0, kb * p.displacement,
        0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        0.0, 0.0, p.displacement / p.inertia, -p.displacement / p.inertia, 0.0, -p.viscous_friction / p.inertia,
    ]);
    let b = DMatrix::from_row_slice(6, 1, &[0.0, wn * wn, 0.0, 0.0, 0.0, 0.0]);
    Ok(StateSpace::new(a, b, output_matrix(p), DMatrix::zeros(5, 1))?)
}

fn output_matrix(p: &PlantParams) -> DMatrix<f64> {
    #[rustfmt::skip]
    let c = DMatrix::from_row_slice(5, 6, &[
        0.0, 0.0, p.displacement, -p.displacement, 0.0, 0.0,
        0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
        0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        0.0, 0.0, 1.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, 1.0, 0.0, 0.0,
    ]);
    c
}

impl Plant {
    /// Linearizes the nonlinear plant (with its effects, friction taken as
    /// sliding in the direction of `state.velocity`) by central finite
    /// differences at `state` and valve command `command`. The load states of
    /// `load_flexibility` are held at the actuator's.
    pub fn linearize(&self, state: &PlantState, command: f64) -> Result<StateSpace, PlantError> {
        let x0 = state.to_array();
        let direction = state.velocity.signum();
        let f = |x: &[f64; STATES], u: f64| self.derivative(x, u, direction);
        let mut a = DMatrix::zeros(6, 6);
        let mut b = DMatrix::zeros(6, 1);
        for (col, &j) in MAP.iter().enumerate() {
            let h = perturbation(x0[j]);
            let mut plus = x0;
            let mut minus = x0;
            plus[j] += h;
            minus[j] -= h;
            let fp = f(&plus, command);
            let fm = f(&minus, command);
            for (row, &i) in MAP.iter().enumerate() {
                a[(row, col)] = (fp[i] - fm[i]) / (2.0 * h);
            }
        }
        let h = 1e-6;
        let fp = f(&x0, command + h);
        let fm = f(&x0, command - h);
        for (row, &i) in MAP.iter().enumerate() {
            b[(row, 0)] = (fp[i] - fm[i]) / (2.0 * h);
        }
        Ok(StateSpace::new(
            a,
            b,
            output_matrix(self.params()),
            DMatrix::zeros(5, 1),
        )?)
    }
}

fn perturbation(value: f64) -> f64 {
    1e-6 * value.abs().max(1.0)
}
