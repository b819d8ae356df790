//! Identification from measured data: loading and checking it, and fitting
//! models to it. No IPC here.

pub mod data;
pub mod friction_map;
pub mod loop_shaping;
pub mod mechanics;
pub mod pid_tune;
pub mod spectral;
pub mod tf;

pub use data::{DataError, Dataset};
pub use tf::{fit_percent, identify_tf, IdentError, Method, NoiseModel, TfFit, TfOptions};
pub mod greybox;
pub mod lm;
