//! Small loops of the recursions, written with `LANES` independent
//! accumulators so that they are not bound by the latency of one long chain
//! of additions or maxima, and vectorise. The order of every operation is
//! fixed by the code (lane `l` takes the entries `d ≡ l mod LANES`, lanes are
//! combined pairwise), so results do not depend on the CPU.

/// Accumulators per reduction.
const LANES: usize = 8;

const NEG_INF: f64 = f64::NEG_INFINITY;

/// The larger of two values; NaN-free inputs (an `f64::max` chain would not vectorise).
#[inline(always)]
fn max2(a: f64, b: f64) -> f64 {
    if b > a {
        b
    } else {
        a
    }
}

#[inline(always)]
fn reduce_max(acc: [f64; LANES]) -> f64 {
    let mut m = acc[0];
    for v in &acc[1..] {
        m = max2(m, *v);
    }
    m
}

#[inline(always)]
fn reduce_sum(mut acc: [f64; LANES]) -> f64 {
    let mut w = LANES;
    while w > 1 {
        let h = w / 2;
        for l in 0..h {
            acc[l] += acc[l + h];
        }
        w = h;
    }
    acc[0]
}

/// `out[d] = a[d] + b[d]`; returns `max_d out[d]` (`−inf` for an empty slice).
#[inline]
pub(crate) fn add_max(out: &mut [f64], a: &[f64], b: &[f64]) -> f64 {
    let n = out.len();
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [NEG_INF; LANES];
    let split = n - n % LANES;
    for ((o, x), y) in out[..split]
        .chunks_exact_mut(LANES)
        .zip(a[..split].chunks_exact(LANES))
        .zip(b[..split].chunks_exact(LANES))
    {
        for l in 0..LANES {
            o[l] = x[l] + y[l];
            acc[l] = max2(acc[l], o[l]);
        }
    }
    for d in split..n {
        out[d] = a[d] + b[d];
        acc[d - split] = max2(acc[d - split], out[d]);
    }
    reduce_max(acc)
}

/// `max_d v[d]` (`−inf` for an empty slice).
#[inline]
pub(crate) fn max(v: &[f64]) -> f64 {
    let n = v.len();
    let mut acc = [NEG_INF; LANES];
    let split = n - n % LANES;
    for c in v[..split].chunks_exact(LANES) {
        for l in 0..LANES {
            acc[l] = max2(acc[l], c[l]);
        }
    }
    for d in split..n {
        acc[d - split] = max2(acc[d - split], v[d]);
    }
    reduce_max(acc)
}

/// `Σ_d v[d]`.
#[inline]
pub(crate) fn sum(v: &[f64]) -> f64 {
    let n = v.len();
    let mut acc = [0.0; LANES];
    let split = n - n % LANES;
    for c in v[..split].chunks_exact(LANES) {
        for l in 0..LANES {
            acc[l] += c[l];
        }
    }
    for d in split..n {
        acc[d - split] += v[d];
    }
    reduce_sum(acc)
}

/// `(Σ_d w[d] a[d], Σ_d w[d] b[d], max_d w[d])` (`w ≥ 0`; max 0 for an empty slice).
///
/// Four lanes: three accumulators of four lanes fit the registers of every
/// x86-64 CPU (eight lanes spill on SSE2).
#[inline]
pub(crate) fn dot2_max(w: &[f64], a: &[f64], b: &[f64]) -> (f64, f64, f64) {
    const L: usize = 4;
    let n = w.len();
    let (a, b) = (&a[..n], &b[..n]);
    let mut x = [0.0; L];
    let mut y = [0.0; L];
    let mut m = [0.0; L];
    let split = n - n % L;
    for ((c, p), q) in w[..split]
        .chunks_exact(L)
        .zip(a[..split].chunks_exact(L))
        .zip(b[..split].chunks_exact(L))
    {
        for l in 0..L {
            x[l] += c[l] * p[l];
            y[l] += c[l] * q[l];
            m[l] = max2(m[l], c[l]);
        }
    }
    for d in split..n {
        let l = d - split;
        x[l] += w[d] * a[d];
        y[l] += w[d] * b[d];
        m[l] = max2(m[l], w[d]);
    }
    (
        (x[0] + x[2]) + (x[1] + x[3]),
        (y[0] + y[2]) + (y[1] + y[3]),
        max2(max2(m[0], m[2]), max2(m[1], m[3])),
    )
}

