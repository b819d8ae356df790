//! Command shaping and the last line of safety: publishes the valve's
//! state for every command, and neutral with a fault flag when commands
//! stop, arrive stale, or are garbage. The valve is driven neutral before
//! the loop starts and on every way out of it: a signal, an error, a
//! panic (the drop of `Actuator`).

use std::cell::Cell;
use std::time::{Duration, Instant};

use crate::can_valve::CanValve;
use crate::valve_latch::{latch_path, FaultLatch};
use anyhow::{Context, Result};
use hydractl_bus::{clock, run_until, Inlet, Outlet, Reader, Wake};
use hydractl_samples::{fault, service, source, valid, SensorSample, TorqueSample, ValveSample};
use hydractl_stages::{ValveFaults, ValveStage};

use super::valve_desk::ValveDesk;

/// Readings whose source is remembered: more than the guard's age.
const SOURCES: usize = 16;

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
pub(super) struct Actuator {
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
    /// The command the loop last asked of the valve, before the guards.
    pub(super) last_requested: f64,
}

impl Actuator {
    /// Drives the device and publishes what it does. Returns whether the
    /// command was applied: false when the machine's valve holds neutral
    /// (not Active, or a fault latched), so the shaper starts from there.
    fn drive(&mut self, mut sample: ValveSample) -> Result<bool> {
        // The device first: the valve is what moves the load.
        let mut applied = true;
        if let Device::Can(valve) = &mut self.device {
            let answered = self.sources[sample.sensor_seq as usize % SOURCES];
            let from_machine = self.newest.source == source::MACHINE
                && answered == (sample.sensor_seq, source::MACHINE)
                && sample.faults & fault::OFF == 0;
            let sent = valve.drive(sample.command, from_machine)?;
            self.last_sent = (sample.command, from_machine);
            self.last_sent_at = Instant::now();
            // What the machine's valve does is what is published: neutral
            // until it reports Active, and while a fault is latched.
            if from_machine && !sent {
                sample.command = 0.0;
                applied = false;
                if valve.latched().is_some() {
                    sample.faults |= fault::DEVICE;
                }
            }
        }
        if sample.requested.is_finite() {
            self.last_requested = sample.requested;
        }
        self.is_off = sample.faults & fault::OFF != 0;
        self.out.publish(sample)?;
        Ok(applied)
    }

    /// The machine's valve, when the loop drives one.
    pub(super) fn can_valve(&mut self) -> Option<&mut CanValve> {
        match &mut self.device {
            Device::Can(valve) => Some(valve),
            Device::Simulated => None,
        }
    }

