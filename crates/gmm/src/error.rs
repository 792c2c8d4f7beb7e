//! Errors of the GMM crate.

use phasekit_emission::EmissionError;
use phasekit_hmm::HmmError;
use thiserror::Error;

/// What went wrong when building, fitting or selecting a mixture.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GmmError {
    /// A parameter is outside its domain.
    #[error("invalid parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Which parameter.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// An emission error.
    #[error(transparent)]
    Emission(#[from] EmissionError),
    /// An HMM error (model selection over HMM state counts).
    #[error(transparent)]
    Hmm(#[from] HmmError),
    /// Too few frames for the requested number of components.
    #[error("too few frames: {0}")]
    TooFewFrames(String),
    /// A thread pool could not be built.
    #[error("cannot build a thread pool: {0}")]
    ThreadPool(String),
}

/// Result alias of the GMM crate.
pub type Result<T> = std::result::Result<T, GmmError>;
