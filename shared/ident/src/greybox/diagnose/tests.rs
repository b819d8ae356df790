use std::collections::{BTreeMap, BTreeSet};

use super::{
    alike_in_the_model, before_after, both_exceed, error_share, joint_level, least_fall, nearest, no_effect_verdict,
    owens_t, paired_t, readings_on_lattice, reported, signed_rank, Candidate, PairedTest, Part, SegmentTest,
};
use statrs::distribution::{ContinuousCDF, Normal};

/// Owen's T at two closed forms: T(h, 1) = Φ(h)(1 − Φ(h)) / 2 and
/// T(0, a) = atan(a) / 2π; and the joint tail of two normals at three
/// correlations.
#[test]
fn owens_t_and_the_joint_tail_match_their_closed_forms() {
    let normal = Normal::new(0.0, 1.0).expect("the standard normal");
    for h in [0.5, 2.0, 3.5] {
        let expected = 0.5 * normal.cdf(h) * (1.0 - normal.cdf(h));
        assert!(
            (owens_t(h, 1.0) - expected).abs() < 1e-9 * expected.max(1e-3),
            "T({h}, 1)"
        );
    }
    assert!((owens_t(0.0, 2.0) - 2f64.atan() / (2.0 * std::f64::consts::PI)).abs() < 1e-9);
    let tail = 1.0 - normal.cdf(3.5);
    assert!((both_exceed(3.5, 1.0, &normal) - tail).abs() < 1e-12);
    let independent = both_exceed(3.5, 0.0, &normal);
    assert!(
        (independent - tail * tail).abs() < 1e-3 * tail * tail,
        "{independent} against {}",
        tail * tail
    );
    assert!(both_exceed(3.5, -0.9, &normal) < 1e-12);
}

/// Tests that read the same thing share the whole α; tests that share
/// nothing split it (Bonferroni, nearly); between, a level between.
#[test]
fn the_tests_level_follows_how_they_move_together() {
    let alpha = 0.001;
    let wave: Vec<f64> = (0..36).map(|i| (i as f64 * 0.7).sin()).collect();
    let twice: Vec<f64> = wave.iter().map(|x| 2.0 * x + 1.0).collect();
    let level = joint_level(&[&wave, &twice, &wave], alpha);
    assert!((level - alpha).abs() < 1e-6 * alpha, "{level}");
    let other: Vec<f64> = (0..36).map(|i| (i as f64 * 0.7).cos()).collect();
    let orthogonal: Vec<f64> = (0..36).map(|i| if i % 2 == 0 { 1.0 } else { -1.0 }).collect();
    let apart = joint_level(&[&wave, &other, &orthogonal], alpha);
    assert!(apart >= alpha / 3.0 && apart < 1.05 * alpha / 3.0, "{apart}");
    let noisy: Vec<f64> = wave.iter().zip(&other).map(|(w, o)| w + 0.3 * o).collect();
    let between = joint_level(&[&wave, &noisy], alpha);
    assert!(between > alpha / 2.0 && between < alpha, "{between}");
    assert_eq!(joint_level(&[&wave], alpha), alpha);
}

/// When no test passes, the one that came nearest is reported: a t
/// far below its threshold says less than a share just under its own.
#[test]
fn the_first_test_passed_is_reported_else_the_nearest() {
    let test = |kind, statistic, threshold| PairedTest {
        kind,
        statistic,
        threshold,
        segments: 36,
        effective: 30.0,
    };
    let kinds = |run: &[PairedTest]| reported(run).map(|t| t.kind.name());
    let (t, rank, share) = (SegmentTest::PairedT, SegmentTest::SignedRank, SegmentTest::ErrorShare);
    assert_eq!(
        kinds(&[test(t, 2.8, 3.7), test(rank, 1.0, 3.4), test(share, 3.6, 3.8)]),
        Some("error_share")
    );
    assert_eq!(
        kinds(&[test(t, 2.8, 3.7), test(rank, 3.5, 3.4), test(share, 5.0, 3.8)]),
        Some("signed_rank"),
        "the first passed, not the largest"
    );
    assert_eq!(
        kinds(&[test(t, -1.0, 3.7), test(share, -3.0, f64::INFINITY)]),
        Some("error_share"),
        "too few segments for a threshold: a share of 0, above a negative one"
    );
    assert_eq!(
        kinds(&[test(t, f64::INFINITY, f64::INFINITY), test(share, 1.0, 3.8)]),
        Some("error_share"),
        "an undefined share is never the nearest"
    );
    assert_eq!(kinds(&[]), None);
}

