//! A torque loop designed on the machine and run on it: the stack on the
//! machine's CAN devices (`config/can.toml`, whose stand-in is heavier and
//! rubs more than the model) is recorded, `hydractl ident hinf` designs the
//! H∞ loop from that recording, and the designed config runs live on CAN.

use std::time::Duration;

use hydractl_system_tests::can::*;
use hydractl_system_tests::*;

#[test]
fn an_hinf_loop_designed_from_a_can_recording_runs_live_on_can() {
    let _turn = serial();
    let scope = unique_scope("can_hinf");
    let dir = scratch_dir("can_hinf");
    let config = can_config(&dir, "can.toml", "");
    let recording = dir.join("run.mcap");
    let summary = dir.join("pid.json");
    let out = run_to_end(
        &scope,
        &[
            "--config",
            config.to_str().expect("path"),
            "--duration",
            "10",
            "--record",
            recording.to_str().expect("path"),
            "--summary-json",
            summary.to_str().expect("path"),
        ],
        Duration::from_secs(70),
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let pid: serde_json::Value = read_json(&summary);

    let designed = dir.join("designed.toml");
    let design = hydractl_in(
        &scope,
        &[
            "ident",
            "hinf",
            "--json",
            "--data",
            recording.to_str().expect("path"),
            "--config",
            config.to_str().expect("path"),
            "--out",
            designed.to_str().expect("path"),
        ],
    );
    assert!(design.status.success(), "{}", String::from_utf8_lossy(&design.stderr));
    let report: serde_json::Value = serde_json::from_slice(&design.stdout).expect("json");
    assert!(report["margins"]["closed_loop_stable"] == true, "{report}");
    let text = std::fs::read_to_string(&designed).expect("designed config");
    let hinf = dir.join("designed-hinf.toml");
    std::fs::write(
        &hinf,
        text.replace("torque_variant = \"pid\"", "torque_variant = \"hinf\""),
    )
    .expect("write");

    let live_dir = dir.join("live");
    std::fs::create_dir_all(&live_dir).expect("dir");
    let live = run_config_for(&scope, &live_dir, &hinf, "10");
    let rms = |s: &serde_json::Value| s["rms_tracking_error_rad"].as_f64().expect("rms");
    assert!(
        rms(&live) <= 1.5 * rms(&pid),
        "the designed H∞ on CAN {live} against the PID {pid}"
    );
    assert_eq!(live["valve_faults"].as_array().map(Vec::len), Some(0), "{live}");
}
