//! Multivariate Gaussian emissions with full, diagonal, spherical or tied covariance.
//!
//! `log N(x; μ_i, Σ_i) = −½ (D log 2π + log|Σ_i| + (x − μ_i)ᵀ Σ_i⁻¹ (x − μ_i))`,
//! with `log|Σ_i| = 2 Σ_d log L_dd` from the Cholesky factor `Σ_i = L Lᵀ` and the
//! Mahalanobis term `‖W (x − μ_i)‖²` where `W = L⁻¹` is obtained by a triangular
//! solve (the Cholesky factor of the precision). Neither `Σ⁻¹` nor `|Σ|` is ever formed.
//!
//! Sufficient statistics are accumulated about a per-state reference point
//! (the current mean): `n_i = Σ γ`, `s_i = Σ γ (x − c_i)`, `Q_i = Σ γ (x − c_i)(x − c_i)ᵀ`.
//! The M-step then computes the scatter `Q_i − s_i s_iᵀ / n_i` without the
//! cancellation that raw second moments suffer when the data sit far from the
//! origin. The range of every dimension is tracked as well, so that a constant
//! dimension (or identical frames) gives an exactly zero scatter, not rounding
//! noise that would pass for a tiny positive variance.

mod kernels;
mod missing;
mod simd;
mod stats;

pub use kernels::NEGLIGIBLE_WEIGHT;
pub use stats::{weighted_mean_covariance, GaussianStats};

use crate::capability::{check_split, ConcatStates, Conditional, ConditionalSplit};
use crate::error::{EmissionError, Result};
use crate::linalg::{self, packed_len, packed_lower_sq_norm};
use crate::regularisation::{CovarianceRegularisation, MStepReport, Regularisation};
use crate::{check_dim, check_dims, check_len, check_state, Emission, Frames, Marginal, Shape};
use kernels::with_diff;
use nalgebra::DMatrix;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Structure of the covariance matrices, as in hmmlearn's `covariance_type`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CovarianceType {
    /// A full `D × D` covariance per state.
    Full,
    /// A diagonal covariance per state.
    #[serde(alias = "diag")]
    Diagonal,
    /// `σ_i² I` per state.
    Spherical,
    /// One full covariance shared by all states.
    Tied,
}

impl CovarianceType {
    /// Number of stored covariance values for `s` states of dimension `d`.
    pub fn raw_len(self, s: usize, d: usize) -> usize {
        match self {
            CovarianceType::Full => s * d * d,
            CovarianceType::Diagonal => s * d,
            CovarianceType::Spherical => s,
            CovarianceType::Tied => d * d,
        }
    }
}

/// Serialised form: the parameters only; the factors are recomputed (and the
/// parameters re-validated) on deserialisation.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct GaussianParams {
    covariance_type: CovarianceType,
    n_states: usize,
    dim: usize,
    means: Vec<f64>,
    covariances: Vec<f64>,
}

/// `S` Gaussian states of dimension `D`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "GaussianParams", into = "GaussianParams")]
pub struct Gaussian {
    kind: CovarianceType,
    n_states: usize,
    dim: usize,
    /// True for a [`Gaussian::standard`] template whose means are placeholders:
    /// its statistics then take each state's first weighted frame as reference
    /// point instead of the (possibly far) placeholder mean.
    placeholder: bool,
    /// `S × D`, row-major.
    means: Vec<f64>,
    /// Native shape (see [`CovarianceType::raw_len`]); full matrices are row-major and symmetric.
    covariances: Vec<f64>,
    /// Full/tied: packed `L⁻¹` per covariance; diagonal: `1/σ` per state and dim;
    /// spherical: `1/σ` per state.
    whiten: Vec<f64>,
    /// Full/tied: `whiten` regrouped for one frame under every state at once:
    /// states `8g .. 8g + 8` interleaved entry by entry (`[group][entry][lane]`,
    /// absent states zero); see [`linalg::sq_norms_lanes`].
    whiten_lanes: Vec<f64>,
    /// Full/tied: packed `L` per covariance; diagonal/spherical: `σ` (for sampling).
    factor: Vec<f64>,
    /// `−½ (D log 2π + log|Σ_i|)` per state.
    log_norm: Vec<f64>,
    /// The `r` an added-diagonal regularisation put on every covariance at the
    /// last M-step (0 otherwise, and for a model built or loaded from parameters).
    /// The expected statistics of missing values take it off their
    /// conditional covariance, so that it is not compounded (see `Imputation`).
    #[serde(skip)]
    added_diagonal: f64,
}

