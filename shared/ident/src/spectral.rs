//! Spectral analysis: Welch's averaged periodograms and the empirical
//! transfer function estimate, as the papers use to see the valve's
//! second-order resonance before fitting a parametric model.
//!
//! The data is cut into segments (Hamming window, 50% overlap). The input
//! and output auto-spectra and their cross-spectrum are averaged over the
//! segments; the transfer function is H1 = S_yu / S_uu, which is unbiased
//! by noise on the output. The magnitude-squared coherence |S_yu|² / (S_uu
//! S_yy) says at which frequencies the estimate can be trusted.

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

use crate::tf::IdentError;

#[derive(Debug, Clone, serde::Serialize)]
pub struct Spectrum {
    /// Frequencies, rad/s, from the first above 0 to Nyquist.
    pub frequency_rad_s: Vec<f64>,
    /// One-sided power spectral densities, units² per rad/s.
    pub input_psd: Vec<f64>,
    pub output_psd: Vec<f64>,
    /// |H1(jω)|, output units per input unit.
    pub gain: Vec<f64>,
    pub phase_deg: Vec<f64>,
    pub coherence: Vec<f64>,
    /// Segments averaged.
    pub segments: usize,
}

/// A peak of the estimated gain: the resonance it shows.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Resonance {
    pub frequency_rad_s: f64,
    pub gain: f64,
    /// The peak's gain over the lowest gain between it and the low end of
    /// the band: how far it stands out.
    pub prominence: f64,
    pub coherence: f64,
}

/// Welch's estimate with segments of `segment` samples (a power of two
/// suits the FFT; any length works).
pub fn welch(u: &[f64], y: &[f64], ts: f64, segment: usize) -> Result<Spectrum, IdentError> {
    if u.len() != y.len() {
        return Err(IdentError::Lengths {
            input: u.len(),
            output: y.len(),
        });
    }
    if !(ts.is_finite() && ts > 0.0) {
        return Err(IdentError::SampleTime(ts));
    }
    // Two segments at least (50% overlap): with one, the coherence is 1
    // everywhere and says nothing.
    if segment < 16 || u.len() < segment + segment / 2 {
        return Err(IdentError::TooShort {
            needed: segment.max(16) + segment.max(16) / 2,
            have: u.len(),
        });
    }
    if let Some(k) = u.iter().zip(y).position(|(a, b)| !(a.is_finite() && b.is_finite())) {
        return Err(IdentError::Failed(format!("sample {k} is not finite")));
    }
    if u.iter().all(|&v| v == u[0]) {
        return Err(IdentError::NoExcitation);
    }
    let window: Vec<f64> = (0..segment)
        .map(|i| 0.54 - 0.46 * (2.0 * std::f64::consts::PI * i as f64 / (segment - 1) as f64).cos())
        .collect();
    let window_power: f64 = window.iter().map(|w| w * w).sum();
    let fft = FftPlanner::new().plan_fft_forward(segment);
    let bins = segment / 2;
    let (mut suu, mut syy) = (vec![0.0; bins + 1], vec![0.0; bins + 1]);
    let mut syu = vec![Complex::new(0.0, 0.0); bins + 1];
    let (mut ub, mut yb) = (
        vec![Complex::new(0.0, 0.0); segment],
        vec![Complex::new(0.0, 0.0); segment],
    );
    let hop = segment / 2;
    let mut segments = 0;
    let mut start = 0;
    while start + segment <= u.len() {
        // Each segment's mean removed: an offset is not a response.
        let (um, ym) = (mean(&u[start..start + segment]), mean(&y[start..start + segment]));
        for i in 0..segment {
            ub[i] = Complex::new((u[start + i] - um) * window[i], 0.0);
            yb[i] = Complex::new((y[start + i] - ym) * window[i], 0.0);
        }
        fft.process(&mut ub);
        fft.process(&mut yb);
        for k in 0..=bins {
            suu[k] += ub[k].norm_sqr();
            syy[k] += yb[k].norm_sqr();
            syu[k] += yb[k] * ub[k].conj();
        }
        segments += 1;
        start += hop;
    }
    // One-sided density per rad/s: |X|² ts / (Σw² · 2π), doubled off DC.
    let scale = ts / (window_power * 2.0 * std::f64::consts::PI * segments as f64);
    let dw = 2.0 * std::f64::consts::PI / (segment as f64 * ts);
    let mut spectrum = Spectrum {
        frequency_rad_s: Vec::with_capacity(bins),
        input_psd: Vec::with_capacity(bins),
        output_psd: Vec::with_capacity(bins),
        gain: Vec::with_capacity(bins),
        phase_deg: Vec::with_capacity(bins),
        coherence: Vec::with_capacity(bins),
        segments,
    };
    for k in 1..=bins {
        // One-sided: every bin but DC and, for an even length, Nyquist
        // stands for its mirror image too.
        let sides = if 2 * k == segment { 1.0 } else { 2.0 };
        let h = if suu[k] > 0.0 {
            syu[k] / suu[k]
        } else {
            Complex::new(f64::NAN, f64::NAN)
        };
        let coherence = syu[k].norm_sqr() / (suu[k] * syy[k]);
        spectrum.frequency_rad_s.push(k as f64 * dw);
        spectrum.input_psd.push(sides * suu[k] * scale);
        spectrum.output_psd.push(sides * syy[k] * scale);
        spectrum.gain.push(h.norm());
        spectrum.phase_deg.push(h.arg().to_degrees());
        spectrum
            .coherence
            .push(if coherence.is_finite() { coherence } else { 0.0 });
    }
    Ok(spectrum)
}

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

