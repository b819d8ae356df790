//! The nonlinear rotator, integrated with a fixed step.
//!
//! State: spool position and rate (eq. 10), chamber pressures (eq. 8 with
//! the linearized flow of eq. 9, or orifice flow), actuator angle and
//! velocity (eq. 5), and, with `load_flexibility`, the load's angle and
//! velocity. Classic RK4 per step; the friction discontinuity is handled
//! outside the RK4 stages by an explicit stick/slip state, so the velocity
//! is exactly zero while stuck and never flickers in sign. A fit may ask
//! for the exact step where the rotator is linear by pieces instead
//! ([`Plant::stepping_exactly_where_linear`]).

use nalgebra::{SMatrix, SVector};

use crate::effects::{Deadzone, Effects};
use crate::hydraulics;
use crate::mechanics::{self, Motion};
use crate::{PlantError, PlantParams};

pub(crate) const STATES: usize = 8;
pub(crate) const SPOOL: usize = 0;
pub(crate) const SPOOL_RATE: usize = 1;
pub(crate) const P_A: usize = 2;
pub(crate) const P_B: usize = 3;
pub(crate) const ANGLE: usize = 4;
pub(crate) const VELOCITY: usize = 5;
pub(crate) const LOAD_ANGLE: usize = 6;
pub(crate) const LOAD_VELOCITY: usize = 7;
/// The state, the held input and a constant 1: the exact step's generator.
const AUGMENTED: usize = STATES + 2;

/// The plant's true state, SI units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantState {
    /// Spool position, command units (1 = fully open).
    pub spool: f64,
    pub spool_rate: f64,
    /// Chamber pressures, Pa.
    pub p_a: f64,
    pub p_b: f64,
    /// Actuator angle, rad, and velocity, rad/s.
    pub angle: f64,
    pub velocity: f64,
    /// Load angle and velocity; equal to the actuator's unless the load is flexible.
    pub load_angle: f64,
    pub load_velocity: f64,
    /// True while Coulomb friction holds the actuator still.
    pub stuck: bool,
}

impl PlantState {
    pub(crate) fn to_array(self) -> [f64; STATES] {
        [
            self.spool,
            self.spool_rate,
            self.p_a,
            self.p_b,
            self.angle,
            self.velocity,
            self.load_angle,
            self.load_velocity,
        ]
    }

    pub(crate) fn from_array(x: [f64; STATES], stuck: bool) -> Self {
        Self {
            spool: x[SPOOL],
            spool_rate: x[SPOOL_RATE],
            p_a: x[P_A],
            p_b: x[P_B],
            angle: x[ANGLE],
            velocity: x[VELOCITY],
            load_angle: x[LOAD_ANGLE],
            load_velocity: x[LOAD_VELOCITY],
            stuck,
        }
    }
}

/// A delay line at the integration step's resolution, allocated once.
#[derive(Debug, Clone)]
struct DelayLine {
    buffer: Vec<f64>,
    head: usize,
}

impl DelayLine {
    fn new(steps: usize) -> Self {
        Self {
            buffer: vec![0.0; steps.max(1)],
            head: 0,
        }
    }

    /// Pushes `input` and returns the value pushed `steps` calls ago.
    fn push(&mut self, input: f64) -> f64 {
        let out = self.buffer[self.head];
        self.buffer[self.head] = input;
        self.head = (self.head + 1) % self.buffer.len();
        out
    }

    fn fill(&mut self, value: f64) {
        self.buffer.iter_mut().for_each(|v| *v = value);
    }
}

/// One integration step of the whole rotator where it is linear, or
/// linear by pieces: the valve's dead-zone and asymmetric gain make the
/// flow affine in the spool on each side of the dead band and inside it;
/// a spool clear of its travel limit does not feel the limit. With the
/// linearized flow, no Coulomb friction and no gravity, and the pressures
/// inside tank and supply, the state's rate is then affine in the state
/// and the held input on each piece, and a step that stays on one piece
/// is x ← Φ x + Γ u + γ, from the exponential of a generator built from
/// [`Plant::derivative`] itself: the physics stays defined in one place.
#[derive(Debug, Clone)]
struct ExactStep {
    /// Below the dead band (or a closing spool), inside it, above it.
    pieces: [Option<AffineStep>; 3],
    /// The dead band (of width 0 for an asymmetric gain alone, whose
    /// pieces are the spool's signs); `None` where one affine step holds
    /// for every spool.
    band: Option<Deadzone>,
    travel_limit: Option<f64>,
}

