//! Where the live processes run. A wake-up across cores costs about 25 µs
//! per hop on a small virtual machine, so the loop's processes share one
//! CPU and everything else stays off it.

use nix::sched::{sched_setaffinity, CpuSet};
use nix::unistd::Pid;

/// Pins this process to the loop's CPU, when one is configured. A process
/// that cannot be pinned still runs, so callers report the error and go on.
pub fn pin_to_loop_cpu(loop_cpu: Option<usize>) -> Result<(), PlacementError> {
    match loop_cpu {
        Some(cpu) => pin(|set| set.set(cpu), format!("CPU {cpu}")),
        None => Ok(()),
    }
}

/// Keeps a process that is not in the loop (supervisor, monitor, tools)
/// off the loop's CPU, so it never delays a stage.
pub fn keep_off_loop_cpu(loop_cpu: Option<usize>) -> Result<(), PlacementError> {
    let Some(cpu) = loop_cpu else { return Ok(()) };
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    if cpus < 2 {
        return Ok(());
    }
    pin(
        |set| (0..cpus).filter(|&c| c != cpu).try_for_each(|c| set.set(c)),
        format!("the CPUs other than {cpu}"),
    )
}

#[derive(Debug, thiserror::Error)]
#[error("cannot pin to {what}: {source}; running unpinned")]
pub struct PlacementError {
    what: String,
    source: nix::Error,
}

fn pin(fill: impl FnOnce(&mut CpuSet) -> nix::Result<()>, what: String) -> Result<(), PlacementError> {
    let mut set = CpuSet::new();
    fill(&mut set)
        .and_then(|()| sched_setaffinity(Pid::from_raw(0), &set))
        .map_err(|source| PlacementError { what, source })
}
