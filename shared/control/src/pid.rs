use serde::{Deserialize, Serialize};

use crate::{require, require_non_negative, ControlError};

/// A PID's parameters, in the units of its error and output.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PidParams {
    pub kp: f64,
    pub ki: f64,
    pub kd: f64,
    /// Time constant of the derivative's low-pass filter, s.
    pub derivative_filter_s: f64,
    pub output_min: f64,
    pub output_max: f64,
}

impl Default for PidParams {
    fn default() -> Self {
        Self {
            kp: 1.0,
            ki: 0.0,
            kd: 0.0,
            derivative_filter_s: 0.005,
            output_min: f64::NEG_INFINITY,
            output_max: f64::INFINITY,
        }
    }
}

impl PidParams {
    pub fn validate(&self) -> Result<(), ControlError> {
        require_non_negative("kp", self.kp)?;
        require_non_negative("ki", self.ki)?;
        require_non_negative("kd", self.kd)?;
        require_non_negative("derivative_filter_s", self.derivative_filter_s)?;
        if self.output_min.is_nan() || self.output_max.is_nan() || self.output_min >= self.output_max {
            return Err(ControlError::InvalidParameter {
                name: "output_max",
                value: self.output_max,
                reason: "must be above output_min",
            });
        }
        Ok(())
    }
}

/// A discrete PID: derivative of the error (or a given rate) through a first-order filter,
/// output limits with anti-windup, and a feed-forward input that counts
/// towards saturation. A non-finite input holds the last output and leaves
/// the state untouched, so one bad sample cannot poison the integrator.
#[derive(Debug, Clone)]
pub struct Pid {
    params: PidParams,
    ts: f64,
    integral: f64,
    derivative: f64,
    previous_error: Option<f64>,
    output: f64,
}

impl Pid {
    pub fn new(params: PidParams, ts: f64) -> Result<Self, ControlError> {
        params.validate()?;
        require("sample time", ts, ts > 0.0, "must be positive")?;
        Ok(Self {
            params,
            ts,
            integral: 0.0,
            derivative: 0.0,
            previous_error: None,
            output: 0.0,
        })
    }

    pub fn params(&self) -> &PidParams {
        &self.params
    }

    pub fn reset(&mut self) {
        self.integral = 0.0;
        self.derivative = 0.0;
        self.previous_error = None;
        self.output = 0.0;
    }

    pub fn output(&self) -> f64 {
        self.output
    }

    /// One period: the output for `error`, with `feedforward` added before
    /// the limits.
    pub fn update(&mut self, error: f64, feedforward: f64) -> f64 {
        let previous = self.previous_error.unwrap_or(error);
        self.update_with_rate(error, (error - previous) / self.ts, feedforward)
    }

    /// One period with the error's rate given rather than differenced: a
    /// loop that has an estimate of the velocity puts it here, so that the
    /// derivative is not the encoder's counts differenced once more. The
    /// rate passes the derivative's filter all the same.
    pub fn update_with_rate(&mut self, error: f64, error_rate: f64, feedforward: f64) -> f64 {
        if !(error.is_finite() && error_rate.is_finite() && feedforward.is_finite()) {
            return self.output;
        }
        let p = &self.params;
        let raw_derivative = error_rate;
        let blend = self.ts / (p.derivative_filter_s + self.ts);
        self.derivative += blend * (raw_derivative - self.derivative);
        self.previous_error = Some(error);

        let rest = p.kp * error + p.kd * self.derivative + feedforward;
        let unsaturated = rest + self.integral;
        let output = unsaturated.clamp(p.output_min, p.output_max);
        // Anti-windup: never integrate further into a limit, and while at a
        // limit keep the integrator no further past it than the rest of the
        // output asks; but never push it past zero for what the
        // feed-forward or the proportional part did alone.
        let pushing_into_limit = (output >= p.output_max && error > 0.0) || (output <= p.output_min && error < 0.0);
        if !pushing_into_limit {
            self.integral += p.ki * self.ts * error;
        }
        if output >= p.output_max {
            self.integral = self.integral.min((p.output_max - rest).max(0.0));
        } else if output <= p.output_min {
            self.integral = self.integral.max((p.output_min - rest).min(0.0));
        }
        self.output = output;
        output
    }

