//! The torque stage: the inner loop, torque reference to valve command.

use hydractl_config::{Config, Structure, TorqueVariant};
use hydractl_control::{FadingTransfer, HInfinity, Pid};

use crate::{in_section, PositionOutput, SensorEstimate, StackError};

/// The inner loop's variants.
#[derive(Debug, Clone)]
pub(crate) enum InnerLoop {
    Pid(Pid),
    HInfinity(HInfinity),
}

/// Torque stage: the inner loop, torque reference to valve command.
#[derive(Debug, Clone)]
pub struct TorqueStage {
    structure: Structure,
    variant: TorqueVariant,
    inner: InnerLoop,
    ts: f64,
    velocity_feedforward: f64,
    rate_feedforward: f64,
    rate_blend: f64,
    previous_reference: Option<f64>,
    reference_rate: f64,
    /// The feedforward as the H∞ loop adds it: rolled off at its
    /// `feedforward_roll_off_rad_s` (`None` until the first period).
    rolled_off_feedforward: Option<f64>,
    /// The roll-off's share of each step, 1 − e^(−ω·ts); 1 passes the
    /// feedforward as it is.
    feedforward_blend: f64,
    /// Bumpless transfer into the H∞ loop, whose state, full of fast
    /// modes, is never forced.
    transfer: FadingTransfer,
}

/// How fast a transfer offset fades once a standby inner loop is in charge.
const TRANSFER_FADE_S: f64 = 0.05;

impl TorqueStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Self::with_variant(config, config.control.torque_variant)
    }

    pub fn with_variant(config: &Config, variant: TorqueVariant) -> Result<Self, StackError> {
        let ts = config.timing.control_period();
        let torque = &config.control.torque;
        torque.check_feedforward().map_err(in_section("control.torque"))?;
        let inner = match variant {
            TorqueVariant::Pid => {
                InnerLoop::Pid(Pid::new(config.control.torque.pid, ts).map_err(in_section("control.torque.pid"))?)
            }
            TorqueVariant::Hinf => InnerLoop::HInfinity(
                HInfinity::new(config.control.torque.hinf.clone(), ts).map_err(in_section("control.torque.hinf"))?,
            ),
        };
        Ok(Self {
            structure: config.control.structure,
            variant,
            inner,
            ts,
            velocity_feedforward: torque.velocity_feedforward,
            rate_feedforward: torque.rate_feedforward,
            rate_blend: ts / (torque.rate_filter_s + ts),
            previous_reference: None,
            reference_rate: 0.0,
            rolled_off_feedforward: None,
            feedforward_blend: match config.control.torque.hinf.feedforward_roll_off_rad_s {
                corner if corner > 0.0 => 1.0 - (-corner * ts).exp(),
                _ => 1.0,
            },
            transfer: FadingTransfer::new(TRANSFER_FADE_S, ts),
        })
    }

    pub fn variant(&self) -> TorqueVariant {
        self.variant
    }

    /// The valve command for the position stage's output. In the cascade
    /// that output is a torque reference and the inner loop runs, with the
    /// friction compensation (valve-command units) added as the rotary paper
    /// adds it to its torque PID; in position-only control it already is
    /// the command, and passes through.
    pub fn process(&mut self, position: &PositionOutput, sensor: &SensorEstimate, friction: f64) -> f64 {
        match self.structure {
            Structure::Position => position.output,
            Structure::Cascade => self.inner_loop(position.output, position.reference.velocity, sensor, friction),
        }
    }

    /// Bumpless transfer, as [`PositionStage::track`]: called after
    /// [`TorqueStage::process`] for the same period, sets the inner loop's
    /// state as if its command had been `command`. Nothing to track when
    /// the stage passes the command through.
    pub fn track(&mut self, command: f64, position: &PositionOutput, sensor: &SensorEstimate, friction: f64) {
        if self.structure == Structure::Position {
            return;
        }
        let feedforward = friction
            + self.velocity_feedforward * position.reference.velocity
            + self.rate_feedforward * self.reference_rate;
        let error = position.output - sensor.torque;
        match &mut self.inner {
            InnerLoop::Pid(pid) => pid.initialize_output(command, error, feedforward),
            InnerLoop::HInfinity(_) => self.transfer.track(command),
        }
    }

    fn inner_loop(
        &mut self,
        torque_reference: f64,
        reference_velocity: f64,
        sensor: &SensorEstimate,
        friction: f64,
    ) -> f64 {
        let previous = self.previous_reference.unwrap_or(torque_reference);
        self.previous_reference = Some(torque_reference);
        self.reference_rate += self.rate_blend * ((torque_reference - previous) / self.ts - self.reference_rate);
        let feedforward =
            friction + self.velocity_feedforward * reference_velocity + self.rate_feedforward * self.reference_rate;
        let error = torque_reference - sensor.torque;
        match &mut self.inner {
            InnerLoop::Pid(pid) => pid.update(error, feedforward),
            InnerLoop::HInfinity(hinf) => {
                let previous = self.rolled_off_feedforward.unwrap_or(feedforward);
                let rolled_off = previous + self.feedforward_blend * (feedforward - previous);
                // A non-finite feedforward reaches the valve, which refuses
                // it, this period only: the roll-off does not keep it.
                if rolled_off.is_finite() {
                    self.rolled_off_feedforward = Some(rolled_off);
                }
                self.transfer.apply(hinf.update(error) + rolled_off).clamp(-1.0, 1.0)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hinf_roll_off_lets_a_non_finite_feedforward_through_once_and_keeps_none() {
        let config = Config::default_sim().expect("the built-in config is valid");
        assert!(config.control.torque.hinf.feedforward_roll_off_rad_s > 0.0);
        let mut stage = TorqueStage::with_variant(&config, TorqueVariant::Hinf).expect("builds");
        let (position, sensor) = (PositionOutput::default(), SensorEstimate::default());
        let steady = stage.process(&position, &sensor, 0.2);
        assert!(stage.process(&position, &sensor, f64::NAN).is_nan());
        let after = stage.process(&position, &sensor, 0.2);
        assert!(
            after.is_finite() && (after - steady).abs() < 1e-3,
            "{steady} then {after}"
        );
    }
}
