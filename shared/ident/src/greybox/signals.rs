//! The measured signals the grey-box model is compared with, in SI units,
//! with the smoothed angle and velocity the model's segments start from.

use std::ops::Range;

use hydractl_plant::{EffectKind, PlantParams, PA_PER_BAR};

use super::{ModelError, Part, SEGMENT_S};
use crate::Dataset;

/// The columns every record needs: time and the encoder's angle. Besides
/// them, the valve command `u` or a measured torque `tau` drives the model.
pub const REQUIRED_COLUMNS: [&str; 2] = ["t", "theta"];

/// The columns the model can use, with their units.
pub const COLUMNS: &str =
    "t (s), theta (rad), and u (valve command, [-1, 1]), p_a and p_b (bar), tau (N·m) where measured";

/// Half-width of the smoothing that turns encoder counts into a velocity, s.
/// Wide enough that one count of a 4000-count encoder moves the velocity by
/// under 0.01 rad/s, narrow against the 13 rad/s hydraulic mode; a coarser
/// encoder's is wider ([`smoothing_half_width`]).
const SMOOTHING_HALF_WIDTH_S: f64 = 0.02;

/// Measured data at a uniform sample time, SI units. A signal that was not
/// measured holds NaN, and the parts that need it are not fitted.
#[derive(Debug, Clone)]
pub struct Signals {
    pub source: String,
    pub dt: f64,
    pub t: Vec<f64>,
    /// Valve command as sent, [-1, 1].
    pub u: Vec<f64>,
    /// Chamber pressures, Pa.
    pub p_a: Vec<f64>,
    pub p_b: Vec<f64>,
    /// A torque measured directly (a load cell, a motor's current), N·m.
    pub tau: Option<Vec<f64>>,
    /// Encoder angle, rad.
    pub theta: Vec<f64>,
    /// The angle and velocity of a local straight-line fit (zero phase).
    pub theta_smooth: Vec<f64>,
    pub velocity: Vec<f64>,
    /// The velocity's slope by the same local line, rad/s².
    pub acceleration: Vec<f64>,
    /// The direction of the angle's last motion at or before each sample
    /// (by the smoothed velocity): +1, −1, or 0 before the first. The
    /// mechanical part reads where a load sits in a play from it.
    pub last_motion: Vec<f64>,
    /// Per unit of a play between the actuator and the encoder, how much
    /// faster than the encoder's reading the actuator moves: at each
    /// reversal it crosses the play while the reading holds
    /// ([`play_crossing`]), rad/s per rad of play.
    pub play_crossing: Vec<f64>,
    /// Where the record resumes after readings left out (a sensor without
    /// a value, rows missing from a file): the first sample of each
    /// stretch after the first, ascending. The shooting segments restart
    /// there and no smoothing reaches across.
    pub breaks: Vec<usize>,
    /// Whether the record has the valve command and the chamber pressures.
    pub has_command: bool,
    pub has_pressures: bool,
}

