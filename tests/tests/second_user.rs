//! First contact as a second user: after a run as root, the same
//! computer's other user runs the stack, or is told in one line which file
//! is in the way, whose it is, its mode and what to do.

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use hydractl_bus::{PREFIX_ENV, PROCESS_BINARIES};
use hydractl_system_tests::*;

/// iceoryx2's folder, shared by every user's runs.
const IPC_ROOT: &str = "/tmp/iceoryx2";
/// `nobody`, a user every Linux has.
const SECOND_USER: &str = "65534";

/// The binaries where the second user may run them: linked (or copied)
/// into `dir`, whatever the modes of the folders above the build's.
fn binaries_for_everyone(dir: &Path) -> PathBuf {
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).expect("bin folder");
    for name in PROCESS_BINARIES.iter().chain(&["hydractl"]) {
        let (from, to) = (binary_dir().join(name), bin.join(name));
        if std::fs::hard_link(&from, &to).is_err() {
            std::fs::copy(&from, &to).unwrap_or_else(|e| panic!("{}: {e}", from.display()));
        }
    }
    bin
}

/// `hydractl ARGS` as the second user, in `dir`, on `prefix`, with a
/// backtrace asked for: the user must get one line all the same.
fn as_second_user(dir: &Path, bin: &Path, prefix: &str, args: &[&str]) -> Output {
    Command::new("setpriv")
        .args(["--reuid", SECOND_USER, "--regid", SECOND_USER, "--clear-groups", "--"])
        .arg(bin.join("hydractl"))
        .args(args)
        .current_dir(dir)
        .env("HOME", dir)
        .env("HYDRACTL_STATE_DIR", dir.join("state"))
        .env("HYDRACTL_PROCESS_DIR", bin)
        .env(PREFIX_ENV, prefix)
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("setpriv runs")
}

/// The one line a failed command printed, which must be all it printed.
fn one_error_line(out: &Output) -> String {
    assert!(!out.status.success(), "the second user's run should have failed");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one line, no backtrace, no cause repeated: {stderr}");
    assert!(lines[0].starts_with("Error: "), "{stderr}");
    lines[0].to_owned()
}

/// Sets the shared folder's mode, and puts it back as hydractl leaves it
/// however the test ends.
struct IpcRootMode;

impl IpcRootMode {
    fn set(mode: u32) -> Self {
        std::fs::create_dir_all(IPC_ROOT).expect("iceoryx2 folder");
        std::fs::set_permissions(IPC_ROOT, std::fs::Permissions::from_mode(mode)).expect("chmod");
        Self
    }
}

impl Drop for IpcRootMode {
    fn drop(&mut self) {
        let _ = std::fs::set_permissions(IPC_ROOT, std::fs::Permissions::from_mode(0o1777));
    }
}

fn mode_of(path: &str) -> u32 {
    std::fs::metadata(path).expect("metadata").permissions().mode() & 0o7777
}

#[test]
fn after_a_root_run_a_second_user_runs_or_is_told_in_one_line_what_is_in_the_way() {
    if !nix::unistd::geteuid().is_root() {
        eprintln!("SKIPPED: becoming a second user needs root");
        return;
    }
    let _turn = serial();
    let root_scope = unique_scope("root_run");
    let second_scope = unique_scope("second_user");
    let dir = scratch_dir("second_user");
    std::fs::set_permissions(&*dir, std::fs::Permissions::from_mode(0o777)).expect("chmod scratch");
    let bin = binaries_for_everyone(&dir);
    let second = |args: &[&str]| as_second_user(&dir, &bin, second_scope.prefix(), args);

    // The shared folder as iceoryx2 makes it for its first user, root.
    let _mode = IpcRootMode::set(0o750);
    let line = one_error_line(&second(&["run", "--duration", "1"]));
    for needed in [IPC_ROOT, "root", "mode 750", "chmod 1777"] {
        assert!(line.contains(needed), "{needed} in {line}");
    }

    // A root run leaves it as /tmp is, and the second user's run goes on.
    let out = run_to_end(&root_scope, &["--duration", "1"], std::time::Duration::from_secs(60));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(mode_of(IPC_ROOT), 0o1777);
    let summary = dir.join("summary.json");
    let out = second(&[
        "run",
        "--duration",
        "2",
        "--summary-json",
        summary.to_str().expect("utf-8"),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(read_json(&summary)["cycles"].as_u64().is_some_and(|c| c > 1000));

    // What a root run of the same prefix left behind is named, with its
    // owner, its mode and the fix.
    let left = PathBuf::from(format!("/dev/shm/{}left_by_root", second_scope.prefix()));
    std::fs::write(&left, b"").expect("a root file");
    std::fs::set_permissions(&left, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    let line = one_error_line(&second(&["run", "--duration", "1"]));
    let _ = std::fs::remove_file(&left);
    for needed in [left.to_str().expect("utf-8"), "root", "mode 600", PREFIX_ENV] {
        assert!(line.contains(needed), "{needed} in {line}");
    }
}
