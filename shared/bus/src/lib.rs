//! The live stack's plumbing over iceoryx2. Algorithms never see this
//! crate; the process binaries use it to open their node, publish
//! (`Outlet`), receive (`Inlet`), wait on several inputs at once
//! (`run_loop`), and to clean up what a run leaves behind.

pub mod can;
pub mod clock;
mod command;
pub mod devices;
mod outlet;
pub mod placement;
mod scope;
pub mod semaphore_service;
mod wait;

pub use command::{CommandClient, CommandServer, PendingCommand, PendingReply};
pub use outlet::{Inlet, Outlet, PublisherWatch, Reader};
pub use scope::{quiet_ipc_logging, Bus, DiscoveredService, RunScope, DEFAULT_PREFIX, PREFIX_ENV};
pub use wait::{guarded, run_loop, run_single, run_until, wait_input, Flow, Input, LoopExit, Wake};

/// The directory of the running executable, where cargo puts its sibling
/// binaries (the supervisor, the processes).
pub fn binary_dir() -> Result<std::path::PathBuf, BusError> {
    let exe = std::env::current_exe().map_err(|source| BusError::Executable { source })?;
    exe.parent()
        .map(std::path::Path::to_path_buf)
        .ok_or(BusError::Executable {
            source: std::io::Error::other("the executable has no parent directory"),
        })
}

#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("cannot locate the running executable: {source}")]
    Executable { source: std::io::Error },
    #[error("iceoryx2: {what}: {detail}")]
    Ipc { what: String, detail: String },
    #[error("invalid run prefix `{0}`: use letters, digits and `_`, at most 32")]
    InvalidPrefix(String),
    #[error("cannot remove {path}: {source}")]
    Cleanup { path: String, source: std::io::Error },
    #[error(
        "no permission for {path}, owned by {owner}: another user's run left it; run as {owner}, remove it as root, or set HYDRACTL_IPC_PREFIX to another prefix"
    )]
    Permission { path: String, owner: String },
}

impl BusError {
    pub(crate) fn ipc(what: impl Into<String>, detail: impl std::fmt::Debug) -> Self {
        Self::Ipc {
            what: what.into(),
            detail: format!("{detail:?}"),
        }
    }
}
