//! Small dense linear-algebra helpers on row-major packed triangles.
//!
//! A lower-triangular `D × D` matrix is packed row by row: row `r` holds
//! `r + 1` entries starting at `r (r + 1) / 2`, so a row is contiguous and a
//! triangular matrix–vector product is a sequence of contiguous dot products.

use nalgebra::DMatrix;

/// Number of entries of a packed `d × d` lower triangle.
#[inline]
pub fn packed_len(d: usize) -> usize {
    d * (d + 1) / 2
}

/// Row `r` of a packed lower triangle.
#[inline]
pub fn packed_row(packed: &[f64], r: usize) -> &[f64] {
    let start = r * (r + 1) / 2;
    &packed[start..start + r + 1]
}

/// Packs the lower triangle of `m` row by row.
pub fn pack_lower(m: &DMatrix<f64>, out: &mut Vec<f64>) {
    for r in 0..m.nrows() {
        for c in 0..=r {
            out.push(m[(r, c)]);
        }
    }
}

/// Unpacks a packed lower triangle into a dense matrix (upper part zero).
pub fn unpack_lower(packed: &[f64], d: usize) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(d, d);
    for r in 0..d {
        for (c, v) in packed_row(packed, r).iter().enumerate() {
            m[(r, c)] = *v;
        }
    }
    m
}

/// Frames evaluated together by the batched kernels: the SIMD lanes of
/// [`packed_lower_sq_norms`] are consecutive frames.
pub const LANES: usize = 16;

/// `Σ_r (W_r · v)²` for a packed lower-triangular `W`: the squared norm of `W v`.
///
/// With `W = L⁻¹` for the Cholesky factor `L` of `Σ`, this is the Mahalanobis
/// distance `vᵀ Σ⁻¹ v`. Computed with fused multiply-adds in a fixed order,
/// exactly as one lane of [`packed_lower_sq_norms`], so that the one-frame and
/// the batched evaluations agree to the last bit.
#[inline]
pub fn packed_lower_sq_norm(packed: &[f64], v: &[f64]) -> f64 {
    let mut out = [0.0];
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU supports AVX2 and FMA (checked above).
            unsafe { sq_norms_avx2_fma::<1>(packed, v.len(), v, &mut out) };
            return out[0];
        }
    }
    sq_norms::<1>(packed, v.len(), v, &mut out);
    out[0]
}

/// `out[l] = ‖W v_l‖²` for `L` vectors at once: `xt` holds them transposed
/// (`xt[k·L + l]` is entry `k` of vector `l`, `D × L`). Every lane does the
/// arithmetic of [`packed_lower_sq_norm`], so results do not depend on `L`,
/// on the SIMD width or on how frames are grouped.
#[inline]
pub fn packed_lower_sq_norms(packed: &[f64], d: usize, xt: &[f64], out: &mut [f64; LANES]) {
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU supports AVX2 and FMA (checked above).
            unsafe { sq_norms16_avx2_fma(packed, d, xt, out) };
            return;
        }
    }
    sq_norms::<LANES>(packed, d, xt, out)
}

/// While alive, the current thread flushes subnormal results to zero and
/// treats subnormal operands as zero (MXCSR FTZ and DAZ); the previous mode
/// is restored on drop (also when unwinding). Only values below
/// `f64::MIN_POSITIVE` (2.2e-308) are affected.
#[cfg(target_arch = "x86_64")]
pub struct FlushSubnormals(u32);

#[cfg(target_arch = "x86_64")]
impl FlushSubnormals {
    /// Sets FTZ and DAZ, remembering the previous MXCSR.
    #[inline]
    pub fn new() -> Self {
        let mut old: u32 = 0;
        // SAFETY: stmxcsr stores the 32-bit MXCSR into `old`; ldmxcsr loads a
        // valid MXCSR (the current one with FTZ (bit 15) and DAZ (bit 6) set).
        unsafe {
            std::arch::asm!("stmxcsr [{}]", in(reg) &mut old, options(nostack, preserves_flags));
            let new = old | 0x8040;
            std::arch::asm!("ldmxcsr [{}]", in(reg) &new, options(nostack, preserves_flags));
        }
        FlushSubnormals(old)
    }
}

#[cfg(target_arch = "x86_64")]
impl Default for FlushSubnormals {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(target_arch = "x86_64")]
impl Drop for FlushSubnormals {
    #[inline]
    fn drop(&mut self) {
        // SAFETY: restores the MXCSR saved by `new`.
        unsafe {
            std::arch::asm!("ldmxcsr [{}]", in(reg) &self.0, options(nostack, preserves_flags));
        }
    }
}

