//! `hydractl model learn` as a user runs it: one command from a record to
//! a model with every missing effect added, each step in its output, its
//! JSON, the model file's history and the report.

use std::process::Command;

use hydractl_system_tests::{hydractl, scratch_dir};

fn run_ok(command: &mut Command) -> String {
    let out = command.output().expect("runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).expect("utf-8")
}

/// A worn rotator's two effects at once: the loop adds the valve's dead
/// band and the Coulomb friction, each lowering its output's error, then
/// stops because nothing more helps; the file and the report keep every step.
#[test]
fn learn_adds_both_missing_effects_and_stops_when_nothing_more_helps() {
    let dir = scratch_dir("cli-learn");
    let data = dir.join("worn.csv");
    run_ok(
        hydractl()
            .args(["sim", "--duration", "60", "--seed", "1", "--effect", "deadzone"])
            .args(["--effect", "coulomb_friction", "--out"])
            .arg(&data),
    );
    let (model, report) = (dir.join("learned.toml"), dir.join("learned.html"));
    let out = run_ok(
        hydractl()
            .args(["model", "learn", "--json", "--data"])
            .arg(&data)
            .arg("--out")
            .arg(&model)
            .arg("--report")
            .arg(&report),
    );
    let json: serde_json::Value = serde_json::from_str(&out).expect("json");
    let steps = json["steps"].as_array().expect("steps");
    let effects: Vec<&str> = steps.iter().map(|s| s["effect"].as_str().expect("effect")).collect();
    assert_eq!(effects, ["deadzone", "coulomb_friction"], "{json:#}");
    for step in steps {
        let (before, after) = (
            step["nrmse_before"].as_f64().expect("before"),
            step["nrmse_after"].as_f64().expect("after"),
        );
        assert!(after < 0.5 * before, "{step}");
        assert!(step["statistic"].as_f64() > step["threshold"].as_f64(), "{step}");
        for key in ["output", "params", "test"] {
            assert!(!step[key].is_null(), "{key} in {step}");
        }
    }
    let width = steps[0]["params"]["width"].as_f64().expect("width");
    assert!((width - 0.1).abs() < 0.025, "the band's width {width}");
    assert_eq!(json["stop"], "nothing_significant");
    assert!(
        json["stopped_because"].as_str().expect("why").starts_with("no effect"),
        "{json:#}"
    );

    let learned = hydractl_ident::greybox::Model::load(&model).expect("the model loads");
    let history: Vec<&str> = learned.history.iter().map(|s| s.step.as_str()).collect();
    assert_eq!(history, ["baseline", "deadzone", "coulomb_friction"]);
    assert!(learned.history[1..]
        .iter()
        .all(|s| s.test.is_some() && s.statistic.is_some()));
    let html = std::fs::read_to_string(&report).expect("the report");
    assert!(html.contains("The model, step by step"));
    assert!(html.contains("coulomb_friction"));

    // One step at most: the loop says it was cut short, in words too.
    let out = run_ok(
        hydractl()
            .args(["model", "learn", "--max-steps", "1", "--data"])
            .arg(&data)
            .arg("--out")
            .arg(dir.join("one.toml")),
    );
    let lines: Vec<&str> = out.lines().collect();
    assert!(lines[0].starts_with("step 1: add `deadzone`"), "{out}");
    assert!(lines[1].contains("--max-steps"), "{out}");
}
