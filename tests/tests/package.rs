//! The package for the vehicle computer: what `cargo deb -p hydractl`
//! builds holds every binary, the configs and the unit, the unit passes
//! `systemd-analyze verify`, and the installed layout, extracted into a
//! folder of its own, runs the stack with its own binaries and configs.

use std::path::{Path, PathBuf};
use std::process::Command;

use hydractl_system_tests::*;

use hydractl_bus::PROCESS_BINARIES as PROCESSES;

/// The package: `HYDRACTL_DEB` (`.ci/run` builds it), else built here by
/// `cargo deb --no-build` from the binaries the tests were built with.
/// `None` when cargo-deb is missing and not required (`HYDRACTL_REQUIRE_DEB=1`).
fn package(dir: &Path) -> Option<PathBuf> {
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    if let Ok(deb) = std::env::var("HYDRACTL_DEB") {
        // A relative path is the workspace's, where `.ci/run` runs;
        // cargo runs this test from `tests/`.
        let deb = workspace.join(deb);
        assert!(deb.is_file(), "HYDRACTL_DEB names no file: {}", deb.display());
        return Some(deb);
    }
    let out = Command::new("cargo")
        .current_dir(&workspace)
        .args(["deb", "-p", "hydractl", "--no-build", "--strip", "-o"])
        .arg(dir)
        .output();
    match out {
        Ok(out) if out.status.success() => {
            let path = String::from_utf8_lossy(&out.stdout)
                .trim()
                .lines()
                .last()
                .map(PathBuf::from);
            path.filter(|p| p.extension().is_some_and(|e| e == "deb"))
        }
        other => {
            let why = match other {
                Ok(out) => String::from_utf8_lossy(&out.stderr).into_owned(),
                Err(e) => e.to_string(),
            };
            assert!(
                std::env::var("HYDRACTL_REQUIRE_DEB").as_deref() != Ok("1"),
                "cargo deb failed: {why}"
            );
            eprintln!("SKIPPED: no package (cargo install cargo-deb, as .ci/run does): {why}");
            None
        }
    }
}

