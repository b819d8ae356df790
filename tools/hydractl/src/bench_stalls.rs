//! `hydractl bench stalls`: how long this computer takes a CPU away from a
//! process that nothing in the operating system may preempt. A loop at
//! SCHED_FIFO 99, pinned to the loop's CPU, only reads the clock; every
//! gap between two readings is time the CPU was elsewhere: interrupts, or
//! on a virtual machine the host running something else. A control loop
//! cannot be steadier than this, whatever its transport. Beside the gaps
//! it prints the steal time the kernel was told of meanwhile (the host's
//! own account of running something else on that CPU): when the two agree,
//! the gaps are the host's.

use std::time::Duration;

use anyhow::{Context, Result};
use hydractl_bus::clock;
use hydractl_config::Config;

use crate::slowest::Slowest;

#[derive(clap::Args)]
pub struct StallsArgs {
    /// Seconds of spinning, in bursts.
    #[arg(long, default_value_t = 60.0)]
    duration: f64,
    /// The CPU to watch (default: the config's loop CPU).
    #[arg(long)]
    cpu: Option<usize>,
    /// The config whose loop CPU is watched, with its interrupts steered
    /// off it as a run steers them (default: the simulated default).
    #[arg(long)]
    config: Option<std::path::PathBuf>,
}

/// A burst stays well inside the kernel's real-time budget (95% of each
/// second): the CPU is given back between bursts, so the system's own
/// work on it is not starved.
const BURST: Duration = Duration::from_millis(400);
const REST: Duration = Duration::from_millis(600);
pub const WATCHED_NS: [u64; 3] = [100_000, 1_000_000, 10_000_000];
/// A gap this long is time taken away; a clock reading takes about 30 ns.
const TAKEN_NS: u64 = 10_000;

/// What a measurement of the loop CPU's stalls found.
pub struct Stalls {
    pub bursts: usize,
    pub spun_ns: u64,
    /// Gaps of at least each of [`WATCHED_NS`].
    pub over: [u64; WATCHED_NS.len()],
    /// The longest gaps, ns, longest first.
    pub longest_ns: Vec<u64>,
    pub taken_ns: u64,
    /// The host's steal time meanwhile, when the kernel reports it.
    pub stolen_ns: Option<u64>,
    /// Device interrupts steered off the CPU, and those the kernel kept there.
    pub steered: Option<(usize, usize)>,
}

pub fn bench(args: StallsArgs) -> Result<()> {
    let config = Config::load_or_default(args.config.as_deref())?;
    let cpu = args.cpu.or(config.timing.loop_cpu);
    let s = measure(&config, cpu, args.duration)?;
    let top: Vec<String> = s
        .longest_ns
        .iter()
        .map(|gap| format!("{:.2}", *gap as f64 / 1e6))
        .collect();
    let mut where_ = cpu.map_or("unpinned".to_owned(), |c| format!("CPU {c}"));
    if let Some((moved, kept)) = s.steered {
        where_ += &format!(" ({moved} device interrupts steered off it, {kept} kept there by the kernel)");
    }
    crate::emit(&format!(
        "bench stalls: {where_}, SCHED_FIFO 99, {:.1} s spun in {} bursts\n\
         gaps ≥ 0.1 ms: {}\ngaps ≥ 1 ms:   {}\ngaps ≥ 10 ms:  {}\nlongest, ms:   {}\n\
         taken away:    {:.1} ms in gaps ≥ 10 µs\n\
         steal time:    {} (the host's account, /proc/stat, in 10 ms ticks)\n",
        s.spun_ns as f64 / 1e9,
        s.bursts,
        s.over[0],
        s.over[1],
        s.over[2],
        if top.is_empty() {
            "none".to_owned()
        } else {
            top.join(" ")
        },
        s.taken_ns as f64 / 1e6,
        s.stolen_ns
            .map_or("not reported by this kernel".to_owned(), |ns| format!(
                "{:.0} ms",
                ns as f64 / 1e6
            )),
    ))
}

/// Spins `duration_s` in bursts on `cpu` at SCHED_FIFO 99, with the CPU
/// reserved as `config`'s run reserves it, and measures every gap.
pub fn measure(config: &Config, cpu: Option<usize>, duration_s: f64) -> Result<Stalls> {
    // The computer as a run sees it.
    let timing = &config.timing;
    let (reservation, refusals) =
        hydractl_rt::reserve_for_run(cpu, timing.cpu_dma_latency_us, timing.interrupts_off_loop_cpu);
    for e in refusals {
        tracing::warn!("{e}");
    }
    let refusals = hydractl_rt::enter_loop(cpu, Some(99));
    if let Some(e) = refusals.first() {
        // Preemptible, the loop would measure the system's other work.
        return Err(anyhow::anyhow!("{e}")).context("bench stalls needs the CPU pinned at SCHED_FIFO 99");
    }
    let bursts = (duration_s / BURST.as_secs_f64()).ceil().max(1.0) as usize;
    let mut over = [0u64; WATCHED_NS.len()];
    // Kept without allocating: the spin loop measures its own delays too.
    let mut longest = Slowest::<(), 5>::default();
    let mut spun_ns = 0u64;
    let mut taken_ns = 0u64;
    let mut stolen_ns = Some(0u64);
    for _ in 0..bursts {
        let steal_before = steal_ns(cpu);
        let start = clock::now_ns();
        let end = start + BURST.as_nanos() as u64;
        let mut last = start;
        while last < end {
            let now = clock::now_ns();
            let gap = now - last;
            last = now;
            if gap >= TAKEN_NS {
                taken_ns += gap;
            }
            if gap >= WATCHED_NS[0] {
                for (count, limit) in over.iter_mut().zip(WATCHED_NS) {
                    *count += u64::from(gap >= limit);
                }
                longest.keep(gap, ());
            }
        }
        spun_ns += last - start;
        stolen_ns = match (stolen_ns, steal_before, steal_ns(cpu)) {
            (Some(sum), Some(before), Some(after)) => Some(sum + after.saturating_sub(before)),
            _ => None,
        };
        std::thread::sleep(REST);
    }
    Ok(Stalls {
        bursts,
        spun_ns,
        over,
        longest_ns: longest.iter().map(|(gap, ())| *gap).collect(),
        taken_ns,
        stolen_ns,
        steered: reservation.interrupts.as_ref().map(|s| (s.moved(), s.kept_by_kernel)),
    })
}

/// The steal time the kernel has accounted to `cpu` (all CPUs when
/// unpinned) since boot, from `/proc/stat`; `None` where it is not there.
fn steal_ns(cpu: Option<usize>) -> Option<u64> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let label = cpu.map_or("cpu".to_owned(), |c| format!("cpu{c}"));
    let ticks_per_s = nix::unistd::sysconf(nix::unistd::SysconfVar::CLK_TCK).ok()??;
    stat.lines()
        .find_map(|line| line.split_whitespace().next().filter(|l| *l == label).map(|_| line))
        .and_then(steal_ticks)
        .map(|ticks| ticks * 1_000_000_000 / ticks_per_s.max(1) as u64)
}

/// The steal field (the eighth number) of a `/proc/stat` CPU line.
fn steal_ticks(line: &str) -> Option<u64> {
    line.split_whitespace().nth(8)?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steal_is_the_eighth_figure_of_a_cpu_line() {
        assert_eq!(
            steal_ticks("cpu1 2892539 0 176171 2328298 28979 0 5413 986 0 0"),
            Some(986)
        );
        assert_eq!(steal_ticks("cpu1 1 2 3"), None);
    }
}
