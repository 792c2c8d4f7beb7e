//! The command's error type: a message for the user, and the exit status.

use std::fmt;

/// An error reported to the user as `phasekit: error: MESSAGE`, exit status 1.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CliError {
    /// What went wrong, with where (file, row, column) when known.
    pub message: String,
}

impl CliError {
    /// An error with this message.
    pub fn new(message: impl Into<String>) -> Self {
        CliError {
            message: message.into(),
        }
    }

    /// The same error, prefixed by `context: `.
    pub fn context(self, context: impl fmt::Display) -> Self {
        CliError {
            message: format!("{context}: {}", self.message),
        }
    }
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for CliError {}

macro_rules! from_display {
    ($($t:ty),*) => {$(
        impl From<$t> for CliError {
            fn from(e: $t) -> Self {
                CliError::new(e.to_string())
            }
        }
    )*};
}

from_display!(
    crate::data::DataError,
    phasekit_tsc::TscError,
    phasekit_emission::EmissionError,
    phasekit_gmr::GmrError,
    String,
    &str
);

/// Result alias of the command.
pub type Result<T> = std::result::Result<T, CliError>;

/// Bails out with a formatted [`CliError`].
#[macro_export]
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err($crate::error::CliError::new(format!($($arg)*)))
    };
}
