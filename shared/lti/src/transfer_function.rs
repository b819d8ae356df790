use nalgebra::{Complex, DMatrix};

use crate::{poly_eval, poly_from_roots, poly_roots, LtiError, StateSpace};

/// A SISO transfer function `num(s) / den(s)`, stored with `den` monic.
#[derive(Debug, Clone, PartialEq)]
pub struct TransferFunction {
    num: Vec<f64>,
    den: Vec<f64>,
}

impl TransferFunction {
    /// Builds `num / den`, normalizing `den` to be monic. Leading zeros are
    /// stripped; the result must be proper.
    pub fn new(num: Vec<f64>, den: Vec<f64>) -> Result<Self, LtiError> {
        if num.iter().chain(&den).any(|v| !v.is_finite()) {
            return Err(LtiError::NotFinite);
        }
        let den = strip_leading_zeros(den);
        let num = strip_leading_zeros(num);
        let Some(&lead) = den.first() else {
            return Err(LtiError::InvalidDenominator);
        };
        if num.len() > den.len() {
            return Err(LtiError::Improper {
                num: num.len() - 1,
                den: den.len() - 1,
            });
        }
        let num = if num.is_empty() { vec![0.0] } else { num };
        Ok(Self {
            num: num.iter().map(|v| v / lead).collect(),
            den: den.iter().map(|v| v / lead).collect(),
        })
    }

    /// The same system with pole-zero pairs that coincide within
    /// `tolerance` (relative to the pole's magnitude, or absolute below 1)
    /// cancelled: the minimal transfer function of a state space whose modes
    /// are not all controllable and observable from this input and output.
    pub fn minimal(&self, tolerance: f64) -> TransferFunction {
        let mut zeros = self.zeros();
        let mut poles = self.poles();
        let gain = self.num[0];
        let mut i = 0;
        while i < zeros.len() {
            let nearest = poles
                .iter()
                .enumerate()
                .map(|(j, p)| (j, (zeros[i] - p).norm() / p.norm().max(1.0)))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            match nearest {
                Some((j, distance)) if distance <= tolerance => {
                    zeros.remove(i);
                    poles.remove(j);
                }
                _ => i += 1,
            }
        }
        let num: Vec<f64> = poly_from_roots(&zeros).iter().map(|c| c * gain).collect();
        Self {
            num,
            den: poly_from_roots(&poles),
        }
    }

    pub fn num(&self) -> &[f64] {
        &self.num
    }

    pub fn den(&self) -> &[f64] {
        &self.den
    }

    pub fn order(&self) -> usize {
        self.den.len() - 1
    }

    pub fn eval(&self, s: Complex<f64>) -> Complex<f64> {
        poly_eval(&self.num, s) / poly_eval(&self.den, s)
    }

    /// `G(jω)`.
    pub fn frequency_response(&self, omega: f64) -> Complex<f64> {
        self.eval(Complex::new(0.0, omega))
    }

    pub fn dc_gain(&self) -> f64 {
        self.eval(Complex::new(0.0, 0.0)).re
    }

    pub fn poles(&self) -> Vec<Complex<f64>> {
        poly_roots(&self.den)
    }

    pub fn zeros(&self) -> Vec<Complex<f64>> {
        poly_roots(&self.num)
    }

    /// The complex pole pairs as (natural frequency rad/s, damping ratio),
    /// one entry per pair, slowest first.
    pub fn resonances(&self) -> Vec<(f64, f64)> {
        let mut pairs: Vec<(f64, f64)> = self
            .poles()
            .iter()
            .filter(|p| p.im > 1e-9)
            .map(|p| (p.norm(), -p.re / p.norm()))
            .collect();
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        pairs
    }

    /// Controllable canonical realization.
    pub fn to_state_space(&self) -> StateSpace {
        let n = self.order();
        let mut num = vec![0.0; n + 1 - self.num.len()];
        num.extend_from_slice(&self.num);
        let d = num[0];
        let mut a = DMatrix::zeros(n, n);
        let mut b = DMatrix::zeros(n, 1);
        let mut c = DMatrix::zeros(1, n);
        if n > 0 {
            for j in 0..n {
                a[(0, j)] = -self.den[j + 1];
                // Remove the feedthrough part: num - d * den.
                c[(0, j)] = num[j + 1] - d * self.den[j + 1];
            }
            for i in 1..n {
                a[(i, i - 1)] = 1.0;
            }
            b[(0, 0)] = 1.0;
        }
        StateSpace {
            a,
            b,
            c,
            d: DMatrix::from_element(1, 1, d),
        }
    }

