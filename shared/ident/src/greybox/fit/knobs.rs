//! What a fit may move: each part's and each effect's knobs with their
//! ranges and scales, and the starts an effect's fit begins from.

use super::*;
use hydractl_plant::{FitRange, StartScale};

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

/// The most inertia a fit may give the rigid body, kg·m²: one that ends
/// here has found no body at all.
pub(super) const INERTIA_MAX: f64 = 1e5;

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
            log(Knob::Inertia, 1e-3, INERTIA_MAX),
            log(Knob::ViscousFriction, 1e-3, 1e5),
            linear(Knob::LoadTorque, 10.0, -1e6, 1e6),
        ],
        Part::Mechanical => vec![
            log(Knob::Inertia, 1e-3, INERTIA_MAX),
            log(Knob::ViscousFriction, 1e-3, 1e5),
        ],
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
            log(Knob::Inertia, 1e-3, INERTIA_MAX),
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

/// An effect's free parameters, with the ranges its catalog entry gives
/// ([`hydractl_plant::FitRange`]); one read off the data is not among them.
pub(super) fn effect_knobs(kind: EffectKind) -> Vec<Free> {
    kind.params()
        .iter()
        .filter_map(|p| {
            let knob = Knob::Effect(kind, p.key);
            match p.fit {
                FitRange::Fixed => None,
                FitRange::Log { min, max } => Some(log(knob, min, max)),
                FitRange::Linear { unit, min, max } => Some(linear(knob, unit, min, max)),
            }
        })
        .collect()
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
/// it can plausibly take, as its catalog entry gives them
/// ([`EffectKind::fit_starts`]), the others at the catalog's defaults.
pub(super) fn starts(kind: EffectKind, signals: &Signals) -> Vec<Effect> {
    let from = |given: BTreeMap<String, f64>| Effect::from_params(kind, &given).ok();
    let (Some(main), plan) = (kind.params().first(), kind.fit_starts()) else {
        return from(BTreeMap::new()).into_iter().collect();
    };
    let size = match plan.of {
        StartScale::Absolute => 1.0,
        StartScale::PeakCommand => signals.u.iter().fold(0.0_f64, |m, u| m.max(u.abs())),
        StartScale::EncoderStep => encoder_step(&signals.theta),
    };
    // A share of the data's command below the range the fit searches
    // starts at the range's floor.
    let floor = match (plan.of, main.fit) {
        (StartScale::PeakCommand, FitRange::Linear { min, .. } | FitRange::Log { min, .. }) => min,
        _ => f64::NEG_INFINITY,
    };
    plan.values
        .iter()
        .filter_map(|v| {
            let value = (v * size).max(floor);
            let mut given = BTreeMap::from([(main.key.to_owned(), value)]);
            if let Some((key, factor)) = plan.tied {
                given.insert(key.to_owned(), factor * value);
            }
            from(given)
        })
        .collect()
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
