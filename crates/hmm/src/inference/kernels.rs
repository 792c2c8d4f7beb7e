//! The arithmetic shared by the scaled recursions, each in one fixed order
//! (so that the fast and the general form of a step, the batch and the
//! online filter, and every instruction-set build agree to the last bit).
//!
//! The recursions keep their per-state vectors in chunks of [`W`] = 8 lanes
//! ([`Lanes`]), padded past the last state with values that change nothing
//! (probability 0, log-density [`PAD_LOG_B`]), so that every loop runs over
//! whole chunks; with `C` chunks known at compile time (`S ≤ 32`) the
//! vectors live in registers.

use phasekit_emission::linalg::{exp_slice, reduce_lanes};

/// Probabilities at or above this keep full relative precision in the scaled
/// recursions: a term that underflowed carries an absolute error of at most
/// ~1e-308 after normalisation, negligible next to them.
pub(crate) const SAFE: f64 = 1e-290;

/// A normaliser below this is not divided out but absorbed by re-shifting the
/// exponent, so that underflowed terms are never magnified by more than `1/ε`.
pub(crate) const RESCALE: f64 = f64::EPSILON;

/// Lanes of a chunk.
pub(crate) const W: usize = 8;

/// A chunk of eight states.
pub(crate) type Lanes = [f64; W];

/// The log-density of a padding lane: finite (so that it passes the check
/// that every density is positive), below every real maximum, and
/// `e^{PAD − m} = 0`.
pub(crate) const PAD_LOG_B: f64 = f64::MIN;

/// Number of chunks for `s` states.
#[inline]
pub(crate) fn chunks(s: usize) -> usize {
    s.div_ceil(W).max(1)
}

/// `Σ_j v_j` over every lane (the padding is zero): eight interleaved
/// partial sums (lane `l` takes `j ≡ l mod 8`), combined pairwise as
/// `((q₀ + q₄) + (q₂ + q₆)) + ((q₁ + q₅) + (q₃ + q₇))`.
#[inline(always)]
pub(crate) fn sum_lanes(v: &[Lanes]) -> f64 {
    let mut q = [0.0; W];
    for c in v {
        for l in 0..W {
            q[l] += c[l];
        }
    }
    reduce_lanes(q)
}

/// `out_k = e^{v_k − m}` on every lane, in one vectorised pass of
/// exponentials: the shift-and-exponentiate of a scaled step of the forward
/// and backward recursions (`e^{log b_j − m}`, `m` the largest log-density,
/// so that the largest term is 1 and none overflows) — taken by the general
/// steps and the online step themselves; the batch passes take every frame's
/// at once ([`shifted_rows`]), with the same bits.
#[inline(always)]
pub(crate) fn exp_shifted(v: &[Lanes], m: f64, out: &mut [Lanes]) {
    for (ok, vk) in out.iter_mut().zip(v) {
        for l in 0..W {
            ok[l] = vk[l] - m;
        }
    }
    exp_slice(out.as_flattened_mut());
}

/// The shift `m = max_j log b_j` of a frame's fast step, or NaN when the
/// fast form cannot take the frame (a zero or NaN density, `m = +∞`): the
/// conditions the fast steps test first.
#[inline(always)]
pub(crate) fn fast_shift(log_b: &[Lanes]) -> f64 {
    let m = max_lanes(log_b);
    if all_positive_densities(log_b) && m != f64::INFINITY {
        m
    } else {
        f64::NAN
    }
}

/// `out = log b − m` lane by lane, the arguments of [`exp_shifted`]'s
/// exponentials (zeros when `m` is NaN, a frame the fast form does not take).
#[inline(always)]
pub(crate) fn shifted_arguments(log_b: &[Lanes], m: f64, out: &mut [Lanes]) {
    let fast = !m.is_nan();
    for (ok, vk) in out.iter_mut().zip(log_b) {
        for l in 0..W {
            ok[l] = if fast { vk[l] - m } else { 0.0 };
        }
    }
}

