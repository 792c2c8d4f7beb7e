//! The windows of the recursions: for every state, the last `D` segment
//! starts (forward) or ends (backward), with their normalised
//! log-probabilities, advanced by one frame at a time.
//!
//! Advancing adds the same `r_j = log b_j(x_t) − ℓ_t` to every entry of
//! state `j` (the cumulative sums of the module documentation of
//! [`crate::inference`]) and inserts one new entry. Each entry is stored
//! twice, relative to a per-state log-scale `c_j`: as its logarithm `u`
//! (absolute value `u + c_j`, exact whatever its size) and as `w = e^{u}`.
//! Advancing then only changes `c_j` (no work per entry) and writes one new
//! entry (one exponential); the sums the recursions need are dot products
//! of `w` with the linear duration tables (two multiply-adds per entry, no
//! exponential). The scale is moved (`u −= δ`, `w ×= e^{−δ}`) to keep the
//! largest `w` of a window within `[10^{-100}, 10^{100}]`.
//!
//! A linear sum is exact when it is at least `10^{-150}` times the window's
//! largest entry: every term lost to underflow (of `w`, of the table value or
//! of their product) is below `2.2·10^{-308}` times `max(1, largest entry)`,
//! so all of them together are below `10^{-50}` of the sum. Otherwise the
//! sum is taken again in log space from `u` and the log tables, so that no
//! explanation of the data is lost however unlikely it is at first.

use crate::kernels;
use phasekit_emission::linalg::{exp_in_place, log_sum_exp};
use std::ops::Range;

const NEG_INF: f64 = f64::NEG_INFINITY;
/// Range of the largest `w` of a window: wide, so that the scale moves
/// rarely (a state that the data rule out gains about as many nats per frame
/// as its density lags behind, and would move it every frame in a narrow range).
const LOW: f64 = 1e-100;
const HIGH: f64 = 1e100;
/// A new entry whose `u` exceeds this moves the scale first, so that `e^{u}` is finite.
const INSERT_HIGH: f64 = 700.0;
/// Below this fraction of the window's largest entry a linear sum is re-done
/// in log space: the terms lost to underflow (below `2.2·10^{-308}` each,
/// or `2.2·10^{-308}` times the largest entry) are then below `10^{-50}` of the sum.
const EXACT: f64 = 1e-150;

/// Windows of `S` states, `D` entries each, in ring buffers sharing one head.
#[derive(Debug, Clone)]
pub(crate) struct Windows {
    s: usize,
    dm: usize,
    /// `[j·D + pos]`: log of the entry relative to `scale[j]`.
    u: Vec<f64>,
    /// `e^{u}`.
    w: Vec<f64>,
    /// `c_j`.
    scale: Vec<f64>,
    /// Ring position of entry `d = 1`.
    head: usize,
    /// Number of entries (`d = 1..=n`).
    n: usize,
    scratch: Vec<f64>,
}

/// A sum over a window: its value relative to the state's scale, in log
/// form, and whether it was re-done in log space.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LogSum {
    pub(crate) log: f64,
    pub(crate) exact_log: bool,
}

impl Windows {
    pub(crate) fn new(s: usize, dm: usize) -> Self {
        Windows {
            s,
            dm,
            u: vec![NEG_INF; s * dm],
            w: vec![0.0; s * dm],
            scale: vec![0.0; s],
            head: 0,
            n: 0,
            scratch: vec![0.0; dm],
        }
    }

    pub(crate) fn shape(&self) -> (usize, usize) {
        (self.s, self.dm)
    }

    /// No entry.
    pub(crate) fn clear(&mut self) {
        self.u.fill(NEG_INF);
        self.w.fill(0.0);
        self.scale.fill(0.0);
        self.head = 0;
        self.n = 0;
    }

    /// Copies another window's state (same shape) without allocating.
    pub(crate) fn copy_from(&mut self, other: &Windows) {
        self.u.copy_from_slice(&other.u);
        self.w.copy_from_slice(&other.w);
        self.scale.copy_from_slice(&other.scale);
        self.head = other.head;
        self.n = other.n;
    }

    /// Number of entries.
    pub(crate) fn len(&self) -> usize {
        self.n
    }

    /// The scale `c_j`.
    pub(crate) fn scale(&self, j: usize) -> f64 {
        self.scale[j]
    }

