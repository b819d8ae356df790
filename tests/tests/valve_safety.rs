//! The valve path's safety (SAFETY.md): the valve driven neutral on every
//! way out of its process and at every start, whatever stopped it.

use std::time::{Duration, Instant};

use hydractl_bus::clock;
use hydractl_recording::{decode, read_messages};
use hydractl_samples::{fault, service, ValveSample};
use hydractl_system_tests::*;
use nix::sys::signal::Signal;

/// Every valve sample of a recording, in the order recorded.
fn recorded_valve(path: &std::path::Path) -> Vec<ValveSample> {
    let mut samples = Vec::new();
    read_messages(path, |m| {
        if m.topic == service::VALVE {
            if let Some(v) = decode::<ValveSample>(m) {
                samples.push(v);
            }
        }
        Ok(())
    })
    .expect("read the recording");
    samples
}

fn is_off(v: &ValveSample) -> bool {
    v.faults & fault::OFF != 0 && v.command == 0.0
}

/// After `at_ns`: the old process's last healthy commands, then `off_count`
/// neutral samples of the valve starting or stopping before any healthy one.
fn assert_neutral_after(samples: &[ValveSample], at_ns: u64, off_count: usize, what: &str) {
    let after: Vec<&ValveSample> = samples.iter().filter(|v| v.stage_time_ns > at_ns).collect();
    let first_unhealthy = after.iter().position(|v| v.faults != 0).expect(what);
    assert!(is_off(after[first_unhealthy]), "{what}: {:?}", after[first_unhealthy]);
    let until_healthy = after[first_unhealthy..]
        .iter()
        .position(|v| v.faults == 0)
        .unwrap_or(after.len() - first_unhealthy);
    let offs = after[first_unhealthy..first_unhealthy + until_healthy]
        .iter()
        .filter(|v| is_off(v))
        .count();
    assert!(
        offs >= off_count,
        "{what}: {offs} neutral samples of a valve off, expected {off_count}"
    );
}

fn new_valve(observer: &Observer, old: u32) -> u32 {
    let deadline = Instant::now() + Duration::from_secs(5);
    while Instant::now() < deadline {
        if let Some(pid) = observer
            .pid_of("valve", Duration::from_millis(100))
            .filter(|&p| p != old)
        {
            return pid;
        }
    }
    panic!("no new valve process after {old}");
}

#[test]
fn the_valve_drives_neutral_when_stopped_killed_or_restarted() {
    let _turn = serial();
    let scope = unique_scope("valveoff");
    let dir = scratch_dir("valveoff");
    let observer = Observer::open(&scope);
    let run = RecordedRun::start(&scope, &dir, &["--duration", "40"]);
    assert!(observer.wait_healthy(300, Duration::from_secs(20)), "the loop runs");
    let mut signalled = Vec::new();
    let mut pid = observer.pid_of("valve", Duration::from_secs(2)).expect("valve");
    for sig in [Signal::SIGTERM, Signal::SIGKILL, Signal::SIGSTOP] {
        signalled.push((sig, clock::now_ns()));
        signal(pid, sig);
        pid = new_valve(&observer, pid);
        observer.drain_valve();
        assert!(
            observer.wait_healthy(300, Duration::from_secs(5)),
            "the loop resumes after {sig}"
        );
    }
    let summary = run.finish();
    let samples = recorded_valve(&dir.join("run.mcap"));
    // SIGTERM: neutral on the way out, and again by the new process at its start.
    assert_neutral_after(&samples, signalled[0].1, 2, "SIGTERM");
    // SIGKILL leaves no way to drive anything (the valve amplifier's own
    // timeout holds the spool); the new process starts neutral.
    assert_neutral_after(&samples, signalled[1].1, 1, "SIGKILL");
    // SIGSTOP: found hung, killed; the new process starts neutral.
    assert_neutral_after(&samples, signalled[2].1, 1, "SIGSTOP");
    let last = samples.last().expect("valve samples");
    assert!(is_off(last), "the run ends with the valve neutral: {last:?}");
    let faults = summary["faults"].as_array().expect("faults");
    let kinds: Vec<(&str, &str)> = faults
        .iter()
        .map(|f| (f["process"].as_str().unwrap_or("?"), f["kind"].as_str().unwrap_or("?")))
        .collect();
    assert_eq!(
        kinds,
        [("valve", "crash"), ("valve", "crash"), ("valve", "hang")],
        "{summary}"
    );
    for f in faults {
        eprintln!("{f}");
        assert!(f["valve_safe_after_periods"].as_u64().is_some(), "{f}");
    }
    drop(observer);
}

