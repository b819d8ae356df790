//! The diagnosis in words: each effect's evidence, and the verdict when
//! no effect is significant.

use super::*;

/// What the diagnosis found for one effect, for its words.
pub(super) struct Judgement {
    pub(super) before: f64,
    pub(super) after: f64,
    pub(super) significant: bool,
    pub(super) test: PairedTest,
    pub(super) found_nothing: bool,
    /// Fitted to the value at which the effect does nothing.
    pub(super) at_null: bool,
    pub(super) resolution: Option<f64>,
    pub(super) not_itself: Option<String>,
    /// How many readings lie on the encoder's lattice, and its step, if all do.
    pub(super) on_lattice: Option<(usize, f64)>,
    /// The refit's validation NRMSE without the effect, when the effect
    /// itself removes too little of it: the gain was the refit's.
    pub(super) refit_alone: Option<f64>,
}

/// Which test over the validation segments decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum SegmentTest {
    /// A t-test of the mean log ratio: strongest when the gain is spread
    /// over the segments.
    PairedT,
    /// A signed-rank test: strongest when a few segments gain by orders
    /// of magnitude and widen the t-test's spread.
    SignedRank,
    /// A t-test of the share of the whole validation error removed (the
    /// segments' summed squared errors, after over before): strongest when
    /// the segments that hold most of the error gain and the quiet ones,
    /// noise alone, cannot (a delay, seen where the command steps).
    ErrorShare,
    /// The error-share t over segments that start just before each large
    /// step of the command, sample by sample: a delay told from a lag,
    /// which between the steps takes up the delay's phase.
    StepWindows,
}

/// The verdict when the first effect is significant but the record cannot
/// tell it from others: every one named, each with what it does, and the
/// first added only as the data's slight preference.
pub(super) fn tied_verdict(best: &Candidate, candidates: &[Candidate]) -> String {
    let others: Vec<String> = best
        .indistinguishable_from
        .iter()
        .filter_map(|name| candidates.iter().find(|c| &c.effect == name))
        .map(|c| {
            format!(
                "`{}` ({})",
                c.effect,
                before_after(c.validation_nrmse_before, c.validation_nrmse_after)
            )
        })
        .collect();
    format!(
        "add `{}` or {}: the record cannot tell them apart (each removes the {} error alike: `{}` {}, {} = {:.1} over {} segments, \
         threshold {:.1}; none beats another by the {:.0}% that counts); `{}` removes slightly more, and a record that tells them \
         apart decides (other signals, other motions)",
        best.effect,
        others.join(" or "),
        best.output,
        best.effect,
        before_after(best.validation_nrmse_before, best.validation_nrmse_after),
        best.statistic_symbol(),
        best.statistic,
        best.segments,
        best.threshold,
        100.0 * MIN_ERROR_REMOVED,
        best.effect
    )
}

/// The verdict when no effect is significant: whether a fit that is not
/// the effect it names still showed that something is missing, and the
/// catalog's near miss, if any.
pub(super) fn no_effect_verdict(
    candidates: &[Candidate],
    plausible_effects: &BTreeSet<String>,
    baseline: &BTreeMap<String, f64>,
) -> String {
    let verdict = catalog_verdict(candidates, plausible_effects);
    // Nothing of the catalog helps, but the baseline may still be far off:
    // never say it explains the data then; say what is left and how much.
    let unexplained: Vec<String> = ["p_a", "p_b", "theta"]
        .into_iter()
        .filter_map(|o| baseline.get(o).map(|v| (o, *v)))
        .filter(|(_, nrmse)| *nrmse > crate::greybox::UNEXPLAINED_NRMSE)
        .map(|(o, nrmse)| format!("{o} (NRMSE {nrmse:.3}, a fit of {:.0} %)", 100.0 * (1.0 - nrmse)))
        .collect();
    if unexplained.is_empty() {
        return verdict;
    }
    let head = verdict
        .strip_suffix(": the model explains this data as well as it can")
        .unwrap_or(&verdict);
    format!(
        "{head}; but the model leaves much of {} unexplained, which no effect of the catalog takes: \
         a parameter far from the data sheet's, a sensor's fault or scaling, or an effect the catalog lacks",
        unexplained.join(" and ")
    )
}

