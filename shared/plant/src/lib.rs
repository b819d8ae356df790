//! The hydraulic rotary actuator: the papers' physics, the effect catalog,
//! sensors, fixed-step integration and linearization. No IPC here.
//!
//! What it holds: The rotator of the papers (spool eq. 10, flow eq. 9,
//! pressures eq. 8, torque eq. 7, mechanics eq. 5), the effect catalog
//! (`deadzone`, `saturation`, `time_delay`, `asymmetric_gain`,
//! `orifice_flow`, `coulomb_friction`, `gravity_load`, `backlash`,
//! `quantization`, `load_flexibility`), sensor models, RK4 integration with
//! an explicit stick/slip state, linearization (analytic and by finite
//! differences), `affine_step` (the exact step of a map that is affine by
//! pieces, taken by the simulator and by identification alike), and `Drift`:
//! one effect's parameter moving over time (`[machine.drift]`), every step
//! built at start-up. The hydraulic half (`hydraulics`) and the mechanical
//! half (`mechanics`) are free functions, so that model identification drives
//! each with measured signals.

mod drift;
pub mod effects;
pub mod hydraulics;
mod linearize;
pub mod mechanics;
mod params;
mod plant;
mod sensor;

pub use drift::{Drift, DriftSpec};

/// Pascal per bar. The plant, its parameters and the live samples hold
/// pressures in Pa; CSV data and the exports of recordings in bar.
pub const PA_PER_BAR: f64 = 1e5;
pub use effects::{Effect, EffectKind, Effects, EffectsConfig, FitRange, FitStarts, ParamSpec, StartScale};
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
