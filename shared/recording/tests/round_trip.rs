use std::collections::BTreeMap;
use std::path::Path;

use hydractl_recording::{
    decode, export_rows, read_messages, read_messages_in, summarize, RecordOptions, RecordingError, RecordingWriter,
    Window,
};
use hydractl_samples::{service, source, PlantReading, PositionSample, Recordable, SensorSample, ValveSample};

fn sensor(seq: u64) -> SensorSample {
    SensorSample {
        sensor_seq: seq,
        sensor_time_ns: 1_000_000_000 + seq * 1_000_000,
        stage_time_ns: 1_000_000_000 + seq * 1_000_000 + 20_000,
        angle: 0.001 * seq as f64,
        p_a: 8.0e6,
        p_b: 7.0e6,
        velocity: 0.25 + 0.001 * seq as f64,
        torque: 50.0,
        valid: 7,
        ..SensorSample::default()
    }
}

fn valve(seq: u64) -> ValveSample {
    ValveSample {
        sensor_seq: seq,
        sensor_time_ns: 1_000_000_000 + seq * 1_000_000,
        stage_time_ns: 1_000_000_000 + seq * 1_000_000 + 60_000,
        command: -0.5 + 0.001 * seq as f64,
        requested: -0.4 + 0.001 * seq as f64,
        ..ValveSample::default()
    }
}

fn reading(seq: u64) -> PlantReading {
    PlantReading {
        sensor_seq: seq,
        sensor_time_ns: 1_000_000_000 + seq * 1_000_000,
        angle: 0.001 * seq as f64,
        p_a: 8.0e6,
        p_b: 7.0e6,
        ..PlantReading::default()
    }
}

fn position(seq: u64) -> PositionSample {
    PositionSample {
        sensor_seq: seq,
        sensor_time_ns: 1_000_000_000 + seq * 1_000_000,
        stage_time_ns: 1_000_000_000 + seq * 1_000_000 + 40_000,
        reference_angle: 0.5,
        ..PositionSample::default()
    }
}

/// The three channels the model tools read: valve, position, plant.
fn model_channels(w: &mut RecordingWriter) -> [hydractl_recording::ChannelHandle; 3] {
    [
        (service::VALVE, &ValveSample::KIND),
        (service::POSITION, &PositionSample::KIND),
        (service::PLANT_READING, &PlantReading::KIND),
    ]
    .map(|(topic, kind)| w.add_channel(topic, kind).expect("channel"))
}

/// A recording of `n` periods of the three channels the model tools read.
fn record(path: &Path, n: u64, options: RecordOptions) -> Vec<std::path::PathBuf> {
    let mut w = RecordingWriter::create(path, options).expect("create");
    let s = w.add_channel(service::SENSOR, &SensorSample::KIND).expect("channel");
    let [v, p, r] = model_channels(&mut w);
    for seq in 0..n {
        w.write_sample(r, &reading(seq)).expect("write");
        w.write_sample(s, &sensor(seq)).expect("write");
        // The stages skipped reading 40, as a loaded stage may.
        if seq != 40 {
            w.write_sample(p, &position(seq)).expect("write");
            w.write_sample(v, &valve(seq)).expect("write");
        }
    }
    w.finish().expect("finish")
}

#[test]
fn samples_come_back_bit_for_bit_with_their_metadata() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("run.mcap");
    let metadata = BTreeMap::from([("version".to_owned(), "0.1.0".to_owned())]);
    let files = record(
        &path,
        500,
        RecordOptions {
            metadata: metadata.clone(),
            ..RecordOptions::default()
        },
    );
    assert_eq!(files, vec![path.clone()]);
    let mut sensors = Vec::new();
    let outcome = read_messages(&path, |m| {
        if let Some(s) = decode::<SensorSample>(m) {
            assert_eq!(m.log_time_ns, s.stage_time_ns);
            sensors.push(s);
        }
        Ok(())
    })
    .expect("read");
    assert_eq!(outcome.messages, 4 * 500 - 2);
    assert_eq!(outcome.truncated, None);
    assert_eq!(outcome.metadata, metadata);
    assert_eq!(sensors, (0..500).map(sensor).collect::<Vec<_>>());

    let summary = summarize(&path).expect("summary");
    let valve = summary
        .channels
        .iter()
        .find(|c| c.topic == service::VALVE)
        .expect("valve");
    assert_eq!(
        (valve.messages, valve.first_seq, valve.last_seq, valve.missing),
        (499, 0, 499, 1)
    );
    let plant = summary
        .channels
        .iter()
        .find(|c| c.topic == service::PLANT_READING)
        .expect("plant");
    assert!((plant.rate_hz - 1000.0).abs() < 1e-6);
    assert_eq!(valve.schema, "hydractl/msg/ValveSample");
}

