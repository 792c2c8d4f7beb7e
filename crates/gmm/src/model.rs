//! The mixture `p(x) = Σ_k π_k c_k(x)` over the `K` states of any emission.

use crate::error::{GmmError, Result};
use phasekit_emission::linalg::log_sum_exp;
use phasekit_emission::{Emission, Frames, Gaussian, Marginal};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Format version written into serialised mixtures.
pub const MODEL_FORMAT_VERSION: u32 = 1;

#[derive(Serialize, Deserialize)]
struct MixtureParams<E> {
    format_version: u32,
    weights: Vec<f64>,
    components: E,
}

/// A finite mixture whose components are the `K` states of an [`Emission`].
///
/// `Gmm` (that is, `Gmm<Gaussian>`) is a Gaussian mixture with full,
/// diagonal, spherical or tied covariances; any other emission (Poisson,
/// categorical, …) gives the corresponding mixture with no new code.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(
    try_from = "MixtureParams<E>",
    into = "MixtureParams<E>",
    bound = "E: Emission + Serialize + for<'a> Deserialize<'a>"
)]
pub struct Gmm<E: Emission = Gaussian> {
    pub(crate) weights: Vec<f64>,
    pub(crate) log_weights: Vec<f64>,
    pub(crate) components: E,
}

impl<E: Emission> TryFrom<MixtureParams<E>> for Gmm<E> {
    type Error = GmmError;
    fn try_from(p: MixtureParams<E>) -> Result<Self> {
        if p.format_version != MODEL_FORMAT_VERSION {
            return Err(GmmError::InvalidParameter {
                name: "format_version",
                reason: format!(
                    "mixture file has format version {}, this build reads version {MODEL_FORMAT_VERSION}",
                    p.format_version
                ),
            });
        }
        Gmm::new(p.weights, p.components)
    }
}

impl<E: Emission> From<Gmm<E>> for MixtureParams<E> {
    fn from(m: Gmm<E>) -> Self {
        MixtureParams {
            format_version: MODEL_FORMAT_VERSION,
            weights: m.weights,
            components: m.components,
        }
    }
}

fn ln0(p: f64) -> f64 {
    if p > 0.0 {
        p.ln()
    } else {
        f64::NEG_INFINITY
    }
}

