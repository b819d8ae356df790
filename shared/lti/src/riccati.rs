//! Continuous algebraic Riccati equations, `Aᵀ X + X A − X G X + Q = 0`,
//! by the matrix sign function of the Hamiltonian (Roberts; Byers' scaled
//! Newton iteration). It needs no ordered Schur form and stays accurate for
//! the few states of a loop-shaping design, whose shaped plants mix fast
//! valve modes with an integrator.

use nalgebra::DMatrix;

use crate::LtiError;

/// Newton steps before the sign iteration gives up; it converges
/// quadratically, in a dozen steps for a well-separated spectrum.
const SIGN_ITERATIONS: usize = 100;
/// Relative change of the iterate at which it has converged.
const SIGN_TOLERANCE: f64 = 1e-13;
/// Below this relative change, an iterate that stops shrinking has reached
/// the rounding floor.
const STAGNATION_TOLERANCE: f64 = 1e-8;
/// Newton–Kleinman steps after the sign function, each kept only while it
/// lowers the residual.
const REFINEMENT_STEPS: usize = 3;
/// A solution whose residual is larger than this, relative to the terms of
/// the equation, is refused: the Hamiltonian had eigenvalues too close to
/// the imaginary axis to split.
const RESIDUAL_TOLERANCE: f64 = 1e-6;

/// `sign(H)`: the matrix with the eigenvectors of `H` and eigenvalues ±1 by
/// the sign of their real parts. Newton's iteration `Z ← (c Z + Z⁻¹/c)/2`,
/// scaled by `c = |det Z|^(−1/n)` (computed from the LU factors' logarithms,
/// so that it neither overflows nor underflows).
pub(crate) fn matrix_sign(h: &DMatrix<f64>) -> Result<DMatrix<f64>, LtiError> {
    let n = h.nrows();
    if n == 0 || h.ncols() != n {
        return Err(LtiError::Dimension(format!(
            "sign of a {}x{} matrix",
            h.nrows(),
            h.ncols()
        )));
    }
    let mut z = h.clone();
    let mut previous_change = f64::INFINITY;
    for _ in 0..SIGN_ITERATIONS {
        let lu = z.clone().lu();
        let log_det: f64 = (0..n).map(|i| lu.u()[(i, i)].abs().ln()).sum();
        let inverse = lu
            .try_inverse()
            .filter(|m| m.iter().all(|v| v.is_finite()))
            .ok_or_else(|| LtiError::Riccati("the Hamiltonian has an eigenvalue on the imaginary axis".into()))?;
        let scale = (-log_det / n as f64).exp();
        let next = (&z * scale + inverse / scale) * 0.5;
        let change = (&next - &z).norm();
        z = next;
        // Converged, or at the rounding floor of an ill-conditioned H:
        // small and no longer shrinking (the residual check judges it).
        let relative = change / z.norm();
        if relative <= SIGN_TOLERANCE || (relative <= STAGNATION_TOLERANCE && change >= previous_change) {
            return Ok(z);
        }
        previous_change = change;
    }
    Err(LtiError::Riccati(format!(
        "the sign iteration did not converge in {SIGN_ITERATIONS} steps"
    )))
}

/// The stabilizing solution `X = Xᵀ` of `Aᵀ X + X A − X G X + Q = 0`
/// (`G`, `Q` symmetric): the one with `A − G X` stable. The stable
/// invariant subspace of `H = [A, −G; −Q, −Aᵀ]` is spanned by `[I; X]` and
/// is the null space of `sign(H) + I`, so `X` solves, in least squares,
/// `[W₁₂; W₂₂ + I] X = −[W₁₁ + I; W₂₁]`.
pub fn solve_care(a: &DMatrix<f64>, g: &DMatrix<f64>, q: &DMatrix<f64>) -> Result<DMatrix<f64>, LtiError> {
    let n = a.nrows();
    if a.ncols() != n || g.shape() != (n, n) || q.shape() != (n, n) {
        return Err(LtiError::Dimension(format!(
            "Riccati equation with A {:?}, G {:?}, Q {:?}",
            a.shape(),
            g.shape(),
            q.shape()
        )));
    }
    let mut hamiltonian = DMatrix::zeros(2 * n, 2 * n);
    hamiltonian.view_mut((0, 0), (n, n)).copy_from(a);
    hamiltonian.view_mut((0, n), (n, n)).copy_from(&(-g));
    hamiltonian.view_mut((n, 0), (n, n)).copy_from(&(-q));
    hamiltonian.view_mut((n, n), (n, n)).copy_from(&(-a.transpose()));
    let sign = matrix_sign(&hamiltonian)?;
    let identity = DMatrix::<f64>::identity(n, n);
    let mut lhs = DMatrix::zeros(2 * n, n);
    lhs.view_mut((0, 0), (n, n)).copy_from(&sign.view((0, n), (n, n)));
    lhs.view_mut((n, 0), (n, n))
        .copy_from(&(sign.view((n, n), (n, n)) + &identity));
    let mut rhs = DMatrix::zeros(2 * n, n);
    rhs.view_mut((0, 0), (n, n))
        .copy_from(&(-(sign.view((0, 0), (n, n)) + &identity)));
    rhs.view_mut((n, 0), (n, n)).copy_from(&(-sign.view((n, 0), (n, n))));
    let x = lhs
        .svd(true, true)
        .solve(&rhs, 1e-14)
        .map_err(|e| LtiError::Riccati(format!("the stable subspace is not a graph: {e}")))?;
    let mut x = (&x + x.transpose()) * 0.5;
    // The sign function's rounding grows with the Hamiltonian's condition;
    // Newton–Kleinman steps polish what it found.
    for _ in 0..REFINEMENT_STEPS {
        match newton_step(a, g, q, &x) {
            Some(next) if residual(a, g, q, &next) < residual(a, g, q, &x) => x = next,
            _ => break,
        }
    }
    let terms = [(a.transpose() * &x).norm(), (&x * g * &x).norm(), q.norm()];
    let scale = terms.iter().fold(f64::MIN_POSITIVE, |m, t| m.max(*t));
    let residual = residual(a, g, q, &x);
    if residual.is_nan() || residual > RESIDUAL_TOLERANCE * scale {
        return Err(LtiError::Riccati(format!(
            "the solution's residual is {:.1e} of the equation's terms",
            residual / scale
        )));
    }
    Ok(x)
}