#[test]
fn a_spinning_controller_is_named_and_killed_and_the_valve_goes_neutral_meanwhile() {
    let _turn = serial();
    let scope = unique_scope("spin");
    let dir = scratch_dir("spin");
    let observer = Observer::open(&scope);
    // The outer loop spins at the loop's priority from reading 2000 (2 s).
    let run = RecordedRun::start_with_env(
        &scope,
        &dir,
        &["--duration", "30"],
        &[("HYDRACTL_INJECT_FAULT", "position:spin@2000")],
    );
    assert!(observer.wait_healthy(300, Duration::from_secs(20)), "the loop runs");
    let spinner = observer.pid_of("position", Duration::from_secs(2)).expect("position");
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut replaced = false;
    while !replaced && Instant::now() < deadline {
        replaced = observer
            .pid_of("position", Duration::from_millis(100))
            .is_some_and(|p| p != spinner);
    }
    assert!(replaced, "the spinner was replaced");
    observer.drain_valve();
    assert!(observer.wait_healthy(300, Duration::from_secs(5)), "the loop resumes");
    let summary = run.finish();
    eprintln!("{}", summary["faults"]);
    // A fault found before the spin began (a stall of a shared test machine)
    // says nothing of what the spinner starved.
    let faults: Vec<&serde_json::Value> = summary["faults"]
        .as_array()
        .expect("faults")
        .iter()
        .filter(|f| f["last_seq"].as_u64().is_none_or(|seq| seq >= 1990))
        .collect();
    assert_eq!(
        faults.len(),
        1,
        "the spinner alone is blamed, not the processes it starved: {summary}"
    );
    assert_eq!(
        (faults[0]["process"].as_str(), faults[0]["kind"].as_str()),
        (Some("position"), Some("spin"))
    );
    assert_eq!(faults[0]["pid"].as_u64(), Some(u64::from(spinner)));
    // The valve, above the chain on its CPU, is neutral within its silence
    // timeout (20 ms) and one tick of its clock (5 ms) of its last command.
    let samples = recorded_valve(&dir.join("run.mcap"));
    let first_fault = samples
        .iter()
        .position(|v| v.faults != 0 && v.sensor_seq >= 1900)
        .expect("a neutral valve");
    let last_healthy = &samples[first_fault - 1];
    let neutral_after_ms = (samples[first_fault].stage_time_ns - last_healthy.stage_time_ns) as f64 * 1e-6;
    eprintln!(
        "valve neutral {neutral_after_ms:.1} ms after its last command: {:?}",
        samples[first_fault]
    );
    assert_eq!(samples[first_fault].command, 0.0);
    assert!(neutral_after_ms <= 30.0, "neutral after {neutral_after_ms} ms");
    drop(observer);
}

