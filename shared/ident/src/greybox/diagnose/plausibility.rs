//! Whether a fitted effect is the effect it names: not its null value,
//! not below the data's resolution, an encoder's lattice seen in the
//! readings.

use super::*;

/// Why a fitted effect is not the effect its name says, if it is not: a
/// parameter pressed against the edge of its range, a play narrower than
/// the encoder's step, or a flexible load that does not ring (damped
/// beyond critical: a lag, not a resonance).
pub(super) fn not_itself(
    kind: EffectKind,
    params: &BTreeMap<String, f64>,
    signals: &Signals,
    refit: &Model,
) -> Option<String> {
    if let Some(edge) = crate::greybox::fit::at_edge(kind, params) {
        return Some(edge);
    }
    // A model that rounds the shaft as the encoder does holds its readings
    // at a reversal as long as rounding alone would: a play's gain beside
    // it is the play's.
    let rounds_as_the_encoder = refit.effects.0.contains_key(EffectKind::Quantization.name());
    if kind == EffectKind::Backlash && !rounds_as_the_encoder {
        let width = params.get("width").copied().unwrap_or(0.0);
        let step = crate::greybox::fit::encoder_step(&signals.theta);
        // A quantized reading may stand still for up to a step after any
        // reversal by rounding alone, on the level the shaft leaves and on
        // the one it comes back to.
        if width < 2.0 * step {
            return Some(format!(
                "its play, {width:.5} rad, is narrower than two steps of the encoder ({step:.5} rad each): rounding alone holds a reading that long at a reversal"
            ));
        }
    }
    if kind == EffectKind::Deadzone {
        let width = params.get("width").copied().unwrap_or(0.0);
        // Beside Coulomb friction a band of 0.0015 took a fifth of the
        // pressures' error on foreign plants that had none: the valve's
        // null behaves otherwise than the model's linear law there, and an
        // inverse that narrow changes nothing a loop does.
        if width < MIN_DEADZONE_WIDTH && params.get("offset").is_none_or(|o| o.abs() < MIN_DEADZONE_WIDTH) {
            return Some(format!(
                "its band, {width:.4} each side of the null, is under {MIN_DEADZONE_WIDTH} of the spool's travel: \
                 the valve's null region differs from the model's linear law, which no dead band's inverse would change"
            ));
        }
    }
    if kind == EffectKind::TimeDelay {
        let delay = params.get("delay_s").copied().unwrap_or(0.0);
        if let Some(lag) =
            crate::greybox::fit::pressure_lag_behind_motion(signals, &refit.plant, 0..signals.len(), 2.0 * delay)
        {
            if lag >= 0.5 * delay {
                return Some(format!(
                    "the pressures lag the motion they drive by {:.1} ms, as much as the fitted delay ({:.1} ms): the pressure transducers lag, not the valve",
                    1e3 * lag,
                    1e3 * delay
                ));
            }
        }
    }
    if kind == EffectKind::LoadFlexibility {
        let get = |key: &str| params.get(key).copied().unwrap_or(f64::NAN);
        let (stiffness, damping, fraction) = (get("stiffness"), get("damping"), get("load_fraction"));
        let inertia = refit.plant.inertia;
        let reduced = inertia * fraction * (1.0 - fraction);
        let damping_ratio = damping / (2.0 * (stiffness * reduced).sqrt());
        if damping_ratio.is_nan() || damping_ratio >= 1.0 {
            return Some(format!(
                "its coupling is damped beyond critical (ζ = {damping_ratio:.2}): nothing rings"
            ));
        }
    }
    None
}

/// The narrowest dead band worth naming, in command units (1 % of the
/// spool's travel each side of the null).
pub(super) const MIN_DEADZONE_WIDTH: f64 = 0.01;

/// The share of a step within which a reading counts as on the encoder's
/// lattice: a continuous reading lands so with a chance of twice this.
pub(super) const LATTICE_TOLERANCE: f64 = 0.01;

