//! The live plant, paced in real time at the control rate: the simulated
//! rotator (`plant`), or the machine's stand-in (`machine`), a plant with
//! its own parameters and effects that stands in for the hardware here.
//!
//! Each period the plant in charge publishes the sensors' readings, waits
//! (bounded) for the valve command derived from them, and integrates one
//! period with it, as the offline simulator does. A command that never
//! comes in time is counted as a deadline miss and the valve holds its last
//! command, as a real valve holds its current; with none for longer than
//! the valve guard's age, the valve amplifier's own watchdog drives it to
//! neutral. When the computer stalls, the plant pauses or catches up, as
//! `timing.stall_policy` says.
//!
//! The plant seat (`PlantSeat`) decides which of the two publishes the
//! loop's readings. The simulated plant in standby only watches the loop's
//! last measured state; when it takes over, it starts from that state with
//! the valve neutral. The machine out of charge goes on existing: its valve
//! neutral, its readings on the standby service.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use hydractl_bus::{clock, Inlet, Outlet, PublisherWatch, Reader};
use hydractl_config::StallPolicy;
use hydractl_plant::{Drift, Plant, SensorModel};
use hydractl_samples::{
    fault, service, source, FrictionSample, PlantReading, PositionSample, SensorSample, TorqueSample, ValveSample,
};
use hydractl_sim::build_plant;

use crate::can_sensors::CanSensors;
use crate::handover::{HandoverInbox, PlantSeat, SeatChange};
use crate::last_measured::LastMeasured;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlantKind {
    Simulation,
    Machine,
}

