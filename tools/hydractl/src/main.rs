//! `hydractl`: the command line of the hydraulic rotator control stack.
//!
//! What it holds: The command line (every command in its `README.md`, the
//! benchmarks' figures in `BENCHMARKS.md`; `run/monitor.rs`: what `run` makes
//! of the samples, latency histograms, the tracking error over the last
//! second and since the start, the live line; `run/summary.rs`, the summary's
//! parts; `run/recording.rs`, the recording read back; `run/valve_faults.rs`;
//! `run/virtual_machine.rs`, the virtual bus's wire and ECUs): `run`, `sim`
//! (also `--valve-steps`), `plant`, `effects`, `linearize`, `ident
//! tf/mech/spectrum/friction-map/pid-iae`, `model
//! fit/compare/diagnose/add/report/compensate` (the report's plots by
//! `plotters`; data from CSV or MCAP; `progress.rs`: `indicatif` bars for
//! long work, on a terminal only), `swap`, `status`, `valve reset`
//! (`control.rs`), `record`, `replay`, `mcap info`, `mcap export-csv`, `mcap
//! export-candump`, `bench sim`, `bench latency`, `bench diagnose`, `bench
//! foreign`, `bench record`, `bench stalls`, `bench syscalls` (`strace -c`
//! attached to each stage of `bench latency`'s chain), `can
//! budget/dump/replay`, `doctor` (`doctor.rs`: the computer against the
//! config, check by check, read from `/proc`, `/sys`, `/dev` under a root
//! that tests point at fixture trees). `debian/`: the package's unit,
//! maintainer script, system user and udev rule (`[package.metadata.deb]` in
//! its `Cargo.toml`).

mod bench_latency;
mod bench_record;
mod bench_stalls;
mod bench_syscalls;
mod can;
mod control;
mod doctor;
mod ident;
mod ident_hinf;
mod model;
mod progress;
mod recording;
mod reference;
mod report;
mod run;
mod slowest;

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use hydractl_config::{Config, Structure};
use hydractl_plant::{Effect, EffectKind};
use hydractl_sim::{simulate, simulate_streaming, simulate_valve_steps, write_csv, CsvRows};

#[derive(Parser)]
#[command(
    name = "hydractl",
    version,
    about = "Control stack for a hydraulic rotary actuator",
    after_help = "Exit status: 0 success; 1 failure (the reason on stderr); 2 usage (bad flags); 3 a run whose recording is incomplete (its summary says what is missing)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Log filter for hydractl and every process it starts (`info`,
    /// `debug`, `warn,hydractl=debug`); before `RUST_LOG` and a config's
    /// `[log] level`.
    #[arg(long, global = true, value_name = "FILTER")]
    log_level: Option<String>,
    /// The folder of the process binaries (`supervisor`, the stages)
    /// [default: beside hydractl, else the installed ../lib/hydractl].
    #[arg(long, global = true, value_name = "DIR", env = hydractl_bus::PROCESS_DIR_ENV)]
    process_dir: Option<PathBuf>,
}

