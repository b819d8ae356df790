//! The control stack's five stages, each the algorithm one live process
//! will run: sensor → friction → position → torque → valve. The offline
//! simulator calls them in sequence; the processes will wire the same
//! objects to shared memory, which is why each stage takes plain values and
//! keeps its own state.

use hydractl_control::{
    ControlError, FrictionCompensator, HInfinity, LimitCycleDetector, LimitCycleParams, Mfc, Pid, Reference,
    Trajectory, ValveShaper, VelocityEstimator,
};
use hydractl_plant::RawReading;

use crate::config::{Config, PositionVariant, Structure, TorqueVariant};

#[derive(Debug, thiserror::Error)]
pub enum StackError {
    #[error("[{section}] {source}")]
    Control {
        section: &'static str,
        source: ControlError,
    },
}

fn in_section(section: &'static str) -> impl Fn(ControlError) -> StackError {
    move |source| StackError::Control { section, source }
}

/// What the sensor stage publishes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SensorEstimate {
    pub angle: f64,
    pub velocity: f64,
    /// Pa.
    pub p_a: f64,
    pub p_b: f64,
    /// D (p_a − p_b), N·m.
    pub torque: f64,
}

/// Sensor stage: raw readings to the published estimate.
#[derive(Debug, Clone)]
pub struct SensorStage {
    velocity: VelocityEstimator,
    displacement: f64,
}

impl SensorStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Ok(Self {
            velocity: VelocityEstimator::new(config.control.velocity_estimator, config.timing.control_period())
                .map_err(in_section("control.velocity_estimator"))?,
            displacement: config.plant.displacement,
        })
    }

    pub fn process(&mut self, raw: &RawReading) -> SensorEstimate {
        SensorEstimate {
            angle: raw.angle,
            velocity: self.velocity.update(raw.angle),
            p_a: raw.p_a,
            p_b: raw.p_b,
            torque: self.displacement * (raw.p_a - raw.p_b),
        }
    }
}

/// Friction stage: the crane paper's eq. (1) on the previous period's
/// reference velocity and valve command (both are one period old in the
/// live pipeline too, since friction runs before position and valve).
#[derive(Debug, Clone)]
pub struct FrictionStage {
    compensator: FrictionCompensator,
}

impl FrictionStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        let outer = config.control.outer();
        Ok(Self {
            compensator: FrictionCompensator::new(outer.friction.clone())
                .map_err(in_section(outer_section(config, "friction")))?,
        })
    }

    pub fn process(&mut self, sensor: &SensorEstimate, reference_velocity: f64, valve_command: f64) -> f64 {
        self.compensator
            .update(sensor.velocity, reference_velocity, valve_command)
    }

    /// The blended velocity of eq. (1) behind the last compensation.
    pub fn blended_velocity(&self) -> f64 {
        self.compensator.blended_velocity()
    }
}

fn outer_section(config: &Config, part: &'static str) -> &'static str {
    match (config.control.structure, part) {
        (Structure::Position, "friction") => "control.position_only.friction",
        (Structure::Position, "pid") => "control.position_only.pid",
        (Structure::Position, _) => "control.position_only.mfc",
        (Structure::Cascade, "friction") => "control.cascade.friction",
        (Structure::Cascade, "pid") => "control.cascade.pid",
        (Structure::Cascade, _) => "control.cascade.mfc",
    }
}

/// The outer loop's variants.
#[derive(Debug, Clone)]
// One lives per stage and is never moved on the hot path; boxing would only
// add an indirection.
#[allow(clippy::large_enum_variant)]
pub enum OuterLoop {
    Pid(Pid),
    Mfc(Mfc),
}

/// What the position stage publishes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PositionOutput {
    pub reference: Reference,
    /// Valve command (position-only) or torque reference, N·m (cascade).
    pub output: f64,
}

