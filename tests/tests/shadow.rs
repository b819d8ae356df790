//! The shadow model beside the machine: on `config/machine-drift.toml` the
//! machine's valve overlap opens from none to 0.06 between 10 s and 12 s,
//! and the shadow, watching with the model fitted from a minute of the
//! unchanged machine (`config/machine-model.toml`), detects the drift
//! within 5 s of its end and names it a dead-zone of the right width; on
//! the unchanged machine it raises nothing.

use std::path::Path;
use std::time::Duration;

use hydractl_system_tests::*;
use nix::sys::signal::Signal;

fn config(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../config").join(name)
}

#[test]
fn a_valve_whose_overlap_opens_is_detected_and_named_a_deadzone() {
    let _turn = serial();
    let scope = unique_scope("drift");
    let dir = scratch_dir("drift");
    // The drift of machine-drift.toml, the learned model written out.
    let learned = dir.join("learned.toml");
    let drifting = dir.join("drifting.toml");
    std::fs::write(
        &drifting,
        format!(
            "base = {:?}\n[shadow]\nlearned = {:?}\n",
            config("machine-drift.toml"),
            learned
        ),
    )
    .expect("config");
    let summary_path = dir.join("summary.json");
    let mut run = start_run(
        &scope,
        &[
            "--config",
            drifting.to_str().expect("path"),
            "--duration",
            "50",
            "--summary-json",
            summary_path.to_str().expect("path"),
        ],
    );
    // Named, the drift's model is written; the run goes on a few seconds
    // more, long enough for a second naming to show, and is stopped as a
    // person would.
    let named = wait_for(Duration::from_secs(50), Duration::from_millis(100), || {
        learned.exists().then_some(())
    });
    assert!(named.is_some(), "the drift is named while the run goes on");
    std::thread::sleep(Duration::from_secs(5));
    signal(run.0.id(), Signal::SIGINT);
    assert!(wait_exit(&mut run.0, Duration::from_secs(30)).success());
    let summary = read_json(&summary_path);
    let drifts = summary["model_drift"].as_array().expect("model_drift");
    let shadow = &summary["shadow"];
    assert_eq!(drifts.len(), 1, "one drift, named once: {drifts:?}, shadow {shadow}");
    let drift = &drifts[0];
    let detected = drift["detected_after_s"].as_f64().expect("detected_after_s");
    // The change runs from 10 s to 12 s.
    assert!((10.0..=17.0).contains(&detected), "detected at {detected} s: {drift}");
    assert_eq!(drift["part"], "hydraulic", "{drift}");
    assert_eq!(drift["outcome"], "named", "{drift}, shadow {shadow}");
    assert_eq!(drift["effect"], "deadzone", "{drift}");
    let width = drift["params"]["width"].as_f64().expect("width");
    assert!((width - 0.06).abs() <= 0.25 * 0.06, "width {width}: {drift}");
    // What the shadow learned, for `hydractl model compensate`.
    let text = std::fs::read_to_string(&learned).expect("the learned model is written");
    let model: toml::Table = toml::from_str(&text).expect("a model file");
    let learned_width = model["effects"]["deadzone"]["width"].as_float().expect("its dead-zone");
    assert!((learned_width - width).abs() < 1e-9, "{learned_width} against {width}");
    assert!(shadow["windows"].as_u64().expect("windows") >= 20, "{shadow}");
    assert!(
        shadow["fit_percent"]["theta"].as_f64().expect("theta's fit") > 90.0,
        "{shadow}"
    );
}

#[test]
fn on_the_unchanged_machine_the_shadow_fits_and_raises_nothing() {
    let _turn = serial();
    let scope = unique_scope("nodrift");
    let dir = scratch_dir("nodrift");
    let unchanged = dir.join("watched.toml");
    std::fs::write(
        &unchanged,
        format!(
            // As machine-drift.toml: the shadow pauses while the simulated
            // plant stands in, and this test is about the shadow.
            "base = {:?}\n[supervisor]\nmachine_lost_after_periods = 100\n[shadow]\nmodel = {:?}\n",
            config("machine.toml"),
            config("machine-model.toml")
        ),
    )
    .expect("config");
    let summary_path = dir.join("summary.json");
    let mut run = start_run(
        &scope,
        &[
            "--config",
            unchanged.to_str().expect("path"),
            "--duration",
            "30",
            "--summary-json",
            summary_path.to_str().expect("path"),
        ],
    );
    // `hydractl status` shows the shadow's fit while the run goes on.
    std::thread::sleep(Duration::from_secs(20));
    let status = status(&scope);
    assert_eq!(process(&status, "shadow")["healthy"], true, "{status}");
    let watching = &status["shadow"];
    assert!(watching["windows"].as_u64().expect("windows") >= 5, "{status}");
    assert!(
        watching["fit_percent"]["theta"].as_f64().expect("fit") > 85.0,
        "{status}"
    );
    assert!(wait_exit(&mut run.0, Duration::from_secs(90)).success());
    let summary = read_json(&summary_path);
    assert_eq!(
        summary["model_drift"],
        serde_json::json!([]),
        "{}",
        summary["model_drift"]
    );
    let shadow = &summary["shadow"];
    assert!(shadow["windows"].as_u64().expect("windows") >= 22, "{shadow}");
    // The last window's fit: a window's varies with what the reference
    // does in it (over ten minutes, processes/README.md: 60.6 % at worst);
    // this run's last window fits about 85 %.
    for output in ["theta", "p_a", "p_b"] {
        let fit = shadow["fit_percent"][output].as_f64().expect("fit");
        assert!(fit > 80.0, "{output}: {fit} % in {shadow}");
    }
}
