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
    std::fs::remove_dir_all(dir).ok();
}
