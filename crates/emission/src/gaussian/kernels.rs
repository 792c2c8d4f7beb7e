//! The Gaussian's full/tied kernels: log-densities of blocks of frames (and
//! of one frame under every state), and the weighted accumulation of the
//! sufficient statistics.
//!
//! Both are written once, generic over the [`Lanes`] of [`super::simd`], and
//! compiled for AVX-512, for AVX2 + FMA and portably; the lanes of a vector
//! never exchange values, so every build gives the same bits (see
//! [`super::simd`]). Each value is computed by a fixed sequence of IEEE
//! operations that does not depend on how the frames are split into calls or
//! blocks either:
//!
//! * log-density of frame `t` under state `i` (exactly the arithmetic of the
//!   one-frame reference [`Gaussian::log_density_one`]): `y = x_t − μ_i`,
//!   `z_r = Σ_{k ≤ r} W_rk y_k` by fused multiply-adds in increasing `k` from
//!   `0`, `m = Σ_r z_r²` by fused multiply-adds in increasing `r` from `0`,
//!   `log b = log_norm_i − ½ m`, with `W = L⁻¹` packed;
//! * statistics of state `i`: over the frames with a weight that counts
//!   (`|w| ≥` [`NEGLIGIBLE_WEIGHT`]), in frame order and continuing from the
//!   values already in the statistics: `n_i ← n_i + w`, `e = x_t − c_i`,
//!   `a = w·e`, `s_i ← s_i + a`, `Q_i[r][c] ← fma(a_r, e_c, Q_i[r][c])` for
//!   `c ≤ r`, and the range `lo`/`hi` of every dimension.
//!
//! The tests at the end of this file hold every build to these definitions
//! and to the textbook formulas.

use super::simd::{isa, Isa, Lanes, Portable};
#[cfg(target_arch = "x86_64")]
use super::simd::{Avx2, Avx512};
use super::{Gaussian, GaussianStats};
use crate::linalg::{self, packed_len};
use crate::{CovarianceType, Frames};

/// Weights below this in magnitude, `2⁻⁶⁰⁰ ≈ 2.4·10⁻¹⁸¹`, count as zero in
/// the Gaussian's statistics.
///
/// Posteriors of well-separated models span hundreds of orders of magnitude
/// (on the NuiSI demonstrations about 5 % of the state·frame weights lie
/// between `10⁻³⁰⁸` and `10⁻¹⁸⁰`). Their terms are far below the rounding of
/// any statistic that has a weight of ordinary size, but products such as
/// `w·e_r·e_c` with `w ≈ 10⁻³⁰⁰` are subnormal, and on x86 every subnormal
/// result costs a microcode assist of about a hundred cycles (with 1.5 % of
/// the products subnormal, the accumulation ran ten times slower). Setting
/// the CPU to flush subnormals to zero would avoid that only on some CPUs,
/// giving different numbers on others; leaving out the negligible weights
/// themselves gives the same numbers everywhere: with `|w| ≥ 2⁻⁶⁰⁰`, a term
/// is subnormal only where `|e_r e_c| < 2⁻⁴²²`, i.e. for data whose values
/// differ by less than `10⁻⁶³`.
pub const NEGLIGIBLE_WEIGHT: f64 = f64::from_bits((1023 - 600) << 52);

/// True when weight `w` counts in the statistics (`|w| ≥` [`NEGLIGIBLE_WEIGHT`];
/// a NaN counts, so that it shows in the statistics rather than vanishing).
#[inline(always)]
pub(super) fn counts(w: f64) -> bool {
    w.abs() >= NEGLIGIBLE_WEIGHT || w.is_nan()
}

/// Vectors of frames per block of the log-density kernel (the last block
/// of a call may use fewer): 32 frames with AVX-512, 16 otherwise.
const LD_VECTORS: usize = 4;

impl Gaussian {
    /// Full/tied log-densities of complete frames (`data` row-major `T × D`)
    /// into `out` (`T × S`), with the instruction set of this CPU.
    pub(super) fn full_log_density(&self, data: &[f64], out: &mut [f64]) {
        self.full_log_density_with(isa(), data, out)
    }

    /// [`Gaussian::full_log_density`] with the build for `isa`, which the CPU
    /// must support (see [`Isa::available`]).
    pub(super) fn full_log_density_with(&self, isa: Isa, data: &[f64], out: &mut [f64]) {
        let (s, d) = (self.n_states, self.dim);
        assert!(data.len().is_multiple_of(d) && out.len() == data.len() / d * s);
        if data.len() == d {
            // One frame (the online filter): the states go in the lanes.
            self.full_one_frame_with(isa, data, out);
            return;
        }
        match isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => {
                assert!(Isa::available().contains(&Isa::Avx512));
                // SAFETY: the CPU supports AVX-512F (asserted above).
                unsafe { log_density_avx512(self, data, out) }
            }
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => {
                assert!(Isa::available().contains(&Isa::Avx2));
                // SAFETY: the CPU supports AVX2 and FMA (asserted above).
                unsafe { log_density_avx2(self, data, out) }
            }
            _ => log_density_blocks::<Portable, 2>(self, data, out),
        }
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

    /// [`Gaussian::full_one_frame`] with the build for `isa` (the CPU must
    /// support it).
    fn full_one_frame_with(&self, isa: Isa, x: &[f64], out: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        {
            if isa >= Isa::Avx2 {
                assert!(Isa::available().contains(&Isa::Avx2));
                // SAFETY: the CPU supports AVX2 and FMA (asserted above).
                unsafe { full_one_frame_avx2_fma(self, x, out) };
                return;
            }
        }
        let _ = isa;
        self.full_one_frame(x, out)
    }

    /// The full/tied part of [`Emission::accumulate`](crate::Emission::accumulate)
    /// for complete frames, with the instruction set of this CPU (see the
    /// module documentation for the arithmetic).
    pub(super) fn accumulate_full(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) {
        self.accumulate_full_with(isa(), frames, weights, stats)
    }

