//! Identification from measured data: loading and checking it, and fitting
//! models to it. No IPC here.
//!
//! What it holds: Measured data from CSV with every defect named by file,
//! line and column; continuous transfer functions by instrumental-variable
//! ARX and output-error / prediction-error refinement; the papers' other
//! methods: H∞ loop shaping (Glover–McFarlane) with the loop's margins
//! (`loop_shaping`), the mechanics from P-controlled runs (`mechanics`),
//! Welch spectra and the empirical transfer function (`spectral`), the
//! pseudo-friction map from valve steps (`friction_map`), PID gains by IAE
//! (`pid_tune`); the grey-box model of the rotator (`greybox`, with `shadow`:
//! the model compared over a sliding window of live data and a CUSUM on each
//! part's segment residual, standardized by the validation spread the model
//! file keeps): its hydraulic and mechanical parts driven by measured
//! coupling signals and compared by multiple shooting, the fit
//! (Levenberg–Marquardt, `lm`, Huber loss), `compare` (fit per output,
//! residual by part and regime, `resid`'s tests), `diagnose` (every
//! catalog effect tried, refitted and ranked, effects the record cannot
//! tell apart named together; the parts fitted follow the sensors the
//! record has: hydraulic + mechanical, the whole command → angle without
//! pressures, mechanical alone with a measured torque; `Progress` reports
//! each fit as it finishes) and `learn` (diagnose and add until nothing
//! more helps).

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