#[derive(Debug, Clone)]
struct AffineStep {
    transition: SMatrix<f64, STATES, STATES>,
    from_input: SVector<f64, STATES>,
    constant: SVector<f64, STATES>,
}

impl AffineStep {
    /// The step of `plant`'s rates about `reference`, which must lie on
    /// the piece, moving the spool by `spool_delta` within it.
    fn about(plant: &Plant, mut reference: [f64; STATES], spool_delta: f64) -> Option<Self> {
        let p = &plant.params;
        let neutral = plant.neutral_pressure();
        // Columns by differences about a state inside the pressures'
        // bounds, where no rate is held at tank or supply: exact for an
        // affine map, whatever the perturbation's size.
        let room = (neutral - p.tank_pressure).min(p.supply_pressure - neutral);
        if room.is_nan() || room <= 0.0 {
            return None;
        }
        reference[P_A] = neutral;
        reference[P_B] = neutral;
        // z = [state, command, 1].
        let rates = |z: &SVector<f64, AUGMENTED>| {
            let mut state = [0.0; STATES];
            state.copy_from_slice(&z.as_slice()[..STATES]);
            let mut rate = SVector::<f64, AUGMENTED>::zeros();
            rate.fixed_rows_mut::<STATES>(0)
                .copy_from_slice(&plant.derivative(&state, z[STATES], 0.0));
            rate
        };
        let mut augmented = SVector::<f64, AUGMENTED>::zeros();
        augmented.fixed_rows_mut::<STATES>(0).copy_from_slice(&reference);
        augmented[AUGMENTED - 1] = 1.0;
        let delta = |i: usize| match i {
            P_A | P_B => 0.1 * room,
            SPOOL => spool_delta,
            _ => 1.0,
        };
        let exact = crate::affine_step(rates, augmented, delta, plant.step);
        let step = Self {
            transition: exact.fixed_view::<STATES, STATES>(0, 0).into_owned(),
            from_input: exact.fixed_view::<STATES, 1>(0, STATES).into_owned(),
            constant: exact.fixed_view::<STATES, 1>(0, STATES + 1).into_owned(),
        };
        step.transition.iter().all(|v| v.is_finite()).then_some(step)
    }

    #[inline]
    fn apply(&self, state: &[f64; STATES], input: f64) -> [f64; STATES] {
        (self.transition * SVector::<f64, STATES>::from(*state) + self.from_input * input + self.constant).into()
    }
}

impl ExactStep {
    /// `None` where the rotator is not linear by pieces.
    fn new(plant: &Plant) -> Option<Self> {
        let e = &plant.effects;
        if e.orifice_flow.is_some() || e.coulomb_friction.is_some() || e.gravity_load.is_some() {
            return None;
        }
        // Clear of its limit the spool moves as if it had none.
        let mut free = plant.clone();
        free.effects.saturation = None;
        let band = e.valve_band();
        let at = |spool: f64| {
            let mut reference = [0.0; STATES];
            reference[SPOOL] = spool;
            reference
        };
        let pieces = crate::effects::valve_piece_probes(band)
            .map(|probe| probe.and_then(|(spool, delta)| AffineStep::about(&free, at(spool), delta)));
        // Without a band the one piece is the whole map: it must exist.
        if band.is_none() && pieces[1].is_none() {
            return None;
        }
        Some(Self {
            pieces,
            band,
            travel_limit: e.saturation.map(|s| s.limit),
        })
    }

    /// The piece the spool is on: 0 below the dead band, 1 inside (or
    /// everywhere, without pieces), 2 above.
    #[inline]
    fn piece(&self, spool: f64) -> usize {
        crate::effects::valve_piece(self.band, spool)
    }

    /// The state one step on, or `None` where the step starts or ends with
    /// a pressure at a bound or the spool at its limit, or leaves its
    /// piece: there the rotator is not linear.
    #[inline]
    fn step(&self, params: &PlantParams, state: &[f64; STATES], input: f64) -> Option<[f64; STATES]> {
        let linear_at = |x: &[f64; STATES]| {
            [x[P_A], x[P_B]]
                .iter()
                .all(|&p| p > params.tank_pressure && p < params.supply_pressure)
                && self.travel_limit.is_none_or(|limit| x[SPOOL].abs() < limit)
        };
        if !linear_at(state) {
            return None;
        }
        let piece = self.piece(state[SPOOL]);
        let next = self.pieces[piece].as_ref()?.apply(state, input);
        (linear_at(&next) && self.piece(next[SPOOL]) == piece).then_some(next)
    }
}

