//! `[control]`: the structure, each loop's variants and gains, and the valve's guard.

use hydractl_control::{
    ControlError, FrictionCompensator, FrictionCompensatorParams, HInfinity, HInfinityParams, LimitCycleDetector,
    LimitCycleParams, LoadModel, Mfc, MfcParams, Pid, PidParams, ValveShaper, ValveShaperParams, VelocityEstimator,
    VelocityEstimatorParams,
};
use serde::{Deserialize, Serialize};

/// Position-only: the outer loop drives the valve. Cascade: the outer loop
/// gives a torque reference to the inner torque loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Structure {
    Position,
    Cascade,
}

impl Structure {
    pub fn name(self) -> &'static str {
        match self {
            Structure::Position => "position",
            Structure::Cascade => "cascade",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PositionVariant {
    Pid,
    Mfc,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TorqueVariant {
    Pid,
    Hinf,
}

/// The outer loop of one structure: its output is a valve command
/// (position-only) or a torque in N·m (cascade), so each structure has its
/// own variant and gains.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OuterLoopConfig {
    /// The variant in charge when this structure runs.
    pub variant: PositionVariant,
    pub pid: PidParams,
    pub mfc: MfcParams,
    pub friction: FrictionCompensatorParams,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TorqueLoopConfig {
    /// Valve command per rad/s of reference velocity, added to either
    /// variant's output: the flow the motion needs, 1 / (rad/s per unit
    /// command), taken from the reference so that it adds no velocity
    /// feedback to undo the damping the torque loop gives. 0 switches it off.
    #[serde(default)]
    pub velocity_feedforward: f64,
    /// Valve command per N·m/s of torque-reference rate, added to either
    /// variant's output. Pressure integrates flow, so the command that makes
    /// torque rise at rate τ̇ is τ̇ / (D β/V 4 K_q); without it an inner loop
    /// lags a moving reference. Not in the papers; 0 switches it off.
    #[serde(default)]
    pub rate_feedforward: f64,
    /// Time constant of the low-pass filter on the differenced reference, s.
    #[serde(default = "default_rate_filter")]
    pub rate_filter_s: f64,
    pub pid: PidParams,
    #[serde(default)]
    pub hinf: HInfinityParams,
}

fn default_rate_filter() -> f64 {
    0.005
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlConfig {
    pub structure: Structure,
    pub torque_variant: TorqueVariant,
    #[serde(default)]
    pub velocity_estimator: VelocityEstimatorParams,
    pub position_only: OuterLoopConfig,
    pub cascade: OuterLoopConfig,
    pub torque: TorqueLoopConfig,
    #[serde(default)]
    pub valve: ValveShaperParams,
    #[serde(default)]
    pub valve_guard: ValveGuardParams,
}

/// The valve's last line of safety.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValveGuardParams {
    /// A command derived from a sensor reading more than this many periods
    /// older than the newest one puts the valve in neutral.
    pub max_age_periods: u64,
    /// With neither readings nor commands for this long, ms, the loop
    /// upstream is gone and the valve goes to neutral on its own clock.
    /// Longer than the stalls of a busy computer (up to 10 ms seen here).
    pub silence_timeout_ms: f64,
    /// A limit cycle: `limit_cycle_reversals` reversals of the requested
    /// command in a row, each a swing of at least `limit_cycle_swing`
    /// (command units, peak to peak) within `limit_cycle_half_period_periods`
    /// of the one before. The valve then stays neutral until the commands
    /// stop (their controller replaced). 0 reversals: no check.
    pub limit_cycle_swing: f64,
    pub limit_cycle_half_period_periods: u64,
    pub limit_cycle_reversals: u64,
}

impl Default for ValveGuardParams {
    fn default() -> Self {
        Self {
            max_age_periods: 3,
            silence_timeout_ms: 20.0,
            limit_cycle_swing: 1.0,
            limit_cycle_half_period_periods: 150,
            limit_cycle_reversals: 12,
        }
    }
}

impl ControlConfig {
    /// The outer loop of the structure in charge.
    pub fn outer(&self) -> &OuterLoopConfig {
        match self.structure {
            Structure::Position => &self.position_only,
            Structure::Cascade => &self.cascade,
        }
    }

    /// The section of the outer loop's `part` (`friction`, `pid`, `mfc`)
    /// for the structure in charge, as errors name it.
    pub fn outer_section(&self, part: OuterPart) -> &'static str {
        match (self.structure, part) {
            (Structure::Position, OuterPart::Friction) => "control.position_only.friction",
            (Structure::Position, OuterPart::Pid) => "control.position_only.pid",
            (Structure::Position, OuterPart::Mfc) => "control.position_only.mfc",
            (Structure::Cascade, OuterPart::Friction) => "control.cascade.friction",
            (Structure::Cascade, OuterPart::Pid) => "control.cascade.pid",
            (Structure::Cascade, OuterPart::Mfc) => "control.cascade.mfc",
        }
    }

    /// Builds every controller the structure in charge runs, with its
    /// configured variants, so that a parameter no controller accepts is
    /// found at load, named by its section.
    pub(crate) fn check_controllers(
        &self,
        control_period: f64,
        load: LoadModel,
    ) -> Result<(), (&'static str, ControlError)> {
        let ts = control_period;
        let within = |section: &'static str| move |e: ControlError| (section, e);
        VelocityEstimator::new(self.velocity_estimator, load, ts).map_err(within("control.velocity_estimator"))?;
        let outer = self.outer();
        FrictionCompensator::new(outer.friction.clone()).map_err(within(self.outer_section(OuterPart::Friction)))?;
        match outer.variant {
            PositionVariant::Pid => Pid::new(outer.pid, ts).map(drop),
            PositionVariant::Mfc => Mfc::new(outer.mfc, ts).map(drop),
        }
        .map_err(within(self.outer_section(outer.variant.into())))?;
        self.torque.check_feedforward().map_err(within("control.torque"))?;
        // Both variants, whichever is in charge: a swap may reach either.
        Pid::new(self.torque.pid, ts).map_err(within("control.torque.pid"))?;
        HInfinity::new(self.torque.hinf.clone(), ts).map_err(within("control.torque.hinf"))?;
        self.torque
            .hinf
            .check_design()
            .map_err(within("control.torque.hinf.design"))?;
        ValveShaper::new(self.valve, ts).map_err(within("control.valve"))?;
        self.valve_guard.check().map_err(within("control.valve_guard"))
    }
}

/// The parts of an outer loop's section.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OuterPart {
    Friction,
    Pid,
    Mfc,
}

impl From<PositionVariant> for OuterPart {
    fn from(variant: PositionVariant) -> Self {
        match variant {
            PositionVariant::Pid => OuterPart::Pid,
            PositionVariant::Mfc => OuterPart::Mfc,
        }
    }
}

impl TorqueLoopConfig {
    /// The feed-forward terms every inner-loop variant adds.
    pub fn check_feedforward(&self) -> Result<(), ControlError> {
        hydractl_control::require_finite("velocity_feedforward", self.velocity_feedforward)?;
        hydractl_control::require_finite("rate_feedforward", self.rate_feedforward)?;
        hydractl_control::require_non_negative_pub("rate_filter_s", self.rate_filter_s)
    }
}

/// The longest command age the valve's guard supports, in periods.
pub const MAX_GUARD_PERIODS: usize = 32;

impl ValveGuardParams {
    pub fn check(&self) -> Result<(), ControlError> {
        if self.max_age_periods == 0 || self.max_age_periods as usize > MAX_GUARD_PERIODS {
            return Err(ControlError::InvalidParameter {
                name: "max_age_periods",
                value: self.max_age_periods as f64,
                reason: "must be from 1 to 32",
            });
        }
        if !(self.silence_timeout_ms.is_finite() && self.silence_timeout_ms > 0.0) {
            return Err(ControlError::InvalidParameter {
                name: "silence_timeout_ms",
                value: self.silence_timeout_ms,
                reason: "must be positive",
            });
        }
        LimitCycleDetector::new(self.limit_cycle()).map(drop)
    }

    /// The limit-cycle detector's parameters.
    pub fn limit_cycle(&self) -> LimitCycleParams {
        LimitCycleParams {
            swing: self.limit_cycle_swing,
            half_period: self.limit_cycle_half_period_periods,
            reversals: self.limit_cycle_reversals,
        }
    }
}
