//! What a user sees when something goes wrong: an exit status by kind, and
//! one clear line, never a backtrace unless asked for.

use hydractl_system_tests::hydractl;

#[test]
fn exit_status_is_0_on_success_1_on_failure_2_on_usage() {
    assert_eq!(hydractl().arg("effects").output().expect("runs").status.code(), Some(0));
    let usage = hydractl().args(["sim", "--no-such-flag"]).output().expect("runs");
    assert_eq!(usage.status.code(), Some(2));
    let failure = hydractl()
        .args(["sim", "--duration", "1", "--config", "/no/such/config.toml"])
        .output()
        .expect("runs");
    assert_eq!(failure.status.code(), Some(1));
}

#[test]
fn an_error_is_one_line_and_its_backtrace_only_on_asking() {
    let missing = [
        "ident",
        "tf",
        "--data",
        "/no/such/run.csv",
        "--input",
        "u",
        "--output",
        "torque",
        "--poles",
        "2",
        "--zeros",
        "0",
    ];
    let out = hydractl()
        .args(missing)
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with("Error: ") && stderr.contains("/no/such/run.csv"),
        "{stderr}"
    );
    // The cause is said once, not again as its own line or clause.
    let cause = "No such file or directory";
    assert_eq!(stderr.matches(cause).count(), 1, "{stderr}");

    let debug = hydractl()
        .args(["--log-level", "debug"])
        .args(missing)
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&debug.stderr);
    assert!(stderr.contains("Stack backtrace"), "{stderr}");
}
