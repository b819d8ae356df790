//! `hydractl ident hinf`: an H∞ loop-shaping torque controller designed for
//! the machine that made the measurements, written into a config.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use hydractl_control::{HInfinityDesign, HInfinityParams};
use hydractl_ident::loop_shaping::{design, LoopShapingDesign, PiWeight};
use hydractl_ident::{DataError, Method, TfFit, TfOptions};
use hydractl_lti::StateSpace;

use crate::emit;
use crate::recording::load_dataset;

/// A γ above this leaves the loop little room for a plant unlike its model
/// (ε = 1/γ below 0.25): the usual bound of a good loop-shaping design.
const GAMMA_WARNING: f64 = 4.0;
/// A plant model that explains less of the validation data than this is
/// too poor to design on.
const FIT_WARNING_PERCENT: f64 = 70.0;

#[derive(clap::Args)]
pub struct IdentHinfArgs {
    /// The machine's measurements: a recording (`.mcap`) or CSV of the loop
    /// at work, the cascade on the machine (`hydractl run --record`).
    #[arg(long)]
    data: PathBuf,
    /// The valve command column.
    #[arg(long, default_value = "u")]
    input: String,
    /// The command the controller does not make, subtracted from the input:
    /// the friction compensation is added beside the torque loop, so the
    /// controller drives the plant with that compensation inside it (`none`
    /// to take the input as it is).
    #[arg(long, default_value = "friction_comp")]
    feedforward: String,
    #[arg(long, default_value = "torque")]
    output: String,
    /// The plant model's poles and zeros (`ident tf`): the valve's and the
    /// load's two pole pairs, with the zero of the load's motion.
    #[arg(long, default_value_t = 4)]
    poles: usize,
    #[arg(long, default_value_t = 1)]
    zeros: usize,
    /// Where the shaped loop crosses 1, rad/s: higher tracks more closely
    /// and costs robustness (γ) and valve travel.
    #[arg(long, default_value_t = 40.0)]
    crossover: f64,
    /// The weight's integral action below this, rad/s [default: half the crossover].
    #[arg(long)]
    integral_corner: Option<f64>,
    /// The weight's roll-off above this, rad/s: the sensor noise it keeps
    /// off the valve. The feedforward beside the controller rolls off here
    /// too.
    #[arg(long, default_value_t = 300.0)]
    roll_off: f64,
    /// γ over its optimum: a controller a little short of the optimum is
    /// better conditioned.
    #[arg(long, default_value_t = 1.1)]
    gamma_factor: f64,
    /// The config to build on [default: the built-in config/sim.toml].
    #[arg(long)]
    config: Option<PathBuf>,
    /// The config written: the base with this controller as
    /// `[control.torque.hinf]` and its design record.
    #[arg(long)]
    out: PathBuf,
    /// Print {"out", "plant": {"num", "den", "fit_percent"}, "weight": {"num",
    /// "den"}, "gamma", "gamma_min", "epsilon", "margins": {...}, "warnings"}.
    #[arg(long)]
    json: bool,
}

pub fn hinf(args: IdentHinfArgs) -> Result<()> {
    let fit = identify_plant(&args)?;
    let weight = PiWeight {
        crossover_rad_s: args.crossover,
        integral_corner_rad_s: args.integral_corner.unwrap_or(args.crossover / 2.0),
        roll_off_rad_s: args.roll_off,
    }
    .for_plant(&fit.tf)
    .context("the shaping weight")?;
    let designed = design(&fit.tf, &weight, args.gamma_factor).context("the loop-shaping synthesis")?;
    let margins = &designed.margins;
    if !margins.closed_loop_stable {
        bail!(
            "the designed loop is unstable around its own plant model (slowest pole {:.3}/s): nothing written; try a lower --crossover",
            margins.slowest_pole_real
        );
    }
    let (Some(crossover), Some(bandwidth), Some(phase_margin)) = (
        margins.crossover_rad_s,
        margins.bandwidth_rad_s,
        margins.phase_margin_deg,
    ) else {
        bail!("the designed loop never crosses 1 between 0.001 and 10⁵ rad/s: nothing written");
    };
    let mut warnings = Vec::new();
    if fit.fit_percent < FIT_WARNING_PERCENT {
        warnings.push(format!(
            "the plant model fits the validation data at {:.0}%: a design on it may not hold on the machine; record the cascade at work for longer, or change --poles/--zeros",
            fit.fit_percent
        ));
    }
    if designed.gamma > GAMMA_WARNING {
        warnings.push(format!(
            "γ = {:.2}: the loop tolerates little model error (ε = {:.2}); a lower --crossover buys robustness",
            designed.gamma,
            1.0 / designed.gamma
        ));
    }
    let base = hydractl_config::Config::load_or_default(args.config.as_deref())?;
    let mut config = base.clone();
    config.control.torque.hinf = params(&designed, &fit, &args, crossover, bandwidth, phase_margin, &base)?;
    let source = args
        .config
        .as_ref()
        .map_or("the built-in config/sim.toml".to_owned(), |p| p.display().to_string());
    let header = format!(
        "# [control.torque.hinf] designed by `hydractl ident hinf` from {} on {source}:\n\
         # H∞ loop shaping, γ = {:.2}, crossover {crossover:.1} rad/s, phase margin {phase_margin:.0}°.\n\
         # Swap to it with `hydractl swap torque hinf`, or set control.torque_variant = \"hinf\".\n",
        args.data.display(),
        designed.gamma,
    );
    crate::model::write_config(&args.out, header, &config)?;
    report(&args, &fit, &designed, &warnings)
}