/// `v_j ← v_j · inv` on every lane (the normalisation by `1 / Σ_j v_j` of a
/// scaled step).
#[inline(always)]
pub(crate) fn scale_lanes(v: &mut [Lanes], inv: f64) {
    for vk in v.iter_mut() {
        for x in vk.iter_mut() {
            *x *= inv;
        }
    }
}

/// `Σ_j x_j y_j` in the order of [`sum_lanes`], by fused multiply-adds.
#[inline(always)]
pub(crate) fn dot_lanes(x: &[Lanes], y: &[Lanes]) -> f64 {
    let mut q = [0.0; W];
    for (a, b) in x.iter().zip(y) {
        for l in 0..W {
            q[l] = a[l].mul_add(b[l], q[l]);
        }
    }
    reduce_lanes(q)
}

/// `max_j v_j` (exact in any order; callers rule NaN out separately).
#[inline(always)]
pub(crate) fn max_lanes(v: &[Lanes]) -> f64 {
    let mut q = [f64::NEG_INFINITY; W];
    for c in v {
        for l in 0..W {
            q[l] = if c[l] > q[l] { c[l] } else { q[l] };
        }
    }
    q.iter()
        .fold(f64::NEG_INFINITY, |m, x| if *x > m { *x } else { m })
}

/// Whether every `v_j > −∞` (false for NaN), branch-free.
#[inline(always)]
pub(crate) fn all_positive_densities(v: &[Lanes]) -> bool {
    let mut ok = [true; W];
    for c in v {
        for l in 0..W {
            ok[l] &= c[l] > f64::NEG_INFINITY;
        }
    }
    ok.iter().all(|x| *x)
}

/// Whether every `v_j ≥ floor_j` (false for NaN), branch-free.
#[inline(always)]
pub(crate) fn all_at_least(v: &[Lanes], floor: &[Lanes]) -> bool {
    let mut ok = [true; W];
    for (c, f) in v.iter().zip(floor) {
        for l in 0..W {
            ok[l] &= c[l] >= f[l];
        }
    }
    ok.iter().all(|x| *x)
}

/// `out = Σ_{i < S} v_i m_i` for the `S` rows `m_i` of `C` chunks (a vector
/// times a matrix: the prediction `Aᵀ h` with the rows of `A`, the backward
/// message `A u` with the rows of `Aᵀ`). Fused multiply-adds in increasing
/// `i`, the even `i` and the odd `i` in two accumulators (two chains of half
/// the length), added at the end. `C` known at compile time: the
/// accumulators are registers.
#[inline(always)]
pub(crate) fn vec_mat<const C: usize>(v: &[f64], m: &[Lanes]) -> [Lanes; C] {
    let s = v.len();
    debug_assert!(m.len() == s * C);
    let mut even = [[0.0; W]; C];
    let mut odd = [[0.0; W]; C];
    let mut rows = m.chunks_exact(2 * C);
    for (pair, vp) in (&mut rows).zip(v.chunks_exact(2)) {
        let (r0, r1) = pair.split_at(C);
        for k in 0..C {
            for l in 0..W {
                even[k][l] = vp[0].mul_add(r0[k][l], even[k][l]);
                odd[k][l] = vp[1].mul_add(r1[k][l], odd[k][l]);
            }
        }
    }
    let last = rows.remainder();
    if !last.is_empty() {
        let v0 = v[s - 1];
        for k in 0..C {
            for l in 0..W {
                even[k][l] = v0.mul_add(last[k][l], even[k][l]);
            }
        }
    }
    for k in 0..C {
        for l in 0..W {
            even[k][l] += odd[k][l];
        }
    }
    even
}