    /// The unit-step response at times `t`, from the partial-fraction
    /// expansion over the poles: `y(t) = G(0) + Σ r_i e^{p_i t} / p_i` with
    /// residues `r_i = num(p_i) / den'(p_i)`. Valid for distinct, nonzero
    /// poles; it is independent of any time-stepping, which is why tests use it.
    pub fn step_response_analytic(&self, t: &[f64]) -> Vec<f64> {
        let poles = self.poles();
        let derivative: Vec<f64> = {
            let n = self.den.len() - 1;
            self.den[..n]
                .iter()
                .enumerate()
                .map(|(i, c)| c * (n - i) as f64)
                .collect()
        };
        let feedthrough = if self.num.len() == self.den.len() {
            self.num[0]
        } else {
            0.0
        };
        // Strictly proper part: num - feedthrough * den.
        let mut strict = vec![0.0; self.den.len() - self.num.len()];
        strict.extend_from_slice(&self.num);
        for (s, d) in strict.iter_mut().zip(&self.den) {
            *s -= feedthrough * d;
        }
        let residues: Vec<Complex<f64>> = poles
            .iter()
            .map(|&p| poly_eval(&strict, p) / poly_eval(&derivative, p))
            .collect();
        let dc = self.dc_gain();
        t.iter()
            .map(|&time| {
                let transient: Complex<f64> = poles
                    .iter()
                    .zip(&residues)
                    .map(|(&p, &r)| r * (p * time).exp() / p)
                    .sum();
                dc + transient.re
            })
            .collect()
    }
}

fn strip_leading_zeros(mut p: Vec<f64>) -> Vec<f64> {
    let first = p.iter().position(|&v| v != 0.0).unwrap_or(p.len());
    p.drain(..first);
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalizes_and_rejects_improper() {
        let tf = TransferFunction::new(vec![2.0], vec![2.0, 4.0]).expect("tf");
        assert_eq!(tf.den(), &[1.0, 2.0]);
        assert_eq!(tf.num(), &[1.0]);
        assert!(matches!(
            TransferFunction::new(vec![1.0, 0.0, 0.0], vec![1.0, 1.0]),
            Err(LtiError::Improper { .. })
        ));
        assert!(TransferFunction::new(vec![1.0], vec![0.0]).is_err());
    }

    #[test]
    fn analytic_step_of_first_order() {
        let tf = TransferFunction::new(vec![3.0], vec![1.0, 3.0]).expect("tf");
        let y = tf.step_response_analytic(&[0.0, 1.0]);
        assert!(y[0].abs() < 1e-12);
        assert!((y[1] - (1.0 - (-3.0_f64).exp())).abs() < 1e-12);
    }

    #[test]
    fn realization_round_trips() {
        // Coprime: a common factor would be cancelled by the minimal realization.
        let tf = TransferFunction::new(vec![1.0, 3.0, 5.0], vec![1.0, 4.0, 6.0, 4.0]).expect("tf");
        let back = tf.to_state_space().transfer_function(0, 0).expect("tf");
        for (a, b) in back.num().iter().zip(tf.num()) {
            assert!((a - b).abs() < 1e-8, "{:?} vs {:?}", back.num(), tf.num());
        }
        for (a, b) in back.den().iter().zip(tf.den()) {
            assert!((a - b).abs() < 1e-8);
        }
    }

    #[test]
    fn minimal_cancels_coincident_pole_zero_pairs() {
        // (s + 2) s / ((s + 2) s (s + 3)) = 1 / (s + 3).
        let tf = TransferFunction::new(vec![1.0, 2.0, 0.0], vec![1.0, 5.0, 6.0, 0.0]).expect("tf");
        let m = tf.minimal(1e-9);
        assert_eq!(m.num().len(), 1);
        assert!((m.num()[0] - 1.0).abs() < 1e-12);
        assert!((m.den()[0] - 1.0).abs() < 1e-12 && (m.den()[1] - 3.0).abs() < 1e-9);
    }

    #[test]
    fn resonance_of_papers_rotary_tf() {
        // The rotary paper's eq. (18): a pair near 32 rad/s.
        let tf = TransferFunction::new(
            vec![20.79, -1696.0, 8.005e4, 1.139e5],
            vec![1.0, 35.68, 1428.0, 1.972e4, 2.783e4],
        )
        .expect("tf");
        let pairs = tf.resonances();
        assert_eq!(pairs.len(), 1);
        assert!((pairs[0].0 - 32.9).abs() < 0.1);
        assert!((pairs[0].1 - 0.272).abs() < 0.005);
    }
}