fn identify_plant(args: &IdentHinfArgs) -> Result<TfFit> {
    let subtract = args.feedforward != "none";
    let mut columns = vec!["t", args.input.as_str(), args.output.as_str()];
    if subtract {
        columns.push(&args.feedforward);
    }
    let data = load_dataset(&args.data, &columns).map_err(|e| {
        // The feedforward's column missing: say what it is and the way out.
        let missing_feedforward = e.chain().any(|cause| {
            matches!(cause.downcast_ref::<DataError>(),
                Some(DataError::MissingColumn { column, .. }) if *column == args.feedforward)
        });
        if subtract && missing_feedforward {
            e.context(format!(
                "the plant's input is `{}` minus `{}`, the command the controller does not make (`--feedforward none` when the data has none)",
                args.input, args.feedforward
            ))
        } else {
            e
        }
    })?;
    let mut input = data.column(&args.input)?.to_vec();
    if subtract {
        for (u, f) in input.iter_mut().zip(data.column(&args.feedforward)?) {
            *u -= f;
        }
    }
    let options = TfOptions {
        poles: args.poles,
        zeros: args.zeros,
        method: Method::Oe,
        estimation_fraction: 0.7,
    };
    hydractl_ident::identify_tf(&input, data.column(&args.output)?, data.sample_time()?, options).with_context(|| {
        format!(
            "identifying the torque loop's plant ({} → {}) in {}",
            plant_input(args),
            args.output,
            args.data.display()
        )
    })
}

/// The plant's input as the reports name it: `u − friction_comp`, or `u`.
fn plant_input(args: &IdentHinfArgs) -> String {
    if args.feedforward == "none" {
        args.input.clone()
    } else {
        format!("{} − {}", args.input, args.feedforward)
    }
}

fn params(
    designed: &LoopShapingDesign,
    fit: &TfFit,
    args: &IdentHinfArgs,
    crossover_rad_s: f64,
    bandwidth_rad_s: f64,
    phase_margin_deg: f64,
    base: &hydractl_config::Config,
) -> Result<HInfinityParams> {
    let StateSpace { a, b, c, .. } = &designed.controller;
    let n = a.nrows();
    Ok(HInfinityParams {
        num: Vec::new(),
        den: Vec::new(),
        a: (0..n).map(|i| a.row(i).iter().copied().collect()).collect(),
        b: b.column(0).iter().copied().collect(),
        c: c.row(0).iter().copied().collect(),
        // Designed in the torque loop's own units: N·m in, command out.
        error_scale: 1.0,
        output_limit: base.control.torque.hinf.output_limit,
        feedforward_roll_off_rad_s: args.roll_off,
        design: Some(HInfinityDesign {
            data: args.data.display().to_string(),
            plant_num: fit.tf.num().to_vec(),
            plant_den: fit.tf.den().to_vec(),
            plant_fit_percent: fit.fit_percent,
            weight_num: designed.weight.num().to_vec(),
            weight_den: designed.weight.den().to_vec(),
            gamma: designed.gamma,
            gamma_min: designed.gamma_min,
            crossover_rad_s,
            bandwidth_rad_s,
            phase_margin_deg,
            gain_margin_db: designed.margins.gain_margin_db,
            peak_sensitivity: designed.margins.peak_sensitivity,
        }),
    })
}

fn report(args: &IdentHinfArgs, fit: &TfFit, designed: &LoopShapingDesign, warnings: &[String]) -> Result<()> {
    let m = &designed.margins;
    if args.json {
        let json = serde_json::json!({
            "out": args.out,
            "plant": {"num": fit.tf.num(), "den": fit.tf.den(), "fit_percent": fit.fit_percent},
            "weight": {"num": designed.weight.num(), "den": designed.weight.den()},
            "gamma": designed.gamma,
            "gamma_min": designed.gamma_min,
            "epsilon": 1.0 / designed.gamma,
            "states": designed.controller.states(),
            "margins": m,
            "warnings": warnings,
        });
        return emit(&(serde_json::to_string_pretty(&json)? + "\n"));
    }
    let fmt = |p: &[f64]| p.iter().map(|c| format!("{c:.4e}")).collect::<Vec<_>>().join(", ");
    let optional = |v: Option<f64>, unit: &str| v.map_or("none".to_owned(), |v| format!("{v:.1} {unit}"));
    let mut text = format!(
        "plant ({} → {}): num [{}], den [{}], fit {:.1}% on validation\n\
         weight W1: num [{}], den [{}]\n\
         γ = {:.3} (optimum {:.3}, ε = {:.3}), a controller of {} states\n\
         loop around the model: crossover {}, phase margin {}, gain margin {}, bandwidth {}, peak |S| {:.2}\n",
        plant_input(args),
        args.output,
        fmt(fit.tf.num()),
        fmt(fit.tf.den()),
        fit.fit_percent,
        fmt(designed.weight.num()),
        fmt(designed.weight.den()),
        designed.gamma,
        designed.gamma_min,
        1.0 / designed.gamma,
        designed.controller.states(),
        optional(m.crossover_rad_s, "rad/s"),
        optional(m.phase_margin_deg, "°"),
        optional(m.gain_margin_db, "dB"),
        optional(m.bandwidth_rad_s, "rad/s"),
        m.peak_sensitivity,
    );
    for warning in warnings {
        text += &format!("warning: {warning}\n");
    }
    text += &format!("config written to {}\n", args.out.display());
    emit(&text)
}
