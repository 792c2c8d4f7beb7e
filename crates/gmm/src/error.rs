//! Errors of the GMM crate.

use phasekit_emission::EmissionError;
use thiserror::Error;

/// What went wrong when building, fitting or selecting a mixture.
///
/// Non-exhaustive: new failure modes may be added without a breaking change.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
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
    /// Too few frames for the requested number of components.
    #[error("too few frames: {0}")]
    TooFewFrames(String),
    /// A thread pool could not be built.
    #[error("cannot build a thread pool: {0}")]
    ThreadPool(String),
}

/// Result alias of the GMM crate.
pub type Result<T> = std::result::Result<T, GmmError>;
