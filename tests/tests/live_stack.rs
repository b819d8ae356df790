//! The live stack, as real processes over iceoryx2.

use std::time::{Duration, Instant};

use hydractl_samples::fault;
use hydractl_system_tests::*;
use nix::sys::signal::Signal;

#[test]
fn the_stack_runs_ten_seconds_and_tracks_as_offline() {
    let _turn = serial();
    let scope = unique_scope("track");
    let dir = scratch_dir("track");
    let (live, offline) = (dir.join("live.json"), dir.join("offline.json"));
    let out = run_to_end(
        &scope,
        &["--duration", "10", "--summary-json", live.to_str().expect("path")],
        Duration::from_secs(40),
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let sim = hydractl()
        .args(["sim", "--duration", "10", "--controller", "cascade", "--summary-json"])
        .arg(&offline)
        .output()
        .expect("sim runs");
    assert!(sim.status.success());
    let (live, offline) = (read_json(&live), read_json(&offline));
    let cycles = live["cycles"].as_u64().expect("cycles");
    assert!(cycles >= 9_500, "{live}");
    for key in ["p50", "p99", "p999", "max"] {
        assert!(
            live["latency_us"][key].as_f64().is_some_and(|v| v > 0.0),
            "latency {key}: {live}"
        );
    }
    assert!(live["deadline_misses"].is_u64());
    // Each reading answered before the next is never stale, and the loop
    // is never silent: a run that missed no deadline drove no valve fault,
    // its start and end included.
    if live["deadline_misses"] == 0 {
        assert_eq!(live["valve_fault_cycles"], 0, "{live}");
    }
    let (rms_live, rms_offline) = (
        live["rms_tracking_error_rad"].as_f64().expect("rms"),
        offline["rms_tracking_error_rad"].as_f64().expect("rms"),
    );
    assert!(
        (rms_live - rms_offline).abs() <= 0.10 * rms_offline,
        "live rms {rms_live} vs offline {rms_offline}"
    );
    let names: Vec<&str> = live["processes"]
        .as_array()
        .expect("processes")
        .iter()
        .filter_map(|p| p["name"].as_str())
        .collect();
    for name in [
        "supervisor",
        "plant",
        "sensor",
        "friction",
        "position",
        "torque",
        "valve",
    ] {
        assert!(names.contains(&name), "{name} in {names:?}");
    }
    assert!(!scope.has_files(), "a clean stop leaves nothing behind");
}

#[test]
fn a_killed_controller_is_detected_the_valve_goes_neutral_and_it_restarts() {
    let _turn = serial();
    let scope = unique_scope("kill");
    let dir = scratch_dir("kill");
    let summary = dir.join("summary.json");
    let mut run = start_run(&scope, &["--summary-json", summary.to_str().expect("path")]);
    {
        let observer = Observer::open(&scope);
        assert!(observer.wait_healthy(200, Duration::from_secs(10)), "the loop starts");
        for name in ["friction", "position", "torque"] {
            let pid = observer.pid_of(name, Duration::from_secs(2)).expect("running");
            observer.drain_valve();
            let killed = Instant::now();
            signal(pid, Signal::SIGKILL);
            // The valve goes neutral, flagged stale, within a few periods.
            let mut neutral_after = None;
            let (mut samples, mut last) = (0, None);
            while killed.elapsed() < Duration::from_secs(1) && neutral_after.is_none() {
                while let Ok(Some(v)) = observer.valve.next() {
                    samples += 1;
                    last = Some(v);
                    if v.faults & fault::STALE != 0 && v.command == 0.0 {
                        neutral_after = Some(killed.elapsed());
                        break;
                    }
                }
            }
            let neutral_after = neutral_after.unwrap_or_else(|| {
                std::thread::sleep(Duration::from_millis(150));
                let status = observer.status.latest().ok().flatten().map(|s| {
                    s.processes[..s.process_count as usize]
                        .iter()
                        .map(|p| format!("{} pid {} restarts {}", hydractl_samples::name_str(&p.name), p.pid, p.restarts))
                        .collect::<Vec<_>>()
                        .join(", ")
                });
                panic!("{name} (pid {pid}): the valve did not go neutral; {samples} valve samples, last {last:?}; status: {status:?}")
            });
            assert!(
                neutral_after < Duration::from_millis(50),
                "{name}: neutral after {neutral_after:?}"
            );
            // The supervisor restarts it and the loop resumes.
            let deadline = Instant::now() + Duration::from_secs(3);
            let mut restarted = None;
            while Instant::now() < deadline && restarted.is_none() {
                restarted = observer
                    .pid_of(name, Duration::from_millis(100))
                    .filter(|&new| new != pid);
            }
            assert!(restarted.is_some(), "{name} restarted");
            assert!(
                observer.wait_healthy(200, Duration::from_secs(5)),
                "{name}: the loop resumes"
            );
        }
    }
    signal(run.id(), Signal::SIGTERM);
    assert!(wait_exit(&mut run.0, Duration::from_secs(10)).success());
    assert!(!scope.has_files(), "nothing left after the stop");
    // Each kill is in the summary, with how long each step took.
    let summary = read_json(&summary);
    let faults = summary["faults"].as_array().expect("faults");
    let names: Vec<&str> = faults.iter().filter_map(|f| f["process"].as_str()).collect();
    assert_eq!(names, ["friction", "position", "torque"], "{summary}");
    for f in faults {
        assert_eq!(f["kind"], "crash");
        assert!(f["detected_after_ms"].as_f64().is_some_and(|ms| ms < 50.0), "{f}");
        assert!(f["restarted_after_ms"].as_f64().is_some_and(|ms| ms < 1000.0), "{f}");
        // The valve holds its last command from the first reading without a
        // fresh one, and goes neutral when its stale guard trips, 3 periods
        // on (a reading or two later when the paused plant waits for it).
        assert!(f["valve_safe_after_periods"].as_u64().is_some_and(|p| p <= 3), "{f}");
    }
}

#[test]
fn ctrl_c_stops_everything_and_leaves_no_files() {
    let _turn = serial();
    let scope = unique_scope("ctrlc");
    let interrupts_before = interrupt_affinities();
    let interrupts_to_put_back = put_back_as_recorded(interrupts_before.clone());
    let mut run = start_run(&scope, &[]);
    {
        let observer = Observer::open(&scope);
        assert!(observer.wait_healthy(100, Duration::from_secs(10)), "the loop starts");
    }
    assert!(scope.has_files());
    // The default config steers device interrupts off the loop's CPU (1)
    // for the run, and puts them back after.
    for (irq, during) in interrupt_affinities() {
        if interrupts_before.get(&irq).is_some_and(|before| *before != during) {
            assert!(
                !cpu_list_has(&during, 1),
                "IRQ {irq} moved, but onto the loop's CPU: {during}"
            );
        }
    }
    // The default config keeps idle CPUs polling for the run (where the
    // kernel lets the run ask: root).
    let held_during_run = idle_latency_limit_us();
    if let Some(limit) = held_during_run {
        assert_eq!(limit, 0, "cpu_dma_latency_us = 0 is held while the loop runs");
    }
    signal(run.id(), Signal::SIGINT);
    assert!(wait_exit(&mut run.0, Duration::from_secs(10)).success());
    if let Some(limit) = idle_latency_limit_us().filter(|_| held_during_run.is_some()) {
        assert!(limit > 0, "the idle latency request ends with the run");
    }
    assert_eq!(
        interrupt_affinities(),
        interrupts_to_put_back,
        "interrupts are put back"
    );
    assert!(
        !std::path::Path::new(INTERRUPTS_RECORD).exists(),
        "the record goes with the run"
    );
    assert!(
        !scope.has_files(),
        "left: {:?} and {}",
        scope.shm_files(),
        scope.root().display()
    );
}

/// Every device interrupt's CPU list, by number.
fn interrupt_affinities() -> std::collections::BTreeMap<String, String> {
    std::fs::read_dir("/proc/irq")
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .filter_map(|e| {
                    let list = std::fs::read_to_string(e.path().join("smp_affinity_list")).ok()?;
                    Some((e.file_name().to_string_lossy().into_owned(), list.trim().to_owned()))
                })
                .collect()
        })
        .unwrap_or_default()
}

