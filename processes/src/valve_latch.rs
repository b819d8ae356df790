//! The machine's valve's latched fault, kept on disk so that it survives a
//! restart of the valve process and of the whole stack: a fault stays a
//! fault until a person resets it (`hydractl valve reset`), as ISO
//! 13849-1 asks of a safety stop. The file is written when the fault is
//! first seen, before anything else is done about it, and replaced
//! atomically (written beside, synced, renamed).
//!
//! It also keeps the times of the last resets: a valve that faults again
//! after each of `MAX_RESETS` resets within `RESET_WINDOW_S` needs
//! service, not another reset (`--serviced` says it had it).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use hydractl_bus::clock::unix_now_s;
use serde::{Deserialize, Serialize};

/// Resets within [`RESET_WINDOW_S`] after which another is refused.
pub(crate) const MAX_RESETS: usize = 3;
pub(crate) const RESET_WINDOW_S: f64 = 600.0;

/// Where a run keeps what must outlive it: `HYDRACTL_STATE_DIR`, else
/// systemd's `STATE_DIRECTORY` (the unit's `StateDirectory=`), else
/// `$XDG_STATE_HOME/hydractl`, else `~/.local/state/hydractl`; one
/// folder per run prefix below it.
pub fn state_dir(prefix: &str) -> PathBuf {
    let env = |name| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    let base = env("HYDRACTL_STATE_DIR")
        .or_else(|| {
            // systemd lists several, colon-separated: ours is the first.
            std::env::var("STATE_DIRECTORY")
                .ok()
                .and_then(|v| v.split(':').next().filter(|s| !s.is_empty()).map(PathBuf::from))
        })
        .or_else(|| env("XDG_STATE_HOME").map(|d| d.join("hydractl")))
        .or_else(|| env("HOME").map(|d| d.join(".local/state/hydractl")))
        .unwrap_or_else(|| PathBuf::from("/var/lib/hydractl"));
    base.join(prefix)
}

/// The latch file of the valve `node` on `interface`.
pub fn latch_path(prefix: &str, interface: &str, node: u8) -> PathBuf {
    state_dir(prefix).join(format!("valve-{interface}-node{node:#04x}.toml"))
}

/// A fault of the machine's valve, as latched.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LatchedFault {
    /// The EMCY's error code, or the stack's own (`can_valve::fault_code`).
    pub code: u32,
    pub meaning: String,
    /// When it was first seen, seconds since the Unix epoch.
    pub since_unix_s: f64,
}

#[derive(Debug, Default, Serialize, Deserialize)]
struct LatchFile {
    fault: Option<LatchedFault>,
    /// Seconds since the Unix epoch of the resets within the window.
    #[serde(default)]
    resets_unix_s: Vec<f64>,
}

/// Why a reset was refused.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Refusal {
    NothingLatched,
    NeedsService { resets: usize, window_s: f64 },
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NothingLatched => write!(f, "no fault is latched"),
            Self::NeedsService { resets, window_s } => write!(
                f,
                "the valve faulted again after each of the last {resets} resets within {:.0} min: it needs \
                 service, not another reset; once it has had it, `hydractl valve reset --serviced`",
                window_s / 60.0
            ),
        }
    }
}

pub struct FaultLatch {
    path: PathBuf,
    file: LatchFile,
}

