//! Levenberg–Marquardt least squares with a finite-difference Jacobian and
//! box bounds: the one optimizer behind the grey-box fits.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Where to stop and how to differentiate.
#[derive(Debug, Clone, Copy)]
pub struct LmOptions {
    pub max_iterations: usize,
    /// Forward-difference step, in the parameters' own (scaled) units.
    pub difference_step: f64,
    /// Stop when this many iterations in a row lower the cost by less than
    /// `tolerance` of it: one small gain may be a bend of the valley.
    /// 1e-4: the crawl below it (a dead-zone's or a delay's fit spent 40
    /// iterations at gains of 1e-6 to 1e-4) moved no judgement and no
    /// parameter beyond its uncertainty on the foreign plants' data.
    pub tolerance: f64,
    pub small_gains_to_stop: usize,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self {
            max_iterations: 30,
            difference_step: 1e-4,
            tolerance: 1e-4,
            small_gains_to_stop: 3,
        }
    }
}

#[derive(Debug, Clone)]
pub struct LmResult {
    pub params: Vec<f64>,
    /// Sum of squared residuals at `params`.
    pub cost: f64,
    /// The residuals at `params`.
    pub residuals: Vec<f64>,
    pub iterations: usize,
    /// Whether it stopped for want of progress, not of iterations.
    pub converged: bool,
    /// JᵀJ at the last Jacobian, in the scaled parameters: with the noise
    /// level, the parameters' covariance.
    pub normal_matrix: DMatrix<f64>,
}

