//! Hidden Markov models generic over pluggable emissions.
//!
//! * [`Hmm`]: parameters `λ = (π, A, B)`, validated at construction, with
//!   [`Hmm::forward`], [`Hmm::backward`], [`Hmm::posteriors`], [`Hmm::viterbi`],
//!   [`Hmm::log_likelihood`], [`Hmm::marginal`], [`Hmm::sample`], AIC/BIC and
//!   a serde form that carries a format version;
//! * [`ForwardFilter`]: the online forward filter, one frame at a time;
//! * [`BaumWelch`]: multi-sequence EM with a parallel, thread-count-independent
//!   E-step, freezing, regularisation, restarts and per-iteration history;
//! * [`HmmInit`]: temporal k-bins, k-means++ and random initialisation;
//! * [`selection`]: the number of states by BIC ([`select_states_bic`]) and the
//!   largest number the data can support ([`max_supported_states`]).
//!
//! The emissions (`b_i(x)`, any [`emission::Emission`]) come from
//! `phasekit-emission`, re-exported as [`emission`]; this crate depends on
//! nothing else of the workspace.
//!
//! # Example
//!
//! Fit a two-state HMM to sequences drawn from a known one, decode a sequence
//! and choose the number of states by BIC:
//!
//! ```
//! use phasekit_hmm::emission::{CovarianceType, Gaussian, SequenceSet, Shape};
//! use phasekit_hmm::{select_states_bic, BaumWelch, Hmm};
//! use rand::SeedableRng;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // The truth: two 1-D Gaussian states at -5 and +5 that rarely switch.
//! let truth = Hmm::new(
//!     vec![0.5, 0.5],
//!     vec![0.95, 0.05, 0.05, 0.95],
//!     Gaussian::spherical(1, vec![-5.0, 5.0], vec![1.0, 1.0])?,
//! )?;
//! let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
//! let sequences: Vec<Vec<f64>> = (0..5)
//!     .map(|_| truth.sample(100, &mut rng).map(|(frames, _)| frames))
//!     .collect::<Result<_, _>>()?;
//! let data = SequenceSet::new(&sequences, 1)?;
//!
//! // Baum-Welch from a two-state template (its parameters are ignored).
//! let shape = |n_states| Gaussian::standard(CovarianceType::Full, Shape { n_states, dim: 1 });
//! let fitted = BaumWelch::builder().max_iter(50).build()?.fit(&shape(2)?, &data)?;
//! let mut means = fitted.model.emission().means().to_vec();
//! means.sort_by(f64::total_cmp); // the states' order is arbitrary
//! assert!((means[0] + 5.0).abs() < 0.5 && (means[1] - 5.0).abs() < 0.5, "{means:?}");
//!
//! // The most likely state path of the first sequence.
//! let path = fitted.model.viterbi(data.get(0))?;
//! assert_eq!(path.states.len(), 100);
//!
//! // BIC prefers the true number of states.
//! let chosen = select_states_bic(&BaumWelch::default(), shape, &data, 1..=4)?;
//! assert_eq!(chosen.best, 2);
//! # Ok(())
//! # }
//! ```

#![warn(missing_docs)]

pub mod error;
pub mod filter;
pub mod fit;
pub mod inference;
pub mod init;
pub mod model;
pub mod selection;

pub use error::{HmmError, Result};
pub use filter::ForwardFilter;
pub use fit::{
    default_regularisation, BaumWelch, BaumWelchBuilder, Convergence, ExpectedStatistics, HmmFit,
    HmmFitReport, StepCounts, Update, DEFAULT_ADDED_DIAGONAL,
};
pub use inference::{Forward, Posteriors, ViterbiPath};
pub use init::{initialise, kbins_edges, HmmInit};
pub use model::{Hmm, MODEL_FORMAT_VERSION};
pub use phasekit_emission as emission;
pub use selection::{max_supported_states, select_states_bic, StateLimit, StateSelection};