    /// [`Gaussian::accumulate_full`] with the build for `isa`, which the CPU
    /// must support.
    pub(super) fn accumulate_full_with(
        &self,
        isa: Isa,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut GaussianStats,
    ) {
        let (s, d) = (self.n_states, self.dim);
        let data = frames.as_slice();
        assert!(frames.dim() == d && weights.len() == frames.len() * s);
        assert!(stats.has_shape(self.kind, s, d));
        match isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => {
                assert!(Isa::available().contains(&Isa::Avx512));
                // SAFETY: the CPU supports AVX-512F (asserted above).
                unsafe { accumulate_avx512(data, d, s, weights, stats) }
            }
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => {
                assert!(Isa::available().contains(&Isa::Avx2));
                // SAFETY: the CPU supports AVX2 and FMA (asserted above).
                unsafe { accumulate_avx2(data, d, s, weights, stats) }
            }
            _ => accumulate_states::<Portable, 4, 2, 2>(data, d, s, weights, stats),
        }
    }

    /// Log-densities of complete frames (no NaN) into `out` (`T × S`).
    pub(super) fn log_density_complete(&self, frames: Frames<'_>, out: &mut [f64]) {
        match self.kind {
            CovarianceType::Full | CovarianceType::Tied => {
                if !frames.is_empty() {
                    self.full_log_density(frames.as_slice(), out)
                }
            }
            CovarianceType::Diagonal | CovarianceType::Spherical => {
                let (s, d) = (self.n_states, self.dim);
                match d {
                    1 => return self.diagonal_log_density_small::<1>(frames, out),
                    2 => return self.diagonal_log_density_small::<2>(frames, out),
                    3 => return self.diagonal_log_density_small::<3>(frames, out),
                    4 => return self.diagonal_log_density_small::<4>(frames, out),
                    _ => {}
                }
                if s * d <= DIAG_LANES_MAX {
                    self.diagonal_log_density(frames, out);
                    return;
                }
                for (x, row) in frames.iter().zip(out.chunks_exact_mut(s)) {
                    for (i, o) in row.iter_mut().enumerate() {
                        *o = self.log_density_raw(i, x);
                    }
                }
            }
        }
    }

    /// Diagonal/spherical log-densities for `D` ≤ 4 known at compile time:
    /// state by state, the frames in the lanes; for every frame and state
    /// exactly the arithmetic of [`Gaussian::log_density_raw`].
    fn diagonal_log_density_small<const D: usize>(&self, frames: Frames<'_>, out: &mut [f64]) {
        let s = self.n_states;
        let (x, _) = frames.as_slice().as_chunks::<D>();
        for i in 0..s {
            let mut mu = [0.0; D];
            let mut w = [0.0; D];
            for k in 0..D {
                mu[k] = self.means[i * D + k];
                w[k] = match self.kind {
                    CovarianceType::Spherical => self.whiten[i],
                    _ => self.whiten[i * D + k],
                };
            }
            let ln = self.log_norm[i];
            linalg::dispatch(
                #[inline(always)]
                || {
                    for (xt, o) in x.iter().zip(out[i..].iter_mut().step_by(s)) {
                        let mut m = 0.0;
                        for k in 0..D {
                            let e = (xt[k] - mu[k]) * w[k];
                            m += e * e;
                        }
                        *o = ln - 0.5 * m;
                    }
                },
            );
        }
    }

    /// Diagonal/spherical log-densities with the states in the lanes
    /// (`S·D ≤ DIAG_LANES_MAX`): for every frame and state exactly the
    /// arithmetic of [`Gaussian::log_density_raw`] (`m = Σ_k ((x_k − μ_ik)
    /// w_ik)²` in increasing `k`, `log b = log_norm_i − ½ m`), the states of
    /// a frame side by side instead of one after the other.
    fn diagonal_log_density(&self, frames: Frames<'_>, out: &mut [f64]) {
        let (s, d) = (self.n_states, self.dim);
        // μ and the whitening scale by dimension, then state.
        let mut mu = [0.0; DIAG_LANES_MAX];
        let mut w = [0.0; DIAG_LANES_MAX];
        for i in 0..s {
            for k in 0..d {
                mu[k * s + i] = self.means[i * d + k];
                w[k * s + i] = match self.kind {
                    CovarianceType::Spherical => self.whiten[i],
                    _ => self.whiten[i * d + k],
                };
            }
        }
        let (mu, w, log_norm) = (&mu[..s * d], &w[..s * d], &self.log_norm[..s]);
        linalg::dispatch(
            #[inline(always)]
            || {
                for (x, row) in frames.iter().zip(out.chunks_exact_mut(s)) {
                    row.fill(0.0);
                    for ((xk, mk), wk) in x.iter().zip(mu.chunks_exact(s)).zip(w.chunks_exact(s)) {
                        for ((o, m), c) in row.iter_mut().zip(mk).zip(wk) {
                            let e = (xk - m) * c;
                            *o += e * e;
                        }
                    }
                    for (o, ln) in row.iter_mut().zip(log_norm) {
                        *o = ln - 0.5 * *o;
                    }
                }
            },
        )
    }
}

/// The largest `S·D` of a diagonal or spherical Gaussian whose kernels run
/// with the states in the lanes (parameters and statistics transposed into
/// buffers on the stack).
pub(super) const DIAG_LANES_MAX: usize = 256;

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

// ---------------------------------------------------------------------------
// Log-densities: blocks of frames in the lanes.

/// Log-densities of all frames of `data` by blocks of up to
/// `LD_VECTORS · W` frames (frames in the lanes), whitening `R` rows of the
/// packed factor at a time.
///
/// A block is transposed once (`D × F`), centred on each state's mean and
/// whitened by [`whiten_rows`]; the frames of a block do not interact, so a
/// frame's value is the same in whichever block (and call) it falls.
#[inline(always)]
fn log_density_blocks<V: Lanes, const R: usize>(g: &Gaussian, data: &[f64], out: &mut [f64]) {
    const { assert!(R >= 1 && R <= 4) };
    let d = g.dim;
    let t_len = data.len() / d;
    let f_max = LD_VECTORS * V::W;
    let mut xt = vec![0.0; d * f_max];
    let mut xc = vec![0.0; d * f_max];
    let mut t0 = 0;
    while t0 < t_len {
        let nf = (t_len - t0).min(f_max);
        match nf.div_ceil(V::W) {
            1 => log_density_block::<V, 1, R>(g, data, t0, nf, &mut xt, &mut xc, out),
            2 => log_density_block::<V, 2, R>(g, data, t0, nf, &mut xt, &mut xc, out),
            3 => log_density_block::<V, 3, R>(g, data, t0, nf, &mut xt, &mut xc, out),
            _ => log_density_block::<V, LD_VECTORS, R>(g, data, t0, nf, &mut xt, &mut xc, out),
        }
        t0 += nf;
    }
}

