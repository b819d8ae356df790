use serde::{Deserialize, Serialize};

use crate::{require, require_non_negative, require_positive, ControlError};

/// How the angle becomes a velocity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VelocityMethod {
    /// The crane paper's differentiator and low-pass filter: the encoder's
    /// counts alone.
    #[default]
    Differentiator,
    /// A model-based observer: the measured torque drives the load's model
    /// `Ĵ ω̇ = τ − b̂ ω` and the encoder corrects it. The motion the torque
    /// explains needs no differencing, so the encoder's quantization is
    /// filtered at the observer's bandwidth while a real acceleration is
    /// followed without that lag.
    Observer,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VelocityEstimatorParams {
    pub method: VelocityMethod,
    /// The differentiator's low-pass cutoff, rad/s. A 4000 count encoder
    /// differenced at 1 kHz moves in steps of 1.57 rad/s, so the filter must
    /// be well below the loop rate.
    pub cutoff_rad_s: f64,
    /// Where the observer's three error poles sit, rad/s: the bandwidth at
    /// which the encoder corrects the model (its Ĵ, b̂ and the torque
    /// reading's errors are forgotten this fast).
    pub observer_bandwidth_rad_s: f64,
}

impl Default for VelocityEstimatorParams {
    fn default() -> Self {
        Self {
            method: VelocityMethod::Differentiator,
            cutoff_rad_s: 40.0,
            observer_bandwidth_rad_s: 80.0,
        }
    }
}

/// The load's model the observer runs: inertia Ĵ (kg·m²) and viscous
/// friction b̂ (N·m·s/rad), the config's `[plant]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoadModel {
    pub inertia: f64,
    pub viscous_friction: f64,
}

#[derive(Debug, Clone)]
enum Method {
    /// A backward difference through a first-order low-pass filter,
    /// discretized exactly (pole at e^{-ω_c T}).
    Differentiator { pole: f64 },
    /// Predict with the model, correct with the encoder's innovation. The
    /// load's torque (friction, gravity, a hose) is a third state, so a
    /// load the model lacks leaves no lasting error in the velocity; the
    /// gains place the three poles of the discrete error dynamics at
    /// `p = e^{-ω_o T}`.
    Observer {
        /// 1 − T b̂/Ĵ: the model's velocity decay over one period.
        decay: f64,
        /// T/Ĵ: a period's velocity per N·m.
        torque_gain: f64,
        /// The innovation's share in angle, velocity and load torque.
        gains: [f64; 3],
        /// The observer's angle (rad) and load torque (N·m); the last
        /// finite torque reading.
        angle: f64,
        load: f64,
        torque: f64,
    },
}

/// The loop's velocity from the encoder's angle and, for the observer, the
/// torque the pressures measure.
#[derive(Debug, Clone)]
pub struct VelocityEstimator {
    ts: f64,
    method: Method,
    previous_angle: Option<f64>,
    estimate: f64,
}

impl VelocityEstimator {
    pub fn new(params: VelocityEstimatorParams, model: LoadModel, ts: f64) -> Result<Self, ControlError> {
        require_positive("sample time", ts)?;
        let method = match params.method {
            VelocityMethod::Differentiator => {
                require_positive("cutoff_rad_s", params.cutoff_rad_s)?;
                Method::Differentiator {
                    pole: (-params.cutoff_rad_s * ts).exp(),
                }
            }
            VelocityMethod::Observer => Self::observer(params.observer_bandwidth_rad_s, model, ts)?,
        };
        Ok(Self {
            ts,
            method,
            previous_angle: None,
            estimate: 0.0,
        })
    }