const INTERRUPTS_RECORD: &str = "/run/hydractl-interrupts";

/// `now`, with the affinities that a killed run recorded and left steered.
fn put_back_as_recorded(
    mut now: std::collections::BTreeMap<String, String>,
) -> std::collections::BTreeMap<String, String> {
    let recorded = std::fs::read_to_string(INTERRUPTS_RECORD).unwrap_or_default();
    for line in recorded.lines() {
        if let Some((irq, list)) = line.split_once(' ') {
            if let Some(affinity) = now.get_mut(irq) {
                *affinity = list.trim().to_owned();
            }
        }
    }
    now
}

/// Whether a kernel CPU list such as `0-3,6` holds `cpu`.
fn cpu_list_has(list: &str, cpu: usize) -> bool {
    hydractl_rt::CpuList::parse(list).is_some_and(|l| l.contains(cpu))
}

/// The kernel's present limit on CPU idle exit latency, µs, when this
/// process may read it.
fn idle_latency_limit_us() -> Option<i32> {
    let bytes = std::fs::read("/dev/cpu_dma_latency").ok()?;
    Some(i32::from_ne_bytes(bytes.get(..4)?.try_into().ok()?))
}

#[test]
fn a_start_over_the_files_of_a_killed_run_works() {
    let _turn = serial();
    let scope = unique_scope("stale");
    let mut run = start_run(&scope, &[]);
    let mut pids = vec![run.id()];
    {
        let observer = Observer::open(&scope);
        assert!(observer.wait_healthy(100, Duration::from_secs(10)), "the loop starts");
        for name in [
            "supervisor",
            "plant",
            "sensor",
            "friction",
            "position",
            "torque",
            "valve",
        ] {
            pids.extend(observer.pid_of(name, Duration::from_secs(2)));
        }
    }
    // Kill every process of the run at once, as a crash or power cut would.
    for &pid in &pids {
        signal(pid, Signal::SIGKILL);
    }
    let _ = run.0.wait();
    std::thread::sleep(Duration::from_millis(200));
    assert!(scope.has_files(), "the killed run left its files");
    let dir = scratch_dir("stale");
    let summary = dir.join("summary.json");
    let out = run_to_end(
        &scope,
        &["--duration", "2", "--summary-json", summary.to_str().expect("path")],
        Duration::from_secs(30),
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(read_json(&summary)["cycles"].as_u64().expect("cycles") > 1_500);
    assert!(!scope.has_files());
}
