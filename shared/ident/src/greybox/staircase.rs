//! A coarse encoder's staircase: the shaft path whose readings on the
//! lattice match the measured steps best.

use super::*;

/// A staircase's squared error in counts of its step (step² times the
/// angle's), the path shifted by `shift(i)` counts at sample i, one shift
/// at a time (see [`staircase_errors`] for a grid of them): each sample
/// costs a rounding, not the quantizer's division, in the searches that
/// take most of a coarse encoder's fit. Given up (infinite) once it reaches
/// `bound`: its terms only add, so a search that keeps the smallest is
/// unchanged by it, and most of its tries are out of the race after a few
/// samples.
pub(super) fn staircase_error_below(
    measured_counts: &[f64],
    path_counts: &[f64],
    shift: impl Fn(usize) -> f64,
    bound: f64,
) -> f64 {
    // The terms are whole numbers, so their sum is exact in any order: a
    // block's terms are computed and added together, and a sum that only
    // grows reaches the bound within a block if and only if at its end.
    // (Sample by sample, each rounding and check waited for the sum.)
    const BLOCK: usize = 8;
    let n = measured_counts.len().min(path_counts.len());
    let term = |i: usize, measured: f64, path: f64| (measured - Quantization::nearest_count(path + shift(i))).powi(2);
    // Blocks spread over the segment first: a shift that misses the
    // staircase misses it somewhere, and its error reaches the bound
    // sooner when every part of the segment is sampled early.
    const SPREAD: usize = 8;
    let blocks = n / BLOCK;
    let mut sum = 0.0;
    for b in (0..SPREAD).flat_map(|phase| (phase..blocks).step_by(SPREAD)) {
        let first = b * BLOCK;
        let (measured, path) = (
            &measured_counts[first..first + BLOCK],
            &path_counts[first..first + BLOCK],
        );
        let t: [f64; BLOCK] = std::array::from_fn(|j| term(first + j, measured[j], path[j]));
        sum += ((t[0] + t[1]) + (t[2] + t[3])) + ((t[4] + t[5]) + (t[6] + t[7]));
        if sum >= bound {
            return f64::INFINITY;
        }
    }
    for i in n - n % BLOCK..n {
        sum += term(i, measured_counts[i], path_counts[i]);
    }
    if sum >= bound {
        return f64::INFINITY;
    }
    sum
}

/// A staircase's squared errors for a grid of shifts at once: the path
/// shifted by `angles[j] + velocities[k] · sensitivity[i]` counts at sample
/// i, against the measured staircase in whole counts. `errors[k · angles.len() + j]` is the sum of
/// (measured − rounded path)² over the samples: whole numbers, exact in any
/// order, so it is the same as scoring the shifts one by one.
///
/// The angles and velocities are ascending and the sensitivity is not
/// negative, so a sample's rounded count only grows along a row of the
/// grid: it is rounded at the grid's corners, and where they differ at each
/// row's ends, and the row's few steps are found by bisection. A sample
/// whose count the whole grid leaves alone (most, once the grid is fine)
/// costs two roundings, where scoring the shifts one by one cost one per
/// shift. `None` where the path is not finite, or so far from the
/// measurement that its squares would not be exact.
pub(super) fn staircase_errors(
    measured_counts: &[f64],
    path_counts: &[f64],
    sensitivity: &[f64],
    angles: &[f64],
    velocities: &[f64],
) -> Option<Vec<f64>> {
    // Counts apart beyond which a square loses whole numbers in a sum.
    const FARTHEST: f64 = 1e6;
    let (columns, rows) = (angles.len(), velocities.len());
    if columns == 0 || rows == 0 {
        return Some(Vec::new());
    }
    let mut common = 0.0;
    // Per row, the change of the error from each column to the next.
    let mut steps = vec![0.0; rows * columns];
    for ((&measured, &path), &g) in measured_counts.iter().zip(path_counts).zip(sensitivity) {
        let count = |j: usize, k: usize| Quantization::nearest_count(path + (angles[j] + velocities[k] * g));
        let term = |count: f64| (measured - count).powi(2);
        let (lowest, highest) = (count(0, 0), count(columns - 1, rows - 1));
        if !((measured - lowest).abs() <= FARTHEST && (measured - highest).abs() <= FARTHEST) {
            return None;
        }
        if lowest == highest {
            common += term(lowest);
            continue;
        }
        for (k, row) in steps.chunks_exact_mut(columns).enumerate() {
            let (mut j, mut current) = (0, count(0, k));
            let last = count(columns - 1, k);
            row[0] += term(current);
            while current < last {
                // The first column past j where the count grows.
                let (mut below, mut above) = (j, columns - 1);
                while above - below > 1 {
                    let middle = (below + above) / 2;
                    if count(middle, k) > current {
                        above = middle;
                    } else {
                        below = middle;
                    }
                }
                let next = count(above, k);
                row[above] += term(next) - term(current);
                (j, current) = (above, next);
            }
        }
    }
    for row in steps.chunks_exact_mut(columns) {
        let mut error = common;
        for cell in row {
            error += *cell;
            *cell = error;
        }
    }
    Some(steps)
}

/// A segment's measured angles in whole counts of a coarse encoder's
/// step, once for every search of the segment.
pub(super) struct Staircase {
    pub(super) step: f64,
    pub(super) measured_counts: Vec<f64>,
}

impl Staircase {
    pub(super) fn of(step: f64, measured: &[f64]) -> Self {
        Self {
            step,
            measured_counts: measured.iter().map(|m| Quantization::nearest_count(m / step)).collect(),
        }
    }

