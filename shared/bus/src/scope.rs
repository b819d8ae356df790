use std::path::PathBuf;

use iceoryx2::node::{NodeState, NodeView};
use iceoryx2::prelude::*;

use crate::BusError;

/// Where a run's iceoryx2 resources live: every file in /dev/shm starts with
/// the prefix, and everything else is under the root. Tests give each run
/// its own prefix, so runs in parallel never share a service.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunScope {
    prefix: String,
}

/// The prefix of `hydractl run` when none is given.
pub const DEFAULT_PREFIX: &str = "hydractl_";
/// The environment variable that passes the prefix to child processes.
pub const PREFIX_ENV: &str = "HYDRACTL_IPC_PREFIX";
/// An empty, unreadable storage this old was abandoned by its creator: a
/// live one sizes and opens it within microseconds.
const ABANDONED_AFTER: std::time::Duration = std::time::Duration::from_secs(1);
/// The folder every run's own folder lives in, iceoryx2's, shared by the
/// computer's users.
const IPC_ROOT: &str = "/tmp/iceoryx2";

impl RunScope {
    pub fn new(prefix: &str) -> Result<Self, BusError> {
        let valid =
            !prefix.is_empty() && prefix.len() <= 32 && prefix.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_');
        if !valid {
            return Err(BusError::InvalidPrefix(prefix.to_owned()));
        }
        Ok(Self {
            prefix: prefix.to_owned(),
        })
    }

    /// The scope named by [`PREFIX_ENV`], or the default.
    pub fn from_env() -> Result<Self, BusError> {
        Self::new(&std::env::var(PREFIX_ENV).unwrap_or_else(|_| DEFAULT_PREFIX.to_owned()))
    }

    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The run's own folder under the iceoryx2 folder.
    pub fn root(&self) -> PathBuf {
        PathBuf::from(format!("{IPC_ROOT}/{}/", self.prefix))
    }

    pub fn config(&self) -> Result<Config, BusError> {
        let mut config = Config::default();
        config.global.prefix = FileName::new(self.prefix.as_bytes()).map_err(|e| BusError::ipc("prefix", e))?;
        let root = self.root();
        let root = root.to_string_lossy();
        config
            .global
            .set_root_path(&Path::new(root.as_bytes()).map_err(|e| BusError::ipc("root path", e))?);
        Ok(config)
    }

    /// Removes the resources of this run's nodes whose processes died
    /// (crashed or killed), so their services can be opened afresh.
    /// Returns how many dead nodes were cleaned.
    pub fn remove_dead_nodes(&self) -> Result<usize, BusError> {
        self.remove_abandoned_storages();
        let mut cleaned = 0;
        self.each_node(|state| {
            if let NodeState::Dead(view) = state {
                if view.try_remove_stale_resources().is_ok() {
                    cleaned += 1;
                }
            }
        })?;
        Ok(cleaned)
    }

    /// The names of this run's live nodes.
    pub fn live_node_names(&self) -> Result<Vec<String>, BusError> {
        let mut names = Vec::new();
        self.each_node(|state| {
            if let NodeState::Alive(view) = state {
                if let Some(details) = view.details() {
                    names.push(details.name().as_str().to_owned());
                }
            }
        })?;
        Ok(names)
    }

    /// Over what a crashed run left: removes its dead nodes, and all its
    /// files when none of its nodes is alive.
    pub fn clean_stale(&self) -> Result<(), BusError> {
        self.remove_dead_nodes()?;
        if self.live_nodes()? == 0 {
            self.remove_all_files()?;
        }
        Ok(())
    }

    /// How many nodes of this run are alive.
    pub(crate) fn live_nodes(&self) -> Result<usize, BusError> {
        let mut alive = 0;
        self.each_node(|state| {
            if let NodeState::Alive(_) = state {
                alive += 1;
            }
        })?;
        Ok(alive)
    }

