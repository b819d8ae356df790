//! The tests over the validation segments: paired t, signed rank, the
//! share of the error removed, and their joint level.

use super::*;

/// A one-sided paired test of the squared error, segment by segment.
#[derive(Debug, Clone, Copy)]
pub(super) struct PairedTest {
    pub(super) kind: SegmentTest,
    pub(super) statistic: f64,
    pub(super) threshold: f64,
    pub(super) segments: usize,
    pub(super) effective: f64,
}

impl SegmentTest {
    pub(super) fn name(self) -> &'static str {
        match self {
            SegmentTest::PairedT => "paired_t",
            SegmentTest::SignedRank => "signed_rank",
            SegmentTest::ErrorShare => "error_share",
            SegmentTest::StepWindows => "step_windows",
        }
    }
}

impl PairedTest {
    pub(super) fn passed(&self) -> bool {
        self.statistic > self.threshold
    }

    /// How near the test came to passing (see [`share_of_threshold`]).
    pub(super) fn share_of_threshold(&self) -> f64 {
        share_of_threshold(self.statistic, self.threshold)
    }
}

/// How near a test came to passing: its statistic over its threshold, the
/// same measure for a t and a z (least where undefined).
pub(super) fn share_of_threshold(statistic: f64, threshold: f64) -> f64 {
    let share = statistic / threshold;
    if share.is_nan() {
        f64::NEG_INFINITY
    } else {
        share
    }
}

/// The least fall of a segment's log squared error that counts:
/// d₀ = −2 ln(1 − [`MIN_ERROR_REMOVED`]).
pub(super) fn least_fall() -> f64 {
    -2.0 * (1.0 - MIN_ERROR_REMOVED).ln()
}

/// Effective segments under which the signed-rank test's normal
/// approximation is not trusted: the paired t alone then takes the whole α.
pub(super) const SIGNED_RANK_MIN_EFFECTIVE: f64 = 20.0;

/// Whether `after` predicts `part`'s output better than `before` by more
/// than [`MIN_ERROR_REMOVED`], segment by segment of `validation`. Three
/// one-sided tests share the effect's α (Bonferroni over the effects: α /
/// `tried`; among the tests, by how they move together, [`joint_level`]),
/// and the first that passes is reported, else the
/// one that came nearest (its statistic the largest share of its
/// threshold):
/// - a paired t of d, the log of each segment's squared error before over
///   after, against d₀ = [`least_fall`]: (mean(d) − d₀) / (sd(d) / √n_eff),
///   against the t quantile with n_eff − 1 degrees of freedom, n_eff the
///   segments' effective number (their autocorrelation);
/// - a signed-rank test of d − d₀, its variance scaled by n / n_eff (from
///   20 effective segments on, where its normal approximation holds);
/// - a t of R, the summed squared error after over before, against
///   (1 − [`MIN_ERROR_REMOVED`])², by the delta method for a ratio of sums
///   (see [`error_share`]).
pub(super) fn paired_test(
    signals: &Signals,
    part: Part,
    before: &Prediction,
    after: &Prediction,
    validation: Range<usize>,
    tried: usize,
) -> PairedTest {
    paired_test_at(signals, part, before, after, validation, FAMILY_ALPHA / tried as f64)
}

/// [`paired_test`] at the effect's level `alpha`.
pub(super) fn paired_test_at(
    signals: &Signals,
    part: Part,
    before: &Prediction,
    after: &Prediction,
    validation: Range<usize>,
    alpha: f64,
) -> PairedTest {
    let errors = segment_errors(signals, part, before, after, validation);
    let differences: Vec<f64> = errors
        .iter()
        .map(|(before, after)| {
            // The log of the ratio: each segment weighs alike, whatever its
            // error's size, and the same test holds in bar and in rad.
            let floor = 1e-12 * (before + after) + f64::MIN_POSITIVE;
            ((before + floor) / (after + floor)).ln()
        })
        .collect();
    let n = differences.len();
    // Neighbouring segments share slow errors (a drift, a regime): count
    // them as fewer independent ones.
    let effective = crate::greybox::fit::effective_sample_size(&differences, 1).clamp(1.0, n as f64);
    let with_rank = effective >= SIGNED_RANK_MIN_EFFECTIVE;
    // Each segment's part in each test's statistic: how the tests move
    // together, and so how much of the effect's α each may take.
    let ranks = signed_ranks(&differences).0;
    let share_part: Vec<f64> = share_residuals(&errors).1.iter().map(|r| -r).collect();
    let parts: Vec<&[f64]> = if with_rank {
        vec![&differences, &ranks, &share_part]
    } else {
        vec![&differences, &share_part]
    };
    let alpha = joint_level(&parts, alpha);
    let t = paired_t(&differences, effective, alpha);
    let rank = with_rank.then(|| signed_rank(&differences, effective, alpha));
    let share = error_share(&errors, alpha);
    let run: Vec<PairedTest> = [Some(t), rank, Some(share)].into_iter().flatten().collect();
    reported(&run).unwrap_or(t)
}