impl Signals {
    /// From a dataset with the columns `t` (s) and `theta` (rad) and any
    /// of `u` (command), `p_a`, `p_b` (bar) and `tau` (N·m): a column that
    /// is absent, or empty in every row, was not measured.
    pub fn from_dataset(data: &Dataset) -> Result<Self, ModelError> {
        let source = data.source.display().to_string();
        let fail = |reason: String| ModelError::Signals {
            source_name: source.clone(),
            reason,
        };
        let t = data.column("t")?.to_vec();
        let theta = data.column("theta")?.to_vec();
        // A column measured in some rows only is a defect of the file, not
        // a sensor the machine lacks.
        let optional = |name: &str| -> Result<Option<Vec<f64>>, ModelError> {
            let Ok(column) = data.column(name) else {
                return Ok(None);
            };
            let missing = column.iter().filter(|v| !v.is_finite()).count();
            if missing == column.len() {
                return Ok(None);
            }
            if let Some(i) = column.iter().position(|v| !v.is_finite()) {
                return Err(fail(format!(
                    "line {}: column `{name}` has no value here (empty or NaN) but has values in other rows \
                     (leave it empty in every row if the machine has no such sensor)",
                    i + 2
                )));
            }
            Ok(Some(column.to_vec()))
        };
        let u = optional("u")?;
        let p_a = optional("p_a")?;
        let p_b = optional("p_b")?;
        let tau = optional("tau")?;
        let has_pressures = match (&p_a, &p_b) {
            (Some(_), Some(_)) => true,
            (None, None) => false,
            (Some(_), None) => return Err(fail("column `p_a` without `p_b`: both chambers or neither".to_owned())),
            (None, Some(_)) => return Err(fail("column `p_b` without `p_a`: both chambers or neither".to_owned())),
        };
        if u.is_none() && tau.is_none() && !has_pressures {
            return Err(fail(
                "neither the valve command `u`, the chamber pressures `p_a`, `p_b` nor a measured torque `tau`: \
                 nothing drives the model"
                    .to_owned(),
            ));
        }
        let n = t.len();
        let bar =
            |p: Option<Vec<f64>>| p.map_or_else(|| vec![f64::NAN; n], |p| p.iter().map(|v| v * PA_PER_BAR).collect());
        let has_command = u.is_some();
        let u = u.unwrap_or_else(|| vec![0.0; n]);
        let (p_a, p_b) = (bar(p_a), bar(p_b));
        let (median_step, breaks) = sample_time_and_breaks(&t).map_err(fail)?;
        // Unbroken, the mean step: the same to the last digit whatever the
        // rounding of each time stamp.
        let dt = if breaks.is_empty() {
            data.sample_time()?
        } else {
            median_step
        };
        if let Some(i) = u.iter().position(|u| u.abs() > 1.0 + 1e-9) {
            return Err(fail(format!(
                "line {}: column `u`: {} is outside [-1, 1] (the valve command as sent)",
                i + 2,
                u[i]
            )));
        }
        // The readings left out do not count.
        let duration = if breaks.is_empty() {
            t[n - 1] - t[0]
        } else {
            (n - 1 - breaks.len()) as f64 * dt
        };
        if duration < 8.0 * SEGMENT_S {
            return Err(fail(format!(
                "{duration} s of data{}; the model tools need at least {} s",
                if breaks.is_empty() {
                    ""
                } else {
                    " besides the readings left out"
                },
                8.0 * SEGMENT_S
            )));
        }
        let half_width = smoothing_half_width(crate::greybox::fit::encoder_step(&theta), dt);
        let (theta_smooth, velocity) = per_stretch(&breaks, &theta, |x| local_line(x, dt, half_width));
        let acceleration = per_stretch(&breaks, &velocity, |x| local_line(x, dt, half_width)).1;
        let last_motion = last_motion(&velocity);
        let drive: Option<Vec<f64>> = has_pressures.then(|| p_a.iter().zip(&p_b).map(|(a, b)| a - b).collect());
        let play_crossing = play_crossing(&velocity, &last_motion, drive.as_deref(), dt);
        Ok(Self {
            source,
            dt,
            t,
            u,
            p_a,
            p_b,
            tau,
            theta,
            theta_smooth,
            velocity,
            acceleration,
            last_motion,
            play_crossing,
            breaks,
            has_command,
            has_pressures,
        })
    }

    /// The parts of the model this record can test: the hydraulic part
    /// needs the command and the pressures; the mechanical part a torque,
    /// measured or from the pressures; with the command alone, the whole
    /// path from command to angle.
    pub fn parts(&self) -> Vec<Part> {
        parts_measured(self.has_command, self.has_pressures, self.tau.is_some())
    }

    /// The part of the model through which this record shows `kind`, or
    /// why it cannot show it.
    pub fn part_for(&self, kind: EffectKind) -> Result<Part, String> {
        part_showing(&self.parts(), self.has_command, kind)
    }

    pub fn len(&self) -> usize {
        self.t.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// The torque driving the mechanical part at sample `k`, N·m: the one
    /// measured directly, else the hydraulic torque D (p_a − p_b).
    pub fn torque(&self, plant: &PlantParams, k: usize) -> f64 {
        match &self.tau {
            Some(tau) => tau[k],
            None => plant.displacement * (self.p_a[k] - self.p_b[k]),
        }
    }

    /// The stretches of consecutive readings: the whole record, or the
    /// pieces between the readings left out.
    pub fn stretches(&self) -> impl Iterator<Item = Range<usize>> + '_ {
        stretches_between(&self.breaks, self.len())
    }

