//! The supervisor's status: every process, its variant, pid, restarts and
//! health, as `hydractl status` and the live line show it.

use std::time::{Duration, Instant};

use hydractl_bus::clock;
use hydractl_samples::{fixed_name, source, ProcessStatus, SupervisorStatus, MAX_PROCESSES};

use super::child::Supervised;
use super::seat::Seat;

pub(super) fn status_of(
    seq: u64,
    children: &[Supervised],
    seat: &Seat,
    recorder: Option<&Supervised>,
    own_pid: u32,
    now: Instant,
    hung_after: Duration,
) -> SupervisorStatus {
    let mut status = SupervisorStatus {
        seq,
        plant_is_simulation: u32::from(seat.source == source::SIMULATION),
        stage_time_ns: clock::now_ns(),
        ..SupervisorStatus::default()
    };
    let entries = children.iter().map(|c| ProcessStatus {
        name: fixed_name(c.name),
        variant: fixed_name(c.variant.unwrap_or(if c.name == "torque" { "bypassed" } else { "" })),
        pid: c.pid().unwrap_or(0),
        restarts: c.restarts,
        healthy: u32::from(c.is_running() && now.saturating_duration_since(c.last_output) <= hung_after),
        reserved: 0,
    });
    // The plant not in charge: the simulated plant is ready while it runs;
    // the machine is well while its readings come.
    let spare = seat.spare.as_ref().map(|p| ProcessStatus {
        name: fixed_name(p.name),
        variant: fixed_name("standby"),
        pid: p.pid().unwrap_or(0),
        restarts: p.restarts,
        healthy: u32::from(
            p.is_running() && (p.name == "plant" || now.saturating_duration_since(p.last_output) <= hung_after),
        ),
        reserved: 0,
    });
    // The recorder has no output of its own on the loop: healthy while it runs.
    let recorder = recorder.map(|r| ProcessStatus {
        name: fixed_name(r.name),
        variant: [0; 16],
        pid: r.pid().unwrap_or(0),
        restarts: r.restarts,
        healthy: u32::from(r.is_running()),
        reserved: 0,
    });
    let supervisor = ProcessStatus {
        name: fixed_name("supervisor"),
        variant: [0; 16],
        pid: own_pid,
        restarts: 0,
        healthy: 1,
        reserved: 0,
    };
    let mut count = 0;
    for (slot, entry) in status
        .processes
        .iter_mut()
        .zip(entries.chain(spare).chain(recorder).chain(std::iter::once(supervisor)))
    {
        *slot = entry;
        count += 1;
    }
    status.process_count = count.min(MAX_PROCESSES) as u32;
    status
}
