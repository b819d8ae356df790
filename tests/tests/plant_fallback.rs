//! The plant seat: a machine (here its stand-in, a plant with its own
//! parameters and effects) drives the loop; when its readings stop, or on
//! `hydractl plant sim`, the simulated plant goes on from the last measured
//! state; `hydractl plant machine` goes back. Read from the recording.

use hydractl_samples::code::EventKind;
use std::path::{Path, PathBuf};
use std::time::Duration;

use hydractl_recording::{decode, read_messages};
use hydractl_samples::{name_str, service, source, PlantReading, SensorSample, SupervisorEvent, ValveSample};
use hydractl_system_tests::*;
use nix::sys::signal::Signal;

/// Lost after 50 periods here, not machine.toml's 10: on a loaded 2-core
/// CI machine the stand-in, one process among eleven, can stall for 10 ms
/// and be taken for lost before its bus goes silent.
const LOST_AFTER_PERIODS: u64 = 50;

fn machine_config(dir: &Path, extra: &str) -> PathBuf {
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/machine.toml");
    let path = dir.join("machine.toml");
    std::fs::write(
        &path,
        format!(
            "base = {:?}\n[supervisor]\nmachine_lost_after_periods = {LOST_AFTER_PERIODS}\n{extra}",
            base.display().to_string()
        ),
    )
    .expect("config");
    path
}

/// What the recording says of the plant seat.
#[derive(Default)]
struct Seat {
    /// Every loop reading, in the order of its timestamp: (sequence
    /// number, source, angle). (The file holds them in the order the
    /// recorder received them: publisher by publisher.)
    readings: Vec<(u64, u32, f64)>,
    /// Sensor samples per source.
    sensor_sources: [usize; 2],
    /// Valve samples after each reading, by sequence number.
    valve_seqs: Vec<u64>,
    events: Vec<SupervisorEvent>,
}

fn seat_of(recording: &Path) -> Seat {
    let mut seat = Seat::default();
    let mut readings = Vec::new();
    read_messages(recording, |m| {
        if m.topic == service::PLANT_READING {
            if let Some(r) = decode::<PlantReading>(m) {
                readings.push(r);
            }
        } else if let Some(s) = decode::<SensorSample>(m) {
            seat.sensor_sources[usize::from(s.source == source::MACHINE)] += 1;
        } else if let Some(v) = decode::<ValveSample>(m) {
            seat.valve_seqs.push(v.sensor_seq);
        } else if let Some(e) = decode::<SupervisorEvent>(m) {
            seat.events.push(e);
        }
        Ok(())
    })
    .expect("the recording reads");
    readings.sort_by_key(|r| r.sensor_time_ns);
    seat.readings = readings.iter().map(|r| (r.sensor_seq, r.source, r.angle)).collect();
    seat
}

/// No reading published twice, none going backwards.
fn assert_one_plant_at_a_time(seat: &Seat) {
    for (i, w) in seat.readings.windows(2).enumerate() {
        assert!(
            w[1].0 > w[0].0,
            "reading {} after {}: (seq, source, angle) {:?}",
            w[1].0,
            w[0].0,
            &seat.readings[i.saturating_sub(8)..(i + 8).min(seat.readings.len())]
        );
    }
}

