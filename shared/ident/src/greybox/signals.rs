//! The measured signals the grey-box model is compared with, in SI units,
//! with the smoothed angle and velocity the model's segments start from.

use hydractl_plant::PlantParams;

use super::{ModelError, SEGMENT_S};
use crate::Dataset;

/// The columns the model tools need, as the issue names them.
pub const REQUIRED_COLUMNS: [&str; 5] = ["t", "u", "p_a", "p_b", "theta"];

/// Half-width of the smoothing that turns encoder counts into a velocity, s.
/// Wide enough that one count of a 4000-count encoder moves the velocity by
/// under 0.01 rad/s, narrow against the 13 rad/s hydraulic mode.
const SMOOTHING_HALF_WIDTH_S: f64 = 0.02;

/// Measured data at a uniform sample time, SI units.
#[derive(Debug, Clone)]
pub struct Signals {
    pub source: String,
    pub dt: f64,
    pub t: Vec<f64>,
    /// Valve command as sent, [-1, 1].
    pub u: Vec<f64>,
    /// Chamber pressures, Pa.
    pub p_a: Vec<f64>,
    pub p_b: Vec<f64>,
    /// Encoder angle, rad.
    pub theta: Vec<f64>,
    /// The angle and velocity of a local straight-line fit (zero phase).
    pub theta_smooth: Vec<f64>,
    pub velocity: Vec<f64>,
}

impl Signals {
    /// From a dataset with the columns `t,u,p_a,p_b,theta` (s, command, bar, bar, rad).
    pub fn from_dataset(data: &Dataset) -> Result<Self, ModelError> {
        let source = data.source.display().to_string();
        let t = data.column("t")?.to_vec();
        let u = data.column("u")?.to_vec();
        let bar =
            |name: &str| -> Result<Vec<f64>, ModelError> { Ok(data.column(name)?.iter().map(|p| p * 1e5).collect()) };
        let p_a = bar("p_a")?;
        let p_b = bar("p_b")?;
        let theta = data.column("theta")?.to_vec();
        let dt = data.sample_time()?;
        let fail = |reason: String| ModelError::Signals {
            source_name: source.clone(),
            reason,
        };
        if dt.is_nan() || dt <= 0.0 {
            return Err(fail("fewer than two samples".to_owned()));
        }
        for (i, w) in t.windows(2).enumerate() {
            let step = w[1] - w[0];
            if (step - dt).abs() > 0.1 * dt {
                return Err(fail(format!(
                    "line {}: column `t`: the sample time changes from the mean {dt} s to {step} s; \
                     the model tools need uniformly sampled data",
                    i + 3
                )));
            }
        }
        if let Some(i) = u.iter().position(|u| u.abs() > 1.0 + 1e-9) {
            return Err(fail(format!(
                "line {}: column `u`: {} is outside [-1, 1] (the valve command as sent)",
                i + 2,
                u[i]
            )));
        }
        let duration = t[t.len() - 1] - t[0];
        if duration < 8.0 * SEGMENT_S {
            return Err(fail(format!(
                "{duration} s of data; the model tools need at least {} s",
                8.0 * SEGMENT_S
            )));
        }
        let half_width = ((SMOOTHING_HALF_WIDTH_S / dt).round() as usize).max(1);
        let (theta_smooth, velocity) = local_line(&theta, dt, half_width);
        Ok(Self {
            source,
            dt,
            t,
            u,
            p_a,
            p_b,
            theta,
            theta_smooth,
            velocity,
        })
    }

    pub fn len(&self) -> usize {
        self.t.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// The measured hydraulic torque D (p_a − p_b) at sample `k`, N·m.
    pub fn torque(&self, plant: &PlantParams, k: usize) -> f64 {
        plant.displacement * (self.p_a[k] - self.p_b[k])
    }

    /// The first sample of the validation segment: the estimation segment
    /// is the first `estimation_fraction` of the record.
    pub fn split(&self, estimation_fraction: f64) -> usize {
        ((self.len() as f64 * estimation_fraction).round() as usize).clamp(1, self.len() - 1)
    }
}

/// The slope of `x` by the same local line as the velocity's.
pub(crate) fn smoothed_slope(x: &[f64], dt: f64) -> Vec<f64> {
    let half_width = ((SMOOTHING_HALF_WIDTH_S / dt).round() as usize).max(1);
    local_line(x, dt, half_width).1
}

/// A centred moving average over ± `half_width_s`.
pub(crate) fn moving_average(x: &[f64], half_width_s: f64, dt: f64) -> Vec<f64> {
    let half_width = ((half_width_s / dt).round() as usize).max(1);
    local_line(x, dt, half_width).0
}

/// Level and slope of a least-squares line through the samples within
/// `half_width` of each one (a first-order Savitzky–Golay filter), with the
/// window shrunk symmetrically at the ends.
fn local_line(x: &[f64], dt: f64, half_width: usize) -> (Vec<f64>, Vec<f64>) {
    let n = x.len();
    let mut level = vec![0.0; n];
    let mut slope = vec![0.0; n];
    for k in 0..n {
        let w = half_width.min(k).min(n - 1 - k);
        if w == 0 {
            level[k] = x[k];
            continue;
        }
        let (mut sum, mut moment, mut squares) = (0.0, 0.0, 0.0);
        for j in -(w as i64)..=(w as i64) {
            let v = x[(k as i64 + j) as usize];
            sum += v;
            moment += j as f64 * v;
            squares += (j * j) as f64;
        }
        level[k] = sum / (2 * w + 1) as f64;
        slope[k] = moment / (squares * dt);
    }
    (level, slope)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_line_is_exact_on_a_line() {
        let x: Vec<f64> = (0..100).map(|i| 0.5 + 2.0 * i as f64 * 0.001).collect();
        let (level, slope) = local_line(&x, 0.001, 10);
        for k in 1..99 {
            assert!((level[k] - x[k]).abs() < 1e-12);
            assert!((slope[k] - 2.0).abs() < 1e-9);
        }
    }
}
