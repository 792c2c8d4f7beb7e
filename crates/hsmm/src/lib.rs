//! Hidden semi-Markov models (explicit-duration HMMs) generic over pluggable
//! emissions and durations.
//!
//! An HMM stays in state `i` for a geometric number of frames
//! (`P(d) = (1 − a_ii) a_ii^{d−1}`, most likely one frame), which is a poor
//! model of the phases of an interaction: a handshake's shaking phase lasts
//! about 50 frames, rarely 5. An HSMM draws the length of every visit from
//! an explicit duration distribution `p_i(d)`, `d = 1..=D`:
//!
//! ```text
//! z_1 ~ π,   d_1 ~ p_{z_1},   x_t ~ b_{z_1} for the d_1 frames of the segment,
//! z_2 ~ a_{z_1 ·} (a_ii = 0),   d_2 ~ p_{z_2},   …
//! ```
//!
//! This is the model pbdlib uses for learning from demonstration (and that
//! hmmlearn never merged, PR #582). Here it is generic over the emission
//! (any [`Emission`](phasekit_emission::Emission): Gaussian, mixtures,
//! categorical, Poisson, with missing values) and over the durations (any
//! [`Duration`]: non-parametric, Poisson, negative binomial, pbdlib's Gaussian).
//!
//! * [`Hsmm`]: parameters `(π, A, p, B)` and the [`Censoring`] of the last
//!   segment, validated at construction, with [`Hsmm::forward`],
//!   [`Hsmm::posteriors`] (states, segment starts and ends, transitions and
//!   durations), [`Hsmm::viterbi`] (the most probable segmentation),
//!   [`Hsmm::log_likelihood`], [`Hsmm::marginal`], [`Hsmm::sample`],
//!   AIC/BIC, [`Hsmm::from_hmm`] and a serde form that carries a format version;
//! * [`HsmmFilter`]: the online forward filter with durations, one frame in,
//!   the state marginals out (pbdlib's step-wise forward variable, which
//!   drives HSMM-GMR), and where the interaction is heading
//!   ([`HsmmFilter::predict_states`]);
//! * [`HsmmEm`]: multi-sequence EM of emissions and durations together, with a
//!   parallel E-step that is bit-identical for any thread count, freezing,
//!   restarts and per-iteration reports;
//! * [`HsmmInit`] and [`Structure`]: k-bins (durations from the bin lengths),
//!   k-means and random initialisation; ergodic or left-right transitions.
//!
//! # The forward variable with durations
//!
//! With `ℓ_t = log p(x_t | x_{<t})` and the cumulative sums of normalised
//! emission log-densities `L_j(t) = Σ_{u<t} (log b_j(x_u) − ℓ_u)`, the
//! normalised log-probability that a segment of `j` starts at `t` is
//! `â_t(j)` and that one ends at `t` is `F̂_t(j)`:
//!
//! ```text
//! â_0(j)     = log π_j
//! ℓ_t        = log Σ_j Σ_{d=1}^{D} exp(â_{t−d+1}(j) + L_j(t) − L_j(t−d+1)) · b_j(x_t) · P(D_j ≥ d)
//! F̂_t(j)     = log Σ_{d=1}^{D} exp(â_{t−d+1}(j) + L_j(t+1) − L_j(t−d+1)) · p_j(d)
//! â_{t+1}(k) = log Σ_i exp(F̂_t(i)) · a_ik
//! ```
//!
//! (the first sum runs over the segments still going on at `t`, each of `j`
//! started `d − 1` frames earlier; the second over those ending at `t`). The filtered marginal
//! `h_t(j) = p(z_t = j | x_{≤t})` is the share of state `j` in `ℓ_t`'s sum,
//! and `log p(x) = Σ_t ℓ_t` for a right-censored last segment. The cost is
//! `O(S (S + D))` per frame, linear in the maximum duration `D`; the
//! [`inference`] module has the backward pass and the posteriors.
//!
//! # Duration re-estimation
//!
//! The expected number of complete segments of state `k` lasting `d` frames,
//!
//! ```text
//! η_k(d) = Σ_s exp(â_s(k) + L_k(s+d) − L_k(s) + Ê_{s+d−1}(k)) · p_k(d),
//! ```
//!
//! with `Ê_t(k)` the normalised backward variable after a segment of `k`
//! ends at `t`, plus the right-censored last segments spread over the
//! durations they may have had, `p_k(d) Σ_{d' ≤ d} κ_k(d') / P(D_k ≥ d')`,
//! are the counts `c_k(d)` from which every [`Duration`] re-estimates itself
//! (`p_k(d) = c_k(d) / Σ c_k` for the non-parametric pmf; the exact truncated
//! maximum likelihood for the parametric ones). EM increases
//! `log p(X)` (plus the log-prior of a pseudo-count or inverse-Wishart
//! regularisation) at every iteration.
//!
//! # Example
//!
//! ```
//! use phasekit_emission::{CovarianceType, Gaussian, SequenceSet, Shape};
//! use phasekit_hsmm::{AnyDuration, Hsmm, HsmmEm, PoissonDuration, Structure};
//! use rand::SeedableRng;
//!
//! // A 3-phase left-right model: phases of about 10, 30 and 20 frames.
//! let truth: Hsmm<Gaussian, AnyDuration> = Hsmm::new(
//!     vec![1.0, 0.0, 0.0],
//!     vec![0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
//!     PoissonDuration::new(60, vec![9.0, 29.0, 19.0])?.into(),
//!     Gaussian::diagonal(1, vec![0.0, 3.0, 1.0], vec![0.5, 0.5, 0.5])?,
//! )?;
//! let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
//! let demos: Vec<Vec<f64>> = (0..8)
//!     .map(|_| truth.sample(60, &mut rng).map(|(frames, _, _)| frames))
//!     .collect::<Result<_, _>>()?;
//! let data = SequenceSet::new(&demos, 1)?;
//!
//! let fitted = HsmmEm::builder()
//!     .structure(Structure::LeftRight { skip: 0 })
//!     .max_iter(30)
//!     .build()?
//!     .fit(
//!         &Gaussian::standard(CovarianceType::Diagonal, Shape { n_states: 3, dim: 1 })?,
//!         &AnyDuration::from(PoissonDuration::template(3, 60)?),
//!         &data,
//!     )?;
//! let means = fitted.model.mean_durations();
//! assert!((means[1] - 30.0).abs() < 5.0, "{means:?}");
//!
//! // The most probable segmentation of a demonstration, and the online filter.
//! let path = fitted.model.viterbi(data.get(0))?;
//! assert_eq!(path.segments.len(), 3);
//! let mut filter = fitted.model.filter();
//! for frame in demos[0].chunks(1) {
//!     let belief = filter.step(frame)?; // p(phase | frames so far)
//!     assert!((belief.iter().sum::<f64>() - 1.0).abs() < 1e-12);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

pub mod duration;
pub mod error;
pub mod filter;
pub mod fit;
pub mod inference;
pub mod init;
mod kernels;
pub mod model;
#[cfg(test)]
mod reference;
mod window;

pub use duration::{
    AnyDuration, Duration, DurationEvent, DurationRegularisation, DurationReport, GaussianDuration,
    NegativeBinomialDuration, NonParametricDuration, PoissonDuration,
};
pub use error::{HsmmError, Result};
pub use filter::HsmmFilter;
pub use fit::{
    Convergence, HsmmEm, HsmmEmBuilder, HsmmFit, HsmmFitReport, HsmmStatistics, HsmmUpdate,
};
pub use inference::{HsmmForward, HsmmPosteriors, Segment, ViterbiSegmentation};
pub use init::{
    duration_counts, initialise, suggested_max_duration, HsmmInit, InitSettings, Structure,
};
pub use model::{Censoring, Hsmm, HSMM_FORMAT_VERSION};
pub use phasekit_emission as emission;