/// Every message's (topic, log time) of `path` inside `window`, and the metadata.
fn window_of(path: &Path, window: Option<Window>) -> (Vec<(String, u64)>, BTreeMap<String, String>) {
    let mut seen = Vec::new();
    let outcome = read_messages_in(path, window, |m| {
        seen.push((m.topic.to_owned(), m.log_time_ns));
        Ok(())
    })
    .expect("read");
    (seen, outcome.metadata)
}

#[test]
fn a_window_read_through_the_index_is_the_whole_reads_stretch() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("run.mcap");
    let metadata = BTreeMap::from([("machine_id".to_owned(), "rotator-7".to_owned())]);
    // Small chunks: the window spans several, and most are never read.
    let options = RecordOptions {
        chunk_bytes: 16 * 1024,
        metadata: metadata.clone(),
        ..RecordOptions::default()
    };
    record(&path, 3000, options);
    let (all, _) = window_of(&path, None);
    let first = all.iter().map(|(_, t)| *t).min().expect("messages");
    let inside = |t: u64| (first + 1_000_000_000..first + 1_500_000_000).contains(&t);
    let expected: Vec<_> = all.iter().filter(|(_, t)| inside(*t)).cloned().collect();
    let window = Some(Window { from_s: 1.0, to_s: 1.5 });
    let (got, got_metadata) = window_of(&path, window);
    assert_eq!(got, expected);
    assert_eq!(got_metadata, metadata);
    assert!(
        got.len() > 1500,
        "half a second of four channels at 1 kHz: {}",
        got.len()
    );

    // A file without its summary (a killed recorder) is read from its start.
    let bytes = std::fs::read(&path).expect("read");
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 4]).expect("write");
    let (got, _) = window_of(&cut, window);
    assert_eq!(got, expected);
}

#[test]
fn export_joins_by_sequence_on_the_loop_clock() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("run.mcap");
    record(&path, 100, RecordOptions::default());
    let export = export_rows(&path).expect("export");
    let rows = export.rows;
    assert_eq!(rows.len(), 100);
    // The skipped reading's row holds the previous command.
    assert_eq!(export.held, 1);
    assert_eq!(export.after_loop, 0);
    assert_eq!(rows[40].u, rows[39].u);
    assert!((rows[40].t - 0.040).abs() < 1e-12);
    assert!((rows[10].t - 0.010).abs() < 1e-12);
    assert!((rows[10].u - valve(10).command).abs() < 1e-15);
    assert!((rows[10].p_a - 80.0).abs() < 1e-12);
    assert!((rows[10].theta - 0.010).abs() < 1e-15);
    assert_eq!(rows[10].theta_ref, 0.5);
    // The sensor stage's signals come along; a stage not recorded (no
    // friction or torque loop here) is NaN, not a number it never sent.
    assert_eq!(rows[10].omega_est, sensor(10).velocity);
    assert_eq!(rows[10].torque, sensor(10).torque);
    assert!(rows[10].torque_ref.is_nan() && rows[10].blended_velocity.is_nan());
    assert_eq!(rows[10].valve_requested, valve(10).requested);
}

#[test]
fn splitting_by_size_and_by_duration_makes_parts_that_each_read_alone() {
    let dir = tempfile::tempdir().expect("tempdir");
    let by_time = record(
        &dir.path().join("timed.mcap"),
        3000,
        RecordOptions {
            split_seconds: Some(1.0),
            ..RecordOptions::default()
        },
    );
    assert_eq!(by_time.len(), 3, "{by_time:?}");
    assert!(by_time[0].ends_with("timed_000.mcap"));
    let counts: Vec<u64> = by_time.iter().map(|f| summarize(f).expect("part").messages).collect();
    assert_eq!(counts, vec![4000 - 2, 4000, 4000]);

    let by_size = record(
        &dir.path().join("sized.mcap"),
        20_000,
        RecordOptions {
            split_bytes: Some(64 * 1024),
            chunk_bytes: 16 * 1024,
            ..RecordOptions::default()
        },
    );
    assert!(by_size.len() >= 2, "{by_size:?}");
    let total: u64 = by_size.iter().map(|f| summarize(f).expect("part").messages).sum();
    assert_eq!(total, 80_000 - 2);
}

#[test]
fn a_part_split_by_size_stays_near_its_size_with_chunks_larger_than_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let limit = 100_000u64;
    // The recorder's chunks (512 kB before compression) hold more than a
    // part: the open chunk counts as it will be written.
    let parts = record(
        &dir.path().join("run.mcap"),
        20_000,
        RecordOptions {
            split_bytes: Some(limit),
            ..RecordOptions::default()
        },
    );
    let sizes: Vec<u64> = parts
        .iter()
        .map(|p| std::fs::metadata(p).expect("part").len())
        .collect();
    assert!(parts.len() >= 3, "{sizes:?}");
    // The first part guesses no compression; after it, each lands near its size.
    for size in &sizes[1..sizes.len() - 1] {
        assert!(
            (limit * 7 / 10..=limit * 13 / 10).contains(size),
            "parts of {sizes:?} bytes for a split at {limit}"
        );
    }
}

