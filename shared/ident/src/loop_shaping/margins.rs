//! How a loop closed around a plant model behaves, read from its frequency
//! response `L(jω) = P(jω) K(jω)` on a log grid: what a controls engineer
//! checks before a controller reaches a machine.

use hydractl_lti::{Complex, StateSpace};
use serde::Serialize;

use super::LoopShapingError;

/// The grid: 0.001 to 10⁵ rad/s, this many points per decade.
const POINTS_PER_DECADE: usize = 400;
const LOWEST_DECADE: i32 = -3;
const HIGHEST_DECADE: i32 = 5;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopMargins {
    /// All closed-loop poles in the left half-plane.
    pub closed_loop_stable: bool,
    /// The slowest closed-loop pole's real part, 1/s (negative when stable).
    pub slowest_pole_real: f64,
    /// The highest frequency at which `|L|` falls through 1, rad/s.
    pub crossover_rad_s: Option<f64>,
    /// 180° + ∠L at the crossover, the worst over every crossing of 1.
    pub phase_margin_deg: Option<f64>,
    /// How much more gain the loop takes before it reaches −1, the worst
    /// over the phase's crossings of −180°; none when it never crosses.
    pub gain_margin_db: Option<f64>,
    /// The lowest frequency at which `|S| = |1/(1 + L)|` rises above 1/√2:
    /// up to here the loop follows its reference, rad/s.
    pub bandwidth_rad_s: Option<f64>,
    /// The peak of `|S|`: 2 or less is the rule of thumb.
    pub peak_sensitivity: f64,
}

fn grid() -> impl Iterator<Item = f64> {
    let count = (HIGHEST_DECADE - LOWEST_DECADE) as usize * POINTS_PER_DECADE;
    (0..=count).map(|i| 10f64.powf(f64::from(LOWEST_DECADE) + i as f64 / POINTS_PER_DECADE as f64))
}

/// The margins of `plant` (SISO, no feedthrough) under `controller` on the
/// error, `u = K (r − y)`.
pub(crate) fn loop_margins(plant: &StateSpace, controller: &StateSpace) -> Result<LoopMargins, LoopShapingError> {
    let poles = plant.negative_feedback_poles(controller)?;
    let slowest_pole_real = poles.iter().fold(f64::NEG_INFINITY, |m, p| m.max(p.re));
    let mut margins = LoopMargins {
        closed_loop_stable: slowest_pole_real < 0.0,
        slowest_pole_real,
        crossover_rad_s: None,
        phase_margin_deg: None,
        gain_margin_db: None,
        bandwidth_rad_s: None,
        peak_sensitivity: 0.0,
    };
    let mut previous: Option<(f64, Complex<f64>)> = None;
    for omega in grid() {
        let l = plant.frequency_response(omega) * controller.frequency_response(omega);
        let sensitivity = 1.0 / (Complex::new(1.0, 0.0) + l).norm();
        margins.peak_sensitivity = margins.peak_sensitivity.max(sensitivity);
        if margins.bandwidth_rad_s.is_none() && sensitivity >= std::f64::consts::FRAC_1_SQRT_2 {
            margins.bandwidth_rad_s = Some(omega);
        }
        if let Some((_, before)) = previous {
            if (before.norm() - 1.0) * (l.norm() - 1.0) <= 0.0 && before.norm() != l.norm() {
                let margin = 180.0 - l.arg().to_degrees().abs();
                margins.phase_margin_deg = Some(margins.phase_margin_deg.map_or(margin, |m: f64| m.min(margin)));
                if l.norm() < 1.0 {
                    margins.crossover_rad_s = Some(omega);
                }
            }
            // The phase through ±180°: the imaginary part changes sign on the
            // negative real axis.
            if before.im * l.im <= 0.0 && l.re < 0.0 && before.im != l.im {
                let margin = -20.0 * l.norm().log10();
                margins.gain_margin_db = Some(margins.gain_margin_db.map_or(margin, |m: f64| m.min(margin)));
            }
        }
        previous = Some((omega, l));
    }
    Ok(margins)
}

/// `‖[I; K] (I + P K)⁻¹ [P, I]‖∞` for SISO `plant` and `controller` (on the
/// error), the quantity a Glover–McFarlane controller keeps below its `γ`:
/// for SISO the matrix has rank one and the norm is
/// `√(1 + |K|²) √(1 + |P|²) / |1 + P K|`, taken over the grid.
pub fn coprime_robustness(plant: &StateSpace, controller: &StateSpace) -> f64 {
    grid()
        .map(|omega| {
            let p = plant.frequency_response(omega);
            let k = controller.frequency_response(omega);
            (1.0 + k.norm_sqr()).sqrt() * (1.0 + p.norm_sqr()).sqrt() / (Complex::new(1.0, 0.0) + p * k).norm()
        })
        .fold(0.0, f64::max)
}