impl TryFrom<GaussianParams> for Gaussian {
    type Error = EmissionError;
    fn try_from(p: GaussianParams) -> Result<Self> {
        // A corrupted file may claim any sizes: compare without overflowing.
        if p.dim == 0 || p.n_states.checked_mul(p.dim) != Some(p.means.len()) {
            return Err(EmissionError::InvalidParameter {
                name: "means",
                reason: format!(
                    "expected {} states × {} dims, found {} values",
                    p.n_states,
                    p.dim,
                    p.means.len()
                ),
            });
        }
        Gaussian::new(p.covariance_type, p.dim, p.means, p.covariances)
    }
}

impl From<Gaussian> for GaussianParams {
    fn from(g: Gaussian) -> Self {
        GaussianParams {
            covariance_type: g.kind,
            n_states: g.n_states,
            dim: g.dim,
            means: g.means,
            covariances: g.covariances,
        }
    }
}

fn invalid(name: &'static str, reason: String) -> EmissionError {
    EmissionError::InvalidParameter { name, reason }
}

/// Cholesky of a full covariance, or the error naming `state`.
fn factor_full(cov: &DMatrix<f64>, state: usize, detail: &str) -> Result<DMatrix<f64>> {
    linalg::cholesky(cov).ok_or_else(|| EmissionError::NotPositiveDefinite {
        state,
        component: None,
        detail: detail.to_string(),
    })
}

impl Gaussian {
    /// Builds `S = means.len() / dim` Gaussian states.
    ///
    /// `means` is `S × D` row-major; `covariances` has the native shape of `kind`:
    /// full `S × D × D`, diagonal `S × D` (variances), spherical `S` (variances),
    /// tied `D × D`. Full matrices must be symmetric (to `1e-9` relative) and
    /// positive definite; variances must be positive; everything finite.
    pub fn new(
        kind: CovarianceType,
        dim: usize,
        means: Vec<f64>,
        covariances: Vec<f64>,
    ) -> Result<Self> {
        if dim == 0 {
            return Err(invalid("dim", "must be at least 1".into()));
        }
        if means.is_empty() || !means.len().is_multiple_of(dim) {
            return Err(invalid(
                "means",
                format!(
                    "{} values is not a positive multiple of dim {dim}",
                    means.len()
                ),
            ));
        }
        let n_states = means.len() / dim;
        if let Some(i) = means.iter().position(|v| !v.is_finite()) {
            return Err(invalid(
                "means",
                format!(
                    "state {}, dim {}: value {} is not finite",
                    i / dim,
                    i % dim,
                    means[i]
                ),
            ));
        }
        let expected = kind.raw_len(n_states, dim);
        if covariances.len() != expected {
            return Err(invalid(
                "covariances",
                format!(
                    "{kind:?} covariance for {n_states} states of dim {dim} needs {expected} values, found {}",
                    covariances.len()
                ),
            ));
        }
        if let Some(i) = covariances.iter().position(|v| !v.is_finite()) {
            return Err(invalid(
                "covariances",
                format!("entry {i}: value {} is not finite", covariances[i]),
            ));
        }
        match kind {
            CovarianceType::Diagonal | CovarianceType::Spherical => {
                if let Some(i) = covariances.iter().position(|v| *v <= 0.0) {
                    let per = if kind == CovarianceType::Diagonal {
                        dim
                    } else {
                        1
                    };
                    return Err(EmissionError::NotPositiveDefinite {
                        state: i / per,
                        component: None,
                        detail: format!(" (variance {} is not positive)", covariances[i]),
                    });
                }
            }
            CovarianceType::Full | CovarianceType::Tied => {
                for (k, m) in covariances.chunks_exact(dim * dim).enumerate() {
                    for r in 0..dim {
                        for c in 0..r {
                            let (a, b) = (m[r * dim + c], m[c * dim + r]);
                            let scale = m[r * dim + r]
                                .abs()
                                .max(m[c * dim + c].abs())
                                .max(f64::MIN_POSITIVE);
                            if (a - b).abs() > 1e-9 * scale {
                                return Err(invalid(
                                    "covariances",
                                    format!(
                                        "covariance {k} is not symmetric at ({r}, {c}): {a} vs {b}"
                                    ),
                                ));
                            }
                        }
                    }
                }
            }
        }
        let mut g = Gaussian {
            kind,
            n_states,
            dim,
            placeholder: false,
            means,
            covariances,
            whiten: Vec::new(),
            whiten_lanes: Vec::new(),
            factor: Vec::new(),
            log_norm: Vec::new(),
            added_diagonal: 0.0,
        };
        g.refactor()?;
        Ok(g)
    }