/// True when the CPU has AVX2 and FMA (cached by the standard library).
#[cfg(target_arch = "x86_64")]
#[inline]
pub fn has_avx2_fma() -> bool {
    std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn sq_norms_avx2_fma<const L: usize>(
    packed: &[f64],
    d: usize,
    xt: &[f64],
    out: &mut [f64; L],
) {
    sq_norms::<L>(packed, d, xt, out)
}

/// [`sq_norms`] for [`LANES`] = 16 frames with AVX2 registers (four per row):
/// the same fused multiply-adds in the same order, lane by lane.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
pub unsafe fn sq_norms16_avx2_fma(packed: &[f64], d: usize, xt: &[f64], out: &mut [f64; LANES]) {
    use std::arch::x86_64::*;
    assert!(LANES == 16 && packed.len() >= packed_len(d) && xt.len() >= d * LANES);
    let w = packed.as_ptr();
    let x = xt.as_ptr();
    let zero = _mm256_setzero_pd();
    let mut acc = [zero; 4];
    let mut start = 0;
    let mut r = 0;
    while r + 1 < d {
        let row0 = w.add(start);
        let row1 = w.add(start + r + 1);
        let mut z0 = [zero; 4];
        let mut z1 = [zero; 4];
        for k in 0..=r {
            let a = _mm256_broadcast_sd(&*row0.add(k));
            let b = _mm256_broadcast_sd(&*row1.add(k));
            let xk = x.add(k * LANES);
            for q in 0..4 {
                let v = _mm256_loadu_pd(xk.add(4 * q));
                z0[q] = _mm256_fmadd_pd(a, v, z0[q]);
                z1[q] = _mm256_fmadd_pd(b, v, z1[q]);
            }
        }
        let b = _mm256_broadcast_sd(&*row1.add(r + 1));
        let xk = x.add((r + 1) * LANES);
        for q in 0..4 {
            let v = _mm256_loadu_pd(xk.add(4 * q));
            z1[q] = _mm256_fmadd_pd(b, v, z1[q]);
            acc[q] = _mm256_fmadd_pd(z0[q], z0[q], acc[q]);
            acc[q] = _mm256_fmadd_pd(z1[q], z1[q], acc[q]);
        }
        start += 2 * r + 3;
        r += 2;
    }
    if r < d {
        let row = w.add(start);
        let mut z = [zero; 4];
        for k in 0..=r {
            let a = _mm256_broadcast_sd(&*row.add(k));
            let xk = x.add(k * LANES);
            for (q, zq) in z.iter_mut().enumerate() {
                *zq = _mm256_fmadd_pd(a, _mm256_loadu_pd(xk.add(4 * q)), *zq);
            }
        }
        for (aq, zq) in acc.iter_mut().zip(&z) {
            *aq = _mm256_fmadd_pd(*zq, *zq, *aq);
        }
    }
    for (q, aq) in acc.iter().enumerate() {
        _mm256_storeu_pd(out.as_mut_ptr().add(4 * q), *aq);
    }
}

/// Body of the squared-norm kernels: rows of `W` two at a time (sharing the
/// loads of `v`), `z_r = Σ_{k ≤ r} w_rk v_k` by fused multiply-adds in
/// increasing `k`, then `acc += z_r²` in increasing `r`. `f64::mul_add` is
/// correctly rounded on every target (hardware or libm), so all code paths
/// give identical results.
#[inline(always)]
pub fn sq_norms<const L: usize>(packed: &[f64], d: usize, xt: &[f64], out: &mut [f64; L]) {
    assert!(packed.len() >= packed_len(d) && xt.len() >= d * L);
    let lane = |k: usize| -> &[f64; L] { xt[k * L..(k + 1) * L].try_into().unwrap() };
    let mut acc = [0.0; L];
    let mut start = 0;
    let mut r = 0;
    while r + 1 < d {
        let row0 = &packed[start..start + r + 1];
        let row1 = &packed[start + r + 1..start + 2 * r + 3];
        let mut z0 = [0.0; L];
        let mut z1 = [0.0; L];
        for k in 0..=r {
            let x = lane(k);
            let (a, b) = (row0[k], row1[k]);
            for l in 0..L {
                z0[l] = a.mul_add(x[l], z0[l]);
                z1[l] = b.mul_add(x[l], z1[l]);
            }
        }
        let x = lane(r + 1);
        let b = row1[r + 1];
        for l in 0..L {
            z1[l] = b.mul_add(x[l], z1[l]);
            acc[l] = z0[l].mul_add(z0[l], acc[l]);
            acc[l] = z1[l].mul_add(z1[l], acc[l]);
        }
        start += 2 * r + 3;
        r += 2;
    }
    if r < d {
        let row = &packed[start..start + r + 1];
        let mut z = [0.0; L];
        for (k, a) in row.iter().enumerate() {
            let x = lane(k);
            for l in 0..L {
                z[l] = a.mul_add(x[l], z[l]);
            }
        }
        for l in 0..L {
            acc[l] = z[l].mul_add(z[l], acc[l]);
        }
    }
    *out = acc;
}

/// States evaluated together by [`sq_norms_lanes`].
pub const STATE_LANES: usize = 8;

/// `out[l] = ‖W_l v_l‖²` for [`STATE_LANES`] different packed lower
/// triangles at once (one frame under several states): `wl[e·8 + l]` is entry
/// `e` of `W_l`, `xt[k·8 + l]` entry `k` of `v_l`. Every lane does exactly the
/// arithmetic of [`packed_lower_sq_norm`] (and of one lane of [`sq_norms`]).
#[inline(always)]
pub fn sq_norms_lanes(wl: &[f64], d: usize, xt: &[f64], out: &mut [f64; STATE_LANES]) {
    const L: usize = STATE_LANES;
    assert!(wl.len() >= packed_len(d) * L && xt.len() >= d * L);
    let lane = |v: &[f64], k: usize| -> [f64; L] { v[k * L..(k + 1) * L].try_into().unwrap() };
    let mut acc = [0.0; L];
    let mut start = 0;
    let mut r = 0;
    while r + 1 < d {
        let mut z0 = [0.0; L];
        let mut z1 = [0.0; L];
        for k in 0..=r {
            let x = lane(xt, k);
            let a = lane(wl, start + k);
            let b = lane(wl, start + r + 1 + k);
            for l in 0..L {
                z0[l] = a[l].mul_add(x[l], z0[l]);
                z1[l] = b[l].mul_add(x[l], z1[l]);
            }
        }
        let x = lane(xt, r + 1);
        let b = lane(wl, start + 2 * r + 2);
        for l in 0..L {
            z1[l] = b[l].mul_add(x[l], z1[l]);
            acc[l] = z0[l].mul_add(z0[l], acc[l]);
            acc[l] = z1[l].mul_add(z1[l], acc[l]);
        }
        start += 2 * r + 3;
        r += 2;
    }
    if r < d {
        let mut z = [0.0; L];
        for k in 0..=r {
            let x = lane(xt, k);
            let a = lane(wl, start + k);
            for l in 0..L {
                z[l] = a[l].mul_add(x[l], z[l]);
            }
        }
        for l in 0..L {
            acc[l] = z[l].mul_add(z[l], acc[l]);
        }
    }
    *out = acc;
}

/// `dst[j] = src[j] − m` (elementwise, so every code path agrees exactly).
#[inline(always)]
pub fn sub_scalar(dst: &mut [f64], src: &[f64], m: f64) {
    assert_eq!(dst.len(), src.len());
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU supports AVX2 (checked above); lengths are equal.
            unsafe { sub_scalar_avx2(dst, src, m) };
            return;
        }
    }
    for (o, v) in dst.iter_mut().zip(src) {
        *o = v - m;
    }
}

