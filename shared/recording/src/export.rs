use std::collections::BTreeMap;
use std::path::Path;

use hydractl_plant::PA_PER_BAR;
use hydractl_samples::{
    fault, service, source, FrictionSample, PlantReading, PositionSample, SensorSample, TorqueSample, ValveSample,
};
use serde::Serialize;

use crate::{decode, read_messages_in, CommandJoin, ReadOutcome, RecordingError, Window};

/// The columns the model tools read, in order.
pub const MODEL_COLUMNS: [&str; 6] = ["t", "u", "p_a", "p_b", "theta", "theta_ref"];

/// The stages' other signals, after the model columns: NaN in every row
/// when the recording lacks the stage (a position-only run has no torque
/// loop), so that `ident` and `model` can read any recorded signal. Named
/// as `hydractl sim --out` names the same signals.
pub const SIGNAL_COLUMNS: [&str; 8] = [
    "omega_est",
    "torque",
    "blended_velocity",
    "friction_comp",
    "position_output",
    "torque_ref",
    "torque_command",
    "valve_requested",
];

/// One control period as the model tools read it, the same columns as
/// `hydractl sim` writes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ModelRow {
    /// s from the first exported reading, on the loop's own clock
    /// (sequence number × period), so rows are evenly spaced.
    pub t: f64,
    /// Valve command as driven, [-1, 1].
    pub u: f64,
    /// bar.
    pub p_a: f64,
    pub p_b: f64,
    /// Measured angle, rad.
    pub theta: f64,
    pub theta_ref: f64,
    /// The sensor stage's velocity estimate (differentiated, filtered), rad/s.
    pub omega_est: f64,
    /// The sensor stage's torque D (p_a − p_b), N·m.
    pub torque: f64,
    /// The friction stage's blended velocity (crane paper eq. 1), rad/s.
    pub blended_velocity: f64,
    /// The friction stage's compensation, valve command units.
    pub friction_comp: f64,
    /// The position loop's output: valve command (position-only) or torque
    /// reference, N·m (cascade).
    pub position_output: f64,
    /// The torque loop's reference and its valve command before shaping.
    pub torque_ref: f64,
    pub torque_command: f64,
    /// What the valve stage was asked for, before its guards.
    pub valve_requested: f64,
}

impl ModelRow {
    /// The row's values in the order of [`MODEL_COLUMNS`] then [`SIGNAL_COLUMNS`].
    pub fn values(&self) -> [f64; MODEL_COLUMNS.len() + SIGNAL_COLUMNS.len()] {
        [
            self.t,
            self.u,
            self.p_a,
            self.p_b,
            self.theta,
            self.theta_ref,
            self.omega_est,
            self.torque,
            self.blended_velocity,
            self.friction_comp,
            self.position_output,
            self.torque_ref,
            self.torque_command,
            self.valve_requested,
        ]
    }
}

/// What [`export_rows`] made of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Export {
    pub rows: Vec<ModelRow>,
    /// Rows whose command (or reference) was not in the recording, because
    /// the stage skipped that reading: the previous one is held, as the
    /// valve holds its current.
    pub held: usize,
    /// Readings after the loop last drove the valve (the stack stopping
    /// while the plant still read, or the valve held neutral to the end by
    /// a latched fault): left out, they answer nothing.
    pub after_loop: usize,
    /// In a recording of the machine, readings of the simulated plant that
    /// stood in for it (the machine lost, or a switch asked for): not the
    /// machine's measurements, left out; and the first one's time, s.
    pub simulated: usize,
    pub simulated_from_s: Option<f64>,
    pub read: ReadOutcome,
}

/// One row per plant reading (the sensor bus's raw angle and pressures, as
/// `hydractl sim` writes them), with the valve command and the reference
/// derived from it, joined by the reading's sequence number, from the first
/// reading that has both to the last.
pub fn export_rows(path: &Path) -> Result<Export, RecordingError> {
    export_rows_in(path, None)
}

