//! Kernels of the weighted scatter `Σ_t w_t (x_t − c)(x_t − c)ᵀ` (the
//! Gaussian statistics), on frames stored transposed (one row per dimension):
//! centring and weighting ([`centre_weight`]), sums by interleaved partial
//! sums ([`lane_sum`], [`reduce_lanes`]) and 4 × 3 tiles of dot products
//! ([`dot_tile`]).
//!
//! The number of interleaved partial sums ([`DOT_LANES`]) is part of the
//! arithmetic, not of the SIMD width: every build adds the same terms in the
//! same order, so results are the same bits on every CPU.

/// Interleaved partial sums of [`dot_tile`] and [`centre_weight`] (one AVX2 register).
pub const DOT_LANES: usize = 4;

/// `dst[j] = src[j] − m` (elementwise, so every code path agrees exactly).
#[inline(always)]
pub fn sub_scalar(dst: &mut [f64], src: &[f64], m: f64) {
    assert_eq!(dst.len(), src.len());
    #[cfg(target_arch = "x86_64")]
    if super::dispatch::has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked by `has_avx2_fma`).
        unsafe { super::x86::sub_scalar_avx2(dst, src, m) };
        return;
    }
    for (o, v) in dst.iter_mut().zip(src) {
        *o = v - m;
    }
}

/// Centred and weighted values for the accumulation: `d[j] = x[j] − c`,
/// `a[j] = w[j]·d[j]`; returns `Σ_j a[j]` by four interleaved partial sums
/// (lane `j mod 4`) combined by [`reduce_lanes`]. All lengths are equal and a
/// multiple of 4.
#[inline(always)]
pub fn centre_weight(x: &[f64], c: f64, w: &[f64], d: &mut [f64], a: &mut [f64]) -> f64 {
    let n = x.len();
    assert!(n % DOT_LANES == 0 && w.len() == n && d.len() == n && a.len() == n);
    #[cfg(target_arch = "x86_64")]
    if super::dispatch::has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked by `has_avx2_fma`).
        return reduce_lanes(unsafe { super::x86::centre_weight_avx2(x, c, w, d, a) });
    }
    let mut part = [0.0; DOT_LANES];
    for (((x, w), d), a) in x
        .chunks_exact(DOT_LANES)
        .zip(w.chunks_exact(DOT_LANES))
        .zip(d.chunks_exact_mut(DOT_LANES))
        .zip(a.chunks_exact_mut(DOT_LANES))
    {
        for l in 0..DOT_LANES {
            d[l] = x[l] - c;
            a[l] = w[l] * d[l];
            part[l] += a[l];
        }
    }
    reduce_lanes(part)
}

/// `Σ_j v_j` by `L` interleaved partial sums (lane `l` takes `j ≡ l mod L`),
/// combined pairwise; `v.len()` must be a multiple of `L`.
#[inline(always)]
pub fn lane_sum<const L: usize>(v: &[f64]) -> f64 {
    assert!(v.len() % L == 0);
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
/// multiply-adds into [`DOT_LANES`] interleaved partial sums per entry (one
/// register each, twelve accumulators), combined by [`reduce_lanes`].
#[inline(always)]
pub fn dot_tile(a: &[f64], b: &[f64], m: usize, r0: usize, c0: usize) -> [[f64; 3]; 4] {
    const L: usize = DOT_LANES;
    assert!(m % L == 0 && a.len() >= (r0 + 4) * m && b.len() >= (c0 + 3) * m);
    let (a0, a1, a2, a3) = (
        &a[r0 * m..(r0 + 1) * m],
        &a[(r0 + 1) * m..(r0 + 2) * m],
        &a[(r0 + 2) * m..(r0 + 3) * m],
        &a[(r0 + 3) * m..(r0 + 4) * m],
    );
    let (b0, b1, b2) = (
        &b[c0 * m..(c0 + 1) * m],
        &b[(c0 + 1) * m..(c0 + 2) * m],
        &b[(c0 + 2) * m..(c0 + 3) * m],
    );
    #[cfg(target_arch = "x86_64")]
    if super::dispatch::has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked by `has_avx2_fma`).
        let acc = unsafe { super::x86::dot_tile_avx2_fma([a0, a1, a2, a3, b0, b1, b2], m) };
        return std::array::from_fn(|u| std::array::from_fn(|v| reduce_lanes(acc[u][v])));
    }
    let mut acc = [[[0.0; L]; 3]; 4];
    fn chunks(r: &[f64]) -> impl Iterator<Item = [f64; DOT_LANES]> + '_ {
        r.chunks_exact(DOT_LANES).map(|c| c.try_into().unwrap())
    }
    let rows_a = chunks(a0).zip(chunks(a1)).zip(chunks(a2)).zip(chunks(a3));
    let rows_b = chunks(b0).zip(chunks(b1)).zip(chunks(b2));
    for ((((x0, x1), x2), x3), ((y0, y1), y2)) in rows_a.zip(rows_b) {
        let ys = [y0, y1, y2];
        for (u, x) in [x0, x1, x2, x3].iter().enumerate() {
            for (v, y) in ys.iter().enumerate() {
                for l in 0..L {
                    acc[u][v][l] = x[l].mul_add(y[l], acc[u][v][l]);
                }
            }
        }
    }
    std::array::from_fn(|u| std::array::from_fn(|v| reduce_lanes(acc[u][v])))
}
