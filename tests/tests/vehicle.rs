//! What the vehicle computer needs of a run: locked memory and no page
//! fault on the loop.

use std::path::Path;

use hydractl_system_tests::*;

/// Whether this process may lock all its memory: root, or an unlimited
/// `RLIMIT_MEMLOCK` (the unit's `LimitMEMLOCK=infinity`).
fn may_lock_memory() -> bool {
    use nix::sys::resource::{getrlimit, Resource, RLIM_INFINITY};
    nix::unistd::geteuid().is_root() || getrlimit(Resource::RLIMIT_MEMLOCK).is_ok_and(|(soft, _)| soft == RLIM_INFINITY)
}

#[test]
fn a_thirty_second_run_takes_no_page_fault_on_the_loop() {
    let _turn = serial();
    let scope = unique_scope("pagefaults");
    let dir = scratch_dir("pagefaults");
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/sim.toml");
    let summary = run_config_for(&scope, &dir, &config, "30");
    let processes = summary["processes"].as_array().expect("processes");
    let loop_processes = ["plant", "sensor", "friction", "position", "torque", "valve"];
    for name in loop_processes {
        let p = processes
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("{name} in {summary}"));
        assert_eq!(p["page_faults_after_start"], 0, "{name}: {p}");
        if may_lock_memory() {
            assert_eq!(p["memory_locked"], true, "{name}: {p}");
        }
    }
    // The supervisor has no loop: nothing is counted for it.
    let supervisor = processes
        .iter()
        .find(|p| p["name"] == "supervisor")
        .expect("supervisor");
    assert!(supervisor["page_faults_after_start"].is_null(), "{supervisor}");
    assert!(summary["cycles"].as_u64().expect("cycles") >= 29_000, "{summary}");
    let _ = std::fs::remove_dir_all(&dir);
}