/// The simulated rotator.
#[derive(Debug, Clone)]
pub struct Plant {
    params: PlantParams,
    effects: Effects,
    step: f64,
    state: [f64; STATES],
    stuck: bool,
    delay: Option<DelayLine>,
    time: f64,
    exact: Option<ExactStep>,
}

impl Plant {
    /// A plant at rest with pressures at their neutral equilibrium.
    /// `step` is the fixed integration step, s (1e-4 for 10 kHz).
    pub fn new(params: PlantParams, effects: Effects, step: f64) -> Result<Self, PlantError> {
        params.validate()?;
        if !(step.is_finite() && step > 0.0) {
            return Err(PlantError::invalid("integration step", step, "must be positive"));
        }
        let delay = effects
            .time_delay
            .filter(|d| d.delay_s > 0.0)
            .map(|d| DelayLine::new((d.delay_s / step).round() as usize));
        let mut plant = Self {
            params,
            effects,
            step,
            state: [0.0; STATES],
            stuck: false,
            delay,
            time: 0.0,
            exact: None,
        };
        plant.reset_to(PlantState {
            spool: 0.0,
            spool_rate: 0.0,
            p_a: plant.neutral_pressure(),
            p_b: plant.neutral_pressure(),
            angle: 0.0,
            velocity: 0.0,
            load_angle: 0.0,
            load_velocity: 0.0,
            stuck: false,
        });
        Ok(plant)
    }

    /// Steps exactly where the rotator is linear by pieces (`ExactStep`)
    /// and by RK4 elsewhere: for a fit, which simulates the model thousands of times,
    /// one matrix product a step in place of four evaluations of the
    /// rates. A step that starts or ends with a pressure at a bound or the
    /// spool at its limit, or that crosses a dead band's edge, is taken by
    /// RK4. The simulator keeps RK4 throughout.
    pub fn stepping_exactly_where_linear(mut self) -> Self {
        self.exact = ExactStep::new(&self);
        self
    }

    /// Puts the plant in a given state, for a fallback that starts from the
    /// last measured state. The delay line is filled with neutral commands.
    pub fn reset_to(&mut self, state: PlantState) {
        self.restart_from(state);
        if let Some(delay) = &mut self.delay {
            delay.fill(0.0);
        }
    }

    /// Puts the plant in a given state and keeps the commands on their way
    /// through the delay: for multiple shooting, where each segment starts
    /// from a state estimated afresh while the valve's input runs on.
    pub fn restart_from(&mut self, state: PlantState) {
        self.state = state.to_array();
        if self.effects.load_flexibility.is_none() {
            self.state[LOAD_ANGLE] = self.state[ANGLE];
            self.state[LOAD_VELOCITY] = self.state[VELOCITY];
        }
        self.stuck = state.stuck && self.effects.coulomb_friction.is_some();
    }

    /// Chamber pressure with the spool centred and the actuator still:
    /// `K_c p_s / (C_em + 2 K_c)` from eqs. (8)–(9), for the linearized flow.
    pub fn neutral_pressure(&self) -> f64 {
        let p = &self.params;
        let denominator = p.leakage + 2.0 * p.flow_pressure_coefficient;
        if denominator > 0.0 {
            (p.flow_pressure_coefficient * p.supply_pressure / denominator).clamp(p.tank_pressure, p.supply_pressure)
        } else {
            0.5 * p.supply_pressure
        }
    }

    pub fn params(&self) -> &PlantParams {
        &self.params
    }

    pub fn effects(&self) -> &Effects {
        &self.effects
    }

    /// The machine changes while it runs ([`crate::Drift`]): its effects'
    /// parameters, never its structure (the delay line stays as made).
    pub fn drift_to(&mut self, effects: &Effects) {
        debug_assert_eq!(effects.time_delay, self.effects.time_delay);
        self.effects = *effects;
    }

    pub fn integration_step(&self) -> f64 {
        self.step
    }

    pub fn time(&self) -> f64 {
        self.time
    }

    pub fn state(&self) -> PlantState {
        PlantState::from_array(self.state, self.stuck)
    }

    /// Hydraulic torque D (p_a − p_b), N·m (eq. 7).
    pub fn torque(&self) -> f64 {
        self.params.displacement * (self.state[P_A] - self.state[P_B])
    }

