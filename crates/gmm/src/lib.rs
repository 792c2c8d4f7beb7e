//! Finite mixture models fitted by EM, generic over the emission trait.
//!
//! * [`Gmm`] (and [`Gmm`] for Gaussian components): `p(x) = Σ_k π_k c_k(x)`,
//!   with responsibilities, hard labels, per-frame log-likelihood, sampling, AIC/BIC;
//! * [`Em`]: EM with k-means++ or random initialisation, restarts, tolerance,
//!   regularisation reported as in the emission crate, per-iteration history and a
//!   parallel E-step that is bit-identical for any number of threads;
//! * [`selection`]: the number of mixture components or of HMM states, by BIC
//!   over a range ([`select_mixture_bic`], [`select_hmm_states_bic`]) and by
//!   G-means with the Anderson–Darling test ([`gmeans`],
//!   [`select_hmm_states_gmeans`]).

#![warn(missing_docs)]

pub mod em;
pub mod error;
pub mod model;
pub mod selection;

pub use em::{Em, EmBuilder, GmmFit, GmmFitReport, GmmInit, MixtureStatistics};
pub use error::{GmmError, Result};
pub use model::{Gmm, MODEL_FORMAT_VERSION};
pub use selection::{
    anderson_darling_normal, gmeans, select_hmm_states_bic, select_hmm_states_gmeans,
    select_mixture_bic, GMeans, GMeansBuilder, GMeansResult, GMeansStates, Selection,
};
