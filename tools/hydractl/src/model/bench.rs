//! The model tools' benchmarks: `bench diagnose` (wall time over data
//! lengths) and `bench foreign` (diagnoses on plants simulated apart from
//! the model).

use anyhow::Result;
use hydractl_ident::greybox::{self, FitOptions, Signals};
use hydractl_ident::Dataset;
use hydractl_plant::EffectKind;

use crate::emit;

/// `hydractl bench diagnose`: wall time of `diagnose` over the whole catalog
/// on closed-loop data with a hidden dead-zone, for several data lengths,
/// and of `learn` on a foreign plant with two effects.
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
        let signals = Signals::from_dataset(&Dataset::from_columns("simulated", run.model_columns()))?;
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
    text += &bench_learn(repeat)?;
    emit(&text)
}

/// The plant `bench diagnose` times `model learn` on: a foreign plant (its
/// seed as `bench foreign --effects deadzone+coulomb_friction` draws its
/// first) with a worn rotator's two effects.
const LEARN_PLANT_SEED: u64 = 1_117_003;

/// `model learn` on 60 s of a foreign plant with a dead band and Coulomb
/// friction: its wall time (median of `repeat`) and the steps it took.
fn bench_learn(repeat: usize) -> Result<String> {
    use hydractl_sim::foreign::{foreign_plant, Hidden, Sensors};
    let hidden = [
        Hidden::Deadzone {
            width: 0.1,
            offset: 0.0,
        },
        Hidden::CoulombFriction {
            sliding: 60.0,
            breakaway: 90.0,
        },
    ];
    let data = foreign_plant(LEARN_PLANT_SEED, &hidden, 60.0);
    let signals = Signals::from_dataset(&Dataset::from_columns("foreign", data.record(Sensors::Full, 1)))?;
    let mut times = Vec::new();
    let mut steps = Vec::new();
    for _ in 0..repeat.max(1) {
        let start = std::time::Instant::now();
        let learned = greybox::learn(&signals, None, FitOptions::default(), 4, &greybox::Silent)?;
        times.push(start.elapsed().as_secs_f64());
        steps = learned.steps.iter().map(|s| s.effect.clone()).collect();
    }
    times.sort_by(f64::total_cmp);
    Ok(format!(
        "  model learn, 60 s of a foreign plant with a dead band and Coulomb friction (seed {LEARN_PLANT_SEED}): {:.2} s (min {:.2}, max {:.2}); added: {}\n",
        times[times.len() / 2],
        times[0],
        times[times.len() - 1],
        steps.join(", ")
    ))
}
