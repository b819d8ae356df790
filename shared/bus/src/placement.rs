//! Where the live processes run. A wake-up across cores costs about 25 µs
//! per hop on a small virtual machine, so the loop's processes share one
//! CPU and everything else stays off it.

use nix::sched::{sched_setaffinity, CpuSet};
use nix::unistd::Pid;

/// Pins this process to the loop's CPU, when one is configured; says so
/// when that CPU does not exist, rather than failing.
pub fn pin_to_loop_cpu(loop_cpu: Option<usize>) {
    if let Some(cpu) = loop_cpu {
        pin(|set| set.set(cpu), &format!("CPU {cpu}"));
    }
}

/// Keeps a process that is not in the loop (supervisor, monitor, tools)
/// off the loop's CPU, so it never delays a stage.
pub fn keep_off_loop_cpu(loop_cpu: Option<usize>) {
    if let Some(cpu) = loop_cpu {
        let cpus = std::thread::available_parallelism().map_or(1, usize::from);
        if cpus > 1 {
            pin(
                |set| (0..cpus).filter(|&c| c != cpu).try_for_each(|c| set.set(c)),
                &format!("the CPUs other than {cpu}"),
            );
        }
    }
}

fn pin(fill: impl FnOnce(&mut CpuSet) -> nix::Result<()>, what: &str) {
    let mut set = CpuSet::new();
    if let Err(e) = fill(&mut set).and_then(|()| sched_setaffinity(Pid::from_raw(0), &set)) {
        eprintln!("not pinned to {what}: {e}; running unpinned");
    }
}