    /// Full covariance per state: `covariances` is `S × D × D`.
    pub fn full(dim: usize, means: Vec<f64>, covariances: Vec<f64>) -> Result<Self> {
        Self::new(CovarianceType::Full, dim, means, covariances)
    }

    /// Diagonal covariance per state: `variances` is `S × D`.
    pub fn diagonal(dim: usize, means: Vec<f64>, variances: Vec<f64>) -> Result<Self> {
        Self::new(CovarianceType::Diagonal, dim, means, variances)
    }

    /// Spherical covariance `σ_i² I` per state: `variances` has `S` values.
    pub fn spherical(dim: usize, means: Vec<f64>, variances: Vec<f64>) -> Result<Self> {
        Self::new(CovarianceType::Spherical, dim, means, variances)
    }

    /// One full `D × D` covariance shared by all states.
    pub fn tied(dim: usize, means: Vec<f64>, covariance: Vec<f64>) -> Result<Self> {
        Self::new(CovarianceType::Tied, dim, means, covariance)
    }

    /// `S` states with zero means and identity covariances: a template whose
    /// parameters an initialisation or M-step fills in.
    ///
    /// ```
    /// use phasekit_emission::{CovarianceType, Emission, Gaussian, Shape};
    /// let template = Gaussian::standard(CovarianceType::Full, Shape { n_states: 4, dim: 12 })?;
    /// assert_eq!((template.n_states(), template.dim()), (4, 12));
    /// # Ok::<(), phasekit_emission::EmissionError>(())
    /// ```
    pub fn standard(kind: CovarianceType, shape: Shape) -> Result<Self> {
        let Shape { n_states, dim } = shape;
        if n_states == 0 {
            return Err(invalid("n_states", "must be at least 1".into()));
        }
        let eye: Vec<f64> = (0..dim * dim)
            .map(|k| if k % (dim + 1) == 0 { 1.0 } else { 0.0 })
            .collect();
        let covs = match kind {
            CovarianceType::Full => eye.repeat(n_states),
            CovarianceType::Tied => eye,
            CovarianceType::Diagonal => vec![1.0; n_states * dim],
            CovarianceType::Spherical => vec![1.0; n_states],
        };
        let mut g = Self::new(kind, dim, vec![0.0; n_states * dim], covs)?;
        g.placeholder = true;
        Ok(g)
    }

