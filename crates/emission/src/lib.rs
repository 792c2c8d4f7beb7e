//! Pluggable emission distributions for hidden Markov models and mixtures.
//!
//! An [`Emission`] is the set of `S` per-state distributions `b_i(x)` of a
//! model. The HMM and the GMM are generic over it, so a new distribution plugs
//! into both without touching either. The trait is shaped around the E- and
//! M-steps of EM:
//!
//! * [`Emission::log_density_into`] writes `log b_i(x_t)` for a whole block of
//!   frames into a caller-provided `T × S` buffer (no allocation per frame);
//! * [`Emission::accumulate`] adds the weighted sufficient statistics
//!   `Σ_t γ_t(i) φ(x_t)` of a block to a [`SufficientStatistics`] value, which
//!   can be built per thread or per sequence and merged in a fixed order;
//! * [`Emission::m_step`] re-estimates the parameters from merged statistics
//!   with explicit [`Regularisation`], and reports what it had to do;
//! * [`Emission::initialise`] builds parameters from fixed weights (the
//!   initialisation of HMMs and mixtures);
//! * [`Emission::sample_into`] draws a frame from one state.
//!
//! Capabilities beyond it, each a small trait ([`capability`]): [`Marginal`]
//! (the human-only filter), [`ConcatStates`] (the TSC-HMM's union) and
//! [`Conditional`] (regression); [`ScaleFeatures`] maps a fitted emission to
//! features multiplied by constants ([`scale`]).
//!
//! Implementations: [`Gaussian`] (full, diagonal, spherical and tied
//! covariance), [`Categorical`], [`Poisson`], [`MixtureEmission`] (a mixture of
//! any emission per state, e.g. hmmlearn's GMMHMM) and, on the per-state route
//! ([`PerState`] over a [`StateDistribution`]), [`StudentT`]. The guide
//! [`guide`] ("Writing an emission") shows how to add one.
//!
//! ```
//! use phasekit_emission::{CovarianceType, Emission, Frames, Gaussian, Regularisation, Shape};
//! use phasekit_emission::rand::SeedableRng;
//!
//! // Two states in one dimension, fitted to frames with fixed weights.
//! let template = Gaussian::standard(CovarianceType::Full, Shape { n_states: 2, dim: 1 })?;
//! let x = [0.0, 10.0, 0.2, 10.4, -0.2, 9.6];
//! let frames = Frames::new(&x, 1)?;
//! let w = [1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0];
//! let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
//! let (g, _) = template.initialise(&[(frames, &w)], &Regularisation::none(), &mut rng)?;
//! assert!((g.mean(1)[0] - 10.0).abs() < 1e-12);
//! let log_b = g.log_density(frames)?; // T × S
//! assert!(log_b[0] > log_b[1]);
//! # Ok::<(), phasekit_emission::EmissionError>(())
//! ```
//!
//! Missing values: a NaN in a frame means "not observed". Every implementation
//! evaluates such a frame on the marginal of its observed values
//! (`b_i(x_o) = ∫ b_i(x) dx_m`, 1 when nothing is observed) and accumulates
//! the expected sufficient statistics `E[φ(x) | x_o, state i]` under its
//! current parameters, so that EM stays exact EM for the observed data; a
//! frame with nothing observed adds nothing to the emission statistics (its
//! density does not depend on them). Data without NaN take the plain paths,
//! bit for bit. The helpers are public ([`missing`]).
//!
//! With an added-diagonal regularisation `Σ = S/n + rI` (the seed paper's), the
//! expected statistics condition on the maximum-likelihood part `S/n`, so that
//! `r` is not compounded from one M-step to the next (it would otherwise settle
//! the variances near `s + r/(1 − f)` for a fraction `f` missing, instead of
//! `s + r`); EM with an added diagonal is not monotone in any case.

#![warn(missing_docs)]

pub mod capability;
pub mod categorical;
pub mod error;
pub mod frames;
pub mod gaussian;
pub mod guide;
pub mod kmeans;
/// Dense kernels shared by the crates of the workspace (packed triangles,
/// SIMD norms and tiles, log-sum-exp). Not a checked API: they assume shapes
/// their callers have validated and panic otherwise.
#[doc(hidden)]
pub mod linalg;
pub mod missing;
pub mod mixture;
pub mod per_state;
pub mod poisson;
pub mod regularisation;
pub mod restarts;
pub mod scale;
pub mod student_t;

/// The `nalgebra` this crate's public API uses ([`Gaussian::covariance`]
/// returns its matrices): a plug-in that names its types compiles against
/// this one, whatever version it depends on itself.
pub use nalgebra;
/// The `rand` this crate's public API uses ([`Emission::sample_into`] and
/// [`Emission::initialise`] take its generators): a plug-in implements them
/// with `phasekit_emission::rand::Rng`, whatever version it depends on itself.
pub use rand;