#[derive(Subcommand)]
enum Command {
    /// Run the whole stack live: every stage its own process over iceoryx2,
    /// on the simulated plant, supervised.
    Run(run::RunArgs),
    /// Run the closed loop offline, in one process, as fast as the CPU allows.
    Sim(SimArgs),
    /// List the effect catalog: names, keys, defaults and units.
    Effects,
    /// The baseline plant's linear model from valve command to an output:
    /// transfer function, poles with natural frequency and damping, DC gain.
    Linearize(LinearizeArgs),
    /// Identification from measured data.
    #[command(subcommand)]
    Ident(ident::IdentCommand),
    /// The grey-box model against measurements: fit, compare, diagnose, add an effect, report.
    #[command(subcommand)]
    Model(model::ModelCommand),
    /// Swap a controller variant while the loop runs: `swap position mfc`, `swap torque hinf`, back with `pid`.
    Swap(control::SwapArgs),
    /// Move the running loop to the simulated plant (`plant sim`) or back to the machine (`plant machine`).
    Plant(control::PlantArgs),
    /// The running stack: processes, pids, variants in charge, health, restarts, plant.
    Status(control::StatusArgs),
    /// The machine's valve on CAN: `valve reset` clears its latched fault, a person's deliberate act.
    Valve(control::ValveArgs),
    /// Attach a recorder to the run already alive: every sample to MCAP.
    Record(recording::RecordArgs),
    /// Republish a recording's samples on their services.
    Replay(recording::ReplayArgs),
    /// Read recordings.
    #[command(subcommand)]
    Mcap(recording::McapCommand),
    /// The machine's CAN bus: a period's frame budget, and the run's virtual bus dumped or replayed.
    #[command(subcommand)]
    Can(can::CanCommand),
    /// Whether this computer can hold the config's loop: kernel, CPU,
    /// limits, memory, CAN interfaces, binaries; pass, warn or fail with
    /// the fix for each (exit 0 when ready, 1 when not).
    Doctor(doctor::DoctorArgs),
    /// Benchmarks.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// A stage process of `bench latency` (started by it).
    #[command(hide = true)]
    BenchStage(bench_latency::StageArgs),
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
    #[arg(long, required_unless_present = "valve_steps")]
    duration: Option<f64>,
    /// Instead of the closed loop, the crane paper's friction experiment,
    /// open loop: the valve command stepped through ±STEP, ±2·STEP, … up
    /// to ±1, each held for `--dwell` s (for `ident friction-map`).
    #[arg(long, value_name = "STEP", conflicts_with_all = ["duration", "controller", "summary_json"])]
    valve_steps: Option<f64>,
    /// How long each valve step is held, s.
    #[arg(long, default_value_t = 2.0, requires = "valve_steps")]
    dwell: f64,
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

#[derive(clap::Args)]
struct LinearizeArgs {
    /// Configuration file [default: the built-in config/sim.toml]
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output of the transfer function.
    #[arg(long, value_enum, default_value_t = LinearOutput::Torque)]
    output: LinearOutput,
    /// Print JSON: {"output", "num", "den", "poles": [{"re", "im", "natural_frequency_rad_s", "damping"}], "dc_gain"}.
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, ValueEnum)]
enum LinearOutput {
    Torque,
    Angle,
    Velocity,
    PA,
    PB,
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
    /// Wall time of `model diagnose` over the whole catalog, by data length,
    /// and of `model learn` on 60 s of a foreign plant with two effects.
    Diagnose {
        /// Data lengths to time, s of 1 kHz data.
        #[arg(long, value_delimiter = ',', default_values_t = [15.0, 30.0, 60.0])]
        durations: Vec<f64>,
        #[arg(long, default_value_t = 3)]
        repeat: usize,
    },
    /// `model diagnose` on plants simulated apart from the model (parameters
    /// ±40 % from the prior, other noise, a transducer lag, supply ripple,
    /// quadratic friction, their own controller), with one hidden effect
    /// or none: how often the hidden effect is named, and false alarms;
    /// with several hidden, `model learn`: how often it adds every one.
    Foreign {
        /// Plants per case.
        #[arg(long, default_value_t = 20)]
        plants: usize,
        /// Seconds of 1 kHz data per plant.
        #[arg(long, default_value_t = 60.0)]
        duration: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Cases to run: `none`, effect names, effects hidden together as
        /// `A+B`, and `pairs` for every pair [default: none and each effect alone].
        #[arg(long, value_delimiter = ',')]
        effects: Vec<String>,
        /// Print JSON: {"duration_s", "seed", "cases": [{"hidden", "truth" (per effect), "plants", "named_first",
        /// "within_25_percent", "goal" (several hidden), "any_significant", "runs": [{"seed", "plant", "first",
        /// "first_significant", "significant", "fitted" (per effect), "stop" (several hidden), "seconds"}]}]}.
        #[arg(long)]
        json: bool,
        /// Also write each plant's data to DIR/<case>-<seed>.csv
        /// (the columns diagnosed), for `model diagnose` and other tools,
        /// and its diagnosis to DIR/<case>-<seed>.json (as `model diagnose --json`).
        #[arg(long, value_name = "DIR")]
        save_data: Option<std::path::PathBuf>,
        /// The sensors the machine has: `full` (valve command, both chamber
        /// pressures, angle) or `motion` (valve command and angle only).
        #[arg(long, value_enum, default_value_t = model::ForeignSensors::Full)]
        sensors: model::ForeignSensors,
        /// Sample rate of the data diagnosed, Hz: the simulation's 1 kHz
        /// taken every 1000/RATE samples (RATE divides 1000).
        #[arg(long, default_value_t = 1000)]
        rate: u32,
    },
    /// Sensor-to-valve latency of the five stages over iceoryx2 between
    /// processes, over UDP loopback between processes, and as function calls.
    Latency(bench_latency::LatencyArgs),
    /// System calls per hop of the loop's live-stack transport, counted by
    /// strace attached to each stage.
    Syscalls(bench_syscalls::SyscallsArgs),
    /// Sustained recording throughput against the mcap crate's raw write speed.
    Record(bench_record::RecordBenchArgs),
    /// How long this computer takes the loop's CPU away from a process
    /// nothing may preempt (SCHED_FIFO 99): the floor under any deadline.
    Stalls(bench_stalls::StallsArgs),
}

