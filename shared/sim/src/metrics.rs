//! Figures of merit computed from a run's signals.

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// The mean power of a signal's content above a frequency, accumulated as
/// the signal streams by: Welch's method, Hann-windowed blocks of
/// [`PowerAbove::BLOCK`] samples (the last, shorter one included), each
/// block's periodogram summed over the bins above the frequency, weighted
/// by its length. Fixed memory however long the signal.
pub struct PowerAbove {
    ts: f64,
    omega: f64,
    block: Vec<f64>,
    planner: FftPlanner<f64>,
    spectrum: Vec<Complex<f64>>,
    /// Σ over blocks of (block power above ω × block length), and Σ lengths.
    weighted_power: f64,
    samples: usize,
}

impl PowerAbove {
    /// 16 384 samples: 16 s at 1 kHz, bins of 0.38 rad/s.
    pub const BLOCK: usize = 16_384;

    /// The power above `omega` rad/s of a signal sampled every `ts` s.
    pub fn new(ts: f64, omega: f64) -> Self {
        Self {
            ts,
            omega,
            block: Vec::with_capacity(Self::BLOCK),
            planner: FftPlanner::new(),
            spectrum: Vec::with_capacity(Self::BLOCK),
            weighted_power: 0.0,
            samples: 0,
        }
    }

    pub fn push(&mut self, value: f64) {
        self.block.push(value);
        if self.block.len() == Self::BLOCK {
            self.close_block();
        }
    }

    /// The mean power above the frequency, (unit)²; 0 with under two samples.
    pub fn finish(mut self) -> f64 {
        self.close_block();
        if self.samples == 0 {
            return 0.0;
        }
        self.weighted_power / self.samples as f64
    }

    fn close_block(&mut self) {
        let n = self.block.len();
        if n < 2 {
            self.block.clear();
            return;
        }
        let mean = self.block.iter().sum::<f64>() / n as f64;
        let window = |k: usize| 0.5 - 0.5 * (std::f64::consts::TAU * k as f64 / n as f64).cos();
        self.spectrum.clear();
        self.spectrum.extend(
            self.block
                .iter()
                .enumerate()
                .map(|(k, &v)| Complex::new((v - mean) * window(k), 0.0)),
        );
        self.planner.plan_fft_forward(n).process(&mut self.spectrum);
        let window_power: f64 = (0..n).map(|k| window(k).powi(2)).sum();
        let bin_omega = std::f64::consts::TAU / (n as f64 * self.ts);
        let above: f64 = self
            .spectrum
            .iter()
            .enumerate()
            .filter(|(k, _)| {
                // Bin k and its mirror n − k stand for the same frequency.
                let folded = (*k).min(n - k);
                folded as f64 * bin_omega > self.omega
            })
            .map(|(_, x)| x.norm_sqr())
            .sum();
        // Parseval with the window's power: the block's mean square above ω
        // is above / (n Σw²), weighted here by the block's n samples.
        self.weighted_power += above / window_power;
        self.samples += n;
        self.block.clear();
    }
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
        // second, of mean square 1/2. A block and a shorter last one.
        let power_above = |omega| {
            let mut power = PowerAbove::new(ts, omega);
            signal.iter().for_each(|&v| power.push(v));
            power.finish()
        };
        assert!((power_above(30.0) - 0.5).abs() < 5e-3, "{}", power_above(30.0));
        assert!((power_above(1.0) - 5.0).abs() < 5e-2, "{}", power_above(1.0));
        assert_eq!(PowerAbove::new(ts, 1.0).finish(), 0.0);
    }
}