/// Position stage: reference trajectory and outer loop.
#[derive(Debug, Clone)]
pub struct PositionStage {
    structure: Structure,
    variant: PositionVariant,
    trajectory: Trajectory,
    outer: OuterLoop,
    mfc_model: Option<(f64, f64)>,
    started: bool,
}

impl PositionStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Self::with_variant(config, config.control.outer().variant)
    }

    pub fn with_variant(config: &Config, variant: PositionVariant) -> Result<Self, StackError> {
        let outer = config.control.outer();
        let ts = config.timing.control_period();
        let outer = match variant {
            PositionVariant::Pid => {
                OuterLoop::Pid(Pid::new(outer.pid, ts).map_err(in_section(outer_section(config, "pid")))?)
            }
            PositionVariant::Mfc => {
                OuterLoop::Mfc(Mfc::new(outer.mfc, ts).map_err(in_section(outer_section(config, "mfc")))?)
            }
        };
        let mfc = &config.control.outer().mfc;
        Ok(Self {
            structure: config.control.structure,
            variant,
            trajectory: config.trajectory.clone(),
            outer,
            mfc_model: Some((mfc.j_hat, mfc.b_hat)),
            started: false,
        })
    }

    pub fn variant(&self) -> PositionVariant {
        self.variant
    }

    pub fn structure(&self) -> Structure {
        self.structure
    }

    /// One period. The friction compensation (a valve command) joins this
    /// loop's output only when this loop drives the valve (position-only);
    /// in the cascade the torque stage adds it.
    pub fn process(&mut self, time: f64, sensor: &SensorEstimate, friction: f64) -> PositionOutput {
        let friction = match self.structure {
            Structure::Position => friction,
            Structure::Cascade => 0.0,
        };
        let reference = self.trajectory.sample(time);
        let error = reference.angle - sensor.angle;
        if !self.started {
            self.started = true;
            // Start where the machine is, not at zero: a stage restarted
            // mid-run would otherwise begin with its model a whole motion
            // away. The output starts at the model's inverse dynamics.
            if let (OuterLoop::Mfc(mfc), Some((j_hat, b_hat))) = (&mut self.outer, self.mfc_model) {
                let output = j_hat * reference.acceleration + b_hat * reference.velocity + friction;
                mfc.initialize_output(output, reference.angle, sensor.angle, sensor.velocity, friction);
            }
        }
        let output = match &mut self.outer {
            OuterLoop::Pid(pid) => pid.update(error, friction),
            OuterLoop::Mfc(mfc) => mfc.update(reference.angle, sensor.angle, friction),
        };
        PositionOutput { reference, output }
    }

    /// Bumpless transfer: called after [`PositionStage::process`] for the
    /// same period, sets this loop's state as if its output had been
    /// `output`, the output of the loop it is about to replace, so that it
    /// goes on from there. A standby stage calls it every period while it
    /// tracks the running one.
    pub fn track(&mut self, output: f64, time: f64, sensor: &SensorEstimate, friction: f64) {
        let friction = match self.structure {
            Structure::Position => friction,
            Structure::Cascade => 0.0,
        };
        let reference = self.trajectory.sample(time);
        match &mut self.outer {
            OuterLoop::Pid(pid) => pid.initialize_output(output, reference.angle - sensor.angle, friction),
            // A standby MFC has started (and initialized its model) on its
            // first period; from then on its model runs on.
            OuterLoop::Mfc(mfc) if self.started => mfc.track(output),
            OuterLoop::Mfc(mfc) => {
                mfc.initialize_output(output, reference.angle, sensor.angle, sensor.velocity, friction)
            }
        }
        self.started = true;
    }
}

/// The inner loop's variants.
#[derive(Debug, Clone)]
pub enum InnerLoop {
    Pid(Pid),
    HInfinity(HInfinity),
}