/// Writes to stdout; a reader that closed the pipe early (`| head`) ends
/// the output quietly instead of failing.
pub(crate) fn emit(text: &str) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

/// The exit status of a run whose recording is incomplete.
const EXIT_RECORDING_INCOMPLETE: u8 = 3;

fn main() -> std::process::ExitCode {
    match run_command() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if e.is::<run::RecordingIncomplete>() => {
            tracing::error!("{e}");
            std::process::ExitCode::from(EXIT_RECORDING_INCOMPLETE)
        }
        Err(e) => {
            // One line for a user; the chain with its backtrace when asked
            // for with `--log-level debug`.
            if tracing::enabled!(tracing::Level::DEBUG) {
                eprintln!("Error: {e:?}");
            } else {
                eprintln!("Error: {}", one_line(&e));
            }
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, `a: b: c`, each cause left out
/// when the message before already says it ("cannot read x: No such file
/// or directory" is not followed by "No such file or directory" again).
fn one_line(error: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line += ": ";
        }
        line += &text;
    }
    line
}

fn run_command() -> Result<()> {
    let cli = Cli::parse();
    let log = hydractl_config::LogConfig::default();
    let filter = hydractl_processes::logging::filter(cli.log_level.as_deref(), &log).map_err(anyhow::Error::msg)?;
    let _log_span = hydractl_processes::logging::init("hydractl", filter, &log);
    // The processes hydractl starts inherit both.
    if let Some(level) = &cli.log_level {
        std::env::set_var("RUST_LOG", level);
    }
    if let Some(dir) = &cli.process_dir {
        std::env::set_var(hydractl_bus::PROCESS_DIR_ENV, dir);
    }
    match cli.command {
        Command::Run(args) => run::run(args),
        Command::Sim(args) => run_sim(args),
        Command::Effects => emit(&effects_table()),
        Command::Linearize(args) => linearize(args),
        Command::Ident(command) => ident::run(command),
        Command::Model(command) => model::run(command),
        Command::Swap(args) => control::swap(args),
        Command::Plant(args) => control::plant(args),
        Command::Status(args) => control::status(args),
        Command::Valve(args) => control::valve(args),
        Command::Record(args) => recording::record(args),
        Command::Replay(args) => recording::replay(args),
        Command::Mcap(command) => recording::mcap(command),
        Command::Can(command) => can::run(command),
        Command::Doctor(args) => doctor::doctor(args),
        Command::Bench(BenchCommand::Sim { duration, repeat }) => bench_sim(duration, repeat),
        Command::Bench(BenchCommand::Diagnose { durations, repeat }) => model::bench_diagnose(&durations, repeat),
        Command::Bench(BenchCommand::Foreign {
            plants,
            duration,
            seed,
            effects,
            json,
            save_data,
            sensors,
            rate,
        }) => model::bench_foreign(
            model::ForeignBench {
                plants,
                duration,
                seed,
                sensors,
                rate,
            },
            &effects,
            json,
            save_data.as_deref(),
        ),
        Command::Bench(BenchCommand::Latency(args)) => bench_latency::bench(args),
        Command::Bench(BenchCommand::Syscalls(args)) => bench_syscalls::bench(args),
        Command::Bench(BenchCommand::Record(args)) => bench_record::bench(args),
        Command::Bench(BenchCommand::Stalls(args)) => bench_stalls::bench(args),
        Command::BenchStage(args) => bench_latency::stage(args),
    }
}

