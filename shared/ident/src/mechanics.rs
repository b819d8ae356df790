//! The rotary paper's closed-loop identification of the mechanics (its
//! section IV-A, eqs. 12–17).
//!
//! The linearized mechanics Ĵ θ̈ + b̂ θ̇ = v (eq. 12, v the command after
//! friction compensation) integrate, so they are identified under a
//! stabilizing proportional feedback v = K_p (r − θ). The closed loop from
//! reference to angle is then second order (eq. 14),
//!
//!   θ/r = (K_p/Ĵ) / (s² + (b̂/Ĵ) s + K_p/Ĵ),
//!
//! fitted as (b₁ s + b₀) / (s² + a₁ s + a₀) (eq. 15), b₁ ≈ 0 absorbing
//! delays and noise, or with b₁ = 0 as eq. 14 has it. Each run gives
//! Ĵ = K_p / a₀ and b̂ = a₁ Ĵ; the estimate is their mean over runs at
//! different gains, as the paper's.
//!
//! On our rotator the free zero does harm: the valve and the hydraulic
//! mode lag the motion, and a fit with b₁ lands on a pole at the Nyquist
//! frequency and a right-half-plane zero that mimic that lag, and a₀ then
//! says nothing of Ĵ. With b₁ = 0 the runs at different gains agree.

use crate::tf::{identify_tf, IdentError, Method, TfOptions};

/// One P-controlled experiment: its gain, and the reference and measured
/// angle sampled every `ts`.
#[derive(Debug, Clone, Copy)]
pub struct PControlledRun<'a> {
    pub kp: f64,
    pub reference: &'a [f64],
    pub angle: &'a [f64],
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct MechanicsAtGain {
    pub kp: f64,
    /// θ/r, descending powers of s; `den` monic.
    pub num: Vec<f64>,
    pub den: Vec<f64>,
    /// On the validation segment (the last 30%).
    pub fit_percent: f64,
    pub j_hat: f64,
    pub b_hat: f64,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct MechanicsEstimate {
    /// Mean over the runs, in the units of the command per rad (per rad/s,
    /// per rad/s²).
    pub j_hat: f64,
    pub b_hat: f64,
    pub runs: Vec<MechanicsAtGain>,
}

/// `zeros`: 0 for eq. 14's structure (b₁ = 0), 1 for eq. 15's.
pub fn mechanics_from_p_control(
    runs: &[PControlledRun],
    ts: f64,
    zeros: usize,
) -> Result<MechanicsEstimate, IdentError> {
    if zeros > 1 {
        return Err(IdentError::Orders { poles: 2, zeros });
    }
    if runs.is_empty() {
        return Err(IdentError::Failed("no experiment given".into()));
    }
    let mut at_gains = Vec::with_capacity(runs.len());
    for run in runs {
        if !(run.kp.is_finite() && run.kp > 0.0) {
            return Err(IdentError::Failed(format!(
                "the proportional gain must be positive (eq. 13 is stable only then), got {}",
                run.kp
            )));
        }
        let fit = identify_tf(
            run.reference,
            run.angle,
            ts,
            TfOptions {
                poles: 2,
                zeros,
                method: Method::Oe,
                estimation_fraction: 0.7,
            },
        )?;
        let (num, den) = (fit.tf.num().to_vec(), fit.tf.den().to_vec());
        let (a1, a0) = (den[1], den[2]);
        if !(a0 > 0.0 && a1 > 0.0) {
            return Err(IdentError::Failed(format!(
                "at K_p = {} the closed loop fitted is not stable (den {den:?}): not a P-controlled mechanics",
                run.kp
            )));
        }
        let j_hat = run.kp / a0;
        at_gains.push(MechanicsAtGain {
            kp: run.kp,
            num,
            den,
            fit_percent: fit.fit_percent,
            j_hat,
            b_hat: a1 * j_hat,
        });
    }
    let n = at_gains.len() as f64;
    Ok(MechanicsEstimate {
        j_hat: at_gains.iter().map(|r| r.j_hat).sum::<f64>() / n,
        b_hat: at_gains.iter().map(|r| r.b_hat).sum::<f64>() / n,
        runs: at_gains,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eq. (13) simulated: Ĵ θ̈ + b̂ θ̇ = K_p (r − θ) + e, with the
    /// papers' sum of sines at 2–6 rad/s as reference, a disturbance e
    /// and measurement noise on θ.
    fn p_controlled(j: f64, b: f64, kp: f64, seconds: f64, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let ts = 1e-3;
        let n = (seconds / ts) as usize;
        let mut rng = seed;
        let mut noise = move || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((rng >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let (mut theta, mut omega) = (0.0f64, 0.0f64);
        let (mut r, mut y) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let sines = [(0.2, 2.0, 0.0), (0.15, 3.3, 1.0), (0.1, 4.7, 2.0), (0.05, 6.0, 3.0)];
        for i in 0..n {
            let t = i as f64 * ts;
            let reference: f64 = sines.iter().map(|(a, w, p)| a * (w * t + p).sin()).sum();
            let measured = theta + 1e-3 * noise();
            let v = kp * (reference - measured) + 1e-3 * noise();
            r.push(reference);
            y.push(measured);
            for _ in 0..10 {
                let acc = (v - b * omega) / j;
                omega += 1e-4 * acc;
                theta += 1e-4 * omega;
            }
        }
        (r, y)
    }

    #[test]
    fn the_papers_mechanics_are_recovered_from_two_gains() {
        // The rotary paper's mean estimate, identified at its two gains.
        let (j, b) = (0.0085, 0.0554);
        let (r1, y1) = p_controlled(j, b, 0.04, 60.0, 1);
        let (r2, y2) = p_controlled(j, b, 0.16, 60.0, 2);
        let runs = [
            PControlledRun {
                kp: 0.04,
                reference: &r1,
                angle: &y1,
            },
            PControlledRun {
                kp: 0.16,
                reference: &r2,
                angle: &y2,
            },
        ];
        let estimate = mechanics_from_p_control(&runs, 1e-3, 1).expect("identified");
        assert!((estimate.j_hat - j).abs() < 0.05 * j, "{estimate:?}");
        assert!((estimate.b_hat - b).abs() < 0.05 * b, "{estimate:?}");
        for run in &estimate.runs {
            assert!(run.fit_percent > 90.0, "{run:?}");
            // b₁ ≈ 0, b₀ ≈ a₀ = K_p / Ĵ (eq. 15).
            assert!((run.num.last().copied().unwrap_or(0.0) - run.den[2]).abs() < 0.05 * run.den[2]);
        }
        let eq14 = mechanics_from_p_control(&runs, 1e-3, 0).expect("identified");
        assert!((eq14.j_hat - j).abs() < 0.05 * j, "{eq14:?}");
        assert!((eq14.b_hat - b).abs() < 0.05 * b, "{eq14:?}");
    }

    #[test]
    fn a_non_positive_gain_or_no_run_is_refused() {
        let (r, y) = p_controlled(0.0085, 0.0554, 0.04, 5.0, 1);
        let run = PControlledRun {
            kp: 0.0,
            reference: &r,
            angle: &y,
        };
        assert!(mechanics_from_p_control(&[run], 1e-3, 0).is_err());
        assert!(mechanics_from_p_control(&[], 1e-3, 0).is_err());
        let run = PControlledRun { kp: 0.04, ..run };
        assert!(mechanics_from_p_control(&[run], 1e-3, 2).is_err());
    }
}
