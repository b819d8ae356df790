//! `hydractl model`: compare the grey-box model with measurements, see where
//! it fails, find the missing physical effect, add it, and watch the error fall.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use hydractl_ident::greybox::{self, FitOptions, Model, Signals};
use hydractl_plant::EffectKind;

use crate::emit;
use crate::progress::Progress;

mod bench;
mod compensate;
mod foreign;
mod learn;

pub use bench::bench_diagnose;
pub use foreign::{bench_foreign, ForeignBench, ForeignSensors};

#[derive(clap::Subcommand)]
pub enum ModelCommand {
    /// Fit the baseline model (and any listed effects) to measured data.
    Fit(FitArgs),
    /// Compare a model with measured data: fit per output, the residual by
    /// sub-model and by regime, and the residual tests.
    Compare(CompareArgs),
    /// Try every effect of the catalog and rank them by the validation error they remove.
    Diagnose(DiagnoseArgs),
    /// Add one effect to a model, refit, and print the error before and after.
    Add(AddArgs),
    /// Diagnose, add the effect found, and again, until nothing of the
    /// catalog helps significantly: the loop of `diagnose` and `add`.
    Learn(learn::LearnArgs),
    /// Write a self-contained HTML page with the plots that show where the model fails.
    Report(ReportArgs),
    /// Write a config whose compensators use what the model learned (the
    /// controllers only: the plant it simulates stays the base config's).
    Compensate(compensate::CompensateArgs),
}

#[derive(clap::Args)]
pub struct DataArgs {
    /// CSV or MCAP: `t` (s) and `theta` (rad), and the valve command `u`
    /// ([-1, 1]), the pressures `p_a`, `p_b` (bar) and a measured torque
    /// `tau` (N·m) where the machine has them. Without pressures the model
    /// is command → angle; with `tau`, the mechanical part alone.
    #[arg(long)]
    pub data: PathBuf,
    /// Share of the data, from its start, used to estimate; the rest validates.
    #[arg(long, default_value_t = 0.7)]
    pub estimation_fraction: f64,
    /// Only the record from this many seconds after its start (a window
    /// of a long recording, read through its index).
    #[arg(long, value_name = "SECONDS", requires = "to")]
    pub from: Option<f64>,
    /// Only the record up to this many seconds after its start.
    #[arg(long, value_name = "SECONDS", requires = "from")]
    pub to: Option<f64>,
}

impl DataArgs {
    fn window(&self) -> Result<Option<hydractl_recording::Window>> {
        match (self.from, self.to) {
            (Some(from_s), Some(to_s)) if from_s >= 0.0 && to_s > from_s => {
                Ok(Some(hydractl_recording::Window { from_s, to_s }))
            }
            (Some(from), Some(to)) => bail!("--from {from} --to {to}: need 0 <= from < to"),
            _ => Ok(None),
        }
    }
}

#[derive(clap::Args)]
pub struct FitArgs {
    #[command(flatten)]
    data: DataArgs,
    /// Effects of the catalog to add after the baseline, in order: NAME,NAME.
    #[arg(long, value_delimiter = ',')]
    effects: Vec<String>,
    /// The prior (data sheet) parameters: a config with a [plant] table
    /// [default: the built-in config/sim.toml].
    #[arg(long)]
    prior: Option<PathBuf>,
    #[arg(long)]
    out: PathBuf,
}