    /// Each gap of readings left out: the times of the readings either
    /// side of it, s.
    pub fn gaps(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.breaks.iter().map(|&k| (self.t[k - 1], self.t[k]))
    }

    /// What the readings left out come to, for a person: none, or how
    /// many gaps, how long in all, and where the first few are.
    pub fn gaps_said(&self) -> Option<String> {
        if self.breaks.is_empty() {
            return None;
        }
        let total: f64 = self.gaps().map(|(before, after)| after - before - self.dt).sum();
        let shown: Vec<String> = self.gaps().take(5).map(|(a, b)| format!("{a:.3}–{b:.3} s")).collect();
        Some(format!(
            "readings left out in {} gap(s), {total:.3} s in all (between {}{}); the segments restart after each",
            self.breaks.len(),
            shown.join(", "),
            if self.breaks.len() > shown.len() { ", …" } else { "" }
        ))
    }

    /// The first sample of the stretch that holds sample `k`.
    pub fn stretch_start(&self, k: usize) -> usize {
        match self.breaks.partition_point(|&b| b <= k) {
            0 => 0,
            i => self.breaks[i - 1],
        }
    }

    /// The first sample of the validation segment: the estimation segment
    /// is the first `estimation_fraction` of the record.
    pub fn split(&self, estimation_fraction: f64) -> usize {
        ((self.len() as f64 * estimation_fraction).round() as usize).clamp(1, self.len() - 1)
    }
}

/// How far a count moves the smoothed velocity at most, rad/s.
const COUNT_VELOCITY: f64 = 0.01;

/// The widest smoothing, s, for a coarse encoder.
const MAX_SMOOTHING_HALF_WIDTH_S: f64 = 0.1;

/// The smoothing's half-width, samples: [`SMOOTHING_HALF_WIDTH_S`], wider
/// for a coarse encoder (`step`, rad), so that a count entering the window
/// moves the velocity by under [`COUNT_VELOCITY`] (by 1.5 step / (w² dt)).
fn smoothing_half_width(step: f64, dt: f64) -> usize {
    let least = SMOOTHING_HALF_WIDTH_S / dt;
    let for_count = (1.5 * step / (COUNT_VELOCITY * dt)).sqrt();
    for_count
        .min(MAX_SMOOTHING_HALF_WIDTH_S / dt)
        .max(least)
        .round()
        .max(1.0) as usize
}

/// The sample time, the median step of `t`, and the samples after each
/// step of a whole number of sample times (readings left out). Any other
/// step is an error naming its line.
fn sample_time_and_breaks(t: &[f64]) -> Result<(f64, Vec<usize>), String> {
    let mut steps: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    if steps.is_empty() {
        return Err("fewer than two samples".to_owned());
    }
    steps.sort_by(f64::total_cmp);
    let dt = steps[steps.len() / 2];
    if dt.is_nan() || dt <= 0.0 {
        return Err("column `t` does not increase".to_owned());
    }
    let mut breaks = Vec::new();
    for (i, w) in t.windows(2).enumerate() {
        let periods = (w[1] - w[0]) / dt;
        let whole = periods.round();
        if (periods - whole).abs() > 0.1 || whole < 1.0 {
            return Err(format!(
                "line {}: column `t`: the sample time changes from {dt} s to {} s; \
                 the model tools need uniformly sampled data (rows may be missing, not moved)",
                i + 3,
                w[1] - w[0]
            ));
        }
        if whole > 1.0 {
            breaks.push(i + 1);
        }
    }
    Ok((dt, breaks))
}

/// The stretches of `len` samples between `breaks` (ascending, each the
/// first sample after a gap).
fn stretches_between(breaks: &[usize], len: usize) -> impl Iterator<Item = Range<usize>> + '_ {
    let starts = std::iter::once(0).chain(breaks.iter().copied());
    let ends = breaks.iter().copied().chain(std::iter::once(len));
    starts.zip(ends).map(|(start, end)| start..end)
}

