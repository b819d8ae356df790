use serde::{Deserialize, Serialize};

use crate::{require_non_negative, require_positive, ControlError};

/// The reference at one instant: angle, velocity and acceleration.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Reference {
    pub angle: f64,
    pub velocity: f64,
    pub acceleration: f64,
}

/// Reference trajectories for the outer loop. The velocity is exact (the
/// crane paper's friction compensation relies on that), not differenced.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Trajectory {
    /// Σ a_i sin(ω_i t + φ_i), faded in over `fade_in_s` with a smooth
    /// envelope so that the start asks for no impossible velocity step. The
    /// papers' experiments use frequencies of 2–6 rad/s.
    SumOfSines {
        amplitudes: Vec<f64>,
        /// rad/s.
        frequencies: Vec<f64>,
        #[serde(default)]
        phases: Vec<f64>,
        #[serde(default)]
        offset: f64,
        #[serde(default = "default_fade_in")]
        fade_in_s: f64,
    },
    /// Piecewise-constant angles: `angles[i]` from `times[i]` on.
    Steps { times: Vec<f64>, angles: Vec<f64> },
    /// Back and forth between `from` and `to` with a trapezoidal velocity
    /// profile, dwelling `dwell_s` at each end.
    Trapezoid {
        from: f64,
        to: f64,
        velocity: f64,
        acceleration: f64,
        dwell_s: f64,
    },
}

fn default_fade_in() -> f64 {
    1.0
}

impl Default for Trajectory {
    fn default() -> Self {
        Trajectory::SumOfSines {
            amplitudes: vec![0.2, 0.15, 0.1, 0.05],
            frequencies: vec![2.0, 3.0, 4.0, 6.0],
            phases: vec![],
            offset: 0.0,
            fade_in_s: 1.0,
        }
    }
}

impl Trajectory {
    pub fn validate(&self) -> Result<(), ControlError> {
        let table = |reason: String| ControlError::InvalidTable {
            name: "trajectory",
            reason,
        };
        match self {
            Trajectory::SumOfSines {
                amplitudes,
                frequencies,
                phases,
                offset,
                fade_in_s,
            } => {
                if amplitudes.len() != frequencies.len() || amplitudes.is_empty() {
                    return Err(table(format!(
                        "sum_of_sines needs as many amplitudes ({}) as frequencies ({}), at least one",
                        amplitudes.len(),
                        frequencies.len()
                    )));
                }
                if !phases.is_empty() && phases.len() != amplitudes.len() {
                    return Err(table(format!(
                        "sum_of_sines has {} phases for {} sines",
                        phases.len(),
                        amplitudes.len()
                    )));
                }
                if amplitudes
                    .iter()
                    .chain(frequencies)
                    .chain(phases)
                    .any(|v| !v.is_finite())
                    || !offset.is_finite()
                {
                    return Err(table("sum_of_sines has a value that is not finite".into()));
                }
                require_non_negative("fade_in_s", *fade_in_s)?;
            }
            Trajectory::Steps { times, angles } => {
                if times.len() != angles.len() || times.is_empty() {
                    return Err(table(format!(
                        "steps needs as many times ({}) as angles ({}), at least one",
                        times.len(),
                        angles.len()
                    )));
                }
                if times.iter().chain(angles).any(|v| !v.is_finite()) {
                    return Err(table("steps has a value that is not finite".into()));
                }
                if let Some(i) = times.windows(2).position(|w| w[1] <= w[0]) {
                    return Err(table(format!("steps: times must increase; time {} is not", i + 1)));
                }
            }
            Trajectory::Trapezoid {
                from,
                to,
                velocity,
                acceleration,
                dwell_s,
            } => {
                require_positive("velocity", *velocity)?;
                require_positive("acceleration", *acceleration)?;
                require_non_negative("dwell_s", *dwell_s)?;
                if !(from.is_finite() && to.is_finite()) || from == to {
                    return Err(table("trapezoid needs finite, distinct `from` and `to`".into()));
                }
            }
        }
        Ok(())
    }

    /// The reference at time `t` ≥ 0. Allocation-free.
    pub fn sample(&self, t: f64) -> Reference {
        match self {
            Trajectory::SumOfSines {
                amplitudes,
                frequencies,
                phases,
                offset,
                fade_in_s,
            } => {
                let (mut s, mut ds, mut dds) = (0.0, 0.0, 0.0);
                for (i, (&a, &w)) in amplitudes.iter().zip(frequencies).enumerate() {
                    let phase = phases.get(i).copied().unwrap_or(0.0);
                    let (sin, cos) = (w * t + phase).sin_cos();
                    s += a * sin;
                    ds += a * w * cos;
                    dds -= a * w * w * sin;
                }
                let (e, de, dde) = fade_envelope(t, *fade_in_s);
                Reference {
                    angle: offset + e * s,
                    velocity: de * s + e * ds,
                    acceleration: dde * s + 2.0 * de * ds + e * dds,
                }
            }
            Trajectory::Steps { times, angles } => {
                let index = times.partition_point(|&time| time <= t);
                Reference {
                    angle: if index == 0 { 0.0 } else { angles[index - 1] },
                    velocity: 0.0,
                    acceleration: 0.0,
                }
            }
            Trajectory::Trapezoid {
                from,
                to,
                velocity,
                acceleration,
                dwell_s,
            } => trapezoid(t, *from, *to, *velocity, *acceleration, *dwell_s),
        }
    }
}

