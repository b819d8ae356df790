//! The inner torque loop on each position sample (passes the command
//! through in position-only control).

use anyhow::Result;
use hydractl_bus::{clock, run_single, Inlet, Outlet, Reader};
use hydractl_processes::estimate_of;
use hydractl_samples::{code, service, FrictionSample, PositionSample, SensorSample, TorqueSample};
use hydractl_sim::stack::{PositionOutput, TorqueStage};
use hydractl_sim::TorqueVariant;

fn main() -> Result<()> {
    let started = hydractl_processes::start("torque")?;
    let bus = &started.bus;
    let mut stage = TorqueStage::new(&started.config)?;
    let sensor: Reader<SensorSample> = Reader::open(bus, service::SENSOR, 4)?;
    let friction: Reader<FrictionSample> = Reader::open(bus, service::FRICTION, 4)?;
    let position: Inlet<PositionSample> = Inlet::open(bus, service::POSITION, 4)?;
    let out: Outlet<TorqueSample> = Outlet::open(bus, service::TORQUE)?;
    let variant = match stage.variant() {
        TorqueVariant::Pid => code::VARIANT_PID,
        TorqueVariant::Hinf => code::VARIANT_HINF,
    };
    let (mut latest_sensor, mut latest_friction) = (SensorSample::default(), FrictionSample::default());
    let mut failure = None;
    run_single(position.listener(), &started.bus, || {
        hydractl_bus::guarded(&mut failure, || {
            if let Some(s) = sensor.latest()? {
                latest_sensor = s;
            }
            if let Some(f) = friction.latest()? {
                latest_friction = f;
            }
            let Some(p) = position.latest()? else { return Ok(()) };
            let output = PositionOutput {
                reference: hydractl_sim::Reference {
                    angle: p.reference_angle,
                    velocity: p.reference_velocity,
                    acceleration: p.reference_acceleration,
                },
                output: p.output,
            };
            let command = stage.process(&output, &estimate_of(&latest_sensor), latest_friction.compensation);
            out.publish(TorqueSample {
                sensor_seq: p.sensor_seq,
                sensor_time_ns: p.sensor_time_ns,
                stage_time_ns: clock::now_ns(),
                torque_reference: p.output,
                torque: latest_sensor.torque,
                command,
                variant,
                reserved: 0,
            })?;
            Ok(())
        })
    })?;
    failure.map_or(Ok(()), Err)
}
