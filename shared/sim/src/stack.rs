//! The control stack's five stages, each the algorithm one live process
//! will run: sensor → friction → position → torque → valve. The offline
//! simulator calls them in sequence; the processes will wire the same
//! objects to shared memory, which is why each stage takes plain values and
//! keeps its own state.

use hydractl_control::{
    ControlError, FrictionCompensator, HInfinity, Mfc, Pid, Reference, Trajectory, ValveShaper, VelocityEstimator,
};
use hydractl_plant::RawReading;

use crate::config::{Config, PositionVariant, Structure, TorqueVariant};

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
            velocity: VelocityEstimator::new(config.control.velocity_estimator, config.timing.control_period())
                .map_err(in_section("control.velocity_estimator"))?,
            displacement: config.plant.displacement,
        })
    }

    pub fn process(&mut self, raw: &RawReading) -> SensorEstimate {
        SensorEstimate {
            angle: raw.angle,
            velocity: self.velocity.update(raw.angle),
            p_a: raw.p_a,
            p_b: raw.p_b,
            torque: self.displacement * (raw.p_a - raw.p_b),
        }
    }
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
                .map_err(in_section(outer_section(config, "friction")))?,
        })
    }

    pub fn process(&mut self, sensor: &SensorEstimate, reference_velocity: f64, valve_command: f64) -> f64 {
        self.compensator
            .update(sensor.velocity, reference_velocity, valve_command)
    }
}

fn outer_section(config: &Config, part: &'static str) -> &'static str {
    match (config.control.structure, part) {
        (Structure::Position, "friction") => "control.position_only.friction",
        (Structure::Position, "pid") => "control.position_only.pid",
        (Structure::Position, _) => "control.position_only.mfc",
        (Structure::Cascade, "friction") => "control.cascade.friction",
        (Structure::Cascade, "pid") => "control.cascade.pid",
        (Structure::Cascade, _) => "control.cascade.mfc",
    }
}

/// The outer loop's variants.
#[derive(Debug, Clone)]
// One lives per stage and is never moved on the hot path; boxing would only
// add an indirection.
#[allow(clippy::large_enum_variant)]
pub enum OuterLoop {
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
    trajectory: Trajectory,
    outer: OuterLoop,
}

impl PositionStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Self::with_variant(config, config.control.outer().variant)
    }

    pub fn with_variant(config: &Config, variant: PositionVariant) -> Result<Self, StackError> {
        let outer = config.control.outer();
        let ts = config.timing.control_period();
        let outer = match variant {
            PositionVariant::Pid => {
                OuterLoop::Pid(Pid::new(outer.pid, ts).map_err(in_section(outer_section(config, "pid")))?)
            }
            PositionVariant::Mfc => {
                OuterLoop::Mfc(Mfc::new(outer.mfc, ts).map_err(in_section(outer_section(config, "mfc")))?)
            }
        };
        Ok(Self {
            trajectory: config.trajectory.clone(),
            outer,
        })
    }

    pub fn process(&mut self, time: f64, sensor: &SensorEstimate, friction: f64) -> PositionOutput {
        let reference = self.trajectory.sample(time);
        let error = reference.angle - sensor.angle;
        let output = match &mut self.outer {
            OuterLoop::Pid(pid) => pid.update(error, friction),
            OuterLoop::Mfc(mfc) => mfc.update(reference.angle, sensor.angle, friction),
        };
        PositionOutput { reference, output }
    }
}

/// The inner loop's variants.
#[derive(Debug, Clone)]
pub enum InnerLoop {
    Pid(Pid),
    HInfinity(HInfinity),
}

/// Torque stage: the inner loop, torque reference to valve command.
#[derive(Debug, Clone)]
pub struct TorqueStage {
    inner: InnerLoop,
    ts: f64,
    velocity_feedforward: f64,
    rate_feedforward: f64,
    rate_blend: f64,
    previous_reference: Option<f64>,
    reference_rate: f64,
}

impl TorqueStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Self::with_variant(config, config.control.torque_variant)
    }

    pub fn with_variant(config: &Config, variant: TorqueVariant) -> Result<Self, StackError> {
        let ts = config.timing.control_period();
        let torque = &config.control.torque;
        hydractl_control::require_finite("velocity_feedforward", torque.velocity_feedforward)
            .map_err(in_section("control.torque"))?;
        hydractl_control::require_finite("rate_feedforward", torque.rate_feedforward)
            .map_err(in_section("control.torque"))?;
        hydractl_control::require_non_negative_pub("rate_filter_s", torque.rate_filter_s)
            .map_err(in_section("control.torque"))?;
        let inner = match variant {
            TorqueVariant::Pid => {
                InnerLoop::Pid(Pid::new(config.control.torque.pid, ts).map_err(in_section("control.torque.pid"))?)
            }
            TorqueVariant::Hinf => InnerLoop::HInfinity(
                HInfinity::new(config.control.torque.hinf.clone(), ts).map_err(in_section("control.torque.hinf"))?,
            ),
        };
        Ok(Self {
            inner,
            ts,
            velocity_feedforward: torque.velocity_feedforward,
            rate_feedforward: torque.rate_feedforward,
            rate_blend: ts / (torque.rate_filter_s + ts),
            previous_reference: None,
            reference_rate: 0.0,
        })
    }

    /// The valve command for a torque reference; `friction` is the friction
    /// compensation in valve-command units, added as the rotary paper adds
    /// it to its torque PID.
    pub fn process(
        &mut self,
        torque_reference: f64,
        reference_velocity: f64,
        sensor: &SensorEstimate,
        friction: f64,
    ) -> f64 {
        let previous = self.previous_reference.unwrap_or(torque_reference);
        self.previous_reference = Some(torque_reference);
        self.reference_rate += self.rate_blend * ((torque_reference - previous) / self.ts - self.reference_rate);
        let feedforward =
            friction + self.velocity_feedforward * reference_velocity + self.rate_feedforward * self.reference_rate;
        let error = torque_reference - sensor.torque;
        match &mut self.inner {
            InnerLoop::Pid(pid) => pid.update(error, feedforward),
            InnerLoop::HInfinity(hinf) => (hinf.update(error) + feedforward).clamp(-1.0, 1.0),
        }
    }
}

/// Valve stage: command shaping.
#[derive(Debug, Clone)]
pub struct ValveStage {
    shaper: ValveShaper,
}

impl ValveStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Ok(Self {
            shaper: ValveShaper::new(config.control.valve, config.timing.control_period())
                .map_err(in_section("control.valve"))?,
        })
    }

    pub fn process(&mut self, command: f64) -> f64 {
        self.shaper.update(command)
    }
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
    pub friction: f64,
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
        // The friction compensation is a valve command (the crane paper's
        // pseudo-friction is "the valve current required to overcome
        // friction"), so it joins whichever loop drives the valve.
        let (position, torque_reference, demand) = match self.structure {
            Structure::Position => {
                let position = self.position.process(time, &sensor, friction);
                (position, f64::NAN, position.output)
            }
            Structure::Cascade => {
                let position = self.position.process(time, &sensor, 0.0);
                let demand = self
                    .torque
                    .process(position.output, position.reference.velocity, &sensor, friction);
                (position, position.output, demand)
            }
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
