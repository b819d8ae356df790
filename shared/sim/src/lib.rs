//! The offline closed loop behind `hydractl sim`: the simulated rotator
//! driven by the control stack in one process, its rows and metrics.
//!
//! What it holds: The offline closed loop behind `hydractl sim`: the
//! simulated rotator driven by `ControlStack`, the valve-step experiment, CSV
//! rows and metrics; `foreign`, a rotator written apart from the plant crate
//! (semi-implicit Euler at 20 kHz, parameters ±40 % from the prior,
//! transducer lag and noise of its own, supply ripple, quadratic friction,
//! its own P controller and reference, one hidden effect of its own making or
//! none): data the model tools were not built from, for `bench foreign`.

pub mod foreign;
mod metrics;
mod simulator;

pub use simulator::{
    build_plant, simulate, simulate_streaming, simulate_valve_steps, write_csv, CsvRows, Record, SimError,
    SimulationRun, Summary,
};
