//! The supervisor's status: every process, its variant, pid, restarts and
//! health, as `hydractl status` and the live line show it.

use std::time::{Duration, Instant};

use std::collections::HashMap;

use hydractl_bus::clock;
use hydractl_samples::{fixed_name, source, ProcessStatus, SupervisorStatus, MAX_PROCESSES, UNKNOWN};

use super::child::Supervised;
use super::seat::Seat;

/// The loop processes' memory: whether each locked it, and how many page
/// faults it took since it answered its first reading (the goal is none).
/// Counted from its first answer, not from its start: until its peers
/// have all opened their ports, connecting to one maps its memory, which
/// is the start-up's work, not the loop's. And counted afresh once its
/// memory is locked, at the second status that sees it locked: the valve
/// answers (neutral) before it locks, and the locking itself faults in
/// what was not yet resident, after `VmLck` already shows it.
#[derive(Default)]
pub(super) struct LoopMemory {
    /// By pid: its page faults when counting began, and how many
    /// statuses saw its memory locked until then (counting begins afresh
    /// until two have).
    at_first_answer: HashMap<u32, (u64, u8)>,
}

impl LoopMemory {
    /// Process `pid`'s page faults since its first answer and whether its
    /// memory is locked (`VmLck` in `/proc/PID/status`): [`UNKNOWN`] and 0
    /// before it answered.
    fn of(&mut self, child: &Supervised) -> (u32, u32) {
        let (Some(pid), Some(_)) = (child.pid(), child.last_seq) else {
            return (UNKNOWN, 0);
        };
        let Some(now) = hydractl_rt::page_faults(Some(pid)) else {
            return (UNKNOWN, 0);
        };
        let locked = hydractl_rt::memory_locked(pid);
        let entry = self.at_first_answer.entry(pid).or_insert((now, 0));
        if locked && entry.1 < 2 {
            *entry = (now, entry.1 + 1);
        }
        (
            now.saturating_sub(entry.0).min(u64::from(UNKNOWN - 1)) as u32,
            u32::from(locked),
        )
    }
}

#[allow(clippy::too_many_arguments)]
pub(super) fn status_of<'a>(
    seq: u64,
    children: &[Supervised],
    seat: &Seat,
    off_loop: impl Iterator<Item = &'a Supervised>,
    own_pid: u32,
    now: Instant,
    hung_after: Duration,
    memory: &mut LoopMemory,
) -> SupervisorStatus {
    let mut status = SupervisorStatus {
        seq,
        plant_is_simulation: u32::from(seat.source == source::SIMULATION),
        stage_time_ns: clock::now_ns(),
        ..SupervisorStatus::default()
    };
    let entries = children
        .iter()
        .map(|c| {
            let (page_faults_after_start, memory_locked) = memory.of(c);
            ProcessStatus {
                name: fixed_name(c.name),
                variant: fixed_name(c.variant.unwrap_or(if c.name == "torque" { "bypassed" } else { "" })),
                pid: c.pid().unwrap_or(0),
                restarts: c.restarts,
                healthy: u32::from(c.is_running() && now.saturating_duration_since(c.last_output) <= hung_after),
                page_faults_after_start,
                memory_locked,
            }
        })
        .collect::<Vec<_>>();
    // The plant not in charge: the simulated plant is ready while it runs;
    // the machine is well while its readings come.
    let spare = seat.spare.as_ref().map(|p| {
        let (page_faults_after_start, memory_locked) = memory.of(p);
        ProcessStatus {
            name: fixed_name(p.name),
            variant: fixed_name("standby"),
            pid: p.pid().unwrap_or(0),
            restarts: p.restarts,
            healthy: u32::from(
                p.is_running() && (p.name == "plant" || now.saturating_duration_since(p.last_output) <= hung_after),
            ),
            page_faults_after_start,
            memory_locked,
        }
    });
    // The recorder and the shadow have no output on the loop: healthy
    // while they run.
    let off_loop = off_loop.map(|r| ProcessStatus {
        name: fixed_name(r.name),
        variant: [0; 16],
        pid: r.pid().unwrap_or(0),
        restarts: r.restarts,
        healthy: u32::from(r.is_running()),
        page_faults_after_start: UNKNOWN,
        memory_locked: 0,
    });
    let supervisor = ProcessStatus {
        name: fixed_name("supervisor"),
        variant: [0; 16],
        pid: own_pid,
        restarts: 0,
        healthy: 1,
        page_faults_after_start: UNKNOWN,
        memory_locked: 0,
    };
    let mut count = 0;
    for (slot, entry) in status.processes.iter_mut().zip(
        entries
            .into_iter()
            .chain(spare)
            .chain(off_loop)
            .chain(std::iter::once(supervisor)),
    ) {
        *slot = entry;
        count += 1;
    }
    status.process_count = count.min(MAX_PROCESSES) as u32;
    status
}
