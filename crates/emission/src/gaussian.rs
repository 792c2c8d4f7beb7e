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

use crate::error::{EmissionError, Result};
use crate::linalg::{self, packed_len, packed_lower_sq_norm, LANES};
use crate::missing::{for_each_run, observed_dims, PatternCache};
use crate::regularisation::{CovarianceRegularisation, MStepEvent, MStepReport, Regularisation};
use crate::{
    check_dim, check_dims, check_len, check_state, Emission, Frames, Shape, SufficientStatistics,
};
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
        if means.is_empty() || means.len() % dim != 0 {
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

    /// Mean of state `i`. Panics if `i ≥ S` (like slice indexing).
    pub fn mean(&self, i: usize) -> &[f64] {
        &self.means[i * self.dim..(i + 1) * self.dim]
    }

    /// Covariances in their native shape (see [`CovarianceType::raw_len`]).
    pub fn covariances_raw(&self) -> &[f64] {
        &self.covariances
    }

    /// The full `D × D` covariance of state `i`, whatever the structure.
    /// Panics if `i ≥ S` (like slice indexing).
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

    /// The lower Cholesky factor `L` of `Σ_i` (`Σ_i = L Lᵀ`). Panics if `i ≥ S`.
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

    /// `log|Σ_i|`. Panics if `i ≥ S`.
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

    /// Full/tied log-densities of the frames of `data` (row-major `T × D`),
    /// written into `out` (`T × S`); returns how many leading frames were done
    /// (all of them, or all but a last single frame, which the caller
    /// evaluates by [`Gaussian::log_density_one`]).
    ///
    /// Frames go by blocks of [`LANES`] (the last block padded): each block is
    /// transposed once (`D × LANES`), centred on each state's mean and whitened
    /// by [`linalg::sq_norms`], whose lanes do exactly the arithmetic of
    /// [`Gaussian::log_density_one`], so that the result does not depend on how
    /// the frames are split into calls.
    #[inline(always)]
    fn full_blocks(&self, data: &[f64], out: &mut [f64]) -> usize {
        let (s, d) = (self.n_states, self.dim);
        let t_len = data.len() / d;
        let done = if t_len % LANES == 1 { t_len - 1 } else { t_len };
        if done == 0 {
            return 0;
        }
        let pl = packed_len(d);
        let mut xt = vec![0.0; d * LANES];
        let mut xc = vec![0.0; d * LANES];
        let mut maha = [0.0; LANES];
        for t0 in (0..done).step_by(LANES) {
            let nt = LANES.min(done - t0);
            let block = &data[t0 * d..(t0 + nt) * d];
            for (l, x) in block.chunks_exact(d).enumerate() {
                for (k, v) in x.iter().enumerate() {
                    xt[k * LANES + l] = *v;
                }
            }
            // Padding lanes repeat the last frame (finite; their results are dropped).
            for row in xt.chunks_exact_mut(LANES) {
                let last = row[nt - 1];
                row[nt..].fill(last);
            }
            for i in 0..s {
                let mu = &self.means[i * d..(i + 1) * d];
                for (k, m) in mu.iter().enumerate() {
                    let row = k * LANES..(k + 1) * LANES;
                    linalg::sub_scalar(&mut xc[row.clone()], &xt[row], *m);
                }
                let w = match self.kind {
                    CovarianceType::Full => &self.whiten[i * pl..(i + 1) * pl],
                    _ => &self.whiten[..pl],
                };
                linalg::packed_lower_sq_norms(w, d, &xc, &mut maha);
                let ln = self.log_norm[i];
                for (l, m) in maha[..nt].iter().enumerate() {
                    out[(t0 + l) * s + i] = ln - 0.5 * m;
                }
            }
        }
        done
    }

    /// Full/tied log-densities of one frame `x` under every state, into `out`
    /// (length `S`): the states go as the lanes of [`linalg::sq_norms_lanes`],
    /// each lane doing exactly the arithmetic of [`Gaussian::log_density_one`].
    #[inline(always)]
    fn full_one_frame(&self, x: &[f64], out: &mut [f64]) {
        let (s, d) = (self.n_states, self.dim);
        let (pl, sl) = (packed_len(d), linalg::STATE_LANES);
        let mut stack = [0.0; 64 * linalg::STATE_LANES];
        let mut heap = Vec::new();
        let xc: &mut [f64] = if d <= 64 {
            &mut stack[..d * sl]
        } else {
            heap.resize(d * sl, 0.0);
            &mut heap
        };
        let mut maha = [0.0; linalg::STATE_LANES];
        for g in 0..s.div_ceil(sl) {
            for l in 0..sl {
                let i = g * sl + l;
                if i < s {
                    let mu = &self.means[i * d..(i + 1) * d];
                    for k in 0..d {
                        xc[k * sl + l] = x[k] - mu[k];
                    }
                } else {
                    for k in 0..d {
                        xc[k * sl + l] = 0.0;
                    }
                }
            }
            let wl = &self.whiten_lanes[g * pl * sl..(g + 1) * pl * sl];
            linalg::sq_norms_lanes(wl, d, xc, &mut maha);
            for (l, m) in maha.iter().enumerate() {
                let i = g * sl + l;
                if i < s {
                    out[i] = self.log_norm[i] - 0.5 * m;
                }
            }
        }
    }

    /// The full/tied part of [`Emission::accumulate`]: for every state `i`,
    /// `n_i += Σ_t w_ti`, `s_i += Σ_t w_ti (x_t − c_i)` and the lower triangle of
    /// `Q_i += Σ_t w_ti (x_t − c_i)(x_t − c_i)ᵀ`.
    ///
    /// Frames go by chunks of [`ACC_CHUNK`], transposed once (`D × chunk`);
    /// per state the centred frames and their weighted copy are formed and
    /// `Q_i` is computed by 4 × 3 tiles of dot products over the frames
    /// ([`linalg::dot_tile`], a fixed number of interleaved partial sums, so
    /// that the result does not depend on the SIMD width). Zero-weight frames
    /// add exact zeros; they are left out of the range (`lo`/`hi`) only.
    #[inline(always)]
    fn accumulate_full(&self, frames: Frames<'_>, weights: &[f64], stats: &mut GaussianStats) {
        let (s, d) = (self.n_states, self.dim);
        // Rows padded for whole 4 × 3 tiles.
        let dp = d.next_multiple_of(4).max(d.next_multiple_of(3)) + 3;
        let t_len = frames.len();
        let data = frames.as_slice();
        let cap = ACC_CHUNK.min(t_len.next_multiple_of(AL));
        let mut xt = vec![0.0; d * cap];
        let mut xz = vec![0.0; d * cap];
        // Rows d..dp are zero: the padding of the tiles.
        let mut dt = vec![0.0; dp * cap];
        let mut at = vec![0.0; dp * cap];
        let mut w = vec![0.0; cap];
        let mut chunk_lo = vec![0.0; d];
        let mut chunk_hi = vec![0.0; d];
        for c0 in (0..t_len).step_by(cap) {
            let m = cap.min(t_len - c0);
            let mp = m.next_multiple_of(AL);
            for (j, x) in data[c0 * d..(c0 + m) * d].chunks_exact(d).enumerate() {
                for (k, v) in x.iter().enumerate() {
                    xt[k * mp + j] = *v;
                }
            }
            for k in 0..d {
                let row = &xt[k * mp..k * mp + m];
                chunk_lo[k] = row.iter().fold(f64::INFINITY, |a, b| a.min(*b));
                chunk_hi[k] = row.iter().fold(f64::NEG_INFINITY, |a, b| a.max(*b));
            }
            for i in 0..s {
                let mut zeros = 0;
                for (j, wj) in w[..m].iter_mut().enumerate() {
                    *wj = weights[(c0 + j) * s + i];
                    zeros += (*wj == 0.0) as usize;
                }
                if zeros == m {
                    continue;
                }
                let lo = &mut stats.lo[i * d..(i + 1) * d];
                let hi = &mut stats.hi[i * d..(i + 1) * d];
                // The frames with non-zero weight, transposed: all of the chunk,
                // or (when some weights are exactly zero) a compacted copy.
                let (src, wv, mm) = if zeros == 0 {
                    for k in 0..d {
                        lo[k] = lo[k].min(chunk_lo[k]);
                        hi[k] = hi[k].max(chunk_hi[k]);
                    }
                    (&xt[..d * mp], &mut w[..], m)
                } else {
                    let mm = m - zeros;
                    let mmp = mm.next_multiple_of(AL);
                    let mut jj = 0;
                    for j in 0..m {
                        if w[j] != 0.0 {
                            w[jj] = w[j];
                            for k in 0..d {
                                xz[k * mmp + jj] = xt[k * mp + j];
                            }
                            jj += 1;
                        }
                    }
                    for k in 0..d {
                        let row = &xz[k * mmp..k * mmp + mm];
                        lo[k] = row.iter().fold(lo[k], |a, b| a.min(*b));
                        hi[k] = row.iter().fold(hi[k], |a, b| a.max(*b));
                    }
                    (&xz[..d * mmp], &mut w[..], mm)
                };
                let mp = mm.next_multiple_of(AL);
                wv[mm..mp].fill(0.0);
                stats.weight[i] += linalg::lane_sum::<AL>(&wv[..mp]);
                let c = &stats.shift[i * d..(i + 1) * d];
                let sum = &mut stats.sum[i * d..(i + 1) * d];
                for k in 0..d {
                    let drow = &mut dt[k * mp..(k + 1) * mp];
                    let arow = &mut at[k * mp..(k + 1) * mp];
                    // Padding frames (weight 0) enter as exact zeros.
                    sum[k] += linalg::centre_weight(
                        &src[k * mp..(k + 1) * mp],
                        c[k],
                        &wv[..mp],
                        drow,
                        arow,
                    );
                    drow[mm..].fill(0.0);
                }
                dt[d * mp..dp * mp].fill(0.0);
                at[d * mp..dp * mp].fill(0.0);
                let q = &mut stats.sum_sq[i * d * d..(i + 1) * d * d];
                for r0 in (0..d).step_by(4) {
                    for c0 in (0..=r0 + 3).step_by(3).take_while(|c| *c < d) {
                        let tile = linalg::dot_tile(&at, &dt, mp, r0, c0);
                        for (u, row) in tile.iter().enumerate() {
                            let r = r0 + u;
                            if r >= d {
                                break;
                            }
                            for (v, val) in row.iter().enumerate() {
                                let c = c0 + v;
                                if c <= r {
                                    q[r * d + c] += val;
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// Log-densities of complete frames (no NaN) into `out` (`T × S`): blocks
    /// of [`LANES`] frames for full/tied covariances (bit-identical to the
    /// frame-by-frame form, which finishes a last single frame).
    fn log_density_complete(&self, frames: Frames<'_>, out: &mut [f64]) {
        let s = self.n_states;
        let blocked = match self.kind {
            // Blocks of LANES frames at once (bit-identical to the frame-by-frame
            // form below, which finishes a last single frame).
            CovarianceType::Full | CovarianceType::Tied => {
                #[cfg(target_arch = "x86_64")]
                {
                    if linalg::has_avx2_fma() {
                        // SAFETY: the CPU supports AVX2 and FMA (checked above).
                        unsafe { full_blocks_avx2_fma(self, frames.as_slice(), out) }
                    } else {
                        self.full_blocks(frames.as_slice(), out)
                    }
                }
                #[cfg(not(target_arch = "x86_64"))]
                {
                    self.full_blocks(frames.as_slice(), out)
                }
            }
            CovarianceType::Diagonal | CovarianceType::Spherical => 0,
        };
        let full = matches!(self.kind, CovarianceType::Full | CovarianceType::Tied);
        for (x, row) in frames.iter().zip(out.chunks_exact_mut(s)).skip(blocked) {
            if full {
                // A single frame (e.g. the online filter): all states at once.
                #[cfg(target_arch = "x86_64")]
                {
                    if linalg::has_avx2_fma() {
                        // SAFETY: the CPU supports AVX2 and FMA (checked above).
                        unsafe { full_one_frame_avx2_fma(self, x, row) };
                        continue;
                    }
                }
                self.full_one_frame(x, row);
                continue;
            }
            for (i, o) in row.iter_mut().enumerate() {
                *o = self.log_density_raw(i, x);
            }
        }
    }

    /// Log-densities of frames with missing values: runs of complete frames go
    /// through [`Gaussian::log_density_complete`]; an incomplete frame is
    /// evaluated on the marginal of its observed dims `o`,
    /// `log N(x_o; μ_o, Σ_oo)` (the full-covariance sub-block, not a diagonal
    /// shortcut), and a frame with nothing observed has `log b_i = 0`.
    fn log_density_missing(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()> {
        let s = self.n_states;
        let mut marginals: PatternCache<Gaussian> = PatternCache::new();
        let mut obs = Vec::with_capacity(self.dim);
        let mut xo = Vec::with_capacity(self.dim);
        for_each_run(frames, |range, complete| {
            let rows = &mut out[range.start * s..range.end * s];
            if complete {
                self.log_density_complete(frames.slice_complete(range), rows);
                return Ok(());
            }
            let x = frames.frame(range.start);
            observed_dims(x, &mut obs);
            if obs.is_empty() {
                rows.fill(0.0);
                return Ok(());
            }
            let m = marginals.get_or_try_insert(x, || self.marginal(&obs))?;
            xo.clear();
            xo.extend(obs.iter().map(|&k| x[k]));
            // The observed values are complete: the marginal's own one-frame
            // path, as the online filter evaluates them.
            m.log_density_complete(Frames::new(&xo, obs.len())?, rows);
            Ok(())
        })
    }

    /// For a placeholder template, anchors the reference point of every state
    /// that has no weight yet at its first weighted frame (dimension by
    /// dimension at the first observed value, when values are missing).
    fn anchor(&self, frames: Frames<'_>, weights: &[f64], stats: &mut GaussianStats) {
        if !stats.anchor_lazily {
            return;
        }
        let (s, d) = (self.n_states, self.dim);
        for i in 0..s {
            if stats.weight[i] != 0.0 {
                continue;
            }
            let Some(t) = (0..frames.len()).find(|&t| weights[t * s + i] != 0.0) else {
                continue;
            };
            let shift = &mut stats.shift[i * d..(i + 1) * d];
            shift.copy_from_slice(frames.frame(t));
            if frames.has_missing() {
                for (k, c) in shift.iter_mut().enumerate() {
                    if c.is_nan() {
                        *c = (t..frames.len())
                            .filter(|&u| weights[u * s + i] != 0.0)
                            .map(|u| frames.frame(u)[k])
                            .find(|v| !v.is_nan())
                            .unwrap_or(0.0);
                    }
                }
            }
        }
    }

    /// [`Emission::accumulate`] for complete frames (no NaN).
    fn accumulate_complete(&self, frames: Frames<'_>, weights: &[f64], stats: &mut GaussianStats) {
        let (s, d) = (self.n_states, self.dim);
        if matches!(self.kind, CovarianceType::Full | CovarianceType::Tied) {
            #[cfg(target_arch = "x86_64")]
            {
                if linalg::has_avx2_fma() {
                    // SAFETY: the CPU supports AVX2 and FMA (checked above).
                    unsafe { accumulate_full_avx2_fma(self, frames, weights, stats) };
                    return;
                }
            }
            self.accumulate_full(frames, weights, stats);
            return;
        }
        for i in 0..s {
            let c = &stats.shift[i * d..(i + 1) * d];
            let sum = &mut stats.sum[i * d..(i + 1) * d];
            let lo = &mut stats.lo[i * d..(i + 1) * d];
            let hi = &mut stats.hi[i * d..(i + 1) * d];
            let mut n = 0.0;
            {
                let q = &mut stats.sum_sq[i * d..(i + 1) * d];
                for (t, x) in frames.iter().enumerate() {
                    let w = weights[t * s + i];
                    if w == 0.0 {
                        continue;
                    }
                    n += w;
                    for k in 0..d {
                        lo[k] = lo[k].min(x[k]);
                        hi[k] = hi[k].max(x[k]);
                        let e = x[k] - c[k];
                        sum[k] += w * e;
                        q[k] += w * e * e;
                    }
                }
            }
            stats.weight[i] += n;
        }
    }

    /// [`Emission::accumulate`] with missing values: the expected sufficient
    /// statistics of EM for Gaussians with missing data. For an incomplete
    /// frame with observed dims `o` and missing dims `m`, under state `i`,
    /// the missing values are replaced by their conditional mean
    /// `x̂_m = μ_m + Σ_mo Σ_oo⁻¹ (x_o − μ_o)` and the scatter gains the
    /// conditional covariance `Σ_mm − Σ_mo Σ_oo⁻¹ Σ_om` in its `m × m` block:
    /// `E[(x − c)(x − c)ᵀ | x_o] = (x̂ − c)(x̂ − c)ᵀ + Cov(x | x_o)`.
    /// For a placeholder template (whose parameters mean nothing yet) the
    /// missing values take the reference point with no variance; the
    /// initialisations iterate from there ([`crate::fit_weighted`]). Frames
    /// with nothing observed add nothing.
    fn accumulate_missing(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) -> Result<()> {
        let (s, d) = (self.n_states, self.dim);
        let full = matches!(self.kind, CovarianceType::Full | CovarianceType::Tied);
        let mut conditionals: PatternCache<Imputation> = PatternCache::new();
        let mut xhat = vec![0.0; d];
        let mut e = vec![0.0; d];
        for_each_run(frames, |range, complete| {
            let w = &weights[range.start * s..range.end * s];
            if complete {
                self.accumulate_complete(frames.slice_complete(range), w, stats);
                return Ok(());
            }
            let x = frames.frame(range.start);
            // A frame with nothing observed does not depend on the emission
            // parameters at all (its density is 1), so it is left out of their
            // statistics: EM with the observed values of the other frames as
            // the data. (Adding its expected statistics would give the same
            // fixed points, more slowly, and would carry an added-diagonal
            // regularisation of the current covariances into the next M-step.)
            if x.iter().all(|v| v.is_nan()) {
                return Ok(());
            }
            let imp = if stats.anchor_lazily {
                None
            } else {
                Some(conditionals.get_or_try_insert(x, || Imputation::new(self, x))?)
            };
            for (i, &wi) in w.iter().enumerate() {
                if wi == 0.0 {
                    continue;
                }
                let c = &stats.shift[i * d..(i + 1) * d];
                match imp {
                    Some(imp) => imp.fill(self, i, x, &mut xhat),
                    None => {
                        for k in 0..d {
                            xhat[k] = if x[k].is_nan() { c[k] } else { x[k] };
                        }
                    }
                }
                for k in 0..d {
                    e[k] = xhat[k] - c[k];
                }
                stats.weight[i] += wi;
                for k in 0..d {
                    let j = i * d + k;
                    stats.sum[j] += wi * e[k];
                    stats.lo[j] = stats.lo[j].min(xhat[k]);
                    stats.hi[j] = stats.hi[j].max(xhat[k]);
                }
                if full {
                    let q = &mut stats.sum_sq[i * d * d..(i + 1) * d * d];
                    for r in 0..d {
                        for cc in 0..=r {
                            q[r * d + cc] += wi * e[r] * e[cc];
                        }
                    }
                    if let Some(imp) = imp {
                        imp.add_covariance(self, i, wi, |r, cc, v| q[r * d + cc] += v);
                    }
                } else {
                    let q = &mut stats.sum_sq[i * d..(i + 1) * d];
                    for k in 0..d {
                        q[k] += wi * e[k] * e[k];
                    }
                    if let Some(imp) = imp {
                        imp.add_covariance(self, i, wi, |r, cc, v| {
                            if r == cc {
                                q[r] += v
                            }
                        });
                    }
                }
            }
            Ok(())
        })
    }

    fn kept(&self, i: usize, stats: &GaussianStats, reg: &Regularisation) -> bool {
        stats.weight[i] < reg.min_weight().max(f64::MIN_POSITIVE)
    }

    /// Scatter matrix of state `i` about its new mean, `Q − s sᵀ / n` (full, row-major).
    fn scatter_full(stats: &GaussianStats, i: usize) -> DMatrix<f64> {
        let d = stats.dim;
        let n = stats.weight[i];
        let s = &stats.sum[i * d..(i + 1) * d];
        let q = &stats.sum_sq[i * d * d..(i + 1) * d * d];
        DMatrix::from_fn(d, d, |r, c| {
            let (r, c) = if c <= r { (r, c) } else { (c, r) };
            if stats.is_constant(i, r) || stats.is_constant(i, c) {
                // Exactly zero: `Q − s sᵀ / n` would leave rounding noise, which
                // would pass for a tiny positive variance.
                0.0
            } else {
                q[r * d + c] - s[r] * s[c] / n
            }
        })
    }

    /// Applies the covariance regularisation to a scatter matrix with weight
    /// `n` and factors it, jittering if allowed.
    fn regularised_full(
        scatter: DMatrix<f64>,
        n: f64,
        reg: &Regularisation,
        state: usize,
        events: &mut Vec<MStepEvent>,
    ) -> Result<DMatrix<f64>> {
        let d = scatter.nrows();
        let mut cov = match reg.covariance() {
            CovarianceRegularisation::None => scatter / n,
            CovarianceRegularisation::AddDiagonal(r) => {
                let mut c = scatter / n;
                for k in 0..d {
                    c[(k, k)] += r;
                }
                c
            }
            CovarianceRegularisation::InverseWishart { scale, dof } => {
                let mut c = scatter;
                for k in 0..d {
                    c[(k, k)] += scale;
                }
                c / (n + dof + d as f64 + 1.0)
            }
        };
        cov = (&cov + cov.transpose()) * 0.5;
        if linalg::cholesky(&cov).is_some() {
            return Ok(cov);
        }
        let mean_var = (cov.trace() / d as f64).abs();
        let mut jitter = 1e-12
            * if mean_var > 0.0 && mean_var.is_finite() {
                mean_var
            } else {
                1.0
            };
        while jitter <= reg.max_jitter() {
            let mut c = cov.clone();
            for k in 0..d {
                c[(k, k)] += jitter;
            }
            if linalg::cholesky(&c).is_some() {
                events.push(MStepEvent::Jitter {
                    state,
                    component: None,
                    amount: jitter,
                });
                return Ok(c);
            }
            jitter *= 10.0;
        }
        Err(EmissionError::NotPositiveDefinite {
            state,
            component: None,
            detail: format!(
                " after the M-step ({:?}, total weight {n:.3e}, max jitter {:e})",
                reg.covariance(),
                reg.max_jitter()
            ),
        })
    }

    /// Makes the variances of one diagonal/spherical state positive, adding
    /// jitter to all of them (as [`Self::regularised_full`] does to a full
    /// diagonal) when allowed, or errors naming `state`.
    fn jitter_variances(
        vars: &mut [f64],
        reg: &Regularisation,
        state: usize,
        events: &mut Vec<MStepEvent>,
    ) -> Result<()> {
        let bad = |vars: &[f64]| vars.iter().position(|v| !(*v > 0.0 && v.is_finite()));
        let Some(k) = bad(vars) else {
            return Ok(());
        };
        if vars.iter().all(|v| v.is_finite()) {
            let mean_var = (vars.iter().sum::<f64>() / vars.len() as f64).abs();
            let mut jitter = 1e-12
                * if mean_var > 0.0 && mean_var.is_finite() {
                    mean_var
                } else {
                    1.0
                };
            while jitter <= reg.max_jitter() {
                let jittered: Vec<f64> = vars.iter().map(|v| v + jitter).collect();
                if bad(&jittered).is_none() {
                    vars.copy_from_slice(&jittered);
                    events.push(MStepEvent::Jitter {
                        state,
                        component: None,
                        amount: jitter,
                    });
                    return Ok(());
                }
                jitter *= 10.0;
            }
        }
        Err(EmissionError::NotPositiveDefinite {
            state,
            component: None,
            detail: format!(
                " (variance {} after the M-step, max jitter {:e}; a constant dimension needs covariance regularisation)",
                vars[k],
                reg.max_jitter()
            ),
        })
    }

    /// Variance update for diagonal/spherical structure: scatter `q` (sum of squared
    /// deviations), weight `n`, `k` pooled dimensions.
    fn regularised_var(q: f64, n: f64, k: f64, d: f64, reg: &Regularisation) -> f64 {
        let q = q.max(0.0);
        match reg.covariance() {
            CovarianceRegularisation::None => q / (n * k),
            CovarianceRegularisation::AddDiagonal(r) => q / (n * k) + r,
            CovarianceRegularisation::InverseWishart { scale, dof } => {
                (q + k * scale) / (k * (n + dof + d + 1.0))
            }
        }
    }
}

/// Frames per chunk of the full-covariance accumulation (keeps its scratch in L2).
const ACC_CHUNK: usize = 128;

/// Interleaved partial sums of the accumulation (a property of the
/// algorithm, not of the SIMD width, so results are the same on every CPU).
const AL: usize = linalg::DOT_LANES;

/// Calls `f(x − μ)`, using a stack buffer for `D ≤ 64`.
#[inline]
fn with_diff<T>(x: &[f64], mu: &[f64], f: impl FnOnce(&[f64]) -> T) -> T {
    let d = x.len();
    if d <= 64 {
        let mut buf = [0.0; 64];
        for k in 0..d {
            buf[k] = x[k] - mu[k];
        }
        f(&buf[..d])
    } else {
        let v: Vec<f64> = x.iter().zip(mu).map(|(a, b)| a - b).collect();
        f(&v)
    }
}

/// [`Gaussian::full_blocks`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn full_blocks_avx2_fma(g: &Gaussian, data: &[f64], out: &mut [f64]) -> usize {
    g.full_blocks(data, out)
}

/// [`Gaussian::full_one_frame`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn full_one_frame_avx2_fma(g: &Gaussian, x: &[f64], out: &mut [f64]) {
    g.full_one_frame(x, out)
}

/// [`Gaussian::accumulate_full`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn accumulate_full_avx2_fma(
    g: &Gaussian,
    frames: Frames<'_>,
    weights: &[f64],
    stats: &mut GaussianStats,
) {
    // Posteriors far below 1e-300 (which forward-backward produces on
    // well-separated data) would make the weighted products subnormal, and
    // every subnormal operand costs a ~100-cycle microcode assist. Flushing
    // them to zero changes only terms below 2.2e-308.
    let _ftz = linalg::FlushSubnormals::new();
    g.accumulate_full(frames, weights, stats)
}

/// The conditional distribution of the missing dims `m` given the observed
/// dims `o` of one missing pattern, per covariance (one per state, or one
/// shared when tied): the regression `R = Σ_mo Σ_oo⁻¹` (`|m| × |o|`, by a
/// Cholesky solve `Σ_oo Rᵀ = Σ_om`) and the covariance `Σ_mm − R Σ_om`.
#[derive(Debug)]
struct Imputation {
    obs: Vec<usize>,
    mis: Vec<usize>,
    /// Per covariance: `R`, row-major (empty for diagonal/spherical, where it is zero).
    regression: Vec<Vec<f64>>,
    /// Per covariance: the conditional covariance, `|m| × |m|` row-major
    /// (diagonal/spherical: only its diagonal, `|m|` values).
    covariance: Vec<Vec<f64>>,
}

impl Imputation {
    fn new(g: &Gaussian, x: &[f64]) -> Result<Self> {
        let d = g.dim;
        let mut obs = Vec::with_capacity(d);
        crate::missing::observed_dims(x, &mut obs);
        let mis: Vec<usize> = (0..d).filter(|&k| x[k].is_nan()).collect();
        let n_cov = if g.kind == CovarianceType::Tied {
            1
        } else {
            g.n_states
        };
        let mut regression = Vec::with_capacity(n_cov);
        let mut covariance = Vec::with_capacity(n_cov);
        for j in 0..n_cov {
            match g.kind {
                CovarianceType::Full | CovarianceType::Tied => {
                    // Σ = S/n + rI after an added-diagonal M-step. The E-step
                    // conditions on the maximum-likelihood part S/n: with r in
                    // it, the regression onto the observed values would shrink
                    // (covariances biased low) and the conditional variance
                    // would carry r into the next M-step, where r is added
                    // again (variances settling near s + r/(1 − f) for a
                    // fraction f missing, instead of s + r as on complete
                    // data). When S/n is singular on the observed dims (e.g. a
                    // constant one), the regression keeps r and only the
                    // conditional covariance drops it, which stays positive
                    // semi-definite since the off-diagonal blocks hold no r.
                    let sub = |m: &DMatrix<f64>, rows: &[usize], cols: &[usize]| {
                        DMatrix::from_fn(rows.len(), cols.len(), |r, c| m[(rows[r], cols[c])])
                    };
                    let full = g.covariance(j);
                    let ml = (g.added_diagonal > 0.0)
                        .then(|| &full - DMatrix::identity(d, d) * g.added_diagonal)
                        .and_then(|ml| {
                            let chol = nalgebra::Cholesky::new(sub(&ml, &obs, &obs))?;
                            Some((ml, chol))
                        });
                    let (cov, chol, deflate) = match ml {
                        Some((ml, chol)) => (ml, chol, 0.0),
                        None => {
                            let chol = nalgebra::Cholesky::new(sub(&full, &obs, &obs)).ok_or_else(
                                || EmissionError::NotPositiveDefinite {
                                    state: j,
                                    component: None,
                                    detail: format!(" (sub-block of the observed dims {obs:?})"),
                                },
                            )?;
                            (full, chol, g.added_diagonal)
                        }
                    };
                    let s_mm = sub(&cov, &mis, &mis);
                    let s_om = sub(&cov, &obs, &mis);
                    let rt = chol.solve(&s_om); // |o| × |m|: Σ_oo⁻¹ Σ_om
                    let mut cond = &s_mm - rt.transpose() * &s_om;
                    for a in 0..mis.len() {
                        cond[(a, a)] = (cond[(a, a)] - deflate).max(0.0);
                    }
                    // Row-major R = (Σ_oo⁻¹ Σ_om)ᵀ: the column-major storage of `rt`.
                    regression.push(rt.as_slice().to_vec());
                    covariance.push(
                        (0..mis.len() * mis.len())
                            .map(|k| {
                                let (r, c) = (k / mis.len(), k % mis.len());
                                0.5 * (cond[(r, c)] + cond[(c, r)])
                            })
                            .collect(),
                    );
                }
                // As above: the variance without the added diagonal.
                CovarianceType::Diagonal => {
                    regression.push(Vec::new());
                    covariance.push(
                        mis.iter()
                            .map(|&k| (g.covariances[j * d + k] - g.added_diagonal).max(0.0))
                            .collect(),
                    );
                }
                CovarianceType::Spherical => {
                    regression.push(Vec::new());
                    covariance.push(vec![
                        (g.covariances[j] - g.added_diagonal).max(0.0);
                        mis.len()
                    ]);
                }
            }
        }
        Ok(Imputation {
            obs,
            mis,
            regression,
            covariance,
        })
    }

    fn cov_index(&self, g: &Gaussian, state: usize) -> usize {
        if g.kind == CovarianceType::Tied {
            0
        } else {
            state
        }
    }

    /// `x̂`: `x` with its missing values replaced by their conditional mean under `state`.
    fn fill(&self, g: &Gaussian, state: usize, x: &[f64], xhat: &mut [f64]) {
        let mu = g.mean(state);
        xhat.copy_from_slice(x);
        let r = &self.regression[self.cov_index(g, state)];
        let no = self.obs.len();
        for (a, &m) in self.mis.iter().enumerate() {
            let mut v = mu[m];
            if !r.is_empty() {
                for (b, &o) in self.obs.iter().enumerate() {
                    v += r[a * no + b] * (x[o] - mu[o]);
                }
            }
            xhat[m] = v;
        }
    }

    /// Calls `add(r, c, w · C_rc)` for the lower triangle (`c ≤ r`, frame
    /// dims) of the conditional covariance `C` under `state`.
    fn add_covariance(
        &self,
        g: &Gaussian,
        state: usize,
        w: f64,
        mut add: impl FnMut(usize, usize, f64),
    ) {
        let c = &self.covariance[self.cov_index(g, state)];
        let nm = self.mis.len();
        if matches!(g.kind, CovarianceType::Full | CovarianceType::Tied) {
            // `mis` is ascending, so `b ≤ a` is the lower triangle in frame dims too.
            for a in 0..nm {
                for b in 0..=a {
                    add(self.mis[a], self.mis[b], w * c[a * nm + b]);
                }
            }
        } else {
            for (a, &m) in self.mis.iter().enumerate() {
                add(m, m, w * c[a]);
            }
        }
    }
}

/// Sufficient statistics of [`Gaussian`] states, about per-state reference points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GaussianStats {
    kind: CovarianceType,
    dim: usize,
    /// Reference point `c_i` per state (`S × D`): the means of the model that
    /// created the stats, or (for a placeholder template) the state's first weighted frame.
    shift: Vec<f64>,
    /// Anchor every state's reference point at its first weighted frame.
    #[serde(default)]
    anchor_lazily: bool,
    /// `n_i = Σ_t γ_t(i)`.
    weight: Vec<f64>,
    /// `Σ_t γ_t(i) (x_t − c_i)`, `S × D`.
    sum: Vec<f64>,
    /// Full/tied: lower triangle of `Σ_t γ_t(i) (x_t − c_i)(x_t − c_i)ᵀ`, `S × D × D`;
    /// diagonal/spherical: its diagonal, `S × D`.
    sum_sq: Vec<f64>,
    /// Smallest and largest value of every dimension over the frames with positive
    /// weight, `S × D`: a dimension with `lo == hi` is exactly constant, and its
    /// scatter is exactly zero rather than the rounding noise of `Q − s sᵀ / n`.
    lo: Vec<f64>,
    hi: Vec<f64>,
}

impl GaussianStats {
    /// Total weight `n_i` of each state.
    pub fn weights(&self) -> &[f64] {
        &self.weight
    }

    /// True when every array has the length required by `s` states of dimension
    /// `d` and structure `kind` (deserialised statistics may not).
    fn has_shape(&self, kind: CovarianceType, s: usize, d: usize) -> bool {
        let sq = match kind {
            CovarianceType::Full | CovarianceType::Tied => s * d * d,
            CovarianceType::Diagonal | CovarianceType::Spherical => s * d,
        };
        self.kind == kind
            && self.dim == d
            && self.weight.len() == s
            && [&self.shift, &self.sum, &self.lo, &self.hi]
                .iter()
                .all(|v| v.len() == s * d)
            && self.sum_sq.len() == sq
    }

    /// True when dimension `k` took a single value over the frames given to state `i`.
    fn is_constant(&self, i: usize, k: usize) -> bool {
        let j = i * self.dim + k;
        self.lo[j] == self.hi[j]
    }
}

impl SufficientStatistics for GaussianStats {
    fn merge(&mut self, other: &Self) -> Result<()> {
        let s = self.weight.len();
        if !self.has_shape(self.kind, s, self.dim) || !other.has_shape(self.kind, s, self.dim) {
            return Err(EmissionError::StatsMismatch(
                "Gaussian statistics from a different model (structure or dimension differ)".into(),
            ));
        }
        let d = self.dim;
        let full = matches!(self.kind, CovarianceType::Full | CovarianceType::Tied);
        let sq = if full { d * d } else { d };
        let mut delta = vec![0.0; d];
        for i in 0..s {
            let nb = other.weight[i];
            let (ca, cb) = (
                &self.shift[i * d..(i + 1) * d],
                &other.shift[i * d..(i + 1) * d],
            );
            if nb == 0.0 && other.sum[i * d..(i + 1) * d].iter().all(|v| *v == 0.0) {
                continue;
            }
            if self.weight[i] == 0.0
                && self.sum[i * d..(i + 1) * d].iter().all(|v| *v == 0.0)
                && ca != cb
            {
                // Nothing accumulated here yet: adopt the other's reference point.
                self.shift[i * d..(i + 1) * d].copy_from_slice(cb);
            }
            let ca = &self.shift[i * d..(i + 1) * d];
            // Re-centre the other's statistics on our reference point (exact algebra):
            // s' = s_b + n_b δ, Q' = Q_b + δ s_bᵀ + s_b δᵀ + n_b δ δᵀ with δ = c_b − c_a.
            for k in 0..d {
                delta[k] = cb[k] - ca[k];
            }
            let sb = &other.sum[i * d..(i + 1) * d];
            let qb = &other.sum_sq[i * sq..(i + 1) * sq];
            let qa = &mut self.sum_sq[i * sq..(i + 1) * sq];
            if full {
                for r in 0..d {
                    for c in 0..=r {
                        qa[r * d + c] += qb[r * d + c]
                            + delta[r] * sb[c]
                            + sb[r] * delta[c]
                            + nb * delta[r] * delta[c];
                    }
                }
            } else {
                for k in 0..d {
                    qa[k] += qb[k] + 2.0 * delta[k] * sb[k] + nb * delta[k] * delta[k];
                }
            }
            for k in 0..d {
                self.sum[i * d + k] += sb[k] + nb * delta[k];
            }
            self.weight[i] += nb;
        }
        for (a, b) in self.lo.iter_mut().zip(&other.lo) {
            *a = a.min(*b);
        }
        for (a, b) in self.hi.iter_mut().zip(&other.hi) {
            *a = a.max(*b);
        }
        Ok(())
    }

    fn total_weight(&self) -> f64 {
        self.weight.iter().sum()
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
        let (s, d) = (self.n_states, self.dim);
        if !stats.has_shape(self.kind, s, d) {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        let mut report = MStepReport {
            added_diagonal: match reg.covariance() {
                CovarianceRegularisation::AddDiagonal(r) => r,
                _ => 0.0,
            },
            events: Vec::new(),
        };
        let mut means = self.means.clone();
        let mut covs = self.covariances.clone();
        for i in 0..s {
            let n = stats.weight[i];
            if self.kept(i, stats, reg) {
                report.events.push(MStepEvent::KeptEmptyState {
                    state: i,
                    component: None,
                    weight: n,
                });
                continue;
            }
            for k in 0..d {
                means[i * d + k] = if stats.is_constant(i, k) {
                    stats.lo[i * d + k]
                } else {
                    stats.shift[i * d + k] + stats.sum[i * d + k] / n
                };
            }
        }
        match self.kind {
            CovarianceType::Full => {
                for i in 0..s {
                    if self.kept(i, stats, reg) {
                        continue;
                    }
                    let cov = Self::regularised_full(
                        Self::scatter_full(stats, i),
                        stats.weight[i],
                        reg,
                        i,
                        &mut report.events,
                    )?;
                    for r in 0..d {
                        for c in 0..d {
                            covs[i * d * d + r * d + c] = cov[(r, c)];
                        }
                    }
                }
            }
            CovarianceType::Tied => {
                let mut scatter = DMatrix::zeros(d, d);
                let mut n_total = 0.0;
                for i in 0..s {
                    if stats.weight[i] > 0.0 {
                        scatter += Self::scatter_full(stats, i);
                        n_total += stats.weight[i];
                    }
                }
                if n_total >= reg.min_weight().max(f64::MIN_POSITIVE) {
                    let cov = Self::regularised_full(scatter, n_total, reg, 0, &mut report.events)?;
                    for r in 0..d {
                        for c in 0..d {
                            covs[r * d + c] = cov[(r, c)];
                        }
                    }
                }
            }
            CovarianceType::Diagonal | CovarianceType::Spherical => {
                for i in 0..s {
                    if self.kept(i, stats, reg) {
                        continue;
                    }
                    let n = stats.weight[i];
                    let q = |k: usize| {
                        if stats.is_constant(i, k) {
                            return 0.0;
                        }
                        let sk = stats.sum[i * d + k];
                        stats.sum_sq[i * d + k] - sk * sk / n
                    };
                    if self.kind == CovarianceType::Diagonal {
                        for k in 0..d {
                            covs[i * d + k] = Self::regularised_var(q(k), n, 1.0, d as f64, reg);
                        }
                    } else {
                        let total: f64 = (0..d).map(|k| q(k).max(0.0)).sum();
                        covs[i] = Self::regularised_var(total, n, d as f64, d as f64, reg);
                    }
                }
                let per = if self.kind == CovarianceType::Diagonal {
                    d
                } else {
                    1
                };
                for (i, vars) in covs.chunks_exact_mut(per).enumerate() {
                    Self::jitter_variances(vars, reg, i, &mut report.events)?;
                }
            }
        }
        let mut updated = Gaussian {
            means,
            covariances: covs,
            placeholder: false,
            added_diagonal: report.added_diagonal,
            ..self.clone()
        };
        updated.refactor()?;
        *self = updated;
        Ok(report)
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

#[cfg(test)]
mod blocked_paths {
    //! The batched full-covariance kernels against the one-frame form and
    //! against their own portable (non-AVX) build.
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_model(kind: CovarianceType, s: usize, d: usize, rng: &mut ChaCha8Rng) -> Gaussian {
        let means: Vec<f64> = (0..s * d).map(|_| rng.random_range(-2.0..2.0)).collect();
        let n_cov = if kind == CovarianceType::Tied { 1 } else { s };
        let covs: Vec<f64> = (0..n_cov)
            .flat_map(|_| {
                let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-1.0..1.0));
                let m = &a * a.transpose() / d as f64 + DMatrix::identity(d, d) * 0.2;
                let m = (&m + m.transpose()) * 0.5;
                (0..d * d)
                    .map(move |k| m[(k / d, k % d)])
                    .collect::<Vec<_>>()
            })
            .collect();
        Gaussian::new(kind, d, means, covs).unwrap()
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn log_density_blocks_equal_frame_by_frame_and_any_split() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for kind in [CovarianceType::Full, CovarianceType::Tied] {
            for d in [1, 2, 3, 5, 12, 17, 36] {
                let s = 3;
                let g = random_model(kind, s, d, &mut rng);
                let t = 53;
                let x: Vec<f64> = (0..t * d).map(|_| rng.random_range(-4.0..4.0)).collect();
                let frames = Frames::new(&x, d).unwrap();
                let all = g.log_density(frames).unwrap();
                let one: Vec<f64> = x
                    .chunks_exact(d)
                    .flat_map(|f| {
                        (0..s)
                            .map(|i| g.log_density_one(i, f).unwrap())
                            .collect::<Vec<_>>()
                    })
                    .collect();
                assert_eq!(
                    bits(&all),
                    bits(&one),
                    "{kind:?} D={d}: blocks vs one frame"
                );
                let mut split = Vec::new();
                for r in [0..1, 1..3, 3..20, 20..37, 37..53] {
                    split.extend(g.log_density(frames.slice(r)).unwrap());
                }
                assert_eq!(bits(&all), bits(&split), "{kind:?} D={d}: split calls");
                // The portable build of the same kernel.
                let mut portable = vec![0.0; t * s];
                let done = g.full_blocks(&x, &mut portable);
                for (tt, f) in x.chunks_exact(d).enumerate().skip(done) {
                    for i in 0..s {
                        portable[tt * s + i] = g.log_density_raw(i, f);
                    }
                }
                assert_eq!(
                    bits(&all),
                    bits(&portable),
                    "{kind:?} D={d}: portable build"
                );
                // And the textbook value.
                for (tt, f) in x.chunks_exact(d).enumerate() {
                    for i in 0..s {
                        let cov = g.covariance(i);
                        let diff = nalgebra::DVector::from_iterator(
                            d,
                            f.iter().zip(g.mean(i)).map(|(a, b)| a - b),
                        );
                        let chol = nalgebra::Cholesky::new(cov.clone()).unwrap();
                        let maha = diff.dot(&chol.solve(&diff));
                        let want =
                            -0.5 * (d as f64 * (2.0 * PI).ln() + cov.determinant().ln() + maha);
                        let got = all[tt * s + i];
                        assert!(
                            (got - want).abs() <= 1e-9 * (1.0 + want.abs()),
                            "{got} vs {want}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn accumulate_blocks_match_formulas_and_portable_build() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        for kind in [CovarianceType::Full, CovarianceType::Tied] {
            for d in [1, 2, 3, 5, 12, 17, 36] {
                for zero_share in [0.0, 0.3, 0.97] {
                    let s = 3;
                    let g = random_model(kind, s, d, &mut rng);
                    let t = 301;
                    let x: Vec<f64> = (0..t * d).map(|_| rng.random_range(-4.0..4.0)).collect();
                    let w: Vec<f64> = (0..t * s)
                        .map(|_| {
                            if rng.random_range(0.0..1.0) < zero_share {
                                0.0
                            } else {
                                rng.random_range(0.0..1.0)
                            }
                        })
                        .collect();
                    let frames = Frames::new(&x, d).unwrap();
                    let mut st = g.new_stats();
                    g.accumulate(frames, &w, &mut st).unwrap();
                    let mut portable = g.new_stats();
                    g.accumulate_full(frames, &w, &mut portable);
                    assert_eq!(st, portable, "{kind:?} D={d}: portable build");
                    for i in 0..s {
                        let c = &st.shift[i * d..(i + 1) * d];
                        let (mut n, mut sum, mut q) = (0.0, vec![0.0; d], vec![0.0; d * d]);
                        let (mut lo, mut hi) = (vec![f64::INFINITY; d], vec![f64::NEG_INFINITY; d]);
                        for (tt, f) in x.chunks_exact(d).enumerate() {
                            let wt = w[tt * s + i];
                            if wt == 0.0 {
                                continue;
                            }
                            n += wt;
                            for r in 0..d {
                                lo[r] = lo[r].min(f[r]);
                                hi[r] = hi[r].max(f[r]);
                                sum[r] += wt * (f[r] - c[r]);
                                for cc in 0..=r {
                                    q[r * d + cc] += wt * (f[r] - c[r]) * (f[cc] - c[cc]);
                                }
                            }
                        }
                        let close = |a: f64, b: f64| (a - b).abs() <= 1e-11 * (1.0 + b.abs());
                        assert!(close(st.weight[i], n));
                        assert_eq!(&st.lo[i * d..(i + 1) * d], &lo[..], "{kind:?} D={d} lo");
                        assert_eq!(&st.hi[i * d..(i + 1) * d], &hi[..], "{kind:?} D={d} hi");
                        for r in 0..d {
                            assert!(close(st.sum[i * d + r], sum[r]));
                            for cc in 0..d {
                                let got = st.sum_sq[i * d * d + r * d + cc];
                                let want = if cc <= r { q[r * d + cc] } else { 0.0 };
                                assert!(
                                    close(got, want),
                                    "{kind:?} D={d} Q[{r},{cc}] {got} vs {want}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
