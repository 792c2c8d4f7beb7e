//! The forward-backward of up to [`W`] sequences at once, one sequence per
//! SIMD lane ("lane = sequence"), for models with few states.
//!
//! The per-sequence recursions ([`super::forward`], [`super::backward`],
//! [`super::posteriors`]) keep one sequence's states in the lanes: with
//! `S ≤ 16` most lanes carry padding, every step ends in horizontal sums and
//! maxima, and each step waits for the previous one. Here lane `l` carries
//! sequence `l` of a group, every per-state quantity is a vector over the
//! group's sequences, and the sums, maxima and products over states are
//! vertical: eight independent recursions advance in the same instructions.
//!
//! Only the fast form of the steps is done here (linear mode, every state
//! reachable and every `a_ij > 0`, every density positive, no re-scaling,
//! every next message at least [`SAFE`], every overlap `z_t ≥ SAFE`), with
//! exactly the arithmetic of the per-sequence fast forms, lane by lane, in
//! the same order: the sums over states follow [`super::kernels::sum_lanes`]
//! (state `j` into partial sum `j mod 8`, combined by
//! [`phasekit_emission::linalg::reduce_lanes`]), the products over states
//! [`super::kernels::vec_mat`] (even and odd states in two fused
//! multiply-add chains), the exponentials [`exp_slice`] over every frame of
//! the group at once, before the recursions (as the per-sequence path takes
//! them), the logarithm of `log c_t`
//! [`ln_lanes`] (that of [`phasekit_emission::linalg::ln`]). A sequence
//! for which any step leaves the fast form is marked failed and the caller
//! redoes it with the per-sequence path, so every result is bit-identical
//! to [`super::PosteriorWorkspace`]'s (tested).
//!
//! Sequences of unequal lengths share a group: lane `l` is active for frames
//! `t < T_l`; the backward recursion of a shorter sequence waits at
//! `β̂ = 1/S` until its last frame comes, and its inactive frames add exact
//! zeros to the expected transitions.

use super::kernels::{Lanes, RESCALE, SAFE, W};
use crate::model::Hmm;
use phasekit_emission::linalg::{dispatch, exp_slice, ln_lanes};
use phasekit_emission::Emission;

/// The largest number of states the lane form takes.
pub(crate) const MAX_STATES: usize = 16;

