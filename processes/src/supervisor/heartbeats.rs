//! The loop's heartbeats: the newest reading each stage's output answered.

use anyhow::Result;
use hydractl_bus::{Bus, Reader};
use hydractl_control::LimitCycleDetector;
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
    outer: OuterLoopWatch,
    /// The sensor stage's newest velocity estimate, rad/s: a restarted
    /// plant resumes moving as the load was.
    pub(super) velocity: f64,
}

/// Whether the outer loop's output limit-cycles by itself, judged as the
/// valve judges its commands, on the output scaled by the largest the
/// outer loop has given since it started: an inner loop that only follows
/// a limit-cycling reference is not to blame.
pub(super) struct OuterLoopWatch {
    detector: LimitCycleDetector,
    largest: f64,
    pub(super) limit_cycling: bool,
}

impl OuterLoopWatch {
    pub(super) fn new(detector: LimitCycleDetector) -> Self {
        Self {
            detector,
            largest: 0.0,
            limit_cycling: false,
        }
    }

    pub(super) fn push(&mut self, seq: u64, output: f64) {
        if !output.is_finite() {
            return;
        }
        self.largest = self.largest.max(output.abs());
        if self.largest > 0.0 {
            self.limit_cycling = self.detector.update(seq, output / self.largest);
        }
    }

    /// A new outer loop process: its output is judged afresh.
    pub(super) fn reset(&mut self) {
        self.detector.reset();
        self.largest = 0.0;
        self.limit_cycling = false;
    }
}

impl Heartbeats {
    pub(super) fn open(bus: &Bus, outer: OuterLoopWatch) -> Result<Self> {
        Ok(Self {
            plant: Reader::open(bus, service::PLANT_READING, 4)?,
            sensor: Reader::open(bus, service::SENSOR, 4)?,
            friction: Reader::open(bus, service::FRICTION, 4)?,
            // Every output, for the outer loop's limit-cycle watch.
            position: Reader::open(bus, service::POSITION, 256)?,
            torque: Reader::open(bus, service::TORQUE, 4)?,
            valve: Reader::open(bus, service::VALVE, 4)?,
            outer,
            velocity: 0.0,
        })
    }

    /// The outer loop's limit-cycle watch.
    pub(super) fn outer_loop(&mut self) -> &mut OuterLoopWatch {
        &mut self.outer
    }

    /// The newest reading each of the pipeline's outputs answered since the
    /// last call (`None`: it did not advance), in `PIPELINE` order; keeps
    /// the plant's last reading for a restart.
    pub(super) fn advanced(
        &mut self,
        last_reading: &mut Option<PlantReading>,
        position_output_finite: &mut bool,
    ) -> Result<[Option<Answer>; 6]> {
        let reading = self.plant.newest_by(|r| r.sensor_seq)?;
        if reading.is_some() {
            *last_reading = reading;
        }
        let mut position = None;
        while let Some(p) = self.position.next()? {
            self.outer.push(p.sensor_seq, p.output);
            position = Some(p);
        }
        if let Some(p) = position {
            *position_output_finite = p.output.is_finite();
        }
        Ok([
            reading.map(|r| Answer::new(r.sensor_seq, r.sensor_time_ns)),
            self.sensor.latest()?.map(|s| {
                if s.velocity.is_finite() {
                    self.velocity = s.velocity;
                }
                Answer::new(s.sensor_seq, s.stage_time_ns)
            }),
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
