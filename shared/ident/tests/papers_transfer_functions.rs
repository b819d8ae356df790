//! The papers' identified transfer functions, recovered from data simulated
//! from them: the rotary paper's eq. (18) and the crane paper's eq. (7).

use hydractl_ident::spectral::welch;
use hydractl_ident::tf::simulate;
use hydractl_ident::{identify_tf, Method, TfOptions};
use hydractl_lti::TransferFunction;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Steps of random height with random dwell, as the papers' valve-current
/// experiments ("a step with additional random disturbance").
fn excitation(n: usize, seed: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut u = Vec::with_capacity(n);
    while u.len() < n {
        let dwell = rng.random_range(20..400);
        let level: f64 = rng.random_range(-1.0..1.0);
        u.extend(std::iter::repeat_n(level, dwell));
    }
    u.truncate(n);
    u
}

/// Identifies `truth` from noisy data (1% output noise) over several seeds
/// and returns (fit %, natural frequency of the found pair) for each.
fn identify_over_seeds(truth: &TransferFunction, method: Method, seeds: std::ops::Range<u64>) -> Vec<(f64, f64)> {
    let ts = 1e-3;
    seeds
        .map(|seed| {
            let u = excitation(60_000, seed);
            let clean = simulate(truth, &u, ts).expect("simulates");
            let spread = (clean.iter().map(|v| v * v).sum::<f64>() / clean.len() as f64).sqrt();
            let noise = Normal::new(0.0, 0.01 * spread).expect("normal");
            let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
            let y: Vec<f64> = clean.iter().map(|v| v + noise.sample(&mut rng)).collect();
            let options = TfOptions {
                poles: 4,
                zeros: 3,
                method,
                estimation_fraction: 0.7,
            };
            let fit = identify_tf(&u, &y, ts, options).expect("identifies");
            let pair = fit.tf.resonances().first().map_or(f64::NAN, |r| r.0);
            (fit.fit_percent, pair)
        })
        .collect()
}

/// The bar, over every seed: a validation fit of at least 95% and
/// the complex pair's natural frequency within 5% (both methods find it
/// within 1%).
fn check(name: &str, truth: TransferFunction, method: Method) {
    let true_pair = truth.resonances()[0].0;
    for (seed, (fit, pair)) in (1..6).zip(identify_over_seeds(&truth, method, 1..6)) {
        eprintln!("{name} {method:?} seed {seed}: fit {fit:.2}%, pair {pair:.3} against {true_pair:.3} rad/s");
        assert!(fit >= 95.0, "{name} seed {seed}: fit {fit:.1}%");
        assert!(
            (pair - true_pair).abs() <= 0.01 * true_pair,
            "{name} seed {seed}: pair {pair} vs {true_pair}"
        );
    }
}

fn rotary_eq18() -> TransferFunction {
    TransferFunction::new(
        vec![20.79, -1696.0, 8.005e4, 1.139e5],
        vec![1.0, 35.68, 1428.0, 1.972e4, 2.783e4],
    )
    .expect("tf")
}

fn crane_eq7() -> TransferFunction {
    TransferFunction::new(
        vec![2.123e5, 4.253e7, 4.579e8, 6.197e8],
        vec![1.0, 15.68, 647.2, 8636.0, 2.353e4],
    )
    .expect("tf")
}

#[test]
fn rotary_paper_eq18_by_output_error() {
    check("eq. 18", rotary_eq18(), Method::Oe);
}

#[test]
fn crane_paper_eq7_by_output_error() {
    check("eq. 7", crane_eq7(), Method::Oe);
}

#[test]
fn rotary_paper_eq18_by_prediction_error() {
    check("eq. 18", rotary_eq18(), Method::Pem);
}

#[test]
fn crane_paper_eq7_by_prediction_error() {
    check("eq. 7", crane_eq7(), Method::Pem);
}

/// The true gain's peak above `low`, on a fine grid.
fn true_peak(truth: &TransferFunction, low: f64, high: f64) -> f64 {
    let grid: Vec<f64> = (0..20_000).map(|i| low + (high - low) * i as f64 / 20_000.0).collect();
    grid.iter()
        .copied()
        .max_by(|a, b| {
            truth
                .frequency_response(*a)
                .norm()
                .total_cmp(&truth.frequency_response(*b).norm())
        })
        .unwrap_or(f64::NAN)
}

/// Welch's spectra and the empirical transfer function of the papers' own
/// models, from the valve-current steps with 1% output noise: the estimate
/// follows the true gain where it is coherent, and its peak is the valve
/// resonance.
fn check_spectrum(name: &str, truth: TransferFunction, band: (f64, f64), segment: usize) {
    let ts = 1e-3;
    let u = excitation(120_000, 7);
    let clean = simulate(&truth, &u, ts).expect("simulates");
    let spread = (clean.iter().map(|v| v * v).sum::<f64>() / clean.len() as f64).sqrt();
    let noise = Normal::new(0.0, 0.01 * spread).expect("normal");
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let y: Vec<f64> = clean.iter().map(|v| v + noise.sample(&mut rng)).collect();
    let s = welch(&u, &y, ts, segment).expect("spectrum");
    let mut compared = 0;
    for k in 0..s.frequency_rad_s.len() {
        let w = s.frequency_rad_s[k];
        if (2.0..=60.0).contains(&w) && s.coherence[k] > 0.9 {
            let exact = truth.frequency_response(w).norm();
            assert!(
                (s.gain[k] - exact).abs() <= 0.1 * exact,
                "{name}: at {w:.1} rad/s the estimate {} against {exact}",
                s.gain[k]
            );
            compared += 1;
        }
    }
    assert!(compared > 20, "{name}: {compared} coherent bins");
    let peak = s.resonance(band.0, band.1, 0.8).expect("a resonance");
    let exact = true_peak(&truth, band.0, band.1);
    assert!(
        (peak.frequency_rad_s - exact).abs() <= 0.1 * exact,
        "{name}: peak at {} against {exact}",
        peak.frequency_rad_s
    );
}

#[test]
fn rotary_paper_eq18_spectrum_shows_the_valve_resonance() {
    // Its gain dips at 17 rad/s and peaks near 28 rad/s.
    check_spectrum("eq. 18", rotary_eq18(), (10.0, 100.0), 4096);
}

#[test]
fn crane_paper_eq7_spectrum_shows_the_valve_resonance() {
    // Damping 0.023: a peak 1.1 rad/s wide at half power, which needs a
    // longer window (0.38 rad/s resolution) than eq. 18's, as the crane
    // paper's "different hamming windows" (its Fig. 11).
    check_spectrum("eq. 7", crane_eq7(), (5.0, 100.0), 16_384);
}