#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn sub_scalar_avx2(dst: &mut [f64], src: &[f64], m: f64) {
    use std::arch::x86_64::*;
    let n = dst.len();
    let mv = _mm256_set1_pd(m);
    let (o, x) = (dst.as_mut_ptr(), src.as_ptr());
    let mut j = 0;
    while j + 4 <= n {
        _mm256_storeu_pd(o.add(j), _mm256_sub_pd(_mm256_loadu_pd(x.add(j)), mv));
        j += 4;
    }
    while j < n {
        *o.add(j) = *x.add(j) - m;
        j += 1;
    }
}

/// Centred and weighted values for the accumulation: `d[j] = x[j] − c`,
/// `a[j] = w[j]·d[j]`; returns `Σ_j a[j]` by four interleaved partial sums
/// (lane `j mod 4`) combined by [`reduce_lanes`]. All lengths are equal and a
/// multiple of 4.
#[inline(always)]
pub fn centre_weight(x: &[f64], c: f64, w: &[f64], d: &mut [f64], a: &mut [f64]) -> f64 {
    let n = x.len();
    assert!(n.is_multiple_of(4) && w.len() == n && d.len() == n && a.len() == n);
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU supports AVX2 (checked above); lengths checked.
            return unsafe { centre_weight_avx2(x, c, w, d, a) };
        }
    }
    let mut part = [0.0; 4];
    for j in 0..n {
        d[j] = x[j] - c;
        a[j] = w[j] * d[j];
        part[j % 4] += a[j];
    }
    reduce_lanes(part)
}

