//! What a fitted model teaches the controllers: a config whose
//! compensators use the effects the model found, each change with its
//! reason, and each effect no compensator answers yet, with why. Only the
//! controllers change: the plant a tuned config simulates is the base's.

use hydractl_plant::effects::Effects;
use hydractl_plant::{EffectKind, PlantParams};
use serde::Serialize;

use crate::Config;

mod plausible;
pub use plausible::{implausible, Implausible};

/// One key of the config changed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Change {
    /// The key, as the TOML writes it (`control.valve.deadzone_width`).
    pub key: String,
    pub from: f64,
    pub to: f64,
    /// The effect that asked for it, or the plant's parameter
    /// (`load_torque`, the constant load a model fitted).
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

/// Valve command per N·m of load held, in steady state: the load's
/// pressure difference leaks past the piston and the spool's centre,
/// (C_em + 2 K_c) Δp, and the valve must meter that flow back, 4 K_q u
/// (eq. 8–9 of the crane paper, both chambers). In position-only control
/// the loop's output is this command, not a torque.
pub(crate) fn command_per_torque(plant: &PlantParams) -> f64 {
    (plant.leakage + 2.0 * plant.flow_pressure_coefficient) / (4.0 * plant.flow_gain * plant.displacement)
}

/// The compensators of `base` set from the model's `plant` and `effects`.
pub fn compensate(base: &Config, plant: &PlantParams, effects: &Effects) -> Compensation {
    let mut config = base.clone();
    let mut changes = Vec::new();
    let mut not_compensated = Vec::new();
    // `cause`: the effect, or the plant's parameter, that asks for the change.
    let set = |changes: &mut Vec<Change>, key: &str, slot: &mut f64, to: f64, cause: &str, reason: &str| {
        if *slot != to {
            changes.push(Change {
                key: key.to_owned(),
                from: *slot,
                to,
                effect: cause.to_owned(),
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
            EffectKind::Deadzone.name(),
            "the shaper adds the overlap to every command, so that the spool opens as soon as a loop asks",
        );
        set(
            &mut changes,
            "control.valve.deadzone_smoothing",
            &mut control.valve.deadzone_smoothing,
            deadzone.width,
            EffectKind::Deadzone.name(),
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
            EffectKind::Saturation.name(),
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
                EffectKind::Saturation.name(),
                reason,
            );
            set(
                &mut changes,
                &format!("{name}.output_max"),
                max,
                high,
                EffectKind::Saturation.name(),
                reason,
            );
        }
    }
    // The load's feed-forward of both outer loops: N·m of torque reference
    // in the cascade, valve command in position-only control.
    let per_torque = command_per_torque(plant);
    for (section, load, scale) in [
        ("control.cascade.friction.load", &mut control.cascade.friction.load, 1.0),
        (
            "control.position_only.friction.load",
            &mut control.position_only.friction.load,
            per_torque,
        ),
    ] {
        let units = if scale == 1.0 {
            String::new()
        } else {
            format!(" ({scale:.3e} command per N·m: the flow the load's pressure leaks)")
        };
        if let Some(friction) = effects.coulomb_friction {
            set(
                &mut changes,
                &format!("{section}.coulomb"),
                &mut load.coulomb,
                friction.coulomb * scale,
                EffectKind::CoulombFriction.name(),
                &format!(
                    "the fitted sliding friction ({:.1} N·m) pushed with the motion ahead of the loop, \
                     so that the integrator need not build it up at every reversal{units}",
                    friction.coulomb
                ),
            );
        }
        if plant.load_torque != 0.0 {
            set(
                &mut changes,
                &format!("{section}.constant"),
                &mut load.constant,
                plant.load_torque * scale,
                "load_torque",
                &format!(
                    "the model's constant load ({:.1} N·m against positive rotation: a hose's drag, \
                     a load's mean) held ahead of the loop, so that the integrator need not carry it{units}",
                    plant.load_torque
                ),
            );
        }
        if let Some(gravity) = effects.gravity_load {
            let reason = format!(
                "the load's weight held ahead of the loop at the measured angle, \
                 {:.1} N·m · sin(θ − {:.3}) as fitted{units}",
                gravity.amplitude, gravity.offset
            );
            set(
                &mut changes,
                &format!("{section}.gravity_amplitude"),
                &mut load.gravity_amplitude,
                gravity.amplitude * scale,
                EffectKind::GravityLoad.name(),
                &reason,
            );
            set(
                &mut changes,
                &format!("{section}.gravity_offset"),
                &mut load.gravity_offset,
                gravity.offset,
                EffectKind::GravityLoad.name(),
                &reason,
            );
        }
    }
    if let Some(friction) = effects.coulomb_friction.filter(|f| f.breakaway > f.coulomb) {
        not(
            EffectKind::CoulombFriction,
            &format!(
                "the breakaway excess ({:.1} N·m over the sliding level): pushed at every start it \
                 would throw a resting load; the integrator takes it",
                friction.breakaway - friction.coulomb
            ),
        );
    }
    if let Some(asymmetry) = effects.asymmetric_gain {
        set(
            &mut changes,
            "control.valve.negative_gain_ratio",
            &mut control.valve.negative_gain_ratio,
            asymmetry.ratio.clamp(0.1, 10.0),
            EffectKind::AsymmetricGain.name(),
            "the shaper divides negative commands by the fitted ratio, so that both directions move the load \
             alike for the same command",
        );
    }
    if let Some(delay) = effects.time_delay.filter(|d| d.delay_s > 0.0) {
        // Skogestad's SIMC rule for a loop with dead time θ: integral time
        // τ_I = 4 (τ_c + θ), with the tight closed-loop time τ_c = θ. The
        // proportional gain stays: its pressure feedback damps the
        // hydraulic mode, and halving it made the error 2–3× worse under a
        // 20 ms delay. A Smith predictor would need the torque response's
        // model inside the loop and goes wrong with a delay misjudged; one
        // fitted number sets the gains robustly.
        let integral_time = 8.0 * delay.delay_s;
        let pid = &mut control.torque.pid;
        if pid.ki > 0.0 && pid.kp / pid.ki < integral_time {
            set(
                &mut changes,
                "control.torque.pid.ki",
                &mut pid.ki,
                pid.kp / integral_time,
                EffectKind::TimeDelay.name(),
                &format!(
                    "the torque loop's integral time to 8 × the fitted delay ({:.1} ms), Skogestad's SIMC \
                     rule with τ_c = θ: the integrator's phase lag and the delay's together would \
                     leave the loop ringing",
                    delay.delay_s * 1e3
                ),
            );
        }
        not(
            EffectKind::TimeDelay,
            "the H∞ inner loop and the position-only loops keep their gains: their tuning does not \
             follow from one dead time as simply",
        );
    }
    let unanswered: [(bool, EffectKind, &str); 4] = [
        (
            effects.backlash.is_some(),
            EffectKind::Backlash,
            "play between actuator and encoder has no compensator here",
        ),
        (
            effects.quantization.is_some(),
            EffectKind::Quantization,
            "the encoder's step limits the loop, not the velocity estimator: on the catalog's 10° \
             step, cutoffs from 150 down to 20 rad/s left the tracking error at 0.079–0.084 rad \
             (0.085 at 150), while the clean plant's grew 2–14×; a finer encoder is the answer",
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
        let tuned = compensate(&base, &base.plant, &effects);
        let valve = &tuned.config.control.valve;
        assert_eq!(
            (valve.deadzone_width, valve.deadzone_smoothing, valve.limit),
            (0.08, 0.08, 0.6)
        );
        assert_eq!(tuned.config.control.torque.pid.output_max, 0.6);
        assert_eq!(tuned.config.control.position_only.pid.output_min, -0.6);
        // A 10 ms delay: the torque loop's integral time to 80 ms.
        let pid = tuned.config.control.torque.pid;
        assert!((pid.kp / pid.ki - 0.08).abs() < 1e-12, "{pid:?}");
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
    fn coulomb_friction_and_gravity_feed_both_outer_loops_each_in_its_units() {
        let base = Config::default_sim().expect("default");
        let effects = Effects {
            coulomb_friction: Some(hydractl_plant::effects::CoulombFriction {
                coulomb: 40.0,
                breakaway: 40.0,
                stribeck_velocity: 0.05,
            }),
            gravity_load: Some(hydractl_plant::effects::GravityLoad {
                amplitude: 200.0,
                offset: 0.3,
            }),
            ..Effects::none()
        };
        let tuned = compensate(&base, &base.plant, &effects);
        let cascade = tuned.config.control.cascade.friction.load;
        assert_eq!(
            (cascade.coulomb, cascade.gravity_amplitude, cascade.gravity_offset),
            (40.0, 200.0, 0.3)
        );
        let position = tuned.config.control.position_only.friction.load;
        let per_torque = command_per_torque(&base.plant);
        assert!((position.coulomb - 40.0 * per_torque).abs() < 1e-15);
        assert!((position.gravity_amplitude - 200.0 * per_torque).abs() < 1e-15);
        // The default rotator: the flow 40 N·m leak takes a hundredth of
        // the valve's command.
        assert!((1e-3..=2e-2).contains(&position.coulomb), "{}", position.coulomb);
        assert!(tuned.not_compensated.is_empty(), "{:?}", tuned.not_compensated);
        assert_eq!(tuned.config.plant, base.plant);
    }

    #[test]
    fn a_constant_load_torque_is_held_ahead_of_both_outer_loops() {
        let base = Config::default_sim().expect("default");
        let model = PlantParams {
            load_torque: -25.0,
            ..base.plant
        };
        let tuned = compensate(&base, &model, &Effects::none());
        assert_eq!(tuned.config.control.cascade.friction.load.constant, -25.0);
        let position = tuned.config.control.position_only.friction.load.constant;
        assert!((position + 25.0 * command_per_torque(&model)).abs() < 1e-15);
        assert!(
            tuned.changes.iter().all(|c| c.effect == "load_torque"),
            "{:?}",
            tuned.changes
        );
        assert_eq!(tuned.changes.len(), 2);
        assert_eq!(tuned.config.plant, base.plant, "the plant simulated stays the base's");
    }

    #[test]
    fn no_effect_changes_nothing() {
        let base = Config::default_sim().expect("default");
        let tuned = compensate(&base, &base.plant, &Effects::none());
        assert!(tuned.changes.is_empty() && tuned.not_compensated.is_empty());
        assert_eq!(tuned.config, base);
    }
}
