//! Dense kernels shared by the crates of the workspace, one file per job:
//!
//! * `packed`: packed lower triangles, Cholesky factors and their inverses;
//! * `norms`: squared norms `‖W v‖²` (the Mahalanobis distances of the Gaussian log-densities);
//! * `lanes`: sums of lane-wise partial sums in a fixed order;
//! * `exp`: the vectorised `exp` of a slice and the log-sum-exp;
//! * `ln`: a logarithm whose lanes vectorise (fdlibm's algorithm, within 1 ulp);
//! * `dispatch`: which instruction set the kernels run with, chosen once at run time.
//!
//! Every kernel is plain Rust whose SIMD lanes do exactly the arithmetic of
//! the scalar form, compiled once per instruction set by [`dispatch`](fn@crate::linalg::dispatch): the
//! results are the same bits on every CPU (see the `dispatch` module for what
//! that does not cover).

mod dispatch;
mod exp;
mod lanes;
mod ln;
mod norms;
mod packed;
#[cfg(test)]
mod test_support;

pub use dispatch::{dispatch, simd_level, with_simd_level, SimdLevel};
pub use exp::{
    exp_in_place, exp_in_place_portable, exp_lanes, exp_or_zero, exp_slice, log_sum_exp,
    EXP_UNDERFLOW,
};
pub use lanes::reduce_lanes;
pub use ln::{ln, ln_lanes, LN_LANES};
pub use norms::{packed_lower_sq_norm, sq_norms_lanes, STATE_LANES};
pub use packed::{
    cholesky, lower_triangular_inverse, pack_lower, packed_len, packed_lower_mul, packed_row,
    unpack_lower,
};

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// Every dispatched kernel gives the bits of its portable build, and the
    /// per-state lanes of [`sq_norms_lanes`] those of [`packed_lower_sq_norm`].
    #[test]
    fn kernels_give_the_same_bits_at_every_level() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for d in [1usize, 2, 3, 7, 12, 36] {
            let pl = packed_len(d);
            let wl: Vec<f64> = (0..pl * STATE_LANES)
                .map(|_| rng.random_range(-2.0..2.0))
                .collect();
            let xt: Vec<f64> = (0..d * STATE_LANES)
                .map(|_| rng.random_range(-3.0..3.0))
                .collect();
            let b: Vec<f64> = (0..40).map(|_| rng.random_range(-1.0..1.0)).collect();
            let run = || {
                let mut lanes = [0.0; STATE_LANES];
                sq_norms_lanes(&wl, d, &xt, &mut lanes);
                let one: Vec<f64> = (0..STATE_LANES)
                    .map(|l| {
                        let w: Vec<f64> = (0..pl).map(|e| wl[e * STATE_LANES + l]).collect();
                        let v: Vec<f64> = (0..d).map(|k| xt[k * STATE_LANES + l]).collect();
                        packed_lower_sq_norm(&w, &v)
                    })
                    .collect();
                assert_eq!(bits(&lanes), bits(&one), "one state = one lane");
                let mut e: Vec<f64> = b.iter().map(|v| v * 800.0).collect();
                exp_in_place(&mut e);
                (one, e, log_sum_exp(&b))
            };
            let portable = with_simd_level(SimdLevel::Portable, run);
            let native = run();
            assert_eq!(bits(&portable.0), bits(&native.0), "D = {d}: squared norms");
            assert_eq!(bits(&portable.1), bits(&native.1), "exp");
            assert_eq!(portable.2.to_bits(), native.2.to_bits(), "log_sum_exp");
        }
    }
}
