//! `hydractl ident`: the papers' identification methods, each a command
//! over measured data (CSV, or a recording).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Subcommand, ValueEnum};
use hydractl_ident::friction_map::friction_map;
use hydractl_ident::mechanics::{mechanics_from_p_control, PControlledRun};
use hydractl_ident::pid_tune::{iae, tune_pid_iae, IaeTuning};
use hydractl_ident::spectral::welch;
use hydractl_lti::TransferFunction;

use crate::emit;
use crate::recording::load_dataset;

pub fn run(command: IdentCommand) -> Result<()> {
    match command {
        IdentCommand::Tf(args) => tf(args),
        IdentCommand::Mech(args) => mech(args),
        IdentCommand::Spectrum(args) => spectrum(args),
        IdentCommand::FrictionMap(args) => pseudo_friction(args),
        IdentCommand::PidIae(args) => pid_iae(args),
        IdentCommand::Hinf(args) => crate::ident_hinf::hinf(args),
    }
}

#[derive(Subcommand)]
pub enum IdentCommand {
    /// A continuous-time transfer function from one column to another.
    Tf(IdentTfArgs),
    /// The mechanics Ĵ, b̂ from P-controlled runs at several gains (rotary
    /// paper, eqs. 13–17).
    Mech(MechArgs),
    /// Welch power spectra and the empirical transfer function, with the
    /// resonance they show.
    Spectrum(SpectrumArgs),
    /// The static pseudo-friction map from steps of valve current (crane
    /// paper, section 3.1).
    FrictionMap(FrictionMapArgs),
    /// PID gains minimizing the IAE of a step on a transfer function
    /// (rotary paper, eq. 19).
    PidIae(PidIaeArgs),
    /// An H∞ loop-shaping torque controller designed for the machine that
    /// made the data (crane paper, section 6.3), written into a config.
    Hinf(crate::ident_hinf::IdentHinfArgs),
}

#[derive(Clone, Copy, ValueEnum)]
enum IdentMethod {
    /// Prediction error: output error first, then G with a second-order Box–Jenkins noise model.
    Pem,
    /// Output error.
    Oe,
}

#[derive(clap::Args)]
pub struct IdentTfArgs {
    /// CSV with a header row, a `t` column and the two columns named below;
    /// or a recording (`.mcap`), whose columns are those of `mcap export-csv`:
    /// `u,p_a,p_b,theta,theta_ref` and the stages' `omega_est`, `torque`,
    /// `blended_velocity`, `friction_comp`, `position_output`, `torque_ref`,
    /// `torque_command`, `valve_requested`.
    #[arg(long)]
    data: PathBuf,
    #[arg(long)]
    input: String,
    #[arg(long)]
    output: String,
    #[arg(long)]
    poles: usize,
    #[arg(long)]
    zeros: usize,
    #[arg(long, value_enum, default_value_t = IdentMethod::Oe)]
    method: IdentMethod,
    /// Share of the data, from its start, used to estimate; the rest validates.
    #[arg(long, default_value_t = 0.7)]
    estimation_fraction: f64,
    /// Print {"num": [...], "den": [...], "fit_percent": X, ...}: continuous
    /// time, descending powers of s, `den` monic.
    #[arg(long)]
    json: bool,
}

