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
    /// Write every frame of the run's virtual bus in can-utils `candump -l`
    /// format, `(SECONDS.MICROS) IFACE ID#DATA`, until Ctrl-C or `--duration`.
    Dump {
        /// Config naming the bus (`[can] interface`) [default: vcan0].
        #[arg(long)]
        config: Option<PathBuf>,
        /// The log file [default: standard output].
        #[arg(long)]
        log: Option<PathBuf>,
        /// Stop after this many seconds.
        #[arg(long)]
        duration: Option<f64>,
    },
    /// Send a candump log onto the run's virtual bus with its timing (as
    /// can-utils' `canplayer`), whatever interface the log names.
    Replay {
        file: PathBuf,
        /// Config naming the bus (`[can] interface`) [default: vcan0].
        #[arg(long)]
        config: Option<PathBuf>,
    },
}

pub fn run(command: CanCommand) -> Result<()> {
    match command {
        CanCommand::Budget { config, json } => budget(config, json),
        CanCommand::Dump { config, log, duration } => dump(config, log, duration),
        CanCommand::Replay { file, config } => replay(&file, config),
    }
}

/// The run's virtual bus: the config's interface, and a station on it.
fn open_virtual_bus(config: Option<PathBuf>, node: &str) -> Result<(hydractl_bus::Bus, String)> {
    let config = Config::load_or_default(config.as_deref())?;
    let interface = config.can.unwrap_or_default().interface;
    hydractl_bus::quiet_ipc_logging();
    let scope = hydractl_bus::RunScope::from_env()?;
    if !scope.live_node_names()?.iter().any(|n| n == "canbus") {
        bail!(
            "no virtual CAN bus is running under prefix `{}`: start a run whose config has a [can] table \
             (or set {} to that run's prefix)",
            scope.prefix(),
            hydractl_bus::PREFIX_ENV
        );
    }
    let bus = hydractl_bus::Bus::open(&scope, node).with_context(|| format!("{node}: opening the bus"))?;
    Ok((bus, interface))
}

fn dump(config: Option<PathBuf>, log: Option<PathBuf>, duration: Option<f64>) -> Result<()> {
    use hydractl_canio::{CanPort, VirtualCanPort};
    use std::io::Write;
    if duration.is_some_and(|d| !(d.is_finite() && d > 0.0)) {
        bail!("--duration must be a positive number of seconds");
    }
    let (bus, interface) = open_virtual_bus(config, "candump")?;
    let port = VirtualCanPort::monitor(&bus, &interface)?;
    let mut out: Box<dyn Write> = match &log {
        Some(path) => Box::new(std::io::BufWriter::new(
            std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?,
        )),
        None => Box::new(std::io::BufWriter::new(std::io::stdout().lock())),
    };
    // Frames carry the monotonic clock; a candump log the wall clock.
    let wall_now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .context("the wall clock is before 1970")?
        .as_nanos() as u64;
    let epoch_offset = wall_now.saturating_sub(hydractl_bus::clock::now_ns());
    let end = duration.map(|d| std::time::Instant::now() + std::time::Duration::from_secs_f64(d));
    let mut failure = None;
    let inputs = [port.input()];
    hydractl_bus::run_until(
        &inputs,
        &bus,
        || end,
        |wake| {
            if wake == hydractl_bus::Wake::Tick {
                return hydractl_bus::Flow::Stop;
            }
            hydractl_bus::guarded(&mut failure, || -> Result<()> {
                while let Some(received) = port.receive()? {
                    writeln!(
                        out,
                        "{}",
                        hydractl_can::candump::line(received.time_ns + epoch_offset, &interface, &received.frame)
                    )?;
                }
                out.flush()?;
                Ok(())
            })
        },
    )?;
    out.flush()?;
    failure.map_or(Ok(()), Err)
}

fn replay(file: &std::path::Path, config: Option<PathBuf>) -> Result<()> {
    use hydractl_canio::{CanPort, VirtualCanPort};
    let text = std::fs::read_to_string(file).with_context(|| format!("cannot read {}", file.display()))?;
    let frames = hydractl_can::candump::parse(&text).with_context(|| file.display().to_string())?;
    let Some(first) = frames.first() else {
        bail!("{}: no frames (candump lines start with `(`)", file.display());
    };
    let (bus, interface) = open_virtual_bus(config, "canplayer")?;
    let port = VirtualCanPort::open(&bus, &interface, &[])?;
    let start = std::time::Instant::now();
    for logged in &frames {
        // A log whose stamps go back sends at once, as canplayer does.
        let due = start + std::time::Duration::from_nanos(logged.time_ns.saturating_sub(first.time_ns));
        // In slices, so that Ctrl-C in a long gap of the log is heard.
        loop {
            if bus.termination_requested() {
                bail!("interrupted");
            }
            let left = due.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                break;
            }
            std::thread::sleep(left.min(std::time::Duration::from_millis(100)));
        }
        port.send(&logged.frame)?;
    }
    let span = frames.last().map_or(0, |l| l.time_ns.saturating_sub(first.time_ns)) as f64 / 1e9;
    tracing::info!(
        "replayed {} frames over {span:.3} s from {} onto the virtual bus {interface}",
        frames.len(),
        file.display()
    );
    Ok(())
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