    fn observer(bandwidth: f64, model: LoadModel, ts: f64) -> Result<Method, ControlError> {
        require_positive("observer_bandwidth_rad_s", bandwidth)?;
        require_positive("plant.inertia", model.inertia)?;
        require_non_negative("plant.viscous_friction", model.viscous_friction)?;
        // Beyond a tenth of the loop's rate the discrete poles are no longer
        // a bandwidth: the correction would chase single counts.
        require(
            "observer_bandwidth_rad_s",
            bandwidth,
            bandwidth * ts <= 0.1 * std::f64::consts::TAU,
            "must stay below a tenth of the loop's rate (rad/s)",
        )?;
        let decay = 1.0 - ts * model.viscous_friction / model.inertia;
        require(
            "plant.viscous_friction",
            model.viscous_friction,
            decay > 0.0,
            "over the inertia must be below the loop's rate",
        )?;
        let torque_gain = ts / model.inertia;
        Ok(Method::Observer {
            decay,
            torque_gain,
            gains: Self::observer_gains(decay, torque_gain, (-bandwidth * ts).exp(), ts),
            angle: 0.0,
            load: 0.0,
            torque: 0.0,
        })
    }

    /// Ackermann's formula for the error dynamics e⁺ = (I − L C) A e =
    /// (A − L C A) e, states (angle, velocity, load torque):
    /// L = φ(A) O⁻¹ [0 0 1]ᵀ with O the observability matrix of (A, C A)
    /// and φ(z) = (z − p)³.
    fn observer_gains(decay: f64, torque_gain: f64, pole: f64, ts: f64) -> [f64; 3] {
        use nalgebra::{Matrix3, RowVector3, Vector3};
        let a = Matrix3::new(1.0, ts, 0.0, 0.0, decay, -torque_gain, 0.0, 0.0, 1.0);
        let h = RowVector3::new(1.0, 0.0, 0.0) * a;
        let observability = Matrix3::from_rows(&[h, h * a, h * a * a]);
        let shifted = a - Matrix3::identity() * pole;
        // The load reaches the angle through the velocity, so (A, C A) is
        // observable for any T > 0 and finite Ĵ; were it not, the observer
        // would run uncorrected rather than panic.
        let inverse = observability.try_inverse().unwrap_or_else(Matrix3::zeros);
        let gains = shifted * shifted * shifted * inverse * Vector3::new(0.0, 0.0, 1.0);
        [gains[0], gains[1], gains[2]]
    }

    pub fn reset(&mut self) {
        self.previous_angle = None;
        self.estimate = 0.0;
        if let Method::Observer { load, .. } = &mut self.method {
            *load = 0.0;
        }
    }

    /// One period: the angle (rad) and the torque (N·m) read. A non-finite
    /// angle is skipped: the estimate holds (the differentiator) or runs on
    /// the model (the observer) until a valid one; a non-finite torque
    /// reads as the last finite one.
    pub fn update(&mut self, angle: f64, torque: f64) -> f64 {
        let ts = self.ts;
        match &mut self.method {
            Method::Differentiator { pole } => {
                if !angle.is_finite() {
                    return self.estimate;
                }
                let previous = self.previous_angle.unwrap_or(angle);
                let difference = (angle - previous) / ts;
                self.previous_angle = Some(angle);
                self.estimate = *pole * self.estimate + (1.0 - *pole) * difference;
            }
            Method::Observer {
                decay,
                torque_gain,
                gains,
                angle: observed,
                load,
                torque: last_torque,
            } => {
                if torque.is_finite() {
                    *last_torque = torque;
                }
                if self.previous_angle.is_none() {
                    if !angle.is_finite() {
                        return self.estimate;
                    }
                    // Start on the first reading, at rest.
                    *observed = angle;
                    self.previous_angle = Some(angle);
                    return self.estimate;
                }
                let predicted_angle = *observed + ts * self.estimate;
                let predicted_velocity = *decay * self.estimate + *torque_gain * (*last_torque - *load);
                let innovation = if angle.is_finite() {
                    self.previous_angle = Some(angle);
                    angle - predicted_angle
                } else {
                    0.0
                };
                *observed = predicted_angle + gains[0] * innovation;
                self.estimate = predicted_velocity + gains[1] * innovation;
                *load += gains[2] * innovation;
            }
        }
        self.estimate
    }

