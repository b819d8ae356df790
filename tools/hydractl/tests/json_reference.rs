//! The JSON fields `tools/hydractl/README.md` names are in the program's
//! real output: each command's `--json` description, read from the
//! reference, against what the command prints on simulated data. (That
//! every command and flag is in the reference is `src/reference.rs`'s
//! test; the fields of a live run's `status --json` are the system tests'.)

use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;

use hydractl_system_tests::{hydractl, scratch_dir};

const REFERENCE: &str = include_str!("../README.md");

/// The names in backticks from `marker`, in the section of `command`, to
/// the end of its sentence, each group of alternatives ("`a` or `b`") as
/// one entry.
fn documented(command: &str, marker: &str) -> Vec<Vec<String>> {
    let section = REFERENCE
        .find(&format!("## `hydractl {command}`"))
        .unwrap_or_else(|| panic!("the reference has no section for {command}"));
    let start = REFERENCE[section..]
        .find(marker)
        .unwrap_or_else(|| panic!("the reference no longer says {marker:?} of {command}"));
    let text = &REFERENCE[section + start + marker.len()..];
    let end = [". ", ".\n", "\n\n", "\n- "]
        .iter()
        .filter_map(|stop| text.find(stop))
        .min()
        .unwrap_or(text.len());
    let text = &text[..end];
    let mut groups: Vec<Vec<String>> = Vec::new();
    let mut joined = false;
    for (i, piece) in text.split('`').enumerate() {
        if i % 2 == 0 {
            let between = piece.trim_start_matches([',', ' ', '\n']);
            joined = between.starts_with("or ");
            continue;
        }
        let is_name = piece.starts_with(|c: char| c.is_ascii_lowercase())
            && piece
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
        if !is_name {
            continue;
        }
        match groups.last_mut() {
            Some(group) if joined => group.push(piece.to_owned()),
            _ => groups.push(vec![piece.to_owned()]),
        }
    }
    assert!(!groups.is_empty(), "no field named after {marker:?}");
    groups
}

/// Every key of the JSON, at any depth, and every string value.
fn words(value: &serde_json::Value, out: &mut BTreeSet<String>) {
    match value {
        serde_json::Value::Object(map) => {
            for (key, inner) in map {
                out.insert(key.clone());
                words(inner, out);
            }
        }
        serde_json::Value::Array(items) => items.iter().for_each(|v| words(v, out)),
        serde_json::Value::String(s) => {
            out.insert(s.clone());
        }
        _ => {}
    }
}

/// Fails naming each field the reference promises after `marker` and the
/// output lacks, but for `elsewhere` (fields of other data, each with why).
fn assert_documented_fields_present(command: &str, marker: &str, json: &serde_json::Value, elsewhere: &[&str]) {
    let mut present = BTreeSet::new();
    words(json, &mut present);
    let missing: Vec<String> = documented(command, marker)
        .into_iter()
        .filter(|group| {
            !group
                .iter()
                .any(|name| present.contains(name) || elsewhere.contains(&name.as_str()))
        })
        .map(|group| group.join(" or "))
        .collect();
    assert!(
        missing.is_empty(),
        "tools/hydractl/README.md names after {marker:?} of {command} fields the output lacks: {missing:?}\nin {json}"
    );
}

fn json_of(command: &mut Command) -> serde_json::Value {
    let out = command.output().expect("runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("json on stdout")
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("written")).expect("json")
}

#[test]
fn the_offline_commands_print_the_fields_the_reference_names() {
    let dir = scratch_dir("cli-json-reference");
    let data = dir.join("worn.csv");
    let summary = dir.join("summary.json");
    let out = hydractl()
        .args([
            "sim",
            "--duration",
            "30",
            "--seed",
            "2",
            "--effect",
            "deadzone:width=0.08",
        ])
        .arg("--out")
        .arg(&data)
        .arg("--summary-json")
        .arg(&summary)
        .output()
        .expect("runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_documented_fields_present("sim", "`--summary-json FILE`:", &read_json(&summary), &[]);

    let linearized = json_of(hydractl().args(["linearize", "--json"]));
    assert_documented_fields_present("linearize", "`--json` prints", &linearized, &[]);

    let can = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/can.toml");
    let budget = json_of(hydractl().args(["can", "budget", "--json", "--config"]).arg(&can));
    assert_documented_fields_present("can", "`--json` prints", &budget, &[]);

    let model = dir.join("model.toml");
    let out = hydractl()
        .args(["model", "fit", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&model)
        .output()
        .expect("runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let compared = json_of(
        hydractl()
            .args(["model", "compare", "--json", "--data"])
            .arg(&data)
            .arg("--model")
            .arg(&model),
    );
    // Data with a valve command: the angle's residual is tested against it.
    assert_documented_fields_present(
        "model",
        "residual tests. `--json` prints",
        &compared,
        &["cross_correlation_tau"],
    );
    let diagnosed = json_of(
        hydractl()
            .args(["model", "diagnose", "--json", "--data"])
            .arg(&data)
            .arg("--model")
            .arg(&model),
    );
    assert_documented_fields_present("model", "worse. `--json` prints", &diagnosed, &[]);

    let learned = dir.join("learned.toml");
    let steps = json_of(
        hydractl()
            .args(["model", "learn", "--json", "--data"])
            .arg(&data)
            .arg("--model")
            .arg(&model)
            .arg("--out")
            .arg(&learned),
    );
    assert_documented_fields_present("model", "each step. `--json` prints", &steps, &[]);

    let designed = dir.join("hinf.toml");
    let design = json_of(
        hydractl()
            .args(["ident", "hinf", "--json", "--data"])
            .arg(&data)
            .arg("--out")
            .arg(&designed),
    );
    assert_documented_fields_present("ident", "(ε = 1/γ below 0.25). `--json`:", &design, &[]);

    let tuned = dir.join("tuned.toml");
    let compensated = json_of(
        hydractl()
            .args(["model", "compensate", "--json", "--force", "--model"])
            .arg(&learned)
            .arg("--out")
            .arg(&tuned),
    );
    assert_documented_fields_present("model", "head. `--json` prints", &compensated, &[]);
}
