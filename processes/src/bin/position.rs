//! The outer loop and the reference trajectory, on each friction sample.

use anyhow::Result;
use hydractl_bus::{clock, run_single, Inlet, Outlet, Reader};
use hydractl_processes::{estimate_of, time_of};
use hydractl_samples::{code, service, FrictionSample, PositionSample, SensorSample};
use hydractl_sim::stack::PositionStage;
use hydractl_sim::{PositionVariant, Structure};

fn main() -> Result<()> {
    let started = hydractl_processes::start("position")?;
    let (bus, config) = (&started.bus, &started.config);
    let mut stage = PositionStage::new(config)?;
    let sensor: Reader<SensorSample> = Reader::open(bus, service::SENSOR, 4)?;
    let friction: Inlet<FrictionSample> = Inlet::open(bus, service::FRICTION, 4)?;
    let out: Outlet<PositionSample> = Outlet::open(bus, service::POSITION)?;
    let structure = match stage.structure() {
        Structure::Position => code::STRUCTURE_POSITION,
        Structure::Cascade => code::STRUCTURE_CASCADE,
    };
    let variant = match stage.variant() {
        PositionVariant::Pid => code::VARIANT_PID,
        PositionVariant::Mfc => code::VARIANT_MFC,
    };
    let mut latest_sensor = SensorSample::default();
    let mut failure = None;
    run_single(friction.listener(), &started.bus, || {
        hydractl_bus::guarded(&mut failure, || {
            if let Some(s) = sensor.latest()? {
                latest_sensor = s;
            }
            let Some(f) = friction.latest()? else { return Ok(()) };
            let output = stage.process(
                time_of(f.sensor_seq, config),
                &estimate_of(&latest_sensor),
                f.compensation,
            );
            out.publish(PositionSample {
                sensor_seq: f.sensor_seq,
                sensor_time_ns: f.sensor_time_ns,
                stage_time_ns: clock::now_ns(),
                reference_angle: output.reference.angle,
                reference_velocity: output.reference.velocity,
                reference_acceleration: output.reference.acceleration,
                angle: latest_sensor.angle,
                output: output.output,
                structure,
                variant,
            })?;
            Ok(())
        })
    })?;
    failure.map_or(Ok(()), Err)
}
