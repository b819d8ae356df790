//! The ranges within which a fitted effect can be what a rotator has: a
//! compensator acts on nothing outside them. A model file may be corrupt,
//! edited by hand, or fitted on bad data; a dead band of 0.95 of the
//! spool's travel is none of a proportional valve's, and its inverse would
//! throw the spool across its travel at every zero crossing.

use hydractl_plant::effects::Effects;
use hydractl_plant::{EffectKind, PlantParams};
use serde::Serialize;

/// A parameter outside its plausible range.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Implausible {
    /// The model file's key (`effects.deadzone.width`).
    pub key: String,
    pub value: f64,
    pub min: f64,
    pub max: f64,
    /// Why the range is what it is.
    pub why: &'static str,
}

impl std::fmt::Display for Implausible {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} = {} is outside [{}, {}]: {}",
            self.key, self.value, self.min, self.max, self.why
        )
    }
}

/// The plant's stall torque, N·m: the supply's whole pressure on the
/// motor's displacement.
fn stall_torque(plant: &PlantParams) -> f64 {
    plant.displacement * plant.supply_pressure
}

/// Every parameter of `effects` (and the plant's constant load) a
/// compensator would act on that lies outside its plausible range.
pub fn implausible(plant: &PlantParams, effects: &Effects) -> Vec<Implausible> {
    let stall = stall_torque(plant);
    let mut found = Vec::new();
    let mut check = |kind: Option<EffectKind>, key: &str, value: f64, (min, max): (f64, f64), why: &'static str| {
        if !(value >= min && value <= max) {
            let key = match kind {
                Some(kind) => format!("effects.{}.{key}", kind.name()),
                None => format!("plant.{key}"),
            };
            found.push(Implausible {
                key,
                value,
                min,
                max,
                why,
            });
        }
    };
    if let Some(d) = effects.deadzone {
        check(
            Some(EffectKind::Deadzone),
            "width",
            d.width,
            (0.0, 0.3),
            "a proportional valve's overlap reaches at most 30 % of its spool's travel each side",
        );
        check(
            Some(EffectKind::Deadzone),
            "offset",
            d.offset,
            (-0.2, 0.2),
            "a null offset beyond a fifth of the travel is a valve out of adjustment",
        );
    }
    if let Some(s) = effects.saturation {
        check(
            Some(EffectKind::Saturation),
            "limit",
            s.limit,
            (0.2, 1.0),
            "a spool stopped under a fifth of its travel is a fault, not a limit to live with",
        );
    }
    if let Some(d) = effects.time_delay {
        check(
            Some(EffectKind::TimeDelay),
            "delay_s",
            d.delay_s,
            (0.0, 0.1),
            "a command reaching the valve a tenth of a second late is a bus or device fault",
        );
    }
    if let Some(a) = effects.asymmetric_gain {
        check(
            Some(EffectKind::AsymmetricGain),
            "ratio",
            a.ratio,
            (0.25, 4.0),
            "a valve's two directions differ by less than four times",
        );
    }
    if let Some(c) = effects.coulomb_friction {
        for (key, value) in [("coulomb", c.coulomb), ("breakaway", c.breakaway)] {
            check(
                Some(EffectKind::CoulombFriction),
                key,
                value,
                (0.0, 0.3 * stall),
                "friction above 30 % of the stall torque is a seized bearing",
            );
        }
    }
    if let Some(g) = effects.gravity_load {
        check(
            Some(EffectKind::GravityLoad),
            "amplitude",
            g.amplitude.abs(),
            (0.0, 0.8 * stall),
            "a load the motor could not hold with a fifth of its torque to spare",
        );
    }
    check(
        None,
        "load_torque",
        plant.load_torque.abs(),
        (0.0, 0.8 * stall),
        "a load the motor could not hold with a fifth of its torque to spare",
    );
    found
}