#[test]
fn a_file_cut_short_reads_up_to_its_last_whole_chunk() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("killed.mcap");
    let mut w = RecordingWriter::create(&path, RecordOptions::default()).expect("create");
    let v = w.add_channel(service::VALVE, &ValveSample::KIND).expect("channel");
    for seq in 0..300 {
        w.write_sample(v, &valve(seq)).expect("write");
    }
    w.flush().expect("flush");
    let flushed = std::fs::read(&path).expect("read");
    for seq in 300..600 {
        w.write_sample(v, &valve(seq)).expect("write");
    }
    w.flush().expect("flush");
    let later = std::fs::read(&path).expect("read");
    // As a killed recorder leaves it: the first chunk whole, the second cut.
    let cut = &later[..flushed.len() + (later.len() - flushed.len()) / 2];
    let cut_path = dir.path().join("cut.mcap");
    std::fs::write(&cut_path, cut).expect("write");
    let summary = summarize(&cut_path).expect("a cut file still reads");
    assert_eq!(summary.messages, 300);
    assert!(summary.truncated.is_some());
    // And one that stopped between chunks.
    std::fs::write(&cut_path, &flushed).expect("write");
    let summary = summarize(&cut_path).expect("read");
    assert_eq!(summary.messages, 300);
    assert!(summary.truncated.as_deref().is_some_and(|t| t.contains("summary")));
}

#[test]
fn a_corrupt_chunk_loses_only_itself_and_is_named_by_its_time() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("run.mcap");
    let mut w = RecordingWriter::create(&path, RecordOptions::default()).expect("create");
    let v = w.add_channel(service::VALVE, &ValveSample::KIND).expect("channel");
    for seq in 0..900 {
        w.write_sample(v, &valve(seq)).expect("write");
        // Three chunks of 300 samples.
        if seq % 300 == 299 {
            w.flush().expect("flush");
        }
    }
    w.finish().expect("finish");
    let mut bytes = std::fs::read(&path).expect("read");
    let summary = mcap::Summary::read(&bytes).expect("summary").expect("a finished file");
    let mut chunks = summary.chunk_indexes.clone();
    chunks.sort_by_key(|c| c.chunk_start_offset);
    assert_eq!(chunks.len(), 3);
    let middle = (chunks[1].chunk_start_offset + chunks[1].chunk_length / 2) as usize;
    bytes[middle..middle + 64].fill(0xff);
    std::fs::write(&path, &bytes).expect("write");
    let mut seqs = Vec::new();
    let outcome = read_messages(&path, |m| {
        if let Some(valve) = decode::<ValveSample>(m) {
            seqs.push(valve.sensor_seq);
        }
        Ok(())
    })
    .expect("a corrupt chunk does not stop the reading");
    assert_eq!(seqs, (0..300).chain(600..900).collect::<Vec<_>>());
    let why = outcome.truncated.expect("said");
    assert!(why.contains("corrupt") && why.contains("skipped"), "{why}");
}

#[test]
fn bad_files_are_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("notes.mcap");
    std::fs::write(&path, "not a recording").expect("write");
    let e = summarize(&path).expect_err("not mcap");
    assert!(
        e.to_string().contains("notes.mcap") && e.to_string().contains("not an MCAP"),
        "{e}"
    );

    let missing = dir.path().join("absent.mcap");
    let e = summarize(&missing).expect_err("absent");
    assert!(e.to_string().contains("absent.mcap"), "{e}");

    // Only the readings: export says which channel is missing and what there is.
    let path = dir.path().join("readings_only.mcap");
    let mut w = RecordingWriter::create(&path, RecordOptions::default()).expect("create");
    let r = w
        .add_channel(service::PLANT_READING, &PlantReading::KIND)
        .expect("channel");
    w.write_sample(r, &reading(0)).expect("write");
    w.finish().expect("finish");
    match export_rows(&path) {
        Err(RecordingError::MissingChannel { topic, have, .. }) => {
            assert_eq!(topic, service::VALVE);
            assert_eq!(have, service::PLANT_READING);
        }
        other => panic!("expected a missing channel, got {other:?}"),
    }

    // A payload that is not its channel's type.
    let path = dir.path().join("wrong.mcap");
    let mut w = RecordingWriter::create(&path, RecordOptions::default()).expect("create");
    let s = w.add_channel(service::SENSOR, &SensorSample::KIND).expect("channel");
    let e = w.write_sample(s, &valve(0)).expect_err("wrong type");
    assert!(e.to_string().contains(service::SENSOR), "{e}");
}

