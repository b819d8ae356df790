//! The hydraulic part's prediction: the valve's command, delayed as the
//! effects say, through the chambers' pressures, by RK4 steps or their
//! linear equivalent.

use super::*;

/// The valve input after the `time_delay` effect: the command `delay_s`
/// earlier, interpolated between samples so that the delay is continuous.
// Inlined: it runs for every sample of every prediction, and as a call
// it costs 2 % of a diagnosis's instructions (callgrind).
#[inline]
pub(super) fn delayed_command(signals: &Signals, effects: &Effects, k: usize) -> f64 {
    let Some(delay) = effects.time_delay else {
        return signals.u[k];
    };
    let shift = delay.delay_s / signals.dt;
    let whole = shift.floor();
    let fraction = shift - whole;
    // Across readings left out the command is not known: the stretch's
    // first stands in, as zero does before the record.
    let first = if signals.breaks.is_empty() {
        0
    } else {
        signals.stretch_start(k)
    };
    let at = |back: f64| {
        let index = k as f64 - back;
        if index < 0.0 {
            0.0
        } else {
            signals.u[(index as usize).max(first)]
        }
    };
    (1.0 - fraction) * at(whole) + fraction * at(whole + 1.0)
}

/// The spool after readings left out: at rest where the command holds it.
pub(super) fn settled_spool(signals: &Signals, effects: &Effects, k: usize) -> [f64; 2] {
    let (mut spool, mut rate) = (delayed_command(signals, effects, k), 0.0);
    hydraulics::limit_spool(effects, &mut spool, &mut rate);
    [spool, rate]
}

/// Command and measured motion → pressures, segment by segment, each
/// segment starting from the measured pressures; the spool runs unbroken
/// from the start of the record, settled on the command after readings
/// left out.
pub(super) fn predict_hydraulic(
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
    out: &mut Prediction,
) {
    let segment_starts: Vec<usize> = segments(signals, range.clone()).map(|s| s.start).collect();
    predict_hydraulic_from(plant, effects, signals, range, &segment_starts, out);
}