/// Of the tests run, in their order, the first that passed, else the one
/// that came nearest.
pub(super) fn reported(run: &[PairedTest]) -> Option<PairedTest> {
    run.iter()
        .find(|test| test.passed())
        .or_else(|| {
            run.iter()
                .max_by(|a, b| a.share_of_threshold().total_cmp(&b.share_of_threshold()))
        })
        .copied()
}

/// Each validation segment's squared error before and after, summed over
/// the part's outputs.
pub(super) fn segment_errors(
    signals: &Signals,
    part: Part,
    before: &Prediction,
    after: &Prediction,
    validation: Range<usize>,
) -> Vec<(f64, f64)> {
    let outputs: Vec<(&[f64], &[f64], &[f64])> = match part {
        Part::Hydraulic => vec![
            (&signals.p_a, &before.p_a, &after.p_a),
            (&signals.p_b, &before.p_b, &after.p_b),
        ],
        Part::Mechanical | Part::Whole => vec![(&signals.theta, &before.theta, &after.theta)],
    };
    crate::greybox::segments(signals, validation)
        .filter_map(|segment| {
            let (mut error_before, mut error_after) = (0.0, 0.0);
            let mut counted = 0;
            for (y, b, a) in &outputs {
                for k in segment.clone() {
                    if b[k].is_finite() && a[k].is_finite() {
                        error_before += (y[k] - b[k]).powi(2);
                        error_after += (y[k] - a[k]).powi(2);
                        counted += 1;
                    }
                }
            }
            (counted > 0).then_some((error_before, error_after))
        })
        .collect()
}

/// The one-sided t quantile at `alpha` for `effective` segments.
pub(super) fn t_threshold(effective: f64, alpha: f64) -> f64 {
    if effective < 2.0 {
        return f64::INFINITY;
    }
    StudentsT::new(0.0, 1.0, effective - 1.0)
        .map(|t| t.inverse_cdf(1.0 - alpha))
        .unwrap_or(f64::INFINITY)
}

/// The one-sided normal quantile at `alpha`.
pub(super) fn z_threshold(alpha: f64) -> f64 {
    Normal::new(0.0, 1.0)
        .map(|z| z.inverse_cdf(1.0 - alpha))
        .unwrap_or(f64::INFINITY)
}

/// The one-sided paired t of `differences` beyond [`least_fall`] at `alpha`.
pub(super) fn paired_t(differences: &[f64], effective: f64, alpha: f64) -> PairedTest {
    let n = differences.len();
    let threshold = t_threshold(effective, alpha);
    let mean = differences.iter().sum::<f64>() / n.max(1) as f64;
    let variance = differences.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n.max(2) - 1) as f64;
    let statistic = if variance > 0.0 {
        (mean - least_fall()) / (variance / effective).sqrt()
    } else if mean > least_fall() {
        f64::INFINITY
    } else {
        0.0
    };
    PairedTest {
        kind: SegmentTest::PairedT,
        statistic,
        threshold,
        segments: n,
        effective,
    }
}