/// How many readings there are and their step, if every finite angle of the record lies
/// on the lattice of the step the data show, through the first (within
/// [`LATTICE_TOLERANCE`] of a step), and the fitted `step` is that step
/// within 5 %: the encoder's quantization seen in the readings themselves,
/// with no model. Readings of a continuous sensor would each land there by
/// a chance of 2 %, all of thousands of them never.
pub(super) fn readings_on_lattice(theta: &[f64], fitted: f64) -> Option<(usize, f64)> {
    let step = crate::greybox::fit::encoder_step(theta);
    if !(step > 0.0 && (fitted - step).abs() <= 0.05 * step) {
        return None;
    }
    let mut readings = theta.iter().filter(|t| t.is_finite());
    let origin = *readings.next()?;
    let mut count = 1;
    for reading in readings {
        let steps = (reading - origin) / step;
        if (steps - steps.round()).abs() > LATTICE_TOLERANCE {
            return None;
        }
        count += 1;
    }
    (count >= 100).then_some((count, step))
}

/// For the encoder's step: its share of the angle's spread on `validation`.
pub(super) fn resolution_share(
    kind: EffectKind,
    params: &BTreeMap<String, f64>,
    signals: &Signals,
    validation: Range<usize>,
) -> Option<f64> {
    (kind == EffectKind::Quantization)
        .then(|| params.get("step").copied().unwrap_or(0.0) / crate::greybox::fit::spread(&signals.theta[validation]))
}

/// Whether `params` leave `kind` doing nothing: no band, no play, no
/// delay, equal gains, no stop within the valve's travel.
pub(super) fn at_null_value(kind: EffectKind, params: &BTreeMap<String, f64>) -> bool {
    let get = |key: &str| params.get(key).copied().unwrap_or(f64::NAN);
    match kind {
        // A band of no width off zero is still the valve's null offset.
        EffectKind::Deadzone => get("width") < 1e-6 && get("offset").abs() < 1e-6,
        EffectKind::Backlash => get("width") < 1e-6,
        EffectKind::TimeDelay => get("delay_s") < 1e-7,
        EffectKind::AsymmetricGain => (get("ratio") - 1.0).abs() < 1e-6,
        EffectKind::Saturation => get("limit") >= 1.0 - 1e-9,
        _ => false,
    }
}

/// The validation NRMSE of `refit` with `kind` taken out, when the effect
/// itself does not remove the share of the error that counts from it (by
/// the test that judged it against the baseline, at its level `alpha`: the
/// segment tests, or the steps' windows with the refit's prediction there):
/// the refit's gain is then its other parameters', not the effect's. `None`
/// when the effect earns its place. An encoder's lattice is judged by the
/// readings.
#[allow(clippy::too_many_arguments)]
pub(super) fn refit_without_effect(
    signals: &Signals,
    refit: &Model,
    kind: EffectKind,
    part: Part,
    with_effect: &Prediction,
    validation: Range<usize>,
    alpha: f64,
    at_steps: Option<(&StepWindows, &Prediction)>,
) -> Result<Option<f64>, ModelError> {
    if kind == EffectKind::Quantization {
        return Ok(None);
    }
    let mut without = refit.effects.clone();
    without.0.remove(kind.name());
    let without = without.build()?;
    let prediction = crate::greybox::predict(&refit.plant, &without, signals, validation.clone());
    let own = match at_steps {
        Some((steps, with_effect)) => {
            let without_at_steps = steps.predict(&refit.plant, &without, signals, validation.clone());
            steps.test(signals, &refit.plant, &without_at_steps, with_effect, alpha)
        }
        None => paired_test_at(signals, part, &prediction, with_effect, validation.clone(), alpha),
    };
    if own.passed() {
        return Ok(None);
    }
    let errors = crate::greybox::fit::nrmse_by_output(signals, &prediction, validation);
    Ok(errors.get(part.output()).copied())
}
