//! Errors of the GMR crate.

use phasekit_emission::EmissionError;
use phasekit_gmm::GmmError;
use phasekit_hmm::HmmError;
use phasekit_hsmm::HsmmError;
use thiserror::Error;

/// What went wrong when building or running a regression.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GmrError {
    /// Input and output dimensions are invalid (empty, repeated, overlapping or out of range).
    #[error("invalid input/output dimensions: {0}")]
    InvalidDims(String),
    /// The input block of a state's covariance is not positive definite.
    #[error("state {state}: the input block of the covariance is not positive definite, cannot condition on it")]
    SingularInput {
        /// State (component) index.
        state: usize,
    },
    /// An emission error.
    #[error(transparent)]
    Emission(#[from] EmissionError),
    /// An HMM error.
    #[error(transparent)]
    Hmm(#[from] HmmError),
    /// A mixture error.
    #[error(transparent)]
    Gmm(#[from] GmmError),
    /// An HSMM error.
    #[error(transparent)]
    Hsmm(#[from] HsmmError),
}

/// Result alias of the GMR crate.
pub type Result<T> = std::result::Result<T, GmrError>;
