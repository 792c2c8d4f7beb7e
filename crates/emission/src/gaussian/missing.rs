//! Missing values (NaN) in Gaussian emissions: log-densities on the marginal
//! of the observed dims, and the expected sufficient statistics of EM (the
//! conditional mean and covariance of the missing dims given the observed ones).

use super::{Gaussian, GaussianStats};
use crate::error::{EmissionError, Result};
use crate::missing::{for_each_run, observed_dims, PatternCache};
use crate::{CovarianceType, Frames, Marginal};
use nalgebra::DMatrix;

impl Gaussian {
    /// Log-densities of frames with missing values: runs of complete frames go
    /// through [`Gaussian::log_density_complete`]; an incomplete frame is
    /// evaluated on the marginal of its observed dims `o`,
    /// `log N(x_o; μ_o, Σ_oo)` (the full-covariance sub-block, not a diagonal
    /// shortcut), and a frame with nothing observed has `log b_i = 0`.
    pub(super) fn log_density_missing(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()> {
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
    pub(super) fn accumulate_missing(
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
}

/// The conditional distribution of the missing dims `m` given the observed
/// dims `o` of one missing pattern, per covariance (one per state, or one
/// shared when tied): the regression `R = Σ_mo Σ_oo⁻¹` (`|m| × |o|`, by a
/// Cholesky solve `Σ_oo Rᵀ = Σ_om`) and the covariance `Σ_mm − R Σ_om`.
#[derive(Debug)]
pub(super) struct Imputation {
    obs: Vec<usize>,
    mis: Vec<usize>,
    /// Per covariance: `R`, row-major (empty for diagonal/spherical, where it is zero).
    regression: Vec<Vec<f64>>,
    /// Per covariance: the conditional covariance, `|m| × |m|` row-major
    /// (diagonal/spherical: only its diagonal, `|m|` values).
    covariance: Vec<Vec<f64>>,
}

impl Imputation {
    pub(super) fn new(g: &Gaussian, x: &[f64]) -> Result<Self> {
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

    pub(super) fn cov_index(&self, g: &Gaussian, state: usize) -> usize {
        if g.kind == CovarianceType::Tied {
            0
        } else {
            state
        }
    }

    /// `x̂`: `x` with its missing values replaced by their conditional mean under `state`.
    pub(super) fn fill(&self, g: &Gaussian, state: usize, x: &[f64], xhat: &mut [f64]) {
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
    pub(super) fn add_covariance(
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