    /// Whether the loop's newest reading is the machine's.
    pub(super) fn on_machine(&self) -> bool {
        self.newest.source == source::MACHINE
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
        }
        Ok(())
    }

    /// Neutral, and a CAN valve put to hold: the process is leaving.
    fn leave(&mut self) -> Result<()> {
        let off = self.off();
        if let Device::Can(valve) = &mut self.device {
            valve.hold()?;
        }
        off.map(|_| ())
    }

    /// Neutral, answering no reading: at start and at the end.
    fn off(&mut self) -> Result<bool> {
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

/// The valve's own clock: when it looks at the readings without being
/// woken by a command. Commands wake the valve; readings do not (a wake at
/// every reading would take the loop's CPU in the chain's middle, the
/// valve being one priority above it). A reading matters to the guard only
/// once no command answers it in time, so the valve looks when the reading
/// that trips the stale guard is due, and every period after that until a
/// command comes; and at least every `tick`, for the silence guard and a
/// CAN valve's repeated set point.
#[derive(Clone, Copy)]
struct ValveClock {
    period_ns: u64,
    /// From the reading the newest command answered to the reading that
    /// trips the guard (`max_age_periods` + 1 periods on), and a quarter
    /// period more for it to pass the sensor stage.
    overdue_after_ns: u64,
    tick_ns: u64,
    /// The next look at the readings, ns on the monotonic clock.
    look_at_ns: u64,
    last_wake_ns: u64,
}

impl ValveClock {
    fn new(config: &hydractl_config::Config, tick: Duration) -> Self {
        let period_ns = (config.timing.control_period() * 1e9).round() as u64;
        let now = clock::now_ns();
        let tick_ns = tick.as_nanos() as u64;
        Self {
            period_ns,
            overdue_after_ns: (config.control.valve_guard.max_age_periods + 1) * period_ns + period_ns / 4,
            tick_ns,
            look_at_ns: now + tick_ns,
            last_wake_ns: now,
        }
    }

    /// A command answering the reading taken at `reading_ns` was driven.
    fn answered(&mut self, reading_ns: u64) {
        self.look_at_ns = reading_ns.saturating_add(self.overdue_after_ns);
    }

    /// The valve woke; after a look, the next is a period on unless a
    /// command moves it.
    fn woke(&mut self, looked: bool) {
        self.last_wake_ns = clock::now_ns();
        if looked {
            self.look_at_ns = self.last_wake_ns + self.period_ns;
        }
    }

    fn next(&self) -> Instant {
        let at = self.look_at_ns.min(self.last_wake_ns + self.tick_ns);
        Instant::now() + Duration::from_nanos(at.saturating_sub(clock::now_ns()))
    }
}

pub fn run() -> Result<()> {
    let started = crate::start("valve")?;
    let bus = &started.bus;
    let mut stage = ValveStage::new(&started.config)?;
    let torque: Inlet<TorqueSample> = Inlet::open(bus, service::TORQUE, 4)?;
    // Readings are taken when the valve wakes: a few periods' worth at
    // most, before the first command a tick's.
    let sensor: Reader<SensorSample> = Reader::open(bus, service::SENSOR, 64)?;
    // Its output once its inputs are open (a fresh plant starts once every
    // stage publishes), and at once neutral, before any input is read.
    let device = match &started.config.can {
        Some(can) => {
            let profile = can.resolve().context("valve: [can]")?;
            let latch = FaultLatch::open(&latch_path(bus.scope().prefix(), &profile.interface, profile.valve))?;
            Device::Can(Box::new(CanValve::open(bus, &profile, latch)?))
        }
        None => Device::Simulated,
    };
    let mut desk = ValveDesk::open(bus, matches!(device, Device::Can(_)))?;
    let mut actuator = Actuator {
        device,
        sources: [(u64::MAX, source::SIMULATION); SOURCES],
        last_sent: (0.0, false),
        last_sent_at: Instant::now(),
        out: Outlet::open(bus, service::VALVE)?,
        newest: SensorSample::default(),
        is_off: false,
        last_requested: 0.0,
    };
    actuator.off().context("valve: driving neutral at start")?;
    let silence_timeout = Duration::from_secs_f64(started.config.control.valve_guard.silence_timeout_ms / 1000.0);
    let tick = silence_timeout / 4;
    // Silence is counted from the last thing the valve drove: with readings
    // coming and commands not, the guard drives neutral reading by reading;
    // with both stopped (a stage spinning above it, the plant gone), this
    // clock does, within the timeout and a tick.
    let mut last_driven = Instant::now();
    // Until the loop's first command the valve is still starting: the
    // neutral it holds for readings no controller has answered yet (the
    // machine's readings flow before the stages are up) is no fault.
    let mut commanded = false;
    let valve_clock = Cell::new(ValveClock::new(&started.config, tick));
    let mut failure = None;
    started.enter_realtime();
    let ended = run_until(
        &[torque.input()],
        &started.bus,
        || Some(valve_clock.get().next()),
        |wake| {
            hydractl_bus::guarded(&mut failure, || {
                let mut timer = valve_clock.get();
                // Every reading counts towards the guard, in order, before
                // the command that answers one of them.
                let mut neutral = None;
                let loop_started = actuator.newest.sensor_time_ns != 0;
                while let Some(s) = sensor.next()? {
                    actuator.note(s);
                    neutral = stage.on_sensor(s.sensor_seq, s.valid == valid::ALL).or(neutral);
                }
                let newest = actuator.newest;
                // The loop starts with its first reading: silence is counted
                // from there, not from the valve's own start, which waits
                // for the other stages (else the first tick after the first
                // reading would call the start-up silence).
                if !loop_started && newest.sensor_time_ns != 0 {
                    last_driven = Instant::now();
                }
                let command = match wake {
                    Wake::Input(_) => torque.latest()?.and_then(|t| {
                        let (command, faults) = stage.on_command(t.sensor_seq, t.command, t.variant)?;
                        Some((t.sensor_seq, t.sensor_time_ns, command, t.command, faults, t.variant))
                    }),
                    Wake::Tick => None,
                };
                commanded |= command.is_some();
                let decision = command.or_else(|| {
                    neutral
                        .map(|(command, faults)| {
                            (newest.sensor_seq, newest.sensor_time_ns, command, f64::NAN, faults, 0)
                        })
                        // Before the first reading the loop has not started and
                        // the valve is neutral anyway: silence means something
                        // only after.
                        .or_else(|| {
                            (wake == Wake::Tick
                                && newest.sensor_time_ns != 0
                                && last_driven.elapsed() >= silence_timeout)
                                .then(|| {
                                    let (command, faults) = stage.on_silence();
                                    (newest.sensor_seq, newest.sensor_time_ns, command, f64::NAN, faults, 0)
                                })
                        })
                });
                timer.woke(wake == Wake::Tick);
                desk.look(&mut actuator)?;
                match decision {
                    None if wake == Wake::Tick => actuator.refresh(tick)?,
                    None => {}
                    Some((seq, sensor_time_ns, command, requested, faults, variant)) => {
                        let starting = if commanded { 0 } else { fault::OFF };
                        // Silent again after another timeout: said again.
                        last_driven = Instant::now();
                        if faults == ValveFaults::default() {
                            timer.answered(sensor_time_ns);
                        }
                        let applied = actuator.drive(ValveSample {
                            sensor_seq: seq,
                            sensor_time_ns,
                            stage_time_ns: clock::now_ns(),
                            command,
                            requested,
                            faults: encode(faults) | starting,
                            variant,
                        })?;
                        // The valve held neutral: the next command ramps
                        // from there, not from what the shaper had.
                        if !applied {
                            stage.held_at_neutral();
                        }
                    }
                }
                valve_clock.set(timer);
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