#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn centre_weight_avx2(x: &[f64], c: f64, w: &[f64], d: &mut [f64], a: &mut [f64]) -> f64 {
    use std::arch::x86_64::*;
    let n = x.len();
    let cv = _mm256_set1_pd(c);
    let mut acc = _mm256_setzero_pd();
    let mut j = 0;
    while j < n {
        let dv = _mm256_sub_pd(_mm256_loadu_pd(x.as_ptr().add(j)), cv);
        let av = _mm256_mul_pd(_mm256_loadu_pd(w.as_ptr().add(j)), dv);
        _mm256_storeu_pd(d.as_mut_ptr().add(j), dv);
        _mm256_storeu_pd(a.as_mut_ptr().add(j), av);
        acc = _mm256_add_pd(acc, av);
        j += 4;
    }
    let mut part = [0.0; 4];
    _mm256_storeu_pd(part.as_mut_ptr(), acc);
    reduce_lanes(part)
}

/// `Σ_j v_j` by `L` interleaved partial sums (lane `l` takes `j ≡ l mod L`),
/// combined pairwise; `v.len()` must be a multiple of `L`.
#[inline(always)]
pub fn lane_sum<const L: usize>(v: &[f64]) -> f64 {
    assert!(v.len().is_multiple_of(L));
    let mut acc = [0.0; L];
    for chunk in v.chunks_exact(L) {
        for l in 0..L {
            acc[l] += chunk[l];
        }
    }
    reduce_lanes(acc)
}

/// Pairwise sum of `L` partial sums, in a fixed order.
#[inline(always)]
pub fn reduce_lanes<const L: usize>(mut acc: [f64; L]) -> f64 {
    let mut w = L;
    while w > 1 {
        let h = w / 2;
        for l in 0..h {
            acc[l] += acc[l + h];
        }
        if w % 2 == 1 {
            acc[0] += acc[w - 1];
        }
        w = h;
    }
    acc[0]
}

/// A 4 × 3 tile of dot products over `m` frames,
/// `out[u][v] = Σ_j a[(r0+u)·m + j] · b[(c0+v)·m + j]`, for rows of `a` and
/// `b` stored with stride `m` (a multiple of [`DOT_LANES`]): fused
/// multiply-adds into [`DOT_LANES`] interleaved partial sums per entry,
/// combined by [`lane_sum`]'s rule. The AVX2 form (one register per entry,
/// twelve accumulators) and the portable form do the same arithmetic, lane by lane.
#[inline(always)]
pub fn dot_tile(a: &[f64], b: &[f64], m: usize, r0: usize, c0: usize) -> [[f64; 3]; 4] {
    assert!(m.is_multiple_of(DOT_LANES) && a.len() >= (r0 + 4) * m && b.len() >= (c0 + 3) * m);
    let rows: [&[f64]; 7] = [
        &a[r0 * m..(r0 + 1) * m],
        &a[(r0 + 1) * m..(r0 + 2) * m],
        &a[(r0 + 2) * m..(r0 + 3) * m],
        &a[(r0 + 3) * m..(r0 + 4) * m],
        &b[c0 * m..(c0 + 1) * m],
        &b[(c0 + 1) * m..(c0 + 2) * m],
        &b[(c0 + 2) * m..(c0 + 3) * m],
    ];
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU supports AVX2 and FMA (checked above); every row
            // holds `m` values, a multiple of 4.
            let acc = unsafe { dot_tile_avx2_fma(rows, m) };
            return std::array::from_fn(|u| std::array::from_fn(|v| reduce_lanes(acc[u][v])));
        }
    }
    let mut acc = [[[0.0; DOT_LANES]; 3]; 4];
    for j in (0..m).step_by(DOT_LANES) {
        for u in 0..4 {
            for v in 0..3 {
                for l in 0..DOT_LANES {
                    acc[u][v][l] = rows[u][j + l].mul_add(rows[4 + v][j + l], acc[u][v][l]);
                }
            }
        }
    }
    std::array::from_fn(|u| std::array::from_fn(|v| reduce_lanes(acc[u][v])))
}

/// Interleaved partial sums of [`dot_tile`] (one AVX2 register).
pub const DOT_LANES: usize = 4;

