//! The closed loop in one process, as fast as the CPU allows: plant and
//! sensors at the integration rate, the five stages at the control rate.

use std::path::Path;
use std::time::Instant;

use hydractl_plant::{Effect, Plant, PlantError, SensorModel, PA_PER_BAR};
use serde::Serialize;

use crate::metrics;
use hydractl_config::{Config, Structure};
use hydractl_stages::{ControlStack, StackError};

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error(transparent)]
    Plant(#[from] PlantError),
    #[error(transparent)]
    Stack(#[from] StackError),
    #[error("duration must be positive and finite, got {0}")]
    Duration(f64),
    #[error(
        "a duration of {duration} s is {cycles} control periods, more than the {max} ({max_days:.1} simulated days) one run may take{why}"
    )]
    TooLong {
        duration: f64,
        cycles: f64,
        max: u64,
        max_days: f64,
        why: &'static str,
    },
    #[error("cannot write {path}: {source}")]
    Write { path: String, source: csv::Error },
    #[error("cannot write {path}: {source}")]
    Io { path: String, source: std::io::Error },
}

/// One control period, the CSV's row. The first six columns are the ones
/// the model tools read: `t,u,p_a,p_b,theta,theta_ref`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Record {
    /// s.
    pub t: f64,
    /// Valve command as sent, [-1, 1].
    pub u: f64,
    /// Measured chamber pressures, bar.
    pub p_a: f64,
    pub p_b: f64,
    /// Measured (encoder) angle, rad.
    pub theta: f64,
    /// Reference angle, rad.
    pub theta_ref: f64,
    /// Reference velocity, rad/s.
    pub omega_ref: f64,
    /// Velocity estimate of the sensor stage, rad/s.
    pub omega_est: f64,
    /// Measured torque D (p_a − p_b), N·m.
    pub torque: f64,
    /// Torque reference of the cascade's outer loop, N·m (empty in position-only control).
    pub torque_ref: f64,
    /// The friction map's compensation, valve command.
    pub friction_comp: f64,
    /// The load's feed-forward (Coulomb friction, gravity), in the outer
    /// loop's output units.
    pub load_feedforward: f64,
    /// True plant state, for checking: actuator angle and velocity, load angle, spool.
    pub theta_true: f64,
    pub omega_true: f64,
    pub theta_load: f64,
    pub spool: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub structure: &'static str,
    pub position_variant: String,
    pub torque_variant: String,
    pub seed: u64,
    pub effects: Vec<String>,
    pub cycles: u64,
    pub max_abs_tracking_error_rad: f64,
    pub rms_tracking_error_rad: f64,
    /// Mean power of the measured torque's content above 10 rad/s, (N·m)².
    pub torque_power_above_10_rad_s: f64,
    pub sim_seconds: f64,
    /// The whole run: the closed loop and each row handed to its output
    /// (a CSV file, the progress bar).
    pub wall_seconds: f64,
    /// The closed loop alone: plant, sensor model and the five stages,
    /// without the rows' output (timed on one row in 16).
    pub loop_seconds: f64,
    /// Simulated seconds per second of the closed loop alone
    /// (`sim_seconds / loop_seconds`): what the simulator itself costs,
    /// whatever the rows are written to.
    pub real_time_factor: f64,
    /// Simulated seconds per second of the whole run
    /// (`sim_seconds / wall_seconds`), its output included.
    pub real_time_factor_with_output: f64,
}

pub struct SimulationRun {
    pub records: Vec<Record>,
    pub summary: Summary,
}

impl SimulationRun {
    /// The run as the model tools read a measured record: `t`, the valve
    /// command `u`, the chamber pressures `p_a`, `p_b` (bar, as the sensors
    /// read them) and the measured angle `theta`.
    pub fn model_columns(&self) -> Vec<(&'static str, Vec<f64>)> {
        let column = |f: fn(&Record) -> f64| self.records.iter().map(f).collect::<Vec<f64>>();
        vec![
            ("t", column(|r| r.t)),
            ("u", column(|r| r.u)),
            ("p_a", column(|r| r.p_a)),
            ("p_b", column(|r| r.p_b)),
            ("theta", column(|r| r.theta)),
        ]
    }
}

/// The plant of a config with extra effects switched on (replacing any of
/// the same kind the config has).
pub fn build_plant(config: &Config, extra_effects: &[Effect]) -> Result<(Plant, SensorModel), SimError> {
    let mut effects = config.effects.build()?;
    for effect in extra_effects {
        effects.insert(*effect);
    }
    let plant = Plant::new(config.plant, effects, config.timing.integration_step())?;
    let mut sensor = SensorModel::new(config.sensor, &effects, config.simulation.seed)?;
    sensor.home(plant.state().angle);
    Ok((plant, sensor))
}