#[test]
fn a_limit_cycling_baseline_comes_back_ever_later_and_its_bursts_are_bounded() {
    let _turn = serial();
    let scope = unique_scope("lcbackoff");
    let dir = scratch_dir("lcbackoff");
    // The inner PID, the papers' baseline, at 25 times its tuned gain: it
    // limit-cycles at about 5 Hz through the valve's whole range, again
    // after every restart. No fallback variant: `on_limit_cycle =
    // "baseline"` finds it already the baseline and backs off, from a
    // quarter of a second (the default 1 s made this test a minute long).
    let config = config_from_default(&dir, "limit_cycle.toml", |sim| {
        sim.replace("[control.torque.pid]\nkp = 2.0e-3", "[control.torque.pid]\nkp = 5.0e-2")
            .replacen("limit_cycle_backoff_ms = 1000", "limit_cycle_backoff_ms = 250", 1)
    });
    let summary_path = dir.join("summary.json");
    let out = run_to_end(
        &scope,
        &[
            "--config",
            config.to_str().expect("path"),
            "--duration",
            "22",
            "--summary-json",
            summary_path.to_str().expect("path"),
        ],
        Duration::from_secs(60),
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let summary = read_json(&summary_path);
    let faults = summary["faults"].as_array().expect("faults");
    let bursts: Vec<&serde_json::Value> = faults.iter().filter(|f| f["kind"] == "limit_cycle").collect();
    eprintln!("{}", summary["faults"]);
    // The limit cycle is blamed on the inner loop alone. A stall of this
    // virtual machine may also make a process miss its period long enough
    // to be found hung (the plant, after 60 ms, once in a full suite here):
    // that is another fault, not the limit cycle's.
    assert!(
        faults
            .iter()
            .all(|f| (f["process"] == "torque" && f["kind"] == "limit_cycle") || f["kind"] == "hang"),
        "the inner loop alone is blamed: {summary}"
    );
    // Waits of 0.25, 0.5, 1, 2, 4, 8 s after bursts of about 1.3 s each:
    // five or six bursts in 22 s, where restarting at once would have made
    // 20 (the restart limit) within 30 s and then left it down.
    assert!((4..=7).contains(&bursts.len()), "{} bursts: {summary}", bursts.len());
    // A wait is the back-off plus the new process's start-up until it
    // answers (30-50 ms on CI's two cores), so the doubling is of the
    // back-off, not of the whole wait: 296 then 529 ms is on schedule.
    let waits: Vec<f64> = bursts.iter().filter_map(|f| f["restarted_after_ms"].as_f64()).collect();
    for (k, &wait) in waits.iter().enumerate() {
        let backoff = 250.0 * 2f64.powi(k as i32);
        assert!(
            (backoff..backoff + 200.0).contains(&wait),
            "wait {k} is its back-off of {backoff} ms and a start-up: {waits:?}"
        );
    }
    for f in &bursts {
        assert!(f["valve_safe_after_periods"].as_u64().is_some_and(|p| p <= 2), "{f}");
    }
}

#[test]
fn a_run_of_no_duration_starts_the_whole_stack_and_ends_cleanly() {
    let _turn = serial();
    let scope = unique_scope("zero");
    for _ in 0..3 {
        let out = run_to_end(&scope, &["--duration", "0"], Duration::from_secs(30));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{stderr}");
        assert!(!stderr.contains("Error"), "no process was stopped mid-start: {stderr}");
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            stdout.contains(" cycles,") && !stdout.starts_with("0 cycles,"),
            "{stdout}"
        );
        assert!(scope.shm_files().is_empty(), "{:?}", scope.shm_files());
    }
}