#[test]
fn a_ring_deletes_the_oldest_parts_earlier_runs_first_and_keeps_within_its_limit() {
    let dir = tempfile::tempdir().expect("tempdir");
    // An earlier run's parts in the same ring, 40 kB each.
    let earlier: Vec<std::path::PathBuf> = (0..3)
        .map(|i| {
            let p = dir.path().join(format!("run-2026-11-24T100000Z_00{i}.mcap"));
            std::fs::write(&p, vec![0u8; 40_000]).expect("earlier part");
            p
        })
        .collect();
    let keep = 200_000;
    let options = RecordOptions {
        split_bytes: Some(30_000),
        // Small chunks, so that the parts split near their size.
        chunk_bytes: 16 * 1024,
        keep_bytes: Some(keep),
        adopt: earlier.clone(),
        ..RecordOptions::default()
    };
    let kept = record(&dir.path().join("run-2026-11-24T110000Z.mcap"), 20_000, options);
    assert!(earlier.iter().all(|p| !p.exists()), "the earlier run's parts go first");
    let on_disk: u64 = std::fs::read_dir(dir.path())
        .expect("dir")
        .filter_map(Result::ok)
        .map(|e| e.metadata().expect("meta").len())
        .sum();
    assert!(on_disk <= keep, "{on_disk} bytes kept, over {keep}");
    assert!(kept.len() >= 3, "{kept:?}");
    // The newest part holds the end, whole.
    let newest = summarize(kept.last().expect("a part")).expect("readable");
    assert_eq!(newest.truncated, None);
    let valve = newest
        .channels
        .iter()
        .find(|c| c.topic == service::VALVE)
        .expect("valve");
    assert_eq!(valve.last_seq, 19_999);
}

#[test]
fn a_message_that_cannot_be_read_is_named_by_channel_time_and_sequence() {
    use hydractl_recording::{MESSAGE_ENCODING, SCHEMA_ENCODING};
    use hydractl_samples::CDR_HEADER;
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("bad.mcap");
    // Written apart from RecordingWriter, which refuses such a payload: a
    // sensor sample cut short, after a whole one.
    let file = std::io::BufWriter::new(std::fs::File::create(&path).expect("create"));
    let mut writer = mcap::Writer::new(file).expect("writer");
    let kind = &SensorSample::KIND;
    let schema = writer
        .add_schema(kind.schema_name, SCHEMA_ENCODING, kind.ros2msg.as_bytes())
        .expect("schema");
    let channel = writer
        .add_channel(schema, service::SENSOR, MESSAGE_ENCODING, &BTreeMap::new())
        .expect("channel");
    let whole = [&CDR_HEADER[..], bytemuck::bytes_of(&sensor(6))].concat();
    let cut = &whole[..whole.len() - 8];
    for (sequence, log_time, data) in [(6, 1_006_000_000, &whole[..]), (7, 1_007_000_000, cut)] {
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence,
            log_time,
            publish_time: log_time,
        };
        writer.write_to_known_channel(&header, data).expect("write");
    }
    writer.finish().expect("finish");

    let err = read_messages(&path, |_| Ok(())).expect_err("a cut sample").to_string();
    for part in [
        "bad.mcap",
        "message 1 on `hydractl/sensor`",
        "log time 1007000000 ns",
        "sequence 7",
    ] {
        assert!(err.contains(part), "{part}: {err}");
    }
}

#[test]
fn in_a_recording_of_the_machine_the_simulated_plants_readings_are_left_out() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("run.mcap");
    let mut w = RecordingWriter::create(&path, RecordOptions::default()).expect("create");
    let [v, p, r] = model_channels(&mut w);
    // The machine lost at reading 70, the simulated plant in charge until
    // the machine is asked back at 85.
    for seq in 0..100 {
        let on_machine = !(70..85).contains(&seq);
        let source = if on_machine {
            source::MACHINE
        } else {
            source::SIMULATION
        };
        w.write_sample(r, &PlantReading { source, ..reading(seq) })
            .expect("write");
        w.write_sample(p, &position(seq)).expect("write");
        w.write_sample(v, &valve(seq)).expect("write");
    }
    w.finish().expect("finish");
    let export = export_rows(&path).expect("export");
    assert_eq!((export.simulated, export.simulated_from_s), (15, Some(0.070)));
    assert_eq!(export.rows.len(), 85);
    // The machine's readings keep their own times: the left-out stretch is
    // a gap, never closed up.
    assert!((export.rows[69].t - 0.069).abs() < 1e-12);
    assert!((export.rows[70].t - 0.085).abs() < 1e-12);
}
