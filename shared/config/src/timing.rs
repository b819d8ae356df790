//! `[timing]`: the loop's rate and where and how its processes run.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Timing {
    /// Control loop rate, Hz (the papers' dSPACE loops; 1 kHz).
    pub control_rate_hz: f64,
    /// Plant integration rate, Hz; an integer multiple of the control rate.
    pub integration_rate_hz: f64,
    /// The CPU the live loop's processes (plant, sensor, friction,
    /// position, torque, valve) are pinned to; none to let the scheduler
    /// place them. A wake-up across cores costs about 25 µs per hop on a
    /// small virtual machine; on one core the pipeline's hand-offs are cheap.
    pub loop_cpu: Option<usize>,
    /// SCHED_FIFO priority (1–98) of the live loop's processes; none for
    /// the normal scheduler. Above every ordinary process, a stage is never
    /// preempted by one, only by the kernel and by higher real-time work;
    /// the kernel's real-time throttling (95% of each second by default)
    /// still leaves the CPU to others should a stage spin.
    pub realtime_priority: Option<u8>,
    /// Held for the run through the kernel's PM QoS request: no CPU enters
    /// an idle state slower to leave than this, µs; none to let CPUs sleep
    /// as deeply as they like. 0 keeps idle CPUs polling, so that a stage
    /// woken by its input runs at once: on this virtual machine a halted
    /// virtual CPU takes about 25 µs to wake, and the loop wakes at every
    /// hop. Costs power on idle CPUs; needs root.
    pub cpu_dma_latency_us: Option<u32>,
    /// Move device interrupts off `loop_cpu` for the run: their handlers
    /// preempt even a real-time stage. Needs root and a `loop_cpu`.
    pub interrupts_off_loop_cpu: bool,
    /// What the live plant process does when the computer stalls.
    pub stall_policy: StallPolicy,
    /// How long, in periods, the paused plant waits for a command before it
    /// counts a deadline miss and goes on with the valve's last command.
    pub command_timeout_periods: f64,
    /// Each loop process locks its memory (`mlockall`) once its start-up
    /// allocations are done, so that the loop never waits for a page
    /// brought back from disk or first touched. Needs `LimitMEMLOCK=infinity`
    /// (or root); without it the process says so once and runs on.
    pub lock_memory: bool,
}

/// A stalled computer delays the loop. A simulated plant can wait for it
/// (`pause`: its time is the loop's, so it stays exactly the offline
/// simulation); a machine cannot (`catch_up`: physics runs on with the
/// valve's last command, as a stand-in for real hardware).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StallPolicy {
    Pause,
    CatchUp,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            control_rate_hz: 1000.0,
            integration_rate_hz: 10_000.0,
            loop_cpu: None,
            realtime_priority: None,
            cpu_dma_latency_us: None,
            interrupts_off_loop_cpu: false,
            stall_policy: StallPolicy::Pause,
            command_timeout_periods: 1.5,
            lock_memory: true,
        }
    }
}

impl Timing {
    pub fn control_period(&self) -> f64 {
        1.0 / self.control_rate_hz
    }

    /// How many control periods `ms` milliseconds span, rounded.
    pub fn periods_in_ms(&self, ms: u64) -> u64 {
        (ms as f64 / 1000.0 / self.control_period()).round() as u64
    }

    pub fn integration_step(&self) -> f64 {
        1.0 / self.integration_rate_hz
    }

    pub fn substeps(&self) -> usize {
        (self.integration_rate_hz / self.control_rate_hz).round() as usize
    }
}