/// One block: frames `t0 .. t0 + nf` in `N` vectors of lanes (padding lanes
/// repeat the last frame; their results are dropped).
#[inline(always)]
fn log_density_block<V: Lanes, const N: usize, const R: usize>(
    g: &Gaussian,
    data: &[f64],
    t0: usize,
    nf: usize,
    xt: &mut [f64],
    xc: &mut [f64],
    out: &mut [f64],
) {
    let (s, d) = (g.n_states, g.dim);
    let fs = N * V::W;
    assert!(nf >= 1 && nf <= fs && (t0 + nf) * d <= data.len() && (t0 + nf) * s <= out.len());
    assert!(xt.len() >= d * fs && xc.len() >= d * fs && fs <= 64);
    let pl = packed_len(d);
    assert!(g.means.len() == s * d && g.log_norm.len() == s);
    assert!(
        g.whiten.len()
            >= if g.kind == CovarianceType::Full {
                s * pl
            } else {
                pl
            }
    );
    for l in 0..fs {
        let frame = &data[(t0 + l.min(nf - 1)) * d..][..d];
        for (k, v) in frame.iter().enumerate() {
            xt[k * fs + l] = *v;
        }
    }
    let mut res = [0.0; 64];
    for i in 0..s {
        let mu = &g.means[i * d..(i + 1) * d];
        let w = match g.kind {
            CovarianceType::Full => &g.whiten[i * pl..(i + 1) * pl],
            _ => &g.whiten[..pl],
        };
        // SAFETY: `xt` and `xc` hold `d · fs` values (asserted above), row `k`
        // at `k · fs`, `fs = N · W`; `w` holds the packed `d × d` triangle
        // that `whiten_rows` reads; `res` holds `fs ≤ 64` values.
        unsafe {
            let (pt, pc) = (xt.as_ptr(), xc.as_mut_ptr());
            for (k, m) in mu.iter().enumerate() {
                let m = V::splat(*m);
                for n in 0..N {
                    let at = k * fs + n * V::W;
                    V::sub(V::load(pt.add(at)), m).store(pc.add(at));
                }
            }
            let mut acc = [V::zero(); N];
            let mut r0 = 0;
            while r0 < d {
                let rows = (d - r0).min(R);
                let (wp, xp) = (w.as_ptr(), xc.as_ptr());
                match rows {
                    1 => whiten_rows::<V, N, 1>(wp, r0, xp, fs, &mut acc),
                    2 => whiten_rows::<V, N, 2>(wp, r0, xp, fs, &mut acc),
                    3 => whiten_rows::<V, N, 3>(wp, r0, xp, fs, &mut acc),
                    _ => whiten_rows::<V, N, R>(wp, r0, xp, fs, &mut acc),
                }
                r0 += rows;
            }
            let (ln, half) = (V::splat(g.log_norm[i]), V::splat(0.5));
            for (n, a) in acc.iter().enumerate() {
                V::sub(ln, V::mul(half, *a)).store(res.as_mut_ptr().add(n * V::W));
            }
        }
        for (l, v) in res[..nf].iter().enumerate() {
            out[(t0 + l) * s + i] = *v;
        }
    }
}

/// Rows `r0 .. r0 + RR` of `z = W y` for `N` vectors of frames, then
/// `acc += z_r²` in increasing `r`: the columns `k < r0`, shared by the rows,
/// share each load of `y_k`; the triangle `r0 ≤ k ≤ r` follows. Every `z_r`
/// is summed in increasing `k` from `0`, as in [`linalg::packed_lower_sq_norm`].
///
/// # Safety
/// `w` points to the packed triangle (at least `packed_len(r0 + RR)`
/// values), `y` to `r0 + RR` rows of `N · W` values at stride `fs`.
#[inline(always)]
unsafe fn whiten_rows<V: Lanes, const N: usize, const RR: usize>(
    w: *const f64,
    r0: usize,
    y: *const f64,
    fs: usize,
    acc: &mut [V; N],
) {
    let row: [*const f64; RR] = std::array::from_fn(|j| w.add((r0 + j) * (r0 + j + 1) / 2));
    let mut z = [[V::zero(); N]; RR];
    for k in 0..r0 {
        let x: [V; N] = std::array::from_fn(|n| V::load(y.add(k * fs + n * V::W)));
        for j in 0..RR {
            let b = V::splat(*row[j].add(k));
            for n in 0..N {
                z[j][n] = V::fma(b, x[n], z[j][n]);
            }
        }
    }
    for m in 0..RR {
        let k = r0 + m;
        let x: [V; N] = std::array::from_fn(|n| V::load(y.add(k * fs + n * V::W)));
        for j in m..RR {
            let b = V::splat(*row[j].add(k));
            for n in 0..N {
                z[j][n] = V::fma(b, x[n], z[j][n]);
            }
        }
    }
    for zj in &z {
        for n in 0..N {
            acc[n] = V::fma(zj[n], zj[n], acc[n]);
        }
    }
}

/// [`log_density_blocks`] compiled for AVX-512 (rows four at a time).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn log_density_avx512(g: &Gaussian, data: &[f64], out: &mut [f64]) {
    log_density_blocks::<Avx512, 4>(g, data, out)
}

/// [`log_density_blocks`] compiled for AVX2 and FMA (rows two at a time:
/// sixteen registers).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn log_density_avx2(g: &Gaussian, data: &[f64], out: &mut [f64]) {
    log_density_blocks::<Avx2, 2>(g, data, out)
}

/// [`Gaussian::full_one_frame`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn full_one_frame_avx2_fma(g: &Gaussian, x: &[f64], out: &mut [f64]) {
    g.full_one_frame(x, out)
}

// ---------------------------------------------------------------------------
// Statistics: rank-1 updates of register tiles of `Q`.

