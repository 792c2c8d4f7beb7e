//! Capabilities beyond [`Emission`], each a small trait, for the compositions
//! built on top of the HMM and the mixture:
//!
//! * [`Marginal`]: the same states restricted to some dimensions (the
//!   human-only filter of a joint human–robot model);
//! * [`ConcatStates`]: the states of two emissions of one kind side by side
//!   (the TSC-HMM's union of a base model and a transition model);
//! * [`Conditional`]: per state, the distribution of output dimensions given
//!   input dimensions, precomputed once per split (Gaussian mixture
//!   regression), evaluated by a [`ConditionalSplit`] without allocation.
//!
//! An emission implements the ones it can. The per-state route
//! ([`crate::PerState`]) offers them through the optional methods and traits
//! of [`crate::StateDistribution`].

use crate::error::Result;
use crate::Emission;
use std::fmt::Debug;

/// The same states restricted to the dimensions `dims` (in that order):
/// `b_i(x_dims) = ∫ b_i(x) dx_rest`.
pub trait Marginal: Emission {
    /// The marginal emission on `dims` (non-empty, in range, no repeats;
    /// [`crate::check_dims`] checks them).
    fn marginal(&self, dims: &[usize]) -> Result<Self>;
}

/// The states of `self` followed by those of `other`, as one emission of the
/// same kind (`S_a + S_b` states of one dimension).
///
/// Errors when the two cannot be one emission of this type (different
/// dimension, number of mixture components or symbols, or two different
/// shared covariances).
pub trait ConcatStates: Emission {
    /// `self`'s states `0..S_a`, then `other`'s as `S_a..S_a + S_b`.
    fn concat_states(&self, other: &Self) -> Result<Self>;
}

/// Regression: per state, the conditional distribution of the output
/// dimensions `O` given the input dimensions `I`.
pub trait Conditional: Emission {
    /// What is precomputed for one `(input, output)` split.
    type Split: ConditionalSplit;

    /// Precomputes the conditionals of `output` given `input` (each in range,
    /// no repeats; the two disjoint; `output` non-empty). An empty `input`
    /// gives the outputs' marginals (what a regression predicts for a frame
    /// whose inputs are all missing); an emission that cannot do that
    /// returns an error.
    fn conditional(&self, input: &[usize], output: &[usize]) -> Result<Self::Split>;
}

/// The conditionals of one `(input, output)` split of every state, evaluated
/// without allocation (the `&mut self` is for the split's own scratch; clone
/// a split per thread).
///
/// Every method checks the lengths of its buffers and the state index (an
/// error, never a panic); the input must be complete and finite.
pub trait ConditionalSplit: Clone + Debug + Send + Sync {
    /// Number of states `S`.
    fn n_states(&self) -> usize;

    /// The input dimensions `I`, in the order the input values are given.
    fn input_dims(&self) -> &[usize];

    /// The output dimensions `O`, in the order the outputs are written.
    fn output_dims(&self) -> &[usize];

    /// `log b_i(x_I)`: state `state`'s marginal log-density of the input (the
    /// weight a regression gives the state for this input).
    fn input_log_density(&mut self, state: usize, input: &[f64]) -> Result<f64>;

    /// `E[x_O | x_I, state]` into `mean` (`|O|`) and `Cov[x_O | x_I, state]`
    /// into `covariance` (`|O| × |O|`, row-major).
    fn predict(
        &mut self,
        state: usize,
        input: &[f64],
        mean: &mut [f64],
        covariance: &mut [f64],
    ) -> Result<()>;
}

/// Checks an `(input, output)` split of a `dim`-dimensional emission: both
/// valid dimension lists ([`crate::check_dims`]; the input may be empty, for
/// the outputs' marginals) and disjoint.
pub fn check_split(input: &[usize], output: &[usize], dim: usize) -> Result<()> {
    if !input.is_empty() {
        crate::check_dims(input, dim)?;
    }
    crate::check_dims(output, dim)?;
    if let Some(d) = input.iter().find(|d| output.contains(d)) {
        return Err(crate::EmissionError::InvalidDims {
            dims: output.to_vec(),
            dim,
            reason: if *d < dim {
                "an output dimension is also an input dimension"
            } else {
                "dimension out of range"
            },
        });
    }
    Ok(())
}