/// Effects that act alike on the angle: from the command and the angle
/// alone, each holds the load still while the command is small (a band of
/// the valve that passes no flow; a friction the drive must overcome).
const ALIKE_ON_THE_ANGLE: [(&str, &str); 1] = [("deadzone", "coulomb_friction")];

/// When the near miss acts on the angle alike with an effect the model
/// already has, and the record has neither pressures nor a torque to tell
/// them apart: both named, and that the record cannot say whether both are
/// there (the one in the model may hold the other's share too).
pub(super) fn alike_in_the_model(near: &Candidate, in_model: &BTreeSet<String>) -> Option<String> {
    if near.part != Part::Whole {
        return None;
    }
    let other = ALIKE_ON_THE_ANGLE.iter().find_map(|&(a, b)| {
        if near.effect == a {
            Some(b)
        } else if near.effect == b {
            Some(a)
        } else {
            None
        }
    })?;
    in_model.contains(other).then(|| {
        format!(
            "from the command and the angle alone, `{}` and the `{other}` in the model act alike (each holds the load still while the command is small), and without pressures or a torque this record cannot tell whether both are there",
            near.effect
        )
    })
}

/// The verdict from the candidates alone.
fn catalog_verdict(candidates: &[Candidate], plausible_effects: &BTreeSet<String>) -> String {
    // A fit that clears the test without being the effect it names
    // says that something is missing all the same, only not
    // something of the catalog.
    let missing = candidates
        .iter()
        .filter(|c| c.stands_in.is_some())
        .max_by(|a, b| a.share_of_threshold().total_cmp(&b.share_of_threshold()))
        .map(|c| {
            format!(
                "`{}` lowers the {} validation NRMSE {} ({}) without being what it names ({}): something the catalog lacks is missing",
                c.effect,
                c.output,
                before_after(c.validation_nrmse_before, c.validation_nrmse_after),
                c.test_figures(),
                c.stands_in.as_deref().unwrap_or_default(),
            )
        });
    // A fall the test could not make sure of is worth a user's
    // knowing: a longer record, or one that excites it more, may.
    let near = nearest(candidates, plausible_effects).map(|near| {
        format!(
            "the nearest, `{}`, lowers the {} validation NRMSE {}, not surely ({}; tried alone, at {:.0} %, it would pass): a longer record may tell",
            near.effect,
            near.output,
            before_after(near.validation_nrmse_before, near.validation_nrmse_after),
            near.test_figures(),
            100.0 * NEAR_MISS_ALPHA,
        )
    });
    match (missing, near) {
        (Some(missing), Some(near)) => {
            format!("no effect of the catalog helps significantly, yet {missing}; of the catalog, {near}")
        }
        (Some(missing), None) => format!("no effect of the catalog helps significantly, yet {missing}"),
        (None, Some(near)) => format!("no effect of the catalog helps significantly; {near}"),
        (None, None) => {
            "no effect of the catalog helps significantly: the model explains this data as well as it can".to_owned()
        }
    }
}

/// Of the `plausible` effects (fits that are the effect they name) that
/// lower their output's error and that the test turned down, though it
/// would have passed them at [`NEAR_MISS_ALPHA`] as the only effect tried,
/// the one closest to its threshold.
pub(super) fn nearest<'a>(candidates: &'a [Candidate], plausible: &BTreeSet<String>) -> Option<&'a Candidate> {
    let nominal = |c: &Candidate| {
        if c.test == SegmentTest::SignedRank.name() {
            z_threshold(NEAR_MISS_ALPHA)
        } else {
            t_threshold(c.effective_segments, NEAR_MISS_ALPHA)
        }
    };
    candidates
        .iter()
        .filter(|c| {
            plausible.contains(&c.effect)
                && !c.significant
                && c.statistic >= nominal(c)
                && c.statistic < c.threshold
                && c.validation_nrmse_after < c.validation_nrmse_before
        })
        .max_by(|a, b| a.share_of_threshold().total_cmp(&b.share_of_threshold()))
}