/// Torque stage: the inner loop, torque reference to valve command.
#[derive(Debug, Clone)]
pub struct TorqueStage {
    structure: Structure,
    variant: TorqueVariant,
    inner: InnerLoop,
    ts: f64,
    velocity_feedforward: f64,
    rate_feedforward: f64,
    rate_blend: f64,
    previous_reference: Option<f64>,
    reference_rate: f64,
    /// Bumpless transfer into the H∞ loop: the running command less the
    /// H∞'s own, added to its output and faded out after the switch (its
    /// state, full of fast modes, is never forced).
    transfer_offset: f64,
    transfer_fade: f64,
    /// The H∞ loop's own last command, before the offset.
    own_command: f64,
}

/// How fast a transfer offset fades once a standby inner loop is in charge.
const TRANSFER_FADE_S: f64 = 0.05;

impl TorqueStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Self::with_variant(config, config.control.torque_variant)
    }

    pub fn with_variant(config: &Config, variant: TorqueVariant) -> Result<Self, StackError> {
        let ts = config.timing.control_period();
        let torque = &config.control.torque;
        hydractl_control::require_finite("velocity_feedforward", torque.velocity_feedforward)
            .map_err(in_section("control.torque"))?;
        hydractl_control::require_finite("rate_feedforward", torque.rate_feedforward)
            .map_err(in_section("control.torque"))?;
        hydractl_control::require_non_negative_pub("rate_filter_s", torque.rate_filter_s)
            .map_err(in_section("control.torque"))?;
        let inner = match variant {
            TorqueVariant::Pid => {
                InnerLoop::Pid(Pid::new(config.control.torque.pid, ts).map_err(in_section("control.torque.pid"))?)
            }
            TorqueVariant::Hinf => InnerLoop::HInfinity(
                HInfinity::new(config.control.torque.hinf.clone(), ts).map_err(in_section("control.torque.hinf"))?,
            ),
        };
        Ok(Self {
            structure: config.control.structure,
            variant,
            inner,
            ts,
            velocity_feedforward: torque.velocity_feedforward,
            rate_feedforward: torque.rate_feedforward,
            rate_blend: ts / (torque.rate_filter_s + ts),
            previous_reference: None,
            reference_rate: 0.0,
            transfer_offset: 0.0,
            transfer_fade: (-ts / TRANSFER_FADE_S).exp(),
            own_command: 0.0,
        })
    }

    pub fn variant(&self) -> TorqueVariant {
        self.variant
    }

    /// The valve command for the position stage's output. In the cascade
    /// that output is a torque reference and the inner loop runs, with the
    /// friction compensation (valve-command units) added as the rotary paper
    /// adds it to its torque PID; in position-only control it already is
    /// the command, and passes through.
    pub fn process(&mut self, position: &PositionOutput, sensor: &SensorEstimate, friction: f64) -> f64 {
        match self.structure {
            Structure::Position => position.output,
            Structure::Cascade => self.inner_loop(position.output, position.reference.velocity, sensor, friction),
        }
    }

    /// Bumpless transfer, as [`PositionStage::track`]: called after
    /// [`TorqueStage::process`] for the same period, sets the inner loop's
    /// state as if its command had been `command`. Nothing to track when
    /// the stage passes the command through.
    pub fn track(&mut self, command: f64, position: &PositionOutput, sensor: &SensorEstimate, friction: f64) {
        if self.structure == Structure::Position {
            return;
        }
        let feedforward = friction
            + self.velocity_feedforward * position.reference.velocity
            + self.rate_feedforward * self.reference_rate;
        let error = position.output - sensor.torque;
        match &mut self.inner {
            InnerLoop::Pid(pid) => pid.initialize_output(command, error, feedforward),
            InnerLoop::HInfinity(_) => self.transfer_offset = command - self.own_command,
        }
    }

    fn inner_loop(
        &mut self,
        torque_reference: f64,
        reference_velocity: f64,
        sensor: &SensorEstimate,
        friction: f64,
    ) -> f64 {
        let previous = self.previous_reference.unwrap_or(torque_reference);
        self.previous_reference = Some(torque_reference);
        self.reference_rate += self.rate_blend * ((torque_reference - previous) / self.ts - self.reference_rate);
        let feedforward =
            friction + self.velocity_feedforward * reference_velocity + self.rate_feedforward * self.reference_rate;
        let error = torque_reference - sensor.torque;
        match &mut self.inner {
            InnerLoop::Pid(pid) => pid.update(error, feedforward),
            InnerLoop::HInfinity(hinf) => {
                self.own_command = hinf.update(error) + feedforward;
                let command = self.own_command + self.transfer_offset;
                self.transfer_offset *= self.transfer_fade;
                command.clamp(-1.0, 1.0)
            }
        }
    }
}

