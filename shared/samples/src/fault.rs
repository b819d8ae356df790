//! Fault flags of the valve's state.

/// No fresh command: older than the configured number of periods.
pub const STALE: u32 = 1 << 0;
/// The command was NaN or infinite.
pub const NOT_FINITE: u32 = 1 << 1;
/// The command was outside [-1, 1].
pub const OUT_OF_RANGE: u32 = 1 << 2;
/// The sensor sample the command derives from was not valid.
pub const INVALID_SENSOR: u32 = 1 << 3;
/// The requested commands limit-cycle: neutral until they stop.
pub const LIMIT_CYCLE: u32 = 1 << 4;
/// The valve process is starting (before the loop's first command) or
/// stopping: neutral, answering no reading of a closed loop (its
/// `sensor_seq` is the newest it knew, if any).
pub const OFF: u32 = 1 << 5;
/// The valve device (on CAN) has a latched fault: neutral until a
/// person resets it (`hydractl valve reset`).
pub const DEVICE: u32 = 1 << 6;

/// Each flag with its name, as summaries and status write it.
pub const NAMES: [(u32, &str); 7] = [
    (STALE, "stale"),
    (NOT_FINITE, "not_finite"),
    (OUT_OF_RANGE, "out_of_range"),
    (INVALID_SENSOR, "invalid_sensor"),
    (LIMIT_CYCLE, "limit_cycle"),
    (OFF, "off"),
    (DEVICE, "device"),
];