    /// Recomputes the factors from `means`/`covariances`.
    fn refactor(&mut self) -> Result<()> {
        let (s, d) = (self.n_states, self.dim);
        let half_log_2pi = 0.5 * d as f64 * (2.0 * PI).ln();
        self.whiten.clear();
        self.whiten_lanes.clear();
        self.factor.clear();
        self.log_norm.clear();
        match self.kind {
            CovarianceType::Full | CovarianceType::Tied => {
                let mut log_dets = Vec::new();
                for (k, m) in self.covariances.chunks_exact(d * d).enumerate() {
                    let cov = DMatrix::from_row_slice(d, d, m);
                    let l = factor_full(&cov, k, "")?;
                    log_dets.push(2.0 * l.diagonal().iter().map(|v| v.ln()).sum::<f64>());
                    linalg::pack_lower(&linalg::lower_triangular_inverse(&l), &mut self.whiten);
                    linalg::pack_lower(&l, &mut self.factor);
                }
                for i in 0..s {
                    let ld = if self.kind == CovarianceType::Tied {
                        log_dets[0]
                    } else {
                        log_dets[i]
                    };
                    self.log_norm.push(-half_log_2pi - 0.5 * ld);
                }
                let (pl, sl) = (packed_len(d), linalg::STATE_LANES);
                self.whiten_lanes = vec![0.0; s.div_ceil(sl) * pl * sl];
                for i in 0..s {
                    let w = match self.kind {
                        CovarianceType::Full => &self.whiten[i * pl..(i + 1) * pl],
                        _ => &self.whiten[..pl],
                    };
                    let (g, l) = (i / sl, i % sl);
                    for (e, v) in w.iter().enumerate() {
                        self.whiten_lanes[(g * pl + e) * sl + l] = *v;
                    }
                }
            }
            CovarianceType::Diagonal => {
                for i in 0..s {
                    let v = &self.covariances[i * d..(i + 1) * d];
                    self.log_norm
                        .push(-half_log_2pi - 0.5 * v.iter().map(|x| x.ln()).sum::<f64>());
                    self.factor.extend(v.iter().map(|x| x.sqrt()));
                    self.whiten.extend(v.iter().map(|x| 1.0 / x.sqrt()));
                }
            }
            CovarianceType::Spherical => {
                for &v in &self.covariances {
                    self.log_norm.push(-half_log_2pi - 0.5 * d as f64 * v.ln());
                    self.factor.push(v.sqrt());
                    self.whiten.push(1.0 / v.sqrt());
                }
            }
        }
        Ok(())
    }

    /// Covariance structure.
    pub fn covariance_type(&self) -> CovarianceType {
        self.kind
    }

    /// All means, `S × D` row-major.
    pub fn means(&self) -> &[f64] {
        &self.means
    }

    /// Mean of state `i`.
    ///
    /// # Panics
    /// If `i ≥ S` (like slice indexing); [`Gaussian::state_mean`] is the checked form.
    pub fn mean(&self, i: usize) -> &[f64] {
        &self.means[i * self.dim..(i + 1) * self.dim]
    }

    /// Mean of state `i`, or the error naming it.
    pub fn state_mean(&self, i: usize) -> Result<&[f64]> {
        check_state(i, self.n_states)?;
        Ok(self.mean(i))
    }

    /// Covariances in their native shape (see [`CovarianceType::raw_len`]).
    pub fn covariances_raw(&self) -> &[f64] {
        &self.covariances
    }

    /// The full `D × D` covariance of state `i`, whatever the structure.
    ///
    /// # Panics
    /// If `i ≥ S` (like slice indexing).
    pub fn covariance(&self, i: usize) -> DMatrix<f64> {
        let d = self.dim;
        match self.kind {
            CovarianceType::Full => {
                DMatrix::from_row_slice(d, d, &self.covariances[i * d * d..(i + 1) * d * d])
            }
            CovarianceType::Tied => DMatrix::from_row_slice(d, d, &self.covariances),
            CovarianceType::Diagonal => DMatrix::from_diagonal(
                &nalgebra::DVector::from_column_slice(&self.covariances[i * d..(i + 1) * d]),
            ),
            CovarianceType::Spherical => DMatrix::identity(d, d) * self.covariances[i],
        }
    }

