//! Where the model fails: fit per output on the validation segment, the
//! residual split by sub-model and by operating regime, and the residual
//! tests of MATLAB's `resid` (whiteness, cross-correlation with the input).

use std::collections::BTreeMap;
use std::ops::Range;

use hydractl_plant::effects::Effects;
use hydractl_plant::PlantParams;
use serde::Serialize;

use super::fit::{encoder_step, nrmse_by_output, spread};
use super::{predict, Part, Prediction, Signals};

/// Speed below which the load counts as at rest, rad/s.
pub const REST_SPEED: f64 = 0.02;
/// Commands below this magnitude count as small.
pub const SMALL_COMMAND: f64 = 0.1;
/// Samples this close to a velocity reversal count as at a reversal, s.
pub const REVERSAL_WINDOW_S: f64 = 0.05;
/// Lags of the residual tests, samples.
pub const MAX_LAG: usize = 25;
/// The tests' confidence: 99%, as `resid`'s default.
pub const CONFIDENCE_Z: f64 = 2.576;

#[derive(Debug, Clone, Serialize)]
pub struct OutputScore {
    pub output: String,
    /// 100 (1 − ‖y − ŷ‖ / ‖y − mean(y)‖), MATLAB `compare`'s fit.
    pub fit_percent: f64,
    /// ‖y − ŷ‖ / ‖y − mean(y)‖.
    pub nrmse: f64,
}

/// The residual in one operating regime: its RMS divided by the output's
/// spread over the whole validation segment, so regimes compare directly.
#[derive(Debug, Clone, Serialize)]
pub struct RegimeScore {
    pub regime: String,
    pub samples: usize,
    pub nrmse: BTreeMap<String, f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct CorrelationTest {
    pub output: String,
    /// `autocorrelation` (whiteness), or `cross_correlation_u` with the
    /// valve command (`cross_correlation_tau` with the driving torque, in a
    /// record without one).
    pub test: String,
    /// ± this is the 99% band a correct model's residual stays within:
    /// for the cross-correlation, Bartlett's, from both signals' own
    /// autocorrelation; for the autocorrelation, a white residual's.
    pub bound: f64,
    /// The largest |r| over the lags judged, and its lag.
    pub max_abs: f64,
    pub lag_of_max: i64,
    pub within_bounds: bool,
    /// Whether the test bears on the model: the autocorrelation does not
    /// (see `note`).
    pub judged: bool,
    /// What the test can and cannot say about this model.
    pub note: String,
    /// The correlation at lags `first_lag`, `first_lag` + 1, …
    pub first_lag: i64,
    pub values: Vec<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    pub validation_start_s: f64,
    pub validation_end_s: f64,
    pub method: String,
    pub outputs: Vec<OutputScore>,
    /// NRMSE of each sub-model's output, and the sensors' noise floor.
    pub submodels: BTreeMap<String, f64>,
    pub regimes: Vec<RegimeScore>,
    pub residual_tests: Vec<CorrelationTest>,
    #[serde(skip)]
    pub prediction: Prediction,
    #[serde(skip)]
    pub validation: Range<usize>,
}

/// How the model is compared with a record of these signals, in words.
pub fn method(signals: &Signals) -> String {
    let mut parts = Vec::new();
    for part in signals.parts() {
        parts.push(match part {
            Part::Hydraulic => "pressures from the measured pressures at each segment's start, driven by the command and the measured motion",
            Part::Mechanical if signals.tau.is_some() => "angle from a least-squares initial angle and velocity per segment, driven by the measured torque tau",
            Part::Mechanical => "angle from a least-squares initial angle and velocity per segment, driven by the measured torque D (p_a - p_b)",
            Part::Whole => "angle from the command, each segment started from the smoothed angle, velocity and the load pressure its acceleration asks for",
        });
    }
    format!("multiple shooting over 0.5 s segments: {}", parts.join("; "))
}

/// The outputs the record measures and the model predicts.
pub fn measured_outputs(signals: &Signals) -> Vec<&'static str> {
    if signals.parts().contains(&Part::Hydraulic) {
        vec!["p_a", "p_b", "theta"]
    } else {
        vec!["theta"]
    }
}

