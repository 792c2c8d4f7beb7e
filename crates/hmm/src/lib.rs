//! Hidden Markov models generic over pluggable emissions.
//!
//! * [`Hmm`]: parameters `λ = (π, A, B)`, validated at construction, with
//!   [`Hmm::forward`], [`Hmm::backward`], [`Hmm::posteriors`], [`Hmm::viterbi`],
//!   [`Hmm::log_likelihood`], [`Hmm::marginal`], [`Hmm::sample`], AIC/BIC and
//!   a serde form that carries a format version;
//! * [`ForwardFilter`]: the online forward filter, one frame at a time;
//! * [`BaumWelch`]: multi-sequence EM with a parallel, thread-count-independent
//!   E-step, freezing, regularisation, restarts and per-iteration history;
//! * [`HmmInit`]: temporal k-bins, k-means++ and random initialisation.

#![warn(missing_docs)]

pub mod error;
pub mod filter;
pub mod fit;
pub mod inference;
pub mod init;
pub mod model;

pub use error::{HmmError, Result};
pub use filter::ForwardFilter;
pub use fit::{
    BaumWelch, BaumWelchBuilder, Convergence, ExpectedStatistics, HmmFit, HmmFitReport, Update,
};
pub use inference::{Forward, Posteriors, ViterbiPath};
pub use init::{initialise, kbins_edges, HmmInit};
pub use model::{Hmm, MODEL_FORMAT_VERSION};
pub use phasekit_emission as emission;
