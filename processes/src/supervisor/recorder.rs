//! The recorder, when the run records: started before the loop and
//! stopped after it, restarted into a new file beside the first.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use hydractl_bus::{Bus, Reader, RunScope};
use hydractl_samples::{service, RecorderStatus};

use super::child::Supervised;
use crate::SplitArgs;

/// The recorder, when the run records: started before the loop, so that
/// the loop's first samples are recorded, and stopped after it.
pub(super) struct RecorderChild {
    pub(super) child: Supervised,
    pub(super) split: SplitArgs,
    pub(super) out: PathBuf,
    /// The ring of earlier runs' recordings it belongs to.
    pub(super) ring: Option<String>,
}

impl RecorderChild {
    /// Starts the recorder and waits until it is subscribed (its first
    /// status); a recorder that dies first (an unwritable file, say) fails
    /// the run, having said why on stderr.
    pub(super) fn start(&mut self, bus: &Bus, scope: &RunScope) -> Result<()> {
        let ready: Reader<RecorderStatus> = Reader::open(bus, service::RECORDER_STATUS, 4)?;
        self.child.spawn(scope, &self.recorder_args(&self.out)?)?;
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if ready.latest()?.is_some() {
                return Ok(());
            }
            if self.child.reap() {
                bail!(
                    "the recorder exited before it started recording to {}",
                    self.out.display()
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        bail!("the recorder did not start within 10 s")
    }

    fn recorder_args(&self, out: &Path) -> Result<Vec<String>> {
        let mut args = self.split.recorder_args(out)?;
        if let Some(ring) = &self.ring {
            args.extend(["--ring".to_owned(), ring.clone()]);
        }
        Ok(args)
    }

    /// A restarted recorder writes a new file beside the first:
    /// `STEM_restartN.mcap`, so that nothing recorded is overwritten.
    pub(super) fn restart(&mut self, scope: &RunScope) -> Result<()> {
        let n = self.child.restarts + 1;
        let out = restart_file(&self.out, n);
        self.child.spawn(scope, &self.recorder_args(&out)?)?;
        self.child.restarts = n;
        Ok(())
    }
}

/// The file of the recorder's `n`th restart, beside the first:
/// `STEM_restartN.mcap`, so that nothing recorded is overwritten.
fn restart_file(out: &Path, n: u32) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    out.with_file_name(format!("{stem}_restart{n}.mcap"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_restarted_recorder_writes_beside_the_first_file() {
        assert_eq!(
            restart_file(Path::new("/data/run.mcap"), 2),
            PathBuf::from("/data/run_restart2.mcap")
        );
    }
}