#[test]
fn a_stranger_publishing_commands_is_found_and_reported() {
    let _turn = serial();
    let scope = unique_scope("stranger");
    let dir = scratch_dir("stranger");
    let observer = Observer::open(&scope);
    let run = SummarizedRun::start(&scope, &dir, "30");
    assert!(observer.wait_healthy(300, Duration::from_secs(20)), "the loop runs");
    // This test's own process publishes torque commands into the run:
    // full swing, tagged with readings the valve has seen and has not.
    const STRANGER_VARIANT: u32 = 99;
    {
        let bus = hydractl_bus::Bus::open(&scope, "stranger").expect("node");
        let torque: hydractl_bus::Outlet<hydractl_samples::TorqueSample> =
            hydractl_bus::Outlet::open(&bus, service::TORQUE).expect("outlet");
        let readings: hydractl_bus::Reader<hydractl_samples::SensorSample> =
            hydractl_bus::Reader::open(&bus, service::SENSOR, 4).expect("reader");
        let until = Instant::now() + Duration::from_millis(500);
        let mut k = 0u64;
        while Instant::now() < until {
            let newest = readings.latest().expect("read").map_or(0, |s| s.sensor_seq);
            let seq = if k.is_multiple_of(2) {
                newest
            } else {
                newest + 1_000_000
            };
            torque
                .publish(hydractl_samples::TorqueSample {
                    sensor_seq: seq,
                    sensor_time_ns: clock::now_ns(),
                    stage_time_ns: clock::now_ns(),
                    command: if k % 4 < 2 { 1.0 } else { -1.0 },
                    variant: STRANGER_VARIANT,
                    ..hydractl_samples::TorqueSample::default()
                })
                .expect("publish");
            k += 1;
            std::thread::sleep(Duration::from_micros(700));
        }
    }
    let mut driven_by_stranger = 0;
    while let Ok(Some(v)) = observer.valve.next() {
        driven_by_stranger += usize::from(v.variant == STRANGER_VARIANT && v.faults == 0 && v.command.abs() > 0.5);
    }
    let summary = run.finish();
    let strangers = summary["strangers"].as_array().expect("strangers");
    eprintln!("{}", summary["strangers"]);
    assert!(
        strangers
            .iter()
            .any(|s| s["pid"].as_u64() == Some(u64::from(std::process::id())) && s["service"] == "torque"),
        "{summary}"
    );
    // Not asserted: a stranger's command answering a valid reading before
    // the torque stage's is driven (SAFETY.md, H10); counted to be seen.
    eprintln!("valve samples driven full swing by the stranger: {driven_by_stranger}");
    drop(observer);
}

#[test]
fn a_restarted_plant_does_not_shake_the_load() {
    let _turn = serial();
    let scope = unique_scope("plantkill");
    let dir = scratch_dir("plantkill");
    let observer = Observer::open(&scope);
    let run = SummarizedRun::start(&scope, &dir, "30");
    // Past the trajectory's fade-in and the start's own transient.
    assert!(observer.wait_healthy(3000, Duration::from_secs(20)), "the loop runs");
    for _ in 0..2 {
        let plant = observer.pid_of("plant", Duration::from_secs(2)).expect("plant");
        signal(plant, Signal::SIGKILL);
        let deadline = Instant::now() + Duration::from_secs(5);
        while observer.pid_of("plant", Duration::from_millis(100)) == Some(plant) && Instant::now() < deadline {}
        observer.drain_valve();
        assert!(observer.wait_healthy(2000, Duration::from_secs(10)), "the loop resumes");
    }
    let summary = run.finish();
    let faults = summary["faults"].as_array().expect("faults");
    assert_eq!(faults.len(), 2, "{summary}");
    let mut safe_after: Vec<u64> = Vec::new();
    for f in faults {
        // The loop's own band on this trajectory: a run with no fault
        // reaches 0.019-0.028 rad past its start. Resumed at rest under a
        // moving load, the plant reached 0.045 rad.
        let after = f["tracking_error_max_after_rad"].as_f64().expect("measured");
        eprintln!("plant restarted: tracking error max over the second after {after:.4} rad; {f}");
        assert!(after <= 0.035, "{f}");
        safe_after.push(f["valve_safe_after_periods"].as_u64().unwrap_or(u64::MAX));
    }
    // No reading came after the plant's last: the valve's silence timeout
    // (20 ms) made it safe, said in periods of the loop's time. A stall of
    // this virtual machine delays the guard with everything else (44
    // periods once in a full suite here), as the hundred kills allow once:
    // one restart within 30 periods, both within 60.
    safe_after.sort_unstable();
    assert!(safe_after[0] <= 30, "{safe_after:?}: {summary}");
    assert!(safe_after[1] <= 60, "{safe_after:?}: {summary}");
    drop(observer);
}
