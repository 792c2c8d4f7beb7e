//! The kernels of the Gaussian log-densities and statistics written with
//! AVX2 intrinsics, because LLVM's vectorisation of their portable form, in
//! the AVX2 build of a generic x86-64 target, uses 128-bit vectors or keeps
//! fewer accumulators in registers, and is measurably slower (`bench_compare
//! kernels`, interleaved runs, best of 6: the statistics 1.3× slower at
//! S = 16, D = 12 with the portable tile and centring, the log-densities
//! 1.2× slower).
//!
//! Each does, lane by lane, exactly the arithmetic of its portable form
//! ([`super::sq_norms`], [`super::dot_tile`], [`super::centre_weight`],
//! [`super::sub_scalar`]): tested bit for bit.

use super::norms::LANES;
use super::packed::packed_len;
use super::tiles::DOT_LANES;
use std::arch::x86_64::*;

/// [`super::sq_norms`] for [`LANES`] = 16 frames, four AVX2 registers per
/// row, two rows per pass (eight independent chains of fused multiply-adds).
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(super) fn sq_norms16_avx2_fma(packed: &[f64], d: usize, xt: &[f64], out: &mut [f64; LANES]) {
    assert!(LANES == 16 && packed.len() >= packed_len(d) && xt.len() >= d * LANES);
    let zero = _mm256_setzero_pd();
    let mut acc = [zero; 4];
    let w = packed.as_ptr();
    let x = xt.as_ptr();
    // SAFETY: every pointer below stays inside `packed` (entries
    // `start .. start + 2r + 3 ≤ packed_len(d)` of rows `r`, `r + 1 < d`) or
    // `xt` (entries `k·16 .. k·16 + 16` for `k < d`), whose lengths are
    // asserted above; the loads are unaligned loads of plain `f64`.
    unsafe {
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
}

/// The partial sums of [`super::dot_tile`]: one AVX2 register per entry of
/// the 4 × 3 tile (twelve accumulators), rows `0..4` of `a`, `4..7` of `b`.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(super) fn dot_tile_avx2_fma(rows: [&[f64]; 7], m: usize) -> [[[f64; DOT_LANES]; 3]; 4] {
    assert!(DOT_LANES == 4 && m % 4 == 0 && rows.iter().all(|r| r.len() >= m));
    let p: [*const f64; 7] = std::array::from_fn(|k| rows[k].as_ptr());
    let mut c = [_mm256_setzero_pd(); 12];
    let mut out = [[[0.0; 4]; 3]; 4];
    // SAFETY: `j + 4 ≤ m` and every row holds at least `m` values (asserted
    // above); unaligned loads and stores of plain `f64`.
    unsafe {
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
        for u in 0..4 {
            for v in 0..3 {
                _mm256_storeu_pd(out[u][v].as_mut_ptr(), c[3 * u + v]);
            }
        }
    }
    out
}

/// [`super::sub_scalar`] with AVX2.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(super) fn sub_scalar_avx2(dst: &mut [f64], src: &[f64], m: f64) {
    assert_eq!(dst.len(), src.len());
    let n = dst.len();
    let mv = _mm256_set1_pd(m);
    let (o, x) = (dst.as_mut_ptr(), src.as_ptr());
    // SAFETY: `j + 4 ≤ n` and both slices hold `n` values.
    unsafe {
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
}

/// [`super::centre_weight`] with AVX2.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub(super) fn centre_weight_avx2(
    x: &[f64],
    c: f64,
    w: &[f64],
    d: &mut [f64],
    a: &mut [f64],
) -> [f64; 4] {
    let n = x.len();
    assert!(n % 4 == 0 && w.len() == n && d.len() == n && a.len() == n);
    let cv = _mm256_set1_pd(c);
    let mut acc = _mm256_setzero_pd();
    let mut part = [0.0; 4];
    // SAFETY: `j + 4 ≤ n` and all four slices hold `n` values.
    unsafe {
        let mut j = 0;
        while j < n {
            let dv = _mm256_sub_pd(_mm256_loadu_pd(x.as_ptr().add(j)), cv);
            let av = _mm256_mul_pd(_mm256_loadu_pd(w.as_ptr().add(j)), dv);
            _mm256_storeu_pd(d.as_mut_ptr().add(j), dv);
            _mm256_storeu_pd(a.as_mut_ptr().add(j), av);
            acc = _mm256_add_pd(acc, av);
            j += 4;
        }
        _mm256_storeu_pd(part.as_mut_ptr(), acc);
    }
    part
}
