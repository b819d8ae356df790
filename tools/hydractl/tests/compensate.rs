//! `hydractl model compensate` proves its proposal before it writes it: a
//! model no rotator could be is refused by its key, value and range, a
//! proposal that tracks worse or chatters on the model it came from is
//! refused with both figures, and `--force` writes it saying so.

use std::path::Path;
use std::process::{Command, Output};

use hydractl_system_tests::{hydractl, scratch_dir};

fn output(command: &mut Command) -> Output {
    command.output().expect("runs")
}

fn run_ok(command: &mut Command) -> String {
    let out = output(command);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).expect("utf-8")
}

fn compensate(model: &Path, tuned: &Path, extra: &[&str]) -> Output {
    output(
        hydractl()
            .args(["model", "compensate", "--json", "--model"])
            .arg(model)
            .arg("--out")
            .arg(tuned)
            .args(extra),
    )
}

#[test]
fn a_dead_band_no_valve_has_is_refused_and_written_only_when_forced() {
    let dir = scratch_dir("cli-compensate-proof");
    let data = dir.join("run.csv");
    run_ok(
        hydractl()
            .args([
                "sim",
                "--duration",
                "30",
                "--seed",
                "5",
                "--effect",
                "deadzone",
                "--out",
            ])
            .arg(&data),
    );
    let model = dir.join("model.toml");
    run_ok(
        hydractl()
            .args(["model", "fit", "--effects", "deadzone", "--data"])
            .arg(&data)
            .arg("--out")
            .arg(&model),
    );

    // The fitted model's proposal tracks better on it, and is written.
    let tuned = dir.join("tuned.toml");
    let out = compensate(&model, &tuned, &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    let proof = &json["proof"];
    assert!(
        proof["tuned"]["rms_rad"].as_f64() < proof["untuned"]["rms_rad"].as_f64(),
        "{json:#}"
    );
    assert_eq!(proof["refused"].as_array().map(Vec::len), Some(0), "{json:#}");
    assert_eq!(json["forced"], false);

    // The same model with its band at 0.95 of the spool's travel: refused,
    // naming the key, its value and the range, and nothing written.
    let mut corrupt: toml::Table = std::fs::read_to_string(&model).expect("model").parse().expect("toml");
    corrupt["effects"]["deadzone"]
        .as_table_mut()
        .expect("a dead band fitted")
        .insert("width".into(), toml::Value::Float(0.95));
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, corrupt.to_string()).expect("write");
    let refused_out = dir.join("refused.toml");
    let out = compensate(&bad, &refused_out, &[]);
    assert!(!out.status.success(), "a 0.95 dead band written");
    let error = String::from_utf8_lossy(&out.stderr);
    assert!(error.contains("effects.deadzone.width = 0.95"), "{error}");
    assert!(error.contains("[0, 0.3]"), "{error}");
    assert!(error.contains("--force"), "{error}");
    assert!(!refused_out.exists(), "nothing is written");

    // Forced: written, and the file says why it should not have been.
    let out = compensate(&bad, &refused_out, &["--force"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(json["forced"], true);
    let written = std::fs::read_to_string(&refused_out).expect("written");
    assert!(
        written.contains("# WRITTEN WITH --force although") && written.contains("effects.deadzone.width = 0.95"),
        "{written}"
    );
}
