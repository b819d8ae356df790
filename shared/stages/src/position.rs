//! The position stage: the reference trajectory and the outer loop.

use hydractl_config::{Config, OuterPart, PositionVariant, Structure};
use hydractl_control::{Mfc, Pid, Reference, Trajectory, VelocityMethod};

use crate::{in_section, FrictionOutput, SensorEstimate, StackError};

/// The outer loop's variants.
#[derive(Debug, Clone)]
// One lives per stage and is never moved on the hot path; boxing would only
// add an indirection.
#[allow(clippy::large_enum_variant)]
pub(crate) enum OuterLoop {
    Pid(Pid),
    Mfc(Mfc),
}

/// What the position stage publishes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PositionOutput {
    pub reference: Reference,
    /// Valve command (position-only) or torque reference, N·m (cascade).
    pub output: f64,
}

/// Position stage: reference trajectory and outer loop.
#[derive(Debug, Clone)]
pub struct PositionStage {
    structure: Structure,
    variant: PositionVariant,
    trajectory: Trajectory,
    outer: OuterLoop,
    started: bool,
    /// The derivative from the sensor's velocity, not the angle's error
    /// differenced: only the observer's velocity is worth more than that.
    derivative_from_velocity: bool,
}

impl PositionStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Self::with_variant(config, config.control.outer().variant)
    }

    pub fn with_variant(config: &Config, variant: PositionVariant) -> Result<Self, StackError> {
        let outer = config.control.outer();
        let ts = config.timing.control_period();
        let outer = match variant {
            PositionVariant::Pid => OuterLoop::Pid(
                Pid::new(outer.pid, ts).map_err(in_section(config.control.outer_section(OuterPart::Pid)))?,
            ),
            PositionVariant::Mfc => OuterLoop::Mfc(
                Mfc::new(outer.mfc, ts).map_err(in_section(config.control.outer_section(OuterPart::Mfc)))?,
            ),
        };
        Ok(Self {
            structure: config.control.structure,
            variant,
            trajectory: config.trajectory.clone(),
            outer,
            started: false,
            derivative_from_velocity: config.control.velocity_estimator.method == VelocityMethod::Observer,
        })
    }

    pub fn variant(&self) -> PositionVariant {
        self.variant
    }

    pub fn structure(&self) -> Structure {
        self.structure
    }

    /// One period. The load's feed-forward joins this loop's output; the
    /// map's compensation (a valve command) only when this loop drives the
    /// valve (position-only): in the cascade the torque stage adds it.
    pub fn process(&mut self, time: f64, sensor: &SensorEstimate, friction: FrictionOutput) -> PositionOutput {
        let friction = self.feedforward(friction);
        let reference = self.trajectory.sample(time);
        let error = reference.angle - sensor.angle;
        if !self.started {
            // Start where the machine is, not at zero: a stage restarted
            // mid-run would otherwise begin with its model a whole motion
            // away. The output starts at the model's inverse dynamics; an
            // invalid reading (a late CAN PDO's NaN) starts nothing.
            self.started = match &mut self.outer {
                OuterLoop::Mfc(mfc) => {
                    let output = mfc.inverse_dynamics(reference.acceleration, reference.velocity) + friction;
                    mfc.initialize_output(output, reference.angle, sensor.angle, sensor.velocity, friction)
                }
                OuterLoop::Pid(_) => true,
            };
        }
        let output = match &mut self.outer {
            OuterLoop::Pid(pid) if self.derivative_from_velocity => {
                pid.update_with_rate(error, reference.velocity - sensor.velocity, friction)
            }
            OuterLoop::Pid(pid) => pid.update(error, friction),
            OuterLoop::Mfc(mfc) => {
                let velocity = self.derivative_from_velocity.then_some(sensor.velocity);
                mfc.update(reference.angle, sensor.angle, velocity, friction)
            }
        };
        PositionOutput { reference, output }
    }

    /// What the friction stage adds to this loop's output.
    fn feedforward(&self, friction: FrictionOutput) -> f64 {
        match self.structure {
            Structure::Position => friction.compensation + friction.load_feedforward,
            Structure::Cascade => friction.load_feedforward,
        }
    }

    /// Bumpless transfer: called after [`PositionStage::process`] for the
    /// same period, sets this loop's state as if its output had been
    /// `output`, the output of the loop it is about to replace, so that it
    /// goes on from there. A standby stage calls it every period while it
    /// tracks the running one.
    pub fn track(&mut self, output: f64, time: f64, sensor: &SensorEstimate, friction: FrictionOutput) {
        let friction = self.feedforward(friction);
        let reference = self.trajectory.sample(time);
        self.started = match &mut self.outer {
            OuterLoop::Pid(pid) => {
                pid.initialize_output(output, reference.angle - sensor.angle, friction);
                true
            }
            // A standby MFC has started (and initialized its model) on its
            // first valid period; from then on its model runs on.
            OuterLoop::Mfc(mfc) if self.started => {
                mfc.track(output);
                true
            }
            OuterLoop::Mfc(mfc) => {
                mfc.initialize_output(output, reference.angle, sensor.angle, sensor.velocity, friction)
            }
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model-following loop whose first reading is invalid (a late CAN
    /// PDO's NaN) starts on the first valid one and tracks as one that
    /// never saw it; started at the NaN, its model stayed NaN and its
    /// output held for good.
    #[test]
    fn an_invalid_first_reading_starts_nothing() {
        let config = Config::default_sim().expect("valid");
        let mut clean = PositionStage::with_variant(&config, PositionVariant::Mfc).expect("stage");
        let mut late = clean.clone();
        let ts = config.timing.control_period();
        let at = |k: usize| SensorEstimate {
            angle: 0.1 * (k as f64 * ts).sin(),
            velocity: 0.1 * (k as f64 * ts).cos(),
            ..SensorEstimate::default()
        };
        let nan = SensorEstimate {
            angle: f64::NAN,
            velocity: f64::NAN,
            ..SensorEstimate::default()
        };
        let none = FrictionOutput::default();
        late.process(0.0, &nan, none);
        for k in 1..500 {
            let time = k as f64 * ts;
            let expected = clean.process(time, &at(k), none).output;
            let output = late.process(time, &at(k), none).output;
            assert!(output.is_finite());
            assert!(
                (output - expected).abs() < 1e-9,
                "period {k}: {output} against {expected}"
            );
        }
    }
}