fn tf(args: IdentTfArgs) -> Result<()> {
    let data = load_dataset(&args.data, &["t", &args.input, &args.output])?;
    let ts = data.sample_time()?;
    let method = match args.method {
        IdentMethod::Pem => hydractl_ident::Method::Pem,
        IdentMethod::Oe => hydractl_ident::Method::Oe,
    };
    let progress = crate::progress::Progress::new("ident tf", args.json);
    progress.step(&format!("fitting {} → {}", args.input, args.output), 0, 1);
    let fit = hydractl_ident::identify_tf(
        data.column(&args.input)?,
        data.column(&args.output)?,
        ts,
        hydractl_ident::TfOptions {
            poles: args.poles,
            zeros: args.zeros,
            method,
            estimation_fraction: args.estimation_fraction,
        },
    )
    .with_context(|| {
        format!(
            "identifying {} → {} in {}",
            args.input,
            args.output,
            args.data.display()
        )
    })?;
    drop(progress);
    let pairs: Vec<serde_json::Value> = fit
        .tf
        .resonances()
        .iter()
        .map(|(wn, zeta)| serde_json::json!({"natural_frequency_rad_s": wn, "damping": zeta}))
        .collect();
    if args.json {
        let json = serde_json::json!({
            "num": fit.tf.num(),
            "den": fit.tf.den(),
            "fit_percent": fit.fit_percent,
            "warning": tf_fit_warning(fit.fit_percent),
            "estimation_fit_percent": fit.estimation_fit_percent,
            "resonances": pairs,
            "sample_time_s": ts,
            "iterations": fit.iterations,
            "noise_model": fit.noise_model.as_ref().map(|h| serde_json::json!({"c": h.c, "d": h.d})),
        });
        return emit(&(serde_json::to_string_pretty(&json)? + "\n"));
    }
    let fmt = |p: &[f64]| p.iter().map(|c| format!("{c:.6e}")).collect::<Vec<_>>().join(", ");
    let mut text = format!(
        "{} → {}: num [{}], den [{}], fit {:.1}% on validation ({:.1}% on estimation)\n",
        args.input,
        args.output,
        fmt(fit.tf.num()),
        fmt(fit.tf.den()),
        fit.fit_percent,
        fit.estimation_fit_percent
    );
    if let Some(warning) = tf_fit_warning(fit.fit_percent) {
        text += &format!("warning: {warning}\n");
    }
    emit(&text)
}

/// A fit below zero predicts the output worse than its mean does.
fn tf_fit_warning(fit_percent: f64) -> Option<String> {
    (fit_percent < 0.0 || fit_percent.is_nan()).then(|| {
        format!(
            "a fit of {fit_percent:.0}% is worse than predicting the output's mean: this structure (--poles, --zeros, --delay) or this input does not explain this output"
        )
    })
}

#[derive(clap::Args)]
pub struct MechArgs {
    /// A P-controlled run (CSV or recording); repeat, one per gain.
    #[arg(long, required = true)]
    data: Vec<PathBuf>,
    /// The proportional gain of each run, in the order of `--data`.
    #[arg(long, required = true)]
    kp: Vec<f64>,
    #[arg(long, default_value = "theta_ref")]
    reference: String,
    #[arg(long, default_value = "theta")]
    output: String,
    /// 0: θ/r = b₀ / (s² + a₁ s + a₀), eq. 14's structure; 1: eq. 15's, with
    /// a zero that absorbs delays (on a rotator whose valve lags the motion
    /// it absorbs the inertia too).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=1))]
    zeros: u8,
    /// Print {"j_hat", "b_hat", "runs": [{"kp", "num", "den", "fit_percent", "j_hat", "b_hat"}]}.
    #[arg(long)]
    json: bool,
}