impl FaultLatch {
    /// The latch at `path`, with what an earlier process latched there.
    /// Its folder is created and proven writable now, not when a fault
    /// comes.
    pub fn open(path: &Path) -> Result<Self> {
        let dir = path.parent().unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).with_context(|| format!("creating the valve's state folder {}", dir.display()))?;
        let file = match std::fs::read_to_string(path) {
            Ok(text) => toml::from_str(&text).with_context(|| {
                format!(
                    "{}: not a latch file this stack wrote; the valve stays neutral until a person looks at it",
                    path.display()
                )
            })?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => LatchFile::default(),
            Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
        };
        let latch = Self {
            path: path.to_owned(),
            file,
        };
        latch.save()?;
        Ok(latch)
    }

    pub fn latched(&self) -> Option<&LatchedFault> {
        self.file.fault.as_ref()
    }

    /// Latches a fault and writes it down; a fault already latched stays
    /// the one reported (the first cause, not its consequences).
    pub(crate) fn latch(&mut self, code: u32, meaning: String) -> Result<()> {
        if self.file.fault.is_some() {
            return Ok(());
        }
        self.file.fault = Some(LatchedFault {
            code,
            meaning,
            since_unix_s: unix_now_s(),
        });
        self.save()
    }

    /// Whether a reset is allowed now, and which fault it clears.
    pub(crate) fn may_reset(&self, serviced: bool, now_unix_s: f64) -> Result<LatchedFault, Refusal> {
        let Some(fault) = &self.file.fault else {
            return Err(Refusal::NothingLatched);
        };
        let recent = self.recent_resets(now_unix_s);
        if !serviced && recent >= MAX_RESETS {
            return Err(Refusal::NeedsService {
                resets: recent,
                window_s: RESET_WINDOW_S,
            });
        }
        Ok(fault.clone())
    }

    /// Clears the latched fault (after `FaultLatch::may_reset`) and
    /// writes the reset down.
    pub fn reset(&mut self, serviced: bool, now_unix_s: f64) -> Result<()> {
        self.file.fault = None;
        if serviced {
            self.file.resets_unix_s.clear();
        }
        self.file.resets_unix_s.retain(|&t| now_unix_s - t < RESET_WINDOW_S);
        self.file.resets_unix_s.push(now_unix_s);
        self.save()
    }

    fn recent_resets(&self, now_unix_s: f64) -> usize {
        self.file
            .resets_unix_s
            .iter()
            .filter(|&&t| now_unix_s - t < RESET_WINDOW_S)
            .count()
    }

    fn save(&self) -> Result<()> {
        let text = format!(
            "# The machine's valve, as hydractl's valve process left it. A latched fault keeps\n\
             # the valve neutral until `hydractl valve reset`; do not edit.\n{}",
            toml::to_string(&self.file).context("the latch file")?
        );
        let partial = self.path.with_extension("toml.partial");
        let write = || -> std::io::Result<()> {
            use std::io::Write;
            let mut f = std::fs::File::create(&partial)?;
            f.write_all(text.as_bytes())?;
            f.sync_all()?;
            std::fs::rename(&partial, &self.path)?;
            if let Some(dir) = self.path.parent() {
                std::fs::File::open(dir)?.sync_all()?;
            }
            Ok(())
        };
        write().with_context(|| format!("writing the valve's latch {}", self.path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("hydractl-latch-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir.join("valve.toml")
    }

    #[test]
    fn a_latched_fault_outlives_its_process_and_the_first_cause_is_kept() {
        let path = scratch("outlives");
        let mut latch = FaultLatch::open(&path).expect("open");
        assert!(latch.latched().is_none());
        latch.latch(0x81FF, "EMCY 0x81ff (RPDO timeout)".into()).expect("latch");
        latch.latch(0x8130, "the heartbeat stopped".into()).expect("latch");
        drop(latch);
        let again = FaultLatch::open(&path).expect("reopen");
        let fault = again.latched().expect("still latched");
        assert_eq!(fault.code, 0x81FF);
        assert!(fault.since_unix_s > 0.0);
        let _ = std::fs::remove_dir_all(path.parent().expect("dir"));
    }

    #[test]
    fn resets_are_counted_and_a_valve_that_keeps_faulting_needs_service() {
        let path = scratch("resets");
        let mut latch = FaultLatch::open(&path).expect("open");
        let now = 1_000_000.0;
        assert_eq!(latch.may_reset(false, now), Err(Refusal::NothingLatched));
        for i in 0..MAX_RESETS {
            latch.latch(0x81FF, "again".into()).expect("latch");
            let t = now + i as f64 * 60.0;
            assert!(latch.may_reset(false, t).is_ok(), "reset {i}");
            latch.reset(false, t).expect("reset");
        }
        latch.latch(0x81FF, "again".into()).expect("latch");
        let t = now + 200.0;
        let refusal = latch.may_reset(false, t).expect_err("needs service");
        assert!(refusal.to_string().contains("--serviced"), "{refusal}");
        assert!(latch.may_reset(true, t).is_ok());
        assert!(
            latch.may_reset(false, now + RESET_WINDOW_S + 1.0).is_ok(),
            "the window passed"
        );
        latch.reset(true, t).expect("serviced");
        drop(latch);
        let reopened = FaultLatch::open(&path).expect("reopen");
        assert!(reopened.latched().is_none());
        let _ = std::fs::remove_dir_all(path.parent().expect("dir"));
    }

    #[test]
    fn a_latch_file_that_is_not_ours_is_refused_naming_it() {
        let path = scratch("garbled");
        std::fs::create_dir_all(path.parent().expect("dir")).expect("dir");
        std::fs::write(&path, "fault = 3\n").expect("write");
        let e = FaultLatch::open(&path).err().expect("refused");
        assert!(format!("{e:#}").contains("valve.toml"), "{e:#}");
        let _ = std::fs::remove_dir_all(path.parent().expect("dir"));
    }
}
