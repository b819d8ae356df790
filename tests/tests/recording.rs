//! Recording the live stack to MCAP: nothing lost, a killed recorder's
//! file still readable, attaching to a running stack, and a process run
//! again on recorded data.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use hydractl_bus::{Bus, Reader, PREFIX_ENV};
use hydractl_recording::{decode, read_messages, summarize, RecordingSummary};
use hydractl_samples::{
    name_str, service, PlantReading, PositionSample, RecorderStatus, SensorSample, SupervisorStatus, ValveSample,
};
use hydractl_system_tests::*;
use nix::sys::signal::Signal;

fn channel<'a>(summary: &'a RecordingSummary, topic: &str) -> &'a hydractl_recording::ChannelSummary {
    summary
        .channels
        .iter()
        .find(|c| c.topic == topic)
        .unwrap_or_else(|| panic!("no channel {topic} in {summary:?}"))
}

/// The last sample of each kind, as the Rust reader decodes it, in the
/// field names of the schema.
fn last_samples(path: &Path) -> BTreeMap<String, serde_json::Value> {
    let mut last = BTreeMap::new();
    read_messages(path, |m| {
        let value = if let Some(v) = decode::<ValveSample>(m) {
            serde_json::json!({"sensor_seq": v.sensor_seq, "command": v.command, "faults": v.faults})
        } else if let Some(s) = decode::<SensorSample>(m) {
            serde_json::json!({"sensor_seq": s.sensor_seq, "angle": s.angle, "p_a": s.p_a, "torque": s.torque, "valid": s.valid})
        } else if let Some(p) = decode::<PositionSample>(m) {
            serde_json::json!({"sensor_seq": p.sensor_seq, "reference_angle": p.reference_angle, "output": p.output, "variant": p.variant})
        } else if let Some(p) = decode::<PlantReading>(m) {
            serde_json::json!({"sensor_seq": p.sensor_seq, "p_b": p.p_b, "true_angle": p.true_angle})
        } else if let Some(r) = decode::<RecorderStatus>(m) {
            serde_json::json!({"seq": r.seq, "messages": r.messages, "dropped": r.dropped, "gaps": r.gaps})
        } else if let Some(s) = decode::<SupervisorStatus>(m) {
            let names: Vec<&str> = s.processes[..s.process_count as usize]
                .iter()
                .map(|p| name_str(&p.name))
                .collect();
            serde_json::json!({"seq": s.seq, "process_count": s.process_count, "names": names})
        } else {
            return Ok(());
        };
        last.insert(m.topic.to_owned(), value);
        Ok(())
    })
    .expect("read");
    last
}

