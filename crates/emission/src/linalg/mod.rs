//! Dense kernels shared by the crates of the workspace, one file per job:
//!
//! * `packed`: packed lower triangles, Cholesky factors and their inverses;
//! * `norms`: squared norms `‖W v‖²` (the Mahalanobis distances of the Gaussian log-densities);
//! * `tiles`: centring, weighting and dot-product tiles (the Gaussian statistics);
//! * `exp`: the vectorised `exp` of a slice and the log-sum-exp;
//! * `x86`: the two kernels written with AVX2 intrinsics;
//! * `dispatch`: which instruction set the kernels run with, chosen once at run time.
//!
//! Every kernel is plain Rust whose SIMD lanes do exactly the arithmetic of
//! the scalar form, compiled once per instruction set by [`dispatch`]: the
//! results are the same bits on every CPU (see the `dispatch` module for what
//! that does not cover).

mod dispatch;
mod exp;
mod norms;
mod packed;
mod tiles;
#[cfg(target_arch = "x86_64")]
mod x86;

#[cfg(target_arch = "x86_64")]
pub use dispatch::FlushSubnormals;
pub use dispatch::{dispatch, has_avx2_fma, simd_level, with_simd_level, SimdLevel};
pub use exp::{
    exp_in_place, exp_in_place_portable, exp_or_zero, exp_slice, log_sum_exp, EXP_UNDERFLOW,
};
pub use norms::{
    packed_lower_sq_norm, packed_lower_sq_norms, sq_norms, sq_norms_lanes, LANES, STATE_LANES,
};
pub use packed::{
    cholesky, lower_triangular_inverse, pack_lower, packed_len, packed_lower_mul, packed_row,
    unpack_lower,
};
pub use tiles::{centre_weight, dot_tile, lane_sum, reduce_lanes, sub_scalar, DOT_LANES};

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// Every kernel with a hand-written or dispatched build gives the bits of
    /// its portable build (and the one-frame norm those of a batch lane).
    #[test]
    fn kernels_give_the_same_bits_at_every_level() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for d in [1usize, 2, 3, 7, 12, 36] {
            let w: Vec<f64> = (0..packed_len(d))
                .map(|_| rng.random_range(-2.0..2.0))
                .collect();
            let xt: Vec<f64> = (0..d * LANES)
                .map(|_| rng.random_range(-3.0..3.0))
                .collect();
            let m = 4 * rng.random_range(1..40);
            let rows = d.next_multiple_of(4).max(d.next_multiple_of(3)) + 3;
            let a: Vec<f64> = (0..rows * m).map(|_| rng.random_range(-1.0..1.0)).collect();
            let b: Vec<f64> = (0..rows * m).map(|_| rng.random_range(-1.0..1.0)).collect();
            let wt: Vec<f64> = (0..m).map(|_| rng.random_range(0.0..1.0)).collect();
            let run = || {
                let mut out = [0.0; LANES];
                packed_lower_sq_norms(&w, d, &xt, &mut out);
                let one: Vec<f64> = (0..LANES)
                    .map(|l| {
                        let v: Vec<f64> = (0..d).map(|k| xt[k * LANES + l]).collect();
                        packed_lower_sq_norm(&w, &v)
                    })
                    .collect();
                assert_eq!(bits(&out), bits(&one), "one frame = one lane");
                let mut tiles = Vec::new();
                for r0 in (0..d).step_by(4) {
                    for c0 in (0..=r0 + 3).step_by(3).take_while(|c| *c < d) {
                        tiles.extend(dot_tile(&a, &b, m, r0, c0).into_iter().flatten());
                    }
                }
                let (mut dd, mut aa) = (vec![0.0; m], vec![0.0; m]);
                let sum = centre_weight(&a[..m], 0.3, &wt, &mut dd, &mut aa);
                let mut sub = vec![0.0; m - 1];
                sub_scalar(&mut sub, &b[..m - 1], 0.7);
                let mut e: Vec<f64> = a.iter().map(|v| v * 800.0).collect();
                exp_in_place(&mut e);
                (out, tiles, sum, dd, aa, sub, e, log_sum_exp(&b))
            };
            let portable = with_simd_level(SimdLevel::Portable, run);
            let native = run();
            assert_eq!(bits(&portable.0), bits(&native.0), "D = {d}: squared norms");
            assert_eq!(bits(&portable.1), bits(&native.1), "D = {d}: dot tiles");
            assert_eq!(
                portable.2.to_bits(),
                native.2.to_bits(),
                "centre_weight sum"
            );
            assert_eq!(bits(&portable.3), bits(&native.3));
            assert_eq!(bits(&portable.4), bits(&native.4));
            assert_eq!(bits(&portable.5), bits(&native.5), "sub_scalar");
            assert_eq!(bits(&portable.6), bits(&native.6), "exp");
            assert_eq!(portable.7.to_bits(), native.7.to_bits(), "log_sum_exp");
        }
    }
}
