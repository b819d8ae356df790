use serde::{Deserialize, Serialize};

use crate::{require_non_negative, require_positive, ControlError, FadingTransfer, Pid, PidParams};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MfcParams {
    /// Ĵ of the forward model Ĵ θ̈ + b̂ θ̇ = u (rotary paper, eq. 12), in the
    /// output's units per rad/s².
    pub j_hat: f64,
    /// b̂ of the forward model, in the output's units per rad/s.
    pub b_hat: f64,
    /// PID A: driven by the process error, model angle minus measured angle.
    pub pid_a: PidParams,
    /// PID B: drives the forward model along the reference.
    pub pid_b: PidParams,
    /// Output limits of the whole controller.
    pub output_min: f64,
    pub output_max: f64,
}

/// The rotary paper's model-following controller (its Fig. 8, after
/// Rafael 2006): PID B drives a forward model of the mechanics along the
/// reference, so the model's input is an inverse-dynamics feed-forward free
/// of measurement noise; PID A, driven by the difference between model and
/// plant, corrects for disturbances and model error. Output:
/// `u = u_B + u_A + feedforward`.
#[derive(Debug, Clone)]
pub struct Mfc {
    params: MfcParams,
    ts: f64,
    pid_a: Pid,
    pid_b: Pid,
    model_angle: f64,
    model_velocity: f64,
    /// What a handover asked beyond u_B + u_A + feed-forward.
    transfer: FadingTransfer,
    output: f64,
}

/// The time constant over which the step between a handed-over output and
/// this controller's own fades out. PID B has no integral action (ki = 0
/// in every config) to unwind a step put into its integrator: one stayed
/// there for good and, through the forward model, held the plant 0.045 rad
/// off the reference after a swap pid → mfc (0.004 before it). A fifth of
/// a second is a few of the outer loop's own time constants.
pub const TRANSFER_FADE_S: f64 = 0.2;

impl Mfc {
    pub fn new(params: MfcParams, ts: f64) -> Result<Self, ControlError> {
        require_positive("j_hat", params.j_hat)?;
        require_non_negative("b_hat", params.b_hat)?;
        if params.output_min.is_nan() || params.output_max.is_nan() || params.output_min >= params.output_max {
            return Err(ControlError::InvalidParameter {
                name: "output_max",
                value: params.output_max,
                reason: "must be above output_min",
            });
        }
        // Each PID is limited to the controller's range, so neither winds up
        // while the sum saturates and the model never sees a force the
        // actuator cannot give.
        let limited = |mut pid: PidParams| {
            pid.output_min = pid.output_min.max(params.output_min);
            pid.output_max = pid.output_max.min(params.output_max);
            pid
        };
        Ok(Self {
            params,
            ts,
            pid_a: Pid::new(limited(params.pid_a), ts)?,
            pid_b: Pid::new(limited(params.pid_b), ts)?,
            model_angle: 0.0,
            model_velocity: 0.0,
            transfer: FadingTransfer::new(TRANSFER_FADE_S, ts),
            output: 0.0,
        })
    }

    pub fn reset(&mut self) {
        self.pid_a.reset();
        self.pid_b.reset();
        self.model_angle = 0.0;
        self.model_velocity = 0.0;
        self.transfer.reset();
        self.output = 0.0;
    }

    pub fn model_angle(&self) -> f64 {
        self.model_angle
    }

    /// One period: the output for the reference and the measured angle.
    /// With a measured `velocity`, PID_A's derivative is the model's
    /// velocity less it; without, the angle's error differenced.
    pub fn update(&mut self, reference: f64, angle: f64, velocity: Option<f64>, feedforward: f64) -> f64 {
        if !(reference.is_finite() && angle.is_finite() && feedforward.is_finite()) {
            return self.output;
        }
        let u_b = self.pid_b.update(reference - self.model_angle, 0.0);
        let error_a = self.model_angle - angle;
        let u_a = match velocity {
            Some(velocity) => self
                .pid_a
                .update_with_rate(error_a, self.model_velocity - velocity, 0.0),
            None => self.pid_a.update(error_a, 0.0),
        };
        // The forward model, semi-implicit Euler: Ĵ θ̈ = u_B − b̂ θ̇.
        let p = &self.params;
        self.model_velocity += self.ts * (u_b - p.b_hat * self.model_velocity) / p.j_hat;
        self.model_angle += self.ts * self.model_velocity;
        self.output = self
            .transfer
            .apply(u_b + u_a + feedforward)
            .clamp(p.output_min, p.output_max);
        self.output
    }