    /// Advances `steps` integration steps with the valve command held
    /// (zero-order hold, as a valve driver holds its current). The command
    /// is the valve amplifier's input in [-1, 1]; a non-finite command is
    /// taken as neutral.
    pub fn advance(&mut self, command: f64, steps: usize) {
        let command = if command.is_finite() {
            command.clamp(-1.0, 1.0)
        } else {
            0.0
        };
        for _ in 0..steps {
            let input = match &mut self.delay {
                Some(delay) => delay.push(command),
                None => command,
            };
            self.integrate_one_step(input);
        }
    }

    fn integrate_one_step(&mut self, input: f64) {
        let h = self.step;
        if let Some(mut next) = self
            .exact
            .as_ref()
            .and_then(|e| e.step(&self.params, &self.state, input))
        {
            if self.effects.load_flexibility.is_none() {
                next[LOAD_ANGLE] = next[ANGLE];
                next[LOAD_VELOCITY] = next[VELOCITY];
            }
            self.state = next;
            self.time += h;
            return;
        }
        let (direction, stuck) = mechanics::friction_direction(
            &self.params,
            &self.effects,
            &motion_of(&self.state),
            self.torque(),
            self.stuck,
        );
        self.stuck = stuck;
        let x = self.state;
        let k1 = self.derivative(&x, input, direction);
        let k2 = self.derivative(&add_scaled(&x, &k1, 0.5 * h), input, direction);
        let k3 = self.derivative(&add_scaled(&x, &k2, 0.5 * h), input, direction);
        let k4 = self.derivative(&add_scaled(&x, &k3, h), input, direction);
        let mut next = x;
        for i in 0..STATES {
            next[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
        self.enforce_bounds(&mut next);
        let mut motion = motion_of(&next);
        let torque = self.params.displacement * (next[P_A] - next[P_B]);
        self.stuck = mechanics::settle_friction(
            &self.params,
            &self.effects,
            &motion_of(&x),
            &mut motion,
            torque,
            self.stuck,
            direction,
        );
        next[ANGLE..=LOAD_VELOCITY].copy_from_slice(&motion);
        self.state = next;
        self.time += h;
    }

    /// The state's time derivative for spool input `input`; `direction` is
    /// the friction direction frozen for the step (0 when stuck).
    pub(crate) fn derivative(&self, x: &[f64; STATES], input: f64, direction: f64) -> [f64; STATES] {
        let p = &self.params;
        let mut dx = [0.0; STATES];

        (dx[SPOOL], dx[SPOOL_RATE]) = hydraulics::spool_rates(p, &self.effects, x[SPOOL], x[SPOOL_RATE], input);
        (dx[P_A], dx[P_B]) = hydraulics::pressure_rates(p, &self.effects, x[SPOOL], x[P_A], x[P_B], x[VELOCITY]);

        let torque = p.displacement * (x[P_A] - x[P_B]);
        let motion = mechanics::motion_rates(p, &self.effects, &motion_of(x), torque, direction);
        dx[ANGLE..=LOAD_VELOCITY].copy_from_slice(&motion);
        dx
    }

    fn enforce_bounds(&self, x: &mut [f64; STATES]) {
        x[P_A] = hydraulics::bound_pressure(&self.params, x[P_A]);
        x[P_B] = hydraulics::bound_pressure(&self.params, x[P_B]);
        let (mut spool, mut rate) = (x[SPOOL], x[SPOOL_RATE]);
        hydraulics::limit_spool(&self.effects, &mut spool, &mut rate);
        (x[SPOOL], x[SPOOL_RATE]) = (spool, rate);
    }
}

fn motion_of(x: &[f64; STATES]) -> Motion {
    [x[ANGLE], x[VELOCITY], x[LOAD_ANGLE], x[LOAD_VELOCITY]]
}

fn add_scaled(x: &[f64; STATES], k: &[f64; STATES], h: f64) -> [f64; STATES] {
    let mut out = *x;
    for i in 0..STATES {
        out[i] += h * k[i];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::{AsymmetricGain, CoulombFriction, LoadFlexibility, Saturation};

    /// The command a test drives with: a sine and a step, inside the
    /// pressures' bounds.
    fn command(t: f64) -> f64 {
        0.3 * (2.0 * std::f64::consts::PI * 1.5 * t).sin() + if t > 0.8 { 0.15 } else { 0.0 }
    }

    /// `seconds` of `command`, held for each `hold` s, by `plant`
    /// integrating `substeps` steps per hold.
    fn driven(mut plant: Plant, hold: f64, substeps: usize, seconds: f64) -> PlantState {
        for k in 0..(seconds / hold).round() as usize {
            plant.advance(command(k as f64 * hold), substeps);
        }
        plant.state()
    }

    /// Each state's distance from the reference, in its own scale.
    fn errors(a: &PlantState, reference: &PlantState, params: &PlantParams) -> [f64; 5] {
        [
            (a.angle - reference.angle).abs(),
            (a.velocity - reference.velocity).abs(),
            (a.p_a - reference.p_a).abs() / params.supply_pressure,
            (a.p_b - reference.p_b).abs() / params.supply_pressure,
            (a.spool - reference.spool).abs(),
        ]
    }

    #[test]
    fn the_exact_step_is_as_close_to_the_rotator_as_rk4_on_fine_steps_where_it_is_linear_by_pieces() {
        let params = PlantParams::default();
        let cases = [
            ("none", Effects::none()),
            (
                "flexible load",
                Effects {
                    load_flexibility: Some(LoadFlexibility {
                        load_fraction: 0.5,
                        stiffness: 5.0e4,
                        damping: 200.0,
                    }),
                    ..Effects::none()
                },
            ),
            (
                "dead-zone",
                Effects {
                    deadzone: Some(Deadzone {
                        offset: 0.02,
                        width: 0.05,
                    }),
                    ..Effects::none()
                },
            ),
            (
                "asymmetric gain",
                Effects {
                    asymmetric_gain: Some(AsymmetricGain { ratio: 0.7 }),
                    ..Effects::none()
                },
            ),
            (
                "saturation",
                Effects {
                    saturation: Some(Saturation { limit: 0.35 }),
                    ..Effects::none()
                },
            ),
        ];
        let hold = 1e-3;
        for (name, effects) in cases {
            let exact = Plant::new(params, effects, hold)
                .expect("plant")
                .stepping_exactly_where_linear();
            assert!(exact.exact.is_some(), "{name} is linear by pieces");
            let reference = driven(
                Plant::new(params, effects, hold / 200.0).expect("plant"),
                hold,
                200,
                2.0,
            );
            let rk4 = driven(Plant::new(params, effects, hold).expect("plant"), hold, 1, 2.0);
            let (by_exact, by_rk4) = (
                errors(&driven(exact, hold, 1, 2.0), &reference, &params),
                errors(&rk4, &reference, &params),
            );
            for (e, r) in by_exact.iter().zip(by_rk4) {
                assert!(*e <= 1e-9 + 1.5 * r, "{name}: {by_exact:?} against RK4's {by_rk4:?}");
            }
        }
    }

    #[test]
    fn a_rotator_that_is_not_linear_keeps_rk4() {
        let params = PlantParams::default();
        let friction = Effects {
            coulomb_friction: Some(CoulombFriction {
                coulomb: 60.0,
                breakaway: 90.0,
                stribeck_velocity: 0.05,
            }),
            ..Effects::none()
        };
        let exact = Plant::new(params, friction, 1e-3)
            .expect("plant")
            .stepping_exactly_where_linear();
        assert!(exact.exact.is_none());
        let plain = Plant::new(params, friction, 1e-3).expect("plant");
        assert_eq!(driven(exact, 1e-3, 1, 1.0), driven(plain, 1e-3, 1, 1.0));
    }

    #[test]
    fn a_step_to_a_pressure_bound_is_taken_by_rk4() {
        let params = PlantParams::default();
        let hold = 1e-3;
        let mut exact = Plant::new(params, Effects::none(), hold)
            .expect("plant")
            .stepping_exactly_where_linear();
        let mut plain = Plant::new(params, Effects::none(), hold).expect("plant");
        // Fully open, chamber A half a bar under supply and compressed by
        // the actuator turning back: it reaches supply at once.
        let start = PlantState {
            spool: 1.0,
            spool_rate: 0.0,
            p_a: params.supply_pressure - 0.5e5,
            p_b: 0.5 * params.supply_pressure,
            angle: 0.0,
            velocity: -2.0,
            load_angle: 0.0,
            load_velocity: -2.0,
            stuck: false,
        };
        exact.restart_from(start);
        plain.restart_from(start);
        let mut at_bound = false;
        for _ in 0..200 {
            exact.advance(1.0, 1);
            plain.advance(1.0, 1);
            let s = exact.state();
            assert!(s.p_a <= params.supply_pressure && s.p_b >= params.tank_pressure);
            at_bound |= s.p_a == params.supply_pressure || s.p_b == params.tank_pressure;
        }
        assert!(at_bound, "the test reaches a bound");
        let (a, b) = (exact.state(), plain.state());
        assert!((a.velocity - b.velocity).abs() <= 1e-3 * b.velocity.abs().max(1.0));
    }
}
