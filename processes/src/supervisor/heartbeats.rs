//! The loop's heartbeats: the newest reading each stage's output answered.

use anyhow::Result;
use hydractl_bus::{Bus, Reader};
use hydractl_samples::{
    service, FrictionSample, PlantReading, PositionSample, SensorSample, TorqueSample, ValveSample,
};

/// The newest sequence number seen on each pipeline service.
pub(super) struct Heartbeats {
    plant: Reader<PlantReading>,
    sensor: Reader<SensorSample>,
    friction: Reader<FrictionSample>,
    position: Reader<PositionSample>,
    torque: Reader<TorqueSample>,
    valve: Reader<ValveSample>,
}

impl Heartbeats {
    pub(super) fn open(bus: &Bus) -> Result<Self> {
        Ok(Self {
            plant: Reader::open(bus, service::PLANT_READING, 4)?,
            sensor: Reader::open(bus, service::SENSOR, 4)?,
            friction: Reader::open(bus, service::FRICTION, 4)?,
            position: Reader::open(bus, service::POSITION, 4)?,
            torque: Reader::open(bus, service::TORQUE, 4)?,
            valve: Reader::open(bus, service::VALVE, 4)?,
        })
    }

    /// The newest reading each of the pipeline's outputs answered since the
    /// last call (`None`: it did not advance), in `PIPELINE` order; keeps
    /// the plant's last reading for a restart.
    pub(super) fn advanced(
        &self,
        last_reading: &mut Option<PlantReading>,
        position_output_finite: &mut bool,
    ) -> Result<[Option<Answer>; 6]> {
        let reading = self.plant.newest_by(|r| r.sensor_seq)?;
        if reading.is_some() {
            *last_reading = reading;
        }
        let position = self.position.latest()?;
        if let Some(p) = position {
            *position_output_finite = p.output.is_finite();
        }
        Ok([
            reading.map(|r| Answer::new(r.sensor_seq, r.sensor_time_ns)),
            self.sensor
                .latest()?
                .map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
            self.friction
                .latest()?
                .map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
            position.map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
            self.torque
                .latest()?
                .map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
            self.valve.latest()?.map(|s| Answer::new(s.sensor_seq, s.stage_time_ns)),
        ])
    }
}

/// A process's newest output: the reading it answered, and when.
#[derive(Debug, Clone, Copy)]
pub(super) struct Answer {
    pub(super) seq: u64,
    pub(super) time_ns: u64,
}

impl Answer {
    pub(super) fn new(seq: u64, time_ns: u64) -> Self {
        Self { seq, time_ns }
    }
}