#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn dot_tile_avx2_fma(rows: [&[f64]; 7], m: usize) -> [[[f64; 4]; 3]; 4] {
    use std::arch::x86_64::*;
    let p: [*const f64; 7] = std::array::from_fn(|k| rows[k].as_ptr());
    let mut c = [_mm256_setzero_pd(); 12];
    let mut j = 0;
    while j < m {
        let b0 = _mm256_loadu_pd(p[4].add(j));
        let b1 = _mm256_loadu_pd(p[5].add(j));
        let b2 = _mm256_loadu_pd(p[6].add(j));
        for u in 0..4 {
            let x = _mm256_loadu_pd(p[u].add(j));
            c[3 * u] = _mm256_fmadd_pd(x, b0, c[3 * u]);
            c[3 * u + 1] = _mm256_fmadd_pd(x, b1, c[3 * u + 1]);
            c[3 * u + 2] = _mm256_fmadd_pd(x, b2, c[3 * u + 2]);
        }
        j += 4;
    }
    let mut out = [[[0.0; 4]; 3]; 4];
    for u in 0..4 {
        for v in 0..3 {
            _mm256_storeu_pd(out[u][v].as_mut_ptr(), c[3 * u + v]);
        }
    }
    out
}

/// `out = L z` for a packed lower-triangular `L`.
#[inline]
pub fn packed_lower_mul(packed: &[f64], z: &[f64], out: &mut [f64]) {
    for (r, o) in out.iter_mut().enumerate() {
        *o = packed_row(packed, r)
            .iter()
            .zip(&z[..=r])
            .map(|(a, b)| a * b)
            .sum();
    }
}

/// `log Σ_i exp(x_i)`, exact for `-inf` entries; `-inf` for an empty or all-`-inf` slice.
///
/// `m + ln Σ_i e^{x_i − m}` with `m = max_i x_i`; the exponentials are taken
/// by [`exp_in_place`] in blocks on the stack (no allocation) and summed in
/// index order. Terms with `x_i − m <` [`EXP_UNDERFLOW`] are exactly zero and
/// are skipped, as with [`exp_or_zero`].
#[inline]
pub fn log_sum_exp(x: &[f64]) -> f64 {
    let m = x.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    if m == f64::INFINITY {
        return m;
    }
    // Only the terms that are not exactly zero are exponentiated (in well
    // separated models that is often the maximum alone, whose term is 1);
    // leaving out exact zeros does not change the sum.
    let mut buf = [0.0; 32];
    let mut sum = 0.0;
    for chunk in x.chunks(buf.len()) {
        let mut n = 0;
        for v in chunk {
            let d = v - m;
            // NaN is kept (and propagates).
            if d >= EXP_UNDERFLOW || d.is_nan() {
                buf[n] = d;
                n += 1;
            }
        }
        let b = &mut buf[..n];
        if n == 1 && b[0] == 0.0 {
            b[0] = 1.0;
        } else {
            exp_in_place(b);
        }
        for e in b.iter() {
            sum += e;
        }
    }
    m + sum.ln()
}

/// Below this, `exp` is exactly `0.0` in IEEE double precision (the smallest
/// subnormal is `e^{−744.44}`), so skipping the call changes no bit.
pub const EXP_UNDERFLOW: f64 = -746.0;

/// `e^x`, without calling `exp` where the result is exactly zero anyway.
///
/// In the log-space recursions of well-separated models most terms are far
/// below the largest one; skipping their `exp` calls makes those passes
/// several times faster with bit-identical results.
#[inline]
pub fn exp_or_zero(x: f64) -> f64 {
    if x < EXP_UNDERFLOW {
        0.0
    } else {
        x.exp()
    }
}

/// `v_i ← e^{v_i}` for a whole slice, vectorised: within 1 ulp of glibc's
/// (nearly always correctly rounded) `exp` on every argument tested
/// (millions, over the whole finite range, and the edge cases).
///
/// `e^x = 2^k e^r` with `k = round(x / ln 2)` and `r = x − k ln 2` (Cody–Waite:
/// `ln 2` split in two doubles, both products by fused multiply-add, so the
/// error of `r` is far below an ulp of `r`), `|r| ≤ ln 2 / 2`. `e^r` is the
/// degree-13 Taylor polynomial (truncation ≤ 4e-18 relative) with
/// `f64::mul_add`, its high-order part by Estrin and the last terms by Horner.
/// `2^k` is applied as two exact powers `2^{k₁} 2^{k₂}` (`k₁ + k₂ = k`, both
/// halves normal), so results in the subnormal range are rounded once and are
/// as accurate as the subnormal grid allows, results below half the smallest
/// subnormal (`x < −745.13`) are exactly `0.0` (as [`exp_or_zero`]: no
/// flush-to-zero anywhere), and `x > 709.78` gives `+inf`. `−inf → 0`,
/// `+inf → +inf`, NaN → NaN.
///
/// Branch-free lanes in blocks of 8, compiled for AVX2 + FMA when the CPU has
/// them (checked at run time) and otherwise portably with the same
/// operations (`mul_add` is correctly rounded in hardware and in software),
/// so results are bit-identical on every CPU, in every block position and for
/// every slice length.
#[inline]
pub fn exp_in_place(v: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU supports AVX2 and FMA (checked above).
            unsafe { exp_in_place_avx2_fma(v) };
            return;
        }
    }
    exp_in_place_portable(v)
}

