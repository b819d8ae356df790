//! Configuration, the control stack's stages and the offline closed-loop
//! simulator behind `hydractl sim`.

pub mod config;
pub mod metrics;
pub mod simulator;
pub mod stack;

pub use config::{
    Config, ConfigError, PositionVariant, RestartPolicy, RestartRule, StallPolicy, Structure, SupervisorConfig,
    TorqueVariant, SUPERVISED_PROCESSES,
};
pub use hydractl_control::Reference;
pub use simulator::{build_plant, simulate, simulate_valve_steps, write_csv, Record, SimError, SimulationRun, Summary};
pub use stack::ControlStack;