/// A delay's pattern on a foreign plant with noisy sensors: every sixth
/// segment, where the command steps, holds most of the error and loses
/// three quarters of it; the quiet ones are noise, a little better or
/// worse. Each segment's fall tells nothing (the t and the ranks fail),
/// the summed error falls by two thirds.
#[test]
fn a_fall_where_the_error_is_passes_the_error_share_test_alone() {
    let errors: Vec<(f64, f64)> = (0..36)
        .map(|i| match (i % 6, i % 2) {
            (0, _) => (40.0, 10.0),
            (_, 0) => (1.0, 0.95),
            _ => (1.0, 1.05),
        })
        .collect();
    let differences: Vec<f64> = errors.iter().map(|(b, a)| (b / a).ln()).collect();
    let n = differences.len() as f64;
    assert!(!paired_t(&differences, n, 0.0005).passed());
    assert!(!signed_rank(&differences, n, 0.0005).passed());
    let share = error_share(&errors, 0.0005);
    assert!(share.passed(), "{share:?}");
    // In other units, the same test.
    let scaled: Vec<(f64, f64)> = errors.iter().map(|(b, a)| (b * 1e-9, a * 1e-9)).collect();
    assert!((error_share(&scaled, 0.0005).statistic - share.statistic).abs() < 1e-9 * share.statistic);
    // The loud segments no better: nothing to pass.
    let unchanged: Vec<(f64, f64)> = errors
        .iter()
        .enumerate()
        .map(|(i, (b, a))| {
            if *b > 10.0 {
                (*b, b * if i % 12 == 0 { 1.05 } else { 0.95 })
            } else {
                (*b, *a)
            }
        })
        .collect();
    let null = error_share(&unchanged, 0.0005);
    assert!(!null.passed(), "{null:?}");
}

/// A delay's pattern on a foreign plant: most segments gain a little,
/// the few where the command steps gain 400-fold. Their spread sinks
/// the t (2.8 against 3.6); the ranks see 29 of 35 segments better.
#[test]
fn a_few_segments_gaining_by_orders_of_magnitude_pass_the_signed_rank_test() {
    let differences: Vec<f64> = [(0.3, 15), (-0.1, 6), (0.2, 9), (6.0, 5)]
        .iter()
        .flat_map(|&(d, count)| std::iter::repeat_n(d, count))
        .collect();
    let n = differences.len() as f64;
    let t = paired_t(&differences, n, 0.0005);
    assert!((t.statistic - 2.8029).abs() < 1e-3 && !t.passed(), "{t:?}");
    let rank = signed_rank(&differences, n, 0.0005);
    assert!((rank.statistic - 4.8759).abs() < 1e-3 && rank.passed(), "{rank:?}");
    // Fewer independent segments, the same ranks: less sure.
    let fewer = signed_rank(&differences, n / 4.0, 0.0005);
    assert!(
        (fewer.statistic - 4.8759 / 2.0).abs() < 1e-3 && !fewer.passed(),
        "{fewer:?}"
    );
}