impl Spectrum {
    /// The most prominent peak of the gain between `low` and `high` rad/s,
    /// after a 5-bin moving average so that one noisy bin is not a peak,
    /// where one of those five bins has a coherence of at least
    /// `min_coherence`. Its prominence is
    /// its gain over the lowest gain in the band below it.
    pub fn resonance(&self, low: f64, high: f64, min_coherence: f64) -> Option<Resonance> {
        let n = self.gain.len();
        let smooth: Vec<f64> = (0..n)
            .map(|k| {
                let (a, b) = (k.saturating_sub(2), (k + 3).min(n));
                mean(&self.gain[a..b])
            })
            .collect();
        let mut best: Option<Resonance> = None;
        let mut lowest_so_far = f64::INFINITY;
        for k in 1..n.saturating_sub(1) {
            let w = self.frequency_rad_s[k];
            if w < low || w > high || !smooth[k].is_finite() {
                continue;
            }
            lowest_so_far = lowest_so_far.min(smooth[k]);
            let is_peak = smooth[k] >= smooth[k - 1] && smooth[k] > smooth[k + 1];
            // Judged over the same five bins as the smoothed gain.
            let coherence = self.coherence[k.saturating_sub(2)..(k + 3).min(n)]
                .iter()
                .fold(0.0_f64, |m, &c| m.max(c));
            if !is_peak || coherence < min_coherence {
                continue;
            }
            let prominence = smooth[k] / lowest_so_far;
            if best.is_none_or(|b| prominence > b.prominence) {
                best = Some(Resonance {
                    frequency_rad_s: w,
                    gain: smooth[k],
                    prominence,
                    coherence,
                });
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lightly damped second-order system, discretized by Euler at a
    /// fine step, driven by a pseudo-random binary input.
    fn resonant_data(n: usize, wn: f64, zeta: f64, ts: f64) -> (Vec<f64>, Vec<f64>) {
        let mut state = (0.0f64, 0.0f64);
        let mut seed = 12345u64;
        let (mut u, mut y) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let mut level = 1.0;
        for i in 0..n {
            if i % 7 == 0 {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                level = if (seed >> 40) & 1 == 0 { 1.0 } else { -1.0 };
            }
            let sub = 10;
            for _ in 0..sub {
                let h = ts / sub as f64;
                let acc = wn * wn * (level - state.0) - 2.0 * zeta * wn * state.1;
                state.1 += h * acc;
                state.0 += h * state.1;
            }
            u.push(level);
            y.push(state.0);
        }
        (u, y)
    }

    #[test]
    fn the_gain_of_a_resonant_system_peaks_at_its_damped_frequency() {
        let (wn, zeta) = (30.0, 0.1);
        let (u, y) = resonant_data(120_000, wn, zeta, 1e-3);
        let s = welch(&u, &y, 1e-3, 4096).expect("spectrum");
        assert!(s.segments > 50);
        let peak = s.resonance(5.0, 200.0, 0.8).expect("a peak");
        let expected = wn * (1.0 - 2.0 * zeta * zeta).sqrt();
        assert!(
            (peak.frequency_rad_s - expected).abs() < 0.05 * expected,
            "{peak:?} against {expected}"
        );
        assert!(peak.prominence > 3.0, "{peak:?}");
        // Low frequencies: unit gain, in phase, coherent.
        let k = s.frequency_rad_s.iter().position(|&w| w > 3.0).expect("bin");
        assert!((s.gain[k] - 1.0).abs() < 0.05, "{}", s.gain[k]);
        assert!(s.coherence[k] > 0.95);
    }

    #[test]
    fn bad_input_is_refused() {
        assert!(matches!(
            welch(&[1.0; 100], &[0.0; 99], 1e-3, 32),
            Err(IdentError::Lengths { .. })
        ));
        assert!(matches!(
            welch(&[1.0; 100], &[0.0; 100], 1e-3, 32),
            Err(IdentError::NoExcitation)
        ));
        assert!(matches!(
            welch(&[1.0; 10], &[0.0; 10], 1e-3, 32),
            Err(IdentError::TooShort { .. })
        ));
    }
}
