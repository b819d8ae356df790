//! The sensor process's seam to the machine: it reads through a
//! [`SensorDevice`], which the simulated plant's readings implement (on
//! CAN, the `machine` process publishes the same readings). The valve's
//! own seam is its process's actuator, the simulated plant or the CAN
//! valve (`hydractl_processes::process::valve`).

use hydractl_samples::{service, PlantReading};

use crate::{Bus, BusError, Inlet, Input};

/// One reading from the machine's sensors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceReading {
    pub seq: u64,
    pub time_ns: u64,
    /// rad.
    pub angle: f64,
    /// Pa.
    pub p_a: f64,
    pub p_b: f64,
    /// [`hydractl_samples::source`]: the machine or the simulated plant.
    pub source: u32,
}

/// A sensor bus. The process sleeps on [`SensorDevice::input`] and then
/// takes the newest reading.
pub trait SensorDevice {
    /// The newest reading not yet taken, if any.
    fn try_read(&self) -> Result<Option<DeviceReading>, BusError>;
    /// What to wait on for new readings.
    fn input(&self) -> Input<'_>;
}

/// The simulated plant's sensor bus.
pub struct SimulatedSensors {
    readings: Inlet<PlantReading>,
}

impl SimulatedSensors {
    pub fn open(bus: &Bus) -> Result<Self, BusError> {
        Ok(Self {
            readings: Inlet::open(bus, service::PLANT_READING, 4)?,
        })
    }

    pub fn inlet(&self) -> &Inlet<PlantReading> {
        &self.readings
    }
}

impl SensorDevice for SimulatedSensors {
    fn input(&self) -> Input<'_> {
        self.readings.input()
    }

    fn try_read(&self) -> Result<Option<DeviceReading>, BusError> {
        Ok(self.readings.newest_by(|r| r.sensor_seq)?.map(|r| DeviceReading {
            seq: r.sensor_seq,
            time_ns: r.sensor_time_ns,
            angle: r.angle,
            p_a: r.p_a,
            p_b: r.p_b,
            source: r.source,
        }))
    }
}
