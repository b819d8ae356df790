//! The nonlinear rotator, integrated with a fixed step.
//!
//! State: spool position and rate (eq. 10), chamber pressures (eq. 8 with
//! the linearized flow of eq. 9, or orifice flow), actuator angle and
//! velocity (eq. 5), and, with `load_flexibility`, the load's angle and
//! velocity. Classic RK4 per step; the friction discontinuity is handled
//! outside the RK4 stages by an explicit stick/slip state, so the velocity
//! is exactly zero while stuck and never flickers in sign.

use crate::effects::Effects;
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