pub fn run(kind: PlantKind) -> Result<()> {
    let name = match kind {
        PlantKind::Simulation => "plant",
        PlantKind::Machine => "machine",
    };
    let started = crate::start(name)?;
    let config = match kind {
        PlantKind::Simulation => started.config.clone(),
        PlantKind::Machine => started
            .config
            .machine_plant()?
            .context("machine: the config has no [machine] section")?,
    };
    let source_code = match kind {
        PlantKind::Simulation => source::SIMULATION,
        PlantKind::Machine => source::MACHINE,
    };
    let bus = &started.bus;
    // The machine on CAN is read through its bus; its valve is the valve
    // process's to drive (hydractl-can's ValveMaster).
    let can_profile = match (kind, &started.config.can) {
        (PlantKind::Machine, Some(can)) => Some(can.resolve().context("machine: [can]")?),
        _ => None,
    };
    let mut body = match &can_profile {
        Some(profile) => Body::Can(CanSensors::open(bus, profile)?),
        None => {
            let (plant, sensors) = build_plant(&config, &[])?;
            let drift = match (kind, started.config.machine.as_ref().and_then(|m| m.drift.as_ref())) {
                (PlantKind::Machine, Some(spec)) => {
                    Some(Drift::new(plant.effects(), spec).context("machine: [machine.drift]")?)
                }
                _ => None,
            };
            Body::Simulated { plant, sensors, drift }
        }
    };
    let readings: Outlet<PlantReading> = Outlet::open(bus, service::PLANT_READING)?;
    let standby_readings: Outlet<PlantReading> = Outlet::open(bus, service::PLANT_STANDBY)?;
    let stream: Reader<PlantReading> = Reader::open(bus, service::PLANT_READING, 4)?;
    let estimates: Reader<SensorSample> = Reader::open(bus, service::SENSOR, 4)?;
    let mut inbox = HandoverInbox::open(bus, hydractl_samples::code::STAGE_PLANT)?;
    let valve: Inlet<ValveSample> = Inlet::open(bus, service::VALVE, 8)?;
    let mut seat = PlantSeat::new(!started.args.standby);
    // A restarted plant resumes from what the loop last saw of it: its
    // sequence goes on (the reference is a function of it) and its state
    // starts from the last reading, moving as the sensor stage last
    // estimated (at rest, it would jolt a moving load).
    let mut seq = 0u64;
    if let Some(resume) = started.args.resume {
        seq = resume.seq + 1;
    }
    if let (Some(resume), Body::Simulated { plant, sensors, .. }) = (started.args.resume, &mut body) {
        let measured = LastMeasured::of_resume(&resume);
        let mut state = plant.state();
        measured.put_into(&mut state);
        plant.reset_to(state);
        sensors.home(state.angle);
    }
    let period = Duration::from_secs_f64(config.timing.control_period());
    let period_ns = period.as_nanos() as u64;
    let policy = config.timing.stall_policy;
    let command_timeout = match policy {
        StallPolicy::Pause => period.mul_f64(config.timing.command_timeout_periods),
        // Real time waits for no one: the command must come within the period.
        StallPolicy::CatchUp => period.mul_f64(0.9),
    };
    let substeps = config.timing.substeps();
    let bus_lost_at = match kind {
        PlantKind::Machine => started
            .config
            .machine
            .as_ref()
            .and_then(|m| m.bus_lost_after_s)
            .map(|s| Instant::now() + Duration::from_secs_f64(s)),
        PlantKind::Simulation => None,
    };
    let node = bus.node();

    let mut command = 0.0;
    let mut late_commands = 0u64;
    // The valve amplifier's own watchdog: with no fresh command for longer
    // than the valve process's guard allows, the spool is driven to
    // neutral (a dead valve process must not leave it open).
    let amplifier_timeout = config.control.valve_guard.max_age_periods + 1;
    let mut without_command = 0u64;
    let mut loop_running = false;
    let mut last_measured = LastMeasured::default();
    let mut stream_seq = None;
    // A fresh simulated plant in charge waits for the chain, so that its
    // first reading is answered, as in the offline simulation, where the
    // controllers are there from t = 0. A restarted plant finds the chain
    // running; a machine waits for no one.
    // Its first answer is awaited as long as the chain's start: each
    // stage's first cycle maps the segments and faults in the pages it
    // touches, and on a loaded machine a stage woken after the second
    // reading takes the newest and never answers the first.
    let fresh_start = kind == PlantKind::Simulation && started.args.resume.is_none() && seat.in_charge();
    let mut first_answer_timeout = (fresh_start && wait_for_chain(bus)).then_some(CHAIN_START_TIMEOUT);
    let mut next_tick = Instant::now();
    started.enter_realtime();
    loop {
        // Pace: sleep until this period starts; a signal ends the run.
        if node.wait(next_tick.saturating_duration_since(Instant::now())).is_err() {
            break;
        }
        let behind = Instant::now().saturating_duration_since(next_tick);
        if behind >= period {
            match policy {
                // The simulation's time is the loop's: resume from now,
                // without a burst of readings to catch up.
                StallPolicy::Pause => next_tick = Instant::now(),
                // The machine ran on with the valve holding its command.
                StallPolicy::CatchUp => {
                    let overdue = (behind.as_nanos() / period.as_nanos()) as u64;
                    body.advance(command, substeps * overdue as usize);
                    seq += overdue;
                    next_tick += period * overdue as u32;
                    if loop_running {
                        late_commands += overdue;
                    }
                }
            }
        }
        if let Some(r) = stream.newest_by(|r| r.sensor_seq)? {
            last_measured.reading(&r);
            stream_seq = Some(r.sensor_seq);
        }
        if let Some(s) = estimates.latest()? {
            last_measured.velocity(s.velocity);
        }
        let mut change = None;
        while let Some(h) = inbox.next_handover()? {
            change = change.or(seat.update(Some(h), stream_seq, seq, clock::now_ns(), period_ns));
        }
        // Once a period in any case, but not again in a period that already
        // changed the seat: its judgement is of this period's state.
        let change = change.or_else(|| seat.update(None, stream_seq, seq, clock::now_ns(), period_ns));
        match change {
            Some(SeatChange::Take { at_seq }) => {
                tracing::info!("drives the loop from reading {at_seq}");
                if let (Body::Simulated { plant, sensors, .. }, PlantKind::Simulation) = (&mut body, kind) {
                    // From the last measured state, the valve neutral.
                    let mut state = plant.state();
                    state.spool = 0.0;
                    state.spool_rate = 0.0;
                    state.stuck = false;
                    last_measured.put_into(&mut state);
                    plant.reset_to(state);
                    if let Some(angle) = last_measured.angle() {
                        sensors.home(angle);
                    }
                }
                seq = at_seq;
                command = 0.0;
                without_command = 0;
                loop_running = false;
                next_tick = Instant::now();
            }
            Some(SeatChange::Leave) => command = 0.0,
            None => {}
        }
        let bus_lost = bus_lost_at.is_some_and(|at| Instant::now() >= at) || body.sensor_lost();
        if !seat.in_charge() || bus_lost {
            if kind == PlantKind::Machine {
                // The machine exists whether or not it drives the loop: its
                // valve neutral, its readings (if its bus works) on standby.
                let reading = body.read(seq, late_commands, source_code, 0)?;
                if !bus_lost {
                    standby_readings.publish(reading)?;
                }
                command = 0.0;
                body.advance(command, substeps);
                seq += 1;
            }
            next_tick += period;
            continue;
        }
        // The simulated amplifier's figure, or the machine's valve's own word.
        let neutral_for = match &body {
            Body::Can(can) => can
                .valve_held_for_ns()
                .map_or(0, |held| (held / period.as_nanos().max(1) as u64).max(1)),
            Body::Simulated { .. } => without_command.saturating_sub(amplifier_timeout),
        }
        .min(u64::from(u32::MAX)) as u32;
        readings.publish(body.read(seq, late_commands, source_code, neutral_for)?)?;
        // The machine on CAN does not wait for its valve: the next SYNC is
        // due at the next period, whatever the command does.
        let first_answer = first_answer_timeout.take();
        let deadline = match body {
            Body::Can(_) => next_tick + period.mul_f64(0.9),
            Body::Simulated { .. } => Instant::now() + first_answer.unwrap_or(command_timeout),
        };
        // The valve starting or stopping drives neutral, answering no
        // reading; nor does the neutral it holds until its first command.
        let unanswered = if first_answer.is_some() {
            fault::OFF | fault::STALE
        } else {
            fault::OFF
        };
        let mut fresh = false;
        while !fresh {
            let remaining = deadline.saturating_duration_since(Instant::now());
            match valve.wait_latest(remaining)? {
                Some(sample) if sample.sensor_seq >= seq && sample.faults & unanswered == 0 => {
                    command = sample.command;
                    fresh = true;
                }
                Some(sample) => command = sample.command,
                // A signal ends the first reading's long wait too.
                None if bus.termination_requested() => break,
                None => {}
            }
            if remaining.is_zero() {
                break;
            }
        }
        // Before the first command the stages are still starting: not a miss.
        if fresh {
            loop_running = true;
            without_command = 0;
        } else if loop_running {
            late_commands += 1;
            without_command += 1;
            if without_command > amplifier_timeout {
                command = 0.0;
            }
        }
        body.advance(command, substeps);
        next_tick += period;
        seq += 1;
    }
    Ok(())
}

