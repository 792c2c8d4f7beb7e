//! Errors of the recognition crate.

use phasekit_emission::EmissionError;
use phasekit_gmr::GmrError;
use phasekit_hmm::HmmError;
use phasekit_tsc::TscError;
use thiserror::Error;

/// What went wrong when building a library or recognising an interaction.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RecognitionError {
    /// The actions do not form a usable library (too few, unnamed, duplicated,
    /// of different dimensions, or a part that disagrees with the others).
    #[error("invalid library: {0}")]
    InvalidLibrary(String),
    /// A setting is outside its domain.
    #[error("invalid setting `{name}`: {reason}")]
    InvalidSetting {
        /// Which setting.
        name: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// Fitting or applying one action's model failed.
    #[error("action `{action}`: {source}")]
    Action {
        /// The action's name.
        action: String,
        /// What failed.
        source: TscError,
    },
    /// A frame or buffer has the wrong number of values.
    #[error("{context}: {found} values, expected {expected}")]
    DimensionMismatch {
        /// What was being read.
        context: &'static str,
        /// Values expected.
        expected: usize,
        /// Values found.
        found: usize,
    },
    /// A value is infinite (NaN is allowed: it marks a missing value).
    #[error(
        "{context}: value {index} is {value}, not a finite number (NaN marks a missing value)"
    )]
    NonFinite {
        /// What was being read.
        context: &'static str,
        /// 0-based index of the value in the frame.
        index: usize,
        /// The value.
        value: f64,
    },
    /// The frame has probability zero under every action of the library.
    #[error("frame {frame} is impossible under every action of the library (probability zero); nothing was updated: skip it or reset the recogniser")]
    ImpossibleFrame {
        /// 0-based frame index since the last reset.
        frame: usize,
    },
    /// An error of the TSC crate (methods, models, predictors).
    #[error(transparent)]
    Tsc(#[from] TscError),
    /// An HMM error.
    #[error(transparent)]
    Hmm(#[from] HmmError),
    /// A regression error.
    #[error(transparent)]
    Gmr(#[from] GmrError),
    /// An emission error.
    #[error(transparent)]
    Emission(#[from] EmissionError),
}

/// Result alias of the recognition crate.
pub type Result<T> = std::result::Result<T, RecognitionError>;

/// Checks that `frame` has `expected` values, none infinite.
pub(crate) fn check_frame(context: &'static str, frame: &[f64], expected: usize) -> Result<()> {
    if frame.len() != expected {
        return Err(RecognitionError::DimensionMismatch {
            context,
            expected,
            found: frame.len(),
        });
    }
    if let Some(index) = frame.iter().position(|v| v.is_infinite()) {
        return Err(RecognitionError::NonFinite {
            context,
            index,
            value: frame[index],
        });
    }
    Ok(())
}