#[test]
fn signed_ranks_average_ties_and_count_from_the_least_fall() {
    let differences: Vec<f64> = [1.0, -2.0, 3.0, 3.0, -0.5, 4.0, 5.0, -1.0, 2.0, 6.0]
        .iter()
        .map(|d| d + least_fall())
        .collect();
    // scipy.stats.wilcoxon(method="approx", correction=False): W+ = 47
    // of 55, z = 1.9915 with the ties' variance correction.
    let rank = signed_rank(&differences, 10.0, 0.01);
    assert!((rank.statistic - 1.99151).abs() < 1e-4, "{rank:?}");
    // A consistent sliver under the fall that counts is no gain.
    let sliver = vec![0.5 * least_fall(); 40];
    assert!(signed_rank(&sliver, 40.0, 0.01).statistic < -5.0);
}

fn sine(samples: usize) -> impl Iterator<Item = f64> {
    (0..samples).map(|k| 0.3 + 0.8 * (k as f64 * 1e-3 * 2.0).sin())
}

#[test]
fn quantized_readings_lie_on_their_lattice_and_continuous_ones_do_not() {
    let step = 2f64.to_radians();
    // An encoder whose zero is not the record's first reading.
    let quantized: Vec<f64> = sine(5000)
        .map(|x| 0.0123 + step * ((x - 0.0123) / step).round())
        .collect();
    for fitted in [step, 1.03 * step] {
        let (count, seen) = readings_on_lattice(&quantized, fitted).expect("on the lattice");
        assert_eq!(count, 5000);
        assert!((seen - step).abs() < 1e-12, "{seen}");
    }
    assert_eq!(
        readings_on_lattice(&quantized, 1.1 * step),
        None,
        "a fit of another step"
    );
    let continuous: Vec<f64> = sine(5000).collect();
    let seen = crate::greybox::fit::encoder_step(&continuous);
    assert_eq!(readings_on_lattice(&continuous, seen), None);
    let noisy: Vec<f64> = quantized
        .iter()
        .enumerate()
        .map(|(k, x)| x + 0.05 * step * ((k * 7919 % 1000) as f64 - 500.0) / 500.0)
        .collect();
    assert_eq!(readings_on_lattice(&noisy, step), None, "noise after the encoder");
}

fn turned_down(effect: &str, statistic: f64, before: f64, after: f64) -> Candidate {
    Candidate {
        effect: effect.to_owned(),
        output: "pressures".to_owned(),
        validation_nrmse_before: before,
        validation_nrmse_after: after,
        params: BTreeMap::new(),
        significant: false,
        evidence: String::new(),
        score: 1.0 - after / before,
        test: "paired_t",
        statistic,
        threshold: 3.6,
        segments: 36,
        effective_segments: 36.0,
        uncertainty: Default::default(),
        indistinguishable_from: Vec::new(),
        part: Part::Hydraulic,
        read_off_step: None,
        stands_in: None,
    }
}

/// The delay plant 1003003's verdict: of the falls the test turned
/// down, the one nearest its threshold, if one effect tried alone at
/// 5 % (t 1.69 over 36 segments) would have passed it.
#[test]
fn the_nearest_near_miss_is_named_only_when_it_would_pass_alone_and_is_the_effect_it_names() {
    let candidates = [
        turned_down("load_flexibility", 2.0, 0.0019, 0.0013),
        turned_down("time_delay", 2.1, 0.0266, 0.0232),
        turned_down("gravity_load", 2.5, 0.0019, 0.0020),
        turned_down("deadzone", 0.0, 0.0266, 0.0266),
    ];
    let all: BTreeSet<String> = candidates.iter().map(|c| c.effect.clone()).collect();
    assert_eq!(
        nearest(&candidates, &all).map(|c| c.effect.as_str()),
        Some("time_delay")
    );
    // A flexible load damped beyond critical is not one.
    let mut plausible = all.clone();
    plausible.remove("time_delay");
    assert_eq!(
        nearest(&candidates, &plausible).map(|c| c.effect.as_str()),
        Some("load_flexibility")
    );
    let weak = [turned_down("gravity_load", 0.7, 0.0303, 0.0281)];
    assert!(nearest(&weak, &all).is_none(), "t 0.7 passes nothing alone");
}

