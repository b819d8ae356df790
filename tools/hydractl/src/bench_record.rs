//! `hydractl bench record`: sustained recording throughput of the
//! recorder's path (iceoryx2 receive, CDR framing, MCAP with zstd chunks to
//! a file) against the `mcap` crate writing the same messages, with the
//! same options, straight from memory.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use hydractl_bus::{quiet_ipc_logging, Bus, Outlet, RunScope};
use hydractl_config::Config;
use hydractl_plant::PA_PER_BAR;
use hydractl_processes::recording::Recorder;
use hydractl_recording::{RecordOptions, RecordingWriter};
use hydractl_samples::{
    service, FrictionSample, PlantReading, PositionSample, Recordable, SensorSample, TorqueSample, ValveSample,
    CDR_HEADER,
};
use hydractl_sim::simulate;

/// Cycles published between two drains: well inside a tap's buffer.
const BATCH: usize = 100;

#[derive(clap::Args)]
pub struct RecordBenchArgs {
    /// Control cycles of the simulated loop to record (six messages each).
    #[arg(long, default_value_t = 60_000)]
    cycles: usize,
    #[arg(long, default_value_t = 3)]
    repeat: usize,
}

/// One cycle of the loop's six samples, from the offline simulation, so
/// that they compress as the live loop's do.
struct Cycle {
    plant: PlantReading,
    sensor: SensorSample,
    friction: FrictionSample,
    position: PositionSample,
    torque: TorqueSample,
    valve: ValveSample,
}

fn cycles(n: usize) -> Result<Vec<Cycle>> {
    let config = Config::default_sim()?;
    let period = config.timing.control_period();
    let run = simulate(&config, &[], n as f64 * period)?;
    Ok(run
        .records
        .iter()
        .enumerate()
        .map(|(k, r)| {
            let seq = k as u64;
            let t = 1_000_000_000 + seq * 1_000_000;
            Cycle {
                plant: PlantReading {
                    sensor_seq: seq,
                    sensor_time_ns: t,
                    angle: r.theta,
                    p_a: r.p_a * PA_PER_BAR,
                    p_b: r.p_b * PA_PER_BAR,
                    true_angle: r.theta_true,
                    late_commands: 0,
                    ..PlantReading::default()
                },
                sensor: SensorSample {
                    sensor_seq: seq,
                    sensor_time_ns: t,
                    stage_time_ns: t + 12_000,
                    angle: r.theta,
                    velocity: r.omega_est,
                    p_a: r.p_a * PA_PER_BAR,
                    p_b: r.p_b * PA_PER_BAR,
                    torque: r.torque,
                    valid: 7,
                    source: 0,
                },
                friction: FrictionSample {
                    sensor_seq: seq,
                    sensor_time_ns: t,
                    stage_time_ns: t + 25_000,
                    compensation: r.friction_comp,
                    blended_velocity: r.omega_ref,
                    load_feedforward: r.load_feedforward,
                },
                position: PositionSample {
                    sensor_seq: seq,
                    sensor_time_ns: t,
                    stage_time_ns: t + 38_000,
                    reference_angle: r.theta_ref,
                    reference_velocity: r.omega_ref,
                    angle: r.theta,
                    output: r.torque_ref,
                    structure: 1,
                    variant: 1,
                    ..PositionSample::default()
                },
                torque: TorqueSample {
                    sensor_seq: seq,
                    sensor_time_ns: t,
                    stage_time_ns: t + 50_000,
                    torque_reference: r.torque_ref,
                    torque: r.torque,
                    command: r.u,
                    variant: 0,
                    reserved: 0,
                },
                valve: ValveSample {
                    sensor_seq: seq,
                    sensor_time_ns: t,
                    stage_time_ns: t + 60_000,
                    command: r.u,
                    requested: r.u,
                    faults: 0,
                    variant: 0,
                },
            }
        })
        .collect())
}

struct Outlets {
    plant: Outlet<PlantReading>,
    sensor: Outlet<SensorSample>,
    friction: Outlet<FrictionSample>,
    position: Outlet<PositionSample>,
    torque: Outlet<TorqueSample>,
    valve: Outlet<ValveSample>,
}

impl Outlets {
    fn publish(&self, c: &Cycle) -> Result<()> {
        self.plant.publish(c.plant)?;
        self.sensor.publish(c.sensor)?;
        self.friction.publish(c.friction)?;
        self.position.publish(c.position)?;
        self.torque.publish(c.torque)?;
        self.valve.publish(c.valve)?;
        Ok(())
    }
}

