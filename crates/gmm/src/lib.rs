//! Finite mixture models fitted by EM, generic over the emission trait.
//!
//! * [`Gmm`] (`Gmm<Gaussian>` by default): `p(x) = Σ_k π_k c_k(x)`, with
//!   responsibilities, hard labels, per-frame log-likelihood, sampling, AIC/BIC;
//! * [`Em`]: EM with k-means++ or random initialisation, restarts, tolerance,
//!   regularisation reported as in the emission crate, per-iteration history and a
//!   parallel E-step that is bit-identical for any number of threads;
//! * [`selection`]: the number of mixture components by BIC over a range
//!   ([`select_mixture_bic`]) and by G-means with the Anderson–Darling test
//!   ([`gmeans`], [`anderson_darling_normal`]).
//!
//! The components come from `phasekit-emission`; this crate depends on
//! nothing else of the workspace (the number of HMM states is chosen in
//! `phasekit-hmm` by BIC and in `phasekit-tsc` by G-means).
//!
//! # Example
//!
//! Fit a two-component mixture, label frames, and count the clusters with
//! BIC and G-means:
//!
//! ```
//! use phasekit_emission::{CovarianceType, Frames, Gaussian, Shape};
//! use phasekit_gmm::{gmeans, select_mixture_bic, Em, GMeans, Gmm};
//! use rand::SeedableRng;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // 400 frames from two 2-D Gaussians 10 apart.
//! let truth = Gmm::new(
//!     vec![0.5, 0.5],
//!     Gaussian::spherical(2, vec![0.0, 0.0, 10.0, 0.0], vec![1.0, 1.0])?,
//! )?;
//! let (frames, _) = truth.sample(400, &mut rand_chacha::ChaCha8Rng::seed_from_u64(1))?;
//! let frames = Frames::new(&frames, 2)?;
//!
//! let shape = |n_states| Gaussian::standard(CovarianceType::Full, Shape { n_states, dim: 2 });
//! let fitted = Em::builder().restarts(3).build()?.fit(&shape(2)?, frames)?;
//! let labels = fitted.model.predict(frames)?;
//! assert_eq!(labels.len(), 400);
//!
//! assert_eq!(select_mixture_bic(&Em::default(), shape, frames, 1..=4)?.best, 2);
//! let clusters = gmeans(frames, GMeans::default())?;
//! assert_eq!((clusters.k, clusters.capped), (2, false));
//! # Ok(())
//! # }
//! ```

#![warn(missing_docs)]

pub mod em;
pub mod error;
pub mod model;
pub mod selection;

pub use em::{
    default_regularisation, Em, EmBuilder, GmmFit, GmmFitReport, GmmInit, MixtureStatistics,
    DEFAULT_ADDED_DIAGONAL,
};
pub use error::{GmmError, Result};
pub use model::{Gmm, MODEL_FORMAT_VERSION};
pub use selection::{
    anderson_darling_normal, gmeans, select_mixture_bic, GMeans, GMeansBuilder, GMeansResult,
    Selection,
};
