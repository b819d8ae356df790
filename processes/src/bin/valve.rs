//! Command shaping and the last line of safety: publishes the valve's
//! state for every command, and neutral with a fault flag when commands
//! stop, arrive stale, or are garbage.

use std::time::{Duration, Instant};

use anyhow::Result;
use hydractl_bus::devices::{SimulatedValve, ValveDevice};
use hydractl_bus::{clock, run_loop, Inlet, Outlet, Wake};
use hydractl_samples::{fault, service, valid, SensorSample, TorqueSample, ValveSample};
use hydractl_stages::{ValveFaults, ValveStage};

const COMMAND: usize = 0;
const SENSOR: usize = 1;

fn main() -> Result<()> {
    let started = hydractl_processes::start("valve")?;
    let bus = &started.bus;
    let mut stage = ValveStage::new(&started.config)?;
    let mut device = SimulatedValve;
    let torque: Inlet<TorqueSample> = Inlet::open(bus, service::TORQUE, 4)?;
    let sensor: Inlet<SensorSample> = Inlet::open(bus, service::SENSOR, 4)?;
    let out: Outlet<ValveSample> = Outlet::open(bus, service::VALVE)?;
    let silence_timeout = Duration::from_secs_f64(started.config.control.valve_guard.silence_timeout_ms / 1000.0);
    let mut newest = SensorSample::default();
    let mut last_input = Instant::now();
    let mut failure = None;
    // The tick is the valve's own clock, for when readings stop too.
    started.enter_realtime();
    run_loop(
        &[torque.listener(), sensor.listener()],
        Some(silence_timeout / 4),
        &started.bus,
        |wake| {
            hydractl_bus::guarded(&mut failure, || {
                // Every reading counts towards the guard, the one that woke us
                // and any that arrived with it.
                let mut neutral = None;
                while let Some(s) = sensor.next()? {
                    newest = s;
                    last_input = Instant::now();
                    neutral = stage.on_sensor(s.sensor_seq, s.valid == valid::ALL).or(neutral);
                }
                let decision = match wake {
                    Wake::Input(COMMAND) => torque.latest()?.map(|t| {
                        last_input = Instant::now();
                        let (command, faults) = stage.on_command(t.sensor_seq, t.command, t.variant);
                        (t.sensor_seq, t.sensor_time_ns, command, t.command, faults)
                    }),
                    Wake::Input(SENSOR) => neutral
                        .map(|(command, faults)| (newest.sensor_seq, newest.sensor_time_ns, command, f64::NAN, faults)),
                    // Before the first reading the loop has not started and the
                    // valve is neutral anyway: silence means something only after.
                    Wake::Tick if newest.sensor_time_ns != 0 && last_input.elapsed() >= silence_timeout => {
                        // Silent again after another timeout: say so again.
                        last_input = Instant::now();
                        let (command, faults) = stage.on_silence();
                        Some((newest.sensor_seq, newest.sensor_time_ns, command, f64::NAN, faults))
                    }
                    _ => None,
                };
                if let Some((seq, sensor_time_ns, command, requested, faults)) = decision {
                    device.drive(command)?;
                    out.publish(ValveSample {
                        sensor_seq: seq,
                        sensor_time_ns,
                        stage_time_ns: clock::now_ns(),
                        command,
                        requested,
                        faults: encode(faults),
                        reserved: 0,
                    })?;
                }
                Ok(())
            })
        },
    )?;
    failure.map_or(Ok(()), Err)
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