pub fn sum_of_squares(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Minimizes ‖r(θ)‖² over lower ≤ θ ≤ upper, from `initial`. `residuals`
/// returns `None` where the model is not defined (an invalid parameter);
/// such steps are refused. Returns `None` only if `initial` is not defined.
pub fn minimize(
    initial: &[f64],
    lower: &[f64],
    upper: &[f64],
    residuals: impl Fn(&[f64]) -> Option<Vec<f64>> + Sync,
    options: LmOptions,
) -> Option<LmResult> {
    let p = initial.len();
    let clamp = |theta: &mut [f64]| {
        for i in 0..p {
            theta[i] = theta[i].clamp(lower[i], upper[i]);
        }
    };
    let mut theta = initial.to_vec();
    clamp(&mut theta);
    let mut current = residuals(&theta)?;
    let mut cost = sum_of_squares(&current);
    let mut lambda = 1e-2;
    let mut iterations = 0;
    let mut small_gains = 0;
    let mut converged = p == 0;
    let mut normal_matrix = DMatrix::zeros(p, p);
    while iterations < options.max_iterations && p > 0 {
        iterations += 1;
        // The columns are independent simulations: in parallel, which also
        // lends a core to the other fits' threads as they finish.
        let columns: Vec<Option<(f64, Vec<f64>)>> = (0..p)
            .into_par_iter()
            .map(|j| {
                let mut shifted = theta.clone();
                // Step inward at an upper bound, so the difference stays feasible.
                let h = if theta[j] + options.difference_step > upper[j] {
                    -options.difference_step
                } else {
                    options.difference_step
                };
                shifted[j] += h;
                residuals(&shifted).filter(|r| r.len() == current.len()).map(|r| (h, r))
            })
            .collect();
        let mut jacobian = DMatrix::zeros(current.len(), p);
        for (j, column) in columns.iter().enumerate() {
            let Some((h, r)) = column else {
                continue;
            };
            for (i, (ri, ci)) in r.iter().zip(&current).enumerate() {
                jacobian[(i, j)] = (ri - ci) / h;
            }
        }
        let r = DVector::from_column_slice(&current);
        let jt = jacobian.transpose();
        let jtj = &jt * &jacobian;
        normal_matrix.copy_from(&jtj);
        let mut gradient = &jt * &r;
        // A parameter at a bound that the descent would push past it is
        // held there for this step: a step that moves it, clamped, is not
        // the step the others were solved for, and the trials that follow
        // cost a simulation each while the damping grows.
        let held: Vec<bool> = (0..p)
            .map(|i| (theta[i] <= lower[i] && gradient[i] > 0.0) || (theta[i] >= upper[i] && gradient[i] < 0.0))
            .collect();
        for i in (0..p).filter(|i| held[*i]) {
            gradient[i] = 0.0;
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = jtj.clone();
            for i in 0..p {
                damped[(i, i)] += lambda * jtj[(i, i)].max(1e-9);
            }
            for i in (0..p).filter(|i| held[*i]) {
                for j in 0..p {
                    damped[(i, j)] = 0.0;
                    damped[(j, i)] = 0.0;
                }
                damped[(i, i)] = 1.0;
            }
            let Some(step) = damped.lu().solve(&gradient) else {
                lambda *= 10.0;
                continue;
            };
            let mut candidate: Vec<f64> = theta.iter().zip(step.iter()).map(|(t, s)| t - s).collect();
            clamp(&mut candidate);
            if let Some(r_new) = residuals(&candidate) {
                let new_cost = sum_of_squares(&r_new);
                if new_cost.is_finite() && new_cost < cost {
                    let gain = cost - new_cost;
                    theta = candidate;
                    current = r_new;
                    small_gains = if gain < options.tolerance * cost {
                        small_gains + 1
                    } else {
                        0
                    };
                    cost = new_cost;
                    lambda = (lambda / 5.0).max(1e-9);
                    improved = small_gains < options.small_gains_to_stop.max(1);
                    break;
                }
            }
            lambda *= 10.0;
        }
        if !improved {
            converged = true;
            break;
        }
    }
    Some(LmResult {
        params: theta,
        cost,
        residuals: current,
        iterations,
        converged,
        normal_matrix,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parameter_pushed_against_its_bound_lets_the_others_converge() {
        // y = a x + b x², where the data want b < 0 and b is held at 0:
        // the fit must still find a's best value for b = 0, in a few steps.
        let x: Vec<f64> = (1..=40).map(|i| i as f64 * 0.05).collect();
        let y: Vec<f64> = x.iter().map(|x| 2.0 * x - 0.5 * x * x).collect();
        let residuals = |p: &[f64]| Some(x.iter().zip(&y).map(|(x, y)| p[0] * x + p[1] * x * x - y).collect());
        let fit = minimize(&[1.0, 0.0], &[0.0, 0.0], &[10.0, 10.0], residuals, LmOptions::default()).expect("defined");
        let best_a = x.iter().zip(&y).map(|(x, y)| x * y).sum::<f64>() / x.iter().map(|x| x * x).sum::<f64>();
        assert_eq!(fit.params[1], 0.0);
        assert!(
            (fit.params[0] - best_a).abs() < 1e-6,
            "{:?} against {best_a}",
            fit.params
        );
        assert!(fit.converged && fit.iterations <= 5, "{} iterations", fit.iterations);
    }

    #[test]
    fn fits_an_exponential_within_bounds() {
        let t: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
        let y: Vec<f64> = t.iter().map(|t| 3.0 * (-0.7 * t).exp()).collect();
        let residuals = |p: &[f64]| Some(t.iter().zip(&y).map(|(t, y)| p[0] * (-p[1] * t).exp() - y).collect());
        let fit = minimize(&[1.0, 0.1], &[0.0, 0.0], &[10.0, 5.0], residuals, LmOptions::default()).expect("defined");
        assert!((fit.params[0] - 3.0).abs() < 1e-4, "{:?}", fit.params);
        assert!((fit.params[1] - 0.7).abs() < 1e-4, "{:?}", fit.params);
        let bounded =
            minimize(&[1.0, 0.1], &[0.0, 0.0], &[2.0, 5.0], residuals, LmOptions::default()).expect("defined");
        assert!(bounded.params[0] <= 2.0);
    }
}