/// Frames whose weights are sorted into per-state lists at once.
const SUPER_CHUNK: usize = 256;

/// `0, 1, …, SUPER_CHUNK − 1`: the list of a super-chunk whose weights all count.
const IN_ORDER: [u32; SUPER_CHUNK] = {
    let mut v = [0; SUPER_CHUNK];
    let mut j = 0;
    while j < SUPER_CHUNK {
        v[j] = j as u32;
        j += 1;
    }
    v
};

/// Frames gathered per pass of the tiles: the centred and the weighted
/// copies (`2 · m · Dp` values) stay within 16 KiB of L1.
fn chunk_frames(dp: usize) -> usize {
    (1024 / dp).clamp(8, SUPER_CHUNK)
}

/// Per-state running values, padded to whole vectors (`S × dp` each).
struct Running {
    dp: usize,
    shift: Vec<f64>,
    sum: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
}

/// The statistics of every state over the frames of `data` (`T × d`), with
/// tiles of up to `R` rows × `NV` vectors of `Q` and groups of `G` vectors
/// in the centring pass.
///
/// Frames go by super-chunks of [`SUPER_CHUNK`]: one pass over their
/// weights (contiguous rows) lists, per state, the frames whose weight
/// counts. Then, state by state, the listed frames go by chunks of
/// [`chunk_frames`]: [`centre_weight`] forms the centred `e = x − c_i` and
/// weighted `a = w·e` copies (frame-major, rows padded to whole vectors with
/// zeros) and updates `s_i` and the range (`n_i` is summed over the chunk's
/// weights before, in frame order); [`rank1_tiles`] loads every
/// tile of the lower triangle of `Q_i` into registers, updates it by the
/// rank-1 terms `a_r e_cᵀ` of the chunk's frames in order, and stores it
/// (entries above the diagonal are computed in the diagonal tiles but never
/// stored).
#[inline(always)]
fn accumulate_states<V: Lanes, const R: usize, const NV: usize, const G: usize>(
    data: &[f64],
    d: usize,
    s: usize,
    weights: &[f64],
    stats: &mut GaussianStats,
) {
    const { assert!(R >= 1 && R <= 8 && NV >= 1 && NV <= 3 && G >= 1 && G <= 4) };
    let t_len = data.len() / d;
    assert!(data.len() == t_len * d && weights.len() == t_len * s);
    assert!(stats.sum_sq.len() == s * d * d && stats.sum.len() == s * d);
    assert!(stats.lo.len() == s * d && stats.hi.len() == s * d && stats.shift.len() == s * d);
    assert!(stats.weight.len() == s);
    let nvec = d.div_ceil(V::W);
    let dp = nvec * V::W;
    let m_max = chunk_frames(dp);
    let mut e_buf = vec![0.0; m_max * dp];
    let mut a_buf = vec![0.0; m_max * dp];
    let pad = |src: &[f64], fill: f64| -> Vec<f64> {
        let mut v = vec![fill; s * dp];
        for i in 0..s {
            v[i * dp..i * dp + d].copy_from_slice(&src[i * d..(i + 1) * d]);
        }
        v
    };
    let mut run = Running {
        dp,
        shift: pad(&stats.shift, 0.0),
        sum: pad(&stats.sum, 0.0),
        lo: pad(&stats.lo, 0.0),
        hi: pad(&stats.hi, 0.0),
    };
    // Per state, the frames of the super-chunk whose weights count
    // (offsets from its start) and those weights.
    let mut listed = vec![0u32; s * SUPER_CHUNK];
    let mut listed_w = vec![0.0; s * SUPER_CHUNK];
    let mut len = vec![0usize; s];
    let mut t0 = 0;
    while t0 < t_len {
        let nt = (t_len - t0).min(SUPER_CHUNK);
        let rows = &weights[t0 * s..(t0 + nt) * s];
        // Soft posteriors (every weight counts) are the common case: then
        // the lists are every frame in order, and only the weights need
        // gathering by state.
        let every = rows.iter().fold(true, |all, &w| all & counts(w));
        if every {
            for (j, row) in rows.chunks_exact(s).enumerate() {
                for (i, &w) in row.iter().enumerate() {
                    listed_w[i * SUPER_CHUNK + j] = w;
                }
            }
            len.fill(nt);
        } else {
            // Sharp posteriors leave few weights that count in a row: a
            // mask of them per vector of states, then only its set bits.
            len.fill(0);
            for (j, row) in rows.chunks_exact(s).enumerate() {
                let mut i0 = 0;
                while i0 < s {
                    let n = (s - i0).min(V::W);
                    // SAFETY: lanes `i0 .. i0 + n` of the row exist; a partial
                    // load reads no further and fills zeros, which do not count.
                    let mut on = unsafe {
                        let p = row.as_ptr().add(i0);
                        if n == V::W {
                            V::load(p)
                        } else {
                            V::load_partial(p, n)
                        }
                        .counts_mask()
                    };
                    while on != 0 {
                        let i = i0 + on.trailing_zeros() as usize;
                        let at = i * SUPER_CHUNK + len[i];
                        listed[at] = j as u32;
                        listed_w[at] = row[i];
                        len[i] += 1;
                        on &= on - 1;
                    }
                    i0 += n;
                }
            }
        }
        let block = &data[t0 * d..(t0 + nt) * d];
        let mut range: Option<(Vec<f64>, Vec<f64>)> = None;
        for i in 0..s {
            let n_i = len[i];
            if n_i == 0 {
                continue;
            }
            let dense = n_i == nt;
            let offsets = if every {
                &IN_ORDER[..n_i]
            } else {
                &listed[i * SUPER_CHUNK..i * SUPER_CHUNK + n_i]
            };
            let ws = &listed_w[i * SUPER_CHUNK..i * SUPER_CHUNK + n_i];
            let q = &mut stats.sum_sq[i * d * d..(i + 1) * d * d];
            let mut n = stats.weight[i];
            let mut j0 = 0;
            while j0 < n_i {
                let m = (n_i - j0).min(m_max);
                let chunk = Chunk {
                    data: block,
                    d,
                    dp,
                    offsets: &offsets[j0..j0 + m],
                    w: &ws[j0..j0 + m],
                };
                // SAFETY: `e_buf`/`a_buf` hold `m_max · dp ≥ m · dp` values,
                // every offset is a frame of `block`, the running vectors of
                // state `i` hold `dp` values each, and `q` is `d × d`.
                unsafe {
                    n = centre_weight_groups::<V, G>(
                        &chunk, &mut run, i, !dense, n, &mut e_buf, &mut a_buf,
                    );
                    rank1_tiles::<V, R, NV>(q, d, dp, m, &e_buf, &a_buf);
                }
                j0 += m;
            }
            stats.weight[i] = n;
            if dense {
                // Every frame counted: the range of the super-chunk.
                let (lo, hi) = range.get_or_insert_with(|| frame_range(block, d));
                let at = i * dp;
                for k in 0..d {
                    let (l, h) = (&mut run.lo[at + k], &mut run.hi[at + k]);
                    *l = if lo[k] < *l { lo[k] } else { *l };
                    *h = if hi[k] > *h { hi[k] } else { *h };
                }
            }
        }
        t0 += nt;
    }
    for i in 0..s {
        let at = i * dp;
        stats.sum[i * d..(i + 1) * d].copy_from_slice(&run.sum[at..at + d]);
        stats.lo[i * d..(i + 1) * d].copy_from_slice(&run.lo[at..at + d]);
        stats.hi[i * d..(i + 1) * d].copy_from_slice(&run.hi[at..at + d]);
    }
}

