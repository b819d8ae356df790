//! What a fitted model teaches the controllers: a config whose
//! compensators use the effects the model found, each change with its
//! reason, and each effect no compensator answers yet, with why. Only the
//! controllers change: the plant a tuned config simulates is the base's.

use hydractl_plant::effects::Effects;
use hydractl_plant::EffectKind;
use serde::Serialize;

use crate::Config;

/// One key of the config changed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Change {
    /// The key, as the TOML writes it (`control.valve.deadzone_width`).
    pub key: String,
    pub from: f64,
    pub to: f64,
    /// The effect that asked for it.
    pub effect: String,
    pub reason: String,
}

/// An effect of the model that no compensator answers.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NotCompensated {
    pub effect: String,
    pub reason: String,
}

/// The tuned config, and what was done to get it.
#[derive(Debug, Clone)]
pub struct Compensation {
    pub config: Config,
    pub changes: Vec<Change>,
    pub not_compensated: Vec<NotCompensated>,
}

/// A null offset smaller than this is no offset: the fit's own scatter.
const NEGLIGIBLE_OFFSET: f64 = 1e-3;

/// The compensators of `base` set from the model's `effects`.
pub fn compensate(base: &Config, effects: &Effects) -> Compensation {
    let mut config = base.clone();
    let mut changes = Vec::new();
    let mut not_compensated = Vec::new();
    let set = |changes: &mut Vec<Change>, key: &str, slot: &mut f64, to: f64, effect: EffectKind, reason: &str| {
        if *slot != to {
            changes.push(Change {
                key: key.to_owned(),
                from: *slot,
                to,
                effect: effect.name().to_owned(),
                reason: reason.to_owned(),
            });
            *slot = to;
        }
    };
    let mut not = |effect: EffectKind, reason: &str| {
        not_compensated.push(NotCompensated {
            effect: effect.name().to_owned(),
            reason: reason.to_owned(),
        });
    };
    let control = &mut config.control;
    if let Some(deadzone) = effects.deadzone {
        set(
            &mut changes,
            "control.valve.deadzone_width",
            &mut control.valve.deadzone_width,
            deadzone.width,
            EffectKind::Deadzone,
            "the shaper adds the overlap to every command, so that the spool opens as soon as a loop asks",
        );
        set(
            &mut changes,
            "control.valve.deadzone_smoothing",
            &mut control.valve.deadzone_smoothing,
            deadzone.width,
            EffectKind::Deadzone,
            "within the band's width the inverse is a line through zero, not a jump across the overlap: \
             the torque loop's command dithers around zero, and a jump there makes the torque chatter",
        );
        if deadzone.offset.abs() > NEGLIGIBLE_OFFSET {
            not(
                EffectKind::Deadzone,
                &format!(
                    "the null offset ({:+.4}): the shaper inverts a band centred on zero; the loops' \
                     integrators take up the offset",
                    deadzone.offset
                ),
            );
        }
    }
    if let Some(saturation) = effects.saturation {
        let limit = saturation.limit.min(control.valve.limit);
        let reason = "beyond this the spool does not move: the loops limit their command there, so that \
                      their anti-windup stops integrating when the valve can give no more";
        set(
            &mut changes,
            "control.valve.limit",
            &mut control.valve.limit,
            limit,
            EffectKind::Saturation,
            reason,
        );
        // The limits of the loops whose output is a valve command.
        let position = &mut control.position_only;
        for (name, min, max) in [
            (
                "control.position_only.pid",
                &mut position.pid.output_min,
                &mut position.pid.output_max,
            ),
            (
                "control.position_only.mfc",
                &mut position.mfc.output_min,
                &mut position.mfc.output_max,
            ),
            (
                "control.torque.pid",
                &mut control.torque.pid.output_min,
                &mut control.torque.pid.output_max,
            ),
        ] {
            let (low, high) = (min.max(-limit), max.min(limit));
            set(
                &mut changes,
                &format!("{name}.output_min"),
                min,
                low,
                EffectKind::Saturation,
                reason,
            );
            set(
                &mut changes,
                &format!("{name}.output_max"),
                max,
                high,
                EffectKind::Saturation,
                reason,
            );
        }
    }
    if let Some(asymmetry) = effects.asymmetric_gain {
        set(
            &mut changes,
            "control.valve.negative_gain_ratio",
            &mut control.valve.negative_gain_ratio,
            asymmetry.ratio.clamp(0.1, 10.0),
            EffectKind::AsymmetricGain,
            "the shaper divides negative commands by the fitted ratio, so that both directions move the load \
             alike for the same command",
        );
    }
    let unanswered: [(bool, EffectKind, &str); 7] = [
        (
            effects.time_delay.is_some(),
            EffectKind::TimeDelay,
            "no controller takes a delay into account yet (a Smith predictor, or gains tuned for it)",
        ),
        (
            effects.coulomb_friction.is_some(),
            EffectKind::CoulombFriction,
            "the friction compensation's map is in valve command and the model's friction in N·m: \
             the conversion through the flow-pressure coefficient is not written yet",
        ),
        (
            effects.gravity_load.is_some(),
            EffectKind::GravityLoad,
            "the loops have no gravity feed-forward yet",
        ),
        (
            effects.backlash.is_some(),
            EffectKind::Backlash,
            "play between actuator and encoder has no compensator here",
        ),
        (
            effects.quantization.is_some(),
            EffectKind::Quantization,
            "the velocity estimator's cutoff is not matched to the encoder's step yet",
        ),
        (
            effects.orifice_flow.is_some(),
            EffectKind::OrificeFlow,
            "the √Δp flow needs a pressure-aware valve inverse, which the shaper does not have",
        ),
        (
            effects.load_flexibility.is_some(),
            EffectKind::LoadFlexibility,
            "a flexible load needs a notch or a two-mass model in the loop, which no variant has",
        ),
    ];
    for (present, kind, reason) in unanswered {
        if present {
            not(kind, reason);
        }
    }
    Compensation {
        config,
        changes,
        not_compensated,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hydractl_plant::effects::{Deadzone, Saturation, TimeDelay};

    #[test]
    fn a_deadzone_and_a_saturation_set_the_shaper_and_the_limits_and_nothing_else() {
        let base = Config::default_sim().expect("default");
        let effects = Effects {
            deadzone: Some(Deadzone {
                width: 0.08,
                offset: 0.02,
            }),
            saturation: Some(Saturation { limit: 0.6 }),
            time_delay: Some(TimeDelay { delay_s: 0.01 }),
            ..Effects::none()
        };
        let tuned = compensate(&base, &effects);
        let valve = &tuned.config.control.valve;
        assert_eq!(
            (valve.deadzone_width, valve.deadzone_smoothing, valve.limit),
            (0.08, 0.08, 0.6)
        );
        assert_eq!(tuned.config.control.torque.pid.output_max, 0.6);
        assert_eq!(tuned.config.control.position_only.pid.output_min, -0.6);
        // The plant the tuned config simulates is the base's.
        assert_eq!(tuned.config.plant, base.plant);
        assert_eq!(tuned.config.effects, base.effects);
        assert!(tuned
            .changes
            .iter()
            .all(|c| c.key.starts_with("control.") && !c.reason.is_empty()));
        let unanswered: Vec<&str> = tuned.not_compensated.iter().map(|n| n.effect.as_str()).collect();
        assert_eq!(unanswered, ["deadzone", "time_delay"], "the offset and the delay");
    }

    #[test]
    fn no_effect_changes_nothing() {
        let base = Config::default_sim().expect("default");
        let tuned = compensate(&base, &Effects::none());
        assert!(tuned.changes.is_empty() && tuned.not_compensated.is_empty());
        assert_eq!(tuned.config, base);
    }
}
