//! The catalog's names and parameters: what each effect is called on the
//! command line and in JSON, its keys, defaults, units and meaning.

use std::fmt;

use super::*;

/// The catalog's names, exactly as the command line and the JSON use them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EffectKind {
    Deadzone,
    Saturation,
    TimeDelay,
    AsymmetricGain,
    OrificeFlow,
    CoulombFriction,
    GravityLoad,
    Backlash,
    Quantization,
    LoadFlexibility,
}

/// One parameter of an effect: key, default, unit, meaning.
#[derive(Debug, Clone, Copy)]
pub struct ParamSpec {
    pub key: &'static str,
    pub default: f64,
    pub unit: &'static str,
    pub meaning: &'static str,
}

const fn param(key: &'static str, default: f64, unit: &'static str, meaning: &'static str) -> ParamSpec {
    ParamSpec {
        key,
        default,
        unit,
        meaning,
    }
}

impl EffectKind {
    pub const ALL: [EffectKind; 10] = [
        EffectKind::Deadzone,
        EffectKind::Saturation,
        EffectKind::TimeDelay,
        EffectKind::AsymmetricGain,
        EffectKind::OrificeFlow,
        EffectKind::CoulombFriction,
        EffectKind::GravityLoad,
        EffectKind::Backlash,
        EffectKind::Quantization,
        EffectKind::LoadFlexibility,
    ];

    pub fn name(self) -> &'static str {
        match self {
            EffectKind::Deadzone => "deadzone",
            EffectKind::Saturation => "saturation",
            EffectKind::TimeDelay => "time_delay",
            EffectKind::AsymmetricGain => "asymmetric_gain",
            EffectKind::OrificeFlow => "orifice_flow",
            EffectKind::CoulombFriction => "coulomb_friction",
            EffectKind::GravityLoad => "gravity_load",
            EffectKind::Backlash => "backlash",
            EffectKind::Quantization => "quantization",
            EffectKind::LoadFlexibility => "load_flexibility",
        }
    }

    pub fn from_name(name: &str) -> Result<Self, PlantError> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| PlantError::UnknownEffect {
                name: name.to_owned(),
                valid: Self::ALL.iter().map(|k| k.name()).collect::<Vec<_>>().join(", "),
            })
    }

    /// The parameters with their defaults: each default is a size that
    /// matters on the default rotator, so naming the effect alone shows it.
    pub fn params(self) -> &'static [ParamSpec] {
        match self {
            EffectKind::Deadzone => {
                const {
                    &[
                        param("width", 0.1, "command", "spool overlap, half-width"),
                        param(
                            "offset",
                            0.0,
                            "command",
                            "centre of the overlap (the valve's null offset)",
                        ),
                    ]
                }
            }
            EffectKind::Saturation => const { &[param("limit", 0.5, "command", "spool travel limit")] },
            EffectKind::TimeDelay => const { &[param("delay_s", 0.02, "s", "valve command delay")] },
            EffectKind::AsymmetricGain => {
                const {
                    &[param(
                        "ratio",
                        0.7,
                        "-",
                        "flow gain for negative commands / for positive commands",
                    )]
                }
            }
            EffectKind::OrificeFlow => const { &[] },
            EffectKind::CoulombFriction => {
                const {
                    &[
                        param("coulomb", 60.0, "N·m", "sliding friction torque"),
                        param("breakaway", 90.0, "N·m", "static (breakaway) friction torque"),
                        param("stribeck_velocity", 0.05, "rad/s", "Stribeck velocity"),
                    ]
                }
            }
            EffectKind::GravityLoad => {
                const {
                    &[
                        param("amplitude", 150.0, "N·m", "load torque amplitude"),
                        param("offset", 0.0, "rad", "angle of zero load torque"),
                    ]
                }
            }
            EffectKind::Backlash => const { &[param("width", 0.02, "rad", "total play load to encoder")] },
            EffectKind::Quantization => {
                const {
                    &[param(
                        "step",
                        std::f64::consts::PI / 18.0,
                        "rad",
                        "encoder step (10°: the rotary paper's 36-magnet disc)",
                    )]
                }
            }
            EffectKind::LoadFlexibility => {
                const {
                    &[
                        param("stiffness", 5600.0, "N·m/rad", "coupling stiffness"),
                        param("damping", 28.0, "N·m·s/rad", "coupling damping"),
                        param("load_fraction", 0.7, "-", "share of the inertia beyond the coupling"),
                    ]
                }
            }
        }
    }

    /// The parameter an identification reports first and is judged on.
    pub fn main_param(self) -> Option<&'static str> {
        self.params().first().map(|p| p.key)
    }
}

impl fmt::Display for EffectKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}
