//! What every process does at start-up: read its arguments and config,
//! quiet iceoryx2's logging, open its node in the run's scope.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use hydractl_bus::{placement, quiet_ipc_logging, Bus, RunScope};
use hydractl_samples::SensorSample;
use hydractl_sim::stack::SensorEstimate;
use hydractl_sim::Config;

pub mod supervision;

#[derive(Parser, Debug)]
pub struct ProcessArgs {
    /// Configuration file [default: the built-in config/sim.toml].
    #[arg(long)]
    pub config: Option<PathBuf>,
}

pub struct Started {
    pub config: Config,
    pub bus: Bus,
    pub args: ProcessArgs,
}

/// Parses the arguments, loads the config and opens the node `name`.
pub fn start(name: &str) -> Result<Started> {
    let args = ProcessArgs::parse();
    let config = load_config(args.config.as_ref())?;
    if name == "supervisor" {
        placement::keep_off_loop_cpu(config.timing.loop_cpu);
    } else {
        placement::pin_to_loop_cpu(config.timing.loop_cpu);
    }
    quiet_ipc_logging();
    let scope = RunScope::from_env()?;
    let bus = Bus::open(&scope, name).with_context(|| format!("{name}: opening the bus"))?;
    Ok(Started { config, bus, args })
}

pub fn load_config(path: Option<&PathBuf>) -> Result<Config> {
    Ok(match path {
        Some(path) => Config::load(path)?,
        None => Config::default_sim()?,
    })
}

/// The trajectory's time for a sensor sequence number: the loop's own
/// clock, so that a restarted stage continues the same reference.
pub fn time_of(seq: u64, config: &Config) -> f64 {
    seq as f64 * config.timing.control_period()
}

/// The stages' view of a sensor sample.
pub fn estimate_of(s: &SensorSample) -> SensorEstimate {
    SensorEstimate {
        angle: s.angle,
        velocity: s.velocity,
        p_a: s.p_a,
        p_b: s.p_b,
        torque: s.torque,
    }
}