#[derive(clap::Args)]
pub struct CompareArgs {
    #[command(flatten)]
    data: DataArgs,
    #[arg(long)]
    model: PathBuf,
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
pub struct DiagnoseArgs {
    #[command(flatten)]
    data: DataArgs,
    /// The model to improve [default: a baseline fitted here].
    #[arg(long)]
    model: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
pub struct AddArgs {
    /// The effect's catalog name (see `hydractl effects`).
    effect: String,
    #[command(flatten)]
    data: DataArgs,
    #[arg(long)]
    model: PathBuf,
    #[arg(long)]
    out: PathBuf,
}

#[derive(clap::Args)]
pub struct ReportArgs {
    #[command(flatten)]
    data: DataArgs,
    #[arg(long)]
    model: PathBuf,
    #[arg(long)]
    out: PathBuf,
}

pub fn run(command: ModelCommand) -> Result<()> {
    match command {
        ModelCommand::Fit(args) => fit(args),
        ModelCommand::Compare(args) => compare(args),
        ModelCommand::Diagnose(args) => diagnose(args),
        ModelCommand::Add(args) => add(args),
        ModelCommand::Learn(args) => learn::learn(args),
        ModelCommand::Report(args) => crate::report::write(
            &load_signals(&args.data)?,
            &load_model(&args.model)?,
            options(&args.data)?,
            &args.out,
        ),
        ModelCommand::Compensate(args) => compensate::compensate(args),
    }
}

/// Writes `header` (comment lines) and `config` to `out`, once the text
/// loads as the config it is.
pub(crate) fn write_config(out: &std::path::Path, header: String, config: &hydractl_config::Config) -> Result<()> {
    let text = header + "\n" + &config.to_toml();
    hydractl_config::Config::parse(&text, out)
        .with_context(|| format!("the config written to {} does not load", out.display()))?;
    std::fs::write(out, &text).with_context(|| format!("cannot write {}", out.display()))
}

pub fn load_signals(data: &DataArgs) -> Result<Signals> {
    let dataset = crate::recording::load_dataset_in(
        &data.data,
        &greybox::REQUIRED_COLUMNS,
        data.window()?,
        crate::recording::Gaps::LeaveOut,
    )?;
    let signals = Signals::from_dataset(&dataset)?;
    let is_recording = crate::recording::is_recording(&data.data);
    // A recording's gaps were said as they were left out; a file's rows
    // missing are said here.
    if let Some(said) = signals.gaps_said().filter(|_| !is_recording) {
        tracing::warn!("{}: rows are missing: {said}", data.data.display());
    }
    Ok(signals)
}

pub(crate) fn load_model(path: &Path) -> Result<Model> {
    Ok(Model::load(path)?)
}

pub(crate) fn options(data: &DataArgs) -> Result<FitOptions> {
    if !(data.estimation_fraction > 0.1 && data.estimation_fraction < 0.95) {
        bail!(
            "--estimation-fraction {}: must be within (0.1, 0.95)",
            data.estimation_fraction
        );
    }
    Ok(FitOptions {
        estimation_fraction: data.estimation_fraction,
        ..FitOptions::default()
    })
}

fn parse_kind(name: &str) -> Result<EffectKind> {
    Ok(EffectKind::from_name(name.trim())?)
}

fn errors_line(model: &Model) -> String {
    match model.history.last() {
        Some(step) => {
            let outputs: Vec<String> = ["p_a", "p_b", "theta"]
                .iter()
                .filter_map(|o| step.validation_nrmse.get(*o).map(|v| format!("{o} {v:.4}")))
                .collect();
            format!("validation NRMSE: {}", outputs.join(", "))
        }
        None => String::new(),
    }
}

fn fit(args: FitArgs) -> Result<()> {
    let kinds = args.effects.iter().map(|n| parse_kind(n)).collect::<Result<Vec<_>>>()?;
    let options = options(&args.data)?;
    let prior = match &args.prior {
        Some(path) => hydractl_config::Config::load(path)?.plant,
        None => hydractl_config::Config::default_sim()?.plant,
    };
    let signals = load_signals(&args.data)?;
    let progress = Progress::new("model fit", false);
    let steps = 1 + kinds.len();
    progress.step("fitting the baseline", 0, steps);
    let mut model = greybox::fit_baseline(&signals, &prior, options)
        .with_context(|| format!("fitting the baseline to {}", args.data.data.display()))?;
    let mut text = String::new();
    if !signals.has_command {
        text += &format!(
            "{}: no valve command (`u`): the mechanical half is fitted from the measured pressures or torque, the hydraulic half (valve to pressures) stays the prior's\n",
            args.data.data.display()
        );
    }
    text += &format!("baseline: {}\n", errors_line(&model));
    for (i, kind) in kinds.into_iter().enumerate() {
        progress.step(&format!("adding {kind}"), 1 + i, steps);
        model = greybox::fit(&signals, &model, kind, options)
            .with_context(|| format!("adding `{kind}` on {}", args.data.data.display()))?;
        text += &format!("+ {kind}: {}\n", errors_line(&model));
    }
    drop(progress);
    model.save(&args.out)?;
    text += &format!("model written to {}\n", args.out.display());
    emit(&text)
}

fn compare(args: CompareArgs) -> Result<()> {
    let signals = load_signals(&args.data)?;
    let model = load_model(&args.model)?;
    let comparison = greybox::compare(
        &model.plant,
        &model.effects()?,
        &signals,
        options(&args.data)?.estimation_fraction,
    );
    if args.json {
        return emit(&(serde_json::to_string_pretty(&comparison)? + "\n"));
    }
    let mut text = format!(
        "validation {:.1}–{:.1} s ({})\n\n{:<8} {:>8} {:>8}\n",
        comparison.validation_start_s, comparison.validation_end_s, comparison.method, "output", "fit %", "NRMSE"
    );
    for o in &comparison.outputs {
        text += &format!("{:<8} {:>8.2} {:>8.4}\n", o.output, o.fit_percent, o.nrmse);
    }
    text += "\nby sub-model (NRMSE):\n";
    for (name, value) in &comparison.submodels {
        text += &format!("  {name:<24} {value:.4}\n");
    }
    text += "\nby regime (RMS residual / the output's spread):\n";
    let outputs = greybox::measured_outputs(&signals);
    text += &format!("  {:<20} {:>7}", "regime", "samples");
    for output in &outputs {
        text += &format!(" {output:>8}");
    }
    text += "\n";
    for r in &comparison.regimes {
        text += &format!("  {:<20} {:>7}", r.regime, r.samples);
        for output in &outputs {
            text += &format!(" {:>8.4}", r.nrmse.get(*output).copied().unwrap_or(f64::NAN));
        }
        text += "\n";
    }
    text += "\nresidual tests (99% bounds):\n";
    for t in &comparison.residual_tests {
        text += &format!(
            "  {:<6} {:<21} max |r| {:.3} at lag {:>3} (bound {:.3}): {}\n",
            t.output,
            t.test,
            t.max_abs,
            t.lag_of_max,
            t.bound,
            t.outcome()
        );
    }
    text += "  autocorrelation: an output-error model leaves its sensors' filtered noise in the residual, \
             white or not; cross_correlation_u (or _tau, the torque driving a record without a valve command): \
             lags ≥ 1 judged (at ≤ 0 the controller answers the residual), Bartlett's bound\n";
    emit(&text)
}

fn diagnose(args: DiagnoseArgs) -> Result<()> {
    let signals = load_signals(&args.data)?;
    let model = args.model.as_deref().map(load_model).transpose()?;
    let progress = Progress::new("model diagnose", args.json);
    let diagnosis = greybox::diagnose_with(&signals, model.as_ref(), options(&args.data)?, &progress)
        .with_context(|| format!("diagnosing {}", args.data.data.display()))?;
    drop(progress);
    if args.json {
        return emit(&(serde_json::to_string_pretty(&diagnosis)? + "\n"));
    }
    emit(&(diagnosis_table(&diagnosis) + "\n" + &diagnosis.verdict + "\n"))
}

pub fn diagnosis_table(diagnosis: &greybox::Diagnosis) -> String {
    let per_output: Vec<String> = diagnosis
        .baseline
        .fit_percent
        .iter()
        .map(|(output, fit)| format!("{output} {:.4}", 1.0 - fit / 100.0))
        .collect();
    let parts: Vec<&str> = diagnosis.parts.iter().map(|p| p.describe()).collect();
    let mut text = format!("parts fitted: {}\n", parts.join("; "));
    for n in &diagnosis.not_judged {
        text += &format!("not judged: {}: {}\n", n.effect, n.reason);
    }
    text += &format!(
        "baseline, refitted as hard as each candidate: validation NRMSE {:.4}, the RMS of the outputs' ({})\n",
        diagnosis.baseline.validation_nrmse,
        per_output.join(", ")
    );
    for pair in &diagnosis.baseline.uncertainty.inseparable {
        text += &format!("baseline: {pair}\n");
    }
    text += &format!(
        "\n{:<18} {:<10} {:>8} {:>8} {:>6}  {}\n",
        "effect", "output", "before", "after", "sig.", "evidence"
    );
    for c in &diagnosis.candidates {
        text += &format!(
            "{:<18} {:<10} {:>8.4} {:>8.4} {:>6}  {}\n",
            c.effect,
            c.output,
            c.validation_nrmse_before,
            c.validation_nrmse_after,
            if c.significant { "yes" } else { "no" },
            c.evidence
        );
    }
    text
}

fn add(args: AddArgs) -> Result<()> {
    let kind = parse_kind(&args.effect)?;
    let signals = load_signals(&args.data)?;
    let model = load_model(&args.model)?;
    let options = options(&args.data)?;
    // The error before is measured on this data, whatever data the model came from.
    let before = greybox::validation_nrmse(
        &model.plant,
        &model.effects()?,
        &signals,
        signals.split(options.estimation_fraction)..signals.len(),
    );
    let progress = Progress::new("model add", false);
    progress.step(&format!("adding {kind}"), 0, 1);
    let refit = greybox::fit(&signals, &model, kind, options)
        .with_context(|| format!("adding `{kind}` on {}", args.data.data.display()))?;
    drop(progress);
    let after = refit
        .history
        .last()
        .map(|s| s.validation_nrmse.clone())
        .unwrap_or_default();
    refit.save(&args.out)?;
    let mut text = format!("added `{kind}`");
    if let Some(params) = refit.effects.0.get(kind.name()).filter(|p| !p.is_empty()) {
        let list: Vec<String> = params.iter().map(|(k, v)| format!("{k} = {v:.6}")).collect();
        text += &format!(" ({})", list.join(", "));
    }
    text += "\nvalidation NRMSE   before    after\n";
    for output in greybox::measured_outputs(&signals) {
        text += &format!(
            "  {output:<14} {:>8.4} {:>8.4}\n",
            before.get(output).copied().unwrap_or(f64::NAN),
            after.get(output).copied().unwrap_or(f64::NAN)
        );
    }
    text += &format!("model written to {}\n", args.out.display());
    emit(&text)
}