pub use capability::{ConcatStates, Conditional, ConditionalSplit, Marginal};
pub use categorical::{Categorical, CategoricalStats};
pub use error::{EmissionError, Result};
pub use frames::{Frames, SequenceSet, Shape};
pub use gaussian::{CovarianceType, Gaussian, GaussianSplit, GaussianStats};
pub use mixture::{MixtureEmission, MixtureEmissionStats, MixtureSplit};
pub use per_state::{
    PerState, PerStateSplit, PerStateStats, StateConditional, StateDistribution, StateSplit,
};
pub use poisson::{Poisson, PoissonStats};
pub use regularisation::{
    jitter_variances, regularised_covariance, regularised_variance, CovarianceRegularisation,
    MStepEvent, MStepReport, Regularisation,
};
pub use scale::{check_scales, ScaleFeatures};
pub use student_t::{StudentT, StudentTDof, StudentTSplit};

use rand::Rng;
use std::fmt::Debug;

/// Weighted sufficient statistics of an emission model, accumulated over any
/// partition of the data and merged.
///
/// Merging is plain addition, so statistics gathered per sequence, per thread
/// or per machine combine exactly; merging in a fixed order gives results that
/// do not depend on how the work was split.
pub trait SufficientStatistics: Clone + Debug + Send + Sync {
    /// Adds `other` into `self`. Errors if the two come from differently shaped models.
    fn merge(&mut self, other: &Self) -> Result<()>;
    /// Total posterior weight `Σ_t Σ_i γ_t(i)` accumulated so far.
    fn total_weight(&self) -> f64;
}

/// The emission distributions `b_i(x)`, `i = 0..S`, of an HMM or a mixture.
pub trait Emission: Clone + Debug + Send + Sync {
    /// Sufficient statistics for the M-step.
    type Stats: SufficientStatistics;

    /// Number of states `S`.
    fn n_states(&self) -> usize;

    /// Dimension `D` of a frame.
    fn dim(&self) -> usize;

    /// Checks that the frames lie in the support of this emission (dimension,
    /// valid symbols or counts). Called once per data set before fitting or
    /// scoring, so that the hot paths need no checks. NaN (a missing value)
    /// is not refused by an emission that follows the rule of
    /// [`Emission::log_density_into`]; one that cannot marginalise refuses it
    /// here, naming the frame and column.
    fn check_frames(&self, frames: Frames<'_>) -> Result<()> {
        check_dim(self.dim(), frames.dim())
    }