/// [`vec_mat`] for any number of chunks (`out.len()`), through memory: the
/// same arithmetic in the same order.
#[inline(always)]
pub(crate) fn vec_mat_dyn(v: &[f64], m: &[Lanes], out: &mut [Lanes], odd: &mut [Lanes]) {
    let (s, c) = (v.len(), out.len());
    debug_assert!(m.len() == s * c && odd.len() == c);
    out.fill([0.0; W]);
    odd.fill([0.0; W]);
    let mut rows = m.chunks_exact(2 * c);
    for (pair, vp) in (&mut rows).zip(v.chunks_exact(2)) {
        let (r0, r1) = pair.split_at(c);
        for ((e, o), (a0, a1)) in out.iter_mut().zip(odd.iter_mut()).zip(r0.iter().zip(r1)) {
            for l in 0..W {
                e[l] = vp[0].mul_add(a0[l], e[l]);
                o[l] = vp[1].mul_add(a1[l], o[l]);
            }
        }
    }
    let last = rows.remainder();
    if !last.is_empty() {
        let v0 = v[s - 1];
        for (e, a0) in out.iter_mut().zip(last) {
            for l in 0..W {
                e[l] = v0.mul_add(a0[l], e[l]);
            }
        }
    }
    for (e, o) in out.iter_mut().zip(odd.iter()) {
        for l in 0..W {
            e[l] += o[l];
        }
    }
}

/// [`vec_mat`] into `out` for any number of chunks: in registers for up to
/// four ([`vec_mat`]), through memory beyond ([`vec_mat_dyn`]); the same bits
/// either way. For the general steps, which run on every frame of a fitted
/// left-to-right model (through memory, each row's update waited on the
/// previous one's store).
#[inline(always)]
pub(crate) fn vec_mat_into(v: &[f64], m: &[Lanes], out: &mut [Lanes], odd: &mut [Lanes]) {
    match out.len() {
        1 => out.copy_from_slice(&vec_mat::<1>(v, m)),
        2 => out.copy_from_slice(&vec_mat::<2>(v, m)),
        3 => out.copy_from_slice(&vec_mat::<3>(v, m)),
        4 => out.copy_from_slice(&vec_mat::<4>(v, m)),
        _ => vec_mat_dyn(v, m, out, odd),
    }
}

/// A row-major `S × S` matrix as `S` padded rows of `chunks(S)` chunks.
pub(crate) fn padded_rows(m: &[f64], s: usize) -> Vec<Lanes> {
    let c = chunks(s);
    let mut out = vec![[0.0; W]; s * c];
    for i in 0..s {
        for j in 0..s {
            out[i * c + j / W][j % W] = m[i * s + j];
        }
    }
    out
}

/// `v` (length `S`) as padded chunks, the padding set to `pad`.
#[inline(always)]
pub(crate) fn padded(v: &[f64], pad: f64, out: &mut [Lanes]) {
    let full = v.len() / W;
    for (o, c) in out.iter_mut().zip(v.chunks_exact(W)) {
        *o = c.try_into().expect("whole chunks");
    }
    if let Some(o) = out.get_mut(full) {
        let rest = &v[full * W..];
        *o = [pad; W];
        o[..rest.len()].copy_from_slice(rest);
    }
    if out.len() > full + 1 {
        out[full + 1..].fill([pad; W]);
    }
}