/// [`export_rows`] of the readings inside `window` alone.
pub fn export_rows_in(path: &Path, window: Option<Window>) -> Result<Export, RecordingError> {
    let mut plant: BTreeMap<u64, PlantReading> = BTreeMap::new();
    let mut valve: BTreeMap<u64, ValveSample> = BTreeMap::new();
    let mut position: BTreeMap<u64, PositionSample> = BTreeMap::new();
    let mut sensor: BTreeMap<u64, SensorSample> = BTreeMap::new();
    let mut friction: BTreeMap<u64, FrictionSample> = BTreeMap::new();
    let mut torque: BTreeMap<u64, TorqueSample> = BTreeMap::new();
    let mut topics: BTreeMap<String, ()> = BTreeMap::new();
    let read = read_messages_in(path, window, |m| {
        topics.insert(m.topic.to_owned(), ());
        match m.topic {
            service::PLANT_READING => {
                if let Some(r) = decode::<PlantReading>(m) {
                    plant.insert(r.sensor_seq, r);
                }
            }
            service::VALVE => {
                if let Some(v) = decode::<ValveSample>(m) {
                    // A stopping valve's neutral carries the newest reading
                    // it knew: the command that answered that reading came
                    // first, and is the one the machine got.
                    if !valve.get(&v.sensor_seq).is_some_and(drove) {
                        valve.insert(v.sensor_seq, v);
                    }
                }
            }
            service::POSITION => {
                if let Some(p) = decode::<PositionSample>(m) {
                    position.insert(p.sensor_seq, p);
                }
            }
            service::SENSOR => {
                if let Some(s) = decode::<SensorSample>(m) {
                    sensor.insert(s.sensor_seq, s);
                }
            }
            service::FRICTION => {
                if let Some(f) = decode::<FrictionSample>(m) {
                    friction.insert(f.sensor_seq, f);
                }
            }
            service::TORQUE => {
                if let Some(t) = decode::<TorqueSample>(m) {
                    torque.insert(t.sensor_seq, t);
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    for topic in [service::PLANT_READING, service::VALVE, service::POSITION] {
        if !topics.contains_key(topic) {
            let have = match (topics.is_empty(), &read.truncated) {
                (true, Some(why)) => format!("no message at all: {why}"),
                (true, None) => "no message at all".to_owned(),
                (false, _) => topics.keys().cloned().collect::<Vec<_>>().join(", "),
            };
            return Err(RecordingError::MissingChannel {
                path: path.to_path_buf(),
                topic: topic.to_owned(),
                have,
            });
        }
    }
    let period_s = loop_period_s(&plant);
    let start = plant
        .keys()
        .copied()
        .find(|seq| valve.contains_key(seq) && position.contains_key(seq))
        .ok_or_else(|| RecordingError::NothingToExport {
            path: path.to_path_buf(),
            topic: service::VALVE.to_owned(),
        })?;
    // The last reading the loop drove the machine on: after it the stack
    // was stopping (its stages gone, the plant, a machine's bus, still
    // reading) or the valve held neutral to the end, a fault latched or the
    // process stopping: the machine held still answers nothing, and a
    // validation part of it has no spread to judge an error by.
    let end = plant
        .keys()
        .copied()
        .rev()
        .find(|seq| valve.get(seq).is_some_and(drove) && position.contains_key(seq))
        .filter(|end| *end > start)
        .ok_or_else(|| RecordingError::NeverDriven {
            path: path.to_path_buf(),
        })?;
    let after_loop = plant.range(end + 1..).count();
    let mut rows = Vec::with_capacity(plant.len());
    let mut held = 0;
    // Each row starts from the last: a signal holds its value where a stage
    // skipped a reading, as the valve holds its command; the other stages'
    // signals are NaN before their first sample.
    let mut row = ModelRow {
        t: 0.0,
        u: 0.0,
        p_a: f64::NAN,
        p_b: f64::NAN,
        theta: f64::NAN,
        theta_ref: 0.0,
        omega_est: f64::NAN,
        torque: f64::NAN,
        blended_velocity: f64::NAN,
        friction_comp: f64::NAN,
        position_output: f64::NAN,
        torque_ref: f64::NAN,
        torque_command: f64::NAN,
        valve_requested: f64::NAN,
    };
    let mut join = CommandJoin::new();
    // A model of the machine is fitted to the machine's readings alone.
    let of_machine = plant.values().any(|r| r.source == source::MACHINE);
    let (mut simulated, mut simulated_from_s) = (0, None);
    for (seq, r) in plant.range(start..=end) {
        if of_machine && r.source != source::MACHINE {
            simulated += 1;
            simulated_from_s.get_or_insert((seq - start) as f64 * period_s);
            continue;
        }
        join.reading(*r);
        let Some(v) = valve.get(seq) else { continue };
        join.valve(*v, |r, v, own| {
            let seq = r.sensor_seq;
            let p = position.get(&seq);
            if !own || p.is_none() {
                held += 1;
            }
            (row.t, row.p_a, row.p_b, row.theta) = (
                (seq - start) as f64 * period_s,
                r.p_a / PA_PER_BAR,
                r.p_b / PA_PER_BAR,
                r.angle,
            );
            if let Some(v) = v {
                (row.u, row.valve_requested) = (v.command, v.requested);
            }
            if let Some(p) = p {
                (row.theta_ref, row.position_output) = (p.reference_angle, p.output);
            }
            if let Some(s) = sensor.get(&seq) {
                (row.omega_est, row.torque) = (s.velocity, s.torque);
            }
            if let Some(f) = friction.get(&seq) {
                (row.blended_velocity, row.friction_comp) = (f.blended_velocity, f.compensation);
            }
            if let Some(t) = torque.get(&seq) {
                (row.torque_ref, row.torque_command) = (t.torque_reference, t.command);
            }
            rows.push(row);
        });
    }
    Ok(Export {
        rows,
        held,
        after_loop,
        simulated,
        simulated_from_s,
        read,
    })
}

/// Whether the valve drove the machine with this sample's command: not
/// held neutral by a latched fault, nor starting or stopping.
fn drove(v: &ValveSample) -> bool {
    v.faults & (fault::DEVICE | fault::OFF) == 0
}

/// The loop's period: the median time between consecutive readings,
/// rounded to the microsecond (the readings' own timestamps jitter).
fn loop_period_s(plant: &BTreeMap<u64, PlantReading>) -> f64 {
    let mut steps: Vec<u64> = plant
        .iter()
        .zip(plant.iter().skip(1))
        .filter(|((a, _), (b, _))| **b == **a + 1)
        .map(|((_, a), (_, b))| b.sensor_time_ns.saturating_sub(a.sensor_time_ns))
        .collect();
    if steps.is_empty() {
        return 1e-3;
    }
    let middle = steps.len() / 2;
    let (_, median, _) = steps.select_nth_unstable(middle);
    ((*median as f64) / 1000.0).round() * 1e-6
}

/// Writes rows as CSV with the [`MODEL_COLUMNS`] and [`SIGNAL_COLUMNS`]
/// header (a signal the recording lacks is NaN in every row).
pub fn write_csv(rows: &[ModelRow], path: &Path) -> Result<(), RecordingError> {
    let csv_error = |source| RecordingError::Csv {
        path: path.to_path_buf(),
        source,
    };
    let mut writer = csv::Writer::from_path(path).map_err(csv_error)?;
    for row in rows {
        writer.serialize(row).map_err(csv_error)?;
    }
    writer.flush().map_err(|source| RecordingError::Io {
        path: path.to_path_buf(),
        source,
    })
}
