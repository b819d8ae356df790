//! `hydractl`: the command line of the hydraulic rotator control stack.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use hydractl_plant::{Effect, EffectKind};
use hydractl_sim::{simulate, write_csv, Config, Structure};

#[derive(Parser)]
#[command(name = "hydractl", version, about = "Control stack for a hydraulic rotary actuator")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the closed loop offline, in one process, as fast as the CPU allows.
    Sim(SimArgs),
    /// List the effect catalog: names, keys, defaults and units.
    Effects,
    /// Benchmarks.
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Clone, Copy, ValueEnum)]
enum ControllerStructure {
    /// The outer position loop drives the valve.
    Position,
    /// Outer position loop → torque reference → inner torque loop → valve.
    Cascade,
}

#[derive(clap::Args)]
struct SimArgs {
    /// Configuration file [default: the built-in config/sim.toml]
    #[arg(long)]
    config: Option<PathBuf>,
    /// Simulated seconds.
    #[arg(long)]
    duration: f64,
    /// Control structure [default: the config's].
    #[arg(long, value_enum)]
    controller: Option<ControllerStructure>,
    /// CSV with one row per control period: t,u,p_a,p_b,theta,theta_ref,...
    #[arg(long)]
    out: Option<PathBuf>,
    /// Switch an effect on in the plant: NAME or NAME:KEY=VALUE,KEY=VALUE (repeatable).
    #[arg(long = "effect", value_name = "NAME:KEY=VALUE,...")]
    effects: Vec<String>,
    /// Sensor noise seed [default: the config's].
    #[arg(long)]
    seed: Option<u64>,
    /// Write the run's summary as JSON.
    #[arg(long)]
    summary_json: Option<PathBuf>,
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Simulated seconds per wall-clock second of the default plant
    /// (10 kHz integration, 1 kHz control, cascade).
    Sim {
        /// Simulated seconds per repetition.
        #[arg(long, default_value_t = 60.0)]
        duration: f64,
        #[arg(long, default_value_t = 5)]
        repeat: usize,
    },
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Sim(args) => run_sim(args),
        Command::Effects => {
            print_effects();
            Ok(())
        }
        Command::Bench(BenchCommand::Sim { duration, repeat }) => bench_sim(duration, repeat),
    }
}

fn load_config(path: Option<&Path>) -> Result<Config> {
    Ok(match path {
        Some(path) => Config::load(path)?,
        None => Config::default_sim()?,
    })
}

fn run_sim(args: SimArgs) -> Result<()> {
    let mut config = load_config(args.config.as_deref())?;
    if let Some(structure) = args.controller {
        config.control.structure = match structure {
            ControllerStructure::Position => Structure::Position,
            ControllerStructure::Cascade => Structure::Cascade,
        };
    }
    if let Some(seed) = args.seed {
        config.simulation.seed = seed;
    }
    let effects = args
        .effects
        .iter()
        .map(|spec| Effect::parse(spec).with_context(|| format!("--effect {spec}")))
        .collect::<Result<Vec<_>>>()?;
    let run = simulate(&config, &effects, args.duration)?;
    if let Some(out) = &args.out {
        write_csv(&run.records, out)?;
    }
    let s = &run.summary;
    println!(
        "{} ({} outer, {} inner), {} effect(s): max |e| = {:.4} rad, rms e = {:.4} rad, torque power > 10 rad/s = {:.1} (N·m)², {:.0} s simulated in {:.3} s ({:.0}× real time)",
        s.structure,
        s.position_variant,
        s.torque_variant,
        s.effects.len(),
        s.max_abs_tracking_error_rad,
        s.rms_tracking_error_rad,
        s.torque_power_above_10_rad_s,
        s.sim_seconds,
        s.wall_seconds,
        s.real_time_factor
    );
    if let Some(path) = &args.summary_json {
        let json = serde_json::to_string_pretty(s)?;
        std::fs::write(path, json + "\n").with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

fn print_effects() {
    for kind in EffectKind::ALL {
        println!("{}", kind.name());
        if kind.params().is_empty() {
            println!("    (no parameters)");
        }
        for p in kind.params() {
            println!(
                "    {:<18} default {:<10} {:<10} {}",
                p.key, p.default, p.unit, p.meaning
            );
        }
    }
}

fn bench_sim(duration: f64, repeat: usize) -> Result<()> {
    let mut config = Config::default_sim()?;
    config.control.structure = Structure::Cascade;
    let mut factors = Vec::with_capacity(repeat);
    for _ in 0..repeat.max(1) {
        let run = simulate(&config, &[], duration)?;
        factors.push(run.summary.real_time_factor);
    }
    factors.sort_by(f64::total_cmp);
    let median = factors[factors.len() / 2];
    println!(
        "bench sim: default plant, cascade, {} kHz integration, {} kHz control, {duration} s × {}: \
         simulated s per wall s: median {median:.0}, min {:.0}, max {:.0}",
        config.timing.integration_rate_hz / 1000.0,
        config.timing.control_rate_hz / 1000.0,
        factors.len(),
        factors[0],
        factors[factors.len() - 1]
    );
    Ok(())
}