/// `smooth` applied to each stretch of `x` between `breaks` on its own,
/// the pieces joined again.
fn per_stretch(breaks: &[usize], x: &[f64], smooth: impl Fn(&[f64]) -> (Vec<f64>, Vec<f64>)) -> (Vec<f64>, Vec<f64>) {
    if breaks.is_empty() {
        return smooth(x);
    }
    let (mut level, mut slope) = (Vec::with_capacity(x.len()), Vec::with_capacity(x.len()));
    for stretch in stretches_between(breaks, x.len()) {
        let (l, s) = smooth(&x[stretch]);
        level.extend(l);
        slope.extend(s);
    }
    (level, slope)
}

/// The direction of the last motion at or before each sample: the sign of
/// the last smoothed velocity faster than a tenth of the record's RMS
/// (motion, not noise).
fn last_motion(velocity: &[f64]) -> Vec<f64> {
    let moving = moving_speed(velocity);
    let mut sign = 0.0;
    velocity
        .iter()
        .map(|v| {
            if v.abs() > moving {
                sign = v.signum();
            }
            sign
        })
        .collect()
}

/// The speed above which the reading moves rather than shakes with noise:
/// a tenth of the record's RMS velocity.
fn moving_speed(velocity: &[f64]) -> f64 {
    let mean_square = velocity.iter().map(|v| v * v).sum::<f64>() / velocity.len().max(1) as f64;
    0.1 * mean_square.sqrt()
}

/// Per unit of play, the actuator's speed beyond the reading's while it
/// crosses a play. The encoder's side stops when the actuator turns back
/// and moves again once the actuator has crossed the whole play, so the
/// crossing fills the reading's stand-still between the last motion one
/// way and the first the other. Over it the actuator speeds up from rest
/// as the chambers push it: its speed follows the pressure difference's
/// impulse since the stand-still began (`drive`, p_a − p_b), scaled to
/// cross the whole play; without pressures, or where they never push the
/// new way, a ramp. The chambers' flow follows the actuator: taken from
/// the reading's motion alone, the crossing is flow the pressures' model
/// never sees, and beside a play a 20 ms delay fitted at 15 ms or none,
/// the pressures at NRMSE 0.13–0.23 (0.08–0.13 with it).
fn play_crossing(velocity: &[f64], last_motion: &[f64], drive: Option<&[f64]>, dt: f64) -> Vec<f64> {
    let moving = moving_speed(velocity);
    let mut crossing = vec![0.0; velocity.len()];
    let mut last_moving: Option<usize> = None;
    for k in 1..velocity.len() {
        let (before, now) = (last_motion[k - 1], last_motion[k]);
        if before != 0.0 && now != before {
            if let Some(end) = last_moving {
                let dwell = &mut crossing[end + 1..=k];
                let samples = dwell.len() as f64;
                let mut impulse = 0.0;
                let mut total = 0.0;
                if let Some(drive) = drive {
                    for (c, d) in dwell.iter_mut().zip(&drive[end + 1..=k]) {
                        impulse += now * d;
                        *c = impulse.max(0.0);
                        total += *c;
                    }
                }
                if total > 0.0 && total.is_finite() {
                    for c in dwell.iter_mut() {
                        *c *= now / (total * dt);
                    }
                } else {
                    for (j, c) in dwell.iter_mut().enumerate() {
                        *c = now * 2.0 * (j + 1) as f64 / (samples * (samples + 1.0) * dt);
                    }
                }
            }
        }
        if velocity[k].abs() > moving {
            last_moving = Some(k);
        }
    }
    crossing
}

/// The slope of `x` by the same local line as the velocity's.
pub(crate) fn smoothed_slope(x: &[f64], dt: f64) -> Vec<f64> {
    let half_width = ((SMOOTHING_HALF_WIDTH_S / dt).round() as usize).max(1);
    local_line(x, dt, half_width).1
}

/// A centred moving average over ± `half_width_s`.
pub(crate) fn moving_average(x: &[f64], half_width_s: f64, dt: f64) -> Vec<f64> {
    let half_width = ((half_width_s / dt).round() as usize).max(1);
    local_line(x, dt, half_width).0
}