    /// The lower Cholesky factor `L` of `Σ_i` (`Σ_i = L Lᵀ`).
    ///
    /// # Panics
    /// If `i ≥ S` (like slice indexing).
    pub fn cholesky_factor(&self, i: usize) -> DMatrix<f64> {
        let d = self.dim;
        match self.kind {
            CovarianceType::Full => {
                linalg::unpack_lower(&self.factor[i * packed_len(d)..(i + 1) * packed_len(d)], d)
            }
            CovarianceType::Tied => linalg::unpack_lower(&self.factor, d),
            CovarianceType::Diagonal => DMatrix::from_diagonal(
                &nalgebra::DVector::from_column_slice(&self.factor[i * d..(i + 1) * d]),
            ),
            CovarianceType::Spherical => DMatrix::identity(d, d) * self.factor[i],
        }
    }

    /// `log|Σ_i|`.
    ///
    /// # Panics
    /// If `i ≥ S` (like slice indexing).
    pub fn log_det(&self, i: usize) -> f64 {
        -2.0 * (self.log_norm[i] + 0.5 * self.dim as f64 * (2.0 * PI).ln())
    }

    /// `log N(x; μ_i, Σ_i)` of one complete frame `x` (length `D`, finite),
    /// no allocation for `D ≤ 64`. Errors name a wrong state, length or value;
    /// frames with missing values go through [`Emission::log_density_into`].
    pub fn log_density_one(&self, i: usize, x: &[f64]) -> Result<f64> {
        check_state(i, self.n_states)?;
        check_len("frame", self.dim, x.len())?;
        if let Some(k) = x.iter().position(|v| !v.is_finite()) {
            return Err(EmissionError::InvalidValue {
                frame: 0,
                column: k,
                value: x[k],
                reason: "log_density_one needs a complete, finite frame",
            });
        }
        Ok(self.log_density_raw(i, x))
    }

    /// [`Gaussian::log_density_one`] without checks: `i < S`, `x.len() == D`.
    #[inline]
    fn log_density_raw(&self, i: usize, x: &[f64]) -> f64 {
        let d = self.dim;
        let mu = self.mean(i);
        let maha = match self.kind {
            CovarianceType::Full | CovarianceType::Tied => {
                let w = if self.kind == CovarianceType::Full {
                    &self.whiten[i * packed_len(d)..(i + 1) * packed_len(d)]
                } else {
                    &self.whiten[..]
                };
                with_diff(x, mu, |diff| packed_lower_sq_norm(w, diff))
            }
            CovarianceType::Diagonal => {
                let w = &self.whiten[i * d..(i + 1) * d];
                x.iter()
                    .zip(mu)
                    .zip(w)
                    .map(|((a, m), s)| ((a - m) * s).powi(2))
                    .sum()
            }
            CovarianceType::Spherical => {
                let s = self.whiten[i];
                x.iter().zip(mu).map(|(a, m)| ((a - m) * s).powi(2)).sum()
            }
        };
        self.log_norm[i] - 0.5 * maha
    }
}

impl Emission for Gaussian {
    type Stats = GaussianStats;

    fn n_states(&self) -> usize {
        self.n_states
    }

    fn dim(&self) -> usize {
        self.dim
    }