/// [`predict_hydraulic`] with the pressures taken from the measurement at
/// `segment_starts` (ascending, each stretch's first within `range` among
/// them): segments placed where a test wants them.
pub(crate) fn predict_hydraulic_from(
    plant: &PlantParams,
    effects: &Effects,
    signals: &Signals,
    range: Range<usize>,
    segment_starts: &[usize],
    out: &mut Prediction,
) {
    let h = signals.dt;
    let exact = HydraulicSteps::new(plant, effects, h);
    let travel_limit = effects.saturation.map(|s| s.limit);
    let inside = |p: f64| p > plant.tank_pressure && p < plant.supply_pressure;
    let free = |spool: f64| travel_limit.is_none_or(|limit| spool.abs() < limit);
    let mut spool = [0.0_f64; 2];
    let mut pressures = [signals.p_a[0], signals.p_b[0]];
    let mut next_start = 0;
    let play = effects.backlash.map_or(0.0, |b| b.width);
    let actuator_velocity = |k: usize| signals.velocity[k] + play * signals.play_crossing[k];
    for k in 0..range.end {
        if next_start < segment_starts.len() && k == segment_starts[next_start] {
            pressures = [signals.p_a[k], signals.p_b[k]];
            next_start += 1;
            if signals.breaks.binary_search(&k).is_ok() {
                spool = settled_spool(signals, effects, k);
            }
        }
        if k >= range.start {
            out.p_a[k] = pressures[0];
            out.p_b[k] = pressures[1];
        }
        if k + 1 >= range.end {
            break;
        }
        let input = delayed_command(signals, effects, k);
        let (v0, v1) = (actuator_velocity(k), actuator_velocity(k + 1));
        // Before the range only the spool matters.
        let in_segment = k + 1 >= range.start;
        let x = [spool[0], spool[1], pressures[0], pressures[1]];
        // Exactly where the valve and chambers are linear: the spool clear
        // of its stops and the pressures clear of tank and supply, at the
        // step's start and end.
        if let Some(steps) = exact.as_ref().filter(|_| free(x[0])) {
            if !in_segment {
                let next = steps.spool(&x, input);
                if free(next[0]) {
                    spool = next;
                    continue;
                }
            } else if inside(x[2]) && inside(x[3]) {
                let piece = steps.piece(x[0]);
                if let Some(step) = &steps.pieces[piece] {
                    let next = step.apply(&x, input, v0, v1);
                    if free(next[0]) && inside(next[2]) && inside(next[3]) && steps.piece(next[0]) == piece {
                        spool = [next[0], next[1]];
                        pressures = [next[2], next[3]];
                        continue;
                    }
                }
            }
        }
        // RK4 over one sample, the command held and the velocity linear.
        let rates = |x: &[f64; 4], velocity: f64| -> [f64; 4] {
            let (ds, dr) = hydraulics::spool_rates(plant, effects, x[0], x[1], input);
            let (da, db) = if in_segment {
                hydraulics::pressure_rates(plant, effects, x[0], x[2], x[3], velocity)
            } else {
                (0.0, 0.0)
            };
            [ds, dr, da, db]
        };
        let vm = 0.5 * (v0 + v1);
        let k1 = rates(&x, v0);
        let k2 = rates(&add(&x, &k1, 0.5 * h), vm);
        let k3 = rates(&add(&x, &k2, 0.5 * h), vm);
        let k4 = rates(&add(&x, &k3, h), v1);
        let mut next = x;
        for i in 0..4 {
            next[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
        let (mut s, mut r) = (next[0], next[1]);
        hydraulics::limit_spool(effects, &mut s, &mut r);
        spool = [s, r];
        pressures = [
            hydraulics::bound_pressure(plant, next[2]),
            hydraulics::bound_pressure(plant, next[3]),
        ];
    }
}

/// The valve and chambers over one sample where they are linear by
/// pieces, exactly: the spool driven by the held command, the pressures by
/// the spool and by a velocity that moves linearly over the sample (as the
/// RK4 step takes it). Without orifice flow the rates are affine in the
/// state, the command and the velocity on each side of the valve's dead
/// band and inside it (an asymmetric gain's pieces are the opening's
/// signs); a step that stays on one piece is the exponential of a
/// generator whose columns are differences of [`hydraulics::spool_rates`]
/// and [`hydraulics::pressure_rates`], so the physics stays defined in one
/// place. A spool at its stop, a pressure at tank or supply or a step that
/// changes piece is not linear: the caller steps those by RK4.
pub(super) struct HydraulicSteps {
    /// Below the dead band, inside it (or everywhere, without one), above.
    pub(super) pieces: [Option<LinearHydraulicStep>; 3],
    pub(super) band: Option<hydractl_plant::effects::Deadzone>,
}

impl HydraulicSteps {
    /// `None` where the valve and chambers are not linear by pieces.
    pub(super) fn new(plant: &PlantParams, effects: &Effects, h: f64) -> Option<Self> {
        if effects.orifice_flow.is_some() {
            return None;
        }
        // Clear of its stops the spool moves as if it had none.
        let mut free = *effects;
        free.saturation = None;
        let band = effects.valve_band();
        let pieces = hydractl_plant::effects::valve_piece_probes(band)
            .map(|probe| probe.and_then(|(spool, delta)| LinearHydraulicStep::about(plant, &free, spool, delta, h)));
        pieces.iter().any(Option::is_some).then_some(Self { pieces, band })
    }

    /// The piece the spool is on: 0 below the dead band, 1 inside (or
    /// everywhere, without one), 2 above.
    #[inline]
    pub(super) fn piece(&self, spool: f64) -> usize {
        hydractl_plant::effects::valve_piece(self.band, spool)
    }

    /// The spool alone one sample on (the pressures not yet simulated):
    /// the same on every piece, since the flows do not act on it.
    #[inline]
    pub(super) fn spool(&self, x: &[f64; 4], input: f64) -> [f64; 2] {
        let step = self.pieces.iter().flatten().next();
        step.map_or([x[0], x[1]], |step| step.spool(x, input))
    }
}

pub(super) struct LinearHydraulicStep {
    pub(super) transition: nalgebra::Matrix4<f64>,
    pub(super) from_input: nalgebra::Vector4<f64>,
    pub(super) from_velocity: nalgebra::Vector4<f64>,
    /// Per unit of the velocity's change over the sample.
    pub(super) from_velocity_change: nalgebra::Vector4<f64>,
    pub(super) constant: nalgebra::Vector4<f64>,
}

impl LinearHydraulicStep {
    /// The step of the rates about a spool at `spool`, which must lie on
    /// the piece, moving it by `spool_delta` within the piece; the
    /// pressures about mid-way between tank and supply, where no rate is
    /// held.
    pub(super) fn about(plant: &PlantParams, effects: &Effects, spool: f64, spool_delta: f64, h: f64) -> Option<Self> {
        let neutral = 0.5 * (plant.tank_pressure + plant.supply_pressure);
        let room = 0.5 * (plant.supply_pressure - plant.tank_pressure);
        if !room.is_finite() || room <= 0.0 || !spool_delta.is_finite() || spool_delta == 0.0 {
            return None;
        }
        // z = [spool, spool rate, p_a, p_b, velocity, its slope, command, 1].
        let rates = |z: &nalgebra::SVector<f64, 8>| -> nalgebra::SVector<f64, 8> {
            let (ds, dr) = hydraulics::spool_rates(plant, effects, z[0], z[1], z[6]);
            let (da, db) = hydraulics::pressure_rates(plant, effects, z[0], z[2], z[3], z[4]);
            nalgebra::SVector::<f64, 8>::from([ds, dr, da, db, z[5], 0.0, 0.0, 0.0])
        };
        let reference = nalgebra::SVector::<f64, 8>::from([spool, 0.0, neutral, neutral, 0.0, 0.0, 0.0, 1.0]);
        let delta = |i: usize| match i {
            0 => spool_delta,
            2 | 3 => 0.1 * room,
            _ => 1.0,
        };
        let exact = hydractl_plant::affine_step(rates, reference, delta, h);
        let step = Self {
            transition: exact.fixed_view::<4, 4>(0, 0).into_owned(),
            from_velocity: exact.fixed_view::<4, 1>(0, 4).into_owned(),
            from_velocity_change: exact.fixed_view::<4, 1>(0, 5).into_owned() / h,
            from_input: exact.fixed_view::<4, 1>(0, 6).into_owned(),
            constant: exact.fixed_view::<4, 1>(0, 7).into_owned(),
        };
        (step.transition.iter().all(|v| v.is_finite()) && step.constant.iter().all(|v| v.is_finite())).then_some(step)
    }

    /// The state one sample on, from `v0` to `v1` linearly.
    #[inline]
    pub(super) fn apply(&self, x: &[f64; 4], input: f64, v0: f64, v1: f64) -> [f64; 4] {
        (self.transition * nalgebra::Vector4::from(*x)
            + self.from_input * input
            + self.from_velocity * v0
            + self.from_velocity_change * (v1 - v0)
            + self.constant)
            .into()
    }

    /// The spool alone one sample on (the pressures not yet simulated).
    #[inline]
    pub(super) fn spool(&self, x: &[f64; 4], input: f64) -> [f64; 2] {
        let t = &self.transition;
        [
            t[(0, 0)] * x[0] + t[(0, 1)] * x[1] + self.from_input[0] * input + self.constant[0],
            t[(1, 0)] * x[0] + t[(1, 1)] * x[1] + self.from_input[1] * input + self.constant[1],
        ]
    }
}

pub(super) fn add<const N: usize>(x: &[f64; N], k: &[f64; N], h: f64) -> [f64; N] {
    let mut out = *x;
    for i in 0..N {
        out[i] += h * k[i];
    }
    out
}
