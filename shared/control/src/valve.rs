use serde::{Deserialize, Serialize};

use crate::{require, require_non_negative, require_positive, ControlError};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValveShaperParams {
    /// Spool overlap to invert, command units (0: no inversion).
    pub deadzone_width: f64,
    /// Below this |command| the inverse is a line through zero instead of a
    /// jump, so that a command dithering around zero does not chatter the
    /// spool across the overlap.
    pub deadzone_smoothing: f64,
    /// Flow gain of a negative opening relative to a positive one, as the
    /// `asymmetric_gain` effect's `ratio`: negative commands are divided by
    /// it, so that both directions move the load alike (1: symmetric).
    pub negative_gain_ratio: f64,
    /// Command limit, command units.
    pub limit: f64,
    /// Largest change per second, command units/s.
    pub rate_limit_per_s: f64,
}

impl Default for ValveShaperParams {
    fn default() -> Self {
        Self {
            deadzone_width: 0.0,
            deadzone_smoothing: 0.01,
            negative_gain_ratio: 1.0,
            limit: 1.0,
            rate_limit_per_s: 100.0,
        }
    }
}

/// Valve command shaping: the asymmetric gain's inverse, the dead-zone
/// inverse, then saturation, then rate limit.
#[derive(Debug, Clone)]
pub struct ValveShaper {
    params: ValveShaperParams,
    max_step: f64,
    /// 1 / `negative_gain_ratio`, so that a period multiplies.
    negative_scale: f64,
    last: f64,
}

impl ValveShaper {
    pub fn new(params: ValveShaperParams, ts: f64) -> Result<Self, ControlError> {
        require_non_negative("deadzone_width", params.deadzone_width)?;
        require_positive("deadzone_smoothing", params.deadzone_smoothing)?;
        require(
            "limit",
            params.limit,
            params.limit > 0.0 && params.limit <= 1.0,
            "must be in (0, 1]",
        )?;
        require_positive("rate_limit_per_s", params.rate_limit_per_s)?;
        require(
            "negative_gain_ratio",
            params.negative_gain_ratio,
            (0.1..=10.0).contains(&params.negative_gain_ratio),
            "must be in [0.1, 10]",
        )?;
        require_positive("sample time", ts)?;
        Ok(Self {
            params,
            max_step: params.rate_limit_per_s * ts,
            negative_scale: 1.0 / params.negative_gain_ratio,
            last: 0.0,
        })
    }

    pub fn reset(&mut self) {
        self.last = 0.0;
    }

    /// Starts from the command the valve holds now.
    pub fn initialize_output(&mut self, command: f64) {
        self.last = command.clamp(-self.params.limit, self.params.limit);
    }

    pub fn last(&self) -> f64 {
        self.last
    }

    /// The dead-zone inverse alone.
    pub(crate) fn invert_deadzone(&self, command: f64) -> f64 {
        let w = self.params.deadzone_width;
        if w == 0.0 {
            return command;
        }
        let s = self.params.deadzone_smoothing;
        if command.abs() >= s {
            command + w * command.signum()
        } else {
            command * (s + w) / s
        }
    }

    /// The asymmetric gain's inverse alone: the opening that gives a
    /// negative command's flow.
    pub(crate) fn invert_asymmetry(&self, command: f64) -> f64 {
        if command < 0.0 {
            command * self.negative_scale
        } else {
            command
        }
    }

    /// One period: the command to send for the controller's `command`.
    pub fn update(&mut self, command: f64) -> f64 {
        let limited = self
            .invert_deadzone(self.invert_asymmetry(command))
            .clamp(-self.params.limit, self.params.limit);
        let step = (limited - self.last).clamp(-self.max_step, self.max_step);
        self.last += step;
        self.last
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deadzone_inverse_is_continuous_and_offsets_beyond_smoothing() {
        let v = ValveShaper::new(
            ValveShaperParams {
                deadzone_width: 0.1,
                ..ValveShaperParams::default()
            },
            0.001,
        )
        .expect("valid");
        assert!((v.invert_deadzone(0.3) - 0.4).abs() < 1e-15);
        assert!((v.invert_deadzone(-0.3) + 0.4).abs() < 1e-15);
        assert_eq!(v.invert_deadzone(0.0), 0.0);
        let below = v.invert_deadzone(0.01 - 1e-12);
        let above = v.invert_deadzone(0.01 + 1e-12);
        assert!((below - above).abs() < 1e-9);
    }

    #[test]
    fn a_weaker_negative_direction_is_opened_wider_within_the_limit() {
        let mut v = ValveShaper::new(
            ValveShaperParams {
                negative_gain_ratio: 0.5,
                rate_limit_per_s: 1e6,
                ..ValveShaperParams::default()
            },
            0.001,
        )
        .expect("valid");
        assert_eq!(v.invert_asymmetry(0.3), 0.3);
        assert!((v.invert_asymmetry(-0.3) + 0.6).abs() < 1e-15);
        assert_eq!(v.update(-0.8), -1.0, "still within the limit");
        let bad = ValveShaperParams {
            negative_gain_ratio: 0.0,
            ..ValveShaperParams::default()
        };
        assert!(ValveShaper::new(bad, 0.001).is_err());
    }

    #[test]
    fn saturates_then_rate_limits() {
        let mut v = ValveShaper::new(
            ValveShaperParams {
                limit: 0.8,
                rate_limit_per_s: 100.0,
                ..ValveShaperParams::default()
            },
            0.001,
        )
        .expect("valid");
        assert!((v.update(5.0) - 0.1).abs() < 1e-15);
        for _ in 0..20 {
            v.update(5.0);
        }
        assert!((v.last() - 0.8).abs() < 1e-15);
        assert!((v.update(-5.0) - 0.7).abs() < 1e-12);
    }
}