/// The one-sided t of the share of the whole error removed, beyond
/// [`MIN_ERROR_REMOVED`] of its root mean square, at `alpha`: R = Σaᵢ / Σbᵢ
/// over the segments' squared errors after (a) and before (b), its
/// standard error sd(aᵢ − R·bᵢ) / (√n_eff · mean(b)) (the delta method for
/// a ratio of sums, n_eff from those residuals' autocorrelation), and the
/// statistic ((1 − share)² − R) / se. Its ratio, like the t's log, is the
/// same in bar and in rad.
pub(super) fn error_share(errors: &[(f64, f64)], alpha: f64) -> PairedTest {
    let n = errors.len();
    let sum_before: f64 = errors.iter().map(|(before, _)| before).sum();
    let (ratio, residuals) = share_residuals(errors);
    let effective = crate::greybox::fit::effective_sample_size(&residuals, 1).clamp(1.0, n.max(1) as f64);
    // The residuals sum to zero: that is R.
    let variance = residuals.iter().map(|r| r * r).sum::<f64>() / (n.max(2) - 1) as f64;
    let standard_error = variance.sqrt() / effective.sqrt() / (sum_before / n.max(1) as f64);
    let least = (1.0 - MIN_ERROR_REMOVED).powi(2);
    let statistic = if standard_error > 0.0 && standard_error.is_finite() {
        (least - ratio) / standard_error
    } else if ratio < least {
        f64::INFINITY
    } else {
        0.0
    };
    PairedTest {
        kind: SegmentTest::ErrorShare,
        statistic,
        threshold: t_threshold(effective, alpha),
        segments: n,
        effective,
    }
}

/// R = Σaᵢ / Σbᵢ over the segments' squared errors after (a) and before
/// (b), and each segment's residual aᵢ − R·bᵢ: its part in R's error.
pub(super) fn share_residuals(errors: &[(f64, f64)]) -> (f64, Vec<f64>) {
    let (sum_before, sum_after) = errors.iter().fold((0.0, 0.0), |(b, a), (eb, ea)| (b + eb, a + ea));
    let ratio = if sum_before > 0.0 { sum_after / sum_before } else { 1.0 };
    (ratio, errors.iter().map(|(b, a)| a - ratio * b).collect())
}

/// Each segment's signed rank of d − d₀ ([`least_fall`]) by its size, in
/// the segments' order (ties given their mean rank; zero for a zero or an
/// undefined d − d₀, which the test drops), and the ties' correction
/// Σ (t³ − t) to the rank sum's variance.
pub(super) fn signed_ranks(differences: &[f64]) -> (Vec<f64>, f64) {
    let beyond: Vec<f64> = differences.iter().map(|d| d - least_fall()).collect();
    let mut order: Vec<usize> = (0..beyond.len())
        .filter(|&i| beyond[i] != 0.0 && beyond[i].is_finite())
        .collect();
    order.sort_by(|&a, &b| beyond[a].abs().total_cmp(&beyond[b].abs()));
    let mut ranks = vec![0.0; beyond.len()];
    let mut tie_correction = 0.0;
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && beyond[order[j + 1]].abs() == beyond[order[i]].abs() {
            j += 1;
        }
        let rank = (i + j) as f64 / 2.0 + 1.0;
        for &k in &order[i..=j] {
            ranks[k] = rank.copysign(beyond[k]);
        }
        let tied = (j - i + 1) as f64;
        tie_correction += tied.powi(3) - tied;
        i = j + 1;
    }
    (ranks, tie_correction)
}

/// The level at which each of several one-sided tests is judged so that
/// the chance that any of them passes, on data where none should, stays
/// within `alpha`. The tests read the same segments: their statistics,
/// nearly normal, move together as each segment's `parts` in them do.
/// Hunter's bound holds that chance: the sum of the tests' levels less
/// the chance of passing two together, along the most correlated pairs (a
/// spanning tree). Between α / k (Bonferroni, tests that share nothing)
/// and α (one test asked k times).
pub(super) fn joint_level(parts: &[&[f64]], alpha: f64) -> f64 {
    let k = parts.len();
    if k < 2 {
        return alpha;
    }
    let mut correlations = vec![vec![0.0; k]; k];
    for i in 0..k {
        for j in 0..i {
            let r = pearson(parts[i], parts[j]);
            (correlations[i][j], correlations[j][i]) = (r, r);
        }
    }
    // The pairs of the tree: the most correlated first (Prim's), for
    // those share the most.
    let mut in_tree = vec![false; k];
    in_tree[0] = true;
    let mut pairs = Vec::with_capacity(k - 1);
    for _ in 1..k {
        let best = (0..k)
            .filter(|&i| in_tree[i])
            .flat_map(|i| (0..k).filter(|&j| !in_tree[j]).map(move |j| (i, j)))
            .max_by(|a, b| correlations[a.0][a.1].total_cmp(&correlations[b.0][b.1]));
        let Some((i, j)) = best else { break };
        in_tree[j] = true;
        pairs.push(correlations[i][j]);
    }
    let Ok(normal) = Normal::new(0.0, 1.0) else {
        return alpha / k as f64;
    };
    // The chance that any passes at the quantile c, by Hunter's bound;
    // it falls as c rises.
    let any_passes = |c: f64| {
        let one = 1.0 - normal.cdf(c);
        k as f64 * one - pairs.iter().map(|&r| both_exceed(c, r, &normal)).sum::<f64>()
    };
    let (mut low, mut high) = (
        normal.inverse_cdf(1.0 - alpha),
        normal.inverse_cdf(1.0 - alpha / k as f64),
    );
    for _ in 0..60 {
        let mid = 0.5 * (low + high);
        if any_passes(mid) > alpha {
            low = mid;
        } else {
            high = mid;
        }
    }
    1.0 - normal.cdf(high)
}

