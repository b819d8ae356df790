//! Codes of the structure and variants, for samples that report them.

pub const STRUCTURE_POSITION: u32 = 0;
pub const STRUCTURE_CASCADE: u32 = 1;
pub const VARIANT_PID: u32 = 0;
pub const VARIANT_MFC: u32 = 1;
pub const VARIANT_HINF: u32 = 2;
pub const STAGE_POSITION: u32 = 0;
pub const STAGE_TORQUE: u32 = 1;
/// The plant seat: the machine or the simulated plant ([`crate::source`]).
pub const STAGE_PLANT: u32 = 2;
/// [`crate::ValveRequest`] kinds: reset the valve's latched fault.
pub const VALVE_RESET: u32 = 1;

/// What a [`crate::SupervisorEvent`] reports: its `kind` field is the
/// code ([`EventKind::code`]), its words [`EventKind::name`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventKind {
    Swap,
    SwapFailed,
    Crash,
    Hang,
    /// The machine's readings stopped: the simulated plant took over.
    Fallback,
    /// The plant seat changed on request (`hydractl plant sim|machine`).
    PlantSwitch,
    /// A controller's commands were rejected by the valve, reading after
    /// reading: it was restarted (into its fallback variant, if any).
    Misbehaving,
    /// The valve found a controller's commands limit-cycling and held
    /// neutral: it was restarted (into its fallback variant, if any).
    LimitCycle,
    /// A process took more than its share of the loop's CPU for too long
    /// (a busy loop at the loop's priority): it was killed and restarted.
    Spin,
    /// A process that is none of the run's publishes on one of its
    /// services (`process`: the service, `pid`: the stranger).
    Stranger,
    /// A controller restarted into another variant after a fault, judged
    /// by the tracking that followed: kept (`to` the same variant), fallen
    /// further back (`to` the next), or left down (`to` empty).
    FallbackJudged,
}

impl EventKind {
    /// Every kind, in the order of their codes.
    pub const ALL: [EventKind; 11] = [
        Self::Swap,
        Self::SwapFailed,
        Self::Crash,
        Self::Hang,
        Self::Fallback,
        Self::PlantSwitch,
        Self::Misbehaving,
        Self::LimitCycle,
        Self::Spin,
        Self::Stranger,
        Self::FallbackJudged,
    ];

    /// The code a sample carries.
    pub fn code(self) -> u32 {
        self as u32
    }

    /// The kind of a sample's code; `None` for one this build does not know.
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.get(code as usize).copied()
    }

    /// Its word, as summaries and logs write it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Swap => "swap",
            Self::SwapFailed => "swap_failed",
            Self::Crash => "crash",
            Self::Hang => "hang",
            Self::Fallback => "fallback",
            Self::PlantSwitch => "plant_switch",
            Self::Misbehaving => "misbehaving",
            Self::LimitCycle => "limit_cycle",
            Self::Spin => "spin",
            Self::Stranger => "stranger",
            Self::FallbackJudged => "fallback_judged",
        }
    }
}

pub fn variant_name(variant: u32) -> &'static str {
    match variant {
        VARIANT_PID => "pid",
        VARIANT_MFC => "mfc",
        VARIANT_HINF => "hinf",
        _ => "?",
    }
}

pub fn variant_code(name: &str) -> Option<u32> {
    match name {
        "pid" => Some(VARIANT_PID),
        "mfc" => Some(VARIANT_MFC),
        "hinf" => Some(VARIANT_HINF),
        _ => None,
    }
}

pub fn stage_name(stage: u32) -> &'static str {
    match stage {
        STAGE_POSITION => "position",
        STAGE_TORQUE => "torque",
        STAGE_PLANT => "plant",
        _ => "?",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_event_kind_comes_back_from_its_code_with_a_word_of_its_own() {
        let mut words = std::collections::BTreeSet::new();
        for kind in EventKind::ALL {
            assert_eq!(EventKind::from_code(kind.code()), Some(kind));
            assert!(words.insert(kind.name()), "{kind:?}");
        }
        assert_eq!(EventKind::from_code(EventKind::ALL.len() as u32), None);
    }
}