    /// A start with nothing integrated, `error` remembered as the last one
    /// seen, so that the derivative starts from the motion, not a jump.
    pub(crate) fn start_from(&mut self, error: f64) {
        self.reset();
        self.previous_error = Some(error);
    }

    /// Bumpless start: sets the integrator so that, for this `error` and
    /// `feedforward`, the output is `output`. Non-finite inputs (an invalid
    /// reading) leave the state as it is: a NaN integrator would never
    /// recover.
    pub fn initialize_output(&mut self, output: f64, error: f64, feedforward: f64) {
        if !(output.is_finite() && error.is_finite() && feedforward.is_finite()) {
            return;
        }
        let p = &self.params;
        let output = output.clamp(p.output_min, p.output_max);
        self.derivative = 0.0;
        self.previous_error = Some(error);
        self.integral = output - p.kp * error - feedforward;
        self.output = output;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pid(kp: f64, ki: f64, kd: f64) -> Pid {
        Pid::new(
            PidParams {
                kp,
                ki,
                kd,
                derivative_filter_s: 0.0,
                ..PidParams::default()
            },
            0.001,
        )
        .expect("valid")
    }

    #[test]
    fn matches_a_hand_computed_sequence() {
        let mut c = pid(2.0, 10.0, 0.1);
        // k=0: e=1: P=2, I=0 (integrates after), D=0 (no previous error).
        assert!((c.update(1.0, 0.0) - 2.0).abs() < 1e-12);
        // k=1: e=1.5: P=3, I=10*0.001*1=0.01, D=0.1*(0.5/0.001)=50.
        assert!((c.update(1.5, 0.0) - 53.01).abs() < 1e-9);
        // k=2: e=1.5: P=3, I=0.01+0.015=0.025, D=0.
        assert!((c.update(1.5, 0.0) - 3.025).abs() < 1e-9);
    }

    #[test]
    fn anti_windup_keeps_the_integrator_bounded() {
        let mut c = Pid::new(
            PidParams {
                kp: 1.0,
                ki: 100.0,
                output_min: -1.0,
                output_max: 1.0,
                ..PidParams::default()
            },
            0.001,
        )
        .expect("valid");
        for _ in 0..10_000 {
            assert!(c.update(5.0, 0.0) <= 1.0);
        }
        // Without windup, reversing the error brings the output off the
        // limit within a few periods.
        let mut periods = 0;
        while c.update(-0.5, 0.0) >= 1.0 {
            periods += 1;
            assert!(periods < 100, "wound up");
        }
    }

    #[test]
    fn feedforward_past_the_limit_does_not_wind_the_integrator_backwards() {
        let mut c = Pid::new(
            PidParams {
                kp: 0.0,
                ki: 1.0,
                output_min: -1.0,
                output_max: 1.0,
                derivative_filter_s: 0.0,
                ..PidParams::default()
            },
            0.001,
        )
        .expect("valid");
        for _ in 0..1000 {
            c.update(0.0, 5.0);
        }
        // The feed-forward drops: no undershoot from a wound-back integrator.
        assert!(c.update(0.0, 0.0).abs() < 1e-12);
    }

    #[test]
    fn a_nan_holds_the_output_and_spares_the_state() {
        let mut c = pid(2.0, 5.0, 0.0);
        let before = c.update(0.1, 0.0);
        assert_eq!(c.update(f64::NAN, 0.0), before);
        assert!(c.update(0.1, 0.0).is_finite());
    }

    #[test]
    fn initialize_output_is_bumpless() {
        let mut c = pid(2.0, 5.0, 0.0);
        c.initialize_output(0.37, 0.1, 0.05);
        // An invalid reading's NaN changes nothing.
        c.initialize_output(0.37, f64::NAN, 0.05);
        assert!((c.update(0.1, 0.05) - 0.37).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(Pid::new(
            PidParams {
                kp: -1.0,
                ..PidParams::default()
            },
            0.001
        )
        .is_err());
        assert!(Pid::new(
            PidParams {
                kp: f64::NAN,
                ..PidParams::default()
            },
            0.001
        )
        .is_err());
        assert!(Pid::new(PidParams::default(), 0.0).is_err());
    }
}