/// The most states for which the E-step uses the lane form: [`DEFAULT_STATES`],
/// or `PHASEKIT_LANE_STATES` (read once; `0` turns the lane form off, for
/// benchmarks that compare the two paths; capped at [`MAX_STATES`]). The
/// results are the same bits either way.
pub(crate) fn max_states() -> usize {
    static CAP: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *CAP.get_or_init(|| {
        std::env::var("PHASEKIT_LANE_STATES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(DEFAULT_STATES)
            .min(MAX_STATES)
    })
}

/// The default of [`max_states`]. Measured whole fits (D = 12 and 36, 20,000
/// frames in sequences of 250): the lane form was 1.7× faster at S = 4,
/// even at S = 8 (the per-sequence path's one chunk is then all real
/// states), 4–20 % faster at S = 12 and 4–9 % slower at S = 16, where the
/// per-sequence path's two chunks are full (`BENCHMARKS.md`).
pub(crate) const DEFAULT_STATES: usize = 12;

/// The longest sequence the lane form takes (longer ones go alone, through
/// the per-sequence path, whose buffers are `W` times smaller).
pub(crate) const MAX_FRAMES: usize = 4096;

/// Lane-wise `e_l = e_l + v_l`.
#[inline(always)]
fn add(a: Lanes, b: Lanes) -> Lanes {
    let mut o = [0.0; W];
    for l in 0..W {
        o[l] = a[l] + b[l];
    }
    o
}

/// `Σ_j v_j` per lane in the order of [`super::kernels::sum_lanes`]: state
/// `j` into partial sum `q_{j mod 8}` (in increasing `j`, from `0.0`), then
/// `((q₀ + q₄) + (q₂ + q₆)) + ((q₁ + q₅) + (q₃ + q₇))`.
#[inline(always)]
fn sum_states<const S: usize>(v: &[Lanes; S]) -> Lanes {
    let mut q = [[0.0; W]; 8];
    for j in 0..S {
        for l in 0..W {
            q[j % 8][l] += v[j][l];
        }
    }
    reduce8(q)
}

/// `Σ_j x_j y_j` per lane in the order of [`super::kernels::dot_lanes`].
#[inline(always)]
fn dot_states<const S: usize>(x: &[Lanes; S], y: &[Lanes; S]) -> Lanes {
    let mut q = [[0.0; W]; 8];
    for j in 0..S {
        for l in 0..W {
            q[j % 8][l] = x[j][l].mul_add(y[j][l], q[j % 8][l]);
        }
    }
    reduce8(q)
}

/// [`phasekit_emission::linalg::reduce_lanes`] of eight partial sums, per lane.
#[inline(always)]
fn reduce8(q: [Lanes; 8]) -> Lanes {
    let r0 = add(q[0], q[4]);
    let r1 = add(q[1], q[5]);
    let r2 = add(q[2], q[6]);
    let r3 = add(q[3], q[7]);
    add(add(r0, r2), add(r1, r3))
}

/// `out_j = Σ_i v_i m_ij` per lane, `m` given by its transpose (`m_t[j]` =
/// column `j` of `m`), in the order of [`super::kernels::vec_mat`]: even
/// `i` and odd `i` in two fused multiply-add chains of increasing `i`,
/// added at the end.
#[inline(always)]
fn vec_mat_lanes<const S: usize>(v: &[Lanes; S], m_t: &[[f64; S]; S]) -> [Lanes; S] {
    let mut out = [[0.0; W]; S];
    for j in 0..S {
        let (mut even, mut odd) = ([0.0; W], [0.0; W]);
        for i in 0..S {
            let c = m_t[j][i];
            if i % 2 == 0 {
                for l in 0..W {
                    even[l] = v[i][l].mul_add(c, even[l]);
                }
            } else {
                for l in 0..W {
                    odd[l] = v[i][l].mul_add(c, odd[l]);
                }
            }
        }
        out[j] = add(even, odd);
    }
    out
}

/// Buffers and model of the lane form (see the module documentation).
#[derive(Debug, Clone)]
pub(crate) struct LaneWorkspace {
    s: usize,
    /// Whether the E-step uses the lane form for this model (`S ≤` [`max_states`],
    /// every `a_ij > 0`, every `π_i ≥ SAFE`).
    usable: bool,
    /// `A` and `Aᵀ`, row-major; `π`.
    a: Vec<f64>,
    a_t: Vec<f64>,
    start: Vec<f64>,
    /// Sequences (lanes) in use and their lengths (0 past `n`).
    n: usize,
    lens: [usize; W],
    t_max: usize,
    /// `T_max × S` lane vectors: `log b` (then `γ`), `h_t`, `u_t`, `next_t`
    /// (then `h_t / z_t`), and `T_max` vectors of `log c_t`.
    log_b: Vec<Lanes>,
    h: Vec<Lanes>,
    u: Vec<Lanes>,
    next: Vec<Lanes>,
    lc: Vec<Lanes>,
    /// `e^{log b_t − m_t}` (`T_max × S` lane vectors), `m_t = max_j log b_t(j)`
    /// and whether every `log b_t(j) > −∞`, per lane: every frame's, taken
    /// in one pass before the recursions (the exponentials overlap there
    /// instead of waiting on the recursions' chains), used by the forward
    /// step at `t` and the backward step at `t − 1`.
    shifted: Vec<Lanes>,
    shift: Vec<Lanes>,
    finite: Vec<[bool; W]>,
    /// `Σ_t ξ_t(i, j)` per lane, `S × S`.
    xi: Vec<Lanes>,
    /// Scratch: one lane's `log c_t`.
    lc_row: Vec<f64>,
}

impl LaneWorkspace {
    /// Empty buffers for `hmm`.
    pub(crate) fn new<E: Emission>(hmm: &Hmm<E>) -> Self {
        let s = hmm.n_states();
        let a = hmm.transition.clone();
        let a_t = (0..s * s).map(|k| a[(k % s) * s + k / s]).collect();
        LaneWorkspace {
            s,
            usable: s <= max_states()
                && a.iter().all(|v| *v > 0.0)
                && hmm.start.iter().all(|p| *p >= SAFE),
            a,
            a_t,
            start: hmm.start.clone(),
            n: 0,
            lens: [0; W],
            t_max: 0,
            log_b: Vec::new(),
            h: Vec::new(),
            u: Vec::new(),
            next: Vec::new(),
            lc: Vec::new(),
            shifted: Vec::new(),
            shift: Vec::new(),
            finite: Vec::new(),
            xi: Vec::new(),
            lc_row: Vec::new(),
        }
    }

    /// Whether the model admits the lane form.
    pub(crate) fn usable(&self) -> bool {
        self.usable
    }

    /// Starts a group of sequences of these lengths (`1 ≤ n ≤ W`, each `≥ 1`):
    /// sizes the buffers; then [`Self::load`] each lane.
    pub(crate) fn begin(&mut self, lens: &[usize]) {
        debug_assert!(!lens.is_empty() && lens.len() <= W && lens.iter().all(|t| *t > 0));
        self.n = lens.len();
        self.lens = [0; W];
        self.lens[..self.n].copy_from_slice(lens);
        self.t_max = lens.iter().copied().max().unwrap_or(0);
        let len = self.t_max * self.s;
        // `load` writes only a lane's first `T_l` rows: past a sequence's
        // end its lane reads `log b = 0` (results discarded), not an earlier
        // group's values. Every other buffer is written in full by `run`
        // before it is read, so it keeps its old contents here.
        self.log_b.clear();
        self.log_b.resize(len, [0.0; W]);
        for v in [&mut self.h, &mut self.u, &mut self.next, &mut self.shifted] {
            v.resize(len, [0.0; W]);
        }
        for v in [&mut self.lc, &mut self.shift] {
            v.resize(self.t_max, [0.0; W]);
        }
        self.finite.resize(self.t_max, [true; W]);
    }

    /// Lane `l`'s log-densities, row-major `T_l × S`.
    pub(crate) fn load(&mut self, l: usize, log_b: &[f64]) {
        debug_assert_eq!(log_b.len(), self.lens[l] * self.s);
        for (v, x) in self.log_b.iter_mut().zip(log_b) {
            v[l] = *x;
        }
    }

    /// Lane `l`'s `log p(x)`: `Σ_t log c_t` summed in frame order.
    pub(crate) fn log_likelihood(&mut self, l: usize) -> f64 {
        self.lc_row.clear();
        self.lc_row
            .extend(self.lc[..self.lens[l]].iter().map(|v| v[l]));
        self.lc_row.iter().sum()
    }

    /// Lane `l`'s `γ`, row-major `T_l × S`, into `gamma` (resized).
    pub(crate) fn gamma_into(&self, l: usize, gamma: &mut Vec<f64>) {
        let len = self.lens[l] * self.s;
        gamma.clear();
        gamma.extend(self.log_b[..len].iter().map(|v| v[l]));
    }

    /// Lane `l`'s `Σ_t ξ_t(i, j)`, row-major `S × S`, into `xi`.
    pub(crate) fn xi_into(&self, l: usize, xi: &mut [f64]) {
        for (x, v) in xi.iter_mut().zip(&self.xi) {
            *x = v[l];
        }
    }

    /// The forward-backward of the loaded group: which lanes stayed in the
    /// fast form throughout (their `γ`, `Σ ξ` and `log p(x)` are then those
    /// of the per-sequence path to the bit).
    pub(crate) fn run(&mut self) -> [bool; W] {
        dispatch(
            #[inline(always)]
            || self.run_inline(),
        )
    }

    #[inline(always)]
    fn run_inline(&mut self) -> [bool; W] {
        match self.s {
            1 => self.run_fixed::<1>(),
            2 => self.run_fixed::<2>(),
            3 => self.run_fixed::<3>(),
            4 => self.run_fixed::<4>(),
            5 => self.run_fixed::<5>(),
            6 => self.run_fixed::<6>(),
            7 => self.run_fixed::<7>(),
            8 => self.run_fixed::<8>(),
            9 => self.run_fixed::<9>(),
            10 => self.run_fixed::<10>(),
            11 => self.run_fixed::<11>(),
            12 => self.run_fixed::<12>(),
            13 => self.run_fixed::<13>(),
            14 => self.run_fixed::<14>(),
            15 => self.run_fixed::<15>(),
            16 => self.run_fixed::<16>(),
            _ => [false; W],
        }
    }

    /// [`Self::run`] with `S` known at compile time (the per-state vectors
    /// in registers, every loop over states unrolled).
    #[inline(always)]
    fn run_fixed<const S: usize>(&mut self) -> [bool; W] {
        let (t_max, lens) = (self.t_max, self.lens);
        let mut failed = [false; W];
        for (l, f) in failed.iter_mut().enumerate() {
            *f = l >= self.n;
        }
        let mut a = [[0.0; S]; S];
        let mut a_t = [[0.0; S]; S];
        for i in 0..S {
            for j in 0..S {
                a[i][j] = self.a[i * S + j];
                a_t[i][j] = self.a_t[i * S + j];
            }
        }
        // Forward state: the prediction `p_t`; backward: `β̂_{t+1}`.
        let mut pred = [[0.0; W]; S];
        for (p, pi) in pred.iter_mut().zip(&self.start) {
            *p = [*pi; W];
        }
        let mut beta = [[1.0 / S as f64; W]; S];
        let log_b: &[[Lanes; S]] = as_rows(&self.log_b);
        {
            let shifted: &mut [[Lanes; S]] = as_rows_mut(&mut self.shifted);
            for (((lb, e), m), finite) in log_b
                .iter()
                .zip(shifted.iter_mut())
                .zip(self.shift.iter_mut())
                .zip(self.finite.iter_mut())
            {
                (*m, *finite) = max_and_finite(lb);
                for j in 0..S {
                    for l in 0..W {
                        e[j][l] = lb[j][l] - m[l];
                    }
                }
            }
        }
        // Blocks of 8 are lane vectors: each lane's exponentials are those of
        // the per-sequence path, bit for bit (`exp_slice` is elementwise).
        exp_slice(self.shifted.as_flattened_mut());
        let shifted: &[[Lanes; S]] = as_rows(&self.shifted);
        let (shift, finite) = (&self.shift, &self.finite);
        let h: &mut [[Lanes; S]] = as_rows_mut(&mut self.h);
        let u: &mut [[Lanes; S]] = as_rows_mut(&mut self.u);
        let next: &mut [[Lanes; S]] = as_rows_mut(&mut self.next);
        for k in 0..t_max {
            // Forward, frame k (lane l active while k < T_l).
            let mut act = [false; W];
            for l in 0..W {
                act[l] = k < lens[l];
            }
            let frame = (&shifted[k], shift[k], finite[k]);
            self.lc[k] = forward_step(frame, &mut pred, &mut h[k], &a_t, &act, &mut failed);
            // Backward, from frame t + 1 = T_max − 1 − k to t (lane l active
            // while t + 1 ≤ T_l − 1).
            if k + 1 < t_max {
                let t = t_max - 2 - k;
                let mut act = [false; W];
                for l in 0..W {
                    act[l] = t + 2 <= lens[l];
                }
                // Every lane active (equal lengths, or past the longest
                // tail): no selects.
                if act.iter().all(|v| *v) {
                    backward_step::<S, true>(
                        (&shifted[t + 1], shift[t + 1], finite[t + 1]),
                        &mut beta,
                        &mut u[t + 1],
                        &mut next[t],
                        &a,
                        &act,
                        &mut failed,
                    );
                } else {
                    backward_step::<S, false>(
                        (&shifted[t + 1], shift[t + 1], finite[t + 1]),
                        &mut beta,
                        &mut u[t + 1],
                        &mut next[t],
                        &a,
                        &act,
                        &mut failed,
                    );
                }
            }
        }
        // γ (into `log_b`) and `h_t / z_t` (into `next`).
        let gamma: &mut [[Lanes; S]] = as_rows_mut(&mut self.log_b);
        for t in 0..t_max {
            let (ht, nt, g) = (&h[t], &mut next[t], &mut gamma[t]);
            let z = dot_states(ht, nt);
            let mut inv = [0.0; W];
            let (mut inner, mut last) = ([false; W], [false; W]);
            for l in 0..W {
                inner[l] = t + 1 < lens[l];
                last[l] = t + 1 == lens[l];
                let bad = z[l].is_nan() || z[l] < SAFE || z[l] == f64::INFINITY;
                failed[l] |= inner[l] && bad;
                inv[l] = 1.0 / z[l];
            }
            if inner.iter().all(|v| *v) {
                for j in 0..S {
                    for l in 0..W {
                        let hz = ht[j][l] * inv[l];
                        g[j][l] = hz * nt[j][l];
                        nt[j][l] = hz;
                    }
                }
                continue;
            }
            for j in 0..S {
                for l in 0..W {
                    let hz = ht[j][l] * inv[l];
                    g[j][l] = if inner[l] {
                        hz * nt[j][l]
                    } else if last[l] {
                        ht[j][l]
                    } else {
                        0.0
                    };
                    nt[j][l] = if inner[l] { hz } else { 0.0 };
                }
            }
        }
        // Σ_t ξ_t(i, j) = a_ij Σ_{t < T−1} (h_t(i) / z_t) u_{t+1}(j), the sum
        // over t by fused multiply-adds in increasing t (inactive frames add
        // exact zeros); four columns j at a time.
        self.xi.clear();
        self.xi.resize(S * S, [0.0; W]);
        let steps = t_max.saturating_sub(1);
        for i in 0..S {
            for j0 in (0..S).step_by(4) {
                let nj = (S - j0).min(4);
                let mut acc = [[0.0; W]; 4];
                for t in 0..steps {
                    let x = next[t][i];
                    let ut = &u[t + 1];
                    for q in 0..4 {
                        if q < nj {
                            for l in 0..W {
                                acc[q][l] = x[l].mul_add(ut[j0 + q][l], acc[q][l]);
                            }
                        }
                    }
                }
                for (q, m) in acc[..nj].iter().enumerate() {
                    let aij = a[i][j0 + q];
                    let x = &mut self.xi[i * S + j0 + q];
                    for l in 0..W {
                        x[l] = aij * m[l];
                    }
                }
            }
        }
        let mut ok = [false; W];
        for l in 0..W {
            ok[l] = !failed[l];
        }
        ok
    }
}

/// `T × S` lane vectors as `T` rows of `S`.
#[inline(always)]
fn as_rows<const S: usize>(v: &[Lanes]) -> &[[Lanes; S]] {
    let (rows, rest) = v.as_chunks::<S>();
    debug_assert!(rest.is_empty());
    rows
}

/// [`as_rows`], mutable.
#[inline(always)]
fn as_rows_mut<const S: usize>(v: &mut [Lanes]) -> &mut [[Lanes; S]] {
    let (rows, rest) = v.as_chunks_mut::<S>();
    debug_assert!(rest.is_empty());
    rows
}

/// One forward fast step for every lane ([`super::forward`]'s `fast_step`,
/// lane by lane): from the prediction `pred` and a frame's shifted densities
/// (`e^{log b − m}`, the shift `m` and whether every `log b > −∞`, per lane)
/// to the filtered `h` and the next prediction; returns `log c_t`. Marks an
/// active lane failed where a condition of the fast form fails.
#[inline(always)]
fn forward_step<const S: usize>(
    (e, m, finite): (&[Lanes; S], Lanes, [bool; W]),
    pred: &mut [Lanes; S],
    h: &mut [Lanes; S],
    a_t: &[[f64; S]; S],
    act: &[bool; W],
    failed: &mut [bool; W],
) -> Lanes {
    let mut o = *e;
    for j in 0..S {
        for l in 0..W {
            o[j][l] *= pred[j][l];
        }
    }
    let c = sum_states(&o);
    let mut inv = [0.0; W];
    for l in 0..W {
        inv[l] = 1.0 / c[l];
    }
    for oj in o.iter_mut() {
        for l in 0..W {
            oj[l] *= inv[l];
        }
    }
    *pred = vec_mat_lanes(&o, a_t);
    let mut safe = [true; W];
    for p in pred.iter() {
        for l in 0..W {
            safe[l] &= p[l] >= SAFE;
        }
    }
    *h = o;
    let mut lc = c;
    ln_lanes(&mut lc);
    for l in 0..W {
        let good = finite[l] && m[l] != f64::INFINITY && !c[l].is_nan() && c[l] >= RESCALE;
        failed[l] |= act[l] && !(good && safe[l]);
        lc[l] += m[l];
    }
    lc
}

/// `max_j v_j` per lane and whether every `v_j > −∞` (false for NaN).
#[inline(always)]
fn max_and_finite<const S: usize>(lb: &[Lanes; S]) -> (Lanes, [bool; W]) {
    let mut m = [f64::NEG_INFINITY; W];
    let mut finite = [true; W];
    for v in lb {
        for l in 0..W {
            m[l] = if v[l] > m[l] { v[l] } else { m[l] };
            finite[l] &= v[l] > f64::NEG_INFINITY;
        }
    }
    (m, finite)
}

/// One backward fast step for every lane ([`super::backward`]'s
/// `fast_rest`, lane by lane): from `β̂_{t+1}` (`beta`) and the shifted
/// densities of frame `t + 1` (as [`forward_step`] takes them) to `u_{t+1}`,
/// `next_t` and `β̂_t`. Inactive lanes keep `beta` and write zeros (`FULL`:
/// every lane is active).
#[inline(always)]
fn backward_step<const S: usize, const FULL: bool>(
    (e, m, finite): (&[Lanes; S], Lanes, [bool; W]),
    beta: &mut [Lanes; S],
    u: &mut [Lanes; S],
    next: &mut [Lanes; S],
    a: &[[f64; S]; S],
    act: &[bool; W],
    failed: &mut [bool; W],
) {
    let mut w = *e;
    for j in 0..S {
        for l in 0..W {
            w[j][l] *= beta[j][l];
        }
    }
    let total = sum_states(&w);
    let mut inv = [0.0; W];
    for l in 0..W {
        inv[l] = 1.0 / total[l];
    }
    for wj in w.iter_mut() {
        for l in 0..W {
            wj[l] *= inv[l];
        }
    }
    let n = vec_mat_lanes(&w, a);
    let mut safe = [true; W];
    for v in n.iter() {
        for l in 0..W {
            safe[l] &= v[l] >= SAFE;
        }
    }
    let total_next = sum_states(&n);
    let mut inv_next = [0.0; W];
    for l in 0..W {
        inv_next[l] = 1.0 / total_next[l];
        let good = finite[l] && m[l] != f64::INFINITY && !total[l].is_nan() && total[l] >= RESCALE;
        failed[l] |= act[l] && !(good && safe[l]);
    }
    if FULL {
        for j in 0..S {
            for l in 0..W {
                beta[j][l] = n[j][l] * inv_next[l];
            }
        }
        *u = w;
        *next = n;
        return;
    }
    for j in 0..S {
        for l in 0..W {
            beta[j][l] = if act[l] {
                n[j][l] * inv_next[l]
            } else {
                beta[j][l]
            };
            u[j][l] = if act[l] { w[j][l] } else { 0.0 };
            next[j][l] = if act[l] { n[j][l] } else { 0.0 };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inference::forward::tests::random_case;
    use crate::inference::PosteriorWorkspace;
    use crate::model::Hmm;
    use phasekit_emission::Gaussian;

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// A model from `random_case` with densities `log_b`, cut into
    /// sequences of the given lengths.
    fn check_group(hmm: &Hmm<Gaussian>, log_b: &[f64], lens: &[usize]) -> (usize, usize) {
        let s = hmm.n_states();
        let mut lanes = LaneWorkspace::new(hmm);
        let mut ws = PosteriorWorkspace::new(hmm);
        // The workspace as a fit reuses it: after a longer group of NaN
        // densities (whose values must not leak into this one).
        let dirty = vec![70; W];
        lanes.begin(&dirty);
        for l in 0..W {
            lanes.load(l, &vec![f64::NAN; 70 * s]);
        }
        lanes.run();
        lanes.begin(lens);
        let mut offsets = Vec::new();
        let mut o = 0;
        for (l, t) in lens.iter().enumerate() {
            offsets.push(o);
            lanes.load(l, &log_b[o * s..(o + t) * s]);
            o += t;
        }
        let ok = lanes.run();
        let (mut fast, mut slow) = (0, 0);
        let (mut gamma, mut xi) = (Vec::new(), vec![0.0; s * s]);
        for (l, t) in lens.iter().enumerate() {
            let o = offsets[l];
            ws.log_b_for(*t).copy_from_slice(&log_b[o * s..(o + t) * s]);
            let want = ws.run();
            if !ok[l] {
                slow += 1;
                continue;
            }
            fast += 1;
            let want = want.expect("a fast lane is a possible sequence");
            assert_eq!(
                lanes.log_likelihood(l).to_bits(),
                want.to_bits(),
                "lane {l}"
            );
            lanes.gamma_into(l, &mut gamma);
            assert_eq!(bits(&gamma), bits(&ws.gamma), "lane {l}");
            lanes.xi_into(l, &mut xi);
            assert_eq!(bits(&xi), bits(&ws.xi), "lane {l}");
        }
        assert!(ok[lens.len()..].iter().all(|v| !v));
        (fast, slow)
    }

    /// Every lane that stays in the fast form gives the per-sequence path's
    /// bits (`γ`, `Σ ξ`, `log p(x)`), for groups of 1 to 8 sequences of
    /// unequal lengths (one-frame sequences included), `S = 1 … 16`, with
    /// densities that send some lanes out of the fast form.
    #[test]
    fn lanes_equal_the_per_sequence_path_to_the_bit() {
        let (mut fast, mut slow) = (0, 0);
        for seed in 0..160u64 {
            let s = 1 + (seed as usize % MAX_STATES);
            let n = 1 + (seed as usize / 3) % W;
            let lens: Vec<usize> = (0..n)
                .map(|l| match (seed as usize + l) % 5 {
                    0 => 1,
                    1 => 2,
                    _ => 3 + (seed as usize * 7 + l * 13) % 60,
                })
                .collect();
            let total: usize = lens.iter().sum();
            let (hmm, mut log_b) = random_case(seed, s, total, false);
            // Mostly ordinary frames (so that most lanes stay fast); the
            // extreme ones of `random_case` on some seeds only.
            if seed % 4 != 0 {
                for v in log_b.iter_mut() {
                    if !(-30.0..=0.0).contains(v) {
                        *v = -3.0;
                    }
                }
            }
            let (f, sl) = check_group(&hmm, &log_b, &lens);
            fast += f;
            slow += sl;
        }
        assert!(fast > 300, "only {fast} lanes stayed in the lane form");
        assert!(slow > 10, "only {slow} lanes left the lane form");
    }

    /// Models the lane form refuses: a zero transition, a start below SAFE,
    /// more than `MAX_STATES` states.
    #[test]
    fn the_lane_form_refuses_models_outside_its_fast_form() {
        let g = |s: usize| Gaussian::diagonal(1, vec![0.0; s], vec![1.0; s]).unwrap();
        let sparse = Hmm::new(vec![0.5, 0.5], vec![1.0, 0.0, 0.5, 0.5], g(2)).unwrap();
        assert!(!LaneWorkspace::new(&sparse).usable());
        let tiny = Hmm::new(vec![1.0, 1e-300], vec![0.5; 4], g(2)).unwrap();
        assert!(!LaneWorkspace::new(&tiny).usable());
        let s = MAX_STATES + 1;
        let big = Hmm::new(vec![1.0 / s as f64; s], vec![1.0 / s as f64; s * s], g(s)).unwrap();
        assert!(!LaneWorkspace::new(&big).usable());
        let ok = Hmm::new(vec![0.5, 0.5], vec![0.5; 4], g(2)).unwrap();
        assert!(LaneWorkspace::new(&ok).usable());
    }
}