/// [`exp_in_place`] compiled for AVX2 + FMA (the same operations).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn exp_in_place_avx2_fma(v: &mut [f64]) {
    // SAFETY: the caller checked AVX2 and FMA.
    exp_in_place_body(v, |b| unsafe { exp_block_avx2_fma(b) })
}

/// One block for AVX2 + FMA. Kept out of line: inlined into the loop over
/// blocks, LLVM vectorises that loop across blocks (strided loads) instead of
/// the lanes of a block, and short slices (one or two blocks, the common case
/// here) then run its scalar remainder loop.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline(never)]
unsafe fn exp_block_avx2_fma(v: &mut [f64; EXP_BLOCK]) {
    exp_block(v)
}

/// [`exp_in_place`] without run-time CPU dispatch (the reference build).
#[doc(hidden)]
pub fn exp_in_place_portable(v: &mut [f64]) {
    exp_in_place_body(v, exp_block)
}

#[inline(always)]
fn exp_in_place_body(v: &mut [f64], block: impl Fn(&mut [f64; EXP_BLOCK])) {
    let mut chunks = v.chunks_exact_mut(EXP_BLOCK);
    for c in &mut chunks {
        // A block whose lanes are all exactly zero after exponentiation is
        // just cleared (common in the log-space recursions of well-separated
        // models; the result is the same bits).
        let zero = c.iter().fold(true, |z, x| z & (*x < EXP_UNDERFLOW));
        if zero {
            c.fill(0.0);
        } else {
            block(c.try_into().expect("chunks_exact_mut gives full blocks"));
        }
    }
    let rest = chunks.into_remainder();
    if !rest.is_empty() {
        // The tail goes through a padded block too: same lanes, vectorised.
        // Lane by lane rather than `copy_from_slice`, which would call
        // `memmove` for these few bytes.
        let mut buf = [0.0; EXP_BLOCK];
        for (i, b) in buf.iter_mut().enumerate() {
            *b = rest.get(i).copied().unwrap_or(0.0);
        }
        block(&mut buf);
        for (i, b) in buf.iter().enumerate() {
            if let Some(r) = rest.get_mut(i) {
                *r = *b;
            }
        }
    }
}

/// Lanes of one [`exp_in_place`] block (two AVX2 vectors).
const EXP_BLOCK: usize = 8;

/// One block of [`exp_in_place`]: every step is a loop over the 8 lanes
/// (structure of arrays, selects instead of branches), which LLVM turns into
/// two 4-wide vector operations per step.
#[inline(always)]
fn exp_block(v: &mut [f64; EXP_BLOCK]) {
    const N: usize = EXP_BLOCK;
    // Clamp (see EXP_CLAMP_LO); comparisons are false for NaN, which passes
    // through and stays NaN.
    let mut x = *v;
    for xi in x.iter_mut() {
        *xi = if *xi < EXP_CLAMP_LO {
            EXP_CLAMP_LO
        } else {
            *xi
        };
    }
    for xi in x.iter_mut() {
        *xi = if *xi > EXP_CLAMP_HI {
            EXP_CLAMP_HI
        } else {
            *xi
        };
    }
    // t = x / ln 2 + 1.5·2^52 holds k = round(x / ln 2) in its low bits.
    let mut t = [0.0; N];
    for (ti, xi) in t.iter_mut().zip(&x) {
        *ti = xi.mul_add(EXP_LOG2E, EXP_SHIFTER);
    }
    // r = x − k ln 2 (Cody–Waite).
    let mut r = [0.0; N];
    for ((ri, ti), xi) in r.iter_mut().zip(&t).zip(&x) {
        let mk = EXP_SHIFTER - ti;
        *ri = mk.mul_add(EXP_LN2_HI, *xi);
        *ri = mk.mul_add(EXP_LN2_LO, *ri);
    }
    // e^r = 1 + r (1 + r (1/2 + r Q(r))), Q(r) = Σ_{i=0}^{10} r^i / (i + 3)!
    // by Estrin (dependency depth 4 instead of 10: the blocks here are short,
    // so latency rather than throughput bounds them); the last three steps
    // by Horner, where the rounding matters.
    let c = |i: usize| EXP_C[i + 1];
    let mut p = [0.0; N];
    for (pi, ri) in p.iter_mut().zip(&r) {
        let r = *ri;
        let r2 = r * r;
        let r4 = r2 * r2;
        let r8 = r4 * r4;
        let a0 = c(1).mul_add(r, c(0));
        let a1 = c(3).mul_add(r, c(2));
        let a2 = c(5).mul_add(r, c(4));
        let a3 = c(7).mul_add(r, c(6));
        let a4 = c(9).mul_add(r, c(8));
        let b0 = a1.mul_add(r2, a0);
        let b1 = a3.mul_add(r2, a2);
        let b2 = c(10).mul_add(r2, a4);
        let q = b2.mul_add(r8, b1.mul_add(r4, b0));
        let e = q.mul_add(r, EXP_C[0]);
        let e = e.mul_add(r, 1.0);
        *pi = e.mul_add(r, 1.0);
    }
    // u = k + 2048 > 0 from the low mantissa bits of t; 2^k = 2^{k₁} 2^{k₂}
    // with k₁ = ⌊u/2⌋ − 1024 and k₂ = k − k₁, biased exponents k₁ + 1023 and
    // k₂ + 1023 (logical shifts only: AVX2 has no 64-bit arithmetic shift).
    for ((vi, pi), ti) in v.iter_mut().zip(&p).zip(&t) {
        let u = ti
            .to_bits()
            .wrapping_sub(EXP_SHIFTER.to_bits().wrapping_sub(2048));
        let h = u >> 1;
        let s1 = f64::from_bits(h.wrapping_sub(1) << 52);
        let s2 = f64::from_bits(u.wrapping_sub(h).wrapping_sub(1) << 52);
        *vi = pi * s1 * s2;
    }
}

