//! CiA 408, the proportional valve (device type 0x198), as the Danfoss
//! PVED-CC and Moog's valves implement it. The device state machine
//! (DSM) follows the control word's four low bits, D (disabled), H (hold),
//! M (active) and R (reset fault, on its rising edge); the status word
//! reports the state in the same bits, R there meaning ready:
//!
//! | state | status word RMHD |
//! |---|---|
//! | not ready | 0000 |
//! | init | 1000 |
//! | disabled | 1001 |
//! | hold (spool at neutral) | 1011 |
//! | active (spool follows the set point) | 1111 |
//! | fault init | 0000 after a fault |
//! | fault disabled | 0001 |
//! | fault hold (spool at neutral) | 0011 |
//! | fault reaction | 0111 |
//!
//! A master keeps R high and steps Init (0x08) → Disabled (0x09) → Hold
//! (0x0B) → Active (0x0F). A fault is cleared by R low (0x03) then high
//! (0x0B): `RESET_WORDS`, which a master sends only when a person asks
//! (ISO 13849-1's manual reset): its bring-up stops at a fault.

use crate::CanError;

/// The valve's objects.
pub(crate) mod object {
    pub const DEVICE_TYPE: u16 = 0x1000;
    pub const DEVICE_TYPE_VALUE: u32 = 0x198;
    pub const CONTROL_WORD: u16 = 0x6040;
    pub const STATUS_WORD: u16 = 0x6041;
    /// 1: set point from the bus.
    pub const DEVICE_MODE: u16 = 0x6042;
    pub const DEVICE_MODE_BUS: u8 = 1;
    /// Sub-index 1, INT16.
    pub const SET_POINT: u16 = 0x6300;
    /// Sub-index 1, INT16: the spool's actual position.
    pub const ACTUAL_VALUE: u16 = 0x6301;
}

/// Control words a master sends (R kept high but for a fault reset).
pub mod control_word {
    pub(crate) const DISABLED_BIT: u16 = 0x01;
    pub const HOLD_BIT: u16 = 0x02;
    pub const ACTIVE_BIT: u16 = 0x04;
    pub const RESET_FAULT_BIT: u16 = 0x08;
    pub const INIT: u16 = 0x08;
    pub(crate) const DISABLED: u16 = 0x09;
    pub const HOLD: u16 = 0x0B;
    pub const ACTIVE: u16 = 0x0F;
    /// R low; the next control word's R raises it and clears the fault.
    pub(crate) const FAULT_RESET: u16 = 0x03;
}

/// The master's own fault codes for a valve, beside the valve's EMCY
/// codes (16 bits), so that a latched fault has one number either way.
pub mod fault_code {
    /// CiA 301's "life guard or heartbeat error": the master's watch.
    pub const HEARTBEAT: u32 = 0x8130;
    /// A fault state the valve reports: this, or'ed with its status word.
    pub const STATE: u32 = 0x1_0000;
    /// A setting the valve refused or reads back otherwise.
    pub const SETTING: u32 = 0x2_0000;
    /// The spool's reported position does not follow the set point.
    pub const SPOOL: u32 = 0x3_0000;
    /// No status from the valve while the master drove it.
    pub const STATUS_MISSING: u32 = 0x4_0000;
    /// Nothing heard from the valve since the master started.
    pub const NEVER_HEARD: u32 = 0x5_0000;
    /// The bus refused the master's frames, a run of them.
    pub const WRITES_REFUSED: u32 = 0x6_0000;
}

/// A latched fault's code as a person reads it: an EMCY's in hex, the
/// master's own named.
pub fn fault_code_name(code: u32) -> String {
    match code {
        fault_code::SETTING => "a refused setting".to_owned(),
        fault_code::SPOOL => "a spool off its set point".to_owned(),
        fault_code::STATUS_MISSING => "a missing status".to_owned(),
        fault_code::NEVER_HEARD => "a silent valve".to_owned(),
        fault_code::WRITES_REFUSED => "writes refused".to_owned(),
        c if c & !0xFFFF == fault_code::STATE => format!("fault state {:#06b}", c & 0xF),
        c => format!("{c:#06x}"),
    }
}

/// ±16384 is ±100 % spool travel.
pub(crate) const FULL_SCALE: i16 = 16384;
/// PVED-CC: a set point of 32767 commands the float position.
pub const FLOAT: i16 = 32767;

/// The set point for a valve command in [-1, 1]; anything else, NaN
/// included, is clamped or neutral: a garbled command never reaches the
/// bus as travel.
pub fn set_point(command: f64) -> i16 {
    if !command.is_finite() {
        return 0;
    }
    (command.clamp(-1.0, 1.0) * f64::from(FULL_SCALE)).round() as i16
}