    /// Ring positions of entries `d = 1..=m` as two ranges (and the `d − 1`
    /// offset at which the second starts).
    #[inline]
    fn segments(&self, m: usize) -> (Range<usize>, Range<usize>) {
        let first = m.min(self.dm - self.head);
        (self.head..self.head + first, 0..m - first)
    }

    /// Ring position of entry `d`.
    #[inline]
    fn pos(&self, d: usize) -> usize {
        (self.head + d - 1) % self.dm
    }

    /// `(Σ_d w_d a_{d−1}, Σ_d w_d b_{d−1}, max_d w_d)` of state `j` over its entries.
    #[inline]
    fn dots(&self, j: usize, a: &[f64], b: &[f64]) -> (f64, f64, f64) {
        let (m, base) = (self.n, j * self.dm);
        let (r1, r2) = self.segments(m);
        let l1 = r1.len();
        let (x1, y1, m1) =
            kernels::dot2_max(&self.w[base + r1.start..base + r1.end], &a[..l1], &b[..l1]);
        if r2.is_empty() {
            return (x1, y1, m1);
        }
        let (x2, y2, m2) = kernels::dot2_max(&self.w[base..base + r2.end], &a[l1..m], &b[l1..m]);
        (x1 + x2, y1 + y2, m1.max(m2))
    }

    /// `log (Σ_d e^{u_d + la_{d−1}} + e^{u_n + extra})` of state `j`, exactly.
    fn log_dot(&mut self, j: usize, la: &[f64], extra: f64) -> f64 {
        let (m, base) = (self.n, j * self.dm);
        let (r1, r2) = self.segments(m);
        let l1 = r1.len();
        kernels::add_max(
            &mut self.scratch[..l1],
            &self.u[base + r1.start..base + r1.end],
            &la[..l1],
        );
        kernels::add_max(
            &mut self.scratch[l1..m],
            &self.u[base..base + r2.end],
            &la[l1..m],
        );
        let mut total = log_sum_exp(&self.scratch[..m]);
        if extra > NEG_INF {
            let (_, un) = self.entry(j, m);
            total = crate::model::log_add(total, un + extra);
        }
        total
    }

    /// Moves the scale of state `j` by `delta` (values unchanged). Down
    /// (`delta > 0`, entries shrink) by one multiplication per entry: an
    /// entry that underflows is below `e^{−745}` of the new scale, and its
    /// `u` stays exact. Up, every `w` is recomputed from `u`, so that entries
    /// that had underflowed come back.
    fn rescale(&mut self, j: usize, delta: f64) {
        let base = j * self.dm;
        self.scale[j] += delta;
        let (u, w) = (
            &mut self.u[base..base + self.dm],
            &mut self.w[base..base + self.dm],
        );
        u.iter_mut().for_each(|v| *v -= delta);
        if delta > 0.0 {
            let f = (-delta).exp();
            w.iter_mut().for_each(|v| *v *= f);
        } else {
            w.copy_from_slice(u);
            exp_in_place(w);
        }
    }

    /// Recomputes `w = e^{u − max u}` of state `j` exactly (when every `w`
    /// underflowed or overflowed); false when the window holds no possible entry.
    fn renormalise(&mut self, j: usize) -> bool {
        let base = j * self.dm;
        let umax = kernels::max(&self.u[base..base + self.dm]);
        if umax == NEG_INF {
            return false;
        }
        self.scale[j] += umax;
        let (u, w) = (
            &mut self.u[base..base + self.dm],
            &mut self.w[base..base + self.dm],
        );
        u.iter_mut().for_each(|v| *v -= umax);
        w.copy_from_slice(u);
        exp_in_place(w);
        true
    }

    /// The dot products of state `j` with two linear tables, after moving
    /// the scale if the window's largest entry left `[LOW, HIGH]`; `None`
    /// when the window holds no possible entry.
    fn ranged_dots(&mut self, j: usize, a: &[f64], b: &[f64]) -> Option<(f64, f64, f64)> {
        if self.n == 0 {
            return None;
        }
        let (x, y, wmax) = self.dots(j, a, b);
        if (LOW..=HIGH).contains(&wmax) {
            return Some((x, y, wmax));
        }
        if wmax > 0.0 && wmax.is_finite() {
            self.rescale(j, wmax.ln());
        } else if !self.renormalise(j) {
            return None;
        }
        let (x, y, wmax) = self.dots(j, a, b);
        (wmax > 0.0).then_some((x, y, wmax))
    }