fn residual(a: &DMatrix<f64>, g: &DMatrix<f64>, q: &DMatrix<f64>, x: &DMatrix<f64>) -> f64 {
    (a.transpose() * x + x * a - x * g * x + q).norm()
}

/// One Newton–Kleinman step: with `F = A − G X` stable, the next `X`
/// solves the Lyapunov equation `Fᵀ X' + X' F = −Q − X G X`.
fn newton_step(a: &DMatrix<f64>, g: &DMatrix<f64>, q: &DMatrix<f64>, x: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let closed = a - g * x;
    let next = solve_lyapunov(&closed, &(-(q + x * g * x)))?;
    Some((&next + next.transpose()) * 0.5)
}

/// `Fᵀ X + X F = R` by its Kronecker form, `(I ⊗ Fᵀ + Fᵀ ⊗ I) vec X = vec R`:
/// n² unknowns, a few hundred for a loop-shaping design.
fn solve_lyapunov(f: &DMatrix<f64>, r: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let n = f.nrows();
    let ft = f.transpose();
    let identity = DMatrix::<f64>::identity(n, n);
    let system = identity.kronecker(&ft) + ft.kronecker(&identity);
    let rhs = DMatrix::from_column_slice(n * n, 1, r.as_slice());
    let solution = system.lu().solve(&rhs)?;
    Some(DMatrix::from_column_slice(n, n, solution.as_slice()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sign_of_a_diagonalizable_matrix_flips_its_eigenvalues_to_one() {
        // Eigenvalues −3 and 2 under a similarity T.
        let t = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 3.0, 4.0]);
        let d = DMatrix::from_row_slice(2, 2, &[-3.0, 0.0, 0.0, 2.0]);
        let ti = t.clone().try_inverse().expect("invertible");
        let sign = matrix_sign(&(&t * d * &ti)).expect("sign");
        let expected = &t * DMatrix::from_row_slice(2, 2, &[-1.0, 0.0, 0.0, 1.0]) * &ti;
        assert!((sign - expected).norm() < 1e-12);
    }

    #[test]
    fn the_scalar_riccati_equation_has_its_closed_form_root() {
        // 2 a x − b² x² + c² = 0: x = (a + √(a² + b²c²)) / b².
        let (a, b, c) = (-3.0_f64, 2.0_f64, 5.0_f64);
        let x = solve_care(
            &DMatrix::from_element(1, 1, a),
            &DMatrix::from_element(1, 1, b * b),
            &DMatrix::from_element(1, 1, c * c),
        )
        .expect("care");
        let expected = (a + (a * a + b * b * c * c).sqrt()) / (b * b);
        assert!((x[(0, 0)] - expected).abs() < 1e-12, "{x} vs {expected}");
    }

    #[test]
    fn the_lqr_riccati_solution_of_a_double_integrator_is_known() {
        // A = [0 1; 0 0], B = [0; 1], Q = I, R = 1: X = [√3 1; 1 √3].
        let a = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]);
        let b = DMatrix::from_row_slice(2, 1, &[0.0, 1.0]);
        let x = solve_care(&a, &(&b * b.transpose()), &DMatrix::identity(2, 2)).expect("care");
        let s3 = 3.0_f64.sqrt();
        let expected = DMatrix::from_row_slice(2, 2, &[s3, 1.0, 1.0, s3]);
        assert!((x - expected).norm() < 1e-10);
    }

    #[test]
    fn an_eigenvalue_on_the_imaginary_axis_is_refused() {
        // A = 0, G = 0, Q = 0: the Hamiltonian is zero.
        let zero = DMatrix::zeros(1, 1);
        assert!(matches!(solve_care(&zero, &zero, &zero), Err(LtiError::Riccati(_))));
    }
}