/// Smallest and largest value of every dimension over all frames.
fn frame_range(data: &[f64], d: usize) -> (Vec<f64>, Vec<f64>) {
    let mut lo = vec![f64::INFINITY; d];
    let mut hi = vec![f64::NEG_INFINITY; d];
    for x in data.chunks_exact(d) {
        for k in 0..d {
            lo[k] = if x[k] < lo[k] { x[k] } else { lo[k] };
            hi[k] = if x[k] > hi[k] { x[k] } else { hi[k] };
        }
    }
    (lo, hi)
}

/// The frames of one pass of the tiles: frame `offsets[j]` of `data`
/// (`T × d`) with weight `w[j]`.
struct Chunk<'a> {
    data: &'a [f64],
    d: usize,
    dp: usize,
    offsets: &'a [u32],
    w: &'a [f64],
}

/// [`centre_weight`] over the vectors of a row, `G` at a time (so that the
/// running sums and ranges stay in registers over the chunk); returns
/// `n + Σ_j w_j` (summed in order).
///
/// # Safety
/// As [`centre_weight`].
#[inline(always)]
unsafe fn centre_weight_groups<V: Lanes, const G: usize>(
    chunk: &Chunk<'_>,
    run: &mut Running,
    i: usize,
    range: bool,
    n: f64,
    e_buf: &mut [f64],
    a_buf: &mut [f64],
) -> f64 {
    let nvec = chunk.dp / V::W;
    // `n + Σ_j w_j` in frame order, on its own: inside the centring loop the
    // scalar sum was spilled to the stack (no register left beside the
    // group's vectors), and its chain of store, reload and add, ~8 cycles a
    // frame, bounded the loop.
    let n = chunk.w.iter().fold(n, |n, w| n + w);
    let mut v0 = 0;
    while v0 < nvec {
        let g = (nvec - v0).min(G);
        macro_rules! go {
            ($g:literal) => {
                if range {
                    centre_weight::<V, $g, true>(chunk, run, i, v0, e_buf, a_buf)
                } else {
                    centre_weight::<V, $g, false>(chunk, run, i, v0, e_buf, a_buf)
                }
            };
        }
        match g {
            1 => go!(1),
            2 => go!(2),
            3 => go!(3),
            _ => go!(4),
        }
        v0 += g;
    }
    n
}

/// Vectors `v0 .. v0 + GN` of `e_j = x_j − c` and `a_j = w_j e_j` for the
/// frames of the chunk, into the rows of `e_buf`/`a_buf` (stride `dp`;
/// padding lanes zero, since `x` and `c` are read as zero there), with
/// `s ← s + a_j` in order and (with `RANGE`) the range of the frames.
///
/// # Safety
/// The running vectors of state `i` hold `dp` values; `e_buf`, `a_buf` hold
/// `offsets.len() · dp`; every offset is a frame of `data`; `v0 + GN` vectors
/// fit in `dp`.
#[inline(always)]
unsafe fn centre_weight<V: Lanes, const GN: usize, const RANGE: bool>(
    chunk: &Chunk<'_>,
    run: &mut Running,
    i: usize,
    v0: usize,
    e_buf: &mut [f64],
    a_buf: &mut [f64],
) {
    let (d, dp) = (chunk.d, chunk.dp);
    let at = i * run.dp + v0 * V::W;
    let x = chunk.data.as_ptr().add(v0 * V::W);
    let (ep, ap) = (
        e_buf.as_mut_ptr().add(v0 * V::W),
        a_buf.as_mut_ptr().add(v0 * V::W),
    );
    // Lanes of the frame in the last vector of the group.
    let last = (d - (v0 + GN - 1) * V::W).min(V::W);
    let c: [V; GN] = std::array::from_fn(|g| V::load(run.shift.as_ptr().add(at + g * V::W)));
    let mut sv: [V; GN] = std::array::from_fn(|g| V::load(run.sum.as_ptr().add(at + g * V::W)));
    let mut lv: [V; GN] = std::array::from_fn(|g| V::load(run.lo.as_ptr().add(at + g * V::W)));
    let mut hv: [V; GN] = std::array::from_fn(|g| V::load(run.hi.as_ptr().add(at + g * V::W)));
    for (j, (&t, &w)) in chunk.offsets.iter().zip(chunk.w).enumerate() {
        let p = x.add(t as usize * d);
        let wv = V::splat(w);
        for g in 0..GN {
            let xv = if g + 1 < GN || last == V::W {
                V::load(p.add(g * V::W))
            } else {
                V::load_partial(p.add(g * V::W), last)
            };
            let e = V::sub(xv, c[g]);
            let a = V::mul(wv, e);
            e.store(ep.add(j * dp + g * V::W));
            a.store(ap.add(j * dp + g * V::W));
            sv[g] = V::add(sv[g], a);
            if RANGE {
                lv[g] = V::min(xv, lv[g]);
                hv[g] = V::max(xv, hv[g]);
            }
        }
    }
    for g in 0..GN {
        sv[g].store(run.sum.as_mut_ptr().add(at + g * V::W));
        if RANGE {
            lv[g].store(run.lo.as_mut_ptr().add(at + g * V::W));
            hv[g].store(run.hi.as_mut_ptr().add(at + g * V::W));
        }
    }
}