    /// Tracking a running controller's `output`, period after period, while
    /// this one stands by: its forward model and PIDs run on, as they
    /// would in charge, and the transfer takes up the difference, so that
    /// from the switch it goes on from the running output and fades to its
    /// own over `TRANSFER_FADE_S`. (Re-initializing the model from the
    /// measured, noisy velocity every period would not: with the cascade's
    /// gains, one period's noise is tens of N·m.)
    pub fn track(&mut self, output: f64) {
        self.transfer.track(output);
        self.output = output;
    }

    /// The torque the forward model says the motion takes: Ĵ·a + b̂·v.
    pub fn inverse_dynamics(&self, acceleration: f64, velocity: f64) -> f64 {
        self.params.j_hat * acceleration + self.params.b_hat * velocity
    }

    /// Bumpless start from a running loop: the model starts where the plant
    /// is, PID A at zero, and PID B so that the next output is `output`.
    /// Only on finite inputs, and says whether it started: a model started
    /// at an invalid reading's NaN would stay NaN and hold the output for
    /// good.
    #[must_use]
    pub fn initialize_output(
        &mut self,
        output: f64,
        reference: f64,
        angle: f64,
        velocity: f64,
        feedforward: f64,
    ) -> bool {
        if ![output, reference, angle, velocity, feedforward]
            .iter()
            .all(|x| x.is_finite())
        {
            return false;
        }
        self.model_angle = angle;
        self.model_velocity = velocity;
        // Each PID remembers the error it would have seen had it been
        // running, so its derivative term starts from the motion, not from
        // a jump: next period the plant is `velocity·ts` further on (PID A's
        // error), and the reference-to-model error moves at the reference's
        // speed less the model's (PID B's).
        let ts = self.ts;
        self.pid_a.initialize_output(0.0, -velocity * ts, 0.0);
        let error_b = reference - angle + velocity * ts;
        self.pid_b.start_from(error_b);
        // PID B's next output is about kp·error: the rest is a transfer
        // that fades, not a bias in an integrator that has no integral
        // action to unwind it.
        self.transfer
            .start(output, self.params.pid_b.kp * error_b + feedforward);
        self.output = output;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> MfcParams {
        MfcParams {
            j_hat: 0.05,
            b_hat: 0.6,
            pid_a: PidParams {
                kp: 3.0,
                ki: 1.0,
                derivative_filter_s: 0.0,
                ..PidParams::default()
            },
            pid_b: PidParams {
                kp: 10.0,
                kd: 0.5,
                derivative_filter_s: 0.0,
                ..PidParams::default()
            },
            output_min: -1.0,
            output_max: 1.0,
        }
    }

    #[test]
    fn first_steps_match_a_hand_computation() {
        let mut c = Mfc::new(params(), 0.001).expect("valid");
        // k=0: e_B = 0.1, u_B = 10*0.1 = 1.0 (no derivative on first sample);
        // e_A = 0 - 0 = 0; then model: ω = 0.001*(1.0)/0.05 = 0.02, θ = 2e-5.
        let u = c.update(0.1, 0.0, None, 0.0);
        assert!((u - 1.0).abs() < 1e-12);
        assert!((c.model_angle() - 2e-5).abs() < 1e-15);
        // k=1: e_B = 0.1 - 2e-5; u_B = 10 e_B + 0.5 (−2e-5/0.001) = 0.9998 − 0.01.
        // e_A = 2e-5: u_A = 3*2e-5 = 6e-5.
        let u = c.update(0.1, 0.0, None, 0.0);
        assert!((u - (0.9998 - 0.01 + 6e-5)).abs() < 1e-9, "{u}");
    }

    #[test]
    fn plant_equal_to_model_needs_no_correction() {
        let p = params();
        let mut c = Mfc::new(p, 0.001).expect("valid");
        let (mut angle, mut velocity) = (0.0, 0.0);
        for k in 0..3000 {
            let r = 0.2 * (2.0 * k as f64 * 0.001).sin();
            let u = c.update(r, angle, None, 0.0);
            // The same discretization as the model: the plant stays on it.
            velocity += 0.001 * (u - p.b_hat * velocity) / p.j_hat;
            angle += 0.001 * velocity;
            assert!((angle - c.model_angle()).abs() < 1e-9);
        }
    }

    #[test]
    fn tracking_keeps_the_model_and_moves_the_output() {
        let mut c = Mfc::new(params(), 0.001).expect("valid");
        // A slow ramp, the plant on the model: nothing saturates.
        let reference = |k: usize| 0.01 * k as f64 * 0.001;
        let mut own = 0.0;
        for k in 0..200 {
            own = c.update(reference(k), c.model_angle(), None, 0.0);
        }
        let model = c.model_angle();
        c.track(own + 0.1);
        assert_eq!(c.model_angle(), model, "the model runs on untouched");
        let mut free = c.clone();
        free.track(own);
        let shifted = c.update(reference(200), model, None, 0.0);
        let unshifted = free.update(reference(200), model, None, 0.0);
        assert!((shifted - unshifted - 0.1).abs() < 1e-9, "{shifted} {unshifted}");
    }

    #[test]
    fn a_handed_over_step_fades_and_leaves_no_bias() {
        let ts = 0.001;
        let mut c = Mfc::new(params(), ts).expect("valid");
        let reference = |k: usize| 0.2 * (2.0 * k as f64 * ts).sin();
        // The plant a little behind the reference, as a running loop leaves it.
        let angle = |k: usize| 0.9 * reference(k);
        let mut own = 0.0;
        for k in 0..200 {
            own = c.update(reference(k), angle(k), None, 0.0);
        }
        let mut never_stood_by = c.clone();
        never_stood_by.track(own);
        c.track(own + 0.3);
        let periods = |seconds: f64| (seconds / ts).round() as usize;
        let mut gaps = Vec::new();
        for k in 200..200 + periods(10.0 * TRANSFER_FADE_S) {
            let handed = c.update(reference(k), angle(k), None, 0.0);
            let free = never_stood_by.update(reference(k), angle(k), None, 0.0);
            gaps.push(handed - free);
            assert_eq!(
                c.model_angle(),
                never_stood_by.model_angle(),
                "the model runs on untouched"
            );
        }
        assert!((gaps[0] - 0.3).abs() < 1e-12, "bumpless: {}", gaps[0]);
        let after_one_fade = gaps[periods(TRANSFER_FADE_S) - 1];
        assert!((after_one_fade - 0.3 * (-1f64).exp()).abs() < 1e-3, "{after_one_fade}");
        let last = *gaps.last().expect("periods");
        assert!(last.abs() < 0.3 * (-9.9f64).exp(), "no bias left: {last}");
    }

    #[test]
    fn initialize_output_is_bumpless() {
        let mut c = Mfc::new(params(), 0.001).expect("valid");
        assert!(c.initialize_output(0.42, 0.3, 0.25, 0.0, 0.02));
        assert!((c.update(0.3, 0.25, None, 0.02) - 0.42).abs() < 1e-12);
        // On a moving plant the next output moves on from it, without the
        // derivative kick a zero remembered error would give.
        let (velocity, ts) = (0.5, 0.001);
        let mut c = Mfc::new(params(), ts).expect("valid");
        assert!(c.initialize_output(0.42, 0.3, 0.25, velocity, 0.02));
        let next = c.update(0.3 + velocity * ts, 0.25 + velocity * ts, None, 0.02);
        assert!((next - 0.42).abs() < 1e-3, "{next}");
    }

    #[test]
    fn an_encoder_count_moves_the_output_by_the_proportional_part_alone() {
        // PID_A with a derivative and a measured velocity: the angle
        // stepping one count at a steady velocity is no motion to it.
        let mut p = params();
        p.pid_a.kd = 0.8;
        let mut c = Mfc::new(p, 0.001).expect("valid");
        let count = std::f64::consts::TAU / 4000.0;
        let still = c.update(0.0, 0.0, Some(0.0), 0.0);
        let stepped = c.update(0.0, count, Some(0.0), 0.0);
        let proportional = p.pid_a.kp * count;
        assert!(
            ((still - stepped) - proportional).abs() < 1e-3 * proportional,
            "{still} {stepped}"
        );
    }
}
