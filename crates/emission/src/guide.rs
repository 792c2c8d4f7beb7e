//! # Writing an emission
//!
//! An emission is the set of per-state distributions `b_i(x)` of an HMM (or
//! the components of a mixture). There are two routes.
//!
//! ## The per-state route (start here)
//!
//! Write ONE state's distribution as a [`StateDistribution`] — its dimension,
//! the log-density of a frame, a draw, a weighted fit from frames and weights
//! given the previous parameters, and its number of parameters — and wrap `S`
//! of them in [`PerState`]. That is an [`Emission`]: Baum-Welch (parallel
//! E-step, bit-identical for any number of threads), mixture EM, Viterbi,
//! the online filter, AIC/BIC and serde all work, with no statistics to write.
//!
//! ```
//! use phasekit_emission::rand::Rng; // phasekit's rand, whatever yours is
//! use phasekit_emission::{
//!     Emission, Frames, MStepReport, PerState, Regularisation, Result, StateDistribution,
//! };
//!
//! /// A Gaussian with identity covariance: only its mean is fitted.
//! #[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
//! struct UnitGaussian {
//!     mean: Vec<f64>,
//! }
//!
//! impl StateDistribution for UnitGaussian {
//!     fn dim(&self) -> usize {
//!         self.mean.len()
//!     }
//!     fn log_density(&self, x: &[f64]) -> f64 {
//!         let sq: f64 = x.iter().zip(&self.mean).map(|(a, m)| (a - m).powi(2)).sum();
//!         -0.5 * (sq + x.len() as f64 * (2.0 * std::f64::consts::PI).ln())
//!     }
//!     fn sample<R: Rng + ?Sized>(&self, rng: &mut R, out: &mut [f64]) {
//!         for (o, m) in out.iter_mut().zip(&self.mean) {
//!             // Box–Muller, to need nothing but `Rng`.
//!             let (u, v): (f64, f64) = (rng.random(), rng.random());
//!             *o = m + (-2.0 * (1.0 - u).ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos();
//!         }
//!     }
//!     /// The weighted mean: the exact M-step.
//!     fn fit(&self, frames: Frames<'_>, w: &[f64], _: &Regularisation, _: &mut MStepReport) -> Result<Self> {
//!         let n: f64 = w.iter().sum();
//!         let mut mean = vec![0.0; self.dim()];
//!         for (x, wt) in frames.iter().zip(w) {
//!             for (m, v) in mean.iter_mut().zip(x) {
//!                 *m += wt * v / n;
//!             }
//!         }
//!         Ok(UnitGaussian { mean })
//!     }
//!     fn n_parameters(&self) -> usize {
//!         self.dim()
//!     }
//! }
//!
//! // Two states in two dimensions, as an Emission.
//! let template = PerState::repeat(UnitGaussian { mean: vec![0.0; 2] }, 2)?;
//! let x = [0.1, -0.2, 5.2, 4.9, -0.1, 0.3, 4.8, 5.1];
//! let frames = Frames::new(&x, 2)?;
//! // Weights from an initialisation (here: frames 0, 2 to state 0; 1, 3 to state 1).
//! let w = [1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0];
//! let mut rng = <rand_chacha::ChaCha8Rng as phasekit_emission::rand::SeedableRng>::seed_from_u64(0);
//! let (mut model, _) = template.initialise(&[(frames, &w)], &Regularisation::none(), &mut rng)?;
//! assert!((model.states()[1].mean[0] - 5.0).abs() < 1e-12);
//!
//! // One EM step by hand (Baum-Welch and mixture EM do the same with posteriors).
//! let mut stats = model.new_stats();
//! model.accumulate(frames, &w, &mut stats)?;
//! model.m_step(&stats, &Regularisation::none())?;
//! let log_b = model.log_density(frames)?; // T × S
//! assert!(log_b[3] > log_b[2], "frame 1 belongs to state 1");
//! let mut draw = [0.0; 2];
//! model.sample_into(1, &mut rng, &mut draw)?;
//! # Ok::<(), phasekit_emission::EmissionError>(())
//! ```
//!
//! Optional, when the distribution can:
//!
//! * [`StateDistribution::marginal`] with
//!   [`StateDistribution::MISSING_VALUES`] `= true`: missing values (NaN) —
//!   a frame is evaluated on the marginal of its observed values, and `fit`
//!   receives frames with NaN to use the expected statistics of the missing
//!   ones — and the [`Marginal`] capability (the human-only filter);
//! * [`StateConditional`]: the [`Conditional`] capability (regression, GMR);
//! * [`StateDistribution::initialise`]: when the fit depends on the current
//!   parameters (latent weights, components), start from something the data
//!   decide instead of the template's values (see [`StudentT`]);
//! * [`StateDistribution::check_value`] (the support), [`StateDistribution::log_prior`];
//! * [`crate::regularised_covariance`], [`crate::jitter_variances`] and
//!   [`crate::regularised_variance`]: regularise as every built-in emission
//!   does, and report jitter in the `report` given to `fit`;
//! * [`EmissionError::plugin`]: the distribution's own errors, located at
//!   their state by the route.
//!
//! [`ConcatStates`] comes free. The price of the route is memory: its
//! statistics keep a copy of the weighted frames during an E-step (`T (D + S)`
//! values) instead of fixed-size sufficient statistics.
//!
//! Worked examples: [`StudentT`] (full scale matrix, ν fixed or estimated by
//! ECME, missing values, conditional) in this crate, and `examples/plugin`
//! (independent Laplace dimensions with missing values and a conditional),
//! a crate of its own that depends on a newer `rand` than phasekit and uses
//! only the public API; its `impl StateDistribution` is 76 lines, the whole
//! plug-in 194 (both as `cargo fmt` lays them out), and its tests run it through Baum-Welch, mixture EM, the
//! online filter, the generic properties of `tests/every_emission.rs`, the
//! TSC-HMM and its union (`phasekit_tsc::TscHmm::fit_with_regression`) and
//! GMR prediction, batch and online (`phasekit_gmr::HmmRegression`).
//!
//! ## The full trait
//!
//! Implement [`Emission`] directly when fixed-size sufficient statistics or
//! batched kernels matter ([`Gaussian`] packs its covariances and evaluates
//! blocks of frames with SIMD). The contract:
//!
//! * [`Emission::log_density_into`] writes `log b_i(x_t)` for a block into a
//!   caller's `T × S` buffer; a frame with NaN is evaluated on the marginal of
//!   its observed values (the rule of [`crate::missing`]);
//! * [`Emission::accumulate`] adds weighted (expected) sufficient statistics
//!   to a [`crate::SufficientStatistics`] value; merging must be exact and in
//!   the order given, so that the parallel E-step does not depend on the
//!   number of threads;
//! * [`Emission::m_step`] re-estimates from merged statistics with the given
//!   [`Regularisation`], reports what it had to do, and leaves `self`
//!   unchanged on error;
//! * [`Emission::initialise`] builds parameters from fixed weights (the
//!   default, [`crate::fit_weighted`], is exact when the statistics do not
//!   depend on the current parameters);
//! * capabilities ([`Marginal`], [`ConcatStates`], [`Conditional`]) as the
//!   emission can.
//!
//! [`StateDistribution`]: crate::StateDistribution
//! [`StateDistribution::marginal`]: crate::StateDistribution::marginal
//! [`StateDistribution::MISSING_VALUES`]: crate::StateDistribution::MISSING_VALUES
//! [`StateDistribution::initialise`]: crate::StateDistribution::initialise
//! [`StateDistribution::check_value`]: crate::StateDistribution::check_value
//! [`StateDistribution::log_prior`]: crate::StateDistribution::log_prior
//! [`StateConditional`]: crate::StateConditional
//! [`PerState`]: crate::PerState
//! [`Emission`]: crate::Emission
//! [`Emission::log_density_into`]: crate::Emission::log_density_into
//! [`Emission::accumulate`]: crate::Emission::accumulate
//! [`Emission::m_step`]: crate::Emission::m_step
//! [`Emission::initialise`]: crate::Emission::initialise
//! [`Marginal`]: crate::Marginal
//! [`ConcatStates`]: crate::ConcatStates
//! [`Conditional`]: crate::Conditional
//! [`StudentT`]: crate::StudentT
//! [`Gaussian`]: crate::Gaussian
//! [`Regularisation`]: crate::Regularisation
//! [`EmissionError::plugin`]: crate::EmissionError::plugin