    fn log_density_into(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()> {
        check_dim(self.dim, frames.dim())?;
        let s = self.n_states;
        check_len("log-density output buffer", frames.len() * s, out.len())?;
        if frames.has_missing() {
            return self.log_density_missing(frames, out);
        }
        self.log_density_complete(frames, out);
        Ok(())
    }

    fn new_stats(&self) -> GaussianStats {
        let (s, d) = (self.n_states, self.dim);
        let sq = match self.kind {
            CovarianceType::Full | CovarianceType::Tied => s * d * d,
            CovarianceType::Diagonal | CovarianceType::Spherical => s * d,
        };
        GaussianStats {
            kind: self.kind,
            dim: d,
            shift: self.means.clone(),
            anchor_lazily: self.placeholder,
            weight: vec![0.0; s],
            sum: vec![0.0; s * d],
            sum_sq: vec![0.0; sq],
            lo: vec![f64::INFINITY; s * d],
            hi: vec![f64::NEG_INFINITY; s * d],
        }
    }

    fn accumulate(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) -> Result<()> {
        check_dim(self.dim, frames.dim())?;
        let (s, d) = (self.n_states, self.dim);
        check_len("accumulate weights", frames.len() * s, weights.len())?;
        if !stats.has_shape(self.kind, s, d) {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        self.anchor(frames, weights, stats);
        if frames.has_missing() {
            return self.accumulate_missing(frames, weights, stats);
        }
        self.accumulate_complete(frames, weights, stats);
        Ok(())
    }

    fn m_step(&mut self, stats: &GaussianStats, reg: &Regularisation) -> Result<MStepReport> {
        self.maximise(stats, reg)
    }

    fn log_prior(&self, reg: &Regularisation) -> f64 {
        let CovarianceRegularisation::InverseWishart { scale, dof } = reg.covariance() else {
            return 0.0;
        };
        let d = self.dim;
        let expo = 0.5 * (dof + d as f64 + 1.0);
        // log IW(Σ; ψI, ν) = −(ν+D+1)/2 log|Σ| − ψ/2 tr(Σ⁻¹) + const, tr(Σ⁻¹) = ‖L⁻¹‖²_F.
        let term = |log_det: f64, tr_inv: f64| -expo * log_det - 0.5 * scale * tr_inv;
        match self.kind {
            CovarianceType::Full => (0..self.n_states)
                .map(|i| {
                    let w = &self.whiten[i * packed_len(d)..(i + 1) * packed_len(d)];
                    term(self.log_det(i), w.iter().map(|v| v * v).sum())
                })
                .sum(),
            CovarianceType::Tied => term(self.log_det(0), self.whiten.iter().map(|v| v * v).sum()),
            CovarianceType::Diagonal | CovarianceType::Spherical => (0..self.n_states)
                .map(|i| {
                    let tr: f64 = match self.kind {
                        CovarianceType::Diagonal => {
                            self.whiten[i * d..(i + 1) * d].iter().map(|v| v * v).sum()
                        }
                        _ => d as f64 * self.whiten[i] * self.whiten[i],
                    };
                    term(self.log_det(i), tr)
                })
                .sum(),
        }
    }

    fn sample_into<R: Rng + ?Sized>(
        &self,
        state: usize,
        rng: &mut R,
        out: &mut [f64],
    ) -> Result<()> {
        check_state(state, self.n_states)?;
        let d = self.dim;
        check_len("sample output buffer", d, out.len())?;
        let mu = self.mean(state);
        match self.kind {
            CovarianceType::Full | CovarianceType::Tied => {
                let l = if self.kind == CovarianceType::Full {
                    &self.factor[state * packed_len(d)..(state + 1) * packed_len(d)]
                } else {
                    &self.factor[..]
                };
                // x = μ + L z, in place: row r of L z needs z_0..z_r only, so
                // going from the last row up never reads an overwritten z.
                for o in out.iter_mut() {
                    *o = rng.sample(StandardNormal);
                }
                for r in (0..d).rev() {
                    let row = &l[r * (r + 1) / 2..r * (r + 1) / 2 + r + 1];
                    let v: f64 = row.iter().zip(&out[..=r]).map(|(a, b)| a * b).sum();
                    out[r] = mu[r] + v;
                }
            }
            CovarianceType::Diagonal => {
                for k in 0..d {
                    let z: f64 = rng.sample(StandardNormal);
                    out[k] = mu[k] + self.factor[state * d + k] * z;
                }
            }
            CovarianceType::Spherical => {
                for k in 0..d {
                    let z: f64 = rng.sample(StandardNormal);
                    out[k] = mu[k] + self.factor[state] * z;
                }
            }
        }
        Ok(())
    }

    fn n_parameters(&self) -> usize {
        let (s, d) = (self.n_states, self.dim);
        s * d
            + match self.kind {
                CovarianceType::Full => s * d * (d + 1) / 2,
                CovarianceType::Diagonal => s * d,
                CovarianceType::Spherical => s,
                CovarianceType::Tied => d * (d + 1) / 2,
            }
    }
}

impl Marginal for Gaussian {
    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        let d = self.dim;
        check_dims(dims, d)?;
        let means: Vec<f64> = (0..self.n_states)
            .flat_map(|i| dims.iter().map(move |&k| (i, k)))
            .map(|(i, k)| self.means[i * d + k])
            .collect();
        let sub = |block: &[f64]| -> Vec<f64> {
            dims.iter()
                .flat_map(|&r| dims.iter().map(move |&c| block[r * d + c]))
                .collect()
        };
        let covs = match self.kind {
            CovarianceType::Full => self.covariances.chunks_exact(d * d).flat_map(sub).collect(),
            CovarianceType::Tied => sub(&self.covariances),
            CovarianceType::Diagonal => self
                .covariances
                .chunks_exact(d)
                .flat_map(|v| dims.iter().map(move |&k| v[k]))
                .collect(),
            CovarianceType::Spherical => self.covariances.clone(),
        };
        Gaussian::new(self.kind, dims.len(), means, covs)
    }
}

impl ConcatStates for Gaussian {
    /// Same covariance structure and dimension; two tied Gaussians join only
    /// when they share the same covariance (convert with
    /// [`Gaussian::to_full`] otherwise).
    fn concat_states(&self, other: &Self) -> Result<Self> {
        check_dim(self.dim, other.dim)?;
        if self.kind != other.kind {
            return Err(invalid(
                "covariance_type",
                format!(
                    "cannot join {:?} and {:?} Gaussian states; convert both with to_full()",
                    self.kind, other.kind
                ),
            ));
        }
        let mut means = self.means.clone();
        means.extend_from_slice(&other.means);
        let covs = if self.kind == CovarianceType::Tied {
            if self.covariances != other.covariances {
                return Err(invalid(
                    "covariance_type",
                    "two tied Gaussians with different covariances cannot share one; convert both with to_full()".into(),
                ));
            }
            self.covariances.clone()
        } else {
            let mut c = self.covariances.clone();
            c.extend_from_slice(&other.covariances);
            c
        };
        Gaussian::new(self.kind, self.dim, means, covs)
    }
}

impl Gaussian {
    /// The same states with full covariances (whatever the structure).
    pub fn to_full(&self) -> Result<Self> {
        let d = self.dim;
        let covs = (0..self.n_states)
            .flat_map(|i| {
                let c = self.covariance(i);
                (0..d * d).map(move |k| c[(k / d, k % d)])
            })
            .collect();
        Gaussian::new(CovarianceType::Full, d, self.means.clone(), covs)
    }
}

/// The conditionals of a [`Gaussian`] for one `(input, output)` split: per
/// state (one shared for tied), the input marginal `N(x_I; μ_I, Σ_II)` and
/// `E[x_O | x_I] = μ_O + Σ_OI Σ_II⁻¹ (x_I − μ_I)`,
/// `Cov[x_O | x_I] = Σ_OO − Σ_OI Σ_II⁻¹ Σ_IO` (constant in the input), for
/// every covariance structure.
#[derive(Debug, Clone)]
pub struct GaussianSplit {
    input: Vec<usize>,
    output: Vec<usize>,
    n_states: usize,
    /// Per state: `μ_I`, `μ_O`.
    mu_in: Vec<f64>,
    mu_out: Vec<f64>,
    /// Per covariance: packed `L_II⁻¹`, log-density constant, regression and conditional.
    whiten_in: Vec<Vec<f64>>,
    log_norm_in: Vec<f64>,
    regression: Vec<Vec<f64>>,
    conditional: Vec<Vec<f64>>,
    shared: bool,
    diff: Vec<f64>,
}

impl GaussianSplit {
    fn delta(&mut self, state: usize, input: &[f64]) -> f64 {
        let ni = self.input.len();
        if ni == 0 {
            // No input: the outputs' marginal (see `Conditional::conditional`).
            return 0.0;
        }
        for (k, v) in input.iter().enumerate() {
            self.diff[k] = v - self.mu_in[state * ni + k];
        }
        let j = if self.shared { 0 } else { state };
        packed_lower_sq_norm(&self.whiten_in[j], &self.diff)
    }
}

impl ConditionalSplit for GaussianSplit {
    fn n_states(&self) -> usize {
        self.n_states
    }

