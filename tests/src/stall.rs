//! What a live test says when the loop does not come back in time: the
//! supervisor's last status, and where each of its threads waits. A rare
//! failure on a loaded CI machine is then explained by its own log.

use hydractl_bus::{RunScope, PREFIX_ENV};
use std::process::Command;

/// The supervisor's last status and its threads' stacks (by `gdb`, when
/// installed), for a failed assertion's message.
pub fn stall_report(scope: &RunScope) -> String {
    let out = crate::hydractl_in(scope, &["status", "--json"]);
    let stacks = match supervisor_of(scope) {
        Some(pid) => Command::new("timeout")
            .args([
                "20",
                "gdb",
                "-p",
                &pid.to_string(),
                "-batch",
                "-ex",
                "thread apply all bt 30",
            ])
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
            .unwrap_or_else(|e| format!("no stacks: gdb: {e}")),
        None => "no stacks: no supervisor process of this run".to_owned(),
    };
    format!(
        "status: {}{}\nthe supervisor's threads:\n{stacks}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// The run's supervisor, found by its name and its run's prefix: its
/// status may be the very thing missing.
fn supervisor_of(scope: &RunScope) -> Option<u32> {
    let wanted = format!("{PREFIX_ENV}={}", scope.prefix());
    std::fs::read_dir("/proc")
        .ok()?
        .filter_map(Result::ok)
        .find_map(|entry| {
            let pid: u32 = entry.file_name().to_str()?.parse().ok()?;
            let comm = std::fs::read_to_string(entry.path().join("comm")).ok()?;
            let environ = std::fs::read(entry.path().join("environ")).ok()?;
            (comm.trim() == "supervisor" && environ.split(|&b| b == 0).any(|var| var == wanted.as_bytes()))
                .then_some(pid)
        })
}
