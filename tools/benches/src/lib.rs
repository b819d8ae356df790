//! Fixtures for the instruction-count benchmarks (`benches/instructions.rs`):
//! the state each measured call starts from, built outside the count. Every
//! fixture is deterministic (the simulator is seeded), so a count moves
//! only when the code does.
//!
//! Run them with `cargo bench -p hydractl-benches` (valgrind and the
//! `gungraun-runner` of the library's version are needed; `.ci/run`
//! installs both); `tools/benches/guard.py` holds them to
//! `tools/benches/baselines.json`.
//!
//! What it holds: The counts CI holds: `gungraun` (callgrind) benchmarks of
//! one simulated second of `sim`'s loop, one period of each stage, one `model
//! diagnose` of a fixed record and one MCAP write of a fixed batch
//! (`benches/instructions.rs`, fixtures in `src/lib.rs`); `baselines.json`,
//! and `guard.py`, which fails when a count (or `bench syscalls`' system
//! calls per hop) grows over its baseline by more than 10 %.

use std::path::{Path, PathBuf};

use hydractl_config::Config;
use hydractl_ident::greybox::Signals;
use hydractl_ident::Dataset;
use hydractl_plant::{Effect, RawReading};
use hydractl_recording::{ChannelHandle, RecordOptions, RecordingWriter};
use hydractl_samples::{service, Recordable, SensorSample, TorqueSample, ValveSample};
use hydractl_sim::{build_plant, simulate};
use hydractl_stages::{ControlStack, FrictionOutput, PositionOutput, SensorEstimate, ValveStage};

/// Periods the loop runs before the measured one: the controllers and
/// filters in motion, not at their start.
const WARM_PERIODS: u64 = 500;

/// The simulated default, as `hydractl sim` loads it.
pub fn default_config() -> Config {
    Config::default_sim().expect("the built-in config loads")
}

/// The control stack after `WARM_PERIODS` periods on the simulated
/// plant, and what each stage is given in the next period.
#[derive(Clone)]
pub struct NextPeriod {
    pub stack: ControlStack,
    /// The valve process's guard, fed as the live valve feeds it.
    pub valve: ValveStage,
    pub time: f64,
    pub seq: u64,
    pub raw: RawReading,
    pub last_reference_velocity: f64,
    pub last_command: f64,
    pub sensor: SensorEstimate,
    pub friction: FrictionOutput,
    pub position: PositionOutput,
    /// The torque stage's demand: what the valve is sent.
    pub demand: f64,
}

/// The stack warmed up, with the next period's inputs to every stage
/// worked out (each stage's own call is what a benchmark counts).
pub fn next_period() -> NextPeriod {
    let config = default_config();
    let (mut plant, mut sensors) = build_plant(&config, &[]).expect("the default plant builds");
    let mut stack = ControlStack::new(&config).expect("the default stack builds");
    let mut valve = ValveStage::new(&config).expect("the default valve stage builds");
    let period = config.timing.control_period();
    let substeps = config.timing.substeps();
    let (mut last_reference_velocity, mut last_command) = (0.0, 0.0);
    for seq in 0..WARM_PERIODS {
        let raw = sensors.read(&plant.state());
        let out = stack.step(seq as f64 * period, &raw);
        valve.on_sensor(seq, true);
        valve.on_command(seq, out.command, 0);
        last_reference_velocity = out.position.reference.velocity;
        last_command = out.command;
        plant.advance(out.command, substeps);
    }
    let seq = WARM_PERIODS;
    let time = seq as f64 * period;
    let raw = sensors.read(&plant.state());
    let mut ahead = stack.clone();
    let sensor = ahead.sensor.process(&raw);
    let friction = ahead.friction.process(&sensor, last_reference_velocity, last_command);
    let position = ahead.position.process(time, &sensor, friction);
    let demand = ahead.torque.process(&position, &sensor, friction.compensation);
    NextPeriod {
        stack,
        valve,
        time,
        seq,
        raw,
        last_reference_velocity,
        last_command,
        sensor,
        friction,
        position,
        demand,
    }
}

/// A small fixed record for `model diagnose`: `seconds` of the simulated
/// default's closed loop with a hidden dead-zone, as `bench diagnose`
/// takes it.
pub fn diagnose_record(seconds: f64) -> Signals {
    let config = default_config();
    let hidden = Effect::parse("deadzone").expect("a catalog effect");
    let run = simulate(&config, &[hidden], seconds).expect("the simulation runs");
    let data = Dataset::from_columns("simulated", run.model_columns());
    Signals::from_dataset(&data).expect("the record's columns")
}

/// One thread, the caller's: the counts of code that runs on rayon are
/// those of one deterministic order of work, all on the counted thread.
pub fn one_thread() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .use_current_thread()
        .build()
        .expect("a one-thread pool")
}

/// A file of the benchmark's own, removed when dropped.
pub struct ScratchFile(pub PathBuf);

impl ScratchFile {
    pub fn new(name: &str) -> Self {
        Self(std::env::temp_dir().join(format!("hydractl-bench-{}-{name}", std::process::id())))
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for ScratchFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// A recording to write a fixed batch into: the writer, its channels and
/// `cycles` periods of the loop's samples (a reading, a command and the
/// valve's state per period).
pub struct RecordingBatch {
    pub writer: RecordingWriter,
    pub sensor: ChannelHandle,
    pub torque: ChannelHandle,
    pub valve: ChannelHandle,
    pub samples: Vec<(SensorSample, TorqueSample, ValveSample)>,
    pub file: ScratchFile,
}

pub fn recording_batch(cycles: u64) -> RecordingBatch {
    let file = ScratchFile::new("batch.mcap");
    let mut writer = RecordingWriter::create(file.path(), RecordOptions::default()).expect("a recording");
    let sensor = writer
        .add_channel(service::SENSOR, &SensorSample::KIND)
        .expect("a channel");
    let torque = writer
        .add_channel(service::TORQUE, &TorqueSample::KIND)
        .expect("a channel");
    let valve = writer
        .add_channel(service::VALVE, &ValveSample::KIND)
        .expect("a channel");
    let samples = (0..cycles)
        .map(|seq| {
            let t = seq as f64 * 1e-3;
            let time_ns = 1_000_000_000 + seq * 1_000_000;
            let angle = 0.2 * (2.0 * t).sin();
            (
                SensorSample {
                    sensor_seq: seq,
                    sensor_time_ns: time_ns,
                    stage_time_ns: time_ns + 12_000,
                    angle,
                    velocity: 0.4 * (2.0 * t).cos(),
                    p_a: 80e5 + 5e5 * (3.0 * t).sin(),
                    p_b: 80e5,
                    torque: 150.0 * (3.0 * t).sin(),
                    valid: hydractl_samples::valid::ALL,
                    source: hydractl_samples::source::SIMULATION,
                },
                TorqueSample {
                    sensor_seq: seq,
                    sensor_time_ns: time_ns,
                    stage_time_ns: time_ns + 30_000,
                    command: 0.1 * (2.0 * t).cos(),
                    ..TorqueSample::default()
                },
                ValveSample {
                    sensor_seq: seq,
                    sensor_time_ns: time_ns,
                    stage_time_ns: time_ns + 35_000,
                    command: 0.1 * (2.0 * t).cos(),
                    requested: 0.1 * (2.0 * t).cos(),
                    faults: 0,
                    variant: 0,
                },
            )
        })
        .collect();
    RecordingBatch {
        writer,
        sensor,
        torque,
        valve,
        samples,
        file,
    }
}
