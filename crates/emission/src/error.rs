//! Errors of the emission crate. Every variant says what is wrong and where
//! (state, component, frame, column) so that a caller can point at the cause.

use thiserror::Error;

/// What went wrong when building, evaluating or re-estimating an emission model.
///
/// `#[non_exhaustive]`: match with a wildcard arm, new variants may come.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
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
    /// A plug-in distribution's own error (e.g. from [`crate::StateDistribution::fit`]).
    #[error("{emission}{}: {message}", state.map(|s| format!(", state {s}")).unwrap_or_default())]
    Plugin {
        /// The distribution that failed (its type or a name its author chose).
        emission: String,
        /// The state, when known (the per-state route fills it in).
        state: Option<usize>,
        /// What went wrong, in the author's words.
        message: String,
    },
}

impl EmissionError {
    /// A plug-in's own error, without a state (the per-state route adds it).
    pub fn plugin(emission: impl Into<String>, message: impl Into<String>) -> Self {
        EmissionError::Plugin {
            emission: emission.into(),
            state: None,
            message: message.into(),
        }
    }

    /// The same error located at `state` (and `component`, for a mixture's
    /// inner emission), when it is about a state: a per-state route or a
    /// mixture learns the index only after the inner call failed.
    pub fn at_state(self, state: usize, component: Option<usize>) -> Self {
        match self {
            EmissionError::NotPositiveDefinite { detail, .. } => {
                EmissionError::NotPositiveDefinite {
                    state,
                    component,
                    detail,
                }
            }
            EmissionError::Plugin {
                emission, message, ..
            } => EmissionError::Plugin {
                emission,
                state: Some(state),
                message,
            },
            other => other,
        }
    }
}

/// A number as a reader wants it in a message: `0`, `275`, `0.01`, `1.5e-14`.
pub fn readable(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let a = x.abs();
    if (1e-3..1e6).contains(&a) {
        // Four significant digits, trailing zeros dropped.
        let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{x:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        let s = format!("{x:.3e}");
        // 1.500e-14 -> 1.5e-14
        match s.split_once('e') {
            Some((m, e)) if m.contains('.') => {
                format!("{}e{e}", m.trim_end_matches('0').trim_end_matches('.'))
            }
            _ => s,
        }
    }
}

fn location(state: usize, component: Option<usize>) -> String {
    match component {
        Some(c) => format!("state {state}, component {c}"),
        None => format!("state {state}"),
    }
}

/// Result alias of the emission crate.
pub type Result<T> = std::result::Result<T, EmissionError>;