/// The evidence for an effect in plain words, from the data and the fit.
pub(super) fn evidence(
    kind: EffectKind,
    part: Part,
    params: &BTreeMap<String, f64>,
    signals: &Signals,
    refit: &Model,
    judgement: Judgement,
) -> String {
    let Judgement {
        before,
        after,
        significant,
        test,
        found_nothing,
        at_null,
        resolution,
        not_itself,
        on_lattice,
        refit_alone,
    } = judgement;
    let get = |key: &str| params.get(key).copied().unwrap_or(f64::NAN);
    let went = before_after(before, after);
    let change = format!("; with it the {} validation NRMSE goes {went}", part.output());
    let what = match kind {
        // Without pressures the valve's effects show in the motion only.
        EffectKind::Deadzone if part == Part::Whole => {
            let (width, offset) = (get("width"), get("offset"));
            let share = share(&signals.u, |u| (u - offset).abs() < width);
            format!(
                "the load does not move while the command stays within {width:.3} of {offset:+.3} ({:.0}% of the samples): valve dead-zone, its null offset {offset:+.3}",
                100.0 * share
            )
        }
        EffectKind::Saturation if part == Part::Whole => format!(
            "beyond |u| = {:.3} the load moves no faster as the command grows: the spool is at its stop",
            get("limit")
        ),
        EffectKind::TimeDelay if part == Part::Whole => format!(
            "the motion answers the command {:.1} ms later than the valve and the load explain: a pure delay",
            1e3 * get("delay_s")
        ),
        EffectKind::AsymmetricGain if part == Part::Whole => format!(
            "the load moves {:.0}% as fast for negative commands as for positive ones: asymmetric flow gain",
            100.0 * get("ratio")
        ),
        EffectKind::CoulombFriction if part == Part::Whole => format!(
            "the load rests until the valve has built about {:.0} N·m, and moving costs {:.0} N·m more than viscous friction: Coulomb friction",
            get("breakaway"),
            get("coulomb")
        ),
        EffectKind::Deadzone => {
            let (width, offset) = (get("width"), get("offset"));
            let share = share(&signals.u, |u| (u - offset).abs() < width);
            format!(
                "the pressures do not build while the command stays within {width:.3} of {offset:+.3} ({:.0}% of the samples) though the baseline says they should: valve dead-zone",
                100.0 * share
            )
        }
        EffectKind::Saturation => {
            let limit = get("limit");
            let share = share(&signals.u, |u| u.abs() > limit);
            format!(
                "beyond |u| = {limit:.3} ({:.0}% of the samples) the pressures change no faster as the command grows: the spool is at its stop",
                100.0 * share
            )
        }
        EffectKind::TimeDelay => format!(
            "the pressures answer the command {:.1} ms later than the valve's own dynamics explain: a pure delay",
            1e3 * get("delay_s")
        ),
        EffectKind::AsymmetricGain => format!(
            "the pressures move {:.0}% as fast for negative commands as for positive ones: asymmetric flow gain",
            100.0 * get("ratio")
        ),
        EffectKind::OrificeFlow => {
            "the flow, and so the pressure rate, falls as the chamber pressure nears supply or tank: turbulent orifice flow (√Δp)".to_owned()
        }
        EffectKind::CoulombFriction => format!(
            "the load rests while the measured torque builds to {:.0} N·m, and moving costs {:.0} N·m more than viscous friction: Coulomb friction",
            get("breakaway"),
            get("coulomb")
        ),
        EffectKind::GravityLoad => format!(
            "the torque needed to hold the load follows sin(θ − {:.2}) with {:.0} N·m amplitude: a gravity load",
            get("offset"),
            get("amplitude")
        ),
        EffectKind::Backlash => format!(
            "after each velocity reversal the encoder stands still for {:.4} rad of the actuator's motion: backlash",
            get("width")
        ),
        EffectKind::Quantization => format!(
            "the angle moves in steps of {:.4} rad ({:.2}°) and no finer: a coarse encoder",
            get("step"),
            get("step").to_degrees()
        ),
        EffectKind::LoadFlexibility => {
            let inertia = refit.plant.inertia;
            let fraction = get("load_fraction");
            let stiffness = get("stiffness");
            let mode = (stiffness * (1.0 / (inertia * fraction) + 1.0 / (inertia * (1.0 - fraction)))).sqrt();
            // With the load's share of the inertia at its edge the data
            // fixes the coupling's stiffness but not the mode's frequency
            // (our own simulator's 36 rad/s load fits 110 rad/s so).
            match crate::greybox::fit::param_at_edge(kind, "load_fraction", params) {
                Some(edge) => format!(
                    "the angle answers the torque through a spring, which a rigid body cannot: a flexible load ({stiffness:.0} N·m/rad); \
                     {edge}, so the data does not fix how the inertia is shared, nor the frequency it rings at"
                ),
                None => format!(
                    "the angle rings at {mode:.0} rad/s against the torque, which a rigid body cannot: a flexible load ({stiffness:.0} N·m/rad)"
                ),
            }
        }
    };
    let (name, of_what) = match test.kind {
        SegmentTest::PairedT => ("paired t", "each segment's fall"),
        SegmentTest::SignedRank => ("signed-rank z", "each segment's fall"),
        SegmentTest::ErrorShare => ("error-share t", "the fall of the summed error"),
        SegmentTest::StepWindows => ("error-share t at the command's steps", "the fall of the summed error"),
    };
    let over = if test.kind == SegmentTest::StepWindows {
        format!(
            "the windows of {} steps ({:.1} effective samples)",
            test.segments, test.effective
        )
    } else {
        format!(
            "{} validation segments ({:.1} effective)",
            test.segments, test.effective
        )
    };
    let judged = format!(
        "{name} over {over} of {of_what} beyond {:.0}% of the error: {:.1} against {:.1} (one-sided, α = {FAMILY_ALPHA} shared by the effects tried and the segment tests)",
        100.0 * MIN_ERROR_REMOVED,
        test.statistic,
        test.threshold
    );
    let output = part.output();
    if let Some((readings, step)) = on_lattice.filter(|_| significant) {
        return format!(
            "all {readings} readings of the angle lie on multiples of {step:.5} rad (within {:.0}% of a step), where a continuous reading lands so by a chance of {:.0}%; {judged}; {what}{change}",
            100.0 * LATTICE_TOLERANCE,
            200.0 * LATTICE_TOLERANCE
        );
    }
    if at_null {
        format!("not significant: fitted, it ends at the value where it does nothing, so it is the baseline ({judged})")
    } else if found_nothing {
        format!("not significant: fitted as hard as the baseline, it lowers the estimation loss no further ({judged})")
    } else if let Some(alone) = refit_alone.filter(|_| test.passed() && after < before) {
        format!(
            "not significant: its refit takes the {output} validation NRMSE {went}, but the same refit without it does nearly as well \
             ({alone:.4}): the gain is a better fit of the model's other parameters, not the effect ({judged})"
        )
    } else if let Some(why) = not_itself.filter(|_| test.passed() && after < before) {
        format!(
            "not named: fitted, it takes the {output} validation NRMSE {went}, but {why}: \
             it stands in for something the catalog lacks ({judged})"
        )
    } else if let Some(share) = resolution.filter(|s| *s < RESOLUTION_SHARE) {
        format!(
            "not a missing effect: the angle moves in steps of {:.3e} rad, {:.2}% of its spread, the encoder's own resolution (under {:.0}%); \
             modelling the staircase takes the {output} validation NRMSE {went} ({judged})",
            get("step"),
            100.0 * share,
            100.0 * RESOLUTION_SHARE
        )
    } else if significant {
        format!("{judged}; {what}{change}")
    } else if after > before {
        format!("not significant: fitted, it makes the {output} validation NRMSE worse, {went} ({judged})")
    } else {
        format!(
            "not significant: fitted, it lowers the {output} validation NRMSE {went}, not surely by more than the {:.0}% that counts ({judged})",
            100.0 * MIN_ERROR_REMOVED
        )
    }
}

/// "0.0266 → 0.0232": with as many decimals (4 to 8) as it takes to tell
/// them apart, so that a change is never printed as none.
pub(super) fn before_after(before: f64, after: f64) -> String {
    let digits = (4..=8)
        .find(|&d| format!("{before:.d$}") != format!("{after:.d$}"))
        .unwrap_or(4);
    format!("{before:.digits$} → {after:.digits$}")
}

pub(super) fn share(x: &[f64], predicate: impl Fn(f64) -> bool) -> f64 {
    x.iter().filter(|v| predicate(**v)).count() as f64 / x.len().max(1) as f64
}