/// `acc[d] += f · w[d] · t[d]`.
#[inline]
pub(crate) fn axpy_product(acc: &mut [f64], w: &[f64], t: &[f64], f: f64) {
    for ((a, x), y) in acc.iter_mut().zip(w).zip(t) {
        *a += f * (x * y);
    }
}

/// `v[d] += r` and the first index of the largest `v[d] + w[d]` with its
/// value (`(0, −inf)` when every sum is `−inf`).
#[inline]
pub(crate) fn add_argmax(v: &mut [f64], r: f64, w: &[f64]) -> (usize, f64) {
    let n = v.len();
    let w = &w[..n];
    let mut best = [NEG_INF; LANES];
    let mut at = [0usize; LANES];
    let split = n - n % LANES;
    for (k, (c, g)) in v[..split]
        .chunks_exact_mut(LANES)
        .zip(w[..split].chunks_exact(LANES))
        .enumerate()
    {
        for l in 0..LANES {
            c[l] += r;
            let s = c[l] + g[l];
            if s > best[l] {
                best[l] = s;
                at[l] = k * LANES + l;
            }
        }
    }
    for d in split..n {
        v[d] += r;
        let s = v[d] + w[d];
        let l = d - split;
        if s > best[l] {
            best[l] = s;
            at[l] = d;
        }
    }
    // The first index among the lanes' maxima (ties to the lower index).
    let mut out = (0usize, NEG_INF);
    for l in 0..LANES {
        if best[l] > out.1 || (best[l] == out.1 && best[l] > NEG_INF && at[l] < out.0) {
            out = (at[l], best[l]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_match_plain_loops() {
        for n in 0..40 {
            let a: Vec<f64> = (0..n).map(|k| ((k * 37) % 11) as f64 - 5.0).collect();
            let b: Vec<f64> = (0..n).map(|k| ((k * 13) % 7) as f64 * 0.5).collect();
            let mut out = vec![0.0; n];
            let m = add_max(&mut out, &a, &b);
            let want: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x + y).collect();
            assert_eq!(out, want);
            assert_eq!(m, want.iter().copied().fold(NEG_INF, f64::max));
            assert_eq!(max(&a), a.iter().copied().fold(NEG_INF, f64::max));
            assert!((sum(&a) - a.iter().sum::<f64>()).abs() < 1e-12);
            let w: Vec<f64> = a.iter().map(|v| v.abs()).collect();
            let (x, y, m) = dot2_max(&w, &a, &b);
            assert!((x - w.iter().zip(&a).map(|(p, q)| p * q).sum::<f64>()).abs() < 1e-12);
            assert!((y - w.iter().zip(&b).map(|(p, q)| p * q).sum::<f64>()).abs() < 1e-12);
            assert_eq!(m, w.iter().copied().fold(0.0, f64::max));
            let mut acc = vec![1.0; n];
            axpy_product(&mut acc, &w, &b, 2.0);
            for d in 0..n {
                assert_eq!(acc[d], 1.0 + 2.0 * (w[d] * b[d]));
            }
            let mut v = a.clone();
            let (i, best) = add_argmax(&mut v, 1.0, &b);
            let plain: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x + 1.0 + y).collect();
            let pm = plain.iter().copied().fold(NEG_INF, f64::max);
            assert_eq!(best, pm);
            if n > 0 {
                assert_eq!(i, plain.iter().position(|v| *v == pm).unwrap());
            }
        }
    }
}
