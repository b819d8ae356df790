use nalgebra::DMatrix;

use crate::{LtiError, StateSpace, TransferFunction};

/// A discrete-time SISO state-space system for a real-time loop: every buffer
/// is allocated once at construction and [`DiscreteSiso::step`] allocates
/// nothing.
#[derive(Debug, Clone)]
pub struct DiscreteSiso {
    n: usize,
    /// Row-major `n x n`.
    a: Vec<f64>,
    b: Vec<f64>,
    c: Vec<f64>,
    d: f64,
    x: Vec<f64>,
    scratch: Vec<f64>,
    /// Steady state per unit constant input, `(I - A)^-1 B`, for bumpless starts.
    steady_state_per_input: Option<Vec<f64>>,
    /// DC gain of the discrete system, `C (I - A)^-1 B + D`.
    dc_gain: Option<f64>,
}

impl DiscreteSiso {
    /// Realizes a continuous transfer function and discretizes it with a
    /// zero-order hold at sample time `ts`.
    pub fn from_transfer_function_zoh(tf: &TransferFunction, ts: f64) -> Result<Self, LtiError> {
        Self::from_discrete_state_space(&tf.to_state_space().discretize_zoh(ts)?)
    }

    pub fn from_discrete_state_space(ss: &StateSpace) -> Result<Self, LtiError> {
        if ss.b.ncols() != 1 || ss.c.nrows() != 1 {
            return Err(LtiError::Dimension(
                "DiscreteSiso needs one input and one output".into(),
            ));
        }
        let n = ss.states();
        let a: Vec<f64> = (0..n * n).map(|k| ss.a[(k / n, k % n)]).collect();
        let b: Vec<f64> = ss.b.column(0).iter().copied().collect();
        let c: Vec<f64> = ss.c.row(0).iter().copied().collect();
        let d = ss.d[(0, 0)];
        let identity_minus_a = DMatrix::identity(n, n) - &ss.a;
        let steady = identity_minus_a
            .lu()
            .solve(&ss.b)
            .map(|m| m.column(0).iter().copied().collect::<Vec<f64>>());
        let dc_gain = steady
            .as_ref()
            .map(|x| c.iter().zip(x).map(|(ci, xi)| ci * xi).sum::<f64>() + d);
        Ok(Self {
            n,
            a,
            b,
            c,
            d,
            x: vec![0.0; n],
            scratch: vec![0.0; n],
            steady_state_per_input: steady,
            dc_gain,
        })
    }

    pub fn reset(&mut self) {
        self.x.iter_mut().for_each(|v| *v = 0.0);
    }

    /// The output for input `u` now, then advances the state.
    pub fn step(&mut self, u: f64) -> f64 {
        let n = self.n;
        let y = self.peek(u);
        for i in 0..n {
            let row = &self.a[i * n..(i + 1) * n];
            self.scratch[i] = self.b[i] * u + row.iter().zip(&self.x).map(|(a, x)| a * x).sum::<f64>();
        }
        std::mem::swap(&mut self.x, &mut self.scratch);
        y
    }

    /// The output the system would give now for input `u`, without advancing.
    pub(crate) fn peek(&self, u: f64) -> f64 {
        self.d * u + self.c.iter().zip(&self.x).map(|(c, x)| c * x).sum::<f64>()
    }

    /// Puts the system in the steady state whose output is `output`, so that
    /// a controller switched in takes over without a step (bumpless
    /// transfer). With a strictly proper system, the next output is exactly
    /// `output` whatever the input.
    pub fn initialize_output(&mut self, output: f64) {
        match (&self.steady_state_per_input, self.dc_gain) {
            (Some(per_input), Some(gain)) if gain.abs() > 1e-300 && gain.is_finite() => {
                let input = output / gain;
                for (x, p) in self.x.iter_mut().zip(per_input) {
                    *x = p * input;
                }
            }
            _ => {
                // No usable steady state: the minimum-norm state with C x = output.
                let norm2: f64 = self.c.iter().map(|c| c * c).sum();
                if norm2 > 0.0 {
                    for (x, c) in self.x.iter_mut().zip(&self.c) {
                        *x = c * output / norm2;
                    }
                }
            }
        }
    }

    pub fn dc_gain(&self) -> Option<f64> {
        self.dc_gain
    }

    pub fn state(&self) -> &[f64] {
        &self.x
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn discrete_first_order_matches_exact_solution() {
        let tf = TransferFunction::new(vec![2.0], vec![1.0, 2.0]).expect("tf");
        let mut sys = DiscreteSiso::from_transfer_function_zoh(&tf, 0.01).expect("zoh");
        let mut y = 0.0;
        for _ in 0..=100 {
            y = sys.step(1.0);
        }
        // After 100 steps the output reflects t = 1.0 s.
        assert!((y - (1.0 - (-2.0_f64).exp())).abs() < 1e-9, "{y}");
    }

    #[test]
    fn bumpless_initialization_hits_requested_output() {
        let tf = TransferFunction::new(vec![1.0, 5.0], vec![1.0, 3.0, 2.0]).expect("tf");
        let mut sys = DiscreteSiso::from_transfer_function_zoh(&tf, 0.001).expect("zoh");
        sys.initialize_output(0.7);
        assert!((sys.peek(123.0) - 0.7).abs() < 1e-12);
    }
}
