//! Reads the plant's readings (the simulated plant's, or on CAN the
//! `machine` process's: the same service) and publishes the sensor sample:
//! angle, velocity estimate, pressures, torque, validity.

use anyhow::Result;
use hydractl_bus::{clock, run_single, Inlet, Outlet};
use hydractl_plant::RawReading;
use hydractl_samples::{service, valid, PlantReading, SensorSample};
use hydractl_stages::SensorStage;

pub fn run() -> Result<()> {
    let started = crate::start("sensor")?;
    let mut stage = SensorStage::new(&started.config)?;
    let readings: Inlet<PlantReading> = Inlet::open(&started.bus, service::PLANT_READING, 4)?;
    let out: Outlet<SensorSample> = Outlet::open(&started.bus, service::SENSOR)?;
    let mut failure = None;
    started.enter_realtime();
    run_single(readings.input(), &started.bus, || {
        hydractl_bus::guarded(&mut failure, || {
            let Some(reading) = readings.newest_by(|r| r.sensor_seq)? else {
                return Ok(());
            };
            let mut flags = 0;
            if reading.angle.is_finite() {
                flags |= valid::ANGLE;
            }
            if reading.p_a.is_finite() {
                flags |= valid::PRESSURE_A;
            }
            if reading.p_b.is_finite() {
                flags |= valid::PRESSURE_B;
            }
            let estimate = stage.process(&RawReading {
                angle: reading.angle,
                p_a: reading.p_a,
                p_b: reading.p_b,
            });
            out.publish(SensorSample {
                sensor_seq: reading.sensor_seq,
                sensor_time_ns: reading.sensor_time_ns,
                stage_time_ns: clock::now_ns(),
                angle: estimate.angle,
                velocity: estimate.velocity,
                p_a: estimate.p_a,
                p_b: estimate.p_b,
                torque: estimate.torque,
                valid: flags,
                source: reading.source,
            })?;
            Ok(())
        })
    })?;
    failure.map_or(Ok(()), Err)
}