/// `Q[r][c] ← fma(a_j[r], e_j[c], Q[r][c])` for `c ≤ r`, for the `m` frames
/// of the chunk in order, by tiles of `R` rows × up to `NV` vectors (a tile
/// keeps at least eight independent accumulators where the triangle allows,
/// enough to cover the latency of the fused multiply-adds).
///
/// # Safety
/// `q` is `d × d`; `e_buf`, `a_buf` hold `m` rows of `dp` values.
#[inline(always)]
unsafe fn rank1_tiles<V: Lanes, const R: usize, const NV: usize>(
    q: &mut [f64],
    d: usize,
    dp: usize,
    m: usize,
    e_buf: &[f64],
    a_buf: &[f64],
) {
    let mut r0 = 0;
    while r0 < d {
        let rows = (d - r0).min(R);
        let ncv = (r0 + rows).div_ceil(V::W);
        let mut v0 = 0;
        while v0 < ncv {
            let nc = (ncv - v0).min(NV);
            let t = Tile {
                q: q.as_mut_ptr(),
                d,
                dp,
                m,
                r0,
                v0,
                e: e_buf.as_ptr(),
                a: a_buf.as_ptr(),
            };
            macro_rules! rows {
                ($rr:literal) => {
                    match nc {
                        1 => tile::<V, $rr, 1>(&t),
                        2 => tile::<V, $rr, 2>(&t),
                        _ => tile::<V, $rr, NV>(&t),
                    }
                };
            }
            match rows {
                1 => rows!(1),
                2 => rows!(2),
                3 => rows!(3),
                4 => rows!(4),
                5 => rows!(5),
                6 => rows!(6),
                7 => rows!(7),
                _ => rows!(8),
            }
            v0 += nc;
        }
        r0 += rows;
    }
}

/// One tile: rows `r0 .. r0 + RR` of `Q` (row-major `d × d`), columns
/// `v0·W .. (v0 + NC)·W`, over the `m` frames of the chunk.
struct Tile {
    q: *mut f64,
    d: usize,
    dp: usize,
    m: usize,
    r0: usize,
    v0: usize,
    e: *const f64,
    a: *const f64,
}

/// # Safety
/// See [`rank1_tiles`]; rows `r0 .. r0 + RR ≤ d`, vectors `v0 .. v0 + NC`
/// within the padded row `dp`.
#[inline(always)]
unsafe fn tile<V: Lanes, const RR: usize, const NC: usize>(t: &Tile) {
    // Entries of row `r` stored: columns `c ≤ r` (so `c < d`).
    let valid = |u: usize, v: usize| -> usize {
        let (r, c0) = (t.r0 + u, (t.v0 + v) * V::W);
        (r + 1).saturating_sub(c0).min(V::W)
    };
    // Masked loads and stores throughout (no branches): the prologue and
    // epilogue unroll, and the accumulators stay in registers.
    let mut acc = [[V::zero(); NC]; RR];
    for (u, row) in acc.iter_mut().enumerate() {
        for (v, a) in row.iter_mut().enumerate() {
            let p = t.q.add((t.r0 + u) * t.d + (t.v0 + v) * V::W);
            *a = V::load_partial(p, valid(u, v));
        }
    }
    let (mut e, mut a) = (t.e.add(t.v0 * V::W), t.a.add(t.r0));
    for _ in 0..t.m {
        let ev: [V; NC] = std::array::from_fn(|v| V::load(e.add(v * V::W)));
        for (u, row) in acc.iter_mut().enumerate() {
            let b = V::splat(*a.add(u));
            for v in 0..NC {
                row[v] = V::fma(b, ev[v], row[v]);
            }
        }
        e = e.add(t.dp);
        a = a.add(t.dp);
    }
    for (u, row) in acc.iter().enumerate() {
        for (v, a) in row.iter().enumerate() {
            let p = t.q.add((t.r0 + u) * t.d + (t.v0 + v) * V::W);
            a.store_partial(p, valid(u, v));
        }
    }
}

/// [`accumulate_states`] compiled for AVX-512: tiles of 8 rows × 2 vectors
/// (16 accumulators; with 24, LLVM keeps the tile in memory), centring 4
/// vectors at a time.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn accumulate_avx512(
    data: &[f64],
    d: usize,
    s: usize,
    weights: &[f64],
    stats: &mut GaussianStats,
) {
    accumulate_states::<Avx512, 8, 2, 4>(data, d, s, weights, stats)
}

/// [`accumulate_states`] compiled for AVX2 and FMA: tiles of 4 rows × 2
/// vectors (8 accumulators: 16 registers leave no room for 12 without
/// spilling), centring 2 vectors at a time.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn accumulate_avx2(
    data: &[f64],
    d: usize,
    s: usize,
    weights: &[f64],
    stats: &mut GaussianStats,
) {
    accumulate_states::<Avx2, 4, 2, 2>(data, d, s, weights, stats)
}

