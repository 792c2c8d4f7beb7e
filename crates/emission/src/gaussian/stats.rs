//! The Gaussian's sufficient statistics (about per-state reference points,
//! merged exactly) and its M-step with regularisation and jitter.

use super::kernels::{counts, DIAG_LANES_MAX};
use super::Gaussian;
use crate::error::{EmissionError, Result};
use crate::regularisation::{
    jitter_variances, regularised_covariance, regularised_variance, CovarianceRegularisation,
    MStepEvent, MStepReport, Regularisation,
};
use crate::{CovarianceType, Frames, SufficientStatistics};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

impl Gaussian {
    /// For a placeholder template, anchors the reference point of every state
    /// that has no weight yet at its first frame whose weight counts (see
    /// [`NEGLIGIBLE_WEIGHT`](super::NEGLIGIBLE_WEIGHT); dimension by dimension
    /// at the first observed value, when values are missing).
    pub(super) fn anchor(&self, frames: Frames<'_>, weights: &[f64], stats: &mut GaussianStats) {
        if !stats.anchor_lazily {
            return;
        }
        let (s, d) = (self.n_states, self.dim);
        for i in 0..s {
            if stats.weight[i] != 0.0 {
                continue;
            }
            let Some(t) = (0..frames.len()).find(|&t| counts(weights[t * s + i])) else {
                continue;
            };
            let shift = &mut stats.shift[i * d..(i + 1) * d];
            shift.copy_from_slice(frames.frame(t));
            if frames.has_missing() {
                for (k, c) in shift.iter_mut().enumerate() {
                    if c.is_nan() {
                        *c = (t..frames.len())
                            .filter(|&u| counts(weights[u * s + i]))
                            .map(|u| frames.frame(u)[k])
                            .find(|v| !v.is_nan())
                            .unwrap_or(0.0);
                    }
                }
            }
        }
    }

    /// [`Emission::accumulate`] for complete frames (no NaN); weights below
    /// [`NEGLIGIBLE_WEIGHT`](super::NEGLIGIBLE_WEIGHT) count as zero.
    pub(super) fn accumulate_complete(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) {
        let (s, d) = (self.n_states, self.dim);
        if matches!(self.kind, CovarianceType::Full | CovarianceType::Tied) {
            self.accumulate_full(frames, weights, stats);
            return;
        }
        match d {
            1 => return Self::accumulate_diagonal_small::<1>(s, frames, weights, stats),
            2 => return Self::accumulate_diagonal_small::<2>(s, frames, weights, stats),
            3 => return Self::accumulate_diagonal_small::<3>(s, frames, weights, stats),
            4 => return Self::accumulate_diagonal_small::<4>(s, frames, weights, stats),
            _ => {}
        }
        if s * d <= DIAG_LANES_MAX {
            Self::accumulate_diagonal(s, d, frames, weights, stats);
            return;
        }
        Self::accumulate_diagonal_reference(s, d, frames, weights, stats);
    }

