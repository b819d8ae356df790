//! The hydraulic rotary actuator: the papers' physics, the effect catalog,
//! sensors, fixed-step integration and linearization. No IPC here.

mod drift;
pub mod effects;
pub mod hydraulics;
mod linearize;
pub mod mechanics;
mod params;
mod plant;
mod sensor;

pub use drift::{Drift, DriftSpec};
pub use effects::{Effect, EffectKind, Effects, EffectsConfig, ParamSpec};
pub use linearize::{affine_step, baseline_linear_model, LINEAR_OUTPUTS, LINEAR_STATES, TORQUE_OUTPUT};
pub use params::{PlantParams, SensorParams};
pub use plant::{Plant, PlantState};
pub use sensor::{RawReading, SensorModel};

#[derive(Debug, thiserror::Error)]
pub enum PlantError {
    #[error("parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        name: &'static str,
        value: f64,
        reason: &'static str,
    },
    #[error("unknown effect `{name}`; the catalog has: {valid}")]
    UnknownEffect { name: String, valid: String },
    #[error("effect `{effect}` has no parameter `{key}`; valid: {valid}")]
    UnknownEffectKey {
        effect: &'static str,
        key: String,
        valid: String,
    },
    #[error("effect `{effect}` parameter `{key}` = {value}: {reason}")]
    InvalidEffectParam {
        effect: &'static str,
        key: String,
        value: f64,
        reason: &'static str,
    },
    #[error("malformed effect `{spec}`: {reason} (expected NAME or NAME:KEY=VALUE,KEY=VALUE)")]
    MalformedEffect { spec: String, reason: String },
    #[error(transparent)]
    Lti(#[from] hydractl_lti::LtiError),
}

impl PlantError {
    pub(crate) fn invalid(name: &'static str, value: f64, reason: &'static str) -> Self {
        Self::InvalidParameter { name, value, reason }
    }
}
