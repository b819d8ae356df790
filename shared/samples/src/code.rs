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
/// [`crate::SupervisorEvent`] kinds.
pub const EVENT_SWAP: u32 = 0;
pub const EVENT_SWAP_FAILED: u32 = 1;
pub const EVENT_CRASH: u32 = 2;
pub const EVENT_HANG: u32 = 3;
/// The machine's readings stopped: the simulated plant took over.
pub const EVENT_FALLBACK: u32 = 4;
/// The plant seat changed on request (`hydractl plant sim|machine`).
pub const EVENT_PLANT_SWITCH: u32 = 5;
/// A controller's commands were rejected by the valve, reading after
/// reading: it was restarted (into its fallback variant, if any).
pub const EVENT_MISBEHAVING: u32 = 6;
/// The valve found a controller's commands limit-cycling and held
/// neutral: it was restarted (into its fallback variant, if any).
pub const EVENT_LIMIT_CYCLE: u32 = 7;
/// A process took more than its share of the loop's CPU for too long
/// (a busy loop at the loop's priority): it was killed and restarted.
pub const EVENT_SPIN: u32 = 8;
/// A process that is none of the run's publishes on one of its
/// services (`process`: the service, `pid`: the stranger).
pub const EVENT_STRANGER: u32 = 9;
/// [`crate::ValveRequest`] kinds: reset the valve's latched fault.
pub const VALVE_RESET: u32 = 1;

/// An event kind's word, as summaries and logs write it.
pub fn event_name(kind: u32) -> &'static str {
    match kind {
        EVENT_SWAP => "swap",
        EVENT_SWAP_FAILED => "swap_failed",
        EVENT_CRASH => "crash",
        EVENT_HANG => "hang",
        EVENT_FALLBACK => "fallback",
        EVENT_PLANT_SWITCH => "plant_switch",
        EVENT_MISBEHAVING => "misbehaving",
        EVENT_LIMIT_CYCLE => "limit_cycle",
        EVENT_SPIN => "spin",
        EVENT_STRANGER => "stranger",
        _ => "unknown",
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
