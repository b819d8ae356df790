use nalgebra::{Complex, DMatrix};

use crate::{poly_from_roots, LtiError, TransferFunction};

/// A continuous-time (or, after [`StateSpace::discretize_zoh`], discrete-time)
/// linear system `x' = A x + B u`, `y = C x + D u`.
#[derive(Debug, Clone, PartialEq)]
pub struct StateSpace {
    pub a: DMatrix<f64>,
    pub b: DMatrix<f64>,
    pub c: DMatrix<f64>,
    pub d: DMatrix<f64>,
}

impl StateSpace {
    pub fn new(a: DMatrix<f64>, b: DMatrix<f64>, c: DMatrix<f64>, d: DMatrix<f64>) -> Result<Self, LtiError> {
        let n = a.nrows();
        if a.ncols() != n || b.nrows() != n || c.ncols() != n || d.nrows() != c.nrows() || d.ncols() != b.ncols() {
            return Err(LtiError::Dimension(format!(
                "A {}x{}, B {}x{}, C {}x{}, D {}x{}",
                a.nrows(),
                a.ncols(),
                b.nrows(),
                b.ncols(),
                c.nrows(),
                c.ncols(),
                d.nrows(),
                d.ncols()
            )));
        }
        if [&a, &b, &c, &d].iter().any(|m| m.iter().any(|v| !v.is_finite())) {
            return Err(LtiError::NotFinite);
        }
        Ok(Self { a, b, c, d })
    }

    pub fn states(&self) -> usize {
        self.a.nrows()
    }

    pub fn poles(&self) -> Vec<Complex<f64>> {
        eigenvalues(&self.a)
    }

    /// The minimal SISO transfer function from `input` to `output`, using the
    /// matrix determinant lemma, `C (sI - A)^-1 B = det(sI - A + BC) / det(sI - A) - 1`,
    /// then cancelling the pole-zero pairs of modes this input does not reach
    /// or this output does not see.
    pub fn transfer_function(&self, input: usize, output: usize) -> Result<TransferFunction, LtiError> {
        if input >= self.b.ncols() || output >= self.c.nrows() {
            return Err(LtiError::Dimension(format!(
                "input {input} of {}, output {output} of {}",
                self.b.ncols(),
                self.c.nrows()
            )));
        }
        let b = self.b.column(input).into_owned();
        let c = self.c.row(output).into_owned();
        let den = poly_from_roots(&eigenvalues(&self.a));
        let closed = &self.a - &b * &c;
        let shifted = poly_from_roots(&eigenvalues(&closed));
        let feedthrough = self.d[(output, input)];
        let num: Vec<f64> = shifted.iter().zip(&den).map(|(p, q)| p - q + feedthrough * q).collect();
        Ok(TransferFunction::new(trim_leading_negligible(&num, &shifted, &den), den)?.minimal(1e-6))
    }

    /// Zero-order-hold discretization at sample time `ts`, by the matrix
    /// exponential of the augmented matrix `[[A, B], [0, 0]] ts`.
    pub fn discretize_zoh(&self, ts: f64) -> Result<StateSpace, LtiError> {
        if !(ts.is_finite() && ts > 0.0) {
            return Err(LtiError::InvalidSampleTime(ts));
        }
        let n = self.states();
        let m = self.b.ncols();
        let mut augmented = DMatrix::zeros(n + m, n + m);
        augmented.view_mut((0, 0), (n, n)).copy_from(&(&self.a * ts));
        augmented.view_mut((0, n), (n, m)).copy_from(&(&self.b * ts));
        let exp = augmented.exp();
        let a = exp.view((0, 0), (n, n)).into_owned();
        let b = exp.view((0, n), (n, m)).into_owned();
        StateSpace::new(a, b, self.c.clone(), self.d.clone())
    }

    /// Simulates a continuous system's response to a unit step on `input`,
    /// exactly at the sample instants `k ts` (ZOH of a constant is exact).
    pub fn step_response(&self, input: usize, output: usize, ts: f64, samples: usize) -> Result<Vec<f64>, LtiError> {
        let discrete = self.discretize_zoh(ts)?;
        let mut x = nalgebra::DVector::zeros(self.states());
        let b = discrete.b.column(input).into_owned();
        let c = discrete.c.row(output).into_owned();
        let d = discrete.d[(output, input)];
        let mut y = Vec::with_capacity(samples);
        for _ in 0..samples {
            y.push((&c * &x)[(0, 0)] + d);
            x = &discrete.a * x + &b;
        }
        Ok(y)
    }
}

