//! The fleet on a local Ray (`tools/fleet`): three machines over eight
//! days, one of them recorded by the whole stack on the virtual CAN bus,
//! diagnosed together; the two drifting machines named with their effect
//! and direction, nothing on the steady one, bad recordings rows with
//! their error, a second run skipping everything done. The tests themselves
//! are `tools/fleet/tests` (the fleet end to end, the trend's rules), run
//! here with this test's run scope for the CAN runs and the Python that
//! has the package (`HYDRACTL_PYTHON`, where `.ci/run` installs it;
//! required there by `HYDRACTL_REQUIRE_FLEET=1`).

use std::path::Path;
use std::process::Command;

use hydractl_bus::PREFIX_ENV;
use hydractl_system_tests::*;

#[test]
fn the_fleet_names_the_drifting_machines_and_nothing_on_the_steady_one() {
    let _turn = serial();
    let python = std::env::var("HYDRACTL_PYTHON").unwrap_or_else(|_| "python3".into());
    let installed = Command::new(&python)
        .args(["-c", "import hydractl_fleet, ray, pyarrow"])
        .status()
        .is_ok_and(|s| s.success());
    if !installed {
        let required = std::env::var("HYDRACTL_REQUIRE_FLEET").is_ok_and(|v| v == "1");
        assert!(
            !required,
            "{python} lacks hydractl_fleet (pip install ./tools/fleet, as .ci/run does)"
        );
        eprintln!("SKIPPED: {python} lacks hydractl_fleet, ray or pyarrow (pip install ./tools/fleet)");
        return;
    }
    let scope = unique_scope("fleet");
    let tests = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/fleet/tests");
    let out = Command::new(&python)
        .args(["-m", "unittest", "discover", "-v", "-s"])
        .arg(tests)
        .env("HYDRACTL", binary_dir().join("hydractl"))
        .env(PREFIX_ENV, scope.prefix())
        .env("HYDRACTL_STATE_DIR", state_dir())
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "the fleet test failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