    fn input_dims(&self) -> &[usize] {
        &self.input
    }

    fn output_dims(&self) -> &[usize] {
        &self.output
    }

    fn input_log_density(&mut self, state: usize, input: &[f64]) -> Result<f64> {
        check_state(state, self.n_states)?;
        check_len("regression input", self.input.len(), input.len())?;
        let delta = self.delta(state, input);
        let j = if self.shared { 0 } else { state };
        Ok(self.log_norm_in[j] - 0.5 * delta)
    }

    fn predict(
        &mut self,
        state: usize,
        input: &[f64],
        mean: &mut [f64],
        covariance: &mut [f64],
    ) -> Result<()> {
        check_state(state, self.n_states)?;
        let (ni, no) = (self.input.len(), self.output.len());
        check_len("regression input", ni, input.len())?;
        check_len("regression mean", no, mean.len())?;
        check_len("regression covariance", no * no, covariance.len())?;
        for (k, v) in input.iter().enumerate() {
            self.diff[k] = v - self.mu_in[state * ni + k];
        }
        let j = if self.shared { 0 } else { state };
        let r = &self.regression[j];
        for (o, m) in mean.iter_mut().enumerate() {
            *m = self.mu_out[state * no + o]
                + r[o * ni..(o + 1) * ni]
                    .iter()
                    .zip(&self.diff)
                    .map(|(a, b)| a * b)
                    .sum::<f64>();
        }
        covariance.copy_from_slice(&self.conditional[j]);
        Ok(())
    }
}

impl Conditional for Gaussian {
    type Split = GaussianSplit;

