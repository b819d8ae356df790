//! What a fit may move: each part's and each effect's knobs with their
//! ranges and scales, and the starts an effect's fit begins from.

use super::*;

pub(super) const fn log(knob: Knob, min: f64, max: f64) -> Free {
    Free {
        knob,
        scale: Scale::Log { min, max },
    }
}

pub(super) const fn linear(knob: Knob, unit: f64, min: f64, max: f64) -> Free {
    Free {
        knob,
        scale: Scale::Linear { unit, min, max },
    }
}

/// A parameter the fit may move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Knob {
    BulkModulus,
    FlowGain,
    FlowPressureCoefficient,
    Leakage,
    ValveNaturalFrequency,
    ValveDamping,
    Inertia,
    ViscousFriction,
    LoadTorque,
    Effect(EffectKind, &'static str),
}

impl Knob {
    /// The parameter's name in the model file.
    pub(super) fn name(self) -> String {
        match self {
            Knob::BulkModulus => "bulk_modulus".to_owned(),
            Knob::FlowGain => "flow_gain".to_owned(),
            Knob::FlowPressureCoefficient => "flow_pressure_coefficient".to_owned(),
            Knob::Leakage => "leakage".to_owned(),
            Knob::ValveNaturalFrequency => "valve_natural_frequency".to_owned(),
            Knob::ValveDamping => "valve_damping".to_owned(),
            Knob::Inertia => "inertia".to_owned(),
            Knob::ViscousFriction => "viscous_friction".to_owned(),
            Knob::LoadTorque => "load_torque".to_owned(),
            Knob::Effect(kind, key) => format!("{}.{key}", kind.name()),
        }
    }
}