/// Level and slope of a least-squares line through the samples within
/// `half_width` of each one (a first-order Savitzky–Golay filter), with the
/// window shrunk symmetrically at the ends.
fn local_line(x: &[f64], dt: f64, half_width: usize) -> (Vec<f64>, Vec<f64>) {
    let n = x.len();
    // Running sums of x and of i·x: each window's sum and first moment in
    // two differences, whatever its width (the rigid body's 0.1 s low-pass
    // summed 201 samples per sample, on every mechanical fit).
    let mut sums = Vec::with_capacity(n + 1);
    let mut moments = Vec::with_capacity(n + 1);
    let (mut sum, mut moment) = (0.0, 0.0);
    sums.push(sum);
    moments.push(moment);
    for (i, v) in x.iter().enumerate() {
        sum += v;
        moment += i as f64 * v;
        sums.push(sum);
        moments.push(moment);
    }
    let mut level = vec![0.0; n];
    let mut slope = vec![0.0; n];
    for k in 0..n {
        let w = half_width.min(k).min(n - 1 - k);
        if w == 0 {
            level[k] = x[k];
            continue;
        }
        let (lo, hi) = (k - w, k + w + 1);
        let window_sum = sums[hi] - sums[lo];
        let window_moment = moments[hi] - moments[lo] - k as f64 * window_sum;
        let squares = (w * (w + 1) * (2 * w + 1)) as f64 / 3.0;
        level[k] = window_sum / (2 * w + 1) as f64;
        slope[k] = window_moment / (squares * dt);
    }
    (level, slope)
}

/// The parts a record of these signals can fit (see [`Signals::parts`]).
pub fn parts_measured(has_command: bool, has_pressures: bool, has_torque: bool) -> Vec<Part> {
    let mut parts = Vec::new();
    if has_command && has_pressures {
        parts.push(Part::Hydraulic);
    }
    if has_pressures || has_torque {
        parts.push(Part::Mechanical);
    } else if has_command {
        parts.push(Part::Whole);
    }
    parts
}

