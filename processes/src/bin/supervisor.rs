//! The watchdog process: wires the supervisor (`hydractl_processes::supervisor`)
//! to its node, ticks it every 5 ms until SIGTERM or SIGINT, then stops
//! every process and removes every file of the run.

use std::time::{Duration, Instant};

use anyhow::Result;
use hydractl_bus::run_loop;
use hydractl_processes::supervisor::Supervisor;

fn main() -> Result<()> {
    let started = hydractl_processes::start("supervisor")?;
    tracing::info!(
        config = %started.args.config.as_deref().map_or("built-in sim.toml".into(), |p| p.display().to_string()),
        prefix = started.bus.scope().prefix(),
        "hydractl {} supervising the loop ({})",
        env!("CARGO_PKG_VERSION"),
        if started.config.machine.is_some() { "on the machine, the simulated plant standing by" } else { "on the simulated plant" }
    );
    // For the whole run: the loop's stages wake at every hop, and nothing
    // but the loop should take its CPU.
    let timing = &started.config.timing;
    let (_reservation, refusals) = hydractl_rt::reserve_for_run(
        timing.loop_cpu,
        timing.cpu_dma_latency_us,
        timing.interrupts_off_loop_cpu,
    );
    for e in refusals {
        tracing::warn!("{e}");
    }
    // Over what a crashed run left: its dead nodes (its files, when nothing
    // of it was alive, `hydractl run` removed before starting us).
    started.bus.scope().remove_dead_nodes()?;
    let mut supervisor = Supervisor::open(&started.bus, &started.config, &started.args)?;
    let mut failure = None;
    let outcome = supervisor.start(&started.bus).and_then(|()| {
        run_loop(&[], Some(Duration::from_millis(5)), &started.bus, |_| {
            hydractl_bus::guarded(&mut failure, || supervisor.tick(&started.bus, Instant::now()))
        })?;
        failure.map_or(Ok(()), Err)
    });
    // Clean up whatever the outcome; report the outcome's error first.
    let stopped = supervisor.stop(started.bus);
    if stopped.is_ok() {
        tracing::info!("every process stopped, the valve's last command neutral");
    }
    outcome.and(stopped)
}
