//! The crane paper's static pseudo-friction map (its section 3.1): steps of
//! valve current, each held until the velocity settles; each step's steady
//! velocity is matched to its current. The map, velocity → current, is what
//! it takes to overcome friction, in the valve's own units, and goes
//! straight into the friction compensation's `map`.
//!
//! A step is a run of samples with one command. Its steady velocity is the
//! slope of a least-squares line through the angle over the step's last
//! half; it is steady when the slopes of that half's two quarters agree.
//! Each direction's moving points are fitted by a line, command equal to
//! the breakaway plus the slope times the velocity: the breakaway is the
//! Coulomb friction and the valve's dead-zone together, the slope the
//! viscous part (b̂ in command units).

use crate::tf::IdentError;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MapPoint {
    pub command: f64,
    pub velocity_rad_s: f64,
    /// The velocity settled within the step (its last two quarters agree).
    pub steady: bool,
    pub duration_s: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct DirectionFit {
    /// The command at which motion would start, by the line.
    pub breakaway: f64,
    /// Command per rad/s.
    pub per_rad_s: f64,
    pub points: usize,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct FrictionMap {
    pub points: Vec<MapPoint>,
    /// The steady moving points, velocity strictly increasing: the map for
    /// the config.
    pub velocity: Vec<f64>,
    pub output: Vec<f64>,
    pub positive: Option<DirectionFit>,
    pub negative: Option<DirectionFit>,
}

/// Below this, rad/s, the load is taken to stand still.
const STANDSTILL: f64 = 1e-3;
/// The last half's two quarters agree within this share of the velocity
/// plus this many rad/s: a settled step. The rotator's lightly damped
/// hydraulic mode still rings a little in the last half of a 2 s step.
const STEADY_RELATIVE: f64 = 0.1;
const STEADY_ABSOLUTE: f64 = 0.01;

/// The map from time `t`, command `u` and angle `theta`; steps shorter than
/// `min_step_s` are skipped (transitions, or a command that kept moving).
pub fn friction_map(t: &[f64], u: &[f64], theta: &[f64], min_step_s: f64) -> Result<FrictionMap, IdentError> {
    if u.len() != theta.len() || t.len() != u.len() {
        return Err(IdentError::Lengths {
            input: u.len(),
            output: theta.len(),
        });
    }
    let mut points = Vec::new();
    let mut start = 0;
    while start < u.len() {
        let mut end = start + 1;
        while end < u.len() && u[end] == u[start] {
            end += 1;
        }
        let duration = t[end - 1] - t[start];
        if duration >= min_step_s && end - start >= 8 {
            let half = start + (end - start) / 2;
            let three_quarters = half + (end - half) / 2;
            let (whole, early, late) = (
                slope(&t[half..end], &theta[half..end]),
                slope(&t[half..three_quarters], &theta[half..three_quarters]),
                slope(&t[three_quarters..end], &theta[three_quarters..end]),
            );
            let steady = (early - late).abs() <= STEADY_RELATIVE * early.abs().max(late.abs()) + STEADY_ABSOLUTE;
            points.push(MapPoint {
                command: u[start],
                velocity_rad_s: whole,
                steady,
                duration_s: duration,
            });
        }
        start = end;
    }
    if points.is_empty() {
        return Err(IdentError::Failed(format!(
            "no step of the command lasts {min_step_s} s: the data holds no valve-current steps"
        )));
    }
    let mut steady: Vec<&MapPoint> = points.iter().filter(|p| p.steady).collect();
    steady.sort_by(|a, b| a.velocity_rad_s.total_cmp(&b.velocity_rad_s));
    let direction = |positive: bool| {
        let moving: Vec<(f64, f64)> = steady
            .iter()
            .filter(|p| {
                if positive {
                    p.velocity_rad_s > STANDSTILL
                } else {
                    p.velocity_rad_s < -STANDSTILL
                }
            })
            .map(|p| (p.velocity_rad_s, p.command))
            .collect();
        line(&moving).map(|(intercept, gradient)| DirectionFit {
            breakaway: intercept,
            per_rad_s: gradient,
            points: moving.len(),
        })
    };
    // The map holds the moving points only: the commands within the dead
    // band all hold the load still, and a map must rise strictly with the
    // velocity (the friction compensation refuses repeats).
    let mut velocity: Vec<f64> = Vec::with_capacity(steady.len());
    let mut output: Vec<f64> = Vec::with_capacity(steady.len());
    for p in steady.iter().filter(|p| p.velocity_rad_s.abs() > STANDSTILL) {
        if velocity.last().is_some_and(|&v| p.velocity_rad_s <= v) {
            continue;
        }
        velocity.push(p.velocity_rad_s);
        output.push(p.command);
    }
    Ok(FrictionMap {
        velocity,
        output,
        positive: direction(true),
        negative: direction(false),
        points,
    })
}

fn slope(t: &[f64], y: &[f64]) -> f64 {
    let pairs: Vec<(f64, f64)> = t.iter().copied().zip(y.iter().copied()).collect();
    line(&pairs).map_or(0.0, |(_, gradient)| gradient)
}

/// Least-squares line through (x, y): (intercept, gradient); `None` for
/// fewer than two distinct x.
fn line(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    let n = points.len() as f64;
    if points.len() < 2 {
        return None;
    }
    let (mx, my) = (
        points.iter().map(|p| p.0).sum::<f64>() / n,
        points.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let gradient = sxy / sxx;
    Some((my - gradient * mx, gradient))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A first-order load with Coulomb friction: it moves at
    /// (|u| − c)/b in the direction of u once |u| exceeds c.
    fn steps(levels: &[f64], dwell: f64, c: f64, b: f64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let ts = 1e-3;
        let (mut t, mut u, mut theta) = (Vec::new(), Vec::new(), Vec::new());
        let (mut angle, mut velocity) = (0.0, 0.0);
        for &level in levels {
            let target = if f64::abs(level) > c {
                (level - c * f64::signum(level)) / b
            } else {
                0.0
            };
            for _ in 0..(dwell / ts) as usize {
                velocity += (target - velocity) * ts / 0.05;
                angle += velocity * ts;
                t.push(t.len() as f64 * ts);
                u.push(level);
                theta.push(angle);
            }
        }
        (t, u, theta)
    }

    #[test]
    fn coulomb_and_viscous_friction_are_read_from_steps() {
        let levels: Vec<f64> = (1..=10).flat_map(|k| [0.1 * k as f64, -0.1 * k as f64]).collect();
        let (t, u, theta) = steps(&levels, 1.5, 0.15, 0.5);
        let map = friction_map(&t, &u, &theta, 1.0).expect("map");
        assert_eq!(map.points.len(), 20);
        assert!(map.points.iter().all(|p| p.steady), "{:?}", map.points);
        let positive = map.positive.expect("moving up");
        let negative = map.negative.expect("moving down");
        assert!((positive.breakaway - 0.15).abs() < 0.01, "{positive:?}");
        assert!((negative.breakaway + 0.15).abs() < 0.01, "{negative:?}");
        assert!((positive.per_rad_s - 0.5).abs() < 0.02, "{positive:?}");
        // The commands that hold the load still are points, not map entries:
        // the map rises strictly, as the friction compensation requires.
        assert!(map
            .points
            .iter()
            .any(|p| p.command == 0.1 && p.velocity_rad_s.abs() < 1e-6));
        assert_eq!(map.velocity.len(), 18);
        assert!(map.velocity.windows(2).all(|w| w[0] < w[1]));
        let compensation = hydractl_control::StaticMap {
            velocity: map.velocity.clone(),
            output: map.output.clone(),
        };
        compensation.validate("map").expect("a valid map");
    }

    #[test]
    fn data_without_steps_is_refused() {
        let t: Vec<f64> = (0..1000).map(|i| i as f64 * 1e-3).collect();
        let u: Vec<f64> = t.iter().map(|x| x.sin()).collect();
        assert!(friction_map(&t, &u, &u, 1.0).is_err());
    }
}
