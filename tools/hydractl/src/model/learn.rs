//! `hydractl model learn`: the loop of `diagnose` and `add` in one command,
//! one line per effect added and a last line that says why it stopped.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{bail, Context, Result};
use hydractl_ident::greybox::{self, LearnStep, Stop};

use super::{load_model, load_signals, options, DataArgs};
use crate::emit;
use crate::progress::Progress;

#[derive(clap::Args)]
pub struct LearnArgs {
    #[command(flatten)]
    data: DataArgs,
    /// The model to start from [default: a baseline fitted here].
    #[arg(long)]
    model: Option<PathBuf>,
    /// The model learned, with every step in its `[[history]]`.
    #[arg(long)]
    out: PathBuf,
    /// Print {"steps": [{"effect", "output", "nrmse_before", "nrmse_after",
    /// "params", "test", "statistic", "threshold"}], "stopped_because", "stop", "out"};
    /// a step added with another, neither significant alone, names it in "together_with".
    #[arg(long)]
    json: bool,
    /// Also write the HTML report of the model learned (`model report`).
    #[arg(long)]
    report: Option<PathBuf>,
    /// Effects to add at most.
    #[arg(long, default_value_t = 4)]
    max_steps: usize,
}

/// The bar of `model learn`: which step is diagnosed, and each fit in it.
struct LearnBar {
    bar: Progress,
    step: AtomicUsize,
    quiet: bool,
}

impl greybox::Progress for LearnBar {
    fn fitted(&self, what: &str, done: usize, total: usize) {
        let step = self.step.load(Ordering::Relaxed) + 1;
        let what = if done == 0 {
            format!("step {step}: fitting {what}")
        } else {
            format!("step {step}: {what} fitted")
        };
        self.bar.step(&what, done, total);
    }
}

impl greybox::LearnProgress for LearnBar {
    fn diagnosing(&self, index: usize) {
        self.step.store(index, Ordering::Relaxed);
    }

    fn added(&self, index: usize, step: &LearnStep) {
        if !self.quiet {
            // The step's line as soon as it is known: a learn of four
            // steps on a long record takes a while.
            self.bar.println(&step_line(index, step));
        }
    }
}

/// One step in a line: the effect, its output's error before and after,
/// its parameters, the test that decided.
fn step_line(index: usize, step: &LearnStep) -> String {
    let params: Vec<String> = step.params.iter().map(|(k, v)| format!("{k} {v:.4}")).collect();
    let tied = if step.indistinguishable_from.is_empty() {
        String::new()
    } else {
        let names: Vec<String> = step.indistinguishable_from.iter().map(|n| format!("`{n}`")).collect();
        format!(
            "; the record cannot tell it from {}, which remove the error alike: the one with the fewest parameters taken",
            names.join(" or ")
        )
    };
    let together = match &step.together_with {
        Some(other) => format!(" (with `{other}`: neither is significant alone, the test is the pair's)"),
        None => String::new(),
    };
    format!(
        "step {}: add `{}`{together}: {} validation NRMSE {:.4} → {:.4}{}; {} {:.1} against {:.1}{tied}",
        index + 1,
        step.effect,
        step.output,
        step.nrmse_before,
        step.nrmse_after,
        if params.is_empty() {
            String::new()
        } else {
            format!(" ({})", params.join(", "))
        },
        step.test,
        step.statistic,
        step.threshold
    )
}

pub fn learn(args: LearnArgs) -> Result<()> {
    if args.max_steps == 0 {
        bail!("--max-steps 0: give at least 1 (0 would write the start model unchanged)");
    }
    let options = options(&args.data)?;
    let signals = load_signals(&args.data)?;
    let start = args.model.as_deref().map(load_model).transpose()?;
    let bar = LearnBar {
        bar: Progress::new("model learn", args.json),
        step: AtomicUsize::new(0),
        quiet: args.json,
    };
    let learned = greybox::learn(&signals, start.as_ref(), options, args.max_steps, &bar)
        .with_context(|| format!("learning from {}", args.data.data.display()))?;
    drop(bar);
    learned.model.save(&args.out)?;
    if let Some(report) = &args.report {
        // The last diagnosis is the learned model's own when nothing more
        // helped; after --max-steps the model is newer than it.
        let diagnosis = (learned.stop == Stop::NothingSignificant).then_some(&learned.last_diagnosis);
        crate::report::write_with(&signals, &learned.model, diagnosis, options, report)?;
    }
    let stopped_because = learned.stopped_because(args.max_steps);
    if args.json {
        let json = serde_json::json!({
            "steps": learned.steps,
            "stopped_because": stopped_because,
            "stop": learned.stop,
            "out": args.out,
            "report": args.report,
        });
        return emit(&(serde_json::to_string_pretty(&json)? + "\n"));
    }
    let mut text = String::new();
    if learned.steps.is_empty() {
        text += "no effect added\n";
    }
    text += &format!("stopped: {stopped_because}\n");
    text += &format!("model written to {}\n", args.out.display());
    if let Some(report) = &args.report {
        text += &format!("report written to {}\n", report.display());
    }
    emit(&text)
}
