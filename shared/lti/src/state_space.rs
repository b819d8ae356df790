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

    /// The system whose input drives `self` and whose output is `then`'s:
    /// `then ∘ self`, states `[x_self; x_then]`.
    pub fn series(&self, then: &StateSpace) -> Result<StateSpace, LtiError> {
        if self.c.nrows() != then.b.ncols() {
            return Err(LtiError::Dimension(format!(
                "{} outputs into {} inputs",
                self.c.nrows(),
                then.b.ncols()
            )));
        }
        let (n1, n2) = (self.states(), then.states());
        let mut a = DMatrix::zeros(n1 + n2, n1 + n2);
        a.view_mut((0, 0), (n1, n1)).copy_from(&self.a);
        a.view_mut((n1, 0), (n2, n1)).copy_from(&(&then.b * &self.c));
        a.view_mut((n1, n1), (n2, n2)).copy_from(&then.a);
        let mut b = DMatrix::zeros(n1 + n2, self.b.ncols());
        b.view_mut((0, 0), (n1, self.b.ncols())).copy_from(&self.b);
        b.view_mut((n1, 0), (n2, self.b.ncols()))
            .copy_from(&(&then.b * &self.d));
        let mut c = DMatrix::zeros(then.c.nrows(), n1 + n2);
        c.view_mut((0, 0), (then.c.nrows(), n1)).copy_from(&(&then.d * &self.c));
        c.view_mut((0, n1), (then.c.nrows(), n2)).copy_from(&then.c);
        StateSpace::new(a, b, c, &then.d * &self.d)
    }

    /// `C (jω I − A)⁻¹ B + D` from the first input to the first output.
    pub fn frequency_response(&self, omega: f64) -> Complex<f64> {
        let n = self.states();
        let d = Complex::new(self.d[(0, 0)], 0.0);
        if n == 0 {
            return d;
        }
        let shifted = DMatrix::from_fn(n, n, |i, j| {
            let diagonal = if i == j {
                Complex::new(0.0, omega)
            } else {
                Complex::new(0.0, 0.0)
            };
            diagonal - Complex::new(self.a[(i, j)], 0.0)
        });
        let b = DMatrix::from_fn(n, 1, |i, _| Complex::new(self.b[(i, 0)], 0.0));
        match shifted.lu().solve(&b) {
            Some(x) => (0..n).map(|i| x[(i, 0)] * self.c[(0, i)]).sum::<Complex<f64>>() + d,
            // ω is a pole on the axis: the response is unbounded there.
            None => Complex::new(f64::INFINITY, 0.0),
        }
    }

    /// The poles of the SISO loop closed around this plant (no feedthrough)
    /// by `controller` on the error, `u = K (r − y)`.
    pub fn negative_feedback_poles(&self, controller: &StateSpace) -> Result<Vec<Complex<f64>>, LtiError> {
        if self.d.iter().any(|v| *v != 0.0) || self.b.ncols() != 1 || controller.b.ncols() != 1 {
            return Err(LtiError::Dimension(
                "a SISO plant without feedthrough and a SISO controller".into(),
            ));
        }
        let (np, nk) = (self.states(), controller.states());
        let mut a = DMatrix::zeros(np + nk, np + nk);
        let dk = controller.d[(0, 0)];
        a.view_mut((0, 0), (np, np))
            .copy_from(&(&self.a - &self.b * &self.c * dk));
        a.view_mut((0, np), (np, nk)).copy_from(&(&self.b * &controller.c));
        a.view_mut((np, 0), (nk, np)).copy_from(&(-(&controller.b * &self.c)));
        a.view_mut((np, np), (nk, nk)).copy_from(&controller.a);
        Ok(eigenvalues(&a))
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
    let (balanced, _) = balance(a);
    balanced.complex_eigenvalues().iter().copied().collect()
}

impl StateSpace {
    /// The same system in states scaled so that `A`'s rows and columns have
    /// even norms (`A' = D⁻¹ A D`, `B' = D⁻¹ B`, `C' = C D`): the companion
    /// form of a transfer function with coefficients from 1 to 10⁸ is too
    /// uneven for a Riccati solver.
    pub fn balanced(&self) -> StateSpace {
        let (a, scale) = balance(&self.a);
        let mut b = self.b.clone();
        let mut c = self.c.clone();
        for (i, f) in scale.iter().enumerate() {
            b.row_mut(i).iter_mut().for_each(|v| *v /= f);
            c.column_mut(i).iter_mut().for_each(|v| *v *= f);
        }
        StateSpace {
            a,
            b,
            c,
            d: self.d.clone(),
        }
    }
}

/// Parlett–Reinsch balancing by powers of two: a similarity transform
/// `D⁻¹ A D`, so the eigenvalues are unchanged while the row and column
/// norms even out. Returns the balanced matrix and `D`'s diagonal.
fn balance(a: &DMatrix<f64>) -> (DMatrix<f64>, Vec<f64>) {
    let n = a.nrows();
    let mut m = a.clone();
    let mut scale = vec![1.0; n];
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
                scale[i] *= f;
                for j in 0..n {
                    m[(i, j)] /= f;
                    m[(j, i)] *= f;
                }
            }
        }
    }
    (m, scale)
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
    fn a_series_connection_multiplies_the_responses() {
        let first = mass_spring_damper();
        let then = TransferFunction::new(vec![3.0], vec![1.0, 4.0])
            .expect("tf")
            .to_state_space();
        let both = first.series(&then).expect("series");
        for omega in [0.1, 1.0, 10.0] {
            let product = first.frequency_response(omega) * then.frequency_response(omega);
            assert!((both.frequency_response(omega) - product).norm() < 1e-12 * product.norm());
        }
    }

    #[test]
    fn unity_feedback_of_an_integrator_has_its_pole_at_minus_the_gain() {
        let integrator = TransferFunction::new(vec![1.0], vec![1.0, 0.0])
            .expect("tf")
            .to_state_space();
        let gain = StateSpace::new(
            DMatrix::zeros(0, 0),
            DMatrix::zeros(0, 1),
            DMatrix::zeros(1, 0),
            DMatrix::from_element(1, 1, 4.0),
        )
        .expect("static gain");
        let poles = integrator.negative_feedback_poles(&gain).expect("poles");
        assert_eq!(poles.len(), 1);
        assert!((poles[0] - Complex::new(-4.0, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn balancing_keeps_the_response() {
        let tf = TransferFunction::new(vec![7.0e6, 8.8e6], vec![1.0, 22.9, 1227.0, 7904.0, 1725.0]).expect("tf");
        let ss = tf.to_state_space();
        let balanced = ss.balanced();
        for omega in [0.1, 10.0, 1000.0] {
            let (x, y) = (ss.frequency_response(omega), balanced.frequency_response(omega));
            assert!((x - y).norm() < 1e-9 * x.norm());
        }
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
