//! The exponential of a whole slice, vectorised and the same bits on every
//! CPU ([`exp_in_place`]), and the log-sum-exp built on it.

use super::dispatch::dispatch;

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
/// Branch-free lanes in blocks of 8, compiled for the best instruction set
/// of the CPU ([`dispatch`]) with the same operations in every build
/// (`mul_add` is correctly rounded in hardware and in software), so results
/// are bit-identical on every CPU, in every block position and for every
/// slice length.
#[inline]
pub fn exp_in_place(v: &mut [f64]) {
    dispatch(
        #[inline(always)]
        || exp_slice(v),
    )
}

/// [`exp_in_place`] in the build of its caller, for code that is itself run
/// through [`dispatch`] (inlined there, so that it shares its instruction set).
#[inline(always)]
pub fn exp_slice(v: &mut [f64]) {
    let mut chunks = v.chunks_exact_mut(EXP_BLOCK);
    for c in &mut chunks {
        let c: &mut [f64; EXP_BLOCK] = c.try_into().expect("chunks_exact_mut gives full blocks");
        // An opaque step per block keeps LLVM from vectorising this loop
        // across blocks (strided loads, and a scalar loop for the one or two
        // blocks of a short slice, the common case here) instead of across
        // the lanes of a block.
        let c = std::hint::black_box(c);
        // A block whose lanes are all exactly zero after exponentiation is
        // just cleared (common in the log-space recursions of well-separated
        // models; the result is the same bits).
        let zero = c.iter().fold(true, |z, x| z & (*x < EXP_UNDERFLOW));
        if zero {
            *c = [0.0; EXP_BLOCK];
        } else {
            exp_block(c);
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
        exp_block(&mut buf);
        for (i, b) in buf.iter().enumerate() {
            if let Some(r) = rest.get_mut(i) {
                *r = *b;
            }
        }
    }
}

/// `v_l ← e^{v_l}` on the eight lanes of one block: the same bits as
/// [`exp_slice`] (a block whose lanes all underflow is cleared), without
/// its per-block barrier, so that a caller's independent blocks interleave.
/// In the build of its caller.
#[inline(always)]
pub fn exp_lanes(v: &mut [f64; EXP_BLOCK]) {
    let zero = v.iter().fold(true, |z, x| z & (*x < EXP_UNDERFLOW));
    if zero {
        *v = [0.0; EXP_BLOCK];
    } else {
        exp_block(v);
    }
}

/// [`exp_in_place`] without run-time CPU dispatch (the portable build, for tests).
#[doc(hidden)]
#[inline(never)]
pub fn exp_in_place_portable(v: &mut [f64]) {
    exp_slice(v)
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    use crate::linalg::test_support::ulps;

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
