//! The Gaussian's packed kernels: full/tied log-densities of blocks of frames
//! and of one frame under every state, and the blocked accumulation of the
//! full/tied sufficient statistics, with their AVX2/FMA builds. Each does
//! exactly the arithmetic of the one-frame reference form
//! ([`Gaussian::log_density_one`], the textbook accumulation), so that the
//! results do not depend on how frames are split or on the CPU; the tests at
//! the end of this file hold them to it.

use super::{Gaussian, GaussianStats};
use crate::linalg::{self, packed_len, LANES};
use crate::{CovarianceType, Frames};

impl Gaussian {
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
    pub(super) fn full_blocks(&self, data: &[f64], out: &mut [f64]) -> usize {
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
    pub(super) fn full_one_frame(&self, x: &[f64], out: &mut [f64]) {
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
    pub(super) fn accumulate_full(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) {
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
    pub(super) fn log_density_complete(&self, frames: Frames<'_>, out: &mut [f64]) {
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
}

/// Frames per chunk of the full-covariance accumulation (keeps its scratch in L2).
pub(super) const ACC_CHUNK: usize = 128;

/// Interleaved partial sums of the accumulation (a property of the
/// algorithm, not of the SIMD width, so results are the same on every CPU).
pub(super) const AL: usize = linalg::DOT_LANES;

/// Calls `f(x − μ)`, using a stack buffer for `D ≤ 64`.
#[inline]
pub(super) fn with_diff<T>(x: &[f64], mu: &[f64], f: impl FnOnce(&[f64]) -> T) -> T {
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
pub(super) unsafe fn full_blocks_avx2_fma(g: &Gaussian, data: &[f64], out: &mut [f64]) -> usize {
    g.full_blocks(data, out)
}

/// [`Gaussian::full_one_frame`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn full_one_frame_avx2_fma(g: &Gaussian, x: &[f64], out: &mut [f64]) {
    g.full_one_frame(x, out)
}

/// [`Gaussian::accumulate_full`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn accumulate_full_avx2_fma(
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

#[cfg(test)]
mod blocked_paths {
    //! The batched full-covariance kernels against the one-frame form and
    //! against their own portable (non-AVX) build.
    use super::*;
    use crate::Emission;
    use nalgebra::DMatrix;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

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
