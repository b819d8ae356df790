//! `hydractl bench foreign`: the model tools on plants simulated apart from
//! the model (`hydractl_sim::foreign`), with one hidden effect (judged by
//! one `diagnose`) or several (judged by `learn`, the loop a user runs).

use anyhow::{bail, Context, Result};
use hydractl_ident::greybox::{self, FitOptions, Signals, Stop};
use hydractl_ident::Dataset;
use hydractl_plant::EffectKind;
use hydractl_sim::foreign::{foreign_plant, Hidden};

use crate::emit;

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

    /// Whether a record of these sensors can show every effect of `case`
    /// (as `diagnose` judges a record's parts), or why not.
    fn can_show(self, case: &[Hidden]) -> Result<(), String> {
        let columns = self.sensors().columns();
        let has_command = columns.contains(&"u");
        let parts = greybox::parts_measured(
            has_command,
            columns.contains(&"p_a") && columns.contains(&"p_b"),
            columns.contains(&"tau"),
        );
        for hidden in case {
            let kind = EffectKind::from_name(hidden.name()).map_err(|e| e.to_string())?;
            greybox::part_showing(&parts, has_command, kind).map_err(|e| format!("{}: {e}", hidden.name()))?;
        }
        Ok(())
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

/// The effects hidden in a case's plants: none, one, or several.
type Case = Vec<Hidden>;

/// `none`, an effect's name, or the names joined by `+`.
fn case_name(case: &[Hidden]) -> String {
    if case.is_empty() {
        return "none".to_owned();
    }
    case.iter().map(|h| h.name()).collect::<Vec<_>>().join("+")
}

/// The cases `--effects` names: `none`, effect names, `A+B` for effects
/// hidden together, and `pairs` for every pair the sensors can show;
/// nothing means `none` and each effect alone.
fn cases(only: &[String], sensors: ForeignSensors) -> Result<Vec<Case>> {
    let catalog = Hidden::all();
    let known = || {
        std::iter::once("none")
            .chain(catalog.iter().map(|h| h.name()))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let shown = |case: &Case| sensors.can_show(case).is_ok();
    if only.is_empty() {
        let mut all: Vec<Case> = vec![Vec::new()];
        all.extend(catalog.iter().map(|h| vec![*h]).filter(shown));
        return Ok(all);
    }
    let mut chosen = Vec::new();
    for entry in only {
        if entry == "pairs" {
            for (i, a) in catalog.iter().enumerate() {
                chosen.extend(catalog[i + 1..].iter().map(|b| vec![*a, *b]).filter(shown));
            }
            continue;
        }
        if entry == "none" {
            chosen.push(Vec::new());
            continue;
        }
        let mut case = Vec::new();
        for name in entry.split('+') {
            let hidden = catalog
                .iter()
                .find(|h| h.name() == name.trim())
                .with_context(|| format!("--effects: `{name}` is none of {}, or `pairs`", known()))?;
            if case.contains(hidden) {
                bail!("--effects {entry}: `{name}` twice");
            }
            case.push(*hidden);
        }
        if let Err(reason) = sensors.can_show(&case) {
            bail!("--effects {entry}: a record of these sensors cannot show it: {reason}");
        }
        chosen.push(case);
    }
    Ok(chosen)
}

/// A case's place among all cases, for its plants' seeds: `none` 0, an
/// effect alone its place in the catalog from 1, several a number of their
/// own from 100. A case run alone meets the same plants as in a full bench,
/// and a pair the same whatever its order.
fn case_place(case: &[Hidden]) -> u64 {
    let index = |h: &Hidden| Hidden::all().iter().position(|c| c == h).unwrap_or(0) as u64;
    match case {
        [] => 0,
        [one] => 1 + index(one),
        several => 100 + several.iter().map(|h| 1u64 << index(h)).sum::<u64>(),
    }
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

/// One foreign plant diagnosed (one hidden effect or none) or learned
/// (several).
#[derive(serde::Serialize)]
struct ForeignRun {
    seed: u64,
    plant: String,
    /// The effect ranked first (with several hidden: added first).
    first: String,
    first_significant: bool,
    /// The effects called significant (with several hidden: added, in order).
    significant: Vec<String>,
    /// Each hidden effect's main parameter as fitted, when it was tried
    /// (with several hidden: in the model learned, when it was added).
    fitted: Vec<Option<f64>>,
    /// With several hidden: why the loop stopped.
    #[serde(skip_serializing_if = "Option::is_none")]
    stop: Option<Stop>,
    seconds: f64,
}

impl ForeignRun {
    /// Every hidden effect named (alone: ranked first and significant;
    /// several: each added by the loop).
    fn found(&self, case: &[Hidden]) -> bool {
        match case {
            [] => false,
            [one] => self.first == one.name() && self.first_significant,
            several => several.iter().all(|h| self.significant.iter().any(|s| s == h.name())),
        }
    }

    /// …each with its main parameter within 25 % of the truth.
    fn within(&self, case: &[Hidden]) -> bool {
        self.found(case) && case.iter().zip(&self.fitted).all(|(h, fitted)| h.within(*fitted, 0.25))
    }

    /// With several hidden: found, and nothing else added or still
    /// significant at the end.
    fn nothing_else(&self, case: &[Hidden]) -> bool {
        self.found(case) && self.significant.len() == case.len() && self.stop == Some(Stop::NothingSignificant)
    }
}

#[derive(serde::Serialize)]
struct ForeignCase {
    hidden: String,
    /// Each hidden effect's main parameter: key and true value (none for
    /// an effect without one, such as `orifice_flow`).
    truth: Vec<Option<(String, f64)>>,
    plants: usize,
    /// Alone: the hidden effect ranked first and called significant.
    /// Several: every one added by the loop.
    named_first: usize,
    /// …with each main parameter within 25 % of the truth (an effect
    /// without a parameter: as named).
    within_25_percent: usize,
    /// Several hidden: every one added with its parameter within 25 %, and
    /// nothing else added or significant at the end.
    #[serde(skip_serializing_if = "Option::is_none")]
    goal: Option<usize>,
    /// Any effect called significant (with none hidden: false alarms).
    any_significant: usize,
    runs: Vec<ForeignRun>,
}

/// Diagnoses (or, with several hidden, learns) one plant of `case`.
fn run_one(
    case: &[Hidden],
    plant_seed: u64,
    bench: ForeignBench,
    save_data: Option<&std::path::Path>,
) -> Result<ForeignRun> {
    let data = foreign_plant(plant_seed, case, bench.duration);
    let dataset = Dataset::from_columns(
        "foreign",
        data.record(bench.sensors.sensors(), (1000 / bench.rate) as usize),
    );
    let stem = format!("{}-{plant_seed}", case_name(case));
    if let Some(dir) = save_data {
        save_dataset(&dir.join(format!("{stem}.csv")), &dataset)?;
    }
    let signals = Signals::from_dataset(&dataset)?;
    let start = std::time::Instant::now();
    let main_of = |h: &Hidden, params: Option<&std::collections::BTreeMap<String, f64>>| {
        h.main().and_then(|(key, _)| params?.get(key).copied())
    };
    let run = if case.len() < 2 {
        let diagnosis = greybox::diagnose(&signals, None, FitOptions::default())?;
        if let Some(dir) = save_data {
            let path = dir.join(format!("{stem}.json"));
            std::fs::write(&path, serde_json::to_string_pretty(&diagnosis)?)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        let first = diagnosis.candidates.first();
        ForeignRun {
            seed: plant_seed,
            plant: data.description,
            first: first.map(|c| c.effect.clone()).unwrap_or_default(),
            first_significant: first.is_some_and(|c| c.significant),
            significant: diagnosis
                .candidates
                .iter()
                .filter(|c| c.significant)
                .map(|c| c.effect.clone())
                .collect(),
            fitted: case
                .iter()
                .map(|h| {
                    main_of(
                        h,
                        diagnosis
                            .candidates
                            .iter()
                            .find(|c| c.effect == h.name())
                            .map(|c| &c.params),
                    )
                })
                .collect(),
            stop: None,
            seconds: 0.0,
        }
    } else {
        let learned = greybox::learn(&signals, None, FitOptions::default(), 4, &greybox::Silent)?;
        if let Some(dir) = save_data {
            learned.model.save(&dir.join(format!("{stem}.toml")))?;
        }
        ForeignRun {
            seed: plant_seed,
            plant: data.description,
            first: learned.steps.first().map(|s| s.effect.clone()).unwrap_or_default(),
            first_significant: !learned.steps.is_empty(),
            significant: learned.steps.iter().map(|s| s.effect.clone()).collect(),
            // The parameters of the model learned, each refitted with the
            // effects added after it.
            fitted: case
                .iter()
                .map(|h| main_of(h, learned.model.effects.0.get(h.name())))
                .collect(),
            stop: Some(learned.stop),
            seconds: 0.0,
        }
    };
    Ok(ForeignRun {
        seconds: start.elapsed().as_secs_f64(),
        ..run
    })
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
    if let Some(dir) = save_data {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    if plants > 1000 {
        bail!("--plants {plants}: at most 1000 per case (each case draws from its own thousand seeds)");
    }
    let cases = cases(only, sensors)?;
    let plant_seed = |case: &[Hidden], i: usize| {
        seed.wrapping_mul(1_000_003)
            .wrapping_add(case_place(case) * 1000 + i as u64)
    };
    // Plants are independent: both cores, one diagnosis each.
    let jobs: Vec<(usize, usize)> = (0..cases.len())
        .flat_map(|c| (0..plants).map(move |i| (c, i)))
        .collect();
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(jobs.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let finished = std::sync::atomic::AtomicUsize::new(0);
    let progress = crate::progress::Progress::new("bench foreign", json);
    progress.step("simulating and diagnosing the plants", 0, jobs.len());
    let results: Vec<(usize, Result<ForeignRun>)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let j = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(&(c, i)) = jobs.get(j) else { break };
                        let case = &cases[c];
                        done.push((j, run_one(case, plant_seed(case, i), bench, save_data)));
                        let finished = finished.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                        progress.step(&format!("{} diagnosed", case_name(case)), finished, jobs.len());
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
    drop(progress);
    let mut summary: Vec<ForeignCase> = cases
        .iter()
        .map(|case| ForeignCase {
            hidden: case_name(case),
            truth: case.iter().map(|h| h.main().map(|(k, v)| (k.to_owned(), v))).collect(),
            plants: 0,
            named_first: 0,
            within_25_percent: 0,
            goal: (case.len() > 1).then_some(0),
            any_significant: 0,
            runs: Vec::new(),
        })
        .collect();
    for (j, run) in results {
        let (c, _) = jobs[j];
        let case = &cases[c];
        let run = run.with_context(|| format!("diagnosing foreign plant {} of {}", jobs[j].1, case_name(case)))?;
        let entry = &mut summary[c];
        entry.plants += 1;
        entry.named_first += usize::from(run.found(case));
        entry.within_25_percent += usize::from(run.within(case));
        if let Some(goal) = entry.goal.as_mut() {
            *goal += usize::from(run.within(case) && run.nothing_else(case));
        }
        entry.any_significant += usize::from(!run.significant.is_empty());
        entry.runs.push(run);
    }
    if json {
        return emit(
            &(serde_json::to_string_pretty(
                &serde_json::json!({"duration_s": duration, "seed": seed, "sensors": sensors, "rate_hz": rate, "cases": summary}),
            )? + "\n"),
        );
    }
    emit(&table(bench, &summary))
}

/// The bench's table: a row per case.
fn table(bench: ForeignBench, summary: &[ForeignCase]) -> String {
    let mut text = format!(
        "bench foreign: the model tools on plants simulated apart from the model ({} per case, {} s of {} Hz data each, {} sensors, seed {})\n\
         {:<30} {:>6} {:>12} {:>12} {:>13} {:>6} {:>10}\n",
        bench.plants,
        bench.duration,
        bench.rate,
        match bench.sensors {
            ForeignSensors::Full => "full (u, p_a, p_b, theta)",
            ForeignSensors::Motion => "motion (u, theta)",
            ForeignSensors::Torque => "torque (tau, theta; the load's effects only)",
        },
        bench.seed,
        "hidden",
        "plants",
        "named first",
        "param ±25%",
        "any signif.",
        "goal",
        "median s"
    );
    for case in summary {
        let mut times: Vec<f64> = case.runs.iter().map(|r| r.seconds).collect();
        times.sort_by(f64::total_cmp);
        let median = times.get(times.len() / 2).copied().unwrap_or(f64::NAN);
        let (named, within) = if case.truth.is_empty() {
            ("-".to_owned(), "-".to_owned())
        } else if case.truth.iter().all(Option::is_none) {
            // No parameter to be within 25 % of: naming it is all.
            (case.named_first.to_string(), "-".to_owned())
        } else {
            (case.named_first.to_string(), case.within_25_percent.to_string())
        };
        let goal = case.goal.map_or("-".to_owned(), |g| g.to_string());
        text += &format!(
            "{:<30} {:>6} {:>12} {:>12} {:>13} {:>6} {:>10.2}\n",
            case.hidden, case.plants, named, within, case.any_significant, goal, median
        );
    }
    text += "named first: the hidden effect ranked first and called significant (several hidden: each added by `model learn`); \
             any signif.: plants on which any effect was called significant (with none hidden, each is a false alarm); \
             goal (several hidden): each added with its parameter within 25 % and nothing else significant afterwards\n";
    text
}
