//! How well the data pin a fitted parameter: its standard error from the
//! Jacobian, the residuals' effective sample size, inseparable pairs.

use super::*;

/// How well the data pins a fit's parameters down.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Uncertainty {
    /// One standard deviation of each fitted parameter, in its own units
    /// (`inertia`, `deadzone.width`, …), from JᵀJ at the optimum with the
    /// residuals' variance, widened for their autocorrelation.
    pub std: BTreeMap<String, f64>,
    /// Pairs the data cannot separate: |correlation| above 0.95, with it.
    pub inseparable: Vec<String>,
    /// The same pairs by name, for programs (the fleet's trend names no
    /// drift of a parameter the data fixes only in a combination).
    pub inseparable_pairs: Vec<InseparablePair>,
}

/// Two fitted parameters the data fixes only in a combination.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InseparablePair {
    pub parameters: [String; 2],
    pub correlation: f64,
}

impl Uncertainty {
    /// Appends another part's or candidate's fit.
    pub fn extend(&mut self, other: Uncertainty) {
        self.std.extend(other.std);
        self.inseparable.extend(other.inseparable);
        self.inseparable_pairs.extend(other.inseparable_pairs);
    }
}

/// Correlation above which two parameters are said to move as one.
pub(super) const INSEPARABLE_CORRELATION: f64 = 0.95;

/// The knobs' standard deviations and inseparable pairs at a fit's optimum:
/// σ² (JᵀJ)⁻¹ with σ² the residuals' variance, times N / N_eff for their
/// autocorrelation (output-error residuals are far from white).
pub(super) fn uncertainty(
    knobs: &[Free],
    working: &Working,
    result: &lm::LmResult,
    residuals: &[f64],
    stride: usize,
) -> Uncertainty {
    let p = knobs.len();
    let n = residuals.len();
    if p == 0 || n <= p {
        return Uncertainty::default();
    }
    let Some(inverse) = result.normal_matrix.clone().try_inverse() else {
        return Uncertainty {
            inseparable: vec!["the parameters are not all identifiable from this data (JᵀJ is singular)".to_owned()],
            ..Uncertainty::default()
        };
    };
    let variance = lm::sum_of_squares(residuals) / (n - p) as f64;
    let widen = n as f64 / effective_sample_size(residuals, stride).max(1.0);
    let covariance = inverse * (variance * widen);
    let mut std = BTreeMap::new();
    for (i, free) in knobs.iter().enumerate() {
        let scaled_std = covariance[(i, i)].max(0.0).sqrt();
        // Back to the parameter's units: a log knob's σ is relative.
        let value = working.value(free.knob);
        let sigma = match free.scale {
            Scale::Log { .. } => value.abs() * scaled_std,
            Scale::Linear { unit, .. } => unit * scaled_std,
        };
        std.insert(free.knob.name(), sigma);
    }
    let mut inseparable_pairs = Vec::new();
    for i in 0..p {
        for j in i + 1..p {
            let denominator = (covariance[(i, i)] * covariance[(j, j)]).sqrt();
            let correlation = covariance[(i, j)] / denominator;
            if denominator > 0.0 && correlation.abs() > INSEPARABLE_CORRELATION {
                inseparable_pairs.push(InseparablePair {
                    parameters: [knobs[i].knob.name(), knobs[j].knob.name()],
                    correlation,
                });
            }
        }
    }
    let inseparable = inseparable_pairs
        .iter()
        .map(|pair| {
            let [a, b] = &pair.parameters;
            format!(
                "{a} and {b} (correlation {:+.3}): the data fixes a combination of them, not each",
                pair.correlation
            )
        })
        .collect();
    Uncertainty {
        std,
        inseparable,
        inseparable_pairs,
    }
}

/// The effective number of independent residuals, N / (1 + 2 Σ ρ_k), the
/// autocorrelations ρ_k at lags of whole samples (`stride` residuals per
/// sample) summed while positive (Geyer's initial positive sequence).
pub(crate) fn effective_sample_size(residuals: &[f64], stride: usize) -> f64 {
    let n = residuals.len();
    let stride = stride.max(1);
    if n < 4 * stride {
        return n as f64;
    }
    let mean = residuals.iter().sum::<f64>() / n as f64;
    let centred: Vec<f64> = residuals.iter().map(|r| r - mean).collect();
    let variance = centred.iter().map(|r| r * r).sum::<f64>();
    if variance <= 0.0 {
        return n as f64;
    }
    let lagged = lagged_products(&centred);
    let mut sum = 0.0;
    for lag in (stride..n / 2).step_by(stride) {
        let rho = lagged[lag] / variance;
        if rho <= 0.0 {
            break;
        }
        sum += rho;
    }
    n as f64 / (1.0 + 2.0 * sum)
}

/// Σ_k x[k + lag]·x[k] for every lag, through the FFT, zero-padded so it
/// does not wrap around: output-error residuals stay correlated over
/// thousands of lags, and the direct sums cost N per lag.
pub(super) fn lagged_products(x: &[f64]) -> Vec<f64> {
    use rustfft::num_complex::Complex;
    let size = (2 * x.len()).next_power_of_two();
    let mut planner = rustfft::FftPlanner::new();
    let mut buffer: Vec<Complex<f64>> = x
        .iter()
        .map(|&v| Complex::new(v, 0.0))
        .chain(std::iter::repeat(Complex::new(0.0, 0.0)))
        .take(size)
        .collect();
    planner.plan_fft_forward(size).process(&mut buffer);
    for c in &mut buffer {
        *c = Complex::new(c.norm_sqr(), 0.0);
    }
    planner.plan_fft_inverse(size).process(&mut buffer);
    buffer.iter().take(x.len()).map(|c| c.re / size as f64).collect()
}

pub(super) fn median_abs(x: &[f64]) -> f64 {
    let mut a: Vec<f64> = x.iter().map(|v| v.abs()).filter(|v| v.is_finite()).collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f64::total_cmp);
    a[a.len() / 2]
}