/// How a knob is scaled for the optimizer: by its logarithm (positive
/// quantities spanning decades) or divided by a typical size.
#[derive(Debug, Clone, Copy)]
pub(super) enum Scale {
    Log { min: f64, max: f64 },
    Linear { unit: f64, min: f64, max: f64 },
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Free {
    pub(super) knob: Knob,
    pub(super) scale: Scale,
}

/// The baseline's free parameters of each part. Displacement, volumes and
/// supply pressure are the data sheet's and stay fixed: they set the scale
/// that the data alone cannot (only β/V, D/J and the like are observable).
pub(super) fn baseline_knobs(part: Part, signals: &Signals) -> Vec<Free> {
    match part {
        Part::Hydraulic => vec![
            log(Knob::BulkModulus, 1e7, 1e11),
            log(Knob::FlowGain, 1e-7, 1e-2),
            log(Knob::FlowPressureCoefficient, 1e-16, 1e-9),
            log(Knob::Leakage, 1e-16, 1e-9),
            log(Knob::ValveNaturalFrequency, 2.0, 2000.0),
            log(Knob::ValveDamping, 0.02, 5.0),
        ],
        Part::Mechanical if fits_load_torque(signals) => vec![
            log(Knob::Inertia, 1e-3, 1e5),
            log(Knob::ViscousFriction, 1e-3, 1e5),
            linear(Knob::LoadTorque, 10.0, -1e6, 1e6),
        ],
        Part::Mechanical => vec![log(Knob::Inertia, 1e-3, 1e5), log(Knob::ViscousFriction, 1e-3, 1e5)],
        // From the command to the angle alone, the flow gain sets the
        // speed, inertia against the (data sheet's) oil stiffness the
        // hydraulic mode, and viscous friction with the valve's bandwidth
        // and damping its damping; the pressures' own coefficients are not
        // observable. Without the valve's damping, a foreign valve's phase
        // went to a false delay (clean plant 1000011: 5.5 ms, t 6.1).
        Part::Whole => vec![
            log(Knob::FlowGain, 1e-7, 1e-2),
            log(Knob::ValveNaturalFrequency, 2.0, 2000.0),
            log(Knob::ValveDamping, 0.02, 5.0),
            log(Knob::Inertia, 1e-3, 1e5),
            log(Knob::ViscousFriction, 1e-3, 1e5),
        ],
    }
}

/// Whether the rigid body's constant load torque is fitted: where the
/// torque is measured. A torque or force sensor's zero offset, or a drive's,
/// is the rule there, and a model without it takes it out on the friction
/// (on a measured linear axis, a 3 N offset of 150 N hid its Coulomb
/// friction: t 0.5 against 3.4, 6.5 with it). From the pressures it is
/// not fitted: on the foreign plants, whose transducers have no offset, it
/// slowed diagnose by 4–29 % and traded two plants' Coulomb friction for an
/// offset.
pub(super) fn fits_load_torque(signals: &Signals) -> bool {
    signals.tau.is_some()
}

/// An effect's free parameters. The encoder step is not among them: a
/// staircase has no useful derivative, so it is read off the data instead.
pub(super) fn effect_knobs(kind: EffectKind) -> Vec<Free> {
    let k = |key| Knob::Effect(kind, key);
    match kind {
        EffectKind::Deadzone => vec![linear(k("width"), 0.01, 0.0, 0.6), linear(k("offset"), 0.01, -0.3, 0.3)],
        EffectKind::Saturation => vec![linear(k("limit"), 0.01, 0.02, 1.0)],
        EffectKind::TimeDelay => vec![linear(k("delay_s"), 0.001, 0.0, 0.3)],
        EffectKind::AsymmetricGain => vec![log(k("ratio"), 0.1, 10.0)],
        EffectKind::OrificeFlow | EffectKind::Quantization => vec![],
        EffectKind::CoulombFriction => vec![
            log(k("coulomb"), 1e-2, 1e4),
            log(k("breakaway"), 1e-2, 1e4),
            // A Stribeck velocity is a creep speed, the data sheet's 0.05
            // rad/s. Allowed up to the rotator's working speeds (2 rad/s),
            // it made the breakaway excess a falling friction curve over
            // them, and fits settled with the sliding level at its floor
            // (4 of 20 foreign plants' 60 N·m missed, against 2 at 0.3).
            log(k("stribeck_velocity"), 1e-4, 0.3),
        ],
        EffectKind::GravityLoad => vec![
            linear(k("amplitude"), 10.0, -1e5, 1e5),
            linear(k("offset"), 0.01, -std::f64::consts::PI, std::f64::consts::PI),
        ],
        EffectKind::Backlash => vec![linear(k("width"), 0.001, 0.0, 0.5)],
        EffectKind::LoadFlexibility => vec![
            log(k("stiffness"), 1.0, 1e6),
            log(k("damping"), 1e-3, 1e6),
            linear(k("load_fraction"), 0.01, 0.02, 0.98),
        ],
    }
}

/// Whether an effect's main parameter sits at an edge of the range the fit
/// allows it, in words: an effect pressed against its range is standing in
/// for something else. (A secondary parameter at its edge, a Stribeck
/// velocity the data cannot resolve, says only that it is not identified.)
pub(crate) fn at_edge(kind: EffectKind, params: &BTreeMap<String, f64>) -> Option<String> {
    param_at_edge(kind, kind.main_param()?, params)
}

/// Whether the effect's parameter `key` sits at an edge of the range the
/// fit allows it, in words.
pub(crate) fn param_at_edge(kind: EffectKind, key: &str, params: &BTreeMap<String, f64>) -> Option<String> {
    effect_knobs(kind).into_iter().find_map(|free| {
        let Knob::Effect(_, knob_key) = free.knob else {
            return None;
        };
        if knob_key != key {
            return None;
        }
        let value = *params.get(key)?;
        let (lower, upper) = free.bounds();
        let scaled = free.scaled(value);
        let near = 1e-6 * (upper - lower);
        let edge = if scaled <= lower + near {
            "lower"
        } else if scaled >= upper - near {
            "upper"
        } else {
            return None;
        };
        Some(format!("{key} = {value:.4} is at the {edge} edge of its range"))
    })
}

impl Free {
    pub(super) fn bounds(&self) -> (f64, f64) {
        match self.scale {
            Scale::Log { min, max } => (min.ln(), max.ln()),
            Scale::Linear { unit, min, max } => (min / unit, max / unit),
        }
    }

