//! Each live process's own loop, one module per process: the binaries in
//! `src/bin/` only call `run`. Kept in the library so that the iceoryx2
//! ports every process opens are compiled once, not once per binary; left
//! out of the library's unit-test build, which has no use for them.

pub mod canbus;
pub mod friction;
pub mod position;
pub mod recorder;
pub mod sensor;
pub mod shadow;
pub mod torque;
pub mod valve;
mod valve_desk;