    /// Writes `out[t·S + i] = log b_i(x_t)` for every frame `t` and state `i`.
    ///
    /// `out` must hold `frames.len() · S` values. Frames must have passed
    /// [`Emission::check_frames`]; values outside the support give `-inf`.
    ///
    /// The rule for missing values, the same for batch inference and the
    /// online filter: a frame with NaN is evaluated on the marginal of its
    /// observed values, `log b_i(x_o) = log ∫ b_i(x) dx_m`, and a frame with
    /// nothing observed has `log b_i = 0` (see [`missing`]).
    fn log_density_into(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()>;

    /// Allocating convenience form of [`Emission::log_density_into`].
    fn log_density(&self, frames: Frames<'_>) -> Result<Vec<f64>> {
        let mut out = vec![0.0; frames.len() * self.n_states()];
        self.log_density_into(frames, &mut out)?;
        Ok(out)
    }

    /// Empty statistics shaped for this model.
    fn new_stats(&self) -> Self::Stats;

    /// Adds `Σ_t w[t·S + i] φ(x_t)` to the statistics of every state `i`.
    ///
    /// `weights` is row-major `T × S` (e.g. the posteriors `γ`).
    fn accumulate(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut Self::Stats,
    ) -> Result<()>;

    /// Re-estimates the parameters from `stats` (maximum likelihood, or MAP
    /// when `reg` is a prior). On error `self` is left unchanged.
    fn m_step(&mut self, stats: &Self::Stats, reg: &Regularisation) -> Result<MStepReport>;

    /// Log-density of the prior implied by `reg` at the current parameters,
    /// up to a constant; 0 when `reg` is not a prior. EM increases
    /// `log p(X) + log_prior` monotonically when `reg` is a proper prior.
    fn log_prior(&self, reg: &Regularisation) -> f64 {
        let _ = reg;
        0.0
    }

    /// Draws one frame from state `state` into `out` (length `D`).
    fn sample_into<R: Rng + ?Sized>(
        &self,
        state: usize,
        rng: &mut R,
        out: &mut [f64],
    ) -> Result<()>;

    /// Number of free parameters (for AIC/BIC).
    fn n_parameters(&self) -> usize;

    /// New parameters of this emission's structure fitted to frames with
    /// fixed weights, `θ = argmax_θ Σ_t Σ_i w_ti log b_i(x_t; θ)` (plus the
    /// regularisation): the initialisation of HMMs and mixtures (weights from
    /// time bins, k-means clusters or random soft assignments). `parts` are
    /// blocks of frames with their `T × S` weights; `rng` serves emissions
    /// whose initialisation draws (a mixture's k-means++ per state), so that
    /// restarts from different seeds differ.
    ///
    /// This is the one place where an emission is built from nothing: `self`
    /// is a template whose parameter values mean nothing yet (e.g.
    /// [`Gaussian::standard`]'s `μ = 0, Σ = I`). The default, [`fit_weighted`],
    /// is one [`Emission::accumulate`] and one [`Emission::m_step`] from the
    /// template (iterated when values are missing), which is exact when the
    /// sufficient statistics do not depend on the current parameters (Gaussian,
    /// categorical, Poisson on complete data). An emission whose statistics do
    /// depend on them (Student-t weights, mixture responsibilities) must
    /// override it and start from something the data decide: [`StudentT`]
    /// starts from the weighted Gaussian fit and iterates its ECME steps,
    /// [`MixtureEmission`] seeds every state's components by weighted
    /// k-means++ on the frames that state owns.
    fn initialise<R: Rng + ?Sized>(
        &self,
        parts: &[(Frames<'_>, &[f64])],
        reg: &Regularisation,
        rng: &mut R,
    ) -> Result<(Self, MStepReport)> {
        let _ = rng;
        fit_weighted(self, parts, reg)
    }
}

/// Maximum number of re-estimations by [`fit_weighted`] when values are missing.
const MAX_REFINE: usize = 200;

/// The default [`Emission::initialise`]: fits the parameters of `template`'s
/// structure to frames with fixed weights,
/// `θ = argmax_θ Σ_t Σ_i w_ti log b_i(x_t; θ)` (plus the regularisation), by
/// EM for the fixed assignment. `parts` are blocks of frames with their
/// `T × S` weights. A [placeholder template](Gaussian::standard)'s parameter
/// values are ignored; a template with real parameters starts the iterations
/// below when values are missing.
///
/// With complete data this is one accumulation and one M-step. With missing
/// values the expected statistics depend on the parameters, so the step is
/// repeated from its own result (EM for the fixed assignment) while the
/// objective `Σ w log b + log prior` gains more than `1e-14` relative, at most
/// 200 times, and the best model is returned; the first step from a
/// placeholder takes the missing values at each state's reference point, the
/// following ones their conditional expectation.
pub fn fit_weighted<E: Emission>(
    template: &E,
    parts: &[(Frames<'_>, &[f64])],
    reg: &Regularisation,
) -> Result<(E, MStepReport)> {
    let step = |model: &E| -> Result<(E, MStepReport)> {
        let mut stats = model.new_stats();
        for (frames, w) in parts {
            model.accumulate(*frames, w, &mut stats)?;
        }
        let mut next = model.clone();
        let report = next.m_step(&stats, reg)?;
        Ok((next, report))
    };
    let (mut model, mut report) = step(template)?;
    if !parts.iter().any(|(frames, _)| frames.has_missing()) {
        return Ok((model, report));
    }
    let objective = |model: &E| -> Result<f64> {
        let mut total = model.log_prior(reg);
        for (frames, w) in parts {
            let log_b = model.log_density(*frames)?;
            total += log_b
                .iter()
                .zip(w.iter())
                .filter(|(_, w)| **w != 0.0)
                .map(|(l, w)| w * l)
                .sum::<f64>();
        }
        Ok(total)
    };
    let mut best = objective(&model)?;
    for _ in 0..MAX_REFINE {
        let (next, r) = step(&model)?;
        let obj = objective(&next)?;
        // EM increases the objective; a gain within rounding ends the
        // iterations, and a fall (which only an added-diagonal regulariser
        // can cause) keeps the model before it.
        if obj <= best {
            break;
        }
        let gain = obj - best;
        model = next;
        report = r;
        best = obj;
        if gain <= 1e-14 * (1.0 + obj.abs()) {
            break;
        }
    }
    Ok((model, report))
}

/// Errors unless `found == expected` frame dimension.
pub fn check_dim(expected: usize, found: usize) -> Result<()> {
    if expected == found {
        Ok(())
    } else {
        Err(EmissionError::DimensionMismatch {
            context: "frame dimension",
            expected,
            found,
        })
    }
}

/// Errors unless a buffer has length `expected`; `context` names the buffer
/// in the message ("sample output buffer", "log-density output buffer", …).
pub fn check_len(context: &'static str, expected: usize, found: usize) -> Result<()> {
    if expected == found {
        Ok(())
    } else {
        Err(EmissionError::DimensionMismatch {
            context,
            expected,
            found,
        })
    }
}

/// Errors unless `state < n_states`, naming both.
pub fn check_state(state: usize, n_states: usize) -> Result<()> {
    if state < n_states {
        Ok(())
    } else {
        Err(EmissionError::InvalidParameter {
            name: "state",
            reason: format!("state {state} out of range (model has {n_states} states)"),
        })
    }
}

/// Validates a list of marginal dimensions: non-empty, in range, no repeats.
pub fn check_dims(dims: &[usize], dim: usize) -> Result<()> {
    let err = |reason| {
        Err(EmissionError::InvalidDims {
            dims: dims.to_vec(),
            dim,
            reason,
        })
    };
    if dims.is_empty() {
        return err("no dimension selected");
    }
    if dims.iter().any(|&d| d >= dim) {
        return err("dimension out of range");
    }
    let mut seen = vec![false; dim];
    for &d in dims {
        if std::mem::replace(&mut seen[d], true) {
            return err("dimension repeated");
        }
    }
    Ok(())
}
