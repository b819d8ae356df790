//! The valve stage: command shaping and the last line of safety.

use hydractl_config::{Config, MAX_GUARD_PERIODS};
use hydractl_control::{LimitCycleDetector, ValveShaper};

use crate::{in_section, StackError};

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

const RECENT_READINGS: usize = 2 * MAX_GUARD_PERIODS;

impl ValveStage {
    pub fn new(config: &Config) -> Result<Self, StackError> {
        let guard = &config.control.valve_guard;
        guard.check().map_err(in_section("control.valve_guard"))?;
        Ok(Self {
            shaper: ValveShaper::new(config.control.valve, config.timing.control_period())
                .map_err(in_section("control.valve"))?,
            max_age: guard.max_age_periods,
            limit_cycle: LimitCycleDetector::new(guard.limit_cycle()).map_err(in_section("control.valve_guard"))?,
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
    /// do). Returns the command to drive and the faults, or `None` for a
    /// command answering a reading an accepted command already answered
    /// (a second publisher): the valve holds what it drives and says
    /// nothing. A new source (a hot swap hands over without a gap in the
    /// commands) is judged afresh.
    ///
    /// Only an accepted command moves the guard's state: one that is
    /// refused (stale, garbage, or from a reading the valve did not see as
    /// valid) changes neither the command's age, nor the source, nor the
    /// limit-cycle watch, so a garbled sequence number cannot switch the
    /// stale-command guard off.
    pub fn on_command(&mut self, seq: u64, requested: f64, source: u32) -> Option<(f64, ValveFaults)> {
        let reading = self.reading(seq);
        let source_changed = self.command_source.is_some_and(|s| s != source);
        let faults = ValveFaults {
            stale: self.readings_after(seq) > self.max_age,
            not_finite: !requested.is_finite(),
            out_of_range: requested.is_finite() && requested.abs() > 1.0 + 1e-9,
            // A reading the valve never saw is not known to be valid.
            invalid_sensor: reading != Some(true),
            limit_cycle: self.in_limit_cycle && !source_changed,
        };
        let refused = faults.stale || faults.not_finite || faults.out_of_range || faults.invalid_sensor;
        if refused {
            return Some((self.neutral(), faults));
        }
        if self.newest_command_seq.is_some_and(|newest| seq <= newest) {
            return None;
        }
        if source_changed {
            self.forget_limit_cycle();
        }
        self.command_source = Some(source);
        self.in_limit_cycle |= self.limit_cycle.update(seq, requested);
        self.readings_since_command = 0;
        self.newest_command_seq = Some(seq);
        let faults = ValveFaults {
            limit_cycle: self.in_limit_cycle,
            ..ValveFaults::default()
        };
        if faults.any() {
            return Some((self.neutral(), faults));
        }
        Some((self.shaper.update(requested), faults))
    }

    /// A new sensor reading `seq`: when more than `max_age` readings have
    /// come after the one the newest command answered (whenever that
    /// command arrived), the valve goes to neutral (`Some`).
    pub fn on_sensor(&mut self, seq: u64, valid: bool) -> Option<(f64, ValveFaults)> {
        // A sequence going backwards (or repeating) is a restarted plant or a
        // garbled reading: forget the old run, and drive nothing from it.
        if self.filled > 0 {
            let newest = self.recent[(self.next_slot + RECENT_READINGS - 1) % RECENT_READINGS].0;
            if seq <= newest {
                // The command in effect answered the old run's readings.
                self.filled = 0;
                self.next_slot = 0;
                self.newest_command_seq = None;
                self.readings_since_command = 0;
                self.remember(seq, valid);
                return Some(self.stale());
            }
        }
        self.remember(seq, valid);
        let stale = match self.newest_command_seq {
            Some(command) => self.readings_after(command) > self.max_age,
            None => self.readings_since_command > self.max_age,
        };
        if stale {
            return Some(self.stale());
        }
        None
    }

    fn remember(&mut self, seq: u64, valid: bool) {
        self.recent[self.next_slot] = (seq, valid);
        self.next_slot = (self.next_slot + 1) % RECENT_READINGS;
        self.filled = (self.filled + 1).min(RECENT_READINGS);
        self.readings_since_command += 1;
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

    /// The device held the spool at neutral instead of the command (not yet
    /// Active, a fault latched): the next command is rate-limited from
    /// neutral, as the valve sees it.
    pub fn held_at_neutral(&mut self) {
        self.shaper.initialize_output(0.0);
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
        let (command, faults) = v.on_command(10, 0.05, 0).expect("answered");
        assert!(!faults.any());
        assert!((command - 0.05).abs() < 1e-12);
    }

    #[test]
    fn valve_goes_neutral_on_garbage_at_once() {
        let mut v = valve();
        v.on_sensor(1, true);
        v.on_command(1, 0.05, 0);
        v.on_sensor(2, true);
        let (command, faults) = v.on_command(2, f64::NAN, 0).expect("answered");
        assert_eq!((command, faults.not_finite), (0.0, true));
        v.on_sensor(3, true);
        let (command, faults) = v.on_command(3, 1.5, 0).expect("answered");
        assert_eq!((command, faults.out_of_range), (0.0, true));
        v.on_sensor(4, false);
        let (command, faults) = v.on_command(4, 0.05, 0).expect("answered");
        assert_eq!((command, faults.invalid_sensor), (0.0, true));
        // A command from a reading the valve never saw is not trusted either.
        let (command, faults) = v.on_command(99, 0.05, 0).expect("answered");
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
            let (command, faults) = v.on_command(seq, bang_bang(seq), 0).expect("answered");
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
        let (_, faults) = v.on_command(2004, 0.9, 0).expect("answered");
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
        let (command, faults) = v.on_command(1400, 0.3, 2).expect("answered");
        assert!(!faults.any(), "{faults:?}");
        assert!(command > 0.0);
    }

    #[test]
    fn a_command_three_readings_old_is_fresh_and_four_is_stale() {
        let mut v = valve();
        for seq in 5..=8 {
            v.on_sensor(seq, true);
        }
        let (_, faults) = v.on_command(5, 0.05, 0).expect("answered");
        assert!(!faults.stale, "readings 6, 7, 8 came after it");
        v.on_sensor(9, true);
        let (command, faults) = v.on_command(5, 0.05, 0).expect("answered");
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
        let (_, faults) = v.on_command(17, 0.05, 0).expect("answered");
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
        let (_, faults) = v.on_command(0, 0.05, 0).expect("answered");
        assert!(!faults.any());
    }

    #[test]
    fn a_refused_command_moves_nothing_of_the_guard() {
        let mut v = valve();
        v.on_sensor(10, true);
        v.on_command(10, 0.05, 0).expect("answered");
        // Tagged with a reading that never came: refused, and the newest
        // command is still the one for reading 10.
        let (command, faults) = v.on_command(u64::MAX, 0.05, 0).expect("answered");
        assert_eq!((command, faults.invalid_sensor), (0.0, true));
        // Refused garbage from another source does not reset the watch either.
        let (_, faults) = v.on_command(10, f64::NAN, 7).expect("answered");
        assert!(faults.not_finite);
        for seq in 11..=13 {
            assert!(v.on_sensor(seq, true).is_none());
        }
        let (command, faults) = v.on_sensor(14, true).expect("the dead controller's command is stale");
        assert_eq!((command, faults.stale), (0.0, true));
    }

    #[test]
    fn a_second_answer_to_the_same_reading_is_not_driven() {
        let mut v = valve();
        v.on_sensor(9, true);
        v.on_sensor(10, true);
        v.on_command(10, 0.05, 0).expect("answered");
        assert_eq!(v.on_command(10, -0.9, 0), None, "a second publisher is ignored");
        assert_eq!(v.on_command(9, -0.9, 0), None, "an older reading too");
    }

    #[test]
    fn a_sequence_going_backwards_drives_neutral_at_once() {
        let mut v = valve();
        v.on_sensor(10, true);
        v.on_command(10, 0.05, 0).expect("answered");
        let (command, faults) = v.on_sensor(3, true).expect("neutral");
        assert_eq!((command, faults.stale), (0.0, true));
    }
}

#[cfg(test)]
mod properties {
    use super::*;
    use proptest::prelude::*;

    #[derive(Debug, Clone)]
    enum Event {
        /// The next reading, `skip` sequence numbers on (a stall), valid or not.
        Reading {
            skip: u64,
            valid: bool,
        },
        /// A command answering the reading `back` readings before the
        /// newest (stale when large), or one never seen (`future`).
        Command {
            back: u64,
            future: bool,
            value: Value,
            source: u32,
        },
        Silence,
        /// A garbled reading number going backwards.
        Backwards {
            by: u64,
        },
    }

    #[derive(Debug, Clone, Copy)]
    enum Value {
        Sound(f64),
        NotFinite,
        OutOfRange(f64),
    }

    fn value() -> impl Strategy<Value = Value> {
        prop_oneof![
            6 => (-1.0..=1.0f64).prop_map(Value::Sound),
            1 => Just(Value::NotFinite),
            1 => (1.01..100.0f64).prop_map(Value::OutOfRange),
        ]
    }

    fn event() -> impl Strategy<Value = Event> {
        prop_oneof![
            8 => (0..4u64, prop::bool::weighted(0.9)).prop_map(|(skip, valid)| Event::Reading { skip, valid }),
            8 => (0..8u64, prop::bool::weighted(0.05), value(), 0..3u32)
                .prop_map(|(back, future, value, source)| Event::Command { back, future, value, source }),
            1 => Just(Event::Silence),
            1 => (1..50u64).prop_map(|by| Event::Backwards { by }),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// Whatever comes in whatever order, the valve is never driven by a
        /// command older than `max_age` readings (counted as they arrived)
        /// or derived from a reading that was not valid.
        #[test]
        fn the_valve_is_never_driven_by_a_stale_or_invalid_command(events in prop::collection::vec(event(), 1..400)) {
            let config = Config::default_sim().expect("valid");
            let max_age = config.control.valve_guard.max_age_periods;
            let mut v = ValveStage::new(&config).expect("stage");
            // What the test saw: every reading in arrival order.
            let mut arrived: Vec<(u64, bool)> = Vec::new();
            let mut next_seq = 100u64;
            // The command driving the valve: the index in `arrived` of its reading.
            let mut driving: Option<usize> = None;
            for event in events {
                match event {
                    Event::Reading { skip, valid } => {
                        let seq = next_seq + skip;
                        next_seq = seq + 1;
                        arrived.push((seq, valid));
                        if let Some((command, _)) = v.on_sensor(seq, valid) {
                            prop_assert_eq!(command, 0.0);
                            driving = None;
                        }
                    }
                    Event::Backwards { by } => {
                        let seq = next_seq.saturating_sub(by);
                        next_seq = seq + 1;
                        arrived.push((seq, true));
                        if let Some((command, _)) = v.on_sensor(seq, true) {
                            prop_assert_eq!(command, 0.0);
                            driving = None;
                        }
                    }
                    Event::Silence => {
                        prop_assert_eq!(v.on_silence().0, 0.0);
                        driving = None;
                    }
                    Event::Command { back, future, value, source } => {
                        let seq = if future || arrived.is_empty() {
                            next_seq + 5
                        } else {
                            arrived[arrived.len() - 1 - (back as usize).min(arrived.len() - 1)].0
                        };
                        let requested = match value {
                            Value::Sound(x) => x,
                            Value::NotFinite => f64::NAN,
                            Value::OutOfRange(x) => x,
                        };
                        match v.on_command(seq, requested, source) {
                            None => {}
                            Some((command, faults)) if faults.any() => {
                                prop_assert_eq!(command, 0.0);
                                driving = None;
                            }
                            Some((command, _)) => {
                                prop_assert!(command.is_finite() && command.abs() <= 1.0);
                                // The newest arrival of that reading number.
                                let at = arrived.iter().rposition(|(s, _)| *s == seq);
                                prop_assert!(at.is_some(), "driven from reading {} never seen", seq);
                                let at = at.unwrap_or_default();
                                prop_assert!(arrived[at].1, "driven from invalid reading {}", seq);
                                driving = Some(at);
                            }
                        }
                    }
                }
                if let Some(at) = driving {
                    let age = (arrived.len() - 1 - at) as u64;
                    prop_assert!(age <= max_age, "driven by a command {} readings old", age);
                }
            }
        }
    }
}
