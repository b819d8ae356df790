//! The offline closed loop behind `hydractl sim`: the simulated rotator
//! driven by the control stack in one process, its rows and metrics.

pub mod foreign;
pub mod metrics;
pub mod simulator;

pub use simulator::{
    build_plant, simulate, simulate_streaming, simulate_valve_steps, write_csv, CsvRows, Record, SimError,
    SimulationRun, Summary, MAX_CYCLES, MAX_KEPT_CYCLES,
};
