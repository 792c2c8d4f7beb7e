//! Errors of the TSC crate.

use phasekit_emission::EmissionError;
use phasekit_gmm::GmmError;
use phasekit_gmr::GmrError;
use phasekit_hmm::HmmError;
use thiserror::Error;

/// What went wrong when fitting or applying a method.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TscError {
    /// A setting is outside its domain.
    #[error("invalid setting `{name}`: {reason}")]
    InvalidSetting {
        /// Which setting.
        name: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The detector found no transition segment to train the transition model on.
    #[error("no transition segment of at least {min_len} frames was found in the training data; try a larger --window or fewer --tsc-states")]
    NoTransitions {
        /// Minimum run length required.
        min_len: usize,
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
    /// A regression error.
    #[error(transparent)]
    Gmr(#[from] GmrError),
}

/// Result alias of the TSC crate.
pub type Result<T> = std::result::Result<T, TscError>;