    /// `log(v)` when the linear sum `v` is exact, else the sum again in log space.
    fn settle(&mut self, j: usize, v: f64, wmax: f64, lt: &[f64], extra: f64) -> LogSum {
        if v >= EXACT * wmax {
            LogSum {
                log: v.ln(),
                exact_log: false,
            }
        } else {
            LogSum {
                log: self.log_dot(j, lt, extra),
                exact_log: true,
            }
        }
    }

    /// The forward sums of state `j`: `log Σ_d e^{u_d} P(D ≥ d)` and
    /// `log Σ_d e^{u_d} p(d)`, relative to the state's scale (read it after
    /// the call: the call may move it). `None` when the window holds no
    /// possible entry.
    pub(crate) fn forward_sums(
        &mut self,
        j: usize,
        (surv, log_surv): (&[f64], &[f64]),
        (pmf, log_pmf): (&[f64], &[f64]),
    ) -> Option<(LogSum, LogSum)> {
        let (x, y, wmax) = self.ranged_dots(j, surv, pmf)?;
        Some((
            self.settle(j, x, wmax, log_surv, NEG_INF),
            self.settle(j, y, wmax, log_pmf, NEG_INF),
        ))
    }

    /// The backward sum of state `j`: `log (Σ_d e^{u_d} p(d) + e^{u_n} extra)`
    /// (`extra` the last entry's weight beyond `p(n)`, linear and log),
    /// relative to the state's scale. `None` when the window holds no possible entry.
    pub(crate) fn backward_sum(
        &mut self,
        j: usize,
        (pmf, log_pmf): (&[f64], &[f64]),
        (extra, log_extra): (f64, f64),
    ) -> Option<LogSum> {
        let (x, _, wmax) = self.ranged_dots(j, pmf, pmf)?;
        let (wn, _) = self.entry(j, self.n);
        Some(self.settle(j, x + wn * extra, wmax, log_pmf, log_extra))
    }

    /// `w_d` and `u_d` of state `j`, entry `d`.
    #[inline]
    pub(crate) fn entry(&self, j: usize, d: usize) -> (f64, f64) {
        let p = j * self.dm + self.pos(d);
        (self.w[p], self.u[p])
    }

    /// `acc[d − 1] += f · w_d · t_{d−1}` for `d ≤ m` with `f = e^{lf}`, or,
    /// when `linear` is false, `acc[d − 1] += e^{lf + u_d + lt_{d−1}}` term by term.
    pub(crate) fn accumulate(
        &self,
        j: usize,
        m: usize,
        acc: &mut [f64],
        lf: f64,
        (t, lt): (&[f64], &[f64]),
        linear: bool,
    ) {
        let base = j * self.dm;
        let (r1, r2) = self.segments(m);
        let l1 = r1.len();
        if linear {
            let f = lf.exp();
            kernels::axpy_product(
                &mut acc[..l1],
                &self.w[base + r1.start..base + r1.end],
                &t[..l1],
                f,
            );
            kernels::axpy_product(&mut acc[l1..m], &self.w[base..base + r2.end], &t[l1..m], f);
        } else {
            for d in 1..=m {
                let v = lf + self.u[base + self.pos(d)] + lt[d - 1];
                if v > NEG_INF {
                    acc[d - 1] += v.exp();
                }
            }
        }
    }

    /// Advances every window by one frame: entry `d` becomes `d + 1` with
    /// `r_j` added (the entry `d = D` falls off), and `new_j` (a log value)
    /// becomes entry `d = 1`. A state with `r_j = −inf` loses every entry.
    pub(crate) fn advance(&mut self, r: &[f64], new: &[f64]) {
        let dm = self.dm;
        self.head = (self.head + dm - 1) % dm;
        self.n = (self.n + 1).min(dm);
        for j in 0..self.s {
            let base = j * dm;
            if r[j] == NEG_INF || r[j].is_nan() {
                self.u[base..base + dm].fill(NEG_INF);
                self.w[base..base + dm].fill(0.0);
                self.scale[j] = 0.0;
            } else {
                self.scale[j] += r[j];
            }
            let mut un = new[j] - self.scale[j];
            if un > INSERT_HIGH {
                // Keep the new entry's linear value small (older entries shrink).
                self.rescale(j, un);
                un = 0.0;
            }
            let p = base + self.head;
            if un == NEG_INF || un.is_nan() {
                self.u[p] = NEG_INF;
                self.w[p] = 0.0;
            } else {
                self.u[p] = un;
                self.w[p] = un.exp();
            }
        }
    }
}
