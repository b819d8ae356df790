//! The friction stage: the crane paper's eq. (1).

use hydractl_config::{Config, OuterPart};
use hydractl_control::FrictionCompensator;

use crate::{in_section, SensorEstimate, StackError};

/// What the friction stage gives the loops downstream.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrictionOutput {
    /// The map's compensation, valve command.
    pub compensation: f64,
    /// The load's feed-forward (Coulomb friction, gravity), in the outer
    /// loop's output units.
    pub load_feedforward: f64,
}

/// Friction stage: the crane paper's eq. (1) on the previous period's
/// reference velocity and valve command (both are one period old in the
/// live pipeline too, since friction runs before position and valve).
#[derive(Debug, Clone)]
pub struct FrictionStage {
    compensator: FrictionCompensator,
}

impl FrictionStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        let outer = config.control.outer();
        Ok(Self {
            compensator: FrictionCompensator::new(outer.friction.clone())
                .map_err(in_section(config.control.outer_section(OuterPart::Friction)))?,
        })
    }

    pub fn process(&mut self, sensor: &SensorEstimate, reference_velocity: f64, valve_command: f64) -> FrictionOutput {
        let compensation = self
            .compensator
            .update(sensor.velocity, reference_velocity, valve_command);
        FrictionOutput {
            compensation,
            load_feedforward: self.compensator.load_feedforward(sensor.angle),
        }
    }

    /// The blended velocity of eq. (1) behind the last compensation.
    pub fn blended_velocity(&self) -> f64 {
        self.compensator.blended_velocity()
    }
}
