use std::collections::BTreeMap;
use std::path::Path;

use hydractl_samples::{
    service, FrictionSample, PlantReading, PositionSample, SensorSample, TorqueSample, ValveSample,
};
use serde::Serialize;

use crate::{decode, read_messages, ReadOutcome, RecordingError};

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

/// What [`export_rows`] made of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Export {
    pub rows: Vec<ModelRow>,
    /// Rows whose command (or reference) was not in the recording, because
    /// the stage skipped that reading: the previous one is held, as the
    /// valve holds its current.
    pub held: usize,
    pub read: ReadOutcome,
}

/// One row per plant reading (the sensor bus's raw angle and pressures, as
/// `hydractl sim` writes them), with the valve command and the reference
/// derived from it, joined by the reading's sequence number, from the first
/// reading that has both.
pub fn export_rows(path: &Path) -> Result<Export, RecordingError> {
    let mut plant: BTreeMap<u64, PlantReading> = BTreeMap::new();
    let mut valve: BTreeMap<u64, ValveSample> = BTreeMap::new();
    let mut position: BTreeMap<u64, PositionSample> = BTreeMap::new();
    let mut sensor: BTreeMap<u64, SensorSample> = BTreeMap::new();
    let mut friction: BTreeMap<u64, FrictionSample> = BTreeMap::new();
    let mut torque: BTreeMap<u64, TorqueSample> = BTreeMap::new();
    let mut topics: BTreeMap<String, ()> = BTreeMap::new();
    let read = read_messages(path, |m| {
        topics.insert(m.topic.to_owned(), ());
        match m.topic {
            service::PLANT_READING => {
                if let Some(r) = decode::<PlantReading>(m) {
                    plant.insert(r.sensor_seq, r);
                }
            }
            service::VALVE => {
                if let Some(v) = decode::<ValveSample>(m) {
                    valve.insert(v.sensor_seq, v);
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
    let mut rows = Vec::with_capacity(plant.len());
    let (mut u, mut theta_ref, mut held) = (0.0, 0.0, 0);
    // The other stages' signals hold their last value where a reading was
    // skipped, as the command does; NaN before a stage's first sample.
    let mut other = [f64::NAN; SIGNAL_COLUMNS.len()];
    for (seq, r) in plant.range(start..) {
        match (valve.get(seq), position.get(seq)) {
            (Some(v), Some(p)) => (u, theta_ref) = (v.command, p.reference_angle),
            (v, p) => {
                held += 1;
                u = v.map_or(u, |v| v.command);
                theta_ref = p.map_or(theta_ref, |p| p.reference_angle);
            }
        }
        if let Some(s) = sensor.get(seq) {
            (other[0], other[1]) = (s.velocity, s.torque);
        }
        if let Some(f) = friction.get(seq) {
            (other[2], other[3]) = (f.blended_velocity, f.compensation);
        }
        if let Some(p) = position.get(seq) {
            other[4] = p.output;
        }
        if let Some(t) = torque.get(seq) {
            (other[5], other[6]) = (t.torque_reference, t.command);
        }
        if let Some(v) = valve.get(seq) {
            other[7] = v.requested;
        }
        let [omega_est, torque, blended_velocity, friction_comp, position_output, torque_ref, torque_command, valve_requested] =
            other;
        rows.push(ModelRow {
            t: (seq - start) as f64 * period_s,
            u,
            p_a: r.p_a * 1e-5,
            p_b: r.p_b * 1e-5,
            theta: r.angle,
            theta_ref,
            omega_est,
            torque,
            blended_velocity,
            friction_comp,
            position_output,
            torque_ref,
            torque_command,
            valve_requested,
        });
    }
    Ok(Export { rows, held, read })
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