    pub fn estimate(&self) -> f64 {
        self.estimate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MODEL: LoadModel = LoadModel {
        inertia: 20.0,
        viscous_friction: 17.0,
    };

    fn differentiator(cutoff_rad_s: f64) -> VelocityEstimatorParams {
        VelocityEstimatorParams {
            cutoff_rad_s,
            ..VelocityEstimatorParams::default()
        }
    }

    fn observer(bandwidth: f64) -> VelocityEstimatorParams {
        VelocityEstimatorParams {
            method: VelocityMethod::Observer,
            observer_bandwidth_rad_s: bandwidth,
            ..VelocityEstimatorParams::default()
        }
    }

    /// The load of `MODEL` driven by a torque of two sines, read through a
    /// 4000-count encoder: (true velocity, quantized angle, torque) per period.
    fn quantized_run(model: LoadModel, seconds: f64) -> Vec<(f64, f64, f64)> {
        let ts = 0.001;
        let substeps = 10;
        let count = std::f64::consts::TAU / 4000.0;
        let (mut angle, mut velocity) = (0.0_f64, 0.0_f64);
        (0..(seconds / ts) as usize)
            .map(|k| {
                let t = k as f64 * ts;
                let torque = 60.0 * (3.0 * t).sin() + 25.0 * (11.0 * t).sin();
                for _ in 0..substeps {
                    let h = ts / substeps as f64;
                    velocity += h * (torque - model.viscous_friction * velocity) / model.inertia;
                    angle += h * velocity;
                }
                (velocity, (angle / count).floor() * count, torque)
            })
            .collect()
    }

    fn error_rms(params: VelocityEstimatorParams, run: &[(f64, f64, f64)]) -> f64 {
        let mut v = VelocityEstimator::new(params, MODEL, 0.001).expect("valid");
        let skip = 500;
        let sum: f64 = run
            .iter()
            .enumerate()
            .map(|(k, &(truth, angle, torque))| {
                let e = v.update(angle, torque) - truth;
                if k >= skip {
                    e * e
                } else {
                    0.0
                }
            })
            .sum();
        (sum / (run.len() - skip) as f64).sqrt()
    }

    #[test]
    fn the_observer_reads_a_quantized_encoder_closer_than_the_differentiator() {
        let run = quantized_run(MODEL, 10.0);
        let differentiated = error_rms(differentiator(150.0), &run);
        let observed = error_rms(observer(80.0), &run);
        assert!(
            observed < differentiated / 3.0,
            "observer {observed:.4} rad/s rms against the differentiator's {differentiated:.4}"
        );
    }

    #[test]
    fn the_observer_forgets_a_wrong_model() {
        // The load is 20 % heavier and has more friction than the model:
        // the encoder's correction keeps the estimate within what the
        // differentiator makes of the counts.
        let heavier = LoadModel {
            inertia: 24.0,
            viscous_friction: 25.0,
        };
        let run = quantized_run(heavier, 10.0);
        let differentiated = error_rms(differentiator(150.0), &run);
        let observed = error_rms(observer(80.0), &run);
        assert!(
            observed < differentiated,
            "observer {observed:.4} rad/s rms against the differentiator's {differentiated:.4}"
        );
    }

    #[test]
    fn the_observers_three_poles_sit_at_its_bandwidth() {
        use nalgebra::{Matrix3, RowVector3};
        let (ts, bandwidth) = (0.001, 80.0);
        let decay = 1.0 - ts * MODEL.viscous_friction / MODEL.inertia;
        let torque_gain = ts / MODEL.inertia;
        let pole = (-bandwidth * ts).exp();
        let l = VelocityEstimator::observer_gains(decay, torque_gain, pole, ts);
        let a = Matrix3::new(1.0, ts, 0.0, 0.0, decay, -torque_gain, 0.0, 0.0, 1.0);
        let correction =
            Matrix3::identity() - nalgebra::Vector3::new(l[0], l[1], l[2]) * RowVector3::new(1.0, 0.0, 0.0);
        let m = correction * a;
        // (z − p)³ = z³ − 3p z² + 3p² z − p³.
        let minors = (0..3)
            .map(|i| {
                let (j, k) = ((i + 1) % 3, (i + 2) % 3);
                m[(j, j)] * m[(k, k)] - m[(j, k)] * m[(k, j)]
            })
            .sum::<f64>();
        assert!((m.trace() - 3.0 * pole).abs() < 1e-9, "{}", m.trace());
        assert!((minors - 3.0 * pole * pole).abs() < 1e-9, "{minors}");
        assert!((m.determinant() - pole.powi(3)).abs() < 1e-9, "{}", m.determinant());
    }

    #[test]
    fn a_load_the_model_lacks_leaves_no_lasting_velocity_error() {
        // A steady 40 N·m the model does not know, at a steady speed: the
        // load state takes it up and the velocity settles on the truth.
        let mut v = VelocityEstimator::new(observer(80.0), MODEL, 0.001).expect("valid");
        let (speed, load) = (0.5, 40.0);
        let torque = MODEL.viscous_friction * speed + load;
        let mut estimate = 0.0;
        for k in 0..2000 {
            estimate = v.update(speed * k as f64 * 0.001, torque);
        }
        assert!((estimate - speed).abs() < 1e-6, "{estimate}");
    }

    #[test]
    fn an_observer_faster_than_the_loop_is_refused() {
        let err = VelocityEstimator::new(observer(1000.0), MODEL, 0.001).expect_err("too fast");
        assert!(err.to_string().contains("observer_bandwidth_rad_s"), "{err}");
        assert!(VelocityEstimator::new(observer(80.0), MODEL, 0.001).is_ok());
    }

    #[test]
    fn the_observer_runs_on_its_model_through_a_missing_angle() {
        let mut v = VelocityEstimator::new(observer(80.0), MODEL, 0.001).expect("valid");
        v.update(0.0, 0.0);
        v.update(f64::NAN, 100.0);
        assert!(v.estimate() > 0.0 && v.estimate().is_finite());
        assert!(v.update(0.0, f64::NAN).is_finite());
    }

    #[test]
    fn converges_to_a_constant_ramp_rate() {
        let mut v = VelocityEstimator::new(differentiator(40.0), MODEL, 0.001).expect("valid");
        let mut estimate = 0.0;
        for k in 0..1000 {
            estimate = v.update(0.5 * k as f64 * 0.001, 0.0);
        }
        assert!((estimate - 0.5).abs() < 1e-9);
    }

    #[test]
    fn a_nan_angle_is_skipped() {
        let mut v = VelocityEstimator::new(VelocityEstimatorParams::default(), MODEL, 0.001).expect("valid");
        v.update(0.0, 0.0);
        v.update(f64::NAN, 0.0);
        assert!(v.update(0.001, 0.0).is_finite());
    }

    #[test]
    fn first_sample_gives_no_spike() {
        let mut v = VelocityEstimator::new(VelocityEstimatorParams::default(), MODEL, 0.001).expect("valid");
        assert_eq!(v.update(3.0, 0.0), 0.0);
    }

    #[test]
    fn step_response_is_the_exact_first_order_filter() {
        let mut v = VelocityEstimator::new(differentiator(10.0), MODEL, 0.001).expect("valid");
        v.update(0.0, 0.0);
        // A unit velocity from k = 1 on: estimate_k = 1 - e^{-10 k T}.
        for k in 1..=200 {
            let e = v.update(k as f64 * 0.001, 0.0);
            assert!((e - (1.0 - (-10.0 * k as f64 * 0.001).exp())).abs() < 1e-12);
        }
    }
}
