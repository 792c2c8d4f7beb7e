//! Squared norms `‖W v‖²` of packed lower-triangular `W`: the Mahalanobis
//! distances of the Gaussian log-densities (`W = L⁻¹`, `Σ = L Lᵀ`), for one
//! vector or for one frame under [`STATE_LANES`] states at once (blocks of
//! frames are the Gaussian's own kernels, `gaussian/kernels.rs`).
//!
//! Both do, lane by lane, the arithmetic of `sq_norms`: rows of `W`
//! two at a time, `z_r = Σ_{k ≤ r} w_rk v_k` by fused multiply-adds in
//! increasing `k`, then `acc += z_r²` in increasing `r`. So the one-frame,
//! the batched and the per-state evaluations agree to the last bit, whatever
//! the instruction set.

use super::dispatch::dispatch;
use super::packed::packed_len;

/// `Σ_r (W_r · v)²` for a packed lower-triangular `W`: the squared norm of `W v`.
///
/// With `W = L⁻¹` for the Cholesky factor `L` of `Σ`, this is the Mahalanobis
/// distance `vᵀ Σ⁻¹ v`. Computed with fused multiply-adds in a fixed order,
/// exactly as one lane of [`sq_norms_lanes`] and as the Gaussian's batched
/// kernels, so that the one-frame and the batched evaluations agree to the
/// last bit.
#[inline]
pub fn packed_lower_sq_norm(packed: &[f64], v: &[f64]) -> f64 {
    let mut out = [0.0];
    dispatch(
        #[inline(always)]
        || sq_norms::<1>(packed, v.len(), v, &mut out),
    );
    out[0]
}

/// Body of the squared-norm kernels (see the module documentation).
/// `f64::mul_add` is correctly rounded on every target (hardware or libm), so
/// all code paths give identical results.
#[inline(always)]
fn sq_norms<const L: usize>(packed: &[f64], d: usize, xt: &[f64], out: &mut [f64; L]) {
    assert!(packed.len() >= packed_len(d) && xt.len() >= d * L);
    let xt = &xt[..d * L];
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
/// arithmetic of [`packed_lower_sq_norm`] (and of one lane of the private `sq_norms`).
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
