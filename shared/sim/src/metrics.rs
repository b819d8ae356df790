//! Figures of merit computed from a run's signals.

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

pub fn rms(values: &[f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
}

pub fn max_abs(values: &[f64]) -> f64 {
    values.iter().fold(0.0, |m, v| m.max(v.abs()))
}

/// Mean power of the part of `signal` (sampled every `ts` s) above
/// `omega` rad/s, from its periodogram (Parseval: the powers of all bins
/// add up to the signal's mean square).
pub fn power_above(signal: &[f64], ts: f64, omega: f64) -> f64 {
    let n = signal.len();
    if n < 2 {
        return 0.0;
    }
    let mean = signal.iter().sum::<f64>() / n as f64;
    let mut buffer: Vec<Complex<f64>> = signal.iter().map(|&v| Complex::new(v - mean, 0.0)).collect();
    FftPlanner::new().plan_fft_forward(n).process(&mut buffer);
    let bin_omega = std::f64::consts::TAU / (n as f64 * ts);
    let total: f64 = buffer
        .iter()
        .enumerate()
        .filter(|(k, _)| {
            // Bin k and its mirror n − k stand for the same frequency.
            let folded = (*k).min(n - k);
            folded as f64 * bin_omega > omega
        })
        .map(|(_, x)| x.norm_sqr())
        .sum();
    total / (n as f64 * n as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_above_separates_two_sines() {
        let ts = 0.001;
        let n = 20_000;
        let signal: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64 * ts;
                (2.0 * std::f64::consts::TAU * t).sin() * 3.0 + (10.0 * std::f64::consts::TAU * t).sin()
            })
            .collect();
        // 2 Hz = 12.6 rad/s and 10 Hz = 62.8 rad/s: above 30 rad/s only the
        // second, of mean square 1/2.
        assert!((power_above(&signal, ts, 30.0) - 0.5).abs() < 1e-6);
        assert!((power_above(&signal, ts, 1.0) - 5.0).abs() < 1e-6);
    }

    #[test]
    fn rms_and_max() {
        assert!((rms(&[3.0, -4.0]) - (12.5f64).sqrt()).abs() < 1e-12);
        assert_eq!(max_abs(&[1.0, -3.0, 2.0]), 3.0);
    }
}