/// The crane paper's friction experiment, open loop: each command of
/// `levels` held on the valve for `dwell_s`, the plant and sensors as
/// configured. The records' reference and controller columns are zero.
pub fn simulate_valve_steps(
    config: &Config,
    extra_effects: &[Effect],
    levels: &[f64],
    dwell_s: f64,
) -> Result<Vec<Record>, SimError> {
    if !(dwell_s.is_finite() && dwell_s > 0.0) {
        return Err(SimError::Duration(dwell_s));
    }
    let (mut plant, mut sensor) = build_plant(config, extra_effects)?;
    let period = config.timing.control_period();
    let substeps = config.timing.substeps();
    let per_level = cycles_of(
        config,
        dwell_s * levels.len().max(1) as f64,
        MAX_KEPT_CYCLES,
        " with its rows kept in memory",
    )? as usize
        / levels.len().max(1);
    let mut records = Vec::with_capacity(per_level * levels.len());
    for &command in levels {
        let command = command.clamp(-1.0, 1.0);
        for _ in 0..per_level {
            let state = plant.state();
            let raw = sensor.read(&state);
            records.push(Record {
                t: records.len() as f64 * period,
                u: command,
                p_a: raw.p_a / PA_PER_BAR,
                p_b: raw.p_b / PA_PER_BAR,
                theta: raw.angle,
                torque: plant.params().displacement * (raw.p_a - raw.p_b),
                theta_true: state.angle,
                omega_true: state.velocity,
                theta_load: state.load_angle,
                spool: state.spool,
                ..Record::default()
            });
            plant.advance(command, substeps);
        }
    }
    Ok(records)
}

/// The most control periods one streamed run may take: about 11.6
/// simulated days at 1 kHz, hours of computing.
pub const MAX_CYCLES: u64 = 1_000_000_000;
/// The most periods a run whose rows are kept in memory may take: an hour
/// at 1 kHz, about 430 MB of rows.
pub const MAX_KEPT_CYCLES: u64 = 3_600_000;

/// The control periods in `duration` seconds, or why they cannot be run:
/// not a positive duration, or more than `max` periods.
fn cycles_of(config: &Config, duration: f64, max: u64, why: &'static str) -> Result<u64, SimError> {
    if !(duration.is_finite() && duration > 0.0) {
        return Err(SimError::Duration(duration));
    }
    let period = config.timing.control_period();
    let cycles = (duration / period).round();
    if cycles > max as f64 {
        return Err(SimError::TooLong {
            duration,
            cycles,
            max,
            max_days: max as f64 * period / 86_400.0,
            why,
        });
    }
    Ok(cycles as u64)
}

/// Runs the closed loop for `duration` seconds and keeps every period
/// (at most `MAX_KEPT_CYCLES`; [`simulate_streaming`] keeps none).
pub fn simulate(config: &Config, extra_effects: &[Effect], duration: f64) -> Result<SimulationRun, SimError> {
    let cycles = cycles_of(
        config,
        duration,
        MAX_KEPT_CYCLES,
        " with its rows kept in memory; `hydractl sim` streams longer runs to its CSV",
    )?;
    let mut records = Vec::with_capacity(cycles as usize);
    let summary = simulate_streaming(config, extra_effects, duration, |r| {
        records.push(*r);
        Ok(())
    })?;
    Ok(SimulationRun { records, summary })
}

