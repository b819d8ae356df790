//! The crane paper's friction compensation (its eq. 1) on each sensor
//! sample, with the previous period's reference velocity and valve command.

use crate::estimate_of;
use anyhow::Result;
use hydractl_bus::{clock, run_single, Inlet, Outlet, Reader};
use hydractl_samples::{service, FrictionSample, PositionSample, SensorSample, ValveSample};
use hydractl_stages::FrictionStage;

pub fn run() -> Result<()> {
    let started = crate::start("friction")?;
    let bus = &started.bus;
    let mut stage = FrictionStage::new(&started.config)?;
    let sensor: Inlet<SensorSample> = Inlet::open(bus, service::SENSOR, 4)?;
    let position: Reader<PositionSample> = Reader::open(bus, service::POSITION, 4)?;
    let valve: Reader<ValveSample> = Reader::open(bus, service::VALVE, 4)?;
    let out: Outlet<FrictionSample> = Outlet::open(bus, service::FRICTION)?;
    let (mut reference_velocity, mut valve_command) = (0.0, 0.0);
    let mut failure = None;
    started.enter_realtime();
    run_single(sensor.input(), &started.bus, || {
        hydractl_bus::guarded(&mut failure, || {
            if let Some(p) = position.latest()? {
                reference_velocity = p.reference_velocity;
            }
            if let Some(v) = valve.latest()? {
                valve_command = v.command;
            }
            let Some(s) = sensor.latest()? else { return Ok(()) };
            let friction = stage.process(&estimate_of(&s), reference_velocity, valve_command);
            out.publish(FrictionSample {
                sensor_seq: s.sensor_seq,
                sensor_time_ns: s.sensor_time_ns,
                stage_time_ns: clock::now_ns(),
                compensation: friction.compensation,
                blended_velocity: stage.blended_velocity(),
                load_feedforward: friction.load_feedforward,
            })?;
            Ok(())
        })
    })?;
    failure.map_or(Ok(()), Err)
}
