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

/// The kernel's PM QoS request for the CPUs' wake-up latency.
const CPU_DMA_LATENCY: &str = "/dev/cpu_dma_latency";

/// A held limit on how slow a CPU may be to leave idle: while it lives, no
/// CPU enters an idle state whose exit latency exceeds the limit. The
/// kernel drops the request when the file closes, with the process or when
/// this is dropped.
#[derive(Debug)]
pub struct IdleLatencyLimit {
    _request: std::fs::File,
}

/// Asks the kernel to keep every CPU's idle exit latency at or below
/// `max_us` (the PM QoS interface that `cyclictest` uses). At 0 an idle CPU
/// polls instead of halting: on a virtual machine a halted virtual CPU is
/// woken through the host, about 25 µs per wake-up here, and the loop's
/// stages wake at every hop. The price is idle CPUs that draw power. Needs
/// root; like pinning, a failure leaves the run going, for the caller to
/// report.
pub fn limit_idle_latency(max_us: Option<u32>) -> Result<Option<IdleLatencyLimit>, PlacementError> {
    use std::io::Write;
    let Some(max_us) = max_us else { return Ok(None) };
    let request = || -> std::io::Result<std::fs::File> {
        let mut file = std::fs::OpenOptions::new().write(true).open(CPU_DMA_LATENCY)?;
        // The kernel takes the value as a binary 32-bit integer.
        file.write_all(&i32::try_from(max_us).unwrap_or(i32::MAX).to_ne_bytes())?;
        Ok(file)
    };
    request()
        .map(|file| Some(IdleLatencyLimit { _request: file }))
        .map_err(|source| PlacementError::IdleLatency { max_us, source })
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
    #[error("cannot hold {CPU_DMA_LATENCY} at {max_us} µs (needs root): {source}; idle CPUs may sleep deeply and wake slowly")]
    IdleLatency { max_us: u32, source: std::io::Error },
}

fn pin(fill: impl FnOnce(&mut CpuSet) -> nix::Result<()>, what: String) -> Result<(), PlacementError> {
    let mut set = CpuSet::new();
    fill(&mut set)
        .and_then(|()| sched_setaffinity(Pid::from_raw(0), &set))
        .map_err(|source| PlacementError::Pin { what, source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_idle_latency_limit_asks_nothing_of_the_kernel() {
        assert!(matches!(limit_idle_latency(None), Ok(None)));
    }

    #[test]
    fn an_idle_latency_limit_is_held_or_its_refusal_names_the_device() {
        match limit_idle_latency(Some(0)) {
            Ok(Some(_held)) => {
                // While held, the kernel's effective limit is at most ours.
                let effective = std::fs::read(CPU_DMA_LATENCY).expect("reading the request back");
                let bytes: [u8; 4] = effective[..4].try_into().expect("four bytes");
                assert_eq!(i32::from_ne_bytes(bytes), 0);
            }
            Ok(None) => panic!("a limit was asked for"),
            Err(e) => assert!(e.to_string().contains(CPU_DMA_LATENCY), "{e}"),
        }
    }
}