/// `1 / ln 2`.
const EXP_LOG2E: f64 = std::f64::consts::LOG2_E;
/// `ln 2 = EXP_LN2_HI + EXP_LN2_LO` (to ~2^-107).
const EXP_LN2_HI: f64 = std::f64::consts::LN_2;
const EXP_LN2_LO: f64 = 2.319_046_813_846_299_6e-17;
/// `1.5 · 2^52`: adding it rounds to an integer (to nearest, ties to even),
/// which is then held in the low bits of the sum's mantissa.
const EXP_SHIFTER: f64 = 6_755_399_441_055_744.0;
/// Arguments are clamped to this range before the reduction, which keeps `k`
/// in `[−1082, 1024]` (so both halves of `2^k` are normal) and changes no
/// result: `e^{−750}` and `e^{−746}` are both `0.0`, `e^{710}` is `+inf`.
const EXP_CLAMP_LO: f64 = -750.0;
const EXP_CLAMP_HI: f64 = 710.0;
/// `1 / n!` for `n = 2..=13` (correctly rounded).
const EXP_C: [f64; 12] = [
    0.5,
    0.16666666666666666,
    0.041666666666666664,
    0.008333333333333333,
    0.001388888888888889,
    0.0001984126984126984,
    2.48015873015873e-05,
    2.7557319223985893e-06,
    2.755731922398589e-07,
    2.505210838544172e-08,
    2.08767569878681e-09,
    1.6059043836821613e-10,
];

/// Cholesky factor of a symmetric matrix, or `None` when it is not positive
/// definite (or not finite).
pub fn cholesky(m: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let l = nalgebra::Cholesky::new(m.clone())?.unpack();
    if l.diagonal().iter().all(|v| *v > 0.0 && v.is_finite()) {
        Some(l)
    } else {
        None
    }
}