    pub(super) fn scaled(self, value: f64) -> f64 {
        let (lower, upper) = self.bounds();
        let scaled = match self.scale {
            Scale::Log { min, .. } => value.max(min).ln(),
            Scale::Linear { unit, .. } => value / unit,
        };
        scaled.clamp(lower, upper)
    }

    pub(super) fn unscaled(self, scaled: f64) -> f64 {
        match self.scale {
            Scale::Log { .. } => scaled.exp(),
            Scale::Linear { unit, .. } => scaled * unit,
        }
    }
}

/// Starting values to try for an effect: its main parameter over the range
/// it can plausibly take, the others at the catalog's defaults.
pub(super) fn starts(kind: EffectKind, signals: &Signals) -> Vec<Effect> {
    let with = |pairs: &[(&str, f64)]| -> Option<Effect> {
        let given: BTreeMap<String, f64> = pairs.iter().map(|(k, v)| ((*k).to_owned(), *v)).collect();
        Effect::from_params(kind, &given).ok()
    };
    let values: Vec<Vec<(&str, f64)>> = match kind {
        EffectKind::Deadzone => [0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3]
            .iter()
            .map(|w| vec![("width", *w)])
            .collect(),
        EffectKind::Saturation => {
            let peak = signals.u.iter().fold(0.0_f64, |m, u| m.max(u.abs()));
            [0.3, 0.45, 0.6, 0.75, 0.9]
                .iter()
                .map(|f| vec![("limit", (f * peak).max(0.02))])
                .collect()
        }
        EffectKind::TimeDelay => [0.002, 0.005, 0.01, 0.02, 0.035, 0.05, 0.08]
            .iter()
            .map(|d| vec![("delay_s", *d)])
            .collect(),
        EffectKind::AsymmetricGain => [0.4, 0.55, 0.7, 0.85, 1.2, 1.5, 2.0]
            .iter()
            .map(|r| vec![("ratio", *r)])
            .collect(),
        EffectKind::OrificeFlow => vec![vec![]],
        EffectKind::CoulombFriction => [3.0, 10.0, 25.0, 50.0, 100.0, 200.0]
            .iter()
            .map(|c| vec![("coulomb", *c), ("breakaway", 1.5 * c)])
            .collect(),
        EffectKind::GravityLoad => [-300.0, -100.0, -30.0, 30.0, 100.0, 300.0]
            .iter()
            .map(|a| vec![("amplitude", *a)])
            .collect(),
        EffectKind::Backlash => [0.002, 0.005, 0.01, 0.02, 0.04, 0.08]
            .iter()
            .map(|w| vec![("width", *w)])
            .collect(),
        EffectKind::Quantization => {
            let step = encoder_step(&signals.theta);
            [0.98, 1.0, 1.02].iter().map(|f| vec![("step", f * step)]).collect()
        }
        EffectKind::LoadFlexibility => [1000.0, 2500.0, 5000.0, 10000.0, 25000.0]
            .iter()
            .map(|s| vec![("stiffness", *s), ("damping", 0.005 * s)])
            .collect(),
    };
    values.iter().filter_map(|pairs| with(pairs)).collect()
}

/// The encoder's step as the data shows it: the smallest change of the
/// angle between samples that is not noise (the 2nd percentile of the
/// nonzero changes).
pub(crate) fn encoder_step(theta: &[f64]) -> f64 {
    let mut changes: Vec<f64> = theta
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 1e-12)
        .collect();
    if changes.is_empty() {
        return 1e-3;
    }
    changes.sort_by(f64::total_cmp);
    changes[changes.len() / 50]
}

/// A part's knobs: the baseline's, and those of every effect of the part
/// the model has (and of `adding`).
pub(super) fn part_knobs(part: Part, model: &Working, adding: Option<EffectKind>, signals: &Signals) -> Vec<Free> {
    let mut knobs = baseline_knobs(part, signals);
    for present in EffectKind::ALL {
        if signals.part_for(present) == Ok(part) && (model.has(present) || Some(present) == adding) {
            knobs.extend(effect_knobs(present));
        }
    }
    knobs
}
