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
