//! The machine's valve on the virtual CAN bus, as a safety assessor would
//! try it: a fault stays latched across a restart of the valve process and
//! of the whole stack, and only a person's `hydractl valve reset` clears
//! it, refused while the loop asks the valve for travel and accepted at
//! neutral; after it the valve is brought up again and the first set
//! points ramp from neutral. Bus-off and a stuck spool are latched faults
//! too.

use std::time::{Duration, Instant};

use hydractl_bus::clock;
use hydractl_can::canopen::{emcy_code, Emergency};
use hydractl_can::valve::{control_word, DeviceState};
use hydractl_can::Frame;
use hydractl_system_tests::can::*;
use hydractl_system_tests::*;
use nix::sys::signal::Signal;

/// The rate limit of `config/sim.toml` (100 /s at 1 kHz): 10 % of the
/// spool's travel a period, in set-point counts, and one for rounding.
const MAX_STEP: i32 = 1638 + 1;
/// `config/can.toml`'s `[can.valve] spool_tolerance`.
const SPOOL_TOLERANCE: f64 = 0.3;

/// `hydractl status --json`'s `valve`, once `check` holds (or the last one).
fn valve_status_when(
    scope: &hydractl_bus::RunScope,
    timeout: Duration,
    check: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let deadline = Instant::now() + timeout;
    loop {
        // A run still starting has no supervisor to ask yet.
        let out = hydractl_in(scope, &["status", "--json"]);
        let valve = serde_json::from_slice::<serde_json::Value>(&out.stdout)
            .map(|s| s["valve"].clone())
            .unwrap_or_default();
        if (out.status.success() && check(&valve)) || Instant::now() > deadline {
            return valve;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn control_words(frames: &[(u64, Frame)], after_ns: u64) -> Vec<(u64, u16)> {
    frames
        .iter()
        .filter(|(t, f)| *t > after_ns && f.id == VALVE_CONTROL)
        .map(|(t, f)| (*t, u16::from_le_bytes([f.data[0], f.data[1]])))
        .collect()
}

#[test]
fn a_valve_fault_stays_latched_across_restarts_until_a_person_resets_it_at_neutral() {
    let _turn = serial();
    let scope = unique_scope("can_latch");
    let dir = scratch_dir("can_latch");
    let config = can_config(&dir, "can.toml", "");
    let config_arg = config.to_str().expect("path");

    // 1. A fault while Active: the valve process killed, the valve's own
    // timeout trips it.
    let observer = Observer::open(&scope);
    let tap = BusTap::start(&scope);
    let run = SummarizedRun::with_config(&scope, &dir, &config, "60");
    assert!(
        observer.wait_healthy(1000, Duration::from_secs(30)),
        "the loop runs on CAN"
    );
    let valve = observer.pid_of("valve", Duration::from_secs(5)).expect("valve pid");
    let killed_ns = clock::now_ns();
    signal(valve, Signal::SIGKILL);
    let latched = valve_status_when(&scope, Duration::from_secs(10), |v| !v["latched_fault"].is_null());
    assert!(
        !latched["latched_fault"].is_null(),
        "latched after the restart: {latched}"
    );
    assert_eq!(latched["state"], "fault hold", "{latched}");
    let refused = hydractl_in(&scope, &["valve", "reset"]);
    let why = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success(), "refused while the loop asks for travel");
    assert!(why.contains("not neutral"), "{why}");
    std::thread::sleep(Duration::from_millis(500));
    let first = tap.finish();
    let summary = run.finish();
    drop(observer);
    // The valve counted safe by its own word (its status, its EMCY) or by
    // the restarted valve process's neutral, never by the simulated
    // amplifier's 4 periods: the machine's valve holds its set point until
    // its own timeout.
    let crash = summary["faults"]
        .as_array()
        .and_then(|f| f.iter().find(|f| f["process"] == "valve"))
        .expect("the valve's crash in the summary");
    let safe_after = crash["valve_safe_after_periods"].as_u64().expect("made safe");
    eprintln!("the killed valve process: valve safe after {safe_after} periods");
    assert!(
        (10..=60).contains(&safe_after),
        "safe after {safe_after} periods: {crash}"
    );

    let last_set_point = first
        .iter()
        .filter(|(t, f)| *t <= killed_ns && f.id == VALVE_SET_POINT)
        .map(|(t, _)| *t)
        .max()
        .expect("set points before the kill");
    let (emcy_ns, emcy) = first
        .iter()
        .filter(|(t, f)| *t > last_set_point && f.id == VALVE_EMCY)
        .find_map(|(t, f)| Emergency::decode(f).ok().map(|(_, e)| (*t, e)))
        .expect("an EMCY after the kill");
    assert_eq!(emcy.code, emcy_code::VALVE_RPDO_TIMEOUT);
    let after_ms = (emcy_ns - last_set_point) as f64 / 1e6;
    // 20 ms of RPDO timeout, and the ECUs' 1 ms clock; a loaded machine's
    // scheduling on top.
    assert!(after_ms <= 60.0, "EMCY {after_ms:.1} ms after the last set point");
    let statuses_after: Vec<DeviceState> = first
        .iter()
        .filter(|(t, f)| *t > emcy_ns && f.id == VALVE_STATUS)
        .map(|(_, f)| status_of(f))
        .collect();
    assert!(!statuses_after.is_empty());
    assert!(
        statuses_after.iter().all(|s| *s == DeviceState::FaultHold),
        "the valve stays in fault hold: {:?}",
        statuses_after.iter().find(|s| **s != DeviceState::FaultHold)
    );
    assert!(first
        .iter()
        .filter(|(t, f)| *t > emcy_ns && f.id == VALVE_SET_POINT)
        .all(|(_, f)| set_point_of(f) == 0));
    assert!(
        control_words(&first, emcy_ns)
            .iter()
            .all(|(_, w)| w & control_word::RESET_FAULT_BIT != 0),
        "no reset edge (R low) was sent"
    );

    // 2. The whole stack restarted: the fault is still latched, and the
    // valve still neutral.
    let tap = BusTap::start(&scope);
    let run = start_run(&scope, &["--config", config_arg]);
    let carried = valve_status_when(&scope, Duration::from_secs(30), |v| !v.is_null());
    assert_eq!(carried["latched_fault"], latched["latched_fault"], "{carried}");
    let since = carried["since_s"].as_f64().expect("since");
    assert!(since >= 0.5, "latched {since} s ago, before this run");

    // 3. Accepted at neutral: on the simulated plant the loop asks nothing
    // of the machine's valve.
    let sim = hydractl_in(&scope, &["plant", "sim"]);
    assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
    // The handover takes effect at a reading a few periods ahead.
    std::thread::sleep(Duration::from_millis(500));
    let reset_ns = clock::now_ns();
    let reset = hydractl_in(&scope, &["valve", "reset"]);
    let said = String::from_utf8_lossy(&reset.stdout);
    assert!(reset.status.success(), "{}", String::from_utf8_lossy(&reset.stderr));
    assert!(said.contains("reset") && said.contains("fault hold"), "{said}");
    let cleared = valve_status_when(&scope, Duration::from_secs(5), |v| v["latched_fault"].is_null());
    assert!(cleared["latched_fault"].is_null(), "{cleared}");
    let back = hydractl_in(&scope, &["plant", "machine"]);
    assert!(back.status.success(), "{}", String::from_utf8_lossy(&back.stderr));
    let active = valve_status_when(&scope, Duration::from_secs(10), |v| v["state"] == "active");
    assert_eq!(active["state"], "active", "brought up again: {active}");
    std::thread::sleep(Duration::from_millis(500));
    let second = tap.finish();
    drop(run);

    // Before the reset the valve never left fault hold; the reset edge
    // went out only after the person's command.
    let edge = control_words(&second, 0)
        .into_iter()
        .find(|(_, w)| w & control_word::RESET_FAULT_BIT == 0)
        .map(|(t, _)| t)
        .expect("the reset edge");
    assert!(edge > reset_ns, "the reset edge after the command");
    assert!(second
        .iter()
        .filter(|(t, f)| *t < edge && f.id == VALVE_STATUS)
        .all(|(_, f)| status_of(f).is_fault() || status_of(f) == DeviceState::Init));
    // The first set points after Active ramp from neutral at the rate limit;
    // neutral itself may come at once (a command gone stale on a loaded
    // machine), and the ramp then starts again.
    let active_ns = second
        .iter()
        .find(|(t, f)| *t > edge && f.id == VALVE_STATUS && status_of(f) == DeviceState::Active)
        .map(|(t, _)| *t)
        .expect("Active after the reset");
    let set_points: Vec<i32> = second
        .iter()
        .filter(|(t, f)| *t > active_ns && f.id == VALVE_SET_POINT)
        .map(|(_, f)| i32::from(set_point_of(f)))
        .take(50)
        .collect();
    let mut previous = 0;
    for (i, sp) in set_points.iter().enumerate() {
        assert!(
            *sp == 0 || (sp - previous).abs() <= MAX_STEP,
            "set point {i} after Active: {previous} → {sp}: {set_points:?}"
        );
        previous = *sp;
    }
    assert!(set_points.iter().any(|&sp| sp != 0), "driven again");
}

/// The summary's one latched valve fault, still latched at the end.
fn latched_fault(summary: &serde_json::Value) -> &serde_json::Value {
    let faults = summary["valve_faults"].as_array().expect("valve_faults");
    assert_eq!(faults.len(), 1, "one latched fault: {summary}");
    assert!(faults[0]["reset_at_s"].is_null(), "nobody reset it");
    &faults[0]
}

/// The set points the tap heard after `from_ns` that were not neutral.
fn driven_after(frames: &[(u64, Frame)], from_ns: u64) -> Vec<i16> {
    frames
        .iter()
        .filter(|(t, f)| *t > from_ns && f.id == VALVE_SET_POINT)
        .map(|(_, f)| set_point_of(f))
        .filter(|&sp| sp != 0)
        .collect()
}

#[test]
fn bus_off_latches_a_fault_and_the_valve_stays_neutral_after_the_bus_is_back() {
    let _turn = serial();
    let scope = unique_scope("can_bus_off");
    let dir = scratch_dir("can_bus_off");
    let config = can_config(
        &dir,
        "can.toml",
        "[can.faults]\nafter_s = 3.0\nuntil_s = 3.5\nbus_off = true\n",
    );
    let tap = BusTap::start(&scope);
    let summary = run_config_for(&scope, &dir, &config, "6");
    let frames = tap.finish();
    let fault = latched_fault(&summary);
    assert_eq!(fault["code"], 0x8140, "{summary}");
    assert!(fault["meaning"].as_str().expect("meaning").contains("bus-off"));
    let off_ns = frames
        .iter()
        .find(|(_, f)| f.bus_fault().is_some())
        .map(|(t, _)| *t)
        .expect("the bus-off error frame");
    let driven = driven_after(&frames, off_ns);
    assert!(
        driven.is_empty(),
        "driven after bus-off: {:?}",
        &driven[..driven.len().min(10)]
    );
    assert!(
        frames.iter().any(|(t, f)| *t > off_ns && f.id == VALVE_SET_POINT),
        "the bus came back and the valve was sent neutral"
    );
}

#[test]
fn a_stuck_spool_is_found_within_its_hold_time_and_latched() {
    let _turn = serial();
    let scope = unique_scope("can_stuck");
    let dir = scratch_dir("can_stuck");
    let config = can_config(&dir, "can.toml", "[machine.stuck_spool]\nafter_s = 3.0\n");
    let tap = BusTap::start(&scope);
    let summary = run_config_for(&scope, &dir, &config, "6");
    let frames = tap.finish();
    let fault = latched_fault(&summary);
    assert_eq!(fault["code"], 0x3_0000, "{summary}");
    let meaning = fault["meaning"].as_str().expect("meaning");
    assert!(meaning.contains("spool stuck"), "{meaning}");
    // Latched, the valve is sent neutral and told to hold.
    let last_driven = frames
        .iter()
        .filter(|(_, f)| f.id == VALVE_SET_POINT && set_point_of(f) != 0)
        .map(|(t, _)| *t)
        .max()
        .expect("driven before");
    let held = frames
        .iter()
        .filter(|(t, f)| *t > last_driven && f.id == VALVE_CONTROL)
        .any(|(_, f)| u16::from_le_bytes([f.data[0], f.data[1]]) == control_word::HOLD);
    assert!(held, "told to hold after the fault");
    // Found within its hold time of the spool leaving its set point: the
    // first status whose spool is more than the tolerance away from the
    // set point sent before it starts the clock.
    let mut last_set_point = 0.0;
    let mut away_from = None;
    for (t, f) in frames.iter().filter(|(t, _)| *t <= last_driven) {
        if f.id == VALVE_SET_POINT {
            last_set_point = f64::from(set_point_of(f)) / 16384.0;
        } else if f.id == VALVE_STATUS && status_of(f) == DeviceState::Active {
            let actual = f64::from(i16::from_le_bytes([f.data[2], f.data[3]])) / 16384.0;
            if (actual - last_set_point).abs() > SPOOL_TOLERANCE {
                away_from.get_or_insert(*t);
            } else {
                away_from = None;
            }
        }
    }
    let away_from = away_from.expect("the spool left its set point");
    let found_ms = last_driven.saturating_sub(away_from) as f64 / 1e6;
    eprintln!("the stuck spool found {found_ms:.1} ms after it left its set point");
    assert!(found_ms <= 550.0, "{found_ms} ms: the hold time is 500 ms");
}