/// Compares the model with the measurements on the validation segment.
pub fn compare(plant: &PlantParams, effects: &Effects, signals: &Signals, estimation_fraction: f64) -> Comparison {
    let validation = signals.split(estimation_fraction)..signals.len();
    let prediction = predict(plant, effects, signals, validation.clone());
    let nrmse = nrmse_by_output(signals, &prediction, validation.clone());
    let outputs = measured_outputs(signals)
        .iter()
        .map(|o| OutputScore {
            output: (*o).to_owned(),
            fit_percent: 100.0 * (1.0 - nrmse[*o]),
            nrmse: nrmse[*o],
        })
        .collect();
    let v = validation.clone();
    let mut submodels = BTreeMap::from([(
        "sensor_floor_theta".to_owned(),
        encoder_step(&signals.theta) / 12f64.sqrt() / spread(&signals.theta[v.clone()]),
    )]);
    for part in signals.parts() {
        let name = format!("{part:?}").to_lowercase();
        submodels.insert(name, nrmse[part.output()]);
    }
    if nrmse.contains_key("pressures") {
        let pressure_spread = spread(&signals.p_a[v.clone()]).hypot(spread(&signals.p_b[v.clone()])) / 2f64.sqrt();
        submodels.insert(
            "sensor_floor_pressures".to_owned(),
            noise_std(&signals.p_a[v.clone()]).hypot(noise_std(&signals.p_b[v.clone()]))
                / 2f64.sqrt()
                / pressure_spread,
        );
    }
    Comparison {
        validation_start_s: signals.t[validation.start],
        validation_end_s: signals.t[validation.end - 1],
        method: method(signals),
        outputs,
        submodels,
        regimes: regimes(signals, &prediction, validation.clone()),
        residual_tests: residual_tests(plant, signals, &prediction, validation.clone()),
        prediction,
        validation,
    }
}

/// White sensor noise from second differences, which a smooth signal barely has.
fn noise_std(x: &[f64]) -> f64 {
    if x.len() < 3 {
        return 0.0;
    }
    let sum: f64 = x.windows(3).map(|w| (w[2] - 2.0 * w[1] + w[0]).powi(2)).sum();
    (sum / (x.len() - 2) as f64 / 6.0).sqrt()
}

/// The residual of each output at sample `k`.
pub fn residuals(signals: &Signals, prediction: &Prediction, k: usize) -> [(&'static str, f64); 3] {
    [
        ("p_a", signals.p_a[k] - prediction.p_a[k]),
        ("p_b", signals.p_b[k] - prediction.p_b[k]),
        ("theta", signals.theta[k] - prediction.theta[k]),
    ]
}

/// The operating regimes a residual is broken down by, in order.
pub const REGIMES: [&str; 8] = [
    "at_rest",
    "moving",
    "small_command",
    "large_command",
    "velocity_reversal",
    "angle_low_third",
    "angle_middle_third",
    "angle_high_third",
];

/// Which regimes sample `k` belongs to.
pub fn regimes_of(signals: &Signals, k: usize, reversal: &[bool], thirds: (f64, f64)) -> Vec<&'static str> {
    let mut out = Vec::with_capacity(4);
    out.push(if signals.velocity[k].abs() < REST_SPEED {
        "at_rest"
    } else {
        "moving"
    });
    out.push(if signals.u[k].abs() < SMALL_COMMAND {
        "small_command"
    } else {
        "large_command"
    });
    if reversal[k] {
        out.push("velocity_reversal");
    }
    out.push(if signals.theta[k] < thirds.0 {
        "angle_low_third"
    } else if signals.theta[k] < thirds.1 {
        "angle_middle_third"
    } else {
        "angle_high_third"
    });
    out
}