/// The same plant: the flexible load damped beyond critical passed the
/// error-share test (4.6 against 3.6) as a stand-in.
#[test]
fn a_stand_in_that_passes_the_test_says_something_outside_the_catalog_is_missing() {
    let mut stand_in = turned_down("load_flexibility", 4.6, 0.0019, 0.0013);
    stand_in.stands_in = Some("its coupling is damped beyond critical (ζ = 23.83): nothing rings".to_owned());
    let near = turned_down("time_delay", 2.7, 0.0266, 0.0232);
    let plausible: BTreeSet<String> = ["time_delay".to_owned()].into();
    let both = no_effect_verdict(&[stand_in.clone(), near.clone()], &plausible, &BTreeMap::new());
    assert!(
        both.starts_with("no effect of the catalog helps significantly, yet `load_flexibility`"),
        "{both}"
    );
    assert!(
        both.contains("something the catalog lacks is missing") && both.contains("`time_delay`"),
        "{both}"
    );
    let alone = no_effect_verdict(&[stand_in], &BTreeSet::new(), &BTreeMap::new());
    assert!(alone.contains("ζ = 23.83") && !alone.contains("nearest"), "{alone}");
    assert!(no_effect_verdict(&[near], &plausible, &BTreeMap::new())
        .starts_with("no effect of the catalog helps significantly; the nearest"));
    let fitted_well: BTreeMap<String, f64> = [("p_a".to_owned(), 0.0266), ("theta".to_owned(), 0.002)].into();
    let nothing = no_effect_verdict(
        &[turned_down("deadzone", 0.0, 0.0266, 0.0266)],
        &plausible,
        &fitted_well,
    );
    assert!(
        nothing.ends_with("the model explains this data as well as it can"),
        "{nothing}"
    );
}

/// A saturation well inside the command's range was turned down while
/// the baseline fitted the pressures at NRMSE 0.857: the verdict never
/// says the model explains such data; it says what is left, and how much.
#[test]
fn a_baseline_that_fits_badly_is_never_said_to_explain_the_data() {
    let baseline: BTreeMap<String, f64> = [
        ("p_a".to_owned(), 0.857),
        ("p_b".to_owned(), 0.85),
        ("pressures".to_owned(), 0.853),
        ("theta".to_owned(), 0.004),
    ]
    .into();
    let verdict = no_effect_verdict(
        &[turned_down("saturation", 0.0, 0.857, 0.857)],
        &BTreeSet::new(),
        &baseline,
    );
    assert!(!verdict.contains("as well as it can"), "{verdict}");
    assert!(
        verdict.contains("p_a (NRMSE 0.857, a fit of 14 %) and p_b") && !verdict.contains("theta ("),
        "{verdict}"
    );
}

#[test]
fn a_change_is_printed_with_the_decimals_that_show_it() {
    assert_eq!(before_after(0.0266, 0.0232), "0.0266 → 0.0232");
    assert_eq!(before_after(0.001914, 0.0019134), "0.001914 → 0.001913");
    assert_eq!(before_after(0.02, 0.02), "0.0200 → 0.0200");
}

/// Without pressures, Coulomb friction after a dead band was added
/// (foreign plant 1117003, both hidden): both named, and that the record
/// cannot tell whether both are there; not with pressures, nor beside an
/// effect that acts otherwise.
#[test]
fn a_near_miss_alike_on_the_angle_with_an_effect_in_the_model_names_both() {
    let mut near = turned_down("coulomb_friction", 2.7, 0.0195, 0.0191);
    near.part = Part::Whole;
    let band: BTreeSet<String> = ["deadzone".to_owned()].into();
    let said = alike_in_the_model(&near, &band).expect("both named");
    assert!(
        said.contains("`coulomb_friction`") && said.contains("`deadzone`"),
        "{said}"
    );
    assert!(alike_in_the_model(&near, &["gravity_load".to_owned()].into()).is_none());
    near.part = Part::Mechanical;
    assert!(alike_in_the_model(&near, &band).is_none(), "a torque tells them apart");
}
