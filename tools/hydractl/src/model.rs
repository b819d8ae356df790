//! `hydractl model`: compare the grey-box model with measurements, see where
//! it fails, find the missing physical effect, add it, and watch the error fall.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use hydractl_ident::greybox::{self, FitOptions, Model, Signals};
use hydractl_ident::Dataset;
use hydractl_plant::EffectKind;

use crate::emit;
use crate::progress::Progress;

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
    /// Write a self-contained HTML page with the plots that show where the model fails.
    Report(ReportArgs),
    /// Write a config whose compensators use what the model learned (the
    /// controllers only: the plant it simulates stays the base config's).
    Compensate(CompensateArgs),
}

#[derive(clap::Args)]
pub struct CompensateArgs {
    /// The fitted model (`model fit`, `model add`).
    #[arg(long)]
    model: PathBuf,
    /// The config to tune [default: the built-in config/sim.toml].
    #[arg(long)]
    config: Option<PathBuf>,
    /// The tuned config.
    #[arg(long)]
    out: PathBuf,
    /// Print {"out", "changes": [{"key", "from", "to", "effect", "reason"}],
    /// "not_compensated": [{"effect", "reason"}]}.
    #[arg(long)]
    json: bool,
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
        ModelCommand::Report(args) => crate::report::write(
            &load_signals(&args.data.data)?,
            &load_model(&args.model)?,
            options(&args.data)?,
            &args.out,
        ),
        ModelCommand::Compensate(args) => compensate(args),
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

fn compensate(args: CompensateArgs) -> Result<()> {
    let model = load_model(&args.model)?;
    let base = hydractl_config::Config::load_or_default(args.config.as_deref())?;
    let tuned = hydractl_config::compensate::compensate(&base, &model.plant, &model.effects()?);
    let source = args
        .config
        .as_ref()
        .map_or("the built-in config/sim.toml".to_owned(), |p| p.display().to_string());
    let mut text = format!(
        "# Tuned by `hydractl model compensate` from {} on {source}: the controllers\n\
         # use what the model learned; the plant is the base config's.\n",
        args.model.display()
    );
    for change in &tuned.changes {
        text += &format!(
            "# {} = {} (was {}): {}\n",
            change.key, change.to, change.from, change.reason
        );
    }
    write_config(&args.out, text, &tuned.config)?;
    if args.json {
        let json = serde_json::json!({
            "out": args.out,
            "changes": tuned.changes,
            "not_compensated": tuned.not_compensated,
        });
        return emit(&(serde_json::to_string_pretty(&json)? + "\n"));
    }
    let mut out = String::new();
    for change in &tuned.changes {
        out += &format!(
            "{:<44} {:>10} → {:<10} {}: {}\n",
            change.key,
            format!("{:.4}", change.from),
            format!("{:.4}", change.to),
            change.effect,
            change.reason
        );
    }
    if tuned.changes.is_empty() {
        out += "no compensator changed: the model has no effect a compensator answers\n";
    }
    for n in &tuned.not_compensated {
        out += &format!("not compensated: {}: {}\n", n.effect, n.reason);
    }
    out += &format!("tuned config written to {}\n", args.out.display());
    emit(&out)
}

pub fn load_signals(path: &Path) -> Result<Signals> {
    let data = crate::recording::load_dataset(path, &greybox::REQUIRED_COLUMNS)?;
    Ok(Signals::from_dataset(&data)?)
}

fn load_model(path: &Path) -> Result<Model> {
    Ok(Model::load(path)?)
}

fn options(data: &DataArgs) -> Result<FitOptions> {
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
    let signals = load_signals(&args.data.data)?;
    let progress = Progress::new("model fit", false);
    let steps = 1 + kinds.len();
    progress.step("fitting the baseline", 0, steps);
    let mut model = greybox::fit_baseline(&signals, &prior, options)
        .with_context(|| format!("fitting the baseline to {}", args.data.data.display()))?;
    let mut text = format!("baseline: {}\n", errors_line(&model));
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
    let signals = load_signals(&args.data.data)?;
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
    let signals = load_signals(&args.data.data)?;
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
    let signals = load_signals(&args.data.data)?;
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

/// A simulated run as the model tools see a CSV of it.
pub fn signals_from_records(records: &[hydractl_sim::Record]) -> Result<Signals> {
    let column = |f: fn(&hydractl_sim::Record) -> f64| records.iter().map(f).collect::<Vec<f64>>();
    let data = Dataset::from_columns(
        "simulated",
        vec![
            ("t", column(|r| r.t)),
            ("u", column(|r| r.u)),
            ("p_a", column(|r| r.p_a)),
            ("p_b", column(|r| r.p_b)),
            ("theta", column(|r| r.theta)),
        ],
    );
    Ok(Signals::from_dataset(&data)?)
}

/// `hydractl bench diagnose`: wall time of `diagnose` over the whole catalog
/// on closed-loop data with a hidden dead-zone, for several data lengths.
pub fn bench_diagnose(durations: &[f64], repeat: usize) -> Result<()> {
    let config = hydractl_config::Config::default_sim()?;
    let hidden = hydractl_plant::Effect::parse("deadzone")?;
    let mut text = format!(
        "bench diagnose: the whole catalog ({} effects), 1 kHz closed-loop data with a hidden dead-zone, the candidates on {} threads, median of {}\n",
        EffectKind::ALL.len(),
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        repeat.max(1)
    );
    for &duration in durations {
        let run = hydractl_sim::simulate(&config, &[hidden], duration)?;
        let signals = signals_from_records(&run.records)?;
        let mut times = Vec::new();
        let mut first = String::new();
        for _ in 0..repeat.max(1) {
            let start = std::time::Instant::now();
            let diagnosis = greybox::diagnose(&signals, None, FitOptions::default())?;
            times.push(start.elapsed().as_secs_f64());
            first = diagnosis
                .candidates
                .first()
                .map(|c| c.effect.clone())
                .unwrap_or_default();
        }
        times.sort_by(f64::total_cmp);
        let median = times[times.len() / 2];
        text += &format!(
            "  {duration:>5.0} s of data: {median:.2} s (min {:.2}, max {:.2}), {:.0} ms per data second; ranked first: {first}\n",
            times[0],
            times[times.len() - 1],
            1e3 * median / duration
        );
    }
    emit(&text)
}

/// The sensors a foreign plant's machine is given.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ForeignSensors {
    /// Valve command, both chamber pressures, angle.
    Full,
    /// Valve command and angle: a machine without pressure transducers;
    /// the orifice flow, which only the pressures show, is not hidden.
    Motion,
    /// A measured torque and the angle: an axis whose torque is sensed; the
    /// valve's effects cannot show, and only the load's are hidden.
    Torque,
}

impl ForeignSensors {
    /// The same sensors as the foreign plants name them.
    fn sensors(self) -> hydractl_sim::foreign::Sensors {
        use hydractl_sim::foreign::Sensors;
        match self {
            ForeignSensors::Full => Sensors::Full,
            ForeignSensors::Motion => Sensors::Motion,
            ForeignSensors::Torque => Sensors::Torque,
        }
    }