/// The spool position in [-1, 1] (beyond ±1 when the valve reports it).
pub fn spool_position(actual: i16) -> f64 {
    f64::from(actual) / f64::from(FULL_SCALE)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceState {
    NotReady,
    Init,
    Disabled,
    Hold,
    Active,
    FaultInit,
    FaultDisabled,
    FaultHold,
    FaultReaction,
}

impl DeviceState {
    pub fn status_word(self) -> u16 {
        match self {
            Self::NotReady | Self::FaultInit => 0b0000,
            Self::Init => 0b1000,
            Self::Disabled => 0b1001,
            Self::Hold => 0b1011,
            Self::Active => 0b1111,
            Self::FaultDisabled => 0b0001,
            Self::FaultHold => 0b0011,
            Self::FaultReaction => 0b0111,
        }
    }

    /// The state a status word reports. Not ready and fault init share
    /// 0000; read as fault init once the valve had been ready.
    pub fn from_status_word(word: u16, was_ready: bool) -> Self {
        match word & 0x0F {
            0b1000 => Self::Init,
            0b1001 => Self::Disabled,
            0b1011 => Self::Hold,
            0b1111 => Self::Active,
            0b0001 => Self::FaultDisabled,
            0b0011 => Self::FaultHold,
            0b0111 => Self::FaultReaction,
            0b0000 if was_ready => Self::FaultInit,
            0b0000 => Self::NotReady,
            // 1010, 1100, … are no state of the DSM: a fault as far as the
            // master is concerned, so the stack stays safe.
            _ => Self::FaultHold,
        }
    }

    pub fn is_fault(self) -> bool {
        matches!(
            self,
            Self::FaultInit | Self::FaultDisabled | Self::FaultHold | Self::FaultReaction
        )
    }

    /// Only in Active does the spool follow the set point; every other
    /// state holds it at neutral or at its hydraulic fail-safe position.
    pub(crate) fn follows_set_point(self) -> bool {
        self == Self::Active
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::NotReady => "not ready",
            Self::Init => "init",
            Self::Disabled => "disabled",
            Self::Hold => "hold",
            Self::Active => "active",
            Self::FaultInit => "fault init",
            Self::FaultDisabled => "fault disabled",
            Self::FaultHold => "fault hold",
            Self::FaultReaction => "fault reaction",
        }
    }
}

/// The valve's own device state machine: what a CiA 408 valve does with
/// the control words it receives and the faults it detects. The simulated
/// valve ECU runs it; the master's bring-up is tested against it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct StateMachine {
    state: DeviceState,
    last_control_word: u16,
}

impl Default for StateMachine {
    fn default() -> Self {
        Self::power_up()
    }
}

impl StateMachine {
    /// Powered and initialized: Init, waiting for a control word.
    pub fn power_up() -> Self {
        Self {
            state: DeviceState::Init,
            last_control_word: 0,
        }
    }

    pub fn state(&self) -> DeviceState {
        self.state
    }

    pub fn on_control_word(&mut self, word: u16) -> DeviceState {
        let reset_edge =
            word & control_word::RESET_FAULT_BIT != 0 && self.last_control_word & control_word::RESET_FAULT_BIT == 0;
        self.last_control_word = word;
        if self.state.is_fault() {
            if !reset_edge || self.state == DeviceState::FaultReaction {
                return self.state;
            }
            self.state = match self.state {
                DeviceState::FaultHold => DeviceState::Hold,
                DeviceState::FaultDisabled => DeviceState::Disabled,
                _ => DeviceState::Init,
            };
        }
        if self.state == DeviceState::NotReady {
            return self.state;
        }
        // The requested level; every transition between the present state
        // and the requested one is taken.
        self.state = match word & 0x07 {
            0b111 => DeviceState::Active,
            0b011 | 0b010 | 0b110 => DeviceState::Hold,
            0b001 | 0b101 => DeviceState::Disabled,
            _ => DeviceState::Init,
        };
        // H without D, or M without H, is not a level of the DSM: the
        // lower consistent one is taken.
        if word & control_word::DISABLED_BIT == 0 {
            self.state = DeviceState::Init;
        }
        self.state
    }

    /// A fault detected (an RPDO timeout, a lost bus): the fault reaction
    /// brings the spool to neutral. Returns true when the fault is new
    /// (an EMCY is due).
    pub fn on_fault(&mut self) -> bool {
        if self.state.is_fault() {
            return false;
        }
        self.state = match self.state {
            DeviceState::Init | DeviceState::NotReady => DeviceState::FaultInit,
            DeviceState::Disabled => DeviceState::FaultDisabled,
            _ => DeviceState::FaultHold,
        };
        true
    }
}

