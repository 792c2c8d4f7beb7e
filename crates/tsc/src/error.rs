//! Errors of the TSC crate.
//!
//! A setting is named by its parameter: the name of the builder method that
//! sets it (`window`, `tsc_states`, `reg`, …). [`TscError::describe`] writes
//! the message with the parameters named by the caller, so that a front end
//! can name them its own way (the command line names its flags); `Display`
//! names them as `` `window` `` and a suggested value as `` `window = 4` ``.

use phasekit_emission::EmissionError;
use phasekit_gmm::GmmError;
use phasekit_gmr::GmrError;
use phasekit_hmm::HmmError;
use phasekit_hsmm::HsmmError;
use std::fmt;

/// How a message names a parameter: `(name, None)` the parameter itself,
/// `(name, Some(value))` the parameter set to a value.
pub type ParameterNamer<'a> = &'a dyn Fn(&'static str, Option<&str>) -> String;

/// What went wrong when fitting or applying a method.
///
/// Non-exhaustive: new failure modes may be added without a breaking change.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum TscError {
    /// A setting is outside its domain.
    InvalidSetting {
        /// The parameter (the name of the builder method that sets it).
        name: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The parts of a fitted model do not agree (a model built by hand or read
    /// from a corrupted file).
    InvalidModel {
        /// Which model (`tsc-hmm model`, `gmm-tsc model`, …).
        model: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The detector found no transition segment to train the transition model on.
    NoTransitions {
        /// Shortest run of flagged frames that counts as a segment.
        min_run: usize,
        /// Why there was none.
        cause: NoTransitionCause,
    },
    /// The transition HMM `λ_T` could not be fitted on the transition segments.
    TransitionModel {
        /// States of `λ_T`.
        tsc_states: usize,
        /// The dilation `±w` that made the segments.
        window: usize,
        /// Number of transition segments.
        segments: usize,
        /// Frames in all of them.
        frames: usize,
        /// Frames of the shortest.
        shortest: usize,
        /// Why the fit failed.
        source: Box<TscError>,
    },
    /// G-means kept splitting past the largest count allowed, so its count
    /// would only be that cap, not a choice.
    GMeansAboveRange {
        /// What is counted (`HMM states`, `mixture components`, …).
        counting: &'static str,
        /// The clusters G-means found (a lower bound when `capped`).
        found: usize,
        /// Whether G-means was still splitting when it stopped.
        capped: bool,
        /// The largest count allowed.
        max: usize,
        /// `(asked, why)` when `max` is below the largest count asked for
        /// because the data support no more.
        lowered: Option<(usize, String)>,
    },
    /// Cross-validation: no candidate could be scored.
    NoCandidate {
        /// Every candidate's label and why it failed.
        failures: Vec<(String, TscError)>,
    },
    /// Cross-validation: no held-out frame had every robot value observed.
    NoScorableFrames {
        /// Number of folds.
        folds: usize,
    },
    /// A fold of a cross-validation failed.
    InFold {
        /// The fold (0-based).
        fold: usize,
        /// Number of folds.
        folds: usize,
        /// What failed.
        source: Box<TscError>,
    },
    /// An emission error.
    Emission(EmissionError),
    /// An HMM error.
    Hmm(HmmError),
    /// A mixture error.
    Gmm(GmmError),
    /// A regression error.
    Gmr(GmrError),
    /// An HSMM error.
    Hsmm(HsmmError),
}

/// Why no transition segment was found (see [`TscError::NoTransitions`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum NoTransitionCause {
    /// The detector flagged no frame of any training demonstration.
    NothingFlagged {
        /// `(reg, largest variance)` when the covariance regularisation `reg`
        /// exceeds the variance of every feature of the training data: the base
        /// HMM's states then cannot be told apart.
        swamped: Option<(f64, f64)>,
    },
    /// Frames were flagged, but no run of them reached the minimum length.
    RunsTooShort {
        /// Frames flagged over all demonstrations.
        flagged: usize,
        /// The longest run of flagged frames.
        longest: usize,
    },
    /// The frame mixture (Krishnan's TSC) labels every frame of every
    /// demonstration alike.
    NoLabelChange {
        /// Its number of components.
        components: usize,
    },
}

/// Names a parameter as `` `name` `` and a value as `` `name = value` ``.
fn backticks(name: &'static str, value: Option<&str>) -> String {
    match value {
        None => format!("`{name}`"),
        Some(v) => format!("`{name} = {v}`"),
    }
}

impl TscError {
    /// The message, with every parameter named by `param` (see [`ParameterNamer`]);
    /// `Display` is `describe(&backticks)`. Errors of the lower crates are
    /// printed as they are.
    pub fn describe(&self, param: ParameterNamer<'_>) -> String {
        match self {
            TscError::InvalidSetting { name, reason } => {
                format!("invalid setting {}: {reason}", param(name, None))
            }
            TscError::InvalidModel { model, reason } => format!("invalid {model}: {reason}"),
            TscError::NoTransitions { min_run, cause } => match cause {
                NoTransitionCause::NothingFlagged {
                    swamped: Some((reg, var)),
                } => format!(
                    "no transition frame was found: the covariance regularisation {} exceeds the \
                     variance of every feature (largest {var:.3e}), so the base HMM's states cannot \
                     be told apart and its joint and human-only beliefs never disagree; use a {} \
                     well below {var:.1e} (or standardise the data)",
                    param("reg", Some(&format!("{reg:e}"))),
                    param("reg", None),
                ),
                NoTransitionCause::NothingFlagged { swamped: None } => {
                    "no transition frame was found: the base HMM's joint and human-only filtered \
                     states agree on every training frame"
                        .to_string()
                }
                NoTransitionCause::RunsTooShort { flagged, longest } => format!(
                    "no run of at least {min_run} transition frames was found ({flagged} frames \
                     flagged, the longest run {longest}); a larger {} dilates flagged frames into \
                     longer runs",
                    param("window", None)
                ),
                NoTransitionCause::NoLabelChange { components } => format!(
                    "no transition was found: the frame mixture ({components} components) labels \
                     every frame of every demonstration alike; try more {} or another {}",
                    param("states", None),
                    param("window", None)
                ),
            },
            TscError::TransitionModel {
                tsc_states,
                window,
                segments,
                frames,
                shortest,
                source,
            } => {
                let mut s = format!(
                    "fitting the transition HMM ({tsc_states} states) on {segments} transition \
                     segments ({frames} frames, the shortest {shortest}) failed: {}",
                    source.describe(param)
                );
                if matches!(
                    **source,
                    TscError::Hmm(HmmError::TooFewFrames(_))
                ) || shortest < tsc_states
                {
                    let next = (2 * window).max(window + 2);
                    s.push_str(&format!(
                        "\n  (the transition segments are too few or too short for {tsc_states} \
                         transition states: try a larger window than ±{window} (e.g. {}) or fewer \
                         transition states ({}))",
                        param("window", Some(&next.to_string())),
                        param("tsc_states", None)
                    ));
                }
                s
            }
            TscError::GMeansAboveRange {
                counting,
                found,
                capped,
                max,
                lowered,
            } => format!(
                "G-means found {}{found} Gaussian clusters in the pooled frames, more than the {max} \
                 {counting} allowed{}: the frames are not a mixture of so few Gaussian clusters at \
                 α = 1e-4, and the count would only be the cap, not a choice; set the number \
                 ({}){} or choose by BIC ({})",
                if *capped { "at least " } else { "" },
                lowered.as_ref().map_or(String::new(), |(asked, why)| format!(
                    " (of the {asked} asked for by {}: {why})",
                    param("max_states", None)
                )),
                param("states", None),
                if lowered.is_some() {
                    String::new()
                } else {
                    format!(", allow more ({})", param("max_states", None))
                },
                param("select", Some("bic")),
            ),
            TscError::NoCandidate { failures } => format!(
                "no candidate could be scored: {}",
                failures
                    .iter()
                    .map(|(label, e)| format!("{label}: {}", e.describe(param)))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
            TscError::NoScorableFrames { folds } => format!(
                "no held-out frame of the {folds} folds has every robot value observed: there is nothing to score"
            ),
            TscError::InFold {
                fold,
                folds,
                source,
            } => format!("fold {} of {folds}: {}", fold + 1, source.describe(param)),
            TscError::Emission(e) => e.to_string(),
            TscError::Hmm(e) => e.to_string(),
            TscError::Gmm(e) => e.to_string(),
            TscError::Gmr(e) => e.to_string(),
            TscError::Hsmm(e) => e.to_string(),
        }
    }
}

impl fmt::Display for TscError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.describe(&backticks))
    }
}

impl std::error::Error for TscError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            TscError::TransitionModel { source, .. } | TscError::InFold { source, .. } => {
                Some(&**source)
            }
            // The errors of the lower crates are shown as they are (their own
            // message, not wrapped), so their source is theirs.
            TscError::Emission(e) => std::error::Error::source(e),
            TscError::Hmm(e) => std::error::Error::source(e),
            TscError::Gmm(e) => std::error::Error::source(e),
            TscError::Gmr(e) => std::error::Error::source(e),
            TscError::Hsmm(e) => std::error::Error::source(e),
            _ => None,
        }
    }
}

macro_rules! from_lower {
    ($($variant:ident($t:ty)),*) => {$(
        impl From<$t> for TscError {
            fn from(e: $t) -> Self {
                TscError::$variant(e)
            }
        }
    )*};
}

from_lower!(
    Emission(EmissionError),
    Hmm(HmmError),
    Gmm(GmmError),
    Gmr(GmrError),
    Hsmm(HsmmError)
);

/// Result alias of the TSC crate.
pub type Result<T> = std::result::Result<T, TscError>;
