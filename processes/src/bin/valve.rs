//! Command shaping and the last line of safety: publishes the valve's
//! state for every command, and neutral with a fault flag when commands
//! stop, arrive stale, or are garbage. The valve is driven neutral before
//! the loop starts and on every way out of it: a signal, an error, a
//! panic (the drop of [`Actuator`]).

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use hydractl_bus::{clock, run_loop, Inlet, Outlet, Wake};
use hydractl_processes::can_valve::CanValve;
use hydractl_samples::{fault, service, source, valid, SensorSample, TorqueSample, ValveSample};
use hydractl_stages::{ValveFaults, ValveStage};

/// Readings whose source is remembered: more than the guard's age.
const SOURCES: usize = 16;

const COMMAND: usize = 0;
const SENSOR: usize = 1;

/// The valve the command drives.
enum Device {
    /// The simulated plant reads the published state itself.
    Simulated,
    /// The machine's valve on CAN; driven only for the machine's readings
    /// (the loop on the simulated plant leaves it neutral).
    Can(Box<CanValve>),
}

/// The valve device and the valve's published state, driven together:
/// what the device is told is what the loop sees. Dropped, it drives
/// neutral, whatever ended the process's loop.
struct Actuator {
    device: Device,
    /// The source of each of the last readings, by sequence number: a
    /// command drives the machine's valve only if the reading it answers
    /// was the machine's.
    sources: [(u64, u32); SOURCES],
    /// The set point last sent and whether it was for the machine, sent
    /// again on every tick without a decision: the valve's RPDO timeout
    /// is for a dead valve process, not for a quiet loop.
    last_sent: (f64, bool),
    last_sent_at: Instant,
    out: Outlet<ValveSample>,
    newest: SensorSample,
    /// The last thing driven was [`Actuator::off`].
    is_off: bool,
}

impl Actuator {
    fn drive(&mut self, mut sample: ValveSample) -> Result<()> {
        // The device first: the valve is what moves the load.
        let mut device_fault = None;
        if let Device::Can(valve) = &mut self.device {
            let answered = self.sources[sample.sensor_seq as usize % SOURCES];
            let from_machine = self.newest.source == source::MACHINE
                && answered == (sample.sensor_seq, source::MACHINE)
                && sample.faults & fault::OFF == 0;
            valve.drive(sample.command, from_machine)?;
            self.last_sent = (sample.command, from_machine);
            self.last_sent_at = Instant::now();
            device_fault = valve.fault();
            // What the machine's valve does is what is published: neutral
            // until it reports Active.
            if from_machine && !valve.active() {
                sample.command = 0.0;
            }
            if device_fault.is_some() {
                sample.command = 0.0;
                sample.faults |= fault::DEVICE;
            }
        }
        self.is_off = sample.faults & fault::OFF != 0;
        self.out.publish(sample)?;
        match device_fault {
            // Published first, so that the loop and the recording see why.
            Some(why) => anyhow::bail!("valve: {why}; neutral sent, ending so that the valve is brought up afresh"),
            None => Ok(()),
        }
    }

    /// A reading arrived: its source noted.
    fn note(&mut self, reading: SensorSample) {
        self.newest = reading;
        self.sources[reading.sensor_seq as usize % SOURCES] = (reading.sensor_seq, reading.source);
    }

    /// No decision this tick: a CAN valve is sent its last set point again
    /// (the guard drives neutral when the silence lasts).
    fn refresh(&mut self, every: Duration) -> Result<()> {
        if let Device::Can(valve) = &mut self.device {
            if self.last_sent_at.elapsed() < every {
                return Ok(());
            }
            valve.drive(self.last_sent.0, self.last_sent.1)?;
            self.last_sent_at = Instant::now();
            if let Some(why) = valve.fault() {
                anyhow::bail!("valve: {why}; neutral sent, ending so that the valve is brought up afresh");
            }
        }
        Ok(())
    }

    /// Neutral, and a CAN valve put to hold: the process is leaving.
    fn leave(&mut self) -> Result<()> {
        let off = self.off();
        if let Device::Can(valve) = &mut self.device {
            valve.hold()?;
        }
        off
    }

    /// Neutral, answering no reading: at start and at the end.
    fn off(&mut self) -> Result<()> {
        self.drive(ValveSample {
            sensor_seq: self.newest.sensor_seq,
            sensor_time_ns: self.newest.sensor_time_ns,
            stage_time_ns: clock::now_ns(),
            command: 0.0,
            requested: f64::NAN,
            faults: fault::OFF,
            variant: 0,
        })
    }
}