/// A quintic smoothstep from 0 to 1 over `duration`, with its derivatives:
/// continuous up to the acceleration.
fn fade_envelope(t: f64, duration: f64) -> (f64, f64, f64) {
    if duration <= 0.0 || t >= duration {
        return (1.0, 0.0, 0.0);
    }
    if t <= 0.0 {
        return (0.0, 0.0, 0.0);
    }
    let x = t / duration;
    let e = x * x * x * (10.0 - 15.0 * x + 6.0 * x * x);
    let de = 30.0 * x * x * (1.0 - x) * (1.0 - x) / duration;
    let dde = 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x) / (duration * duration);
    (e, de, dde)
}

fn trapezoid(t: f64, from: f64, to: f64, v_max: f64, a: f64, dwell: f64) -> Reference {
    let distance = (to - from).abs();
    // Triangular when the distance is too short to reach v_max.
    let v_peak = v_max.min((distance * a).sqrt());
    let t_accel = v_peak / a;
    let d_accel = 0.5 * a * t_accel * t_accel;
    let t_cruise = (distance - 2.0 * d_accel) / v_peak;
    let t_move = 2.0 * t_accel + t_cruise;
    let period = 2.0 * (t_move + dwell);
    let mut tau = t.max(0.0) % period;
    let (start, direction) = if tau < t_move + dwell {
        (from, (to - from).signum())
    } else {
        tau -= t_move + dwell;
        (to, (from - to).signum())
    };
    // Dwell first, then move.
    if tau < dwell {
        return Reference {
            angle: start,
            velocity: 0.0,
            acceleration: 0.0,
        };
    }
    let m = tau - dwell;
    let (s, v, acc) = if m < t_accel {
        (0.5 * a * m * m, a * m, a)
    } else if m < t_accel + t_cruise {
        (d_accel + v_peak * (m - t_accel), v_peak, 0.0)
    } else if m < t_move {
        let r = t_move - m;
        (distance - 0.5 * a * r * r, a * r, -a)
    } else {
        (distance, 0.0, 0.0)
    };
    Reference {
        angle: start + direction * s,
        velocity: direction * v,
        acceleration: direction * acc,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn numeric_derivative(traj: &Trajectory, t: f64) -> (f64, f64) {
        let h = 1e-6;
        let a = traj.sample(t - h);
        let b = traj.sample(t + h);
        ((b.angle - a.angle) / (2.0 * h), (b.velocity - a.velocity) / (2.0 * h))
    }

    #[test]
    fn sum_of_sines_derivatives_are_exact_including_the_fade() {
        let traj = Trajectory::default();
        traj.validate().expect("valid");
        for &t in &[0.3, 0.7, 1.5, 4.2] {
            let r = traj.sample(t);
            let (v, a) = numeric_derivative(&traj, t);
            assert!((r.velocity - v).abs() < 1e-6, "t={t}");
            assert!((r.acceleration - a).abs() < 1e-4, "t={t}");
        }
        let start = traj.sample(0.0);
        assert_eq!((start.angle, start.velocity), (0.0, 0.0));
        // After the fade it is the plain sum.
        let r = traj.sample(3.0);
        let plain: f64 = [(0.2, 2.0), (0.15, 3.0), (0.1, 4.0), (0.05, 6.0)]
            .iter()
            .map(|(a, w)| a * (w * 3.0_f64).sin())
            .sum();
        assert!((r.angle - plain).abs() < 1e-12);
    }

    #[test]
    fn trapezoid_moves_dwells_and_returns_with_consistent_derivatives() {
        let traj = Trajectory::Trapezoid {
            from: 0.0,
            to: 1.0,
            velocity: 0.5,
            acceleration: 1.0,
            dwell_s: 1.0,
        };
        traj.validate().expect("valid");
        assert_eq!(traj.sample(0.5).angle, 0.0);
        // Move: 0.5 s accel, 1.5 s cruise, 0.5 s decel = 2.5 s.
        assert!((traj.sample(3.5).angle - 1.0).abs() < 1e-12);
        assert!((traj.sample(2.0).velocity - 0.5).abs() < 1e-12);
        for &t in &[1.2, 2.0, 3.3, 4.7, 5.5] {
            let (v, _) = numeric_derivative(&traj, t);
            assert!((traj.sample(t).velocity - v).abs() < 1e-5, "t={t}");
        }
        // Back at the start after one period of 7 s.
        assert!(traj.sample(7.2).angle.abs() < 1e-12);
    }

    #[test]
    fn steps_hold_their_values() {
        let traj = Trajectory::Steps {
            times: vec![1.0, 2.0],
            angles: vec![0.5, -0.2],
        };
        traj.validate().expect("valid");
        assert_eq!(traj.sample(0.5).angle, 0.0);
        assert_eq!(traj.sample(1.0).angle, 0.5);
        assert_eq!(traj.sample(2.5).angle, -0.2);
    }

    #[test]
    fn invalid_trajectories_say_why() {
        let bad = Trajectory::SumOfSines {
            amplitudes: vec![1.0],
            frequencies: vec![],
            phases: vec![],
            offset: 0.0,
            fade_in_s: 1.0,
        };
        assert!(bad.validate().expect_err("bad").to_string().contains("frequencies"));
    }
}
