//! `hydractl model compensate`: a config whose compensators use what the
//! model learned, proven before it is written. A tuned config drives the
//! valve of a crane: parameters no rotator has are refused, and the tuned
//! and the untuned config are simulated on the model they came from; a
//! proposal that tracks worse or makes the torque chatter is refused with
//! both figures, unless `--force` (said so in the file).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use hydractl_config::compensate::{implausible, Compensation};
use hydractl_config::Config;
use hydractl_ident::greybox::Model;

use super::{load_model, write_config};
use crate::emit;

#[derive(clap::Args)]
pub struct CompensateArgs {
    /// The fitted model (`model fit`, `model add`, `model learn`).
    #[arg(long)]
    model: PathBuf,
    /// The config to tune [default: the built-in config/sim.toml].
    #[arg(long)]
    config: Option<PathBuf>,
    /// The tuned config.
    #[arg(long)]
    out: PathBuf,
    /// Write the config even when its parameters are implausible or it
    /// does worse than the untuned one on the model (said so in the file).
    #[arg(long)]
    force: bool,
    /// Print {"out", "changes": [{"key", "from", "to", "effect", "reason"}],
    /// "not_compensated": [{"effect", "reason"}], "proof": {"duration_s",
    /// "untuned", "tuned", "refused"}, "forced"}.
    #[arg(long)]
    json: bool,
}

/// Seconds each config is simulated for on the model.
const PROOF_S: f64 = 30.0;

/// Tracking worse than the untuned config's by more than this share is a
/// worse proposal (the simulation is deterministic: the share is a margin
/// for what the model may get wrong, not for noise).
const WORSE_TRACKING: f64 = 0.05;

/// The torque's power above 10 rad/s more than this many times the
/// untuned config's is a valve made to chatter.
const CHATTER_FACTOR: f64 = 3.0;

/// One config run on the model.
#[derive(Debug, Clone, Copy, serde::Serialize)]
struct Tracking {
    rms_rad: f64,
    max_rad: f64,
    torque_power_above_10_rad_s: f64,
}

/// The tuned and the untuned config on the model they came from.
#[derive(Debug, serde::Serialize)]
struct Proof {
    duration_s: f64,
    untuned: Tracking,
    tuned: Tracking,
    /// Why the proposal is refused, if it is.
    refused: Vec<String>,
}

impl Proof {
    /// Untuned → tuned on the model, in a line (the file's head and the
    /// command's output).
    fn figures(&self) -> String {
        format!(
            "on the model ({} s): tracking rms {:.4} → {:.4} rad, max {:.4} → {:.4} rad, torque power above 10 rad/s {:.0} → {:.0} (N·m)²",
            self.duration_s,
            self.untuned.rms_rad,
            self.tuned.rms_rad,
            self.untuned.max_rad,
            self.tuned.max_rad,
            self.untuned.torque_power_above_10_rad_s,
            self.tuned.torque_power_above_10_rad_s
        )
    }
}

/// `config`'s controllers on the model's plant and effects.
fn on_model(config: &Config, model: &Model) -> Result<Tracking> {
    let mut on = config.clone();
    on.plant = model.plant;
    on.effects = model.effects.clone();
    let summary = hydractl_sim::simulate_streaming(&on, &[], PROOF_S, |_| Ok(()))
        .context("simulating a config on the model it is tuned from")?;
    Ok(Tracking {
        rms_rad: summary.rms_tracking_error_rad,
        max_rad: summary.max_abs_tracking_error_rad,
        torque_power_above_10_rad_s: summary.torque_power_above_10_rad_s,
    })
}

fn prove(base: &Config, tuned: &Compensation, model: &Model, mut refused: Vec<String>) -> Result<Proof> {
    let untuned = on_model(base, model)?;
    let with = on_model(&tuned.config, model)?;
    let finite = [with.rms_rad, with.max_rad, with.torque_power_above_10_rad_s]
        .iter()
        .all(|v| v.is_finite());
    if !finite || with.rms_rad > (1.0 + WORSE_TRACKING) * untuned.rms_rad {
        refused.push(format!(
            "it tracks worse on the model: rms {:.4} rad against {:.4} untuned (max {:.4} against {:.4})",
            with.rms_rad, untuned.rms_rad, with.max_rad, untuned.max_rad
        ));
    }
    if with.torque_power_above_10_rad_s > CHATTER_FACTOR * untuned.torque_power_above_10_rad_s {
        refused.push(format!(
            "it makes the valve chatter on the model: the torque's power above 10 rad/s {:.0} (N·m)² against {:.0} untuned",
            with.torque_power_above_10_rad_s, untuned.torque_power_above_10_rad_s
        ));
    }
    Ok(Proof {
        duration_s: PROOF_S,
        untuned,
        tuned: with,
        refused,
    })
}

pub fn compensate(args: CompensateArgs) -> Result<()> {
    let model = load_model(&args.model)?;
    let base = Config::load_or_default(args.config.as_deref())?;
    let effects = model.effects()?;
    let tuned = hydractl_config::compensate::compensate(&base, &model.plant, &effects);
    let outside: Vec<String> = implausible(&model.plant, &effects)
        .iter()
        .map(|i| format!("{}: {i}", args.model.display()))
        .collect();
    let proof = prove(&base, &tuned, &model, outside)?;
    if !proof.refused.is_empty() && !args.force {
        bail!(
            "{} not written: {}; `--force` writes it anyway",
            args.out.display(),
            proof.refused.join("; ")
        );
    }
    let source = args
        .config
        .as_ref()
        .map_or("the built-in config/sim.toml".to_owned(), |p| p.display().to_string());
    let mut text = format!(
        "# Tuned by `hydractl model compensate` from {} on {source}: the controllers\n\
         # use what the model learned; the plant is the base config's.\n",
        args.model.display()
    );
    text += &format!("# {}\n", proof.figures());
    for reason in &proof.refused {
        text += &format!("# WRITTEN WITH --force although {reason}\n");
    }
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
            "proof": proof,
            "forced": !proof.refused.is_empty(),
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
    out += &format!("{}\n", proof.figures());
    for reason in &proof.refused {
        out += &format!("written with --force although {reason}\n");
    }
    out += &format!("tuned config written to {}\n", args.out.display());
    emit(&out)
}
