//! A natural logarithm whose lanes vectorise: the `log c_t` of the scaled
//! recursions, eight sequences at a time in the HMM's lane form.
//!
//! The algorithm is fdlibm's `__ieee754_log` (Sun Microsystems, 1993; the
//! one behind musl's and FreeBSD's `log` for many years): `x = 2^k (1 + f)`
//! with `1 + f` in `[√2/2, √2)`, `s = f / (2 + f)`, `ln(1 + f) = f − s(f −
//! R)` with `R(s²)` a minimax polynomial of degree 14 in `s`, and
//! `ln x = k ln2_hi − ((s(f − R) − k ln2_lo) − f)` (or the form with `½f²`
//! for `1 + f` away from 1), error below 1 ulp. It is written branch-free
//! for positive normal `x` (both forms computed, one selected), so that the
//! same operations run in every lane and in the scalar [`ln`]: [`ln_lanes`]
//! and [`ln`] give the same bits. Zero, subnormal, negative, infinite and NaN
//! arguments go to the platform's `f64::ln`.

/// Lanes of [`ln_lanes`].
pub const LN_LANES: usize = 8;

// fdlibm's constants, by their bits (`e_log.c`).
const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
const LG1: f64 = f64::from_bits(0x3fe5_5555_5555_5593);
const LG2: f64 = f64::from_bits(0x3fd9_9999_9997_fa04);
const LG3: f64 = f64::from_bits(0x3fd2_4924_9422_9359);
const LG4: f64 = f64::from_bits(0x3fcc_71c5_1d8e_78af);
const LG5: f64 = f64::from_bits(0x3fc7_4664_96cb_03de);
const LG6: f64 = f64::from_bits(0x3fc3_9a09_d078_c69f);
const LG7: f64 = f64::from_bits(0x3fc2_f112_df3e_5244);

/// Whether `x` takes the polynomial path (positive, normal, finite).
// `&` rather than `contains` (`&&`): no short circuit, the lanes stay branch-free.
#[allow(clippy::manual_range_contains)]
#[inline(always)]
fn in_range(x: f64) -> bool {
    (x >= f64::MIN_POSITIVE) & (x <= f64::MAX)
}

/// fdlibm's logarithm for a positive normal `x`, branch-free, with 64-bit
/// integer lanes only (so that it vectorises with AVX2 as with AVX-512).
#[inline(always)]
fn ln_normal(x: f64) -> f64 {
    let bits = x.to_bits();
    let hx = bits >> 32;
    // The biased exponent and the high 20 bits of the mantissa.
    let kb = hx >> 20;
    let hm = hx & 0x000f_ffff;
    // Scale 1 + f into [√2/2, √2): i = 0x100000 when the mantissa is above √2.
    let i = (hm + 0x95f64) & 0x0010_0000;
    let m = f64::from_bits(((hm | (i ^ 0x3ff0_0000)) << 32) | (bits & 0xffff_ffff));
    let kb = kb + (i >> 20);
    let f = m - 1.0;
    let s = f / (2.0 + f);
    // k = kb − 1023 as f64, exactly: the low mantissa bits of 1.5·2^52 hold kb.
    let dk = f64::from_bits(0x4338_0000_0000_0000 + kb) - (6_755_399_441_055_744.0 + 1023.0);
    let z = s * s;
    let w = z * z;
    let t1 = w * (LG2 + w * (LG4 + w * LG6));
    let t2 = z * (LG1 + w * (LG3 + w * (LG5 + w * LG7)));
    let r = t2 + t1;
    // fdlibm's choice between the two forms (`(hx − 0x6147a) | (0x6b851 − hx) > 0`
    // on the unscaled mantissa bits).
    #[allow(clippy::manual_range_contains)] // `&`: branch-free lanes
    let with_hfsq = (hm >= 0x6147a) & (hm <= 0x6b851);
    let hfsq = 0.5 * f * f;
    let a = dk * LN2_HI - ((hfsq - (s * (hfsq + r) + dk * LN2_LO)) - f);
    let b = dk * LN2_HI - ((s * (f - r) - dk * LN2_LO) - f);
    if with_hfsq {
        a
    } else {
        b
    }
}

/// `ln x` (within 1 ulp; the same bits as each lane of [`ln_lanes`]).
#[inline(always)]
pub fn ln(x: f64) -> f64 {
    if in_range(x) {
        ln_normal(x)
    } else {
        x.ln()
    }
}

/// `v_l ← ln v_l` on every lane, the lanes of positive normal values
/// vectorised (see [`ln`]). In the build of its caller: run it through
/// [`dispatch`](crate::linalg::dispatch()).
#[inline(always)]
pub fn ln_lanes(v: &mut [f64; LN_LANES]) {
    let x = *v;
    // Any positive normal stands in for the other lanes, so that every lane
    // runs the same branch-free arithmetic (one pass, vectorised).
    let mut y = [1.0; LN_LANES];
    for (yi, xi) in y.iter_mut().zip(&x) {
        *yi = if in_range(*xi) { *xi } else { 1.0 };
    }
    for (o, yi) in v.iter_mut().zip(&y) {
        *o = ln_normal(*yi);
    }
    if x.iter().any(|xi| !in_range(*xi)) {
        for (o, xi) in v.iter_mut().zip(&x) {
            if !in_range(*xi) {
                *o = xi.ln();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    use crate::linalg::test_support::ulps;

    /// Within 1 ulp of the platform's `ln` on 2 million arguments spread over
    /// every binade, 1 ± tiny, powers of two; the special values are the
    /// platform's; the lanes are the scalar function's bits.
    #[test]
    fn ln_is_within_one_ulp_and_the_lanes_are_the_scalar() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut worst = 0;
        let mut check = |x: f64| {
            let got = ln(x);
            let want = x.ln();
            let u = ulps(got, want);
            assert!(u <= 1, "ln({x:e}) = {got:e}, libm {want:e}");
            worst = worst.max(u);
            let mut lanes = [x, 1.0, 2.0, x, 0.5, x, 3.0, x];
            ln_lanes(&mut lanes);
            assert_eq!(lanes[0].to_bits(), got.to_bits());
        };
        for _ in 0..2_000_000 {
            let e: i32 = rng.random_range(-1021..1023);
            let m: f64 = rng.random_range(1.0..2.0);
            check(m * 2f64.powi(e));
        }
        for k in 1..2000 {
            check(1.0 + k as f64 * f64::EPSILON);
            check(1.0 - k as f64 * f64::EPSILON / 2.0);
            check(1.0 + k as f64 * 1e-9);
        }
        for e in -1022..1024 {
            check(2f64.powi(e));
        }
        check(f64::MIN_POSITIVE);
        check(f64::MAX);
        check(f64::EPSILON);
        for x in [0.0, -0.0, -1.0, f64::INFINITY, f64::NAN, 1e-310, 5e-324] {
            let mut lanes = [x; LN_LANES];
            ln_lanes(&mut lanes);
            assert_eq!(ln(x).to_bits(), x.ln().to_bits());
            assert!(lanes.iter().all(|v| v.to_bits() == x.ln().to_bits()));
        }
        assert_eq!(ln(1.0), 0.0);
        eprintln!("worst: {worst} ulp");
    }
}