/// P(X > c, Y > c) for standard normals X, Y of correlation `r`:
/// 1 − Φ(c) − 2 T(c, √((1 − r) / (1 + r))), T Owen's function.
pub(super) fn both_exceed(c: f64, r: f64, normal: &Normal) -> f64 {
    let r = r.clamp(-1.0 + 1e-12, 1.0);
    let a = ((1.0 - r) / (1.0 + r)).sqrt();
    (1.0 - normal.cdf(c) - 2.0 * owens_t(c, a)).max(0.0)
}

/// Owen's T(h, a) = (1 / 2π) ∫₀ᵃ exp(−h²(1 + x²) / 2) / (1 + x²) dx, by
/// Simpson's rule; past x = 10 / |h| (and 10) the integrand is nil at the
/// quantiles judged here.
pub(super) fn owens_t(h: f64, a: f64) -> f64 {
    let upper = a.min(10.0 / h.abs().max(1.0));
    if upper <= 0.0 {
        return 0.0;
    }
    const STEPS: usize = 400;
    let step = upper / STEPS as f64;
    let f = |x: f64| (-0.5 * h * h * (1.0 + x * x)).exp() / (1.0 + x * x);
    let inner: f64 = (1..STEPS)
        .map(|i| f(i as f64 * step) * if i % 2 == 1 { 4.0 } else { 2.0 })
        .sum();
    (f(0.0) + inner + f(upper)) * step / 3.0 / (2.0 * std::f64::consts::PI)
}

/// The correlation of two equally long series; zero where either is flat.
pub(super) fn pearson(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len().min(y.len());
    if n < 2 {
        return 0.0;
    }
    let mean = |v: &[f64]| v[..n].iter().sum::<f64>() / n as f64;
    let (mx, my) = (mean(x), mean(y));
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x[..n].iter().zip(&y[..n]) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx).powi(2);
        syy += (b - my).powi(2);
    }
    let r = sxy / (sxx * syy).sqrt();
    if r.is_finite() {
        r
    } else {
        0.0
    }
}

/// The one-sided Wilcoxon signed-rank test of `differences` beyond
/// [`least_fall`] at `alpha`, by its normal approximation (ties given
/// their mean rank and the variance corrected for them, zeros dropped),
/// its variance scaled by n / n_eff. It judges the typical segment's fall;
/// the candidate must also lower the output's error as a whole.
pub(super) fn signed_rank(differences: &[f64], effective: f64, alpha: f64) -> PairedTest {
    let n = differences.len();
    let (ranks, tie_correction) = signed_ranks(differences);
    let positive_ranks: f64 = ranks.iter().filter(|r| **r > 0.0).sum();
    let m = ranks.iter().filter(|r| **r != 0.0).count() as f64;
    let mean = m * (m + 1.0) / 4.0;
    let variance = (m * (m + 1.0) * (2.0 * m + 1.0) / 24.0 - tie_correction / 48.0) * (n as f64 / effective);
    let statistic = if variance > 0.0 {
        (positive_ranks - mean) / variance.sqrt()
    } else {
        0.0
    };
    let threshold = z_threshold(alpha);
    PairedTest {
        kind: SegmentTest::SignedRank,
        statistic,
        threshold,
        segments: n,
        effective,
    }
}