    fn conditional(&self, input: &[usize], output: &[usize]) -> Result<GaussianSplit> {
        check_split(input, output, self.dim)?;
        let shared = self.kind == CovarianceType::Tied;
        let n_cov = if shared { 1 } else { self.n_states };
        let half_log_2pi = 0.5 * input.len() as f64 * (2.0 * PI).ln();
        let mut split = GaussianSplit {
            input: input.to_vec(),
            output: output.to_vec(),
            n_states: self.n_states,
            mu_in: Vec::new(),
            mu_out: Vec::new(),
            whiten_in: Vec::new(),
            log_norm_in: Vec::new(),
            regression: Vec::new(),
            conditional: Vec::new(),
            shared,
            diff: vec![0.0; input.len()],
        };
        for i in 0..self.n_states {
            let mu = self.mean(i);
            split.mu_in.extend(input.iter().map(|&k| mu[k]));
            split.mu_out.extend(output.iter().map(|&k| mu[k]));
        }
        for j in 0..n_cov {
            let cov = self.covariance(j);
            let (r, c) = crate::student_t::regression_of(&cov, input, output)
                .map_err(|e| e.at_state(j, None))?;
            let sub = DMatrix::from_fn(input.len(), input.len(), |a, b| cov[(input[a], input[b])]);
            let l = factor_full(&sub, j, " (sub-block of the input dims)")?;
            let log_det = 2.0 * l.diagonal().iter().map(|v| v.ln()).sum::<f64>();
            let mut w = Vec::new();
            linalg::pack_lower(&linalg::lower_triangular_inverse(&l), &mut w);
            split.whiten_in.push(w);
            split.log_norm_in.push(-half_log_2pi - 0.5 * log_det);
            split.regression.push(r);
            split.conditional.push(c);
        }
        Ok(split)
    }
}
