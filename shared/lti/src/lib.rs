//! Linear time-invariant systems, the shared vocabulary of the plant's
//! linearization, the controllers realized from transfer functions, and
//! identification.
//!
//! Conventions: polynomials are coefficient vectors in descending powers of
//! `s` (or `z`), as MATLAB writes them; continuous time unless a type says
//! `Discrete`.
//!
//! What it holds: Polynomials, transfer functions, state space (balanced
//! eigenvalues, determinant-lemma transfer functions), ZOH discretization,
//! series connection, frequency response, closed-loop poles, continuous
//! Riccati equations by the matrix sign function (`riccati`), analytic step
//! responses, and `DiscreteSiso`, an allocation-free discrete system for
//! real-time loops.

mod discrete;
mod poly;
mod riccati;
mod state_space;
mod transfer_function;

pub use discrete::DiscreteSiso;
pub use nalgebra::Complex;
pub use poly::{poly_eval, poly_from_roots, poly_mul, poly_roots};
pub use riccati::solve_care;
pub use state_space::StateSpace;
pub use transfer_function::TransferFunction;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LtiError {
    #[error("the denominator is empty or its leading coefficient is zero")]
    InvalidDenominator,
    #[error("the transfer function is improper: numerator degree {num} > denominator degree {den}")]
    Improper { num: usize, den: usize },
    #[error("dimension mismatch: {0}")]
    Dimension(String),
    #[error("the sample time must be positive and finite, got {0}")]
    InvalidSampleTime(f64),
    #[error("a coefficient is not finite")]
    NotFinite,
    #[error("Riccati equation: {0}")]
    Riccati(String),
}
