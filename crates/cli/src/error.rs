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
    phasekit_emission::EmissionError,
    phasekit_gmr::GmrError,
    String,
    &str
);

/// The library's errors name a setting by its parameter (`window`,
/// `tsc_states`); the command names it by its flag (`--window`,
/// `--tsc-states`), which is also the `NAME:key=value` key without the dashes.
impl From<phasekit_tsc::TscError> for CliError {
    fn from(e: phasekit_tsc::TscError) -> Self {
        CliError::new(e.describe(&flag))
    }
}

/// The flag that sets the library parameter `param` (`tsc_states` →
/// `--tsc-states`), with `value` when given (`--window 4`); a parameter
/// without a flag keeps the library's name in backticks.
pub fn flag(param: &'static str, value: Option<&str>) -> String {
    const FLAGS: [&str; 13] = [
        "states",
        "tsc_states",
        "window",
        "reg",
        "max_iter",
        "tol",
        "restarts",
        "seed",
        "select",
        "max_states",
        "rho",
        "time_clusters",
        "method",
    ];
    let name = match param {
        p if FLAGS.contains(&p) => format!("--{}", p.replace('_', "-")),
        "roles" => "--human/--robot".to_string(),
        p => return value.map_or(format!("`{p}`"), |v| format!("`{p} = {v}`")),
    };
    match value {
        None => name,
        Some(v) => format!("{name} {v}"),
    }
}

/// Result alias of the command.
pub type Result<T> = std::result::Result<T, CliError>;

/// Bails out with a formatted [`CliError`].
#[macro_export]
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err($crate::error::CliError::new(format!($($arg)*)))
    };
}

#[cfg(test)]
mod tests {
    use super::{flag, CliError};
    use phasekit_tsc::{NoTransitionCause, TscError};

    #[test]
    fn library_parameters_are_named_by_their_flags() {
        assert_eq!(flag("tsc_states", None), "--tsc-states");
        assert_eq!(flag("window", Some("4")), "--window 4");
        assert_eq!(flag("max_states", None), "--max-states");
        assert_eq!(flag("roles", None), "--human/--robot");
        // A parameter without a flag keeps the library's name.
        assert_eq!(flag("fraction", None), "`fraction`");
        assert_eq!(flag("min_run", Some("2")), "`min_run = 2`");

        let e = TscError::InvalidSetting {
            name: "window",
            reason: "it must lie in 1..=64, got 0".into(),
        };
        assert_eq!(
            CliError::from(e).message,
            "invalid setting --window: it must lie in 1..=64, got 0"
        );
        let swamped = TscError::NoTransitions {
            min_run: 2,
            cause: NoTransitionCause::NothingFlagged {
                swamped: Some((1e10, 0.02)),
            },
        };
        let msg = CliError::from(swamped).message;
        assert!(
            msg.contains("--reg 1e10 exceeds") && msg.contains("use a --reg well below 2.0e-2"),
            "{msg}"
        );
        assert!(!msg.contains("window"), "{msg}");
        let short = TscError::NoTransitions {
            min_run: 2,
            cause: NoTransitionCause::RunsTooShort {
                flagged: 5,
                longest: 1,
            },
        };
        assert!(CliError::from(short).message.contains("a larger --window"));
        let gmeans = TscError::GMeansAboveRange {
            counting: "HMM states",
            found: 11,
            capped: true,
            max: 10,
            lowered: None,
        };
        let msg = CliError::from(gmeans).message;
        assert!(
            msg.contains("at least 11")
                && msg.contains("allow more (--max-states)")
                && msg.contains("(--select bic)"),
            "{msg}"
        );
        // When the data support fewer than asked for, it says so (not "allow more").
        let lowered = TscError::GMeansAboveRange {
            counting: "HMM states",
            found: 21,
            capped: true,
            max: 20,
            lowered: Some((30, "one more state would give too many parameters".into())),
        };
        let msg = CliError::from(lowered).message;
        assert!(
            msg.contains(
                "more than the 20 HMM states allowed (of the 30 asked for by --max-states: one more state"
            ) && !msg.contains("allow more"),
            "{msg}"
        );
    }
}
