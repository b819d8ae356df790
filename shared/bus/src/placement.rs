//! Where and how the live processes run. A wake-up across cores costs
//! about 25 µs per hop on a small virtual machine, so the loop's processes
//! share one CPU and everything else stays off it; at a real-time priority
//! no ordinary process delays them.

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

/// Runs this process under SCHED_FIFO at `priority`, when one is
/// configured. Like pinning, a failure (no CAP_SYS_NICE) leaves the process
/// running, at normal priority, for the caller to report.
pub fn run_realtime(priority: Option<u8>) -> Result<(), PlacementError> {
    let Some(priority) = priority else { return Ok(()) };
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: plain system call on this process with a valid parameter.
    #[allow(unsafe_code)]
    let status = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if status == 0 {
        Ok(())
    } else {
        Err(PlacementError::Priority {
            priority,
            source: nix::Error::last(),
        })
    }
}

/// Pins this loop process and raises its priority as `loop_cpu` and
/// `realtime_priority` say; every failure is returned, none stops it.
pub fn enter_loop(loop_cpu: Option<usize>, realtime_priority: Option<u8>) -> Vec<PlacementError> {
    [pin_to_loop_cpu(loop_cpu), run_realtime(realtime_priority)]
        .into_iter()
        .filter_map(Result::err)
        .collect()
}

#[derive(Debug, thiserror::Error)]
pub enum PlacementError {
    #[error("cannot pin to {what}: {source}; running unpinned")]
    Pin { what: String, source: nix::Error },
    #[error("cannot run at real-time priority {priority} (SCHED_FIFO needs root or CAP_SYS_NICE): {source}; running at normal priority")]
    Priority { priority: u8, source: nix::Error },
}

fn pin(fill: impl FnOnce(&mut CpuSet) -> nix::Result<()>, what: String) -> Result<(), PlacementError> {
    let mut set = CpuSet::new();
    fill(&mut set)
        .and_then(|()| sched_setaffinity(Pid::from_raw(0), &set))
        .map_err(|source| PlacementError::Pin { what, source })
}
