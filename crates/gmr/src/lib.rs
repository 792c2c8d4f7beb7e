//! Gaussian mixture regression (GMR): predict output dimensions (the robot)
//! from input dimensions (the human) under a joint Gaussian model.
//!
//! * [`Conditional`]: `p(x_o | x_i) = N(μ_o + Σ_oi Σ_ii⁻¹ (x_i − μ_i), Σ_oo − Σ_oi Σ_ii⁻¹ Σ_io)`,
//!   precomputed once per state by Cholesky solves (the seed paper prints the
//!   regression as `μ¹ + Σ²¹(Σ¹²)⁻¹(μ¹ − o¹)`, a typo; this is the correct conditional);
//! * [`GmmRegression`]: static GMR weighted by the responsibilities of the input marginal;
//! * [`HmmRegression`]: weights are the forward variable `h_t` of the HMM on the
//!   input dims, over a whole sequence or frame by frame ([`OnlineRegression`]);
//! * every prediction carries the mean and, on request, the moment-matched
//!   predictive covariance.

#![warn(missing_docs)]

pub mod conditional;
pub mod error;
pub mod regression;

pub use conditional::{check_io, Conditional};
pub use error::{GmrError, Result};
pub use regression::{GmmRegression, HmmRegression, OnlineRegression, Prediction, Regression};