/// Inverse of a lower-triangular matrix by forward substitution against `I`.
///
/// For `L = chol(Σ)` this is the Cholesky factor of the precision (`Σ⁻¹ = Wᵀ W`),
/// the form scikit-learn stores; the covariance itself is never inverted.
pub fn lower_triangular_inverse(l: &DMatrix<f64>) -> DMatrix<f64> {
    let d = l.nrows();
    l.solve_lower_triangular(&DMatrix::identity(d, d))
        .expect("a Cholesky factor has a positive diagonal")
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Distance in units in the last place (ordered bit patterns).
    fn ulps(a: f64, b: f64) -> u64 {
        if a == b {
            return 0;
        }
        let key = |v: f64| {
            let b = v.to_bits() as i64;
            if b < 0 {
                i64::MIN - b
            } else {
                b
            }
        };
        key(a).abs_diff(key(b))
    }

    #[test]
    fn exp_is_within_one_ulp_of_libm() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 2_000_000;
        let mut x: Vec<f64> = (0..n).map(|_| rng.random_range(-745.0..709.0)).collect();
        // Also the range of the forward-backward (shifted log-densities ≤ 0)
        // and the neighbourhood of 0, where the relative precision matters.
        x.extend((0..200_000).map(|_| rng.random_range(-40.0..0.0)));
        x.extend((0..200_000).map(|_| rng.random_range(-1e-3..1e-3)));
        let mut e = x.clone();
        exp_in_place(&mut e);
        let mut worst = (0, 0.0);
        for (xi, ei) in x.iter().zip(&e) {
            let d = ulps(*ei, xi.exp());
            if d > worst.0 {
                worst = (d, *xi);
            }
        }
        assert!(worst.0 <= 1, "{} ulp at x = {:e}", worst.0, worst.1);
    }

    #[test]
    fn exp_edge_cases() {
        let tiny = f64::from_bits(1); // smallest subnormal, e^{−744.44}
        let cases = [
            (0.0, 1.0),
            (-0.0, 1.0),
            (f64::NEG_INFINITY, 0.0),
            (f64::INFINITY, f64::INFINITY),
            (-746.0, 0.0),
            (-745.2, 0.0),
            (-1e300, 0.0),
            (709.8, f64::INFINITY),
            (710.0, f64::INFINITY),
            (1e300, f64::INFINITY),
            (f64::MIN, 0.0),
            (f64::MAX, f64::INFINITY),
        ];
        for (x, want) in cases {
            let mut v = [x];
            exp_in_place(&mut v);
            assert_eq!(v[0].to_bits(), want.to_bits(), "exp({x:e})");
        }
        let mut v = [f64::NAN, -f64::NAN];
        exp_in_place(&mut v);
        assert!(v[0].is_nan() && v[1].is_nan());
        // Subnormal and near-overflow results, and tiny arguments, against libm.
        let mut x: Vec<f64> = Vec::new();
        let mut a = -745.2;
        while a < -707.0 {
            x.push(a);
            a += 0.0137;
        }
        let mut a = 709.0;
        while a < 709.78 {
            x.push(a);
            a += 0.001;
        }
        x.extend([
            709.782_712_893_384,
            -745.133_219_101_941_1,
            -744.440_071_921_381,
            -708.396_418_532_264,
            1e-300,
            -1e-300,
            tiny,
            -tiny,
            f64::EPSILON,
            -f64::EPSILON,
            0.5 * std::f64::consts::LN_2,
            -0.5 * std::f64::consts::LN_2,
            1.0,
            -1.0,
        ]);
        let mut e = x.clone();
        exp_in_place(&mut e);
        for (xi, ei) in x.iter().zip(&e) {
            assert!(
                ulps(*ei, xi.exp()) <= 1,
                "exp({xi:e}) = {ei:e}, libm {:e}",
                xi.exp()
            );
            if *xi < EXP_UNDERFLOW {
                assert_eq!(*ei, 0.0);
            }
        }
        let mut v = [-744.44];
        exp_in_place(&mut v);
        assert_eq!(v[0], tiny);
    }

    #[test]
    fn exp_is_bit_identical_across_builds_and_lengths() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let x: Vec<f64> = (0..100_003)
            .map(|_| rng.random_range(-760.0..720.0))
            .collect();
        let mut dispatched = x.clone();
        exp_in_place(&mut dispatched);
        let mut portable = x.clone();
        exp_in_place_portable(&mut portable);
        for (a, b) in dispatched.iter().zip(&portable) {
            assert_eq!(a.to_bits(), b.to_bits());
        }
        // Tails and offsets: every length 0..=20 at every position.
        for len in 0..=20 {
            for start in 0..5 {
                let mut v = x[start..start + len].to_vec();
                exp_in_place(&mut v);
                for (a, b) in v.iter().zip(&dispatched[start..start + len]) {
                    assert_eq!(a.to_bits(), b.to_bits());
                }
            }
        }
    }

    #[test]
    fn log_sum_exp_matches_the_direct_sum() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for len in [1, 2, 7, 8, 15, 16, 31, 32, 33, 100] {
            let x: Vec<f64> = (0..len).map(|_| rng.random_range(-800.0..50.0)).collect();
            let m = x.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let direct = m + x.iter().map(|v| exp_or_zero(v - m)).sum::<f64>().ln();
            let got = log_sum_exp(&x);
            assert!((got - direct).abs() <= 1e-14 * direct.abs().max(1.0));
        }
        assert_eq!(log_sum_exp(&[]), f64::NEG_INFINITY);
        assert_eq!(log_sum_exp(&[f64::NEG_INFINITY; 3]), f64::NEG_INFINITY);
        assert_eq!(log_sum_exp(&[0.0, f64::NEG_INFINITY]), 0.0);
        assert_eq!(log_sum_exp(&[1.0, f64::INFINITY]), f64::INFINITY);
        assert_eq!(log_sum_exp(&[-5.0, -1000.0]), -5.0);
    }
}
