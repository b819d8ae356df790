//! `hydractl can`: the machine's CAN bus as the config describes it.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Subcommand;
use hydractl_config::Config;

use crate::emit;

#[derive(Subcommand)]
pub enum CanCommand {
    /// The frames of one period, their bus time at the bitrate (stuffing at
    /// its worst), and the load; says whether they fit the loop's period.
    Budget {
        /// Config with a `[can]` table (default: the built-in one's `[can]` defaults).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Print JSON: {"bitrate", "period_us", "frames": [{"frame", "cob_id", "bytes", "bits_min",
        /// "bits_max", "time_max_us"}], "heartbeat_bits_per_period", "time_max_us", "load_percent_max",
        /// "max_bus_load_percent", "fits", "shortest_period_us"}.
        #[arg(long)]
        json: bool,
    },
}

pub fn run(command: CanCommand) -> Result<()> {
    match command {
        CanCommand::Budget { config, json } => budget(config, json),
    }
}

fn budget(path: Option<PathBuf>, json: bool) -> Result<()> {
    // A config whose frames do not fit is refused at load, with the
    // budget that shows why.
    let config = match Config::load_or_default(path.as_deref()) {
        Ok(config) => config,
        Err(hydractl_config::ConfigError::CanBudget { path, table }) => {
            if !json {
                emit(&table)?;
            }
            bail!("config {}: one period's frames do not fit the bus", path.display());
        }
        Err(e) => return Err(e.into()),
    };
    let can = config.can.clone().unwrap_or_default();
    let profile = can.resolve().context("[can]")?;
    let budget = profile.budget((1e9 / config.timing.control_rate_hz) as u64);
    if json {
        emit(&serde_json::to_string_pretty(&budget)?)
    } else {
        emit(&budget.table())
    }
}