/// What the plant in charge reads and moves: the simulated rotator, or
/// the machine through its CAN bus.
// One for the whole process, made at start: its size is no cost.
#[allow(clippy::large_enum_variant)]
enum Body {
    Simulated {
        plant: Plant,
        sensors: SensorModel,
        /// The machine stand-in's effect that changes as it runs.
        drift: Option<Drift>,
    },
    Can(CanSensors),
}

impl Body {
    /// This period's reading: the sensor model's, or a SYNC's PDOs
    /// (awaited up to their deadline).
    fn read(&mut self, seq: u64, late_commands: u64, source: u32, amplifier_neutral_for: u32) -> Result<PlantReading> {
        match self {
            Self::Simulated { plant, sensors, .. } => Ok(read_sensors(
                plant,
                sensors,
                seq,
                late_commands,
                source,
                amplifier_neutral_for,
            )),
            Self::Can(can) => {
                let (values, sync_time_ns) = can.acquire()?;
                Ok(PlantReading {
                    sensor_seq: seq,
                    sensor_time_ns: sync_time_ns,
                    angle: values.angle,
                    p_a: values.p_a,
                    p_b: values.p_b,
                    // The machine's true angle is its encoder's.
                    true_angle: values.angle,
                    late_commands,
                    source,
                    amplifier_neutral_for,
                })
            }
        }
    }

    /// One or more periods with `command` held: the simulated rotator
    /// integrates; the machine moves by itself, its valve driven by the
    /// valve process.
    fn advance(&mut self, command: f64, substeps: usize) {
        if let Self::Simulated { plant, drift, .. } = self {
            if let Some(drift) = drift {
                plant.drift_to(drift.effects_at(plant.time()));
            }
            plant.advance(command, substeps);
        }
    }

    /// A sensor node on CAN has gone silent: the machine is lost.
    fn sensor_lost(&self) -> bool {
        matches!(self, Self::Can(can) if can.lost().is_some())
    }
}

/// How long a fresh plant waits for the chain before it starts anyway (the
/// supervisor reports whichever stage did not come up).
const CHAIN_START_TIMEOUT: Duration = Duration::from_secs(5);

/// Waits until every stage of the chain publishes (each opens its input
/// before its output, so its input is there too), or the timeout passes;
/// whether the whole chain is there.
fn wait_for_chain(bus: &hydractl_bus::Bus) -> bool {
    let started = Instant::now();
    let mut sensor = PublisherWatch::<SensorSample>::new(service::SENSOR);
    let mut friction = PublisherWatch::<FrictionSample>::new(service::FRICTION);
    let mut position = PublisherWatch::<PositionSample>::new(service::POSITION);
    let mut torque = PublisherWatch::<TorqueSample>::new(service::TORQUE);
    let mut valve = PublisherWatch::<ValveSample>::new(service::VALVE);
    loop {
        let mut missing = Vec::new();
        for (name, publishers) in [
            (service::SENSOR, sensor.publishers(bus)),
            (service::FRICTION, friction.publishers(bus)),
            (service::POSITION, position.publishers(bus)),
            (service::TORQUE, torque.publishers(bus)),
            (service::VALVE, valve.publishers(bus)),
        ] {
            if publishers == 0 {
                missing.push(name);
            }
        }
        if missing.is_empty() {
            return true;
        }
        if bus.termination_requested() {
            return false;
        }
        if started.elapsed() >= CHAIN_START_TIMEOUT {
            tracing::warn!(
                "after {CHAIN_START_TIMEOUT:?} nothing publishes on {}; starting without them",
                missing.join(", ")
            );
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// The sensors' reading of the plant's present state, as published.
fn read_sensors(
    plant: &Plant,
    sensors: &mut SensorModel,
    seq: u64,
    late_commands: u64,
    source: u32,
    amplifier_neutral_for: u32,
) -> PlantReading {
    let state = plant.state();
    let raw = sensors.read(&state);
    PlantReading {
        sensor_seq: seq,
        sensor_time_ns: clock::now_ns(),
        angle: raw.angle,
        p_a: raw.p_a,
        p_b: raw.p_b,
        true_angle: state.angle,
        late_commands,
        source,
        amplifier_neutral_for,
    }
}