fn dpkg_deb(args: &[&str], deb: &Path) -> String {
    let out = Command::new("dpkg-deb")
        .args(args)
        .arg(deb)
        .output()
        .expect("dpkg-deb runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_package_holds_the_stack_its_configs_and_a_unit_that_verifies() {
    // Not beside the other test: two `cargo deb` at once strip the same
    // binaries into the same temporary files under `target/` (cargo-deb
    // 3.8's `{name}.stripped-{i}.tmp`), and one would package the other's
    // half-written copy.
    let _turn = serial();
    let dir = scratch_dir("deb");
    let Some(deb) = package(&dir) else { return };
    let listing = dpkg_deb(&["-c"], &deb);
    let mut expected: Vec<String> = PROCESSES.iter().map(|p| format!("./usr/lib/hydractl/{p}")).collect();
    expected.extend(
        [
            "./usr/bin/hydractl",
            "./etc/hydractl/sim.toml",
            "./etc/hydractl/machine.toml",
            "./etc/hydractl/can.toml",
            "./etc/hydractl/vehicle.toml",
            "./usr/lib/systemd/system/hydractl.service",
            "./usr/lib/sysusers.d/hydractl.conf",
            "./usr/lib/udev/rules.d/60-hydractl.rules",
        ]
        .map(str::to_owned),
    );
    for path in &expected {
        assert!(
            listing.lines().any(|l| l.ends_with(path.as_str())),
            "{path} in\n{listing}"
        );
    }
    let control = dir.join("control");
    let _ = std::fs::remove_dir_all(&control);
    let out = Command::new("dpkg-deb")
        .arg("-e")
        .arg(&deb)
        .arg(&control)
        .output()
        .expect("dpkg-deb -e");
    assert!(out.status.success());
    let conffiles = std::fs::read_to_string(control.join("conffiles")).expect("conffiles");
    assert!(conffiles.contains("/etc/hydractl/vehicle.toml"), "{conffiles}");
    let postinst = std::fs::read_to_string(control.join("postinst")).expect("postinst");
    assert!(
        postinst.contains("systemd-sysusers") && postinst.contains("enable hydractl.service"),
        "{postinst}"
    );

    let root = dir.join("root");
    let _ = std::fs::remove_dir_all(&root);
    let out = Command::new("dpkg-deb")
        .arg("-x")
        .arg(&deb)
        .arg(&root)
        .output()
        .expect("dpkg-deb -x");
    assert!(
        out.status.success(),
        "dpkg-deb -x: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let unit_path = root.join("usr/lib/systemd/system/hydractl.service");
    let unit = std::fs::read_to_string(&unit_path).expect("unit");
    for line in [
        "User=hydractl",
        "Restart=on-failure",
        "LimitRTPRIO=",
        "LimitMEMLOCK=infinity",
        "KillSignal=SIGTERM",
        "KillMode=mixed",
        "After=sys-subsystem-net-devices-can0.device",
        "ExecStart=/usr/bin/hydractl run --config /etc/hydractl/vehicle.toml",
    ] {
        assert!(unit.lines().any(|l| l.starts_with(line)), "{line} in the unit");
    }
    for forbidden in [
        "DynamicUser=yes",
        "DynamicUser=true",
        "PrivateTmp=yes",
        "PrivateTmp=true",
    ] {
        assert!(
            !unit.contains(forbidden),
            "{forbidden}: it breaks iceoryx2's shared memory"
        );
    }
    // Offline, with the command pointed at the extracted binary (nothing
    // is installed on this machine): no warning, no error.
    let verified = dir.join("hydractl.service");
    let installed = root.join("usr/bin/hydractl");
    std::fs::write(
        &verified,
        unit.replace("/usr/bin/hydractl", installed.to_str().expect("path")),
    )
    .expect("unit copy");
    match Command::new("systemd-analyze").arg("verify").arg(&verified).output() {
        Ok(out) => {
            let said = String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout);
            assert!(
                out.status.success() && said.trim().is_empty(),
                "systemd-analyze verify: {said}"
            );
        }
        Err(e) => eprintln!("SKIPPED systemd-analyze verify: {e}"),
    }
}

#[test]
fn the_installed_layout_runs_the_stack_with_its_own_binaries_and_configs() {
    let _turn = serial();
    let dir = scratch_dir("installed");
    let Some(deb) = package(&dir) else { return };
    let root = dir.join("root");
    let _ = std::fs::remove_dir_all(&root);
    let out = Command::new("dpkg-deb")
        .arg("-x")
        .arg(&deb)
        .arg(&root)
        .output()
        .expect("dpkg-deb -x");
    assert!(
        out.status.success(),
        "dpkg-deb -x: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let scope = unique_scope("installed");
    let installed = root.join("usr/bin/hydractl");
    // It finds the processes in ../lib/hydractl, nowhere else.
    let doctor = Command::new(&installed)
        .args(["doctor", "--json"])
        .env_remove(hydractl_bus::PROCESS_DIR_ENV)
        .output()
        .expect("doctor runs");
    let report: serde_json::Value = serde_json::from_slice(&doctor.stdout).expect("doctor's json");
    let binaries = report["checks"]
        .as_array()
        .expect("checks")
        .iter()
        .find(|c| c["name"] == "binaries")
        .expect("binaries");
    assert_eq!(binaries["status"], "pass", "{binaries}");
    let lib = root.join("usr/lib/hydractl").canonicalize().expect("lib");
    assert!(
        binaries["detail"]
            .as_str()
            .is_some_and(|d| d.contains(lib.to_str().expect("path"))),
        "{binaries}"
    );
    let summary = dir.join("summary.json");
    let out = Command::new(&installed)
        .args(["run", "--duration", "2", "--config"])
        .arg(root.join("etc/hydractl/sim.toml"))
        .arg("--summary-json")
        .arg(&summary)
        .env(hydractl_bus::PREFIX_ENV, scope.prefix())
        .env_remove(hydractl_bus::PROCESS_DIR_ENV)
        .stdin(std::process::Stdio::null())
        .output()
        .expect("the installed hydractl runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let summary = read_json(&summary);
    assert!(summary["cycles"].as_u64() >= Some(1_900), "{summary}");
}