    /// A path in counts of the step.
    pub(super) fn in_counts(&self, path: &[f64]) -> Vec<f64> {
        path.iter().map(|p| p / self.step).collect()
    }
}

/// With a coarse encoder, least squares on the staircase leaves the initial
/// angle uncertain by up to half a step; this picks, within half a step, the
/// shift of the segment that reproduces the measured staircase best (the
/// first of the least, from −half a step up).
pub(super) fn best_quantized_offset(staircase: &Staircase, shaft: &[f64]) -> f64 {
    const TRIES: usize = 21;
    let (measured_counts, shaft_counts) = (&staircase.measured_counts, staircase.in_counts(shaft));
    let offset = |i: usize| i as f64 / (TRIES - 1) as f64 - 0.5;
    let errors = nearest_first(
        TRIES,
        |i| i.abs_diff(TRIES / 2),
        |i, bound| staircase_error_below(measured_counts, &shaft_counts, |_| offset(i), bound),
    );
    let least = errors.iter().copied().fold(f64::INFINITY, f64::min);
    errors
        .iter()
        .position(|&e| e == least)
        .map_or(0.0, |i| offset(i) * staircase.step)
}

/// The errors of `count` candidates, scored nearest the likely best first
/// (by `distance`): the least so far bounds the rest, which are given up
/// (infinite) once they exceed it. The path comes from least squares on the
/// staircase, so shifts near none are likely best, and a bound from them
/// leaves most others after a few samples. Every candidate that ties the
/// least keeps its exact error.
pub(super) fn nearest_first(
    count: usize,
    distance: impl Fn(usize) -> usize,
    error: impl Fn(usize, f64) -> f64,
) -> Vec<f64> {
    let mut order: Vec<usize> = (0..count).collect();
    order.sort_by_key(|&i| distance(i));
    let mut errors = vec![f64::INFINITY; count];
    let mut least = f64::INFINITY;
    for i in order {
        errors[i] = error(i, least.next_up());
        least = least.min(errors[i]);
    }
    errors
}

/// With a coarse encoder a segment's staircase holds only a few steps, and
/// least squares on it leaves the initial velocity uncertain as well as the
/// angle: over a 0.5 s segment a 10° encoder cannot tell velocities apart
/// by less than a step per segment. This searches the initial angle (within
/// half a step) and velocity (within a step per segment) together, on a
/// coarse grid and then a finer one around its best, for the shift of the
/// segment that reproduces the measured staircase best; the velocity
/// shifts the path by the rigid body's sensitivity.
pub(super) fn refine_on_staircase(
    plant: &PlantParams,
    dt: f64,
    staircase: &Staircase,
    measured: &[f64],
    path: &mut [f64],
) {
    const GRID: i32 = 6;
    const SIDE: usize = 2 * GRID as usize + 1;
    let n = path.len().min(measured.len());
    // A staircase that steps at least every tenth sample pins the path
    // down already (a fine encoder on a moving load): no search needed.
    let steps_taken = measured[..n].windows(2).filter(|w| w[0] != w[1]).count();
    if n < 2 || steps_taken * 10 >= n {
        return;
    }
    let sensitivity: Vec<f64> = velocity_sensitivity(plant, dt).take(n).collect();
    let span_t = sensitivity[n - 1].max(dt);
    let (measured_counts, path_counts) = (&staircase.measured_counts[..n], staircase.in_counts(&path[..n]));
    // In counts: half a step of angle, two steps per segment of velocity.
    let (mut angle_span, mut velocity_span) = (0.5, 2.0 / span_t);
    let (mut centre_angle, mut centre_velocity) = (0.0, 0.0);
    for level in 0..3 {
        let around = |centre: f64, span: f64| -> [f64; SIDE] {
            std::array::from_fn(|i| centre + span * f64::from(i as i32 - GRID) / f64::from(GRID))
        };
        let (angles, velocities) = (around(centre_angle, angle_span), around(centre_velocity, velocity_span));
        // The coarse grid spans a whole step of angle, which moves every
        // sample's count: its shifts are scored one by one, most given up
        // after a few samples. The finer grids move few samples' counts
        // and are scored at once.
        let errors = if level == 0 {
            let ring = |i: usize| (i % SIDE).abs_diff(SIDE / 2).max((i / SIDE).abs_diff(SIDE / 2));
            nearest_first(SIDE * SIDE, ring, |cell, bound| {
                let (a, v) = (cell % SIDE, cell / SIDE);
                let shift = |i: usize| angles[a] + velocities[v] * sensitivity[i];
                staircase_error_below(measured_counts, &path_counts, shift, bound)
            })
        } else {
            match staircase_errors(measured_counts, &path_counts, &sensitivity, &angles, &velocities) {
                Some(errors) => errors,
                None => return,
            }
        };
        // The centre stays unless a shift does better; among the better,
        // the first by angle, then velocity.
        let error = |a: usize, v: usize| errors[v * SIDE + a];
        let centre = GRID as usize;
        let mut best = (error(centre, centre), centre, centre);
        for a in 0..SIDE {
            for v in 0..SIDE {
                if error(a, v) < best.0 {
                    best = (error(a, v), a, v);
                }
            }
        }
        (centre_angle, centre_velocity) = (angles[best.1], velocities[best.2]);
        angle_span /= f64::from(GRID);
        velocity_span /= f64::from(GRID);
    }
    for (p, g) in path.iter_mut().zip(&sensitivity) {
        *p += (centre_angle + centre_velocity * g) * staircase.step;
    }
}