/// Why the valve went to neutral.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ValveFaults {
    /// No command derived from a recent enough sensor reading.
    pub stale: bool,
    pub not_finite: bool,
    pub out_of_range: bool,
    /// The sensor reading behind the command was not valid.
    pub invalid_sensor: bool,
    /// The requested commands are limit-cycling: neutral until they stop.
    pub limit_cycle: bool,
}

impl ValveFaults {
    pub fn any(&self) -> bool {
        self.stale || self.not_finite || self.out_of_range || self.invalid_sensor || self.limit_cycle
    }
}

/// Valve stage: command shaping, and the last line of safety: a stale,
/// non-finite or out-of-range command, or one derived from an invalid
/// reading, puts the valve in neutral at once (not rate-limited) and says
/// why. It never passes garbage on. Requested commands that limit-cycle
/// put it in neutral too, and keep it there until they stop: the
/// supervisor then replaces their controller, whose fresh commands are
/// judged afresh.
///
/// A command's age is counted in loop periods the valve has seen (sensor
/// readings received), not in sequence numbers: when the whole computer
/// stalls, every process stalls together and no command is stale for it,
/// while a dead or hung controller leaves the readings coming and the
/// commands not, which trips the guard after `max_age_periods` readings.
/// When the readings stop too, the process calls [`ValveStage::on_silence`]
/// from its own clock.
#[derive(Debug, Clone)]
pub struct ValveStage {
    shaper: ValveShaper,
    max_age: u64,
    /// Readings received since the last command, before any command.
    readings_since_command: u64,
    /// The newest reading a command answered: the age of the command in
    /// effect is counted in readings from it, whenever it arrived.
    newest_command_seq: Option<u64>,
    /// The most recent readings, a ring: (sequence number, valid).
    recent: [(u64, bool); RECENT_READINGS],
    next_slot: usize,
    filled: usize,
    limit_cycle: LimitCycleDetector,
    in_limit_cycle: bool,
    command_source: Option<u32>,
}

/// The longest guard the valve supports, in periods.
pub const MAX_GUARD_PERIODS: usize = 32;
const RECENT_READINGS: usize = 2 * MAX_GUARD_PERIODS;

