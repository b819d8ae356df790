//! The controllers of the papers, each a discrete-time object that
//! allocates nothing per step, can be reset, and can be initialized from a
//! given output so that a switch between variants is bumpless. No IPC here:
//! the processes wire these to shared memory; the offline simulator calls
//! them directly.
//!
//! What it holds: PID with anti-windup, the crane paper's friction
//! compensation (eq. 1), the rotary paper's model-following controller, an H∞
//! torque controller (the crane paper's eq. 8, or a design for the machine
//! with its design record) as a ZOH state-space system, valve shaping
//! (asymmetric-gain and dead-zone inverses, limit, rate limit), velocity
//! estimation, reference trajectories, limit-cycle detection (the valve's
//! guard). Every controller allocates nothing per step, resets, and
//! initializes from a given output (bumpless; `FadingTransfer` where its
//! state is not forced).

mod friction;
mod hinf;
mod limit_cycle;
mod mfc;
mod pid;
mod trajectory;
mod transfer;
mod valve;
mod velocity;

pub use friction::{FrictionCompensator, FrictionCompensatorParams, LoadFeedforward, StaticMap};
pub use hinf::{HInfinity, HInfinityDesign, HInfinityParams, PAPER_HINF_DEN, PAPER_HINF_NUM};
pub use limit_cycle::{LimitCycleDetector, LimitCycleParams};
pub use mfc::{Mfc, MfcParams};
pub use pid::{Pid, PidParams};
pub use trajectory::{Reference, Trajectory};
pub use transfer::FadingTransfer;
pub use valve::{ValveShaper, ValveShaperParams};
pub use velocity::{LoadModel, VelocityEstimator, VelocityEstimatorParams, VelocityMethod};

#[derive(Debug, thiserror::Error)]
pub enum ControlError {
    #[error("`{name}` = {value}: {reason}")]
    InvalidParameter {
        name: &'static str,
        value: f64,
        reason: &'static str,
    },
    #[error("{name}: {reason}")]
    InvalidTable { name: &'static str, reason: String },
    #[error(transparent)]
    Lti(#[from] hydractl_lti::LtiError),
}

pub(crate) fn require(name: &'static str, value: f64, ok: bool, reason: &'static str) -> Result<(), ControlError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(ControlError::InvalidParameter { name, value, reason })
    }
}

pub(crate) fn require_positive(name: &'static str, value: f64) -> Result<(), ControlError> {
    require(name, value, value > 0.0, "must be positive and finite")
}

/// For callers outside the crate validating their own parameters.
pub fn require_finite(name: &'static str, value: f64) -> Result<(), ControlError> {
    require(name, value, true, "must be finite")
}

/// For callers outside the crate validating their own parameters.
pub fn require_non_negative_pub(name: &'static str, value: f64) -> Result<(), ControlError> {
    require_non_negative(name, value)
}

pub(crate) fn require_non_negative(name: &'static str, value: f64) -> Result<(), ControlError> {
    require(name, value, value >= 0.0, "must be non-negative and finite")
}