impl Drop for Actuator {
    fn drop(&mut self) {
        // Nothing is left to report an error to: neutral was tried.
        if !self.is_off {
            let _ = self.leave();
        }
    }
}

fn main() -> Result<()> {
    let started = hydractl_processes::start("valve")?;
    let bus = &started.bus;
    let mut stage = ValveStage::new(&started.config)?;
    let torque: Inlet<TorqueSample> = Inlet::open(bus, service::TORQUE, 4)?;
    let sensor: Inlet<SensorSample> = Inlet::open(bus, service::SENSOR, 4)?;
    // Its output once its inputs are open (a fresh plant starts once every
    // stage publishes), and at once neutral, before any input is read.
    let device = match &started.config.can {
        Some(can) => {
            let profile = can.resolve().context("valve: [can]")?;
            Device::Can(Box::new(CanValve::open(bus, &profile)?))
        }
        None => Device::Simulated,
    };
    let mut actuator = Actuator {
        device,
        sources: [(u64::MAX, source::SIMULATION); SOURCES],
        last_sent: (0.0, false),
        last_sent_at: Instant::now(),
        out: Outlet::open(bus, service::VALVE)?,
        newest: SensorSample::default(),
        is_off: false,
    };
    actuator.off().context("valve: driving neutral at start")?;
    let silence_timeout = Duration::from_secs_f64(started.config.control.valve_guard.silence_timeout_ms / 1000.0);
    // Silence is counted from the last thing the valve drove: with readings
    // coming and commands not, the guard drives neutral reading by reading;
    // with both stopped (a stage spinning above it, the plant gone), this
    // clock does, within the timeout and a tick.
    let mut last_driven = Instant::now();
    let mut failure = None;
    // The tick is the valve's own clock, for when readings stop too.
    started.enter_realtime();
    let ended = run_loop(
        &[torque.listener(), sensor.listener()],
        Some(silence_timeout / 4),
        &started.bus,
        |wake| {
            hydractl_bus::guarded(&mut failure, || {
                // Every reading counts towards the guard, the one that woke us
                // and any that arrived with it.
                let mut neutral = None;
                while let Some(s) = sensor.next()? {
                    actuator.note(s);
                    neutral = stage.on_sensor(s.sensor_seq, s.valid == valid::ALL).or(neutral);
                }
                let newest = actuator.newest;
                let decision = match wake {
                    Wake::Input(COMMAND) => torque.latest()?.and_then(|t| {
                        let (command, faults) = stage.on_command(t.sensor_seq, t.command, t.variant)?;
                        Some((t.sensor_seq, t.sensor_time_ns, command, t.command, faults, t.variant))
                    }),
                    Wake::Input(SENSOR) => neutral.map(|(command, faults)| {
                        (newest.sensor_seq, newest.sensor_time_ns, command, f64::NAN, faults, 0)
                    }),
                    // Before the first reading the loop has not started and the
                    // valve is neutral anyway: silence means something only after.
                    Wake::Tick if newest.sensor_time_ns != 0 && last_driven.elapsed() >= silence_timeout => {
                        let (command, faults) = stage.on_silence();
                        Some((newest.sensor_seq, newest.sensor_time_ns, command, f64::NAN, faults, 0))
                    }
                    _ => None,
                };
                if decision.is_none() && wake == Wake::Tick {
                    actuator.refresh(silence_timeout / 4)?;
                }
                if let Some((seq, sensor_time_ns, command, requested, faults, variant)) = decision {
                    // Silent again after another timeout: said again.
                    last_driven = Instant::now();
                    actuator.drive(ValveSample {
                        sensor_seq: seq,
                        sensor_time_ns,
                        stage_time_ns: clock::now_ns(),
                        command,
                        requested,
                        faults: encode(faults),
                        variant,
                    })?;
                }
                Ok(())
            })
        },
    );
    // Neutral before anything is reported: the loop is over, however it ended.
    let stopped = actuator.leave().context("valve: driving neutral at the end");
    ended?;
    if let Some(e) = failure {
        return Err(e);
    }
    stopped
}

fn encode(f: ValveFaults) -> u32 {
    let mut bits = 0;
    if f.stale {
        bits |= fault::STALE;
    }
    if f.not_finite {
        bits |= fault::NOT_FINITE;
    }
    if f.out_of_range {
        bits |= fault::OUT_OF_RANGE;
    }
    if f.invalid_sensor {
        bits |= fault::INVALID_SENSOR;
    }
    if f.limit_cycle {
        bits |= fault::LIMIT_CYCLE;
    }
    bits
}