/// The part of a model with these `parts` (from a record with or without
/// a valve command) through which `kind` shows, or why it cannot show:
/// what [`Signals::part_for`] says of a record, known before any data.
pub fn part_showing(parts: &[Part], has_command: bool, kind: EffectKind) -> Result<Part, String> {
    let own = Part::of(kind);
    if parts.contains(&own) {
        return Ok(own);
    }
    if parts.contains(&Part::Whole) {
        return match kind {
            EffectKind::OrificeFlow => Err(
                "no chamber pressures: the √Δp flow shows only in how the pressures approach supply and tank"
                    .to_owned(),
            ),
            EffectKind::LoadFlexibility => Err(
                "no pressures or torque: with the valve between command and motion, a flexible load's ring \
                 cannot be told from the hydraulic mode's"
                    .to_owned(),
            ),
            _ => Ok(Part::Whole),
        };
    }
    Err(match own {
        Part::Hydraulic if !has_command => {
            "no valve command `u`: the axis is driven by the measured torque, the hydraulic part is not fitted"
                .to_owned()
        }
        Part::Hydraulic => "no chamber pressures `p_a`, `p_b`: the hydraulic part is not fitted".to_owned(),
        _ => "no torque `tau` or pressures: the mechanical part is not fitted".to_owned(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Five seconds at 1 kHz of the named columns, each a gentle sine, with
    /// `holes` (column, row) left empty.
    fn record(names: &[&str], holes: &[(&str, usize)]) -> Dataset {
        let n = 5000;
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 1e-3).collect();
        let mut columns = vec![("t", t.clone())];
        for &name in names {
            let mut column: Vec<f64> = t.iter().map(|t| 0.1 * (t * 3.0).sin()).collect();
            for &(hole, row) in holes {
                if hole == name {
                    column[row] = f64::NAN;
                }
            }
            columns.push((name, column));
        }
        Dataset::from_columns("record.csv", columns)
    }

    fn reason(data: &Dataset) -> String {
        match Signals::from_dataset(data) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("accepted"),
        }
    }

    #[test]
    fn the_parts_fitted_follow_the_sensors() {
        let parts = |names: &[&str]| Signals::from_dataset(&record(names, &[])).expect("valid").parts();
        assert_eq!(
            parts(&["u", "p_a", "p_b", "theta"]),
            [Part::Hydraulic, Part::Mechanical]
        );
        assert_eq!(parts(&["u", "theta"]), [Part::Whole]);
        assert_eq!(parts(&["tau", "theta"]), [Part::Mechanical]);
        assert_eq!(parts(&["u", "tau", "theta"]), [Part::Mechanical]);
        assert_eq!(parts(&["p_a", "p_b", "theta"]), [Part::Mechanical]);
        // A column empty in every row is a sensor the machine lacks.
        let all_empty: Vec<(&str, usize)> = (0..5000).flat_map(|i| [("p_a", i), ("p_b", i)]).collect();
        let data = record(&["u", "p_a", "p_b", "theta"], &all_empty);
        assert_eq!(Signals::from_dataset(&data).expect("valid").parts(), [Part::Whole]);
    }

    /// `data` without the rows in `left_out`, as a file with rows missing.
    fn without_rows(data: &Dataset, names: &[&str], left_out: Range<usize>) -> Dataset {
        let columns = std::iter::once("t")
            .chain(names.iter().copied())
            .map(|name| {
                let column = data.column(name).expect("column");
                let kept = column[..left_out.start].iter().chain(&column[left_out.end..]);
                (name, kept.copied().collect())
            })
            .collect();
        Dataset::from_columns("record.csv", columns)
    }

    #[test]
    fn rows_missing_break_the_record_and_nothing_reaches_across() {
        let names = ["u", "p_a", "p_b", "theta"];
        let whole = record(&names, &[]);
        let broken = Signals::from_dataset(&without_rows(&whole, &names, 1200..2000)).expect("valid");
        assert_eq!(broken.breaks, vec![1200]);
        assert!((broken.dt - 1e-3).abs() < 1e-12, "{}", broken.dt);
        assert_eq!(broken.stretches().collect::<Vec<_>>(), vec![0..1200, 1200..4200]);
        assert_eq!((broken.stretch_start(1199), broken.stretch_start(1200)), (0, 1200));
        let said = broken.gaps_said().expect("a gap");
        assert!(
            said.starts_with("readings left out in 1 gap(s), 0.800 s in all (between 1.199–2.000 s)"),
            "{said}"
        );
        // A segment starts where the record resumes; none crosses.
        let segments: Vec<_> = crate::greybox::segments(&broken, 0..broken.len()).collect();
        assert!(segments.iter().any(|s| s.start == 1200));
        assert!(
            segments.iter().all(|s| s.end <= 1200 || s.start >= 1200),
            "{segments:?}"
        );
        // Each side of the jump, the velocity is its own stretch's slope,
        // not a line through the jump.
        let slope = |t: f64| 0.3 * (3.0 * t).cos();
        for (k, t) in [(1190, 1.19), (1230, 2.03)] {
            assert!(
                (broken.velocity[k] - slope(t)).abs() < 1e-3,
                "{k}: {}",
                broken.velocity[k]
            );
        }
        // Moved, not missing: an error naming the line.
        let mut t = whole.column("t").expect("t").to_vec();
        t[3000] += 0.0005;
        let moved = Dataset::from_columns(
            "record.csv",
            vec![
                ("t", t),
                ("theta", whole.column("theta").expect("theta").to_vec()),
                ("u", whole.column("u").expect("u").to_vec()),
            ],
        );
        assert!(reason(&moved).contains("line 3002"), "{}", reason(&moved));
        // Too little left.
        let short = without_rows(&whole, &names, 500..4000);
        assert!(
            reason(&short).contains("besides the readings left out"),
            "{}",
            reason(&short)
        );
    }

    #[test]
    fn a_coarse_encoder_is_smoothed_wider() {
        let counts = |n: f64| std::f64::consts::TAU / n;
        // 4000 counts: the default 20 ms; 2°: 72 ms; 10°: the widest.
        assert_eq!(smoothing_half_width(counts(4000.0), 1e-3), 20);
        assert_eq!(smoothing_half_width(counts(180.0), 1e-3), 72);
        assert_eq!(smoothing_half_width(counts(36.0), 1e-3), 100);
        // Continuous with noise: the default.
        assert_eq!(smoothing_half_width(1e-9, 1e-3), 20);
    }

    #[test]
    fn what_cannot_be_judged_says_why() {
        let motion = Signals::from_dataset(&record(&["u", "theta"], &[])).expect("valid");
        assert_eq!(motion.part_for(EffectKind::Deadzone), Ok(Part::Whole));
        assert_eq!(motion.part_for(EffectKind::Backlash), Ok(Part::Whole));
        assert!(motion
            .part_for(EffectKind::OrificeFlow)
            .is_err_and(|r| r.contains("pressures")));
        let torque = Signals::from_dataset(&record(&["tau", "theta"], &[])).expect("valid");
        assert_eq!(torque.part_for(EffectKind::CoulombFriction), Ok(Part::Mechanical));
        assert!(torque.part_for(EffectKind::Deadzone).is_err_and(|r| r.contains("`u`")));
    }

    #[test]
    fn a_column_missing_in_some_rows_names_its_line() {
        let text = reason(&record(&["u", "p_a", "p_b", "theta"], &[("p_b", 41)]));
        assert!(
            text.contains("record.csv") && text.contains("line 43") && text.contains("`p_b`"),
            "{text}"
        );
        let text = reason(&record(&["u", "p_a", "theta"], &[]));
        assert!(text.contains("`p_a` without `p_b`"), "{text}");
        let text = reason(&record(&["theta"], &[]));
        assert!(text.contains("nothing drives the model"), "{text}");
    }

    #[test]
    fn the_last_motion_outlasts_the_motion_and_ignores_noise() {
        // Still, then forward, then still with a little noise, then back.
        let mut velocity = vec![0.0; 10];
        velocity.extend([1.0; 10]);
        velocity.extend((0..10).map(|i| if i % 2 == 0 { 0.01 } else { -0.01 }));
        velocity.extend([-1.0; 10]);
        let signs = last_motion(&velocity);
        assert!(signs[..10].iter().all(|&s| s == 0.0), "{signs:?}");
        assert!(signs[10..30].iter().all(|&s| s == 1.0), "{signs:?}");
        assert!(signs[30..].iter().all(|&s| s == -1.0), "{signs:?}");
    }

    #[test]
    fn a_play_is_crossed_while_the_reading_stands_still() {
        // Forward, still for 10 samples, then back, then forward at once.
        let dt = 1e-3;
        let mut velocity = vec![1.0; 10];
        velocity.extend([0.0; 10]);
        velocity.extend([-1.0; 10]);
        velocity.extend([1.0; 10]);
        let crossing = play_crossing(&velocity, &last_motion(&velocity), None, dt);
        // Before the first reversal, and while the reading moves one way:
        // nothing beyond the reading's own motion.
        assert!(crossing[..10].iter().all(|&c| c == 0.0), "{crossing:?}");
        assert!(crossing[21..30].iter().all(|&c| c == 0.0), "{crossing:?}");
        // The stand-still and the first sample back cross the whole play
        // backwards, the actuator speeding up until it meets the load.
        let crossed: f64 = crossing[10..21].iter().sum::<f64>() * dt;
        assert!((crossed + 1.0).abs() < 1e-12, "{crossed}");
        assert!(crossing[10..21].windows(2).all(|w| w[1] < w[0]), "{crossing:?}");
        // A reversal with no stand-still crosses the play in one sample.
        assert!((crossing[30] * dt - 1.0).abs() < 1e-12, "{crossing:?}");
        // With pressures, the actuator starts once the chambers push it
        // back: here from the stand-still's sixth sample.
        let drive: Vec<f64> = (0..velocity.len()).map(|k| if k >= 15 { -1e5 } else { 0.0 }).collect();
        let pushed = play_crossing(&velocity, &last_motion(&velocity), Some(&drive), dt);
        assert!(pushed[10..15].iter().all(|&c| c == 0.0), "{pushed:?}");
        assert!(pushed[15..21].windows(2).all(|w| w[1] < w[0]), "{pushed:?}");
        let crossed: f64 = pushed[10..21].iter().sum::<f64>() * dt;
        assert!((crossed + 1.0).abs() < 1e-12, "{crossed}");
    }

    #[test]
    fn local_line_is_exact_on_a_line() {
        let x: Vec<f64> = (0..100).map(|i| 0.5 + 2.0 * i as f64 * 0.001).collect();
        let (level, slope) = local_line(&x, 0.001, 10);
        for k in 1..99 {
            assert!((level[k] - x[k]).abs() < 1e-12);
            assert!((slope[k] - 2.0).abs() < 1e-9);
        }
    }
}
