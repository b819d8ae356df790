//! The simulated rotator, paced in real time at the control rate. Each
//! period it publishes the sensors' readings, waits (bounded) for the valve
//! command derived from them, and integrates one period with it, as the
//! offline simulator does. A command that never comes in time is counted
//! as a deadline miss and the valve holds its last command, as a real valve
//! holds its current; with none for longer than the valve guard's age, the
//! valve amplifier's own watchdog drives it to neutral. When the computer
//! stalls, the plant pauses or catches up, as `timing.stall_policy` says.

use std::time::{Duration, Instant};

use anyhow::Result;
use hydractl_bus::{clock, Inlet, Outlet};
use hydractl_samples::{service, PlantReading, ValveSample};
use hydractl_sim::{build_plant, StallPolicy};

fn main() -> Result<()> {
    let started = hydractl_processes::start("plant")?;
    let config = &started.config;
    let (mut plant, mut sensors) = build_plant(config, &[])?;
    let readings: Outlet<PlantReading> = Outlet::open(&started.bus, service::PLANT_READING)?;
    // A restarted plant resumes from what the loop last saw of it: its
    // sequence goes on (the reference is a function of it) and its state
    // starts from the last reading, at rest.
    let mut seq = 0u64;
    if let Some(resume) = started.args.resume {
        seq = resume.seq + 1;
        let mut state = plant.state();
        state.angle = resume.angle;
        state.load_angle = resume.angle;
        state.p_a = resume.p_a;
        state.p_b = resume.p_b;
        plant.reset_to(state);
        sensors.home(resume.angle);
    }
    let valve: Inlet<ValveSample> = Inlet::open(&started.bus, service::VALVE, 8)?;
    let period = Duration::from_secs_f64(config.timing.control_period());
    let policy = config.timing.stall_policy;
    let command_timeout = match policy {
        StallPolicy::Pause => period.mul_f64(config.timing.command_timeout_periods),
        // Real time waits for no one: the command must come within the period.
        StallPolicy::CatchUp => period.mul_f64(0.9),
    };
    let substeps = config.timing.substeps();
    let node = started.bus.node();

    let mut command = 0.0;
    let mut late_commands = 0u64;
    // The valve amplifier's own watchdog: with no fresh command for longer
    // than the valve process's guard allows, the spool is driven to
    // neutral (a dead valve process must not leave it open).
    let amplifier_timeout = config.control.valve_guard.max_age_periods + 1;
    let mut without_command = 0u64;
    let mut loop_running = false;
    let mut next_tick = Instant::now();
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
                    plant.advance(command, substeps * overdue as usize);
                    seq += overdue;
                    next_tick += period * overdue as u32;
                    if loop_running {
                        late_commands += overdue;
                    }
                }
            }
        }
        let state = plant.state();
        let raw = sensors.read(&state);
        readings.publish(PlantReading {
            sensor_seq: seq,
            sensor_time_ns: clock::now_ns(),
            angle: raw.angle,
            p_a: raw.p_a,
            p_b: raw.p_b,
            true_angle: state.angle,
            late_commands,
        })?;
        let deadline = Instant::now() + command_timeout;
        let mut fresh = false;
        while !fresh {
            let remaining = deadline.saturating_duration_since(Instant::now());
            match valve.wait_latest(remaining)? {
                Some(sample) if sample.sensor_seq >= seq => {
                    command = sample.command;
                    fresh = true;
                }
                Some(sample) => command = sample.command,
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
        plant.advance(command, substeps);
        next_tick += period;
        seq += 1;
    }
    Ok(())
}
