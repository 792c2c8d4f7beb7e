//! Gaussian mixture regression (GMR): predict output dimensions (the robot)
//! from input dimensions (the human) under a joint model whose emission has
//! conditionals (`phasekit_emission::Conditional`: Gaussian, Student-t,
//! mixtures of either, a plug-in's).
//!
//! * [`Conditional`] (the reference for Gaussian states; the regression uses
//!   the emission's own conditional, equal to it to the last bit): `p(x_o | x_i) = N(μ_o + Σ_oi Σ_ii⁻¹ (x_i − μ_i), Σ_oo − Σ_oi Σ_ii⁻¹ Σ_io)`,
//!   precomputed once per state by Cholesky solves (the seed paper prints the
//!   regression as `μ¹ + Σ²¹(Σ¹²)⁻¹(μ¹ − o¹)`, a typo; this is the correct conditional);
//! * [`GmmRegression`]: static GMR weighted by the responsibilities of the input marginal;
//! * [`HmmRegression`]: weights are the forward variable `h_t` of the HMM on the
//!   input dims, over a whole sequence or frame by frame ([`OnlineRegression`]);
//! * every prediction carries the mean and, on request, the moment-matched
//!   predictive covariance;
//! * inputs may be missing (NaN: conditioned on the observed ones only); every
//!   prediction reports each frame's log predictive density (to tell input
//!   unlike the training data), and a frame that no state can explain (a
//!   glitch of `1e200`) is rejected — reported and taken as not observed —
//!   instead of zeroing every later prediction (see [`regression`]).
//!
//! # Example
//!
//! A two-state HMM over one human and one robot dimension (joint frames
//! `[human, robot]`): the robot moves with the human, offset by a state-dependent amount.
//!
//! ```
//! use phasekit_emission::{Frames, Gaussian};
//! use phasekit_gmr::HmmRegression;
//! use phasekit_hmm::Hmm;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // State 0 near (0, 0), state 1 near (1, 2); human and robot correlated (0.08).
//! let emission = Gaussian::full(
//!     2,
//!     vec![0.0, 0.0, 1.0, 2.0],
//!     vec![0.1, 0.08, 0.08, 0.1, 0.1, 0.08, 0.08, 0.1],
//! )?;
//! let hmm = Hmm::new(vec![0.5, 0.5], vec![0.9, 0.1, 0.1, 0.9], emission)?;
//! let gmr = HmmRegression::new(&hmm, &[0], &[1])?;
//!
//! // A whole sequence of human frames, causally: frame t uses frames 0..=t.
//! let human = [0.0, 0.1, 0.9, 1.0];
//! let p = gmr.predict(Frames::new(&human, 1)?, true)?;
//! assert_eq!(p.mean.len(), 4);
//! assert!((p.mean[0] - 0.0).abs() < 0.1 && (p.mean[3] - 2.0).abs() < 0.1);
//! let variance = p.covariance.as_ref().unwrap()[3]; // O × O = 1 × 1 per frame
//! assert!(variance > 0.0 && variance < 0.1);
//!
//! // Frame by frame (a control loop): the same numbers, no allocation per frame.
//! let mut online = gmr.online();
//! for (t, x) in human.iter().enumerate() {
//!     let robot = online.step(&[*x])?;
//!     assert!((robot[0] - p.mean[t]).abs() < 1e-12);
//! }
//!
//! // A missing value (NaN) is predicted from the dynamics; a glitch no state
//! // explains is rejected and reported, and the next frames recover.
//! let glitch = online.step(&[1e200])?.to_vec();
//! assert!(online.evidence().rejected && glitch[0].is_finite());
//! online.step(&[1.0])?;
//! assert!(!online.evidence().rejected && online.evidence().log_predictive > -5.0);
//! # Ok(())
//! # }
//! ```

#![warn(missing_docs)]

pub mod calibration;
pub mod conditional;
pub mod error;
pub mod hsmm;
pub mod regression;

pub use calibration::{
    chi_squared_cdf, chi_squared_quantile, covariance_block, coverage_scale,
    demonstration_inflation, new_demonstration_factor, nlpd_scaled, residual_shape, score_gaussian,
    GaussianScore, NewDemonstration, ResidualShape, COVERAGE_LEVEL,
};
pub use conditional::{check_io, Conditional};
pub use error::{GmrError, Result};
pub use hsmm::{HsmmRegression, OnlineHsmmRegression};
pub use regression::{
    FrameEvidence, GmmRegression, HmmRegression, Mixer, OnlineRegression, Prediction, Regression,
};