    /// The diagonal/spherical statistics state by state, frame by frame (the
    /// definition the faster forms are tested against, and the form for
    /// `D > 4` with `S·D > DIAG_LANES_MAX`).
    pub(super) fn accumulate_diagonal_reference(
        s: usize,
        d: usize,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) {
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
                    if !counts(w) {
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

    /// The diagonal/spherical statistics for `D ≤ 4` known at compile time:
    /// exactly the loop of [`Gaussian::accumulate_complete`] (state by state,
    /// frame by frame), with the state's running sums in registers and
    /// selects instead of a branch on the weight.
    pub(super) fn accumulate_diagonal_small<const D: usize>(
        s: usize,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) {
        let (x, _) = frames.as_slice().as_chunks::<D>();
        for i in 0..s {
            let r = i * D..(i + 1) * D;
            let c: [f64; D] = stats.shift[r.clone()].try_into().expect("D values");
            let sum: [f64; D] = stats.sum[r.clone()].try_into().expect("D values");
            let q: [f64; D] = stats.sum_sq[r.clone()].try_into().expect("D values");
            let lo: [f64; D] = stats.lo[r.clone()].try_into().expect("D values");
            let hi: [f64; D] = stats.hi[r.clone()].try_into().expect("D values");
            // The running values move into the closure and come back as its
            // result: captured by reference, they were stored and reloaded
            // every frame (a chain through memory of ~8 cycles a frame).
            let (n, sum, q, lo, hi) = crate::linalg::dispatch(
                #[inline(always)]
                move || {
                    let (mut n, mut sum, mut q, mut lo, mut hi) = (0.0, sum, q, lo, hi);
                    for (xt, w) in x.iter().zip(weights[i..].iter().step_by(s)) {
                        let on = counts(*w);
                        n = if on { n + w } else { n };
                        for k in 0..D {
                            let e = xt[k] - c[k];
                            lo[k] = if on { lo[k].min(xt[k]) } else { lo[k] };
                            hi[k] = if on { hi[k].max(xt[k]) } else { hi[k] };
                            sum[k] = if on { sum[k] + w * e } else { sum[k] };
                            q[k] = if on { q[k] + w * e * e } else { q[k] };
                        }
                    }
                    (n, sum, q, lo, hi)
                },
            );
            stats.sum[r.clone()].copy_from_slice(&sum);
            stats.sum_sq[r.clone()].copy_from_slice(&q);
            stats.lo[r.clone()].copy_from_slice(&lo);
            stats.hi[r].copy_from_slice(&hi);
            stats.weight[i] += n;
        }
    }

    /// The diagonal/spherical statistics with the states in the lanes
    /// (`S·D ≤ DIAG_LANES_MAX`): for every state exactly the arithmetic of
    /// the loop of [`Gaussian::accumulate_complete`] (over the frames whose
    /// weight counts, in frame order: `n ← n + w`, the range, `e = x − c`,
    /// `s ← s + w·e`, `q ← q + w·e·e`), the states of a frame side by side.
    pub(super) fn accumulate_diagonal(
        s: usize,
        d: usize,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) {
        // Statistics by dimension, then state.
        let z = [0.0; DIAG_LANES_MAX];
        let (mut c, mut sum, mut q, mut lo, mut hi) = (z, z, z, z, z);
        for i in 0..s {
            for k in 0..d {
                let (from, to) = (i * d + k, k * s + i);
                c[to] = stats.shift[from];
                sum[to] = stats.sum[from];
                q[to] = stats.sum_sq[from];
                lo[to] = stats.lo[from];
                hi[to] = stats.hi[from];
            }
        }
        let n = s * d;
        let (c, sum_t, q_t, lo_t, hi_t) = (
            &c[..n],
            &mut sum[..n],
            &mut q[..n],
            &mut lo[..n],
            &mut hi[..n],
        );
        // This call's weight per state, from 0 (added to the total at the end).
        let mut count = [0.0; DIAG_LANES_MAX];
        let weight = &mut count[..s];
        crate::linalg::dispatch(
            #[inline(always)]
            || {
                for (x, wt) in frames.iter().zip(weights.chunks_exact(s)) {
                    for (nw, w) in weight.iter_mut().zip(wt) {
                        *nw = if counts(*w) { *nw + w } else { *nw };
                    }
                    for (k, xk) in x.iter().enumerate() {
                        let r = k * s..(k + 1) * s;
                        for (((((ck, sk), qk), lk), hk), w) in c[r.clone()]
                            .iter()
                            .zip(&mut sum_t[r.clone()])
                            .zip(&mut q_t[r.clone()])
                            .zip(&mut lo_t[r.clone()])
                            .zip(&mut hi_t[r])
                            .zip(wt)
                        {
                            let on = counts(*w);
                            let e = xk - ck;
                            *lk = if on { lk.min(*xk) } else { *lk };
                            *hk = if on { hk.max(*xk) } else { *hk };
                            *sk = if on { *sk + w * e } else { *sk };
                            *qk = if on { *qk + w * e * e } else { *qk };
                        }
                    }
                }
            },
        );
        for (total, n) in stats.weight.iter_mut().zip(&count[..s]) {
            *total += n;
        }
        for i in 0..s {
            for k in 0..d {
                let (to, from) = (i * d + k, k * s + i);
                stats.sum[to] = sum_t[from];
                stats.sum_sq[to] = q_t[from];
                stats.lo[to] = lo_t[from];
                stats.hi[to] = hi_t[from];
            }
        }
    }

    pub(super) fn kept(&self, i: usize, stats: &GaussianStats, reg: &Regularisation) -> bool {
        stats.weight[i] < reg.min_weight().max(f64::MIN_POSITIVE)
    }

    /// Scatter matrix of state `i` about its new mean, `Q − s sᵀ / n` (full, row-major).
    pub(super) fn scatter_full(stats: &GaussianStats, i: usize) -> DMatrix<f64> {
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

    /// The body of [`Emission::m_step`].
    pub(super) fn maximise(
        &mut self,
        stats: &GaussianStats,
        reg: &Regularisation,
    ) -> Result<MStepReport> {
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
                    let cov = regularised_covariance(
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
                    let cov = regularised_covariance(scatter, n_total, reg, 0, &mut report.events)?;
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
                            covs[i * d + k] = regularised_variance(q(k), n, 1.0, d as f64, reg);
                        }
                    } else {
                        let total: f64 = (0..d).map(|k| q(k).max(0.0)).sum();
                        covs[i] = regularised_variance(total, n, d as f64, d as f64, reg);
                    }
                }
                let per = if self.kind == CovarianceType::Diagonal {
                    d
                } else {
                    1
                };
                for (i, vars) in covs.chunks_exact_mut(per).enumerate() {
                    jitter_variances(vars, reg, i, &mut report.events)?;
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
}

/// Sufficient statistics of [`Gaussian`] states, about per-state reference points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GaussianStats {
    pub(super) kind: CovarianceType,
    pub(super) dim: usize,
    /// Reference point `c_i` per state (`S × D`): the means of the model that
    /// created the stats, or (for a placeholder template) the state's first weighted frame.
    pub(super) shift: Vec<f64>,
    /// Anchor every state's reference point at its first weighted frame.
    #[serde(default)]
    pub(super) anchor_lazily: bool,
    /// `n_i = Σ_t γ_t(i)`.
    pub(super) weight: Vec<f64>,
    /// `Σ_t γ_t(i) (x_t − c_i)`, `S × D`.
    pub(super) sum: Vec<f64>,
    /// Full/tied: lower triangle of `Σ_t γ_t(i) (x_t − c_i)(x_t − c_i)ᵀ`, `S × D × D`;
    /// diagonal/spherical: its diagonal, `S × D`.
    pub(super) sum_sq: Vec<f64>,
    /// Smallest and largest value of every dimension over the frames with positive
    /// weight, `S × D`: a dimension with `lo == hi` is exactly constant, and its
    /// scatter is exactly zero rather than the rounding noise of `Q − s sᵀ / n`.
    pub(super) lo: Vec<f64>,
    pub(super) hi: Vec<f64>,
}

impl GaussianStats {
    /// Total weight `n_i` of each state.
    pub fn weights(&self) -> &[f64] {
        &self.weight
    }

    /// True when every array has the length required by `s` states of dimension
    /// `d` and structure `kind` (deserialised statistics may not).
    pub(super) fn has_shape(&self, kind: CovarianceType, s: usize, d: usize) -> bool {
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
    pub(super) fn is_constant(&self, i: usize, k: usize) -> bool {
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

/// The M-step of one Gaussian state's mean and covariance, written as the
/// formula (the reference form):
///
/// `μ = Σ_t w_t x_t / Σ_t w_t`, `Σ = Σ_t w_t (x_t − μ)(x_t − μ)ᵀ / Σ_t w_t`
///
/// for complete frames, before regularisation ([`regularised_covariance`]
/// applies it to the scatter `n Σ`). [`Gaussian`]'s accumulation (blocked,
/// packed, about per-state reference points, merged across blocks) and its
/// M-step compute the same quantities faster; the tests hold them to this
/// function (`crates/emission/tests/capabilities.rs`).
///
/// Errors when the lengths differ, a frame has a missing value, a weight is
/// negative or not finite, or the total weight is not positive.
pub fn weighted_mean_covariance(
    frames: Frames<'_>,
    weights: &[f64],
) -> Result<(Vec<f64>, DMatrix<f64>)> {
    let d = frames.dim();
    crate::check_len("weights", frames.len(), weights.len())?;
    if frames.has_missing() {
        return Err(EmissionError::Unsupported(
            "weighted_mean_covariance takes complete frames".into(),
        ));
    }
    if let Some(t) = weights.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
        return Err(EmissionError::InvalidParameter {
            name: "weights",
            reason: format!(
                "frame {t}: weight {} is not finite and non-negative",
                weights[t]
            ),
        });
    }
    let n: f64 = weights.iter().sum();
    if n.is_nan() || n <= 0.0 {
        return Err(EmissionError::InvalidParameter {
            name: "weights",
            reason: "the total weight is not positive".into(),
        });
    }
    let mut mean = vec![0.0; d];
    for (x, w) in frames.iter().zip(weights) {
        for k in 0..d {
            mean[k] += w * x[k];
        }
    }
    for m in mean.iter_mut() {
        *m /= n;
    }
    let mut cov = DMatrix::zeros(d, d);
    for (x, w) in frames.iter().zip(weights) {
        for r in 0..d {
            for c in 0..d {
                cov[(r, c)] += w * (x[r] - mean[r]) * (x[c] - mean[c]);
            }
        }
    }
    Ok((mean, cov / n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::{with_simd_level, SimdLevel};
    use crate::Emission;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The diagonal/spherical statistics and log-densities of every form
    /// (`D ≤ 4` known at compile time; the states in the lanes; the
    /// per-state loop) are the per-state definitions to the bit, at every
    /// instruction-set level, with weights that do not count (0, below
    /// `NEGLIGIBLE_WEIGHT`), accumulating onto earlier statistics.
    #[test]
    fn diagonal_forms_equal_the_per_state_definitions() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for (s, d) in [
            (1, 1),
            (2, 1),
            (3, 2),
            (7, 3),
            (10, 4),
            (5, 5),
            (9, 7),
            (40, 7),
        ] {
            for spherical in [false, true] {
                let means: Vec<f64> = (0..s * d).map(|_| rng.random_range(-1.0..1.0)).collect();
                let g = if spherical {
                    let v: Vec<f64> = (0..s).map(|_| rng.random_range(0.5..2.0)).collect();
                    Gaussian::spherical(d, means, v).unwrap()
                } else {
                    let v: Vec<f64> = (0..s * d).map(|_| rng.random_range(0.5..2.0)).collect();
                    Gaussian::diagonal(d, means, v).unwrap()
                };
                let t_len = 57;
                let x: Vec<f64> = (0..t_len * d)
                    .map(|_| rng.random_range(-3.0..3.0))
                    .collect();
                let frames = Frames::new(&x, d).unwrap();
                let w: Vec<f64> = (0..t_len * s)
                    .map(|k| match k % 7 {
                        0 => 0.0,
                        1 => 1e-200,
                        _ => rng.random_range(0.0..1.0),
                    })
                    .collect();
                for level in [SimdLevel::Portable, SimdLevel::Avx2Fma, SimdLevel::Avx512] {
                    with_simd_level(level, || {
                        // Log-densities against the one-frame definition.
                        let mut out = vec![0.0; t_len * s];
                        g.log_density_into(frames, &mut out).unwrap();
                        for (t, row) in out.chunks_exact(s).enumerate() {
                            for (i, v) in row.iter().enumerate() {
                                let want = g.log_density_raw(i, frames.frame(t));
                                assert_eq!(v.to_bits(), want.to_bits(), "S {s} D {d} t {t} i {i}");
                            }
                        }
                        // Statistics, twice over (onto earlier sums), every form.
                        let mut want = g.new_stats();
                        let mut forms = [g.new_stats(), g.new_stats(), g.new_stats()];
                        for _ in 0..2 {
                            Gaussian::accumulate_diagonal_reference(s, d, frames, &w, &mut want);
                            g.accumulate(frames, &w, &mut forms[0]).unwrap();
                            if s * d <= DIAG_LANES_MAX {
                                Gaussian::accumulate_diagonal(s, d, frames, &w, &mut forms[1]);
                            } else {
                                Gaussian::accumulate_diagonal_reference(
                                    s,
                                    d,
                                    frames,
                                    &w,
                                    &mut forms[1],
                                );
                            }
                            match d {
                                1 => Gaussian::accumulate_diagonal_small::<1>(
                                    s,
                                    frames,
                                    &w,
                                    &mut forms[2],
                                ),
                                2 => Gaussian::accumulate_diagonal_small::<2>(
                                    s,
                                    frames,
                                    &w,
                                    &mut forms[2],
                                ),
                                3 => Gaussian::accumulate_diagonal_small::<3>(
                                    s,
                                    frames,
                                    &w,
                                    &mut forms[2],
                                ),
                                4 => Gaussian::accumulate_diagonal_small::<4>(
                                    s,
                                    frames,
                                    &w,
                                    &mut forms[2],
                                ),
                                _ => Gaussian::accumulate_diagonal_reference(
                                    s,
                                    d,
                                    frames,
                                    &w,
                                    &mut forms[2],
                                ),
                            }
                        }
                        for (f, got) in forms.iter().enumerate() {
                            let m = format!("S {s} D {d} spherical {spherical} form {f}");
                            assert_eq!(bits(&got.weight), bits(&want.weight), "{m}");
                            assert_eq!(bits(&got.sum), bits(&want.sum), "{m}");
                            assert_eq!(bits(&got.sum_sq), bits(&want.sum_sq), "{m}");
                            assert_eq!(bits(&got.lo), bits(&want.lo), "{m}");
                            assert_eq!(bits(&got.hi), bits(&want.hi), "{m}");
                        }
                    });
                }
            }
        }
    }
}
