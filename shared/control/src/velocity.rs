use serde::{Deserialize, Serialize};

use crate::{require_positive, ControlError};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VelocityEstimatorParams {
    /// Cutoff of the low-pass filter after the differentiator, rad/s. A 4000
    /// count encoder differenced at 1 kHz moves in steps of 1.57 rad/s, so
    /// the filter must be well below the loop rate.
    pub cutoff_rad_s: f64,
}

impl Default for VelocityEstimatorParams {
    fn default() -> Self {
        Self { cutoff_rad_s: 40.0 }
    }
}

/// The crane paper's "differentiator and low-pass filter arrangement":
/// a backward difference of the angle through a first-order low-pass filter,
/// discretized exactly (pole at e^{-ω_c T}).
#[derive(Debug, Clone)]
pub struct VelocityEstimator {
    ts: f64,
    pole: f64,
    previous_angle: Option<f64>,
    estimate: f64,
}

impl VelocityEstimator {
    pub fn new(params: VelocityEstimatorParams, ts: f64) -> Result<Self, ControlError> {
        require_positive("cutoff_rad_s", params.cutoff_rad_s)?;
        require_positive("sample time", ts)?;
        Ok(Self {
            ts,
            pole: (-params.cutoff_rad_s * ts).exp(),
            previous_angle: None,
            estimate: 0.0,
        })
    }

    pub fn reset(&mut self) {
        self.previous_angle = None;
        self.estimate = 0.0;
    }

    /// Starts from a known angle and velocity, e.g. a restarted sensor process.
    pub fn initialize(&mut self, angle: f64, velocity: f64) {
        self.previous_angle = Some(angle);
        self.estimate = velocity;
    }

    /// A non-finite angle is skipped: the estimate holds until a valid one.
    pub fn update(&mut self, angle: f64) -> f64 {
        if !angle.is_finite() {
            return self.estimate;
        }
        let previous = self.previous_angle.unwrap_or(angle);
        let difference = (angle - previous) / self.ts;
        self.previous_angle = Some(angle);
        self.estimate = self.pole * self.estimate + (1.0 - self.pole) * difference;
        self.estimate
    }

    pub fn estimate(&self) -> f64 {
        self.estimate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converges_to_a_constant_ramp_rate() {
        let mut v = VelocityEstimator::new(VelocityEstimatorParams { cutoff_rad_s: 40.0 }, 0.001).expect("valid");
        let mut estimate = 0.0;
        for k in 0..1000 {
            estimate = v.update(0.5 * k as f64 * 0.001);
        }
        assert!((estimate - 0.5).abs() < 1e-9);
    }

    #[test]
    fn a_nan_angle_is_skipped() {
        let mut v = VelocityEstimator::new(VelocityEstimatorParams::default(), 0.001).expect("valid");
        v.update(0.0);
        v.update(f64::NAN);
        assert!(v.update(0.001).is_finite());
    }

    #[test]
    fn first_sample_gives_no_spike() {
        let mut v = VelocityEstimator::new(VelocityEstimatorParams::default(), 0.001).expect("valid");
        assert_eq!(v.update(3.0), 0.0);
    }

    #[test]
    fn step_response_is_the_exact_first_order_filter() {
        let mut v = VelocityEstimator::new(VelocityEstimatorParams { cutoff_rad_s: 10.0 }, 0.001).expect("valid");
        v.update(0.0);
        // A unit velocity from k = 1 on: estimate_k = 1 - e^{-10 k T}.
        for k in 1..=200 {
            let e = v.update(k as f64 * 0.001);
            assert!((e - (1.0 - (-10.0 * k as f64 * 0.001).exp())).abs() < 1e-12);
        }
    }
}
