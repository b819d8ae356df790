//! The catalog's names and parameters: what each effect is called on the
//! command line and in JSON, its keys, defaults, units and meaning, and
//! what an identification needs to know of each: the range it searches a
//! parameter over and the values it starts from.

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

/// One parameter of an effect: key, default, unit, meaning, and how an
/// identification may move it.
#[derive(Debug, Clone, Copy)]
pub struct ParamSpec {
    pub key: &'static str,
    pub default: f64,
    pub unit: &'static str,
    pub meaning: &'static str,
    pub fit: FitRange,
}

/// The range an identification searches a parameter over, and its scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FitRange {
    /// Not fitted: read off the data (an encoder's step has no useful
    /// derivative).
    Fixed,
    /// By its logarithm: a positive quantity spanning decades.
    Log { min: f64, max: f64 },
    /// Divided by `unit`, a typical size.
    Linear { unit: f64, min: f64, max: f64 },
}

/// Where an identification of an effect starts: values of its main
/// parameter over the range it can plausibly take, the others at their
/// defaults (or one tied to the main one).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitStarts {
    pub values: &'static [f64],
    pub of: StartScale,
    /// A parameter set in proportion to the main one: (key, factor).
    pub tied: Option<(&'static str, f64)>,
}

/// What a start value is measured in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StartScale {
    /// The parameter's own unit.
    Absolute,
    /// A share of the largest command in the data.
    PeakCommand,
    /// A share of the encoder's step the data shows.
    EncoderStep,
}

const fn param(key: &'static str, default: f64, unit: &'static str, meaning: &'static str) -> ParamSpec {
    ParamSpec {
        key,
        default,
        unit,
        meaning,
        fit: FitRange::Fixed,
    }
}

impl ParamSpec {
    const fn log(self, min: f64, max: f64) -> Self {
        Self {
            fit: FitRange::Log { min, max },
            ..self
        }
    }

    const fn linear(self, unit: f64, min: f64, max: f64) -> Self {
        Self {
            fit: FitRange::Linear { unit, min, max },
            ..self
        }
    }
}

const fn starts(values: &'static [f64]) -> FitStarts {
    FitStarts {
        values,
        of: StartScale::Absolute,
        tied: None,
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
                        param("width", 0.1, "command", "spool overlap, half-width").linear(0.01, 0.0, 0.6),
                        param(
                            "offset",
                            0.0,
                            "command",
                            "centre of the overlap (the valve's null offset)",
                        )
                        .linear(0.01, -0.3, 0.3),
                    ]
                }
            }
            EffectKind::Saturation => {
                const { &[param("limit", 0.5, "command", "spool travel limit").linear(0.01, 0.02, 1.0)] }
            }
            EffectKind::TimeDelay => {
                const { &[param("delay_s", 0.02, "s", "valve command delay").linear(0.001, 0.0, 0.3)] }
            }
            EffectKind::AsymmetricGain => {
                const {
                    &[param(
                        "ratio",
                        0.7,
                        "-",
                        "flow gain for negative commands / for positive commands",
                    )
                    .log(0.1, 10.0)]
                }
            }
            EffectKind::OrificeFlow => const { &[] },
            EffectKind::CoulombFriction => {
                const {
                    &[
                        param("coulomb", 60.0, "N·m", "sliding friction torque").log(1e-2, 1e4),
                        param("breakaway", 90.0, "N·m", "static (breakaway) friction torque").log(1e-2, 1e4),
                        // A Stribeck velocity is a creep speed, the data
                        // sheet's 0.05 rad/s. Allowed up to the rotator's
                        // working speeds (2 rad/s), it made the breakaway
                        // excess a falling friction curve over them, and
                        // fits settled with the sliding level at its floor.
                        param("stribeck_velocity", 0.05, "rad/s", "Stribeck velocity").log(1e-4, 0.3),
                    ]
                }
            }
            EffectKind::GravityLoad => {
                const {
                    &[
                        param("amplitude", 150.0, "N·m", "load torque amplitude").linear(10.0, -1e5, 1e5),
                        param("offset", 0.0, "rad", "angle of zero load torque").linear(
                            0.01,
                            -std::f64::consts::PI,
                            std::f64::consts::PI,
                        ),
                    ]
                }
            }
            EffectKind::Backlash => {
                const { &[param("width", 0.02, "rad", "total play load to encoder").linear(0.001, 0.0, 0.5)] }
            }
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
                        param("stiffness", 5600.0, "N·m/rad", "coupling stiffness").log(1.0, 1e6),
                        param("damping", 28.0, "N·m·s/rad", "coupling damping").log(1e-3, 1e6),
                        param("load_fraction", 0.7, "-", "share of the inertia beyond the coupling")
                            .linear(0.01, 0.02, 0.98),
                    ]
                }
            }
        }
    }

    /// The parameter an identification reports first and is judged on.
    pub fn main_param(self) -> Option<&'static str> {
        self.params().first().map(|p| p.key)
    }

    /// Where an identification of the effect starts (an effect without
    /// parameters starts once, as it is).
    pub fn fit_starts(self) -> FitStarts {
        match self {
            EffectKind::Deadzone => starts(&[0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3]),
            EffectKind::Saturation => FitStarts {
                of: StartScale::PeakCommand,
                ..starts(&[0.3, 0.45, 0.6, 0.75, 0.9])
            },
            EffectKind::TimeDelay => starts(&[0.002, 0.005, 0.01, 0.02, 0.035, 0.05, 0.08]),
            EffectKind::AsymmetricGain => starts(&[0.4, 0.55, 0.7, 0.85, 1.2, 1.5, 2.0]),
            EffectKind::OrificeFlow => starts(&[]),
            EffectKind::CoulombFriction => FitStarts {
                tied: Some(("breakaway", 1.5)),
                ..starts(&[3.0, 10.0, 25.0, 50.0, 100.0, 200.0])
            },
            EffectKind::GravityLoad => starts(&[-300.0, -100.0, -30.0, 30.0, 100.0, 300.0]),
            EffectKind::Backlash => starts(&[0.002, 0.005, 0.01, 0.02, 0.04, 0.08]),
            EffectKind::Quantization => FitStarts {
                of: StartScale::EncoderStep,
                ..starts(&[0.98, 1.0, 1.02])
            },
            EffectKind::LoadFlexibility => FitStarts {
                tied: Some(("damping", 0.005)),
                ..starts(&[1000.0, 2500.0, 5000.0, 10000.0, 25000.0])
            },
        }
    }
}

impl fmt::Display for EffectKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}
