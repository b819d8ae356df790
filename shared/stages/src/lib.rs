//! The control stack's five stages, each the algorithm one live process
//! runs: sensor → friction → position → torque → valve. The offline
//! simulator calls them in sequence in one process ([`ControlStack`]); the
//! live processes wire the same objects to shared memory, which is why each
//! stage takes plain values and keeps its own state.
//!
//! What it holds: The five stages exactly as the live processes run them, one
//! file each: sensor → friction → position → torque → valve (the valve's
//! guard: stale, garbage, invalid-reading and limit-cycle checks), and
//! `ControlStack`, all five in one process. Every live stage process imports
//! its stage from here.

mod friction;
mod position;
mod sensor;
mod torque;
mod valve;

use hydractl_config::{Config, Structure};
use hydractl_control::ControlError;
use hydractl_plant::RawReading;

pub use friction::{FrictionOutput, FrictionStage};
pub use position::{PositionOutput, PositionStage};
pub use sensor::{SensorEstimate, SensorStage};
pub use torque::TorqueStage;
pub use valve::{ValveFaults, ValveStage};

#[derive(Debug, thiserror::Error)]
pub enum StackError {
    #[error("[{section}] {source}")]
    Control {
        section: &'static str,
        source: ControlError,
    },
}

fn in_section(section: &'static str) -> impl Fn(ControlError) -> StackError {
    move |source| StackError::Control { section, source }
}

/// All five stages, for running the loop in one process.
#[derive(Debug, Clone)]
pub struct ControlStack {
    pub structure: Structure,
    pub sensor: SensorStage,
    pub friction: FrictionStage,
    pub position: PositionStage,
    pub torque: TorqueStage,
    pub valve: ValveStage,
    last_reference_velocity: f64,
    last_command: f64,
}

/// One period's signals through the stack.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StackOutput {
    pub sensor: SensorEstimate,
    pub friction: FrictionOutput,
    pub position: PositionOutput,
    /// The torque reference (cascade), or NaN in position-only control.
    pub torque_reference: f64,
    /// The command sent to the valve.
    pub command: f64,
}

impl ControlStack {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Ok(Self {
            structure: config.control.structure,
            sensor: SensorStage::new(config)?,
            friction: FrictionStage::new(config)?,
            position: PositionStage::new(config)?,
            torque: TorqueStage::new(config)?,
            valve: ValveStage::new(config)?,
            last_reference_velocity: 0.0,
            last_command: 0.0,
        })
    }

    /// One control period, from the raw readings at `time` to the valve command.
    pub fn step(&mut self, time: f64, raw: &RawReading) -> StackOutput {
        let sensor = self.sensor.process(raw);
        let friction = self
            .friction
            .process(&sensor, self.last_reference_velocity, self.last_command);
        let position = self.position.process(time, &sensor, friction);
        let demand = self.torque.process(&position, &sensor, friction.compensation);
        let torque_reference = match self.structure {
            Structure::Position => f64::NAN,
            Structure::Cascade => position.output,
        };
        let command = self.valve.process(demand);
        self.last_reference_velocity = position.reference.velocity;
        self.last_command = command;
        StackOutput {
            sensor,
            friction,
            position,
            torque_reference,
            command,
        }
    }
}