#[test]
fn a_ten_second_recording_holds_every_sample_published_and_python_decodes_it() {
    let _turn = serial();
    let scope = unique_scope("rec10");
    let dir = scratch_dir("rec10");
    let (file, summary_path) = (dir.join("run.mcap"), dir.join("summary.json"));
    let mut witness = Witness::open(&scope);
    let mut run = start_run(
        &scope,
        &[
            "--duration",
            "10",
            "--record",
            file.to_str().expect("path"),
            "--summary-json",
            summary_path.to_str().expect("path"),
        ],
    );
    // A service that appears mid-run, as a hot-swapped controller's does.
    const LATE: &str = "hydractl/position/late";
    let late_bus = Bus::open(&scope, "late").expect("node");
    let mut late: Option<hydractl_bus::Outlet<PositionSample>> = None;
    let mut late_published = 0u64;
    let started = Instant::now();
    let deadline = started + Duration::from_secs(60);
    while run.0.try_wait().expect("wait").is_none() {
        assert!(Instant::now() < deadline, "the run ends");
        witness.poll();
        let elapsed = started.elapsed();
        if late.is_none() && elapsed > Duration::from_secs(3) {
            late = Some(hydractl_bus::Outlet::open(&late_bus, LATE).expect("late outlet"));
        }
        // Discovery runs every 200 ms: publish once the recorder has had time to find it.
        if let Some(outlet) = &late {
            if elapsed > Duration::from_secs(4) && late_published < 500 {
                outlet
                    .publish(PositionSample {
                        sensor_seq: late_published,
                        stage_time_ns: hydractl_bus::clock::now_ns(),
                        ..PositionSample::default()
                    })
                    .expect("publish");
                late_published += 1;
            }
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    drop(late);
    witness.poll();
    assert!(wait_exit(&mut run.0, Duration::from_secs(1)).success());
    let run: serde_json::Value = read_json(&summary_path);
    let cycles = run["cycles"].as_u64().expect("cycles");
    assert!(cycles >= 9_500, "{run}");
    assert!(run["processes"]
        .as_array()
        .expect("processes")
        .iter()
        .any(|p| p["name"] == "recorder"));
    assert_eq!(run["recording"]["files"][0], file.to_str().expect("path"));
    assert_eq!(run["recording"]["dropped"], 0, "{run}");

    // Every sample the witness saw published is in the recording, and the
    // recording holds nothing else.
    let recorded = recorded_sequences(&file);
    for (topic, seen) in &witness.seen {
        let held = &recorded[*topic];
        // A stage under load may skip a reading (it takes the newest).
        assert!(
            seen.len() as u64 + 20 >= cycles,
            "{topic}: the witness saw {}",
            seen.len()
        );
        let lost: Vec<&u64> = seen.difference(held).collect();
        let extra: Vec<&u64> = held
            .range(seen.first().copied().unwrap_or(0)..)
            .filter(|s| !seen.contains(s))
            .collect();
        assert!(lost.is_empty(), "{topic}: published but not recorded: {lost:?}");
        assert!(
            extra.is_empty(),
            "{topic}: recorded but never seen published: {extra:?}"
        );
    }
    drop(witness);

    let summary = summarize(&file).expect("the recording reads");
    assert_eq!(summary.truncated, None);
    for topic in PIPELINE_SERVICES {
        let c = channel(&summary, topic);
        assert!(
            c.messages + 20 >= cycles,
            "{topic}: {} recorded, {cycles} cycles",
            c.messages
        );
    }
    let late = channel(&summary, LATE);
    assert_eq!(
        (late.messages, late.first_seq, late.last_seq),
        (500, 0, 499),
        "{late:?}"
    );
    // Subscribed before the plant existed: its very first reading is there.
    assert_eq!(channel(&summary, service::PLANT_READING).first_seq, 0);
    for topic in [service::SUPERVISOR_STATUS, service::RECORDER_STATUS] {
        assert_eq!(channel(&summary, topic).missing, 0);
    }
    assert!(summary.metadata.get("config").is_some_and(|c| c.contains("[timing]")));
    assert!(summary
        .metadata
        .get("software")
        .is_some_and(|s| s.starts_with("hydractl ")));
    let last = last_samples(&file);
    assert_eq!(last[service::RECORDER_STATUS]["dropped"], 0);
    let names = &last[service::SUPERVISOR_STATUS]["names"];
    for name in [
        "plant",
        "sensor",
        "friction",
        "position",
        "torque",
        "valve",
        "recorder",
        "supervisor",
    ] {
        assert!(
            names.as_array().expect("names").iter().any(|n| n == name),
            "{name} in {names}"
        );
    }

    // The model tools read the recording directly, or as the CSV it exports.
    let csv = dir.join("run.csv");
    let export = hydractl()
        .args(["mcap", "export-csv"])
        .arg(&file)
        .arg("--out")
        .arg(&csv)
        .output()
        .expect("export");
    assert!(export.status.success(), "{}", String::from_utf8_lossy(&export.stderr));
    let text = std::fs::read_to_string(&csv).expect("csv");
    assert!(
        text.starts_with(
            "t,u,p_a,p_b,theta,theta_ref,omega_est,torque,blended_velocity,friction_comp,\
             position_output,torque_ref,torque_command,valve_requested\n"
        ),
        "{}",
        text.lines().next().unwrap_or_default()
    );
    // The plant waits for the chain before its first reading, and for the
    // chain's first answer to it: every reading is answered, the first too
    // (also by a stage that woke late for it), and has its row.
    for stage in [service::POSITION, service::TORQUE, service::VALVE] {
        assert_eq!(channel(&summary, stage).first_seq, 0, "{stage}");
    }
    // One row per reading up to the loop's last command; the readings
    // after it (the stack stopping) answer nothing and are left out.
    let expected = channel(&summary, service::VALVE).last_seq + 1;
    let rows = text.lines().count() as u64 - 1;
    assert_eq!(rows, expected, "{rows} rows, {expected} readings the loop answered");
    let fit = hydractl()
        .args(["model", "fit", "--data"])
        .arg(&file)
        .arg("--out")
        .arg(dir.join("model.toml"))
        .output()
        .expect("fit");
    assert!(fit.status.success(), "{}", String::from_utf8_lossy(&fit.stderr));
    // Every stage's signal is data for `ident`, here the closed torque loop
    // of the cascade: its reference to the torque measured.
    let torque_loop = hydractl()
        .args(["ident", "tf", "--data"])
        .arg(&file)
        .args([
            "--input",
            "torque_ref",
            "--output",
            "torque",
            "--poles",
            "2",
            "--zeros",
            "0",
            "--json",
        ])
        .output()
        .expect("ident tf");
    assert!(
        torque_loop.status.success(),
        "{}",
        String::from_utf8_lossy(&torque_loop.stderr)
    );
    let identified: serde_json::Value = serde_json::from_slice(&torque_loop.stdout).expect("json");
    assert!(
        identified["fit_percent"].as_f64().is_some_and(f64::is_finite),
        "{identified}"
    );

    // Decoded by two readers we did not write: as PlotJuggler's Python
    // tools and as Foxglove itself would.
    let views = [("python", python_view(&[], &file)), ("foxglove", foxglove_view(&file))];
    for (reader, view) in views.iter().filter_map(|(r, v)| v.as_ref().map(|v| (r, v))) {
        for c in &summary.channels {
            let seen = &view[&c.topic];
            assert_eq!(seen["count"].as_u64(), Some(c.messages), "{reader}: {}", c.topic);
            assert_eq!(seen["schema"], c.schema.as_str(), "{reader}");
            assert_eq!(seen["encoding"], "cdr", "{reader}");
        }
        for (topic, fields) in &last {
            let decoded = &view[topic]["last"];
            for (key, value) in fields.as_object().expect("fields") {
                if key == "names" {
                    let python_names: Vec<String> = decoded["processes"]
                        .as_array()
                        .expect("processes")
                        .iter()
                        .take(decoded["process_count"].as_u64().expect("count") as usize)
                        // A ROS 2 string, as Foxglove shows it.
                        .map(|p| p["name"].as_str().expect("the name is a string").to_owned())
                        .collect();
                    assert_eq!(serde_json::json!(python_names), *value, "{reader}: {topic}");
                } else if let (Some(a), Some(b)) = (decoded[key].as_f64(), value.as_f64()) {
                    // serde_json parses the last digit of a float loosely.
                    assert!(
                        (a - b).abs() <= 4.0 * f64::EPSILON * a.abs(),
                        "{reader}: {topic}.{key}: {a} vs {b}"
                    );
                } else {
                    assert_eq!(decoded[key], *value, "{reader}: {topic}.{key}");
                }
            }
        }
    }
}

#[test]
fn a_killed_recorder_leaves_a_readable_file_and_is_restarted_into_a_new_one() {
    let _turn = serial();
    let scope = unique_scope("reckill");
    let dir = scratch_dir("reckill");
    let file = dir.join("run.mcap");
    let observer = Observer::open(&scope);
    let mut run = start_run(&scope, &["--duration", "30", "--record", file.to_str().expect("path")]);
    assert!(observer.wait_healthy(500, Duration::from_secs(20)), "the loop runs");
    std::thread::sleep(Duration::from_millis(2500));
    let pid = observer
        .pid_of("recorder", Duration::from_secs(2))
        .expect("recorder pid");
    signal(pid, Signal::SIGKILL);
    let restarted = wait_for(Duration::from_secs(5), Duration::ZERO, || {
        observer
            .pid_of("recorder", Duration::from_millis(200))
            .filter(|&p| p != pid)
    });
    assert!(restarted.is_some(), "the recorder is restarted");
    std::thread::sleep(Duration::from_millis(1500));
    signal(run.id(), Signal::SIGTERM);
    // What the recorder missed between its kill and its restart is not
    // known: the run says its recording is incomplete.
    assert_eq!(wait_exit(&mut run.0, Duration::from_secs(30)).code(), Some(3));

    let cut = summarize(&file).expect("a killed recorder's file reads");
    assert!(cut.truncated.is_some(), "{cut:?}");
    // Chunks close every second: at least the first two seconds survive.
    assert!(channel(&cut, service::VALVE).messages >= 1_500, "{cut:?}");
    if let Some(python) = python_view(&["--stream"], &file) {
        assert!(python["cut_short"].is_string(), "{python}");
        for c in &cut.channels {
            assert_eq!(
                python["channels"][&c.topic]["count"].as_u64(),
                Some(c.messages),
                "{}",
                c.topic
            );
        }
    }
    let info = hydractl().args(["mcap", "info"]).arg(&file).output().expect("info");
    assert!(info.status.success());
    assert!(String::from_utf8_lossy(&info.stdout).contains("not read whole"));

    let second = summarize(&dir.join("run_restart1.mcap")).expect("the restarted recorder's file");
    assert_eq!(second.truncated, None);
    assert!(channel(&second, service::VALVE).messages >= 500, "{second:?}");
    drop(observer);
}

#[test]
fn record_attaches_to_a_running_stack_and_replay_drives_a_process_with_it() {
    let _turn = serial();
    let scope = unique_scope("recattach");
    let dir = scratch_dir("recattach");
    let file = dir.join("attached.mcap");
    {
        let observer = Observer::open(&scope);
        let _run = start_run(&scope, &["--duration", "30"]);
        assert!(observer.wait_healthy(300, Duration::from_secs(20)), "the loop runs");
        let out = hydractl()
            .args(["record", file.to_str().expect("path"), "--duration", "2"])
            .env(PREFIX_ENV, scope.prefix())
            .output()
            .expect("record runs");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        // Replaying into the live run is refused unless asked for.
        let out = hydractl()
            .args([
                "replay",
                file.to_str().expect("path"),
                "--topics",
                service::PLANT_READING,
            ])
            .env(PREFIX_ENV, scope.prefix())
            .output()
            .expect("replay runs");
        assert_eq!(out.status.code(), Some(1));
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("a run is alive"),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let recorded = summarize(&file).expect("recording");
    assert_eq!(recorded.truncated, None);
    let valve = channel(&recorded, service::VALVE);
    assert!((1_700..=2_300).contains(&valve.messages), "{valve:?}");

    // The sensor process alone, in a scope of its own, fed the recorded
    // plant readings: it computes again what it computed live.
    let replay_scope = unique_scope("recreplay");
    let bus = Bus::open(&replay_scope, "observer").expect("node");
    let outputs: Reader<SensorSample> = Reader::open(&bus, service::SENSOR, 256).expect("reader");
    let mut sensor = Command::new(binary_dir().join("sensor"))
        .env(PREFIX_ENV, replay_scope.prefix())
        .spawn()
        .expect("sensor starts");
    std::thread::sleep(Duration::from_millis(300));
    let mut replay = hydractl()
        .args([
            "replay",
            file.to_str().expect("path"),
            "--speed",
            "1",
            "--topics",
            service::PLANT_READING,
        ])
        .env(PREFIX_ENV, replay_scope.prefix())
        .spawn()
        .expect("replay starts");
    let mut replayed: BTreeMap<u64, SensorSample> = BTreeMap::new();
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut replay_done = None;
    while Instant::now() < deadline && replay_done.is_none_or(|at: Instant| at.elapsed() < Duration::from_millis(100)) {
        while let Ok(Some(s)) = outputs.next() {
            replayed.insert(s.sensor_seq, s);
        }
        if replay_done.is_none() && replay.try_wait().expect("wait").is_some() {
            replay_done = Some(Instant::now());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(wait_exit(&mut replay, Duration::from_secs(1)).success());
    signal(sensor.id(), Signal::SIGTERM);
    wait_exit(&mut sensor, Duration::from_secs(5));

    let mut live: BTreeMap<u64, SensorSample> = BTreeMap::new();
    read_messages(&file, |m| {
        if let Some(s) = decode::<SensorSample>(m) {
            live.insert(s.sensor_seq, s);
        }
        Ok(())
    })
    .expect("read");
    let matched: Vec<(&SensorSample, &SensorSample)> = live
        .iter()
        .filter_map(|(seq, l)| replayed.get(seq).map(|r| (l, r)))
        .collect();
    // A stage takes the newest reading when it wakes: under load it skips
    // some, as it does live (27 of 1977 once on a loaded CI machine).
    assert!(
        matched.len() * 100 >= live.len() * 95,
        "{} replayed of {}",
        matched.len(),
        live.len()
    );
    for (l, r) in &matched {
        assert_eq!(
            (l.angle, l.p_a, l.p_b, l.torque, l.valid),
            (r.angle, r.p_a, r.p_b, r.torque, r.valid)
        );
        // The live sample's timestamps are the reading's; so are the replayed.
        assert_eq!(l.sensor_time_ns, r.sensor_time_ns);
    }
    // The velocity estimate starts from rest in the new process, and a
    // reading skipped (live or replayed: a stage takes the newest) disturbs
    // it for a while; where both saw the 100 readings before, it is the same.
    let undisturbed =
        |seq: u64| (seq.saturating_sub(100)..seq).all(|k| live.contains_key(&k) && replayed.contains_key(&k));
    let settled: Vec<_> = matched.iter().filter(|(l, _)| undisturbed(l.sensor_seq)).collect();
    assert!(
        settled.len() * 10 >= matched.len() * 3,
        "{} of {} undisturbed",
        settled.len(),
        matched.len()
    );
    for (l, r) in settled {
        assert!(
            (l.velocity - r.velocity).abs() <= 1e-6 * (1.0 + l.velocity.abs()),
            "{l:?} vs {r:?}"
        );
    }
    drop(outputs);
    drop(bus);
}