impl ValveStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        let guard = &config.control.valve_guard;
        if guard.max_age_periods == 0 || guard.max_age_periods as usize > MAX_GUARD_PERIODS {
            return Err(StackError::Control {
                section: "control.valve_guard",
                source: ControlError::InvalidParameter {
                    name: "max_age_periods",
                    value: guard.max_age_periods as f64,
                    reason: "must be from 1 to 32",
                },
            });
        }
        if !(guard.silence_timeout_ms.is_finite() && guard.silence_timeout_ms > 0.0) {
            return Err(StackError::Control {
                section: "control.valve_guard",
                source: ControlError::InvalidParameter {
                    name: "silence_timeout_ms",
                    value: guard.silence_timeout_ms,
                    reason: "must be positive",
                },
            });
        }
        Ok(Self {
            shaper: ValveShaper::new(config.control.valve, config.timing.control_period())
                .map_err(in_section("control.valve"))?,
            max_age: guard.max_age_periods,
            limit_cycle: LimitCycleDetector::new(LimitCycleParams {
                swing: guard.limit_cycle_swing,
                half_period: guard.limit_cycle_half_period_periods,
                reversals: guard.limit_cycle_reversals,
            })
            .map_err(in_section("control.valve_guard"))?,
            in_limit_cycle: false,
            command_source: None,
            readings_since_command: 0,
            newest_command_seq: None,
            recent: [(0, false); RECENT_READINGS],
            next_slot: 0,
            filled: 0,
        })
    }

    /// Shapes a command known to be sound (the offline loop's path).
    pub fn process(&mut self, command: f64) -> f64 {
        self.shaper.update(command)
    }

    /// A command derived from sensor reading `seq`, from the controller
    /// variant `source` ([`hydractl_samples`]' `code`, any stable tag will
    /// do). Returns the command to drive and the faults. A new source (a hot
    /// swap hands over without a gap in the commands) is judged afresh.
    pub fn on_command(&mut self, seq: u64, requested: f64, source: u32) -> (f64, ValveFaults) {
        if self.command_source.is_some_and(|s| s != source) {
            self.forget_limit_cycle();
        }
        self.command_source = Some(source);
        let reading = self.reading(seq);
        let sound = requested.is_finite() && requested.abs() <= 1.0 + 1e-9;
        if sound {
            self.in_limit_cycle |= self.limit_cycle.update(seq, requested);
        }
        let faults = ValveFaults {
            stale: self.readings_after(seq) > self.max_age,
            not_finite: !requested.is_finite(),
            out_of_range: requested.is_finite() && requested.abs() > 1.0 + 1e-9,
            // A reading the valve never saw is not known to be valid.
            invalid_sensor: reading != Some(true),
            limit_cycle: self.in_limit_cycle,
        };
        self.readings_since_command = 0;
        self.newest_command_seq = Some(self.newest_command_seq.map_or(seq, |c| c.max(seq)));
        if faults.any() {
            return (self.neutral(), faults);
        }
        (self.shaper.update(requested), faults)
    }

    /// A new sensor reading `seq`: when more than `max_age` readings have
    /// come after the one the newest command answered (whenever that
    /// command arrived), the valve goes to neutral (`Some`).
    pub fn on_sensor(&mut self, seq: u64, valid: bool) -> Option<(f64, ValveFaults)> {
        // A sequence going backwards is a restarted plant: forget the old run.
        if self.filled > 0 {
            let newest = self.recent[(self.next_slot + RECENT_READINGS - 1) % RECENT_READINGS].0;
            if seq < newest {
                self.filled = 0;
                self.next_slot = 0;
                self.newest_command_seq = None;
                self.forget_limit_cycle();
            }
        }
        self.recent[self.next_slot] = (seq, valid);
        self.next_slot = (self.next_slot + 1) % RECENT_READINGS;
        self.filled = (self.filled + 1).min(RECENT_READINGS);
        self.readings_since_command += 1;
        let stale = match self.newest_command_seq {
            Some(command) => self.readings_after(command) > self.max_age,
            None => self.readings_since_command > self.max_age,
        };
        if stale {
            return Some(self.stale());
        }
        None
    }

    /// Neither readings nor commands for the silence timeout: the loop
    /// upstream of the valve is gone, so the valve goes to neutral.
    pub fn on_silence(&mut self) -> (f64, ValveFaults) {
        self.stale()
    }

    fn stale(&mut self) -> (f64, ValveFaults) {
        // The commands stopped: whatever sends the next ones is judged afresh.
        self.forget_limit_cycle();
        let faults = ValveFaults {
            stale: true,
            ..ValveFaults::default()
        };
        (self.neutral(), faults)
    }

    /// The stored readings: the ring fills from slot 0, so until it is
    /// full they are its first `filled` slots, and then all of them.
    fn entries(&self) -> impl Iterator<Item = &(u64, bool)> {
        self.recent.iter().take(self.filled)
    }

    fn reading(&self, seq: u64) -> Option<bool> {
        self.entries().find(|(s, _)| *s == seq).map(|(_, valid)| *valid)
    }

    /// How many readings the valve has received after reading `seq`.
    fn readings_after(&self, seq: u64) -> u64 {
        self.entries().filter(|(s, _)| *s > seq).count() as u64
    }

    fn forget_limit_cycle(&mut self) {
        self.limit_cycle.reset();
        self.in_limit_cycle = false;
    }

    fn neutral(&mut self) -> f64 {
        self.shaper.initialize_output(0.0);
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn valve() -> ValveStage {
        ValveStage::new(&Config::default_sim().expect("valid")).expect("stage")
    }

    #[test]
    fn valve_passes_sound_commands_through_the_shaper() {
        let mut v = valve();
        assert!(v.on_sensor(10, true).is_none());
        let (command, faults) = v.on_command(10, 0.05, 0);
        assert!(!faults.any());
        assert!((command - 0.05).abs() < 1e-12);
    }

    #[test]
    fn valve_goes_neutral_on_garbage_at_once() {
        let mut v = valve();
        v.on_sensor(1, true);
        v.on_command(1, 0.05, 0);
        v.on_sensor(2, true);
        let (command, faults) = v.on_command(2, f64::NAN, 0);
        assert_eq!((command, faults.not_finite), (0.0, true));
        v.on_sensor(3, true);
        let (command, faults) = v.on_command(3, 1.5, 0);
        assert_eq!((command, faults.out_of_range), (0.0, true));
        v.on_sensor(4, false);
        let (command, faults) = v.on_command(4, 0.05, 0);
        assert_eq!((command, faults.invalid_sensor), (0.0, true));
        // A command from a reading the valve never saw is not trusted either.
        let (command, faults) = v.on_command(99, 0.05, 0);
        assert_eq!((command, faults.invalid_sensor), (0.0, true));
    }

    #[test]
    fn a_limit_cycling_controller_is_held_neutral_until_its_commands_stop() {
        let mut v = valve();
        // Bang-bang at 5 Hz: a full swing every 100 readings.
        let bang_bang = |seq: u64| if (seq / 100).is_multiple_of(2) { 0.9 } else { -0.9 };
        let mut first_neutral = None;
        for seq in 0..2000 {
            v.on_sensor(seq, true);
            let (command, faults) = v.on_command(seq, bang_bang(seq), 0);
            if faults.limit_cycle && first_neutral.is_none() {
                first_neutral = Some(seq);
            }
            if first_neutral.is_some() {
                assert_eq!((command, faults.limit_cycle), (0.0, true), "latched at {seq}");
            }
        }
        // The 12th reversal in a row after the first, at reading 1300.
        assert_eq!(first_neutral, Some(1300));
        // Its controller is killed: the commands stop and the valve forgets.
        for seq in 2000..2004 {
            v.on_sensor(seq, true);
        }
        v.on_sensor(2004, true);
        let (_, faults) = v.on_command(2004, 0.9, 0);
        assert!(!faults.any(), "{faults:?}");
    }

    #[test]
    fn a_hot_swap_away_from_a_limit_cycling_controller_is_judged_afresh() {
        let mut v = valve();
        let bang_bang = |seq: u64| if (seq / 100).is_multiple_of(2) { 0.9 } else { -0.9 };
        for seq in 0..1400 {
            v.on_sensor(seq, true);
            v.on_command(seq, bang_bang(seq), 0);
        }
        // The handover leaves no gap in the commands: the new variant's
        // first command is driven.
        v.on_sensor(1400, true);
        let (command, faults) = v.on_command(1400, 0.3, 2);
        assert!(!faults.any(), "{faults:?}");
        assert!(command > 0.0);
    }

    #[test]
    fn a_command_three_readings_old_is_fresh_and_four_is_stale() {
        let mut v = valve();
        for seq in 5..=8 {
            v.on_sensor(seq, true);
        }
        let (_, faults) = v.on_command(5, 0.05, 0);
        assert!(!faults.stale, "readings 6, 7, 8 came after it");
        v.on_sensor(9, true);
        let (command, faults) = v.on_command(5, 0.05, 0);
        assert_eq!((command, faults.stale), (0.0, true));
    }

    #[test]
    fn valve_goes_neutral_when_commands_stop_or_everything_falls_silent() {
        let mut v = valve();
        v.on_sensor(10, true);
        v.on_command(10, 0.05, 0);
        assert!(v.on_sensor(11, true).is_none());
        assert!(v.on_sensor(12, true).is_none());
        assert!(v.on_sensor(13, true).is_none());
        let (command, faults) = v.on_sensor(14, true).expect("stale after 3 periods");
        assert_eq!((command, faults.stale), (0.0, true));
        let (command, faults) = v.on_silence();
        assert_eq!((command, faults.stale), (0.0, true));
    }

    #[test]
    fn a_late_last_command_still_ages_from_its_own_reading() {
        // The controller's last command, for reading 10, came after reading
        // 11 had arrived (it was slow), and then the controller died.
        let mut v = valve();
        v.on_sensor(10, true);
        v.on_sensor(11, true);
        v.on_command(10, 0.05, 0);
        assert!(v.on_sensor(12, true).is_none());
        assert!(v.on_sensor(13, true).is_none());
        assert!(v.on_sensor(14, true).is_some(), "four readings after reading 10");
    }

    #[test]
    fn a_stall_of_the_whole_machine_is_not_a_stale_command() {
        let mut v = valve();
        v.on_sensor(10, true);
        v.on_command(10, 0.05, 0);
        assert!(v.on_sensor(17, true).is_none());
        let (_, faults) = v.on_command(17, 0.05, 0);
        assert!(!faults.any());
    }

    #[test]
    fn a_restarted_plant_starts_a_fresh_history() {
        let mut v = valve();
        for seq in 1000..1010 {
            v.on_sensor(seq, true);
            v.on_command(seq, 0.05, 0);
        }
        v.on_sensor(0, true);
        let (_, faults) = v.on_command(0, 0.05, 0);
        assert!(!faults.any());
    }
}

