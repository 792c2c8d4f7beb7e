//! Errors of the HSMM crate. Every variant says what is wrong and where
//! (parameter, state, sequence, frame), so that a caller can point at the cause.

use phasekit_emission::EmissionError;
use thiserror::Error;

/// What went wrong when building, evaluating or fitting an HSMM.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HsmmError {
    /// A parameter is outside its domain (names the parameter and the index).
    #[error("invalid parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Which parameter.
        name: &'static str,
        /// What is wrong, with the offending state or index.
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
    /// The model gives the sequence probability zero.
    #[error(
        "sequence {sequence} has probability zero under the model (first impossible frame {frame}); \
         a segment lasts at most max_duration = {max_duration} frames, a forbidden transition \
         (a zero of the start or transition probabilities, or a terminal state) cannot be taken, \
         and with censoring `EndsWithSegment` the last frame must end a segment"
    )]
    ImpossibleSequence {
        /// Index of the sequence.
        sequence: usize,
        /// First frame at which every explanation of the data so far had probability zero.
        frame: usize,
        /// The model's maximum duration.
        max_duration: usize,
    },
    /// Too few frames to initialise or fit the requested number of states.
    #[error("too few frames: {0}")]
    TooFewFrames(String),
    /// A thread pool could not be built.
    #[error("cannot build a thread pool: {0}")]
    ThreadPool(String),
}

impl From<EmissionError> for HsmmError {
    fn from(source: EmissionError) -> Self {
        HsmmError::Emission {
            sequence: None,
            source,
        }
    }
}

impl HsmmError {
    /// Attaches the index of the sequence on which the error happened.
    pub fn in_sequence(self, k: usize) -> Self {
        match self {
            HsmmError::Emission {
                sequence: None,
                source,
            } => HsmmError::Emission {
                sequence: Some(k),
                source,
            },
            HsmmError::ImpossibleSequence {
                frame,
                max_duration,
                ..
            } => HsmmError::ImpossibleSequence {
                sequence: k,
                frame,
                max_duration,
            },
            HsmmError::EmptySequence { .. } => HsmmError::EmptySequence { sequence: k },
            other => other,
        }
    }
}

/// Result alias of the HSMM crate.
pub type Result<T> = std::result::Result<T, HsmmError>;

/// Shorthand for an [`HsmmError::InvalidParameter`].
pub(crate) fn invalid(name: &'static str, reason: impl Into<String>) -> HsmmError {
    HsmmError::InvalidParameter {
        name,
        reason: reason.into(),
    }
}
