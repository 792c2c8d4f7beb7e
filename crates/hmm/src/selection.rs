//! Choosing the number of HMM states: BIC over candidate counts, and the
//! largest count the data can support.
//!
//! A G-means count of HMM states needs the mixture crate's G-means and this
//! crate's Baum-Welch; it lives above both, in `phasekit-tsc`.

use crate::error::{HmmError, Result};
use crate::fit::BaumWelch;
use phasekit_emission::{Emission, SequenceSet};
use std::fmt;

/// The BIC of every candidate number of states and the one with the lowest.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct StateSelection {
    /// The number of states with the lowest BIC.
    pub best: usize,
    /// `(S, BIC(S))` for every candidate that could be fitted, in the order tried.
    pub scores: Vec<(usize, f64)>,
    /// `(S, why)` for every candidate that could not be fitted.
    pub failures: Vec<(usize, HmmError)>,
}

/// BIC `−2 log p(X | λ̂_S) + p_S log N` ([`crate::Hmm::bic`]) of an HMM fitted by
/// `bw` for every state count `S` in `candidates`; `template(S)` gives the
/// emission structure with `S` states (its parameters are ignored).
///
/// A candidate that cannot be built or fitted is kept in
/// [`StateSelection::failures`] with its error; the others compete. Errors
/// when no candidate is given, or when none could be fitted (naming each
/// candidate and why).
pub fn select_states_bic<E: Emission>(
    bw: &BaumWelch,
    template: impl Fn(usize) -> phasekit_emission::Result<E>,
    data: &SequenceSet,
    candidates: impl IntoIterator<Item = usize>,
) -> Result<StateSelection> {
    let (mut scores, mut failures) = (Vec::new(), Vec::new());
    for s in candidates {
        let bic = template(s)
            .map_err(HmmError::from)
            .and_then(|t| bw.fit(&t, data))
            .and_then(|f| f.model.bic(data));
        match bic {
            Ok(bic) => scores.push((s, bic)),
            Err(e) => failures.push((s, e)),
        }
    }
    let best = scores
        .iter()
        .filter(|(_, b)| b.is_finite())
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(s, _)| *s);
    match best {
        Some(best) => Ok(StateSelection {
            best,
            scores,
            failures,
        }),
        None if scores.is_empty() && failures.is_empty() => Err(HmmError::InvalidParameter {
            name: "candidates",
            reason: "no candidate number of states was given".into(),
        }),
        None => Err(HmmError::InvalidParameter {
            name: "candidates",
            reason: format!(
                "no candidate number of states could be fitted with a finite BIC: {}",
                scores
                    .iter()
                    .map(|(s, b)| format!("{s} states: BIC {b}"))
                    .chain(failures.iter().map(|(s, e)| format!("{s} states: {e}")))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        }),
    }
}

/// Why no more states can be fitted to a data set (see [`max_supported_states`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum StateLimit {
    /// Every sequence needs at least one frame per state, and this one has only `frames`.
    ShortestSequence {
        /// Index of the shortest sequence.
        sequence: usize,
        /// Its number of frames.
        frames: usize,
    },
    /// One more state would give the model `parameters` free parameters, more
    /// than the `frames` training frames.
    Parameters {
        /// Free parameters `p(S + 1)` of the next count.
        parameters: usize,
        /// Training frames `N`.
        frames: usize,
    },
}

impl fmt::Display for StateLimit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StateLimit::ShortestSequence { sequence, frames } => write!(
                f,
                "sequence {sequence} has {frames} frames and every sequence needs one frame per state"
            ),
            StateLimit::Parameters { parameters, frames } => write!(
                f,
                "one more state would give {parameters} free parameters, more than the {frames} training frames"
            ),
        }
    }
}

/// The largest number of states an HMM with emissions `template(S)` can have
/// on `data`, and what limits it.
///
/// Two limits, whichever is smaller:
/// * every sequence needs at least one frame per state (temporal k-bins gives
///   every state a bin of every sequence): `S ≤ min_k T_k`;
/// * the model may not have more free parameters than there are frames,
///   `p(S) = (S − 1) + S (S − 1) + p_B(S) ≤ N` (hmmlearn's count,
///   [`crate::Hmm::n_parameters_dense`], with `p_B` the emission's
///   [`Emission::n_parameters`]). Beyond it the data cannot determine the
///   parameters, BIC's penalty `p log N` alone outweighs any likelihood, and
///   every candidate costs `O(S²)` per frame and iteration.
///
/// `p(S)` grows with `S`, so a binary search builds `O(log T)` templates.
/// Returns `(0, limit)` when even one state is too many. Errors when `data`
/// is empty or a template cannot be built.
pub fn max_supported_states<E: Emission>(
    template: impl Fn(usize) -> phasekit_emission::Result<E>,
    data: &SequenceSet,
) -> Result<(usize, StateLimit)> {
    let (sequence, shortest) = data
        .lengths()
        .enumerate()
        .min_by_key(|(_, len)| *len)
        .ok_or(HmmError::NoData)?;
    let frames = data.total_frames();
    let parameters = |s: usize| -> Result<usize> {
        let chain = (s - 1) + s * (s - 1);
        Ok(chain + template(s)?.n_parameters())
    };
    // Largest S in 1..=shortest with p(S) ≤ N (0 if none).
    let (mut lo, mut hi) = (0, shortest);
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        if parameters(mid)? <= frames {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    let limit = if lo == shortest {
        StateLimit::ShortestSequence {
            sequence,
            frames: shortest,
        }
    } else {
        StateLimit::Parameters {
            parameters: parameters(lo + 1)?,
            frames,
        }
    };
    Ok((lo, limit))
}