/// All five stages, for running the loop in one process.
#[derive(Debug, Clone)]
pub struct ControlStack {
    pub structure: Structure,
    pub sensor: SensorStage,
    pub friction: FrictionStage,
    pub position: PositionStage,
    pub torque: TorqueStage,
    pub valve: ValveStage,
    last_reference_velocity: f64,
    last_command: f64,
}

/// One period's signals through the stack.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StackOutput {
    pub sensor: SensorEstimate,
    pub friction: f64,
    pub position: PositionOutput,
    /// The torque reference (cascade), or NaN in position-only control.
    pub torque_reference: f64,
    /// The command sent to the valve.
    pub command: f64,
}

impl ControlStack {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        Ok(Self {
            structure: config.control.structure,
            sensor: SensorStage::new(config)?,
            friction: FrictionStage::new(config)?,
            position: PositionStage::new(config)?,
            torque: TorqueStage::new(config)?,
            valve: ValveStage::new(config)?,
            last_reference_velocity: 0.0,
            last_command: 0.0,
        })
    }

    /// One control period, from the raw readings at `time` to the valve command.
    pub fn step(&mut self, time: f64, raw: &RawReading) -> StackOutput {
        let sensor = self.sensor.process(raw);
        let friction = self
            .friction
            .process(&sensor, self.last_reference_velocity, self.last_command);
        let position = self.position.process(time, &sensor, friction);
        let demand = self.torque.process(&position, &sensor, friction);
        let torque_reference = match self.structure {
            Structure::Position => f64::NAN,
            Structure::Cascade => position.output,
        };
        let command = self.valve.process(demand);
        self.last_reference_velocity = position.reference.velocity;
        self.last_command = command;
        StackOutput {
            sensor,
            friction,
            position,
            torque_reference,
            command,
        }
    }
}