    /// Deletes every file of this run: its folder and its /dev/shm entries.
    /// Only for when none of its processes is alive (after a clean stop, or
    /// over what a killed run left). Prefixes must not be prefixes of one
    /// another (`hydractl_` and `hydractl_x_`), or one run's cleanup would
    /// take the other's shared memory.
    pub fn remove_all_files(&self) -> Result<(), BusError> {
        let root = self.root();
        match std::fs::remove_dir_all(&root) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(source) => {
                return Err(self.permission_problem().unwrap_or(BusError::Cleanup {
                    path: root.display().to_string(),
                    source,
                }))
            }
        }
        for path in self.shm_files() {
            match std::fs::remove_file(&path) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(source) => {
                    return Err(self.permission_problem().unwrap_or(BusError::Cleanup {
                        path: path.display().to_string(),
                        source,
                    }))
                }
            }
        }
        Ok(())
    }

    /// iceoryx2 0.10 waits without end, with SIGTERM blocked, to open a
    /// storage whose creator died between making its file and sizing it
    /// (an empty file, write-only until initialized: the open's
    /// `MappingSizeIsZero` case has no timeout), and a dead node's cleanup
    /// opens every storage of its services. A process killed while it
    /// opened a service (a restart) left one, and the supervisor's next
    /// cleanup hung for good. Such a file older than
    /// [`ABANDONED_AFTER`] is an abandoned creation: removed first.
    fn remove_abandoned_storages(&self) {
        use std::os::unix::fs::PermissionsExt;
        for path in self.shm_files() {
            let Ok(meta) = std::fs::metadata(&path) else { continue };
            let abandoned = meta.len() == 0
                && meta.permissions().mode() & 0o444 == 0
                && meta
                    .modified()
                    .ok()
                    .and_then(|at| at.elapsed().ok())
                    .is_some_and(|age| age >= ABANDONED_AFTER);
            if abandoned {
                let _ = std::fs::remove_file(&path);
            }
        }
    }

    /// iceoryx2 0.10 creates its node counter (`…_node.<version>.global_mgmt`
    /// in /dev/shm) writable by every user, 0666, the only file of a run
    /// that is; anyone could then disturb the run's node ids. The run's
    /// files are its user's: owner only. One that is not ours (another
    /// user's run on this prefix) is left as it is; its run says so.
    fn restrict_node_counter(&self) {
        use std::os::unix::fs::PermissionsExt;
        for path in self.shm_files() {
            if path.to_string_lossy().ends_with(".global_mgmt") {
                let _ = std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600));
            }
        }
    }

    /// This run's files in /dev/shm.
    pub fn shm_files(&self) -> Vec<PathBuf> {
        std::fs::read_dir("/dev/shm")
            .map(|entries| {
                entries
                    .filter_map(Result::ok)
                    .filter(|e| e.file_name().to_string_lossy().starts_with(&self.prefix))
                    .map(|e| e.path())
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Every publish-subscribe service of this run, with the type name of its
    /// payload: how a recorder finds what to record, including services that
    /// appear while it runs.
    pub fn publish_subscribe_services(&self) -> Result<Vec<DiscoveredService>, BusError> {
        let mut found = Vec::new();
        ipc::Service::list(&self.config()?, |details| {
            if let iceoryx2::service::static_config::messaging_pattern::MessagingPattern::PublishSubscribe(pattern) =
                details.static_details.messaging_pattern()
            {
                found.push(DiscoveredService {
                    name: details.static_details.name().as_str().to_owned(),
                    type_name: pattern.message_type_details().payload.type_name().to_string(),
                });
            }
            CallbackProgression::Continue
        })
        .map_err(|e| BusError::ipc("listing services", e))?;
        found.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(found)
    }

    /// Calls `visit` with every node of this run, alive or dead.
    fn each_node(&self, mut visit: impl FnMut(NodeState<ipc::Service>)) -> Result<(), BusError> {
        Node::<ipc::Service>::list(&self.config()?, |state| {
            visit(state);
            CallbackProgression::Continue
        })
        .map_err(|e| {
            self.permission_problem()
                .unwrap_or_else(|| BusError::ipc("listing nodes", e))
        })
    }

    /// The first of this run's files that this user may not both read and
    /// write (iceoryx2 needs both), or the shared folder above them when
    /// this user cannot reach or make the run's folder in it, as a
    /// [`BusError::Permission`] naming the file, its owner and the fix.
    pub(crate) fn permission_problem(&self) -> Option<BusError> {
        use nix::unistd::{access, AccessFlags};
        let parent = std::path::Path::new(IPC_ROOT);
        let needs = if self.root().exists() {
            AccessFlags::X_OK
        } else {
            AccessFlags::W_OK | AccessFlags::X_OK
        };
        if parent.exists() && access(parent, needs).is_err() {
            let owner = owner_of(parent);
            return Some(BusError::Permission {
                mode: mode_of(parent),
                fix: format!(
                    "the folder of every user's runs, made by {owner} for its own alone; as root, `chmod 1777 {IPC_ROOT}` (as hydractl leaves it), or run as {owner}"
                ),
                owner,
                path: IPC_ROOT.to_owned(),
            });
        }
        let mut files = self.shm_files();
        let mut folders = vec![self.root()];
        while let Some(folder) = folders.pop() {
            files.push(folder.clone());
            for entry in std::fs::read_dir(&folder).into_iter().flatten().flatten() {
                let path = entry.path();
                if path.is_dir() {
                    folders.push(path);
                } else {
                    files.push(path);
                }
            }
        }
        files
            .into_iter()
            .filter(|path| path.exists())
            .find(|path| access(path.as_path(), AccessFlags::R_OK | AccessFlags::W_OK).is_err())
            .map(|path| {
                let owner = owner_of(&path);
                BusError::Permission {
                    mode: mode_of(&path),
                    fix: format!(
                        "another user's run left it; run as {owner}, remove it as root once that run has ended (`rm -rf {}`), or set {PREFIX_ENV} to a prefix of your own",
                        path.display()
                    ),
                    owner,
                    path: path.display().to_string(),
                }
            })
    }

    /// Whether anything of this run is left on disk.
    pub fn has_files(&self) -> bool {
        self.root().exists() || !self.shm_files().is_empty()
    }
}

/// The user name (or uid) owning `path`.
fn owner_of(path: &std::path::Path) -> String {
    use std::os::unix::fs::MetadataExt;
    let Ok(uid) = std::fs::metadata(path).map(|m| m.uid()) else {
        return "an unknown user".to_owned();
    };
    match nix::unistd::User::from_uid(nix::unistd::Uid::from_raw(uid)) {
        Ok(Some(user)) => format!("{} (uid {uid})", user.name),
        _ => format!("uid {uid}"),
    }
}

/// iceoryx2 makes its folder for its first user alone (0750), and every
/// other user's run then fails: made ours, it becomes what /tmp is
/// (1777: anyone makes a folder in it, only its owner removes it), while
/// each run's own folder and files stay its user's.
fn share_ipc_root() {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let Ok(meta) = std::fs::metadata(IPC_ROOT) else { return };
    if meta.uid() == nix::unistd::geteuid().as_raw() && meta.permissions().mode() & 0o7777 != 0o1777 {
        let _ = std::fs::set_permissions(IPC_ROOT, std::fs::Permissions::from_mode(0o1777));
    }
}

/// The permission bits of `path` (0 when it cannot be read).
fn mode_of(path: &std::path::Path) -> u32 {
    use std::os::unix::fs::PermissionsExt;
    std::fs::metadata(path).map_or(0, |m| m.permissions().mode() & 0o7777)
}

/// A publish-subscribe service found by discovery.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DiscoveredService {
    pub name: String,
    /// The payload's type name, as iceoryx2 keeps it in the service's config.
    pub type_name: String,
}

/// A process's node on the bus.
pub struct Bus {
    node: Node<ipc::Service>,
    scope: RunScope,
}

impl Bus {
    /// Opens the node `name` in `scope`. Signals are left to the caller's
    /// loop ([`crate::run_loop`] returns on SIGINT and SIGTERM).
    pub fn open(scope: &RunScope, name: &str) -> Result<Self, BusError> {
        let config = scope.config()?;
        let node = NodeBuilder::new()
            .name(&NodeName::new(name).map_err(|e| BusError::ipc("node name", e))?)
            .config(&config)
            .create::<ipc::Service>()
            .map_err(|e| {
                scope
                    .permission_problem()
                    .unwrap_or_else(|| BusError::ipc(format!("creating node {name}"), e))
            })?;
        scope.restrict_node_counter();
        share_ipc_root();
        let bus = Self {
            node,
            scope: scope.clone(),
        };
        // iceoryx2 installs its SIGINT/SIGTERM handler on the first check;
        // do it now, so a signal interrupts a blocking wait instead of
        // killing the process before it cleans up.
        bus.termination_requested();
        Ok(bus)
    }

    /// Whether SIGINT or SIGTERM has arrived.
    pub fn termination_requested(&self) -> bool {
        self.node.wait(std::time::Duration::ZERO).is_err()
    }

    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    pub fn scope(&self) -> &RunScope {
        &self.scope
    }
}

/// Keeps iceoryx2's own logging to errors, unless `IOX2_LOG_LEVEL` asks
/// for more: its warning on every dead node it cleans up is routine here,
/// where the supervisor kills and restarts processes by design.
pub fn quiet_ipc_logging() {
    set_log_level_from_env_or(LogLevel::Error);
}

/// A scope of its own, started clean and cleaned when dropped, however its
/// owner ends: a test's failed assert must not leave shared memory behind.
/// Drop it after everything that has a node in it.
#[derive(Debug)]
pub struct OwnedScope(RunScope);

impl OwnedScope {
    /// `prefix`, with what a crashed run of the same prefix left removed.
    pub fn fresh(prefix: &str) -> Result<Self, BusError> {
        let scope = RunScope::new(prefix)?;
        scope.remove_all_files()?;
        Ok(Self(scope))
    }
}

impl std::ops::Deref for OwnedScope {
    type Target = RunScope;
    fn deref(&self) -> &RunScope {
        &self.0
    }
}

impl Drop for OwnedScope {
    fn drop(&mut self) {
        let _ = self.0.clean_stale();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn every_file_of_a_run_is_its_users_alone() {
        let scope = RunScope::new(&format!("t{}_mode_", std::process::id() % 100_000)).expect("prefix");
        scope.remove_all_files().expect("clean start");
        let bus = Bus::open(&scope, "probe").expect("node");
        let files = scope.shm_files();
        assert!(!files.is_empty());
        for path in files {
            let mode = std::fs::metadata(&path).expect("metadata").permissions().mode() & 0o777;
            assert_eq!(mode & 0o077, 0, "{} is {mode:o}", path.display());
        }
        drop(bus);
        scope.clean_stale().expect("clean");
    }

    #[test]
    fn a_storage_whose_creator_died_before_sizing_it_is_removed_before_the_dead_nodes() {
        let scope = RunScope::new(&format!("t{}_abandon_", std::process::id() % 100_000)).expect("prefix");
        scope.remove_all_files().expect("clean start");
        let file = |name: &str, bytes: &[u8], mode: u32, age_s: u64| {
            let path = PathBuf::from(format!("/dev/shm/{}{name}", scope.prefix()));
            std::fs::write(&path, bytes).expect("write");
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).expect("chmod");
            let at = std::time::SystemTime::now() - std::time::Duration::from_secs(age_s);
            std::fs::File::options()
                .write(true)
                .open(&path)
                .and_then(|f| f.set_modified(at))
                .expect("mtime");
            path
        };
        let abandoned = file("abandoned.dynamic", b"", 0o200, 5);
        let being_made = file("being_made.dynamic", b"", 0o200, 0);
        let finished = file("finished.dynamic", b"x", 0o600, 5);
        scope.remove_dead_nodes().expect("cleanup");
        assert!(!abandoned.exists());
        assert!(being_made.exists() && finished.exists());
        scope.remove_all_files().expect("clean");
    }
}