impl<E: Emission> Gmm<E> {
    /// Builds a mixture; `weights` has one entry per state of `components`,
    /// finite, non-negative, summing to 1 (within `1e-8`, then renormalised).
    ///
    /// Weights that already sum to 1 up to rounding (`|Σ − 1| ≤ 2 K ε`) are kept
    /// bit for bit: dividing a normalised vector by its rounded sum again can move
    /// entries by an ulp, so a saved model would not reload exactly.
    pub fn new(weights: Vec<f64>, components: E) -> Result<Self> {
        let k = components.n_states();
        if weights.len() != k {
            return Err(GmmError::InvalidParameter {
                name: "weights",
                reason: format!("{} weights for {k} components", weights.len()),
            });
        }
        if let Some(j) = weights.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(GmmError::InvalidParameter {
                name: "weights",
                reason: format!("component {j}: weight {} is not a probability", weights[j]),
            });
        }
        let total: f64 = weights.iter().sum();
        if (total - 1.0).abs() > 1e-8 {
            return Err(GmmError::InvalidParameter {
                name: "weights",
                reason: format!("weights sum to {total}, not 1"),
            });
        }
        let weights: Vec<f64> = if (total - 1.0).abs() <= 2.0 * k as f64 * f64::EPSILON {
            weights
        } else {
            weights.iter().map(|w| w / total).collect()
        };
        let log_weights = weights.iter().map(|w| ln0(*w)).collect();
        Ok(Gmm {
            weights,
            log_weights,
            components,
        })
    }

    /// Number of components `K`.
    pub fn n_components(&self) -> usize {
        self.weights.len()
    }

    /// Frame dimension `D`.
    pub fn dim(&self) -> usize {
        self.components.dim()
    }

    /// Mixture weights `π_k`.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// The component distributions.
    pub fn components(&self) -> &E {
        &self.components
    }

    /// Validates frames against the components (dimension, support).
    pub fn check_frames(&self, frames: Frames<'_>) -> Result<()> {
        if frames.is_empty() {
            return Err(GmmError::TooFewFrames("no frames given".into()));
        }
        Ok(self.components.check_frames(frames)?)
    }

    /// Writes `out[t·K + k] = log π_k + log c_k(x_t)` and returns nothing else.
    pub(crate) fn joint_log_into(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()> {
        let k = self.n_components();
        self.components.log_density_into(frames, out)?;
        for row in out.chunks_exact_mut(k) {
            for (v, lw) in row.iter_mut().zip(&self.log_weights) {
                *v += lw;
            }
        }
        Ok(())
    }

    /// `log p(x_t) = logsumexp_k (log π_k + log c_k(x_t))` for every frame.
    pub fn score_samples(&self, frames: Frames<'_>) -> Result<Vec<f64>> {
        self.check_frames(frames)?;
        let k = self.n_components();
        let mut joint = vec![0.0; frames.len() * k];
        self.joint_log_into(frames, &mut joint)?;
        Ok(joint.chunks_exact(k).map(log_sum_exp).collect())
    }

    /// `Σ_t log p(x_t)`.
    pub fn log_likelihood(&self, frames: Frames<'_>) -> Result<f64> {
        Ok(self.score_samples(frames)?.iter().sum())
    }

    /// Responsibilities `r_tk = π_k c_k(x_t) / p(x_t)`, `N × K` row-major
    /// (a frame impossible under every component gets all zeros).
    pub fn responsibilities(&self, frames: Frames<'_>) -> Result<Vec<f64>> {
        self.check_frames(frames)?;
        let k = self.n_components();
        let mut r = vec![0.0; frames.len() * k];
        self.joint_log_into(frames, &mut r)?;
        for row in r.chunks_exact_mut(k) {
            normalise_log_row(row);
        }
        Ok(r)
    }

    /// Most responsible component of every frame (ties to the lower index).
    pub fn predict(&self, frames: Frames<'_>) -> Result<Vec<usize>> {
        let k = self.n_components();
        Ok(self
            .responsibilities(frames)?
            .chunks_exact(k)
            .map(|row| {
                row.iter()
                    .enumerate()
                    .fold(
                        (0, f64::NEG_INFINITY),
                        |b, (j, v)| if *v > b.1 { (j, *v) } else { b },
                    )
                    .0
            })
            .collect())
    }

    /// Draws `n` frames; returns them (`n × D`) and their components.
    pub fn sample<R: Rng + ?Sized>(&self, n: usize, rng: &mut R) -> Result<(Vec<f64>, Vec<usize>)> {
        let d = self.dim();
        let mut frames = vec![0.0; n * d];
        let mut labels = Vec::with_capacity(n);
        for t in 0..n {
            let k = phasekit_emission::categorical::sample_index(&self.weights, rng);
            labels.push(k);
            self.components
                .sample_into(k, rng, &mut frames[t * d..(t + 1) * d])?;
        }
        Ok((frames, labels))
    }

    /// Free parameters: `K − 1` weights plus the components'.
    pub fn n_parameters(&self) -> usize {
        self.n_components() - 1 + self.components.n_parameters()
    }

    /// `−2 log p(X) + 2 p`.
    pub fn aic(&self, frames: Frames<'_>) -> Result<f64> {
        Ok(-2.0 * self.log_likelihood(frames)? + 2.0 * self.n_parameters() as f64)
    }

    /// `−2 log p(X) + p log N`.
    pub fn bic(&self, frames: Frames<'_>) -> Result<f64> {
        Ok(-2.0 * self.log_likelihood(frames)?
            + self.n_parameters() as f64 * (frames.len() as f64).ln())
    }
}

impl<E: Marginal> Gmm<E> {
    /// The mixture of the components' marginals on `dims` (same weights).
    pub fn marginal(&self, dims: &[usize]) -> Result<Self> {
        Gmm::new(self.weights.clone(), self.components.marginal(dims)?)
    }
}

/// Turns a row of log-terms into normalised probabilities in place (all zero if every term is `−inf`).
pub(crate) fn normalise_log_row(row: &mut [f64]) -> f64 {
    let lse = log_sum_exp(row);
    if lse == f64::NEG_INFINITY {
        row.fill(0.0);
    } else {
        row.iter_mut().for_each(|v| *v = (*v - lse).exp());
    }
    lse
}