/// The master's next control word to bring a valve reporting `state` to
/// Active: Init → Disabled → Hold → Active. `None` in a fault state: the
/// bring-up stops there, and only [`RESET_WORDS`], sent on a person's
/// command, clear the fault.
pub(crate) fn next_control_word(state: DeviceState) -> Option<u16> {
    match state {
        DeviceState::NotReady | DeviceState::Init => Some(control_word::DISABLED),
        DeviceState::Disabled => Some(control_word::HOLD),
        DeviceState::Hold | DeviceState::Active => Some(control_word::ACTIVE),
        DeviceState::FaultReaction | DeviceState::FaultInit | DeviceState::FaultDisabled | DeviceState::FaultHold => {
            None
        }
    }
}

/// The deliberate fault reset: R low, then high (the rising edge), the
/// spool kept at neutral (Hold).
pub(crate) const RESET_WORDS: [u16; 2] = [control_word::FAULT_RESET, control_word::HOLD];

/// A NaN or out-of-range command is a programming error upstream; the
/// frame carries neutral, and this names it for the caller's fault count.
pub fn checked_set_point(command: f64) -> Result<i16, CanError> {
    if !command.is_finite() || command.abs() > 1.0 {
        return Err(CanError::Malformed {
            cob_id: 0,
            what: "valve set point",
            reason: format!("command {command} is outside [-1, 1]; neutral is sent"),
        });
    }
    Ok(set_point(command))
}

/// The raw value of an INT16 object as a PDO carries it.
pub(crate) fn raw_i16(value: i16) -> u64 {
    u64::from(value as u16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_points_scale_to_sixteen_thousand_three_hundred_eighty_four() {
        assert_eq!(set_point(1.0), 16384);
        assert_eq!(set_point(-1.0), -16384);
        assert_eq!(set_point(0.5), 8192);
        assert_eq!(set_point(2.0), 16384);
        assert_eq!(set_point(f64::NAN), 0);
        assert_eq!(spool_position(-8192), -0.5);
        assert!(checked_set_point(f64::NAN).is_err());
        assert_eq!(checked_set_point(-0.25), Ok(-4096));
    }

    #[test]
    fn the_bring_up_sequence_is_the_manuals() {
        let mut valve = StateMachine::power_up();
        let mut sent = Vec::new();
        while valve.state() != DeviceState::Active && sent.len() < 10 {
            let word = next_control_word(valve.state()).expect("no fault on the way");
            sent.push(word);
            valve.on_control_word(word);
        }
        assert_eq!(sent, [0x09, 0x0B, 0x0F]);
        assert_eq!(valve.state().status_word(), 0x0F);
    }

    #[test]
    fn a_fault_holds_the_spool_until_reset_by_a_rising_r() {
        let mut valve = StateMachine::power_up();
        for word in [0x08, 0x09, 0x0B, 0x0F] {
            valve.on_control_word(word);
        }
        assert!(valve.on_fault(), "a new fault sends an EMCY");
        assert!(!valve.on_fault(), "once");
        assert_eq!(valve.state(), DeviceState::FaultHold);
        assert!(!valve.state().follows_set_point());
        // Keeping R high does not clear it.
        assert_eq!(valve.on_control_word(0x0F), DeviceState::FaultHold);
        // The master's bring-up stops at the fault: it never resets it.
        assert_eq!(next_control_word(valve.state()), None);
        // A person's reset: R low, then high; then the bring-up goes on.
        for word in RESET_WORDS {
            valve.on_control_word(word);
        }
        assert_eq!(valve.state(), DeviceState::Hold, "cleared, spool still at neutral");
        let next = next_control_word(valve.state()).expect("on to Active");
        assert_eq!(valve.on_control_word(next), DeviceState::Active);
    }

    #[test]
    fn every_status_word_reads_back_as_its_state() {
        for state in [
            DeviceState::Init,
            DeviceState::Disabled,
            DeviceState::Hold,
            DeviceState::Active,
            DeviceState::FaultDisabled,
            DeviceState::FaultHold,
            DeviceState::FaultReaction,
        ] {
            assert_eq!(DeviceState::from_status_word(state.status_word(), true), state);
        }
        assert_eq!(DeviceState::from_status_word(0, false), DeviceState::NotReady);
        assert_eq!(DeviceState::from_status_word(0, true), DeviceState::FaultInit);
        assert!(DeviceState::from_status_word(0b1010, true).is_fault());
    }

    #[test]
    fn lowering_the_control_word_steps_down() {
        let mut valve = StateMachine::power_up();
        valve.on_control_word(0x0F);
        assert_eq!(valve.state(), DeviceState::Active, "every transition between is taken");
        assert_eq!(valve.on_control_word(0x0B), DeviceState::Hold);
        assert_eq!(valve.on_control_word(0x09), DeviceState::Disabled);
        assert_eq!(valve.on_control_word(0x08), DeviceState::Init);
        assert_eq!(valve.on_control_word(0x0E), DeviceState::Init, "M and H without D");
    }
}