fn load_config(path: Option<&Path>) -> Result<Config> {
    Ok(Config::load_or_default(path)?)
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
    if let Some(step) = args.valve_steps {
        if !(step.is_finite() && step > 0.0 && step <= 1.0) {
            anyhow::bail!("--valve-steps {step}: the step must be in (0, 1]");
        }
        let count = (1.0 / step + 1e-9).floor() as usize;
        let levels: Vec<f64> = (1..=count)
            .flat_map(|k| [k as f64 * step, -(k as f64) * step])
            .collect();
        let records = simulate_valve_steps(&config, &effects, &levels, args.dwell)?;
        if let Some(out) = &args.out {
            write_csv(&records, out)?;
        }
        return emit(&format!(
            "{} valve steps of {} s each, open loop, {} effect(s): {} rows{}\n",
            levels.len(),
            args.dwell,
            effects.len(),
            records.len(),
            args.out
                .as_ref()
                .map_or(String::new(), |o| format!(" to {}", o.display()))
        ));
    }
    let duration = args.duration.context("--duration is required")?;
    // Rows go to the CSV as they are made: memory does not grow with the run.
    let progress = progress::Progress::new("sim", false);
    let whole_seconds = duration.ceil() as usize;
    let mut next_second = 0.0;
    let mut shown = |t: f64| {
        if t >= next_second {
            progress.step("simulated seconds", t as usize, whole_seconds);
            next_second = t.floor() + 1.0;
        }
    };
    let s = &match &args.out {
        Some(out) => {
            let mut rows = CsvRows::create(out)?;
            let summary = simulate_streaming(&config, &effects, duration, |r| {
                shown(r.t);
                rows.write(r)
            })?;
            rows.finish()?;
            summary
        }
        None => simulate_streaming(&config, &effects, duration, |r| {
            shown(r.t);
            Ok(())
        })?,
    };
    drop(progress);
    emit(&format!(
        "{} ({} outer, {} inner), {} effect(s): max |e| = {:.4} rad, rms e = {:.4} rad, torque power > 10 rad/s = {:.1} (N·m)², {:.0} s simulated in {:.3} s: the loop {:.0}× real time, {:.0}× with its output\n",
        s.structure,
        s.position_variant,
        s.torque_variant,
        s.effects.len(),
        s.max_abs_tracking_error_rad,
        s.rms_tracking_error_rad,
        s.torque_power_above_10_rad_s,
        s.sim_seconds,
        s.wall_seconds,
        s.real_time_factor,
        s.real_time_factor_with_output
    ))?;
    if let Some(path) = &args.summary_json {
        let json = serde_json::to_string_pretty(s)?;
        std::fs::write(path, json + "\n").with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

fn linearize(args: LinearizeArgs) -> Result<()> {
    let config = load_config(args.config.as_deref())?;
    let model = hydractl_plant::baseline_linear_model(&config.plant)?;
    let output = args.output as usize;
    let name = hydractl_plant::LINEAR_OUTPUTS[output];
    let tf = model.transfer_function(0, output)?;
    let poles: Vec<serde_json::Value> = tf
        .poles()
        .iter()
        .filter(|p| p.im >= 0.0)
        .map(|p| {
            serde_json::json!({
                "re": p.re,
                "im": p.im,
                "natural_frequency_rad_s": p.norm(),
                "damping": if p.norm() > 0.0 { -p.re / p.norm() } else { 1.0 },
            })
        })
        .collect();
    // An output with an integrator (the angle) has no finite DC gain.
    let scale = tf.poles().iter().fold(1.0_f64, |m, p| m.max(p.norm()));
    let integrating = tf.poles().iter().any(|p| p.norm() < 1e-9 * scale);
    let dc_gain = if integrating { f64::INFINITY } else { tf.dc_gain() };
    if args.json {
        let json = serde_json::json!({
            "output": name,
            "num": tf.num(),
            "den": tf.den(),
            "poles": poles,
            "dc_gain": if dc_gain.is_finite() { serde_json::json!(dc_gain) } else { serde_json::Value::Null },
        });
        return emit(&(serde_json::to_string_pretty(&json)? + "\n"));
    }
    use std::fmt::Write;
    let fmt = |p: &[f64]| p.iter().map(|c| format!("{c:.6e}")).collect::<Vec<_>>().join(", ");
    let mut text = format!("valve command → {name}, baseline plant linearized (SI units)\n");
    writeln!(text, "  num: [{}]", fmt(tf.num()))?;
    writeln!(text, "  den: [{}]", fmt(tf.den()))?;
    for p in &poles {
        writeln!(
            text,
            "  pole {:>10.4} {:+10.4}j   ω_n = {:8.3} rad/s   ζ = {:.3}",
            p["re"].as_f64().unwrap_or(f64::NAN),
            p["im"].as_f64().unwrap_or(f64::NAN),
            p["natural_frequency_rad_s"].as_f64().unwrap_or(f64::NAN),
            p["damping"].as_f64().unwrap_or(f64::NAN)
        )?;
    }
    writeln!(text, "  DC gain: {dc_gain:.6e}")?;
    emit(&text)
}

fn effects_table() -> String {
    let mut text = String::new();
    for kind in EffectKind::ALL {
        text += kind.name();
        text += "\n";
        if kind.params().is_empty() {
            text += "    (no parameters)\n";
        }
        for p in kind.params() {
            text += &format!(
                "    {:<18} default {:<10} {:<10} {}\n",
                p.key, p.default, p.unit, p.meaning
            );
        }
    }
    text
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
    emit(&format!(
        "bench sim: default plant, cascade, {} kHz integration, {} kHz control, {duration} s × {}: \
         simulated s per wall s: median {median:.0}, min {:.0}, max {:.0}\n",
        config.timing.integration_rate_hz / 1000.0,
        config.timing.control_rate_hz / 1000.0,
        factors.len(),
        factors[0],
        factors[factors.len() - 1]
    ))
}