#[test]
fn a_lost_machine_is_replaced_by_the_simulated_plant_from_its_last_state() {
    let _turn = serial();
    let scope = unique_scope("fallback");
    let dir = scratch_dir("fallback");
    let config = machine_config(&dir, "[machine]\nbus_lost_after_s = 2.0\n");
    let (summary, recording) = (dir.join("summary.json"), dir.join("run.mcap"));
    let observer = Observer::open(&scope);
    let mut run = start_run(
        &scope,
        &[
            "--config",
            config.to_str().expect("path"),
            "--duration",
            "30",
            "--record",
            recording.to_str().expect("path"),
            "--summary-json",
            summary.to_str().expect("path"),
        ],
    );
    assert!(observer.wait_healthy(500, Duration::from_secs(20)), "the loop runs");
    let before = status(&scope);
    assert_eq!(before["plant"], "machine", "{before}");
    assert_eq!(process(&before, "plant")["variant"], "standby");
    assert_eq!(process(&before, "machine")["healthy"], true);
    // The stand-in's bus goes silent 2 s after it started.
    let fell_back = || (status(&scope)["plant"] == "simulation").then_some(());
    assert!(
        wait_for(Duration::from_secs(10), Duration::from_millis(50), fell_back).is_some(),
        "no fallback"
    );
    observer.drain_valve();
    assert!(observer.wait_healthy(1000, Duration::from_secs(5)), "the loop goes on");
    let after = status(&scope);
    assert_eq!(
        process(&after, "machine")["healthy"],
        false,
        "its readings stopped: {after}"
    );
    let out = hydractl_in(&scope, &["plant", "machine"]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("the machine sends no readings"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        status(&scope)["plant"],
        "simulation",
        "only an explicit, possible request goes back"
    );

    signal(run.id(), Signal::SIGTERM);
    assert!(wait_exit(&mut run.0, Duration::from_secs(30)).success());
    let summary = read_json(&summary);
    assert_eq!(summary["plant"], "simulation");
    let switches = summary["plant_switches"].as_array().expect("switches");
    assert_eq!(switches.len(), 1, "{summary}");
    assert_eq!(switches[0]["cause"], "machine lost");
    assert_eq!(
        (switches[0]["from"].as_str(), switches[0]["to"].as_str()),
        (Some("machine"), Some("simulation"))
    );
    // Lost after its periods of silence, seen on the supervisor's 5 ms tick.
    let detected = switches[0]["detected_after_ms"].as_f64().expect("ms");
    let lost_after = LOST_AFTER_PERIODS as f64;
    assert!((lost_after..lost_after + 40.0).contains(&detected), "{detected} ms");
    assert!(summary["faults"].as_array().expect("faults").is_empty(), "{summary}");

    let seat = seat_of(&recording);
    assert_one_plant_at_a_time(&seat);
    let at = switches[0]["at_seq"].as_u64().expect("at_seq");
    assert!(at > 1500, "lost when its bus went silent (2 s), not before: {at}");
    let last_machine = seat
        .readings
        .iter()
        .rev()
        .find(|r| r.1 == source::MACHINE)
        .expect("machine readings");
    let first_sim = seat.readings.iter().find(|r| r.0 >= at).expect("simulated readings");
    assert_eq!((last_machine.0 + 1, first_sim.0), (at, at), "the sequence goes on");
    assert_eq!(first_sim.1, source::SIMULATION);
    assert!(
        seat.readings
            .iter()
            .filter(|r| r.0 >= at)
            .all(|r| r.1 == source::SIMULATION),
        "the machine never drove the loop again"
    );
    // From the last measured state: the angle goes on where it was.
    assert!(
        (first_sim.2 - last_machine.2).abs() < 0.01,
        "simulation starts at {} rad, the machine was at {} rad",
        first_sim.2,
        last_machine.2
    );
    assert!(
        seat.sensor_sources.iter().all(|&n| n > 500),
        "{:?}",
        seat.sensor_sources
    );
    assert!(
        seat.valve_seqs.iter().filter(|&&s| s >= at).count() > 500,
        "the loop resumed"
    );
    let fallback = seat
        .events
        .iter()
        .find(|e| e.kind == EventKind::Fallback.code())
        .expect("the fallback event is recorded");
    assert_eq!(
        (name_str(&fallback.from), name_str(&fallback.to)),
        ("machine", "simulation")
    );
    drop(observer);
}

#[test]
fn the_loop_moves_to_the_simulation_and_back_on_request_without_a_repeated_reading() {
    let _turn = serial();
    let scope = unique_scope("plantswitch");
    let dir = scratch_dir("plant-switch");
    let config = machine_config(&dir, "");
    let (summary, recording) = (dir.join("summary.json"), dir.join("run.mcap"));
    let observer = Observer::open(&scope);
    let mut run = start_run(
        &scope,
        &[
            "--config",
            config.to_str().expect("path"),
            "--duration",
            "30",
            "--record",
            recording.to_str().expect("path"),
            "--summary-json",
            summary.to_str().expect("path"),
        ],
    );
    assert!(observer.wait_healthy(500, Duration::from_secs(20)), "the loop runs");
    for (to, plant) in [("sim", "simulation"), ("machine", "machine")] {
        let out = hydractl_in(&scope, &["plant", to]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("runs on the {plant}")));
        assert_eq!(status(&scope)["plant"], plant);
        observer.drain_valve();
        assert!(
            observer.wait_healthy(500, Duration::from_secs(5)),
            "the loop goes on with {plant}"
        );
    }
    signal(run.id(), Signal::SIGTERM);
    assert!(wait_exit(&mut run.0, Duration::from_secs(30)).success());
    let summary = read_json(&summary);
    assert_eq!(summary["plant"], "machine");
    let switches = summary["plant_switches"].as_array().expect("switches");
    assert_eq!(switches.len(), 2, "{summary}");
    assert!(switches.iter().all(|s| s["cause"] == "asked"));

    let seat = seat_of(&recording);
    assert_one_plant_at_a_time(&seat);
    for s in switches {
        let at = s["at_seq"].as_u64().expect("at_seq");
        let to = if s["to"] == "machine" {
            source::MACHINE
        } else {
            source::SIMULATION
        };
        let i = seat
            .readings
            .iter()
            .position(|r| r.0 >= at)
            .expect("readings after the switch");
        // A live switch: the new plant publishes the very next reading.
        assert_eq!((seat.readings[i - 1].0 + 1, seat.readings[i].0), (at, at), "{s}");
        assert_ne!(seat.readings[i - 1].1, to);
        assert_eq!(seat.readings[i].1, to);
    }
    drop(observer);
}
