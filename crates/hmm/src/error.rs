//! Errors of the HMM crate.

use phasekit_emission::EmissionError;
use thiserror::Error;

/// What went wrong when building, evaluating or fitting an HMM.
///
/// Non-exhaustive: new failure modes may be added without a breaking change.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum HmmError {
    /// A parameter is outside its domain (names the parameter and the index).
    #[error("invalid parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Which parameter.
        name: &'static str,
        /// What is wrong, with the offending index.
        reason: String,
    },
    /// An emission error, with the sequence it happened on when known.
    #[error("{}{source}", match .sequence { Some(k) => format!("sequence {k}: "), None => String::new() })]
    Emission {
        /// Index of the sequence being processed, if any.
        sequence: Option<usize>,
        /// The underlying error.
        source: EmissionError,
    },
    /// A sequence has no frames.
    #[error("sequence {sequence} is empty")]
    EmptySequence {
        /// Index of the sequence.
        sequence: usize,
    },
    /// No data were given.
    #[error("no sequences given")]
    NoData,
    /// The model gives the sequence probability zero (e.g. a forbidden transition is needed).
    #[error(
        "sequence {sequence} has probability zero under the model (first impossible frame {frame})"
    )]
    ImpossibleSequence {
        /// Index of the sequence.
        sequence: usize,
        /// First frame at which the forward probability became zero.
        frame: usize,
    },
    /// Too few frames to initialise or fit the requested number of states.
    #[error("too few frames: {0}")]
    TooFewFrames(String),
    /// A thread pool could not be built.
    #[error("cannot build a thread pool: {0}")]
    ThreadPool(String),
}

impl From<EmissionError> for HmmError {
    fn from(source: EmissionError) -> Self {
        HmmError::Emission {
            sequence: None,
            source,
        }
    }
}

impl HmmError {
    /// Attaches the index of the sequence on which an emission error happened.
    pub fn in_sequence(self, k: usize) -> Self {
        match self {
            HmmError::Emission {
                sequence: None,
                source,
            } => HmmError::Emission {
                sequence: Some(k),
                source,
            },
            HmmError::ImpossibleSequence { frame, .. } => {
                HmmError::ImpossibleSequence { sequence: k, frame }
            }
            HmmError::EmptySequence { .. } => HmmError::EmptySequence { sequence: k },
            other => other,
        }
    }
}

/// Result alias of the HMM crate.
pub type Result<T> = std::result::Result<T, HmmError>;
