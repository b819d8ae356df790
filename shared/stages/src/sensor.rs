//! The sensor stage: raw readings to the published estimate.

use hydractl_config::Config;
use hydractl_control::VelocityEstimator;
use hydractl_plant::RawReading;

use crate::{in_section, StackError};

/// What the sensor stage publishes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SensorEstimate {
    pub angle: f64,
    pub velocity: f64,
    /// Pa.
    pub p_a: f64,
    pub p_b: f64,
    /// D (p_a − p_b), N·m.
    pub torque: f64,
}

/// Sensor stage: raw readings to the published estimate.
#[derive(Debug, Clone)]
pub struct SensorStage {
    velocity: VelocityEstimator,
    displacement: f64,
}

impl SensorStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Ok(Self {
            velocity: VelocityEstimator::new(
                config.control.velocity_estimator,
                config.load_model(),
                config.timing.control_period(),
            )
            .map_err(in_section("control.velocity_estimator"))?,
            displacement: config.plant.displacement,
        })
    }

    pub fn process(&mut self, raw: &RawReading) -> SensorEstimate {
        let torque = self.displacement * (raw.p_a - raw.p_b);
        SensorEstimate {
            angle: raw.angle,
            velocity: self.velocity.update(raw.angle, torque),
            p_a: raw.p_a,
            p_b: raw.p_b,
            torque,
        }
    }
}
