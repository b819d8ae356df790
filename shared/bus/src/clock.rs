//! CLOCK_MONOTONIC in nanoseconds: one time base for every process on the
//! machine, so that a sample's timestamps compare across processes.

use nix::time::{clock_gettime, ClockId};

pub fn now_ns() -> u64 {
    // CLOCK_MONOTONIC cannot fail on Linux with a valid clock id; 0 would
    // only mark a sample as ancient, never crash the loop.
    clock_gettime(ClockId::CLOCK_MONOTONIC)
        .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
        .unwrap_or(0)
}
