//! Instructions of the loop's hot paths, counted by valgrind's callgrind
//! through gungraun: counts do not move with a shared machine's load, as
//! wall-clock times do. Each benchmark counts only its function, not the
//! fixture it starts from (`hydractl_benches`).

use std::hint::black_box;

use gungraun::prelude::*;
use hydractl_benches::{diagnose_record, next_period, one_thread, recording_batch, NextPeriod, RecordingBatch};
use hydractl_ident::greybox::{self, FitOptions, Signals};
use hydractl_stages::PositionOutput;

// One simulated second of `hydractl sim`'s closed loop: the plant at
// 10 kHz, the five stages at 1 kHz, each row written to a CSV file.
#[library_benchmark]
#[bench::default_plant()]
fn sim_one_second() -> u64 {
    let file = hydractl_benches::ScratchFile::new("sim.csv");
    let config = hydractl_benches::default_config();
    let mut rows = hydractl_sim::CsvRows::create(file.path()).expect("a CSV file");
    let summary = hydractl_sim::simulate_streaming(&config, &[], 1.0, |r| rows.write(r)).expect("the simulation runs");
    rows.finish().expect("the CSV file closes");
    black_box(summary.cycles)
}

#[library_benchmark]
#[bench::warm(setup = next_period)]
fn stage_sensor(mut p: NextPeriod) -> f64 {
    black_box(p.stack.sensor.process(black_box(&p.raw))).velocity
}

#[library_benchmark]
#[bench::warm(setup = next_period)]
fn stage_friction(mut p: NextPeriod) -> f64 {
    let out = p
        .stack
        .friction
        .process(black_box(&p.sensor), p.last_reference_velocity, p.last_command);
    black_box(out.compensation)
}

#[library_benchmark]
#[bench::warm(setup = next_period)]
fn stage_position(mut p: NextPeriod) -> f64 {
    black_box(p.stack.position.process(p.time, black_box(&p.sensor), p.friction)).output
}

#[library_benchmark]
#[bench::warm(setup = next_period)]
fn stage_torque(mut p: NextPeriod) -> f64 {
    let position: PositionOutput = black_box(p.position);
    black_box(p.stack.torque.process(&position, &p.sensor, p.friction.compensation))
}

// The valve process's period: the reading counted by the guard, then the
// command that answers it judged and shaped.
#[library_benchmark]
#[bench::warm(setup = next_period)]
fn stage_valve(mut p: NextPeriod) -> f64 {
    p.valve.on_sensor(p.seq, true);
    black_box(p.valve.on_command(p.seq, black_box(p.demand), 0)).map_or(f64::NAN, |(command, _)| command)
}

fn ten_seconds_with_a_deadzone() -> (rayon::ThreadPool, Signals) {
    (one_thread(), diagnose_record(10.0))
}

// `model diagnose` of ten seconds of 1 kHz data over the whole catalog,
// on one thread.
#[library_benchmark]
#[bench::ten_seconds(setup = ten_seconds_with_a_deadzone)]
fn diagnose((pool, signals): (rayon::ThreadPool, Signals)) -> usize {
    let diagnosis = pool
        .install(|| greybox::diagnose(&signals, None, FitOptions::default()))
        .expect("the diagnosis runs");
    black_box(diagnosis.candidates.len())
}

fn a_second_of_samples() -> RecordingBatch {
    recording_batch(1000)
}

// The recorder's write of a second of three services' samples (3000
// messages), to a closed file: CDR framing, chunking, zstd.
#[library_benchmark]
#[bench::one_second(setup = a_second_of_samples)]
fn mcap_write(mut batch: RecordingBatch) -> u64 {
    for (sensor, torque, valve) in &batch.samples {
        batch.writer.write_sample(batch.sensor, sensor).expect("written");
        batch.writer.write_sample(batch.torque, torque).expect("written");
        batch.writer.write_sample(batch.valve, valve).expect("written");
    }
    let messages = batch.writer.messages();
    batch.writer.finish().expect("the file closes");
    black_box(messages)
}

library_benchmark_group!(
    name = loop_hot_paths,
    benchmarks = [
        sim_one_second,
        stage_sensor,
        stage_friction,
        stage_position,
        stage_torque,
        stage_valve,
        diagnose,
        mcap_write
    ]
);

main!(library_benchmark_groups = loop_hot_paths);