/// The recorder's time (drains and the final finish), publishing excluded.
fn time_recorder(data: &[Cycle], path: &std::path::Path) -> Result<Duration> {
    let scope = RunScope::new(&format!("hydractl_benchrec{}_", std::process::id()))?;
    scope.clean_stale()?;
    let outcome = (|| -> Result<Duration> {
        let bus = Bus::open(&scope, "bench")?;
        let writer = RecordingWriter::create(path, RecordOptions::default())?;
        let mut recorder = Recorder::new(&bus, writer)?;
        let outlets = Outlets {
            plant: Outlet::open(&bus, service::PLANT_READING)?,
            sensor: Outlet::open(&bus, service::SENSOR)?,
            friction: Outlet::open(&bus, service::FRICTION)?,
            position: Outlet::open(&bus, service::POSITION)?,
            torque: Outlet::open(&bus, service::TORQUE)?,
            valve: Outlet::open(&bus, service::VALVE)?,
        };
        let mut recording = Duration::ZERO;
        for batch in data.chunks(BATCH) {
            for cycle in batch {
                outlets.publish(cycle)?;
            }
            let started = Instant::now();
            recorder.drain()?;
            recording += started.elapsed();
        }
        let started = Instant::now();
        recorder.finish()?;
        Ok(recording + started.elapsed())
    })();
    scope.clean_stale()?;
    outcome
}

/// The `mcap` crate alone: the same messages, framed in advance, written
/// with the recorder's options.
fn time_raw_mcap(data: &[Cycle], path: &std::path::Path) -> Result<Duration> {
    let options = RecordOptions::default();
    let kinds = [
        (service::PLANT_READING, &PlantReading::KIND),
        (service::SENSOR, &SensorSample::KIND),
        (service::FRICTION, &FrictionSample::KIND),
        (service::POSITION, &PositionSample::KIND),
        (service::TORQUE, &TorqueSample::KIND),
        (service::VALVE, &ValveSample::KIND),
    ];
    let framed = |bytes: &[u8]| [&CDR_HEADER[..], bytes].concat();
    let messages: Vec<[Vec<u8>; 6]> = data
        .iter()
        .map(|c| {
            [
                framed(bytemuck::bytes_of(&c.plant)),
                framed(bytemuck::bytes_of(&c.sensor)),
                framed(bytemuck::bytes_of(&c.friction)),
                framed(bytemuck::bytes_of(&c.position)),
                framed(bytemuck::bytes_of(&c.torque)),
                framed(bytemuck::bytes_of(&c.valve)),
            ]
        })
        .collect();
    let started = Instant::now();
    let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_level(options.zstd_level)
        .compression_threads(0)
        .chunk_size(Some(options.chunk_bytes))
        .create(std::io::BufWriter::with_capacity(256 * 1024, file))?;
    let mut channels = [0u16; 6];
    for (id, (topic, kind)) in channels.iter_mut().zip(kinds) {
        let schema = writer.add_schema(kind.schema_name, "ros2msg", kind.ros2msg.as_bytes())?;
        *id = writer.add_channel(schema, topic, "cdr", &BTreeMap::new())?;
    }
    for (k, cycle) in messages.iter().enumerate() {
        for ((message, channel), (_, kind)) in cycle.iter().zip(channels).zip(kinds) {
            let time = kind.timestamp_ns(&message[4..]).unwrap_or(0);
            writer.write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: channel,
                    sequence: k as u32,
                    log_time: time,
                    publish_time: time,
                },
                message,
            )?;
        }
    }
    writer.finish()?;
    Ok(started.elapsed())
}

pub fn bench(args: RecordBenchArgs) -> Result<()> {
    quiet_ipc_logging();
    let data = cycles(args.cycles.max(BATCH))?;
    let messages = data.len() * 6;
    let bytes: usize = data.len()
        * (4 * 6
            + PlantReading::KIND.size
            + SensorSample::KIND.size
            + FrictionSample::KIND.size
            + PositionSample::KIND.size
            + TorqueSample::KIND.size
            + ValveSample::KIND.size);
    let dir = std::env::temp_dir().join(format!("hydractl-bench-record-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (mut ours, mut raw) = (Vec::new(), Vec::new());
    for _ in 0..args.repeat.max(1) {
        ours.push(time_recorder(&data, &dir.join("recorder.mcap"))?);
        raw.push(time_raw_mcap(&data, &dir.join("raw.mcap"))?);
    }
    let file_bytes = std::fs::metadata(dir.join("recorder.mcap"))
        .map(|m| m.len())
        .unwrap_or(0);
    std::fs::remove_dir_all(&dir).ok();
    ours.sort();
    raw.sort();
    let (ours, raw) = (ours[ours.len() / 2], raw[raw.len() / 2]);
    let rate = |d: Duration| (messages as f64 / d.as_secs_f64(), bytes as f64 / d.as_secs_f64() / 1e6);
    let ((ours_msgs, ours_mb), (raw_msgs, raw_mb)) = (rate(ours), rate(raw));
    crate::emit(&format!(
        "bench record: {} cycles × 6 services = {messages} messages, {:.1} MB framed, {:.1} MB on disk (zstd)\n\
         recorder (iceoryx2 receive + MCAP write): {ours_msgs:.0} msg/s, {ours_mb:.1} MB/s ({:.0}× a 1 kHz loop's 6000 msg/s)\n\
         mcap crate alone, same messages and options: {raw_msgs:.0} msg/s, {raw_mb:.1} MB/s\n\
         ratio recorder / raw: {:.2} (median of {})\n",
        data.len(),
        bytes as f64 / 1e6,
        file_bytes as f64 / 1e6,
        ours_msgs / 6000.0,
        ours_msgs / raw_msgs,
        args.repeat.max(1)
    ))
}