#[cfg(test)]
mod tests {
    //! Every build of the kernels against the definitions of the module
    //! documentation (bit for bit), against each other, against any split of
    //! the frames, and against the textbook formulas.
    use super::*;
    use crate::Emission;
    use nalgebra::DMatrix;
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    fn random_model(kind: CovarianceType, s: usize, d: usize, rng: &mut ChaCha8Rng) -> Gaussian {
        let offset = rng.random_range(-50.0..50.0);
        let means: Vec<f64> = (0..s * d)
            .map(|_| offset + rng.random_range(-2.0..2.0))
            .collect();
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

    fn random_frames(g: &Gaussian, t: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
        let d = g.dim();
        let centre = g.mean(0).to_vec();
        (0..t * d)
            .map(|k| centre[k % d] + rng.random_range(-4.0..4.0))
            .collect()
    }

    /// Weights with exact zeros, negligible values (subnormal ones too),
    /// values just at the threshold and ordinary ones.
    fn random_weights(n: usize, zero_share: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
        (0..n)
            .map(|_| {
                let u: f64 = rng.random_range(0.0..1.0);
                if u < zero_share {
                    match rng.random_range(0..4) {
                        0 => 0.0,
                        1 => 1e-310,
                        2 => NEGLIGIBLE_WEIGHT * 0.5,
                        _ => 1e-200,
                    }
                } else if u < zero_share + 0.02 {
                    NEGLIGIBLE_WEIGHT
                } else {
                    rng.random_range(0.0..1.0)
                }
            })
            .collect()
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    fn stats_bits(st: &GaussianStats) -> Vec<u64> {
        [&st.shift, &st.weight, &st.sum, &st.sum_sq, &st.lo, &st.hi]
            .iter()
            .flat_map(|v| bits(v))
            .collect()
    }

    /// The statistics exactly as the module documentation defines them,
    /// one frame and one entry at a time (scalar, no blocks, no tiles).
    fn defined_stats(g: &Gaussian, x: &[f64], w: &[f64], st: &mut GaussianStats) {
        let (s, d) = (g.n_states(), g.dim());
        for (t, f) in x.chunks_exact(d).enumerate() {
            for i in 0..s {
                let wt = w[t * s + i];
                if wt.abs() < NEGLIGIBLE_WEIGHT {
                    continue;
                }
                st.weight[i] += wt;
                let c = st.shift[i * d..(i + 1) * d].to_vec();
                let e: Vec<f64> = (0..d).map(|k| f[k] - c[k]).collect();
                let a: Vec<f64> = e.iter().map(|v| wt * v).collect();
                for k in 0..d {
                    let j = i * d + k;
                    st.sum[j] += a[k];
                    if f[k] < st.lo[j] {
                        st.lo[j] = f[k];
                    }
                    if f[k] > st.hi[j] {
                        st.hi[j] = f[k];
                    }
                }
                let q = &mut st.sum_sq[i * d * d..(i + 1) * d * d];
                for r in 0..d {
                    for cc in 0..=r {
                        q[r * d + cc] = a[r].mul_add(e[cc], q[r * d + cc]);
                    }
                }
            }
        }
    }

    /// Log-densities (every build, every split) and statistics (every
    /// build, every split) of one random case.
    fn check_case(kind: CovarianceType, s: usize, d: usize, t: usize, zero_share: f64, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let g = random_model(kind, s, d, &mut rng);
        let x = random_frames(&g, t, &mut rng);
        let frames = Frames::new(&x, d).unwrap();
        let what = format!("{kind:?} S={s} D={d} T={t} zeros {zero_share}");

        // Log-densities: the one-frame reference, bit for bit.
        let want: Vec<f64> = x
            .chunks_exact(d)
            .flat_map(|f| {
                (0..s)
                    .map(|i| g.log_density_one(i, f).unwrap())
                    .collect::<Vec<_>>()
            })
            .collect();
        for isa in Isa::available() {
            let mut got = vec![f64::NAN; t * s];
            g.full_log_density_with(isa, &x, &mut got);
            assert_eq!(bits(&got), bits(&want), "{what}: log-density, {isa:?}");
        }
        let all = g.log_density(frames).unwrap();
        assert_eq!(bits(&all), bits(&want), "{what}: log_density");
        let cut = rng.random_range(0..=t);
        let mut split = g.log_density(frames.slice(0..cut)).unwrap();
        split.extend(g.log_density(frames.slice(cut..t)).unwrap());
        assert_eq!(bits(&split), bits(&want), "{what}: split at {cut}");

        // Statistics: the scalar definition, bit for bit, in two calls.
        let w = random_weights(t * s, zero_share, &mut rng);
        let mut defined = g.new_stats();
        defined_stats(&g, &x, &w, &mut defined);
        for isa in Isa::available() {
            let mut st = g.new_stats();
            g.accumulate_full_with(isa, frames, &w, &mut st);
            assert_eq!(
                stats_bits(&st),
                stats_bits(&defined),
                "{what}: stats, {isa:?}"
            );
            let mut two = g.new_stats();
            g.accumulate_full_with(isa, frames.slice(0..cut), &w[..cut * s], &mut two);
            g.accumulate_full_with(isa, frames.slice(cut..t), &w[cut * s..], &mut two);
            assert_eq!(
                stats_bits(&two),
                stats_bits(&defined),
                "{what}: stats split at {cut}, {isa:?}"
            );
        }
        let mut st = g.new_stats();
        g.accumulate(frames, &w, &mut st).unwrap();
        assert_eq!(stats_bits(&st), stats_bits(&defined), "{what}: accumulate");
    }

    #[test]
    fn every_build_follows_the_definitions_bit_for_bit() {
        let mut seed = 0;
        for kind in [CovarianceType::Full, CovarianceType::Tied] {
            for d in [1, 2, 3, 4, 5, 7, 8, 9, 12, 13, 17, 36, 41] {
                for (s, t) in [(1, 1), (3, 2), (4, 33), (9, 70), (16, 9)] {
                    for zero_share in [0.0, 0.5] {
                        seed += 1;
                        check_case(kind, s, d, t, zero_share, seed);
                    }
                }
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn every_build_follows_the_definitions_on_random_shapes(
            tied in any::<bool>(),
            s in 1usize..18,
            d in 1usize..40,
            t in 1usize..150,
            zero_share in 0.0f64..0.95,
            seed in any::<u64>(),
        ) {
            let kind = if tied { CovarianceType::Tied } else { CovarianceType::Full };
            check_case(kind, s, d, t, zero_share, seed);
        }
    }

    #[test]
    fn log_density_matches_the_textbook_value() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for kind in [CovarianceType::Full, CovarianceType::Tied] {
            for d in [1, 2, 3, 5, 12, 17, 36] {
                let s = 3;
                let g = random_model(kind, s, d, &mut rng);
                let t = 53;
                let x = random_frames(&g, t, &mut rng);
                let all = g.log_density(Frames::new(&x, d).unwrap()).unwrap();
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
    fn statistics_match_the_textbook_formulas() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        for kind in [CovarianceType::Full, CovarianceType::Tied] {
            for d in [1, 2, 3, 5, 12, 17, 36] {
                for zero_share in [0.0, 0.3, 0.97] {
                    let s = 3;
                    let g = random_model(kind, s, d, &mut rng);
                    let t = 301;
                    let x = random_frames(&g, t, &mut rng);
                    let w = random_weights(t * s, zero_share, &mut rng);
                    let mut st = g.new_stats();
                    g.accumulate(Frames::new(&x, d).unwrap(), &w, &mut st)
                        .unwrap();
                    for i in 0..s {
                        let c = &st.shift[i * d..(i + 1) * d];
                        let (mut n, mut sum, mut q) = (0.0, vec![0.0; d], vec![0.0; d * d]);
                        let (mut lo, mut hi) = (vec![f64::INFINITY; d], vec![f64::NEG_INFINITY; d]);
                        for (tt, f) in x.chunks_exact(d).enumerate() {
                            let wt = w[tt * s + i];
                            if wt < NEGLIGIBLE_WEIGHT {
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
                        let close =
                            |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-11 * (1.0 + scale);
                        assert!(close(st.weight[i], n, n));
                        assert_eq!(&st.lo[i * d..(i + 1) * d], &lo[..], "{kind:?} D={d} lo");
                        assert_eq!(&st.hi[i * d..(i + 1) * d], &hi[..], "{kind:?} D={d} hi");
                        let qscale = q.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                        let sscale = sum.iter().fold(n, |m, v| m.max(v.abs()));
                        for r in 0..d {
                            assert!(close(st.sum[i * d + r], sum[r], sscale));
                            for cc in 0..d {
                                let got = st.sum_sq[i * d * d + r * d + cc];
                                let want = if cc <= r { q[r * d + cc] } else { 0.0 };
                                assert!(
                                    close(got, want, qscale),
                                    "{kind:?} D={d} Q[{r},{cc}] {got} vs {want}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn negligible_weights_count_as_zero_and_the_threshold_counts() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for kind in [
            CovarianceType::Full,
            CovarianceType::Tied,
            CovarianceType::Diagonal,
            CovarianceType::Spherical,
        ] {
            let (s, d, t) = (2, 5, 40);
            let g = random_model(CovarianceType::Full, s, d, &mut rng);
            let g = match kind {
                CovarianceType::Full => g,
                CovarianceType::Tied => {
                    Gaussian::tied(d, g.means().to_vec(), g.covariances_raw()[..d * d].to_vec())
                        .unwrap()
                }
                CovarianceType::Diagonal => {
                    Gaussian::diagonal(d, g.means().to_vec(), vec![0.5; s * d]).unwrap()
                }
                CovarianceType::Spherical => {
                    Gaussian::spherical(d, g.means().to_vec(), vec![0.5; s]).unwrap()
                }
            };
            let x = random_frames(&g, t, &mut rng);
            let frames = Frames::new(&x, d).unwrap();
            let w: Vec<f64> = (0..t * s).map(|_| rng.random_range(0.1..1.0)).collect();
            let mut zeroed = w.clone();
            let mut tiny = w.clone();
            for k in (0..t * s).step_by(3) {
                zeroed[k] = 0.0;
                tiny[k] = [1e-320, 1e-300, NEGLIGIBLE_WEIGHT / 2.0][k % 3];
            }
            let run = |w: &[f64]| {
                let mut st = g.new_stats();
                g.accumulate(frames, w, &mut st).unwrap();
                stats_bits(&st)
            };
            assert_eq!(run(&tiny), run(&zeroed), "{kind:?}");
            // A weight at the threshold counts (state 0 has no other weight).
            let mut none = zeroed.clone();
            for t in 0..t {
                none[t * s] = 0.0;
            }
            let mut at = none.clone();
            at[0] = NEGLIGIBLE_WEIGHT;
            let mut st = g.new_stats();
            g.accumulate(frames, &at, &mut st).unwrap();
            assert_eq!(st.weights()[0], NEGLIGIBLE_WEIGHT, "{kind:?}");
            assert_ne!(run(&at), run(&none), "{kind:?}");
        }
    }

    /// The listing's mask of the weights that count, in every build this
    /// CPU runs, is `counts` lane by lane, at the edges: zeros of both signs,
    /// subnormals, just below and at the threshold, negative weights, the
    /// infinities and NaNs of both signs.
    #[test]
    fn the_mask_of_counting_weights_is_counts_lane_by_lane() {
        let edge = [
            0.0,
            -0.0,
            1e-310,
            NEGLIGIBLE_WEIGHT * 0.5,
            f64::from_bits(NEGLIGIBLE_WEIGHT.to_bits() - 1),
            NEGLIGIBLE_WEIGHT,
            -NEGLIGIBLE_WEIGHT,
            -NEGLIGIBLE_WEIGHT * 0.5,
            1.0,
            -1.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
            f64::MAX,
            f64::MIN_POSITIVE,
        ];
        let want = |v: &[f64]| -> u32 {
            v.iter()
                .enumerate()
                .fold(0, |m, (l, w)| m | (counts(*w) as u32) << l)
        };
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        for _ in 0..200 {
            let v: [f64; 8] = std::array::from_fn(|_| edge[rng.random_range(0..edge.len())]);
            for isa in Isa::available() {
                let got = match isa {
                    // SAFETY: `Isa::available` lists only what this CPU runs.
                    #[cfg(target_arch = "x86_64")]
                    Isa::Avx512 => unsafe { mask_avx512(&v) },
                    #[cfg(target_arch = "x86_64")]
                    Isa::Avx2 => unsafe { mask_avx2(&v) },
                    _ => unsafe {
                        Portable::load(v.as_ptr()).counts_mask()
                            | Portable::load(v.as_ptr().add(4)).counts_mask() << 4
                    },
                };
                assert_eq!(got, want(&v), "{isa:?}: {v:?}");
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn mask_avx2(v: &[f64; 8]) -> u32 {
        Avx2::load(v.as_ptr()).counts_mask() | Avx2::load(v.as_ptr().add(4)).counts_mask() << 4
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn mask_avx512(v: &[f64; 8]) -> u32 {
        Avx512::load(v.as_ptr()).counts_mask()
    }
}
