//! The two halves of the product chained: a recording of the stack on the
//! machine's CAN devices (`config/can.toml`, with a valve process killed
//! half-way, and the machine lost at the end, the simulated plant taking
//! over) is fitted and diagnosed by the model tools, which name the effect
//! the machine stand-in has and the model lacks (`machine.toml`'s Coulomb
//! friction). The readings a CAN master could not complete in time (NaN),
//! those after the loop's last command and the simulated plant's are left
//! out, and said so; they never stop the tools.

use std::time::Duration;

use hydractl_bus::RunScope;
use hydractl_system_tests::can::*;
use hydractl_system_tests::*;
use nix::sys::signal::Signal;

/// `hydractl ARGS`, which must succeed.
fn model(scope: &RunScope, args: &[&str]) -> std::process::Output {
    let out = hydractl_in(scope, args);
    assert!(
        out.status.success(),
        "hydractl {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

#[test]
fn a_can_runs_recording_with_a_valve_kill_is_fitted_and_its_missing_effect_named() {
    let _turn = serial();
    let scope = unique_scope("can_model");
    let dir = scratch_dir("can_model");
    // The encoder falls silent 2 s after the valve kill: the machine is
    // lost and the simulated plant drives the loop to the end.
    let config = can_config(&dir, "can.toml", "[machine.silent_node]\nnode = 0x20\nafter_s = 20.0\n");
    let recording = dir.join("run.mcap");
    let observer = Observer::open(&scope);
    let run = start_run(
        &scope,
        &[
            "--config",
            config.to_str().expect("path"),
            "--duration",
            "22",
            "--record",
            recording.to_str().expect("path"),
        ],
    );
    assert!(
        observer.wait_healthy(1000, Duration::from_secs(30)),
        "the loop runs on CAN"
    );
    // Late in the run: after the kill the valve stays latched neutral and
    // the machine still, which tells the model nothing.
    std::thread::sleep(Duration::from_secs(18));
    let valve = observer.pid_of("valve", Duration::from_secs(5)).expect("valve pid");
    signal(valve, Signal::SIGKILL);
    let mut run = run;
    assert!(wait_exit(&mut run.0, Duration::from_secs(60)).success(), "the run ends");

    let path = recording.to_str().expect("path");
    let fitted = dir.join("model.toml");
    model(
        &scope,
        &["model", "fit", "--data", path, "--out", fitted.to_str().expect("path")],
    );
    let diagnose = model(
        &scope,
        &[
            "model",
            "diagnose",
            "--data",
            path,
            "--model",
            fitted.to_str().expect("path"),
            "--json",
        ],
    );
    let said = String::from_utf8_lossy(&diagnose.stderr);
    assert!(
        said.contains("came from the simulated plant standing in for the machine"),
        "{said}"
    );
    let verdict: serde_json::Value = serde_json::from_slice(&diagnose.stdout).expect("diagnose json");
    let words = verdict["verdict"].as_str().expect("a verdict");
    assert!(
        words.contains("coulomb_friction"),
        "the stand-in's friction named: {words}"
    );
}
