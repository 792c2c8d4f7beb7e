//! Errors of the emission crate. Every variant says what is wrong and where
//! (state, component, frame, column) so that a caller can point at the cause.

use thiserror::Error;

/// What went wrong when building, evaluating or re-estimating an emission model.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum EmissionError {
    /// A parameter given to a constructor is outside its domain.
    #[error("invalid parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Name of the parameter (`means`, `covariances`, `probabilities`, …).
        name: &'static str,
        /// What is wrong with it, including the offending index where there is one.
        reason: String,
    },
    /// Two shapes that must agree do not.
    #[error("dimension mismatch in {context}: expected {expected}, found {found}")]
    DimensionMismatch {
        /// Where the mismatch was found.
        context: &'static str,
        /// The size that was required.
        expected: usize,
        /// The size that was given.
        found: usize,
    },
    /// A value in the data cannot be used (not finite, not a valid symbol or count).
    #[error("frame {frame}, column {column}: {reason} (value {value})")]
    InvalidValue {
        /// Zero-based index of the frame (row) in the sequence.
        frame: usize,
        /// Zero-based column (dimension) index.
        column: usize,
        /// The offending value.
        value: f64,
        /// Why it is refused.
        reason: &'static str,
    },
    /// A covariance matrix is not positive definite, even after regularisation.
    #[error("{}: covariance is not positive definite{detail}; increase the covariance regularisation (e.g. reg 1e-6 relative to the data's variance) or allow jitter", location(*.state, *.component))]
    NotPositiveDefinite {
        /// The state whose covariance failed.
        state: usize,
        /// The mixture component inside that state, if the emission is a mixture.
        component: Option<usize>,
        /// Extra context (e.g. which regularisation was already added).
        detail: String,
    },
    /// A list of dimensions for a marginal is empty, repeats a dimension or is out of range.
    #[error("invalid marginal dimensions {dims:?} for a {dim}-dimensional emission: {reason}")]
    InvalidDims {
        /// The requested dimensions.
        dims: Vec<usize>,
        /// Dimension of the emission.
        dim: usize,
        /// What is wrong.
        reason: &'static str,
    },
    /// Sufficient statistics of a different shape were merged or used.
    #[error("sufficient statistics do not match the model: {0}")]
    StatsMismatch(String),
    /// The operation is not defined for this emission (e.g. a marginal of a categorical).
    #[error("unsupported operation: {0}")]
    Unsupported(String),
}

fn location(state: usize, component: Option<usize>) -> String {
    match component {
        Some(c) => format!("state {state}, component {c}"),
        None => format!("state {state}"),
    }
}

/// Result alias of the emission crate.
pub type Result<T> = std::result::Result<T, EmissionError>;