fn mech(args: MechArgs) -> Result<()> {
    if args.data.len() != args.kp.len() {
        bail!(
            "{} --data files and {} --kp gains: give one gain per run",
            args.data.len(),
            args.kp.len()
        );
    }
    let mut loaded = Vec::with_capacity(args.data.len());
    let mut ts = None;
    for path in &args.data {
        let data = load_dataset(path, &["t", &args.reference, &args.output])?;
        let run_ts = data.sample_time()?;
        if ts.is_some_and(|t: f64| (t - run_ts).abs() > 1e-9 * t) {
            bail!("{}: sampled every {run_ts} s, unlike the first run", path.display());
        }
        ts = Some(run_ts);
        loaded.push(data);
    }
    let runs = loaded
        .iter()
        .zip(&args.kp)
        .map(|(data, &kp)| {
            Ok(PControlledRun {
                kp,
                reference: data.column(&args.reference)?,
                angle: data.column(&args.output)?,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let estimate = mechanics_from_p_control(&runs, ts.unwrap_or(1e-3), usize::from(args.zeros))
        .context("identifying the mechanics from the P-controlled runs")?;
    if args.json {
        return emit(&(serde_json::to_string_pretty(&estimate)? + "\n"));
    }
    let mut text = String::new();
    for (run, path) in estimate.runs.iter().zip(&args.data) {
        text += &format!(
            "K_p = {}: θ/r = ({:.4e} s + {:.4e}) / (s² + {:.4} s + {:.4}), fit {:.1}%: Ĵ = {:.4e}, b̂ = {:.4e}  ({})\n",
            run.kp,
            if run.num.len() > 1 { run.num[0] } else { 0.0 },
            run.num.last().copied().unwrap_or(0.0),
            run.den[1],
            run.den[2],
            run.fit_percent,
            run.j_hat,
            run.b_hat,
            path.display()
        );
    }
    text += &format!("mean: Ĵ = {:.4e}, b̂ = {:.4e}\n", estimate.j_hat, estimate.b_hat);
    emit(&text)
}

#[derive(clap::Args)]
pub struct SpectrumArgs {
    #[arg(long)]
    data: PathBuf,
    #[arg(long, default_value = "u")]
    input: String,
    #[arg(long)]
    output: String,
    /// Samples per segment (Hamming window, 50% overlap).
    #[arg(long, default_value_t = 4096)]
    segment: usize,
    /// Where to look for the resonance, rad/s: LOW,HIGH.
    #[arg(long, value_delimiter = ',', value_name = "LOW,HIGH", default_values_t = [5.0, 200.0])]
    band: Vec<f64>,
    /// Bins with less coherence are not trusted for the resonance.
    #[arg(long, default_value_t = 0.8)]
    min_coherence: f64,
    /// Write the spectrum as CSV: frequency_rad_s,input_psd,output_psd,gain,phase_deg,coherence.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print {"resonance": {...} | null, "segments", "spectrum": {...}}.
    #[arg(long)]
    json: bool,
}

fn spectrum(args: SpectrumArgs) -> Result<()> {
    let [low, high] = args.band[..] else {
        bail!("--band takes two frequencies LOW,HIGH in rad/s, got {:?}", args.band);
    };
    if !(low >= 0.0 && high > low) {
        bail!("--band {low},{high}: LOW must be at least 0 and below HIGH");
    }
    let data = load_dataset(&args.data, &["t", &args.input, &args.output])?;
    let ts = data.sample_time()?;
    let s = welch(data.column(&args.input)?, data.column(&args.output)?, ts, args.segment)
        .with_context(|| format!("spectral analysis of {}", args.data.display()))?;
    let resonance = s.resonance(low, high, args.min_coherence);
    if let Some(out) = &args.out {
        let mut writer = csv::Writer::from_path(out).with_context(|| format!("cannot write {}", out.display()))?;
        writer.write_record([
            "frequency_rad_s",
            "input_psd",
            "output_psd",
            "gain",
            "phase_deg",
            "coherence",
        ])?;
        for k in 0..s.frequency_rad_s.len() {
            writer.write_record(
                [
                    s.frequency_rad_s[k],
                    s.input_psd[k],
                    s.output_psd[k],
                    s.gain[k],
                    s.phase_deg[k],
                    s.coherence[k],
                ]
                .map(|v| v.to_string()),
            )?;
        }
        writer
            .flush()
            .with_context(|| format!("cannot write {}", out.display()))?;
    }
    if args.json {
        let json = serde_json::json!({"resonance": resonance, "segments": s.segments, "spectrum": s});
        return emit(&(serde_json::to_string_pretty(&json)? + "\n"));
    }
    let resolution = s.frequency_rad_s.first().copied().unwrap_or(f64::NAN);
    emit(&match resonance {
        Some(r) => format!(
            "{} → {}: resonance at {:.1} rad/s (gain {:.4}, {:.2}× the trough below it, coherence {:.2}); {} segments, resolution {:.2} rad/s\n",
            args.input, args.output, r.frequency_rad_s, r.gain, r.prominence, r.coherence, s.segments, resolution
        ),
        None => format!(
            "{} → {}: no resonance between {} and {} rad/s with coherence ≥ {}; {} segments, resolution {:.2} rad/s\n",
            args.input, args.output, low, high, args.min_coherence, s.segments, resolution
        ),
    })
}

#[derive(clap::Args)]
pub struct FrictionMapArgs {
    /// Steps of valve current (`hydractl sim --valve-steps` makes such data).
    #[arg(long)]
    data: PathBuf,
    #[arg(long, default_value = "u")]
    input: String,
    #[arg(long, default_value = "theta")]
    output: String,
    /// Steps shorter than this, s, are skipped.
    #[arg(long, default_value_t = 0.5)]
    min_step: f64,
    /// Print {"points": [...], "velocity": [...], "output": [...], "positive": {...}, "negative": {...}}.
    #[arg(long)]
    json: bool,
}

fn pseudo_friction(args: FrictionMapArgs) -> Result<()> {
    let data = load_dataset(&args.data, &["t", &args.input, &args.output])?;
    let map = friction_map(
        data.column("t")?,
        data.column(&args.input)?,
        data.column(&args.output)?,
        args.min_step,
    )
    .with_context(|| format!("the pseudo-friction map of {}", args.data.display()))?;
    if args.json {
        return emit(&(serde_json::to_string_pretty(&map)? + "\n"));
    }
    let mut text = String::from("command → steady velocity (rad/s)\n");
    for p in &map.points {
        text += &format!(
            "{:8.3} → {:9.4}{}\n",
            p.command,
            p.velocity_rad_s,
            if p.steady { "" } else { "  (not settled: left out)" }
        );
    }
    for (name, fit) in [("positive", map.positive), ("negative", map.negative)] {
        if let Some(f) = fit {
            text += &format!(
                "{name}: breakaway {:.4}, {:.4} per rad/s ({} points)\n",
                f.breakaway, f.per_rad_s, f.points
            );
        }
    }
    let list = |v: &[f64]| v.iter().map(|x| format!("{x:.4}")).collect::<Vec<_>>().join(", ");
    text += &format!(
        "for the config's friction compensation:\nmap = {{ velocity = [{}], output = [{}] }}\n",
        list(&map.velocity),
        list(&map.output)
    );
    emit(&text)
}

#[derive(clap::Args)]
pub struct PidIaeArgs {
    /// The model's numerator, descending powers of s (`ident tf` prints it).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, required = true)]
    num: Vec<f64>,
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, required = true)]
    den: Vec<f64>,
    /// Starting gains KP,KI,KD (repeatable); the search also starts from
    /// gains scaled to the model's DC gain.
    #[arg(long = "start", value_delimiter = ',', value_name = "KP,KI,KD")]
    starts: Vec<f64>,
    /// Controller period, s.
    #[arg(long, default_value_t = 1e-3)]
    ts: f64,
    /// Length of the step response, s.
    #[arg(long, default_value_t = 2.0)]
    horizon: f64,
    /// Height of the reference step, in the model's output units.
    #[arg(long, default_value_t = 0.5)]
    step: f64,
    #[arg(long, default_value_t = 0.002)]
    derivative_filter: f64,
    /// The controller output's limit (the valve's range is 1).
    #[arg(long, default_value_t = 1.0)]
    output_limit: f64,
    /// Print {"kp", "ki", "kd", "iae", "starts": [{"kp", "ki", "kd", "iae"}], "warnings": [...]}.
    #[arg(long)]
    json: bool,
}

fn pid_iae(args: PidIaeArgs) -> Result<()> {
    let model = TransferFunction::new(args.num.clone(), args.den.clone())
        .with_context(|| format!("the model num {:?} / den {:?}", args.num, args.den))?;
    let tuning = IaeTuning {
        ts: args.ts,
        horizon_s: args.horizon,
        step: args.step,
        derivative_filter_s: args.derivative_filter,
        output_limit: args.output_limit,
    };
    if !args.starts.len().is_multiple_of(3) {
        bail!("--start takes three gains KP,KI,KD, got {:?}", args.starts);
    }
    let mut starts: Vec<[f64; 3]> = args.starts.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    // A loop gain of 0.2, an integral time of 0.1 s and a derivative time
    // of 5 ms, whatever the model's units.
    let dc = model.dc_gain().abs();
    if dc.is_finite() && dc > 0.0 {
        let kp = 0.2 / dc;
        starts.push([kp, kp / 0.1, kp * 0.005]);
    }
    if starts.is_empty() {
        bail!("the model has no finite DC gain: give starting gains with --start KP,KI,KD");
    }
    let at_starts = starts
        .iter()
        .map(|g| Ok(serde_json::json!({"kp": g[0], "ki": g[1], "kd": g[2], "iae": iae(&model, *g, tuning)?})))
        .collect::<Result<Vec<_>>>()?;
    let tuned = tune_pid_iae(&model, &starts, tuning).context("minimizing the IAE")?;
    let warnings = pid_warnings(&model, &starts, [tuned.kp, tuned.ki, tuned.kd]);
    if args.json {
        let json = serde_json::json!({
            "kp": tuned.kp, "ki": tuned.ki, "kd": tuned.kd, "iae": tuned.iae,
            "starts": at_starts, "warnings": warnings,
        });
        return emit(&(serde_json::to_string_pretty(&json)? + "\n"));
    }
    let mut text = format!(
        "K_p = {:.4e}, K_i = {:.4e}, K_d = {:.4e}: IAE {:.5} over {} s for a step of {}\n",
        tuned.kp, tuned.ki, tuned.kd, tuned.iae, args.horizon, args.step
    );
    for s in &at_starts {
        let gain = |key: &str| s[key].as_f64().unwrap_or(f64::NAN);
        text += &format!(
            "  from K_p = {:.4e}, K_i = {:.4e}, K_d = {:.4e}: IAE {:.5}\n",
            gain("kp"),
            gain("ki"),
            gain("kd"),
            gain("iae")
        );
    }
    for warning in &warnings {
        text += &format!("warning: {warning}\n");
    }
    emit(&text)
}

/// What a user must know before putting the tuned gains on a machine.
fn pid_warnings(model: &TransferFunction, starts: &[[f64; 3]], tuned: [f64; 3]) -> Vec<String> {
    let mut warnings = Vec::new();
    let unstable: Vec<String> = model
        .poles()
        .iter()
        .filter(|p| p.re > 0.0)
        .map(|p| format!("{:.3}{:+.3}i", p.re, p.im))
        .collect();
    if !unstable.is_empty() {
        warnings.push(format!(
            "the model is unstable (poles {}): the gains that minimize its IAE are those that hold it at the output limit, not gains to trust on a machine",
            unstable.join(", ")
        ));
    }
    // The search spans twelve decades around each start: a gain that ran
    // that far says the IAE hardly depends on it.
    for (i, name) in ["K_p", "K_i", "K_d"].iter().enumerate() {
        let largest_start = starts.iter().map(|g| g[i].abs()).fold(0.0, f64::max);
        if largest_start > 0.0 && tuned[i].abs() > 1e4 * largest_start {
            warnings.push(format!(
                "{name} = {:.1e} is {:.0e} times its largest start: the IAE hardly depends on it (the output limit or the derivative filter decides), so its value means little; give a start near what you expect",
                tuned[i],
                tuned[i].abs() / largest_start
            ));
        }
    }
    warnings
}