/// Runs the closed loop for `duration` seconds, handing each period's row
/// to `each` as it goes and keeping none: memory does not grow with the
/// duration. The summary's metrics are accumulated as the rows go by.
pub fn simulate_streaming(
    config: &Config,
    extra_effects: &[Effect],
    duration: f64,
    mut each: impl FnMut(&Record) -> Result<(), SimError>,
) -> Result<Summary, SimError> {
    let cycles = cycles_of(config, duration, MAX_CYCLES, "")?;
    let (mut plant, mut sensor) = build_plant(config, extra_effects)?;
    let mut stack = ControlStack::new(config)?;
    let period = config.timing.control_period();
    let substeps = config.timing.substeps();
    let (mut sum_squares, mut max_abs_error) = (0.0, 0.0f64);
    let mut torque_power = metrics::PowerAbove::new(period, 10.0);

    let started = Instant::now();
    // The output's time, estimated from one row in this many: two clock
    // reads for every row cost 4 % of a run to /dev/null.
    const OUTPUT_TIMED_EVERY: u64 = 16;
    let mut output_time = std::time::Duration::ZERO;
    for k in 0..cycles {
        let time = k as f64 * period;
        let state = plant.state();
        let raw = sensor.read(&state);
        let out = stack.step(time, &raw);
        let record = Record {
            t: time,
            u: out.command,
            p_a: raw.p_a / PA_PER_BAR,
            p_b: raw.p_b / PA_PER_BAR,
            theta: raw.angle,
            theta_ref: out.position.reference.angle,
            omega_ref: out.position.reference.velocity,
            omega_est: out.sensor.velocity,
            torque: out.sensor.torque,
            torque_ref: out.torque_reference,
            friction_comp: out.friction.compensation,
            load_feedforward: out.friction.load_feedforward,
            theta_true: state.angle,
            omega_true: state.velocity,
            theta_load: state.load_angle,
            spool: state.spool,
        };
        let error = record.theta_ref - record.theta;
        sum_squares += error * error;
        max_abs_error = max_abs_error.max(error.abs());
        torque_power.push(record.torque);
        if k % OUTPUT_TIMED_EVERY == 0 {
            let handed = Instant::now();
            each(&record)?;
            output_time += handed.elapsed() * OUTPUT_TIMED_EVERY as u32;
        } else {
            each(&record)?;
        }
        plant.advance(out.command, substeps);
    }
    let wall_seconds = started.elapsed().as_secs_f64();
    let loop_seconds = (wall_seconds - output_time.as_secs_f64()).max(0.0);
    let sim_seconds = cycles as f64 * period;
    Ok(Summary {
        structure: config.control.structure.name(),
        position_variant: format!("{:?}", config.control.outer().variant).to_lowercase(),
        torque_variant: match config.control.structure {
            Structure::Position => "bypassed".to_owned(),
            Structure::Cascade => format!("{:?}", config.control.torque_variant).to_lowercase(),
        },
        seed: config.simulation.seed,
        effects: plant.effects().list().iter().map(|e| e.to_string()).collect(),
        cycles,
        max_abs_tracking_error_rad: max_abs_error,
        rms_tracking_error_rad: (sum_squares / cycles.max(1) as f64).sqrt(),
        torque_power_above_10_rad_s: torque_power.finish(),
        sim_seconds,
        wall_seconds,
        loop_seconds,
        real_time_factor: sim_seconds / loop_seconds.max(1e-12),
        real_time_factor_with_output: sim_seconds / wall_seconds.max(1e-12),
    })
}

/// Rows written to a CSV file one by one: the header first, then a row
/// per [`Record`]; `torque_ref` is empty where there is none.
pub struct CsvRows {
    writer: csv::Writer<std::fs::File>,
    fields: [String; 16],
    path: String,
}

impl CsvRows {
    pub fn create(path: &Path) -> Result<Self, SimError> {
        let name = path.display().to_string();
        let mut writer = csv::Writer::from_path(path).map_err(|source| SimError::Write {
            path: name.clone(),
            source,
        })?;
        writer
            .write_record([
                "t",
                "u",
                "p_a",
                "p_b",
                "theta",
                "theta_ref",
                "omega_ref",
                "omega_est",
                "torque",
                "torque_ref",
                "friction_comp",
                "load_feedforward",
                "theta_true",
                "omega_true",
                "theta_load",
                "spool",
            ])
            .map_err(|source| SimError::Write {
                path: name.clone(),
                source,
            })?;
        Ok(Self {
            writer,
            fields: Default::default(),
            path: name,
        })
    }

    pub fn write(&mut self, r: &Record) -> Result<(), SimError> {
        let values = [
            r.t,
            r.u,
            r.p_a,
            r.p_b,
            r.theta,
            r.theta_ref,
            r.omega_ref,
            r.omega_est,
            r.torque,
            r.torque_ref,
            r.friction_comp,
            r.load_feedforward,
            r.theta_true,
            r.omega_true,
            r.theta_load,
            r.spool,
        ];
        for (field, value) in self.fields.iter_mut().zip(values) {
            field.clear();
            if value.is_finite() {
                use std::fmt::Write;
                let _ = write!(field, "{value}");
            }
        }
        self.writer
            .write_record(&self.fields)
            .map_err(|source| SimError::Write {
                path: self.path.clone(),
                source,
            })
    }

    pub fn finish(mut self) -> Result<(), SimError> {
        self.writer.flush().map_err(|source| SimError::Io {
            path: self.path,
            source,
        })
    }
}

/// Writes the records as CSV.
pub fn write_csv(records: &[Record], path: &Path) -> Result<(), SimError> {
    let mut rows = CsvRows::create(path)?;
    for r in records {
        rows.write(r)?;
    }
    rows.finish()
}
