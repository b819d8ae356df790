//! Continuous-time transfer functions from sampled input and output data.
//!
//! 1. Block-average down to about 200 Hz, so a discrete fit is well
//!    conditioned for dynamics of tens of rad/s.
//! 2. Discrete ARX by least squares.
//! 3. To continuous time by the inverse bilinear map; the numerator is then
//!    refitted to the requested number of zeros on the frequency response.
//! 4. Levenberg–Marquardt on the continuous coefficients: `oe` minimizes
//!    the simulated output's error; `pem` then goes on from that model to
//!    minimize the one-step prediction error of the Box–Jenkins structure
//!    y = G u + C/D e, the zero-order-hold G and a second-order noise model
//!    C/D estimated together. The noise model is kept low in order on
//!    purpose: at 1 kHz, a noise model of the plant's own order (ARMAX)
//!    predicts one step ahead from the last outputs so well that G is left
//!    almost free, and drifts.
//!
//! The fit is MATLAB `compare`'s, 100 (1 − ‖y − ŷ‖ / ‖y − mean y‖), on the
//! validation segment, simulating the model from rest over all the data.

use hydractl_lti::{poly_mul, Complex, StateSpace, TransferFunction};
use nalgebra::{DMatrix, DVector};

#[derive(Debug, thiserror::Error)]
pub enum IdentError {
    #[error("need at least {needed} samples, have {have}")]
    TooShort { needed: usize, have: usize },
    #[error("input and output lengths differ: {input} and {output}")]
    Lengths { input: usize, output: usize },
    #[error("{zeros} zeros with {poles} poles: a proper model needs fewer zeros than poles, and at least one pole")]
    Orders { poles: usize, zeros: usize },
    #[error("the sample time must be positive, got {0}")]
    SampleTime(f64),
    #[error("the input does not excite the system (it is constant)")]
    NoExcitation,
    #[error("sample {index} of the {signal} is not a number: the fit needs every sample")]
    NotFinite { signal: &'static str, index: usize },
    #[error("the fit did not produce a usable model: {0}")]
    Failed(String),
    #[error(transparent)]
    Lti(#[from] hydractl_lti::LtiError),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Output error: the simulated output's error.
    Oe,
    /// Prediction error with a second-order Box–Jenkins noise model.
    Pem,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TfOptions {
    pub poles: usize,
    pub zeros: usize,
    pub method: Method,
    /// Share of the data, from its start, used to estimate; the rest validates.
    pub estimation_fraction: f64,
}

#[derive(Debug, Clone)]
pub struct TfFit {
    pub tf: TransferFunction,
    /// On the validation segment, percent.
    pub fit_percent: f64,
    /// On the estimation segment, percent.
    pub estimation_fit_percent: f64,
    /// `pem`'s noise model, None for `oe`.
    pub noise_model: Option<NoiseModel>,
    pub iterations: usize,
}

/// The discrete noise model H(q) = C(q)/D(q) of `pem`, in ascending powers
/// of q^-1 from a leading 1, at the data's sample time.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseModel {
    pub c: Vec<f64>,
    pub d: Vec<f64>,
}

/// MATLAB's fit: 100 (1 − ‖y − ŷ‖ / ‖y − mean(y)‖).
pub fn fit_percent(measured: &[f64], modelled: &[f64]) -> f64 {
    let n = measured.len().min(modelled.len());
    if n == 0 {
        return f64::NAN;
    }
    let mean = measured[..n].iter().sum::<f64>() / n as f64;
    let error: f64 = measured[..n].iter().zip(modelled).map(|(y, m)| (y - m).powi(2)).sum();
    let spread: f64 = measured[..n].iter().map(|y| (y - mean).powi(2)).sum();
    100.0 * (1.0 - (error / spread).sqrt())
}

pub fn identify_tf(u: &[f64], y: &[f64], ts: f64, options: TfOptions) -> Result<TfFit, IdentError> {
    let TfOptions {
        poles,
        zeros,
        method,
        estimation_fraction,
    } = options;
    if u.len() != y.len() {
        return Err(IdentError::Lengths {
            input: u.len(),
            output: y.len(),
        });
    }
    if poles == 0 || zeros >= poles {
        return Err(IdentError::Orders { poles, zeros });
    }
    if !(ts.is_finite() && ts > 0.0) {
        return Err(IdentError::SampleTime(ts));
    }
    let needed = 20 * (poles + zeros + 1);
    if u.len() < needed {
        return Err(IdentError::TooShort { needed, have: u.len() });
    }
    // A NaN would make the SVD below iterate for ever.
    for (signal, values) in [("input", u), ("output", y)] {
        if let Some(index) = values.iter().position(|v| !v.is_finite()) {
            return Err(IdentError::NotFinite { signal, index });
        }
    }
    if u.iter().all(|&v| v == u[0]) {
        return Err(IdentError::NoExcitation);
    }
    let split = ((u.len() as f64 * estimation_fraction.clamp(0.1, 1.0)) as usize).clamp(needed / 2, u.len());

    // 1. Decimate the estimation segment to about 200 Hz for the start.
    let factor = ((1.0 / 200.0) / ts).floor().max(1.0) as usize;
    let (ud, yd) = (block_average(&u[..split], factor), block_average(&y[..split], factor));

    // 2–3. ARX, then continuous.
    let initial = arx_to_continuous(&ud, &yd, ts * factor as f64, poles, zeros)?;

    // 4. Refine at the data's own rate, where the zero-order hold is exact
    // (a step inside an averaged block is not held): output error first;
    // prediction error then starts from it and adds its noise model.
    let (ue, ye) = (&u[..split], &y[..split]);
    let Refined {
        mut tf, mut iterations, ..
    } = refine(&initial, ue, ye, ts, Method::Oe)?;
    // A pole spent on the sampling: a second start, and the better stays.
    if let Some(other) = without_fast_poles(&tf, ts).and_then(|second| refine(&second, ue, ye, ts, Method::Oe).ok()) {
        iterations += other.iterations;
        let cost_of = |m: &TransferFunction| {
            simulate(m, ue, ts).map_or(f64::INFINITY, |yhat| {
                ye.iter().zip(&yhat).map(|(a, b)| (a - b).powi(2)).sum::<f64>()
            })
        };
        if cost_of(&other.tf) < cost_of(&tf) {
            tf = other.tf;
        }
    }
    let mut noise_model = None;
    if method == Method::Pem {
        let pem = refine(&tf, ue, ye, ts, Method::Pem)?;
        let (c, d) = pem.noise.split_at(NOISE_ORDER);
        let monic = |p: &[f64]| std::iter::once(1.0).chain(p.iter().copied()).collect();
        noise_model = Some(NoiseModel {
            c: monic(c),
            d: monic(d),
        });
        tf = pem.tf;
        iterations += pem.iterations;
    }

    // Fit at the data's own rate, from rest, over all of it.
    let simulated = simulate(&tf, u, ts)?;
    Ok(TfFit {
        fit_percent: fit_percent(&y[split..], &simulated[split..]),
        estimation_fit_percent: fit_percent(&y[..split], &simulated[..split]),
        tf,
        noise_model,
        iterations,
    })
}

fn block_average(x: &[f64], factor: usize) -> Vec<f64> {
    x.chunks_exact(factor)
        .map(|c| c.iter().sum::<f64>() / factor as f64)
        .collect()
}

/// The response of `tf` to `u` held between samples, from rest.
pub fn simulate(tf: &TransferFunction, u: &[f64], ts: f64) -> Result<Vec<f64>, IdentError> {
    let discrete = tf.to_state_space().discretize_zoh(ts)?;
    Ok(simulate_discrete(&discrete, u))
}

fn simulate_discrete(d: &StateSpace, u: &[f64]) -> Vec<f64> {
    let n = d.states();
    let (a, b) = (&d.a, d.b.column(0));
    let (c, dd) = (d.c.row(0), d.d[(0, 0)]);
    let mut x = DVector::zeros(n);
    let mut next = DVector::zeros(n);
    let mut y = Vec::with_capacity(u.len());
    for &uk in u {
        y.push((c * &x)[(0, 0)] + dd * uk);
        next.gemv(1.0, a, &x, 0.0);
        next.axpy(uk, &b, 1.0);
        std::mem::swap(&mut x, &mut next);
    }
    y
}

/// Least-squares ARX with `n` poles and `n` numerator taps (delay 1), then
/// the inverse bilinear map to continuous time, with the numerator refitted
/// to `zeros` zeros on the frequency response.
fn arx_to_continuous(u: &[f64], y: &[f64], ts: f64, n: usize, zeros: usize) -> Result<TransferFunction, IdentError> {
    let rows = y.len() - n;
    let mut phi = DMatrix::zeros(rows, 2 * n);
    let mut target = DVector::zeros(rows);
    for k in n..y.len() {
        let r = k - n;
        for i in 1..=n {
            phi[(r, i - 1)] = -y[k - i];
            phi[(r, n + i - 1)] = u[k - i];
        }
        target[r] = y[k];
    }
    let mut theta = phi
        .clone()
        .svd(true, true)
        .solve(&target, 1e-12)
        .map_err(|e| IdentError::Failed(format!("ARX least squares: {e}")))?;
    // Least squares is biased when the output is noisy; instrumental
    // variables, the previous estimate's noise-free output, are not.
    for _ in 0..4 {
        let Some(x) = simulate_arx(&theta, u, n) else { break };
        let mut z = DMatrix::zeros(rows, 2 * n);
        for k in n..y.len() {
            for i in 1..=n {
                z[(k - n, i - 1)] = -x[k - i];
                z[(k - n, n + i - 1)] = u[k - i];
            }
        }
        let zt = z.transpose();
        match (&zt * &phi).lu().solve(&(&zt * &target)) {
            Some(next) if next.iter().all(|v| v.is_finite()) && arx_is_stable(&next, n) => theta = next,
            _ => break,
        }
    }
    // A(z) = z^n + a1 z^{n-1} + … ; B(z) = b1 z^{n-1} + … + bn.
    let mut a_z = vec![1.0];
    a_z.extend((0..n).map(|i| theta[i]));
    let mut b_z = vec![0.0];
    b_z.extend((0..n).map(|i| theta[n + i]));
    let (num, den) = (bilinear_to_continuous(&b_z, ts), bilinear_to_continuous(&a_z, ts));
    let den_tf = TransferFunction::new(vec![1.0], den.clone())?;
    // Mirror any unstable pole into the left half-plane, and bring any pole
    // beyond half the Nyquist frequency within it: a stable start the
    // sampled data can see.
    let limit = 0.5 * std::f64::consts::PI / ts;
    let mirrored: Vec<Complex<f64>> = den_tf
        .poles()
        .iter()
        .map(|p| {
            let p = if p.re >= 0.0 {
                Complex::new(-p.re.abs().max(1e-3), p.im)
            } else {
                *p
            };
            if p.norm() > limit {
                p * (limit / p.norm())
            } else {
                p
            }
        })
        .collect();
    let den_monic = hydractl_lti::poly_from_roots(&mirrored);
    let full = TransferFunction::new(num, den)?;
    with_denominator(&full, den_monic, zeros, ts)
}

/// `den` with a numerator of degree `zeros` fitted to `model`'s frequency
/// response below a third of the Nyquist frequency of `ts`.
fn with_denominator(
    model: &TransferFunction,
    den: Vec<f64>,
    zeros: usize,
    ts: f64,
) -> Result<TransferFunction, IdentError> {
    let nyquist = std::f64::consts::PI / ts;
    let grid: Vec<f64> = (1..=200).map(|i| nyquist / 3.0 * i as f64 / 200.0).collect();
    let mut m = DMatrix::zeros(2 * grid.len(), zeros + 1);
    let mut rhs = DVector::zeros(2 * grid.len());
    for (g, &w) in grid.iter().enumerate() {
        let s = Complex::new(0.0, w);
        let target = model.eval(s) * hydractl_lti::poly_eval(&den, s);
        for j in 0..=zeros {
            let power = s.powu((zeros - j) as u32);
            m[(2 * g, j)] = power.re;
            m[(2 * g + 1, j)] = power.im;
        }
        rhs[2 * g] = target.re;
        rhs[2 * g + 1] = target.im;
    }
    let num = m
        .svd(true, true)
        .solve(&rhs, 1e-14)
        .map_err(|e| IdentError::Failed(format!("numerator fit: {e}")))?;
    Ok(TransferFunction::new(num.iter().copied().collect(), den)?)
}

/// A refined model with a real pole pushed against the Nyquist frequency
/// has spent a pole on the sampling rather than the plant: a start with
/// that pole brought down among the slow ones instead, for a second try.
/// `None` when no pole is that fast.
fn without_fast_poles(model: &TransferFunction, ts: f64) -> Option<TransferFunction> {
    let fast = 0.25 * std::f64::consts::PI / ts;
    let poles = model.poles();
    if poles.iter().all(|p| p.norm() < fast) {
        return None;
    }
    let slowest = poles
        .iter()
        .map(|p| p.norm())
        .filter(|&w| w < fast)
        .fold(f64::INFINITY, f64::min);
    let slow = if slowest.is_finite() { 0.5 * slowest } else { 1.0 };
    let moved: Vec<Complex<f64>> = poles
        .iter()
        .map(|p| if p.norm() < fast { *p } else { Complex::new(-slow, 0.0) })
        .collect();
    let den = hydractl_lti::poly_from_roots(&moved);
    // The numerator is fitted to the model below the data's own limit, not
    // the decimated start's: the model is already at the data's rate.
    with_denominator(model, den, model.num().len() - 1, ts).ok()
}

fn arx_is_stable(theta: &DVector<f64>, n: usize) -> bool {
    let mut a = vec![1.0];
    a.extend((0..n).map(|i| theta[i]));
    hydractl_lti::poly_roots(&a).iter().all(|z| z.norm() < 1.0)
}

/// The output of the ARX model `theta` driven by `u` alone; `None` when the
/// model is unstable.
fn simulate_arx(theta: &DVector<f64>, u: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut x = vec![0.0; u.len()];
    for k in n..u.len() {
        let mut v = 0.0;
        for i in 1..=n {
            v += -theta[i - 1] * x[k - i] + theta[n + i - 1] * u[k - i];
        }
        if !v.is_finite() || v.abs() > 1e12 {
            return None;
        }
        x[k] = v;
    }
    Some(x)
}

/// Substitutes z = (2 + sT) / (2 − sT) into a polynomial in z of degree n
/// and clears the denominators: Σ c_k (2 + sT)^k (2 − sT)^{n−k}.
fn bilinear_to_continuous(p: &[f64], ts: f64) -> Vec<f64> {
    let n = p.len() - 1;
    let plus = [ts, 2.0];
    let minus = [-ts, 2.0];
    let mut out = vec![0.0; n + 1];
    for (i, &c) in p.iter().enumerate() {
        let k = n - i; // power of z
        let mut term = vec![c];
        for _ in 0..k {
            term = poly_mul(&term, &plus);
        }
        for _ in 0..(n - k) {
            term = poly_mul(&term, &minus);
        }
        for (o, t) in out.iter_mut().rev().zip(term.iter().rev()) {
            *o += t;
        }
    }
    out
}

/// The order of `pem`'s noise polynomials C and D.
const NOISE_ORDER: usize = 2;

/// Parameters: the numerator's coefficients, then the denominator's below
/// its leading 1, then (for `pem`) the noise model's C and D below their
/// leading 1s. The transfer function's are scaled by their starting values,
/// so one step size suits coefficients from 1 to 1e9; the noise model's lie
/// within ±2 and are not scaled.
struct Parameters {
    zeros: usize,
    poles: usize,
    scale: Vec<f64>,
}

impl Parameters {
    fn new(tf: &TransferFunction, noise: &[f64]) -> Self {
        let raw: Vec<f64> = tf.num().iter().chain(&tf.den()[1..]).copied().collect();
        let largest = raw.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        Self {
            zeros: tf.num().len() - 1,
            poles: tf.den().len() - 1,
            scale: raw
                .iter()
                .map(|v| {
                    if v.abs() > 1e-9 * largest {
                        *v
                    } else {
                        1e-6 * largest.max(1e-12)
                    }
                })
                .chain(noise.iter().map(|_| 1.0))
                .collect(),
        }
    }

    fn initial(&self, tf: &TransferFunction, noise: &[f64]) -> DVector<f64> {
        let raw: Vec<f64> = tf.num().iter().chain(&tf.den()[1..]).chain(noise).copied().collect();
        DVector::from_iterator(raw.len(), raw.iter().zip(&self.scale).map(|(v, s)| v / s))
    }

    fn values(&self, theta: &DVector<f64>) -> Vec<f64> {
        theta.iter().zip(&self.scale).map(|(t, s)| t * s).collect()
    }

    fn model(&self, theta: &DVector<f64>) -> Result<TransferFunction, IdentError> {
        let values = self.values(theta);
        let num = values[..=self.zeros].to_vec();
        let mut den = vec![1.0];
        den.extend_from_slice(&values[self.zeros + 1..=self.zeros + self.poles]);
        Ok(TransferFunction::new(num, den)?)
    }

    /// The noise model's coefficients below the leading 1s: C's, then D's
    /// (empty for `oe`).
    fn noise(&self, theta: &DVector<f64>) -> Vec<f64> {
        self.values(theta)[self.zeros + self.poles + 1..].to_vec()
    }
}

/// A monic polynomial in q^-1 whose roots lie inside the unit circle: its
/// inverse filter is stable.
fn is_minimum_phase(below_leading_one: &[f64]) -> bool {
    let mut p = vec![1.0];
    p.extend_from_slice(below_leading_one);
    hydractl_lti::poly_roots(&p).iter().all(|z| z.norm() < 1.0)
}

/// `pem`'s starting noise model: C = 1 and D from a least-squares AR fit of
/// the output error `v`, so that D v is nearly white (D = 1 when it is
/// white already).
fn noise_model_start(v: &[f64]) -> Vec<f64> {
    let n = NOISE_ORDER;
    let rows = v.len().saturating_sub(n);
    let mut phi = DMatrix::zeros(rows, n);
    let mut target = DVector::zeros(rows);
    for k in n..v.len() {
        for i in 1..=n {
            phi[(k - n, i - 1)] = -v[k - i];
        }
        target[k - n] = v[k];
    }
    let d: Vec<f64> = phi
        .svd(true, true)
        .solve(&target, 1e-12)
        .map(|d| d.iter().copied().collect())
        .unwrap_or_else(|_| vec![0.0; n]);
    let d = if is_minimum_phase(&d) { d } else { vec![0.0; n] };
    std::iter::repeat_n(0.0, n).chain(d).collect()
}

fn residuals(
    tf: &TransferFunction,
    noise: &[f64],
    u: &[f64],
    y: &[f64],
    ts: f64,
    method: Method,
) -> Result<Vec<f64>, IdentError> {
    // An unstable candidate is no model of a stable plant's data, and a pole
    // beyond the Nyquist frequency aliases: the samples cannot tell it
    // from a slow one, so it is no model either.
    let nyquist = std::f64::consts::PI / ts;
    if tf.poles().iter().any(|p| p.re >= 0.0 || p.norm() >= nyquist) {
        return Err(IdentError::Failed("unstable or beyond the Nyquist frequency".into()));
    }
    let discrete = tf.to_state_space().discretize_zoh(ts)?;
    let yhat = simulate_discrete(&discrete, u);
    let output_error = y.iter().zip(&yhat).map(|(a, b)| a - b);
    match method {
        Method::Oe => Ok(output_error.collect()),
        Method::Pem => {
            // y = G u + (C/D) e: the one-step prediction error is
            // e = (D/C) (y − G u).
            let (c, d) = noise.split_at(NOISE_ORDER);
            if !(is_minimum_phase(c) && is_minimum_phase(d)) {
                return Err(IdentError::Failed("unstable noise model".into()));
            }
            let v: Vec<f64> = output_error.collect();
            let mut e = vec![0.0; v.len()];
            for k in 0..v.len() {
                let mut ek = v[k];
                for i in 1..=NOISE_ORDER.min(k) {
                    ek += d[i - 1] * v[k - i] - c[i - 1] * e[k - i];
                }
                e[k] = ek;
            }
            Ok(e)
        }
    }
}

fn cost(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

struct Refined {
    tf: TransferFunction,
    /// `pem`'s C's, then D's coefficients below their leading 1s.
    noise: Vec<f64>,
    iterations: usize,
}

fn refine(initial: &TransferFunction, u: &[f64], y: &[f64], ts: f64, method: Method) -> Result<Refined, IdentError> {
    let noise0: Vec<f64> = match method {
        Method::Oe => Vec::new(),
        Method::Pem => {
            let v = residuals(initial, &[], u, y, ts, Method::Oe)?;
            noise_model_start(&v)
        }
    };
    let params = Parameters::new(initial, &noise0);
    let mut theta = params.initial(initial, &noise0);
    let mut current = match residuals(initial, &noise0, u, y, ts, method) {
        Ok(r) => r,
        // The ARX start can be unstable on poor data: nothing to refine from.
        Err(_) => {
            return Ok(Refined {
                tf: initial.clone(),
                noise: noise0,
                iterations: 0,
            })
        }
    };
    let mut lambda = 1e-3;
    let mut iterations = 0;
    for _ in 0..100 {
        iterations += 1;
        let p = theta.len();
        let mut jacobian = DMatrix::zeros(current.len(), p);
        for j in 0..p {
            // Forward difference; backward where the forward step leaves
            // the stable models.
            let mut h = 1e-6 * theta[j].abs().max(1e-3);
            let mut shifted = theta.clone();
            shifted[j] += h;
            let evaluate = |t: &DVector<f64>| {
                params
                    .model(t)
                    .and_then(|m| residuals(&m, &params.noise(t), u, y, ts, method))
            };
            let r = match evaluate(&shifted) {
                Ok(r) => r,
                Err(_) => {
                    h = -h;
                    shifted[j] = theta[j] + h;
                    match evaluate(&shifted) {
                        Ok(r) => r,
                        // At the edge of stability both ways: hold this
                        // parameter for this iteration (a zero column).
                        Err(_) => continue,
                    }
                }
            };
            for (i, (ri, ci)) in r.iter().zip(&current).enumerate() {
                jacobian[(i, j)] = (ri - ci) / h;
            }
        }
        let r = DVector::from_column_slice(&current);
        let jt = jacobian.transpose();
        let jtj = &jt * &jacobian;
        let gradient = &jt * &r;
        let before = cost(&current);
        let mut improved = false;
        for _ in 0..12 {
            let mut damped = jtj.clone();
            for i in 0..p {
                damped[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(step) = damped.lu().solve(&gradient) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = &theta - &step;
            if let Ok(r_new) = params
                .model(&candidate)
                .and_then(|m| residuals(&m, &params.noise(&candidate), u, y, ts, method))
            {
                if cost(&r_new) < before {
                    theta = candidate;
                    current = r_new;
                    lambda = (lambda / 3.0).max(1e-9);
                    improved = true;
                    break;
                }
            }
            lambda *= 10.0;
        }
        if !improved || (before - cost(&current)) < 1e-10 * before {
            break;
        }
    }
    Ok(Refined {
        tf: params.model(&theta)?,
        noise: params.noise(&theta),
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sample_that_is_not_a_number_is_named_not_iterated_on() {
        let u: Vec<f64> = (0..400).map(|k| (k as f64 * 0.05).sin()).collect();
        let mut y = u.clone();
        y[0] = f64::NAN;
        let options = TfOptions {
            poles: 2,
            zeros: 0,
            method: Method::Oe,
            estimation_fraction: 0.7,
        };
        let err = identify_tf(&u, &y, 1e-3, options).expect_err("a NaN");
        assert!(
            matches!(
                err,
                IdentError::NotFinite {
                    signal: "output",
                    index: 0
                }
            ),
            "{err}"
        );
    }
}
