//! The live stack's plumbing over iceoryx2. Algorithms never see this
//! crate; the process binaries use it to open their node, publish
//! (`Outlet`), receive (`Inlet`), wait on several inputs at once
//! (`run_loop`), and to clean up what a run leaves behind.
//!
//! What it holds: a run's scope (prefix and root, cleanup of dead nodes
//! and files, discovery of its publish-subscribe services, and a
//! permission error that names the file, its owner and mode when another
//! user's run left it), `Outlet` (publish, then wake the readers), `Reader`
//! (polled) and `Inlet` (reader + what to sleep on); `Doorbell`, the loop's
//! wake-up: a futex in the run's shared memory per loop service
//! (`service::PIPELINE_SERVICES`), rung after each sample, waited on with a
//! timeout (every other service wakes its listeners with iceoryx2's events,
//! which `ppoll` sees beside sockets), commands over request-response
//! (`CommandServer`, `CommandClient`), `run_loop` (`ppoll` over the inputs'
//! listeners and a tick, ending on SIGINT/SIGTERM, which are let through only
//! inside the wait; a doorbell alone is waited on by a timed futex wait,
//! which a signal ends), `run_until` (listeners or sockets, and a deadline
//! asked before every wait) and `run_single` (one input, no tick), the
//! monotonic clock, and where the process binaries are (`process_dir`:
//! `HYDRACTL_PROCESS_DIR`, beside the executable, the installed
//! `../lib/hydractl`). Where the processes run is `hydractl-rt`'s; the CAN
//! bus as a process sees it, `hydractl-canio`'s.

pub mod clock;
mod command;
mod doorbell;
mod outlet;
mod scope;
mod wait;

pub use command::{CommandClient, CommandServer, PendingCommand, PendingReply};
pub use doorbell::{Doorbell, Rung};
/// What a command's request and reply must be: plain data iceoryx2 copies.
pub use iceoryx2::prelude::ZeroCopySend;
pub use outlet::{Inlet, Outlet, PublisherWatch, Reader, Wakeup, CAN_RX_MAX_BUFFER};
pub use scope::{quiet_ipc_logging, Bus, DiscoveredService, OwnedScope, RunScope, DEFAULT_PREFIX, PREFIX_ENV};
pub use wait::{
    guarded, run_loop, run_single, run_until, unblock_termination_signals, wait_input, Flow, Input, LoopExit, Wake,
};

/// Names the folder of the process binaries, over where they are looked
/// for otherwise ([`process_dir`]).
pub const PROCESS_DIR_ENV: &str = "HYDRACTL_PROCESS_DIR";

/// Where the installed package keeps the process binaries, relative to the
/// folder of `hydractl` (`/usr/bin` → `/usr/lib/hydractl`): the processes'
/// plain names (`sensor`, `valve`) stay off the `PATH`.
pub(crate) const INSTALLED_PROCESS_DIR: &str = "../lib/hydractl";

/// The binary every process folder holds; the others sit beside it.
const SUPERVISOR: &str = "supervisor";

/// Every process binary a run may start, the supervisor first: what the
/// package installs and `doctor` looks for.
pub const PROCESS_BINARIES: [&str; 12] = [
    SUPERVISOR, "plant", "machine", "sensor", "friction", "position", "torque", "valve", "recorder", "shadow",
    "canbus", "ecus",
];

/// The folder of the process binaries (the supervisor, the stages):
/// [`PROCESS_DIR_ENV`] when set, else beside the running executable (a
/// build tree's `target/release`, or the supervisor starting its
/// children), else the installed package's `INSTALLED_PROCESS_DIR`.
pub fn process_dir() -> Result<std::path::PathBuf, BusError> {
    let exe = std::env::current_exe().map_err(|source| BusError::Executable { source })?;
    let from_env = std::env::var_os(PROCESS_DIR_ENV).map(std::path::PathBuf::from);
    find_process_dir(from_env.as_deref(), &exe)
}

fn find_process_dir(from_env: Option<&std::path::Path>, exe: &std::path::Path) -> Result<std::path::PathBuf, BusError> {
    let holds_supervisor = |dir: &std::path::Path| dir.join(SUPERVISOR).is_file();
    if let Some(dir) = from_env {
        return if holds_supervisor(dir) {
            Ok(dir.to_path_buf())
        } else {
            Err(BusError::NoProcesses {
                looked_in: format!("{} (from {PROCESS_DIR_ENV})", dir.display()),
            })
        };
    }
    let beside = exe.parent().ok_or(BusError::Executable {
        source: std::io::Error::other("the executable has no parent directory"),
    })?;
    let installed = beside.join(INSTALLED_PROCESS_DIR);
    [beside.to_path_buf(), installed.clone()]
        .into_iter()
        .find(|dir| holds_supervisor(dir))
        .map(|dir| dir.canonicalize().unwrap_or(dir))
        .ok_or_else(|| BusError::NoProcesses {
            looked_in: format!("{} and {}", beside.display(), installed.display()),
        })
}

#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("cannot locate the running executable: {source}")]
    Executable { source: std::io::Error },
    #[error(
        "no process binaries (`supervisor` and the stages) in {looked_in}: build them (`cargo build --release --workspace`), install the package, or set HYDRACTL_PROCESS_DIR to their folder"
    )]
    NoProcesses { looked_in: String },
    #[error("iceoryx2: {what}: {detail}")]
    Ipc { what: String, detail: String },
    #[error("invalid run prefix `{0}`: use letters, digits and `_`, at most 32")]
    InvalidPrefix(String),
    #[error("cannot remove {path}: {source}")]
    Cleanup { path: String, source: std::io::Error },
    #[error("cannot open the doorbell {path}: {source}")]
    Doorbell { path: String, source: std::io::Error },
    #[error("no permission for {path} (owner {owner}, mode {mode:o}): {fix}")]
    Permission {
        path: String,
        owner: String,
        mode: u32,
        /// What the user can do about it, in words.
        fix: String,
    },
}

impl BusError {
    pub(crate) fn ipc(what: impl Into<String>, detail: impl std::fmt::Debug) -> Self {
        Self::Ipc {
            what: what.into(),
            detail: format!("{detail:?}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn touch(path: &Path) {
        std::fs::create_dir_all(path.parent().expect("parent")).expect("folder");
        std::fs::write(path, b"").expect("file");
    }

    #[test]
    fn the_process_binaries_are_found_in_a_build_tree_and_in_an_installed_package() {
        let root = tempfile::tempdir().expect("temp dir");
        let build = root.path().join("target/release");
        touch(&build.join("hydractl"));
        touch(&build.join("supervisor"));
        assert_eq!(find_process_dir(None, &build.join("hydractl")).expect("beside"), build);

        let usr = root.path().join("usr");
        touch(&usr.join("bin/hydractl"));
        touch(&usr.join("lib/hydractl/supervisor"));
        assert_eq!(
            find_process_dir(None, &usr.join("bin/hydractl")).expect("installed"),
            usr.join("lib/hydractl").canonicalize().expect("exists")
        );

        let error = find_process_dir(Some(&usr.join("bin")), &usr.join("bin/hydractl"))
            .expect_err("the variable names a folder without them")
            .to_string();
        assert!(error.contains(PROCESS_DIR_ENV) && error.contains("usr/bin"), "{error}");
        let nowhere = root.path().join("elsewhere/hydractl");
        let error = find_process_dir(None, &nowhere).expect_err("none").to_string();
        assert!(
            error.contains("elsewhere") && error.contains("../lib/hydractl"),
            "{error}"
        );
    }
}
