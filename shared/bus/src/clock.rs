//! CLOCK_MONOTONIC in nanoseconds: one time base for every process on the
//! machine, so that a sample's timestamps compare across processes. The
//! wall clock only for what outlives a boot (a latched fault's time).

use nix::time::{clock_gettime, ClockId};

pub fn now_ns() -> u64 {
    // CLOCK_MONOTONIC cannot fail on Linux with a valid clock id; 0 would
    // only mark a sample as ancient, never crash the loop.
    clock_gettime(ClockId::CLOCK_MONOTONIC)
        .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
        .unwrap_or(0)
}

/// The wall clock, seconds since the Unix epoch (0 before it).
pub fn unix_now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}