/// Drops leading numerator coefficients that are rounding noise: each is a
/// difference of two characteristic-polynomial coefficients, so it is noise
/// when it is tiny next to them. A strictly proper system stays strictly proper.
fn trim_leading_negligible(num: &[f64], shifted: &[f64], den: &[f64]) -> Vec<f64> {
    let first = (0..num.len()).find(|&i| {
        let scale = shifted[i].abs().max(den[i].abs());
        num[i].abs() > 1e-9 * scale
    });
    match first {
        Some(i) => num[i..].to_vec(),
        None => vec![0.0],
    }
}

/// Eigenvalues after diagonal balancing, which matters here: a hydraulic
/// state mixes pascals (1e7) with radians (1), and unbalanced QR loses the
/// small eigenvalues.
pub(crate) fn eigenvalues(a: &DMatrix<f64>) -> Vec<Complex<f64>> {
    let balanced = balance(a);
    balanced.complex_eigenvalues().iter().copied().collect()
}

/// Parlett–Reinsch balancing by powers of two: a similarity transform, so
/// the eigenvalues are unchanged while the row and column norms even out.
fn balance(a: &DMatrix<f64>) -> DMatrix<f64> {
    let n = a.nrows();
    let mut m = a.clone();
    let radix = 2.0_f64;
    let mut converged = false;
    let mut sweeps = 0;
    while !converged && sweeps < 100 {
        converged = true;
        sweeps += 1;
        for i in 0..n {
            let mut column = 0.0;
            let mut row = 0.0;
            for j in 0..n {
                if j != i {
                    column += m[(j, i)].abs();
                    row += m[(i, j)].abs();
                }
            }
            if column == 0.0 || row == 0.0 {
                continue;
            }
            let sum = column + row;
            let mut f = 1.0;
            let mut c = column;
            let mut r = row;
            while c < r / radix {
                c *= radix;
                r /= radix;
                f *= radix;
            }
            while c >= r * radix {
                c /= radix;
                r *= radix;
                f /= radix;
            }
            if (c + r) < 0.95 * sum {
                converged = false;
                for j in 0..n {
                    m[(i, j)] /= f;
                    m[(j, i)] *= f;
                }
            }
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mass_spring_damper() -> StateSpace {
        // x'' + 2 x' + 5 x = u, y = x: G(s) = 1 / (s^2 + 2 s + 5).
        StateSpace::new(
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -5.0, -2.0]),
            DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
            DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            DMatrix::zeros(1, 1),
        )
        .expect("valid")
    }

    #[test]
    fn transfer_function_of_mass_spring_damper() {
        let tf = mass_spring_damper().transfer_function(0, 0).expect("tf");
        assert_eq!(tf.num().len(), 1);
        assert!((tf.num()[0] - 1.0).abs() < 1e-9);
        for (a, b) in tf.den().iter().zip([1.0, 2.0, 5.0]) {
            assert!((a - b).abs() < 1e-9);
        }
    }

    #[test]
    fn balanced_eigenvalues_survive_bad_scaling() {
        // Same system with the state scaled by 1e7: eigenvalues -1 ± 2j.
        let s = 1e7;
        let a = DMatrix::from_row_slice(2, 2, &[0.0, s, -5.0 / s, -2.0]);
        let mut ev = eigenvalues(&a);
        ev.sort_by(|x, y| x.im.total_cmp(&y.im));
        assert!((ev[0] - Complex::new(-1.0, -2.0)).norm() < 1e-6);
        assert!((ev[1] - Complex::new(-1.0, 2.0)).norm() < 1e-6);
    }

    #[test]
    fn zoh_of_integrator_is_exact() {
        let ss = StateSpace::new(
            DMatrix::zeros(1, 1),
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::zeros(1, 1),
        )
        .expect("valid");
        let d = ss.discretize_zoh(0.1).expect("zoh");
        assert!((d.a[(0, 0)] - 1.0).abs() < 1e-12);
        assert!((d.b[(0, 0)] - 0.1).abs() < 1e-12);
    }
}