    /// Whether a record of these sensors can show `hidden` at all (as
    /// `diagnose` judges a record's parts), or why not.
    fn can_show(self, hidden: Option<hydractl_sim::foreign::Hidden>) -> Result<(), String> {
        let Some(hidden) = hidden else { return Ok(()) };
        let columns = self.sensors().columns();
        let has_command = columns.contains(&"u");
        let parts = greybox::parts_measured(
            has_command,
            columns.contains(&"p_a") && columns.contains(&"p_b"),
            columns.contains(&"tau"),
        );
        let kind = EffectKind::from_name(hidden.name()).map_err(|e| e.to_string())?;
        greybox::part_showing(&parts, has_command, kind).map(|_| ())
    }
}

/// What `bench foreign` simulates and diagnoses.
#[derive(Debug, Clone, Copy)]
pub struct ForeignBench {
    pub plants: usize,
    pub duration: f64,
    pub seed: u64,
    pub sensors: ForeignSensors,
    /// Hz; divides 1000.
    pub rate: u32,
}

/// A foreign plant's dataset as a CSV file, in the model tools' column
/// order, for `model diagnose` and other tools.
fn save_dataset(path: &std::path::Path, dataset: &Dataset) -> Result<()> {
    let columns: Vec<(&str, &[f64])> = ["t", "u", "p_a", "p_b", "tau", "theta"]
        .into_iter()
        .filter_map(|name| dataset.column(name).ok().map(|c| (name, c)))
        .collect();
    let mut writer = csv::Writer::from_path(path).with_context(|| format!("cannot write {}", path.display()))?;
    writer.write_record(columns.iter().map(|(name, _)| *name))?;
    for k in 0..dataset.len() {
        writer.write_record(columns.iter().map(|(_, c)| c[k].to_string()))?;
    }
    writer
        .flush()
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// One foreign plant diagnosed.
#[derive(serde::Serialize)]
struct ForeignRun {
    seed: u64,
    plant: String,
    first: String,
    first_significant: bool,
    significant: Vec<String>,
    /// The hidden effect's main parameter as fitted, when it was tried.
    fitted: Option<f64>,
    seconds: f64,
}

#[derive(serde::Serialize)]
struct ForeignCase {
    hidden: String,
    /// The hidden effect's main parameter: key and true value (none for
    /// an effect without one, such as `orifice_flow`).
    truth: Option<(String, f64)>,
    plants: usize,
    /// Hidden effect ranked first and called significant.
    named_first: usize,
    /// …with its main parameter within 25 % of the truth (an effect
    /// without a parameter: as `named_first`).
    within_25_percent: usize,
    /// Any effect called significant (with none hidden: false alarms).
    any_significant: usize,
    runs: Vec<ForeignRun>,
}

/// `bench foreign`: diagnose on plants simulated apart from the model.
pub fn bench_foreign(
    bench: ForeignBench,
    only: &[String],
    json: bool,
    save_data: Option<&std::path::Path>,
) -> Result<()> {
    let ForeignBench {
        plants,
        duration,
        seed,
        sensors,
        rate,
    } = bench;
    if rate == 0 || 1000 % rate != 0 {
        bail!(
            "--rate {rate}: the simulation runs at 1000 Hz; give a rate that divides it (1000, 500, 200, 100, 50, …)"
        );
    }
    let every = (1000 / rate) as usize;
    if let Some(dir) = save_data {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    use hydractl_sim::foreign::{foreign_plant, Hidden};
    let mut all_cases: Vec<Option<Hidden>> = vec![None];
    all_cases.extend(Hidden::all().into_iter().map(Some));
    let name = |h: &Option<Hidden>| h.map_or("none", |h| h.name()).to_owned();
    if plants > 1000 {
        bail!("--plants {plants}: at most 1000 per case (each case draws from its own thousand seeds)");
    }
    let known: Vec<String> = all_cases.iter().map(name).collect();
    if let Some(unknown) = only.iter().find(|o| !known.contains(o)) {
        bail!("--effects: `{unknown}` is none of {}", known.join(", "));
    }
    for case in all_cases.iter().filter(|c| only.contains(&name(c))) {
        if let Err(reason) = sensors.can_show(*case) {
            bail!(
                "--effects {}: a record of these sensors cannot show it: {reason}",
                name(case)
            );
        }
    }
    let cases: Vec<Option<Hidden>> = all_cases
        .iter()
        .filter(|c| only.is_empty() || only.contains(&name(c)))
        .filter(|c| sensors.can_show(**c).is_ok())
        .copied()
        .collect();
    // A plant's seed depends on its case's place in the whole list, so a
    // case run alone meets the same plants as in the full bench.
    let plant_seed = |hidden: Option<Hidden>, i: usize| {
        let place = all_cases.iter().position(|c| *c == hidden).unwrap_or(0) as u64;
        seed.wrapping_mul(1_000_003).wrapping_add(place * 1000 + i as u64)
    };
    let diagnose_one = |_case: usize, hidden: Option<Hidden>, i: usize| -> Result<ForeignRun> {
        let plant_seed = plant_seed(hidden, i);
        let data = foreign_plant(plant_seed, hidden, duration);
        let description = data.description.clone();
        let dataset = Dataset::from_columns("foreign", data.record(sensors.sensors(), every));
        if let Some(dir) = save_data {
            save_dataset(&dir.join(format!("{}-{plant_seed}.csv", name(&hidden))), &dataset)?;
        }
        let signals = Signals::from_dataset(&dataset)?;
        let start = std::time::Instant::now();
        let diagnosis = greybox::diagnose(&signals, None, FitOptions::default())?;
        let seconds = start.elapsed().as_secs_f64();
        if let Some(dir) = save_data {
            let path = dir.join(format!("{}-{plant_seed}.json", name(&hidden)));
            std::fs::write(&path, serde_json::to_string_pretty(&diagnosis)?)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        let first = diagnosis.candidates.first();
        let fitted = hidden.and_then(|h| {
            let (key, _) = h.main()?;
            diagnosis
                .candidates
                .iter()
                .find(|c| c.effect == h.name())
                .and_then(|c| c.params.get(key).copied())
        });
        Ok(ForeignRun {
            seed: plant_seed,
            plant: description,
            first: first.map(|c| c.effect.clone()).unwrap_or_default(),
            first_significant: first.is_some_and(|c| c.significant),
            significant: diagnosis
                .candidates
                .iter()
                .filter(|c| c.significant)
                .map(|c| c.effect.clone())
                .collect(),
            fitted,
            seconds,
        })
    };
    // Plants are independent: both cores, one diagnosis each.
    let jobs: Vec<(usize, Option<Hidden>, usize)> = cases
        .iter()
        .enumerate()
        .flat_map(|(c, h)| (0..plants).map(move |i| (c, *h, i)))
        .collect();
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(jobs.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: Vec<(usize, Result<ForeignRun>)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let j = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(&(case, hidden, i)) = jobs.get(j) else { break };
                        done.push((j, diagnose_one(case, hidden, i)));
                    }
                    done
                })
            })
            .collect();
        let mut all: Vec<_> = handles
            .into_iter()
            .flat_map(|h| h.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic)))
            .collect();
        all.sort_by_key(|(j, _)| *j);
        all
    });
    let mut summary: Vec<ForeignCase> = cases
        .iter()
        .map(|h| ForeignCase {
            hidden: name(h),
            truth: h.and_then(|h| h.main()).map(|(key, value)| (key.to_owned(), value)),
            plants: 0,
            named_first: 0,
            within_25_percent: 0,
            any_significant: 0,
            runs: Vec::new(),
        })
        .collect();
    for (j, run) in results {
        let (case, hidden, _) = jobs[j];
        let run = run.with_context(|| format!("diagnosing foreign plant {j}"))?;
        let entry = &mut summary[case];
        entry.plants += 1;
        if let Some(h) = hidden {
            if run.first == h.name() && run.first_significant {
                entry.named_first += 1;
                if h.within(run.fitted, 0.25) {
                    entry.within_25_percent += 1;
                }
            }
        }
        if !run.significant.is_empty() {
            entry.any_significant += 1;
        }
        entry.runs.push(run);
    }
    if json {
        return emit(
            &(serde_json::to_string_pretty(
                &serde_json::json!({"duration_s": duration, "seed": seed, "sensors": sensors, "rate_hz": rate, "cases": summary}),
            )? + "\n"),
        );
    }
    let mut text = format!(
        "bench foreign: model diagnose on plants simulated apart from the model ({plants} per case, {duration} s of {rate} Hz data each, {} sensors, seed {seed})\n\
         {:<18} {:>6} {:>12} {:>12} {:>13} {:>10}\n",
        match sensors {
            ForeignSensors::Full => "full (u, p_a, p_b, theta)",
            ForeignSensors::Motion => "motion (u, theta)",
            ForeignSensors::Torque => "torque (tau, theta; the load's effects only)",
        },
        "hidden", "plants", "named first", "param ±25%", "any signif.", "median s"
    );
    for case in &summary {
        let mut times: Vec<f64> = case.runs.iter().map(|r| r.seconds).collect();
        times.sort_by(f64::total_cmp);
        let median = times.get(times.len() / 2).copied().unwrap_or(f64::NAN);
        let (named, within) = match (case.hidden.as_str(), &case.truth) {
            ("none", _) => ("-".to_owned(), "-".to_owned()),
            // No parameter to be within 25 % of: naming it is all.
            (_, None) => (case.named_first.to_string(), "-".to_owned()),
            _ => (case.named_first.to_string(), case.within_25_percent.to_string()),
        };
        text += &format!(
            "{:<18} {:>6} {:>12} {:>12} {:>13} {:>10.2}\n",
            case.hidden, case.plants, named, within, case.any_significant, median
        );
    }
    text += "named first: the hidden effect ranked first and called significant; any signif.: plants on which any effect was called significant (with none hidden, each is a false alarm)\n";
    emit(&text)
}