/// Samples within `REVERSAL_WINDOW_S` of a sign change of the moving velocity.
pub fn reversal_mask(signals: &Signals) -> Vec<bool> {
    let n = signals.len();
    let window = (REVERSAL_WINDOW_S / signals.dt).round() as usize;
    let mut mask = vec![false; n];
    let mut last_sign = 0.0;
    for k in 0..n {
        let v = signals.velocity[k];
        if v.abs() < REST_SPEED {
            continue;
        }
        if last_sign != 0.0 && v.signum() != last_sign {
            for m in mask.iter_mut().take((k + window).min(n)).skip(k.saturating_sub(window)) {
                *m = true;
            }
        }
        last_sign = v.signum();
    }
    mask
}

pub fn angle_thirds(signals: &Signals, range: Range<usize>) -> (f64, f64) {
    let mut angles = signals.theta[range].to_vec();
    angles.sort_by(f64::total_cmp);
    let at = |f: f64| angles[((angles.len() - 1) as f64 * f) as usize];
    (at(1.0 / 3.0), at(2.0 / 3.0))
}

fn regimes(signals: &Signals, prediction: &Prediction, validation: Range<usize>) -> Vec<RegimeScore> {
    let reversal = reversal_mask(signals);
    let thirds = angle_thirds(signals, validation.clone());
    let spreads = BTreeMap::from([
        ("p_a", spread(&signals.p_a[validation.clone()])),
        ("p_b", spread(&signals.p_b[validation.clone()])),
        ("theta", spread(&signals.theta[validation.clone()])),
    ]);
    let measured = measured_outputs(signals);
    let mut sums: BTreeMap<&str, (usize, BTreeMap<&str, f64>)> = BTreeMap::new();
    for k in validation {
        let r = residuals(signals, prediction, k);
        for regime in regimes_of(signals, k, &reversal, thirds) {
            let entry = sums.entry(regime).or_default();
            entry.0 += 1;
            for (output, e) in r.into_iter().filter(|(o, _)| measured.contains(o)) {
                *entry.1.entry(output).or_default() += e * e;
            }
        }
    }
    REGIMES
        .iter()
        .filter_map(|regime| {
            let (count, squares) = sums.get(regime)?;
            Some(RegimeScore {
                regime: (*regime).to_owned(),
                samples: *count,
                nrmse: squares
                    .iter()
                    .map(|(o, s)| ((*o).to_owned(), (s / *count as f64).sqrt() / spreads[o]))
                    .collect(),
            })
        })
        .collect()
}