/// The padded rows of `log_b` (`T × S`; padding [`PAD_LOG_B`]) into
/// `rows`, and what [`super::forward::ForwardCore::step_shifted_inline`] and
/// [`super::backward::BackwardCore::step_shifted_inline`] take for each:
/// `e^{log b_t − m_t}` into `shifted` and the shift `m_t` ([`fast_shift`],
/// NaN for a frame the fast form does not take) into `shift`. The
/// exponentials of every frame are taken in one pass (they overlap there,
/// where a step's own would wait on the recursion); blocks of 8 are the rows'
/// chunks, as in [`exp_shifted`], so every value has the same bits. The
/// buffers hold at least the frames of `log_b`.
///
/// With `fast` false (a model whose steps never take the fast form: some
/// `a_ij = 0`), only the rows are padded and every shift is NaN: the general
/// steps take their own exponentials, so these would be thrown away.
#[inline(always)]
pub(crate) fn shifted_rows(
    log_b: &[f64],
    s: usize,
    fast: bool,
    rows: &mut [Lanes],
    shifted: &mut [Lanes],
    shift: &mut [f64],
) {
    let (c, frames) = (chunks(s), log_b.len() / s);
    debug_assert!(rows.len() >= frames * c && shifted.len() >= frames * c && shift.len() >= frames);
    for (((lb, row), e), m) in log_b
        .chunks_exact(s)
        .zip(rows.chunks_exact_mut(c))
        .zip(shifted.chunks_exact_mut(c))
        .zip(shift.iter_mut())
    {
        padded(lb, PAD_LOG_B, row);
        *m = if fast { fast_shift(row) } else { f64::NAN };
        if fast {
            shifted_arguments(row, *m, e);
        }
    }
    if fast {
        exp_slice(shifted[..frames * c].as_flattened_mut());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vec_mat_is_the_vector_matrix_product_in_its_order() {
        for s in 1..=33 {
            let c = chunks(s);
            let v: Vec<f64> = (0..s).map(|i| 0.1 + i as f64 * 0.37).collect();
            let dense: Vec<f64> = (0..s * s).map(|k| ((k * 7) % 11) as f64 / 11.0).collect();
            let m = padded_rows(&dense, s);
            let (mut out, mut odd) = (vec![[0.0; W]; c], vec![[0.0; W]; c]);
            vec_mat_dyn(&v, &m, &mut out, &mut odd);
            let (mut into, mut odd) = (vec![[f64::NAN; W]; c], vec![[f64::NAN; W]; c]);
            vec_mat_into(&v, &m, &mut into, &mut odd);
            assert_eq!(
                into.as_flattened()
                    .iter()
                    .map(|x| x.to_bits())
                    .collect::<Vec<_>>(),
                out.as_flattened()
                    .iter()
                    .map(|x| x.to_bits())
                    .collect::<Vec<_>>(),
                "s = {s}"
            );
            let fixed: Vec<Lanes> = match c {
                1 => vec_mat::<1>(&v, &m).to_vec(),
                2 => vec_mat::<2>(&v, &m).to_vec(),
                3 => vec_mat::<3>(&v, &m).to_vec(),
                4 => vec_mat::<4>(&v, &m).to_vec(),
                _ => out.clone(),
            };
            for j in 0..c * W {
                let (mut even, mut oddsum) = (0.0f64, 0.0f64);
                for i in 0..s {
                    let a = if j < s { dense[i * s + j] } else { 0.0 };
                    if i % 2 == 0 {
                        even = v[i].mul_add(a, even);
                    } else {
                        oddsum = v[i].mul_add(a, oddsum);
                    }
                }
                let want = (even + oddsum).to_bits();
                assert_eq!(out[j / W][j % W].to_bits(), want, "s = {s}, j = {j}");
                assert_eq!(fixed[j / W][j % W].to_bits(), want, "s = {s}, j = {j}");
            }
        }
    }

    #[test]
    fn sums_follow_their_documented_order() {
        for n in 0..=20 {
            let c = chunks(n);
            let v: Vec<f64> = (0..n).map(|i| 1.0 / (i as f64 + 3.0)).collect();
            let w: Vec<f64> = v.iter().rev().copied().collect();
            let (mut pv, mut pw) = (vec![[0.0; W]; c], vec![[0.0; W]; c]);
            padded(&v, 0.0, &mut pv);
            padded(&w, 0.0, &mut pw);
            let (mut q, mut r) = ([0.0f64; W], [0.0f64; W]);
            for j in 0..n {
                q[j % W] += v[j];
                r[j % W] = v[j].mul_add(w[j], r[j % W]);
            }
            let order =
                |q: [f64; W]| ((q[0] + q[4]) + (q[2] + q[6])) + ((q[1] + q[5]) + (q[3] + q[7]));
            assert_eq!(sum_lanes(&pv).to_bits(), order(q).to_bits());
            assert_eq!(dot_lanes(&pv, &pw).to_bits(), order(r).to_bits());
        }
    }
}