/// The residual tests of MATLAB's `resid`, with bounds that hold for a
/// correct model of this kind. The model is output error, driven by
/// measured signals in closed loop, and restarted from the measurements at
/// each segment:
/// - its residual is the sensors' noise through their filters plus each
///   segment's start, coloured for a correct model too: the
///   autocorrelation is shown against a white residual's band, not judged;
/// - the cross-correlation with the model's input (the command, or without
///   one the torque that drives the rigid body) is judged at lags ≥ 1 only
///   (the residual against earlier commands: what the model should have
///   explained); at lags ≤ 0 the controller answers the residual, as any
///   closed loop does;
/// - its band is Bartlett's, var r(τ) = (1/N) Σ_m ρ_ee(m) ρ_uu(m), summed
///   over one segment's lags (segments start afresh, so the residual does
///   not correlate further): both signals' own correlation widens it.
fn residual_tests(
    plant: &PlantParams,
    signals: &Signals,
    prediction: &Prediction,
    validation: Range<usize>,
) -> Vec<CorrelationTest> {
    let n = validation.len();
    let white_bound = CONFIDENCE_Z / (n as f64).sqrt();
    let centred = |x: Vec<f64>| {
        let mean = x.iter().sum::<f64>() / x.len().max(1) as f64;
        x.into_iter().map(|v| v - mean).collect::<Vec<f64>>()
    };
    // A record without a valve command is driven by a torque, measured or
    // from the pressures: the residual is judged against that.
    let (input, test_name) = if signals.has_command {
        (signals.u[validation.clone()].to_vec(), "cross_correlation_u")
    } else {
        (
            validation.clone().map(|k| signals.torque(plant, k)).collect(),
            "cross_correlation_tau",
        )
    };
    let u = centred(input);
    let segment = ((super::SEGMENT_S / signals.dt).round() as usize).clamp(1, n.saturating_sub(1).max(1));
    let u_auto = autocorrelation(&u, segment);
    let mut out = Vec::new();
    let measured = measured_outputs(signals);
    for (index, output) in ["p_a", "p_b", "theta"].iter().enumerate() {
        if !measured.contains(output) {
            continue;
        }
        let e = centred(
            validation
                .clone()
                .map(|k| residuals(signals, prediction, k)[index].1)
                .collect(),
        );
        let e_auto = autocorrelation(&e, segment);
        let auto: Vec<f64> = e_auto.iter().take(MAX_LAG + 1).copied().collect();
        let mut whiteness = test(output, "autocorrelation", white_bound, 0, auto, 1);
        whiteness.judged = false;
        whiteness.note = "not judged: an output-error model predicts the output, not its noise; a correct one \
                          leaves the sensors' filtered noise and each segment's start in its residual, which \
                          are not white"
            .to_owned();
        out.push(whiteness);
        let variance =
            (e_auto[0] * u_auto[0] + 2.0 * (1..e_auto.len()).map(|m| e_auto[m] * u_auto[m]).sum::<f64>()) / n as f64;
        let bound = CONFIDENCE_Z * variance.max(0.0).sqrt().max(1.0 / (n as f64).sqrt());
        let cross: Vec<f64> = (-(MAX_LAG as i64)..=MAX_LAG as i64)
            .map(|lag| correlation(&e, &u, lag))
            .collect();
        let mut against_u = test(output, test_name, bound, -(MAX_LAG as i64), cross, MAX_LAG + 1);
        against_u.note = "lags ≥ 1 judged (earlier inputs the model should have explained); at lags ≤ 0 the \
                          controller answers the residual; Bartlett's band from both signals' autocorrelation, wide when the \
                          residual is strongly coloured, so that `diagnose` is the sharper test of a missing effect"
            .to_owned();
        out.push(against_u);
    }
    out
}

impl CorrelationTest {
    /// `passes`, `fails`, or `not judged`, as the tools print it.
    pub fn outcome(&self) -> &'static str {
        match (self.judged, self.within_bounds) {
            (false, _) => "not judged",
            (true, true) => "passes",
            (true, false) => "fails",
        }
    }
}

/// Normalized autocorrelation of `x` at lags 0 ..= `max_lag`.
fn autocorrelation(x: &[f64], max_lag: usize) -> Vec<f64> {
    (0..=max_lag.min(x.len().saturating_sub(1)))
        .map(|lag| correlation(x, x, lag as i64))
        .collect()
}

/// Normalized correlation of e(k) with x(k − lag).
fn correlation(e: &[f64], x: &[f64], lag: i64) -> f64 {
    let n = e.len() as i64;
    let mut sum = 0.0;
    for k in 0..n {
        let j = k - lag;
        if (0..n).contains(&j) {
            sum += e[k as usize] * x[j as usize];
        }
    }
    let norm = (e.iter().map(|v| v * v).sum::<f64>() * x.iter().map(|v| v * v).sum::<f64>()).sqrt();
    if norm > 0.0 {
        sum / norm
    } else {
        0.0
    }
}

/// `skip` leading values do not count (lag 0 of an autocorrelation is 1).
fn test(output: &str, name: &str, bound: f64, first_lag: i64, values: Vec<f64>, skip: usize) -> CorrelationTest {
    let (lag_of_max, max_abs) = values
        .iter()
        .enumerate()
        .skip(skip)
        .map(|(i, v)| (first_lag + i as i64, v.abs()))
        .fold((first_lag, 0.0), |best, x| if x.1 > best.1 { x } else { best });
    CorrelationTest {
        output: output.to_owned(),
        test: name.to_owned(),
        bound,
        max_abs,
        lag_of_max,
        within_bounds: max_abs <= bound,
        judged: true,
        note: String::new(),
        first_lag,
        values,
    }
}
