//! Forward, backward, posteriors and Viterbi of one sequence, in log space.
//!
//! Frames `t = 0..T`, states `i, j, k`, durations `d = 1..=D`. With
//! `e_j(t) = log b_j(x_t)` and the forward log normalisers
//! `ℓ_t = log p(x_t | x_{<t})`, let `L_j(t) = Σ_{u<t} (e_j(u) − ℓ_u)`
//! (cumulative sums of the normalised emission log-densities), so that a
//! segment of `j` over frames `s..=t` emits with normalised log-probability
//! `L_j(t+1) − L_j(s)`.
//!
//! **Forward.** `â_t(j) = log p(a segment of j starts at t | x_{<t})` and
//! `F̂_t(j) = log p(a segment of j ends at t | x_{≤t})`:
//!
//! * `â_0(j) = log π_j`, `â_{t+1}(k) = log Σ_i e^{F̂_t(i)} a_ik`;
//! * `ℓ_t = log Σ_j Σ_d e^{â_{t−d+1}(j) + L_j(t) − L_j(t−d+1) + e_j(t)} P(D_j ≥ d)`
//!   (every segment still going on at `t`);
//! * `F̂_t(j) = log Σ_d e^{â_{t−d+1}(j) + L_j(t+1) − L_j(t−d+1)} p_j(d)`;
//! * the filtered marginals `h_t(j) = p(z_t = j | x_{≤t})` are the `j` parts of `ℓ_t`'s sum.
//!
//! `log p(x) = Σ_t ℓ_t` with [`Censoring::RightCensored`] (the last segment
//! is scored by `P(D ≥ d)`), plus `λ = log Σ_j e^{F̂_{T−1}(j)}` with
//! [`Censoring::EndsWithSegment`].
//!
//! **Backward.** `Ê_t(j)` (after a segment of `j` ends at `t`) and `D̂_s(k)`
//! (from a segment of `k` starting at `s`), normalised by `p(x_{>t} | x_{≤t})`
//! and `p(x_{≥s} | x_{<s})`:
//!
//! * `Ê_{T−1}(j) = −λ`, `Ê_t(j) = log Σ_k a_jk e^{D̂_{t+1}(k)}`;
//! * `D̂_s(k) = log Σ_{d} e^{L_k(s+d) − L_k(s) + Ê_{s+d−1}(k)} q_k(d)` with
//!   `q_k(d) = p_k(d)` for a segment ending before `T − 1` and the last
//!   segment's weight (`P(D ≥ d)` or `p(d)`) for `d = T − s`.
//!
//! **Posteriors.** Segment starts `σ_s(k) = e^{â_s(k) + D̂_s(k)}`, segment
//! ends `ε_t(j) = e^{F̂_t(j) + Ê_t(j)}`, transitions
//! `Σ_t e^{F̂_t(i) + log a_ik + D̂_{t+1}(k)}`, complete durations
//! `η_k(d) = Σ_s e^{â_s(k) + L_k(s+d) − L_k(s) + Ê_{s+d−1}(k)} p_k(d)`,
//! and state marginals by `γ_{T−1} = h_{T−1}` and
//! `γ_t = γ_{t+1} − σ_{t+1} + ε_t` (segments covering `t`).
//!
//! The cumulative sums are carried as the per-state windows of the last `D`
//! starts (forward) or ends (backward), advanced by one frame per step (the
//! `window` module): every term is a sum of at most `D` normalised
//! log-densities (no cancellation of large cumulative sums, and the online
//! filter runs forever at the same precision), and the sums over durations
//! are dot products of linear windows with the duration tables, with an
//! exact log-space fallback wherever underflow could lose a term, so that no
//! explanation of the data is lost however unlikely it is at first. Cost
//! per frame: `O(S (S + D))` arithmetic and `O(S²)` exponentials, no
//! allocation.

use crate::duration::Duration;
use crate::error::{HsmmError, Result};
use crate::kernels;
use crate::model::{Censoring, Hsmm};
use crate::window::Windows;
use phasekit_emission::linalg::{exp_in_place, log_sum_exp};
use phasekit_emission::{Emission, Frames, SequenceSet};
use serde::{Deserialize, Serialize};

const NEG_INF: f64 = f64::NEG_INFINITY;

/// One segment of a segmentation: state `state` on frames `start..start + len`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct Segment {
    /// The state.
    pub state: usize,
    /// First frame.
    pub start: usize,
    /// Number of frames.
    pub len: usize,
}

/// Result of the forward pass on one sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct HsmmForward {
    n_states: usize,
    filtered: Vec<f64>,
    log_normalisers: Vec<f64>,
    final_term: f64,
}

impl HsmmForward {
    /// Filtered state marginals `h_t(j) = p(z_t = j | x_{0..=t})`, `T × S` row-major.
    pub fn filtered(&self) -> &[f64] {
        &self.filtered
    }

    /// `log p(x_t | x_{<t})` per frame (the ongoing segments scored by survival).
    pub fn log_normalisers(&self) -> &[f64] {
        &self.log_normalisers
    }

    /// `log p(x)`: the sum of the log normalisers, plus, with
    /// [`Censoring::EndsWithSegment`], the log-probability that a segment ends at the last frame.
    pub fn log_likelihood(&self) -> f64 {
        self.log_normalisers.iter().sum::<f64>() + self.final_term
    }

    /// Number of states.
    pub fn n_states(&self) -> usize {
        self.n_states
    }
}

/// Posteriors of one sequence.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct HsmmPosteriors {
    /// `γ_t(i) = p(z_t = i | x)`, `T × S` row-major.
    pub gamma: Vec<f64>,
    /// `p(a segment of i starts at t | x)`, `T × S`.
    pub segment_starts: Vec<f64>,
    /// `p(a segment of i ends at t | x)`, `T × S`; at the last frame, the
    /// probability that the last segment is `i` (ended or censored).
    pub segment_ends: Vec<f64>,
    /// Expected number of transitions `i → j` between segments, `S × S`.
    pub expected_transitions: Vec<f64>,
    /// Expected number of complete segments of state `i` lasting `d` frames,
    /// `S × D` (`[i·D + d − 1]`); with [`Censoring::EndsWithSegment`] the last segment is complete.
    pub expected_durations: Vec<f64>,
    /// With [`Censoring::RightCensored`]: the probability that the last
    /// segment is state `i` observed for `d` frames (its full duration is at
    /// least `d`), `S × D`; zero otherwise.
    pub censored_durations: Vec<f64>,
    /// `log p(x)`.
    pub log_likelihood: f64,
}

/// The most probable segmentation.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct ViterbiSegmentation {
    /// The state of every frame.
    pub states: Vec<usize>,
    /// The segments in time order (the last one may be censored).
    pub segments: Vec<Segment>,
    /// `max log p(segmentation, x)`.
    pub log_probability: f64,
}

/// The forward recursion between two frames: the windows of the last `D`
/// segment starts of every state (see the `window` module), advanced by one
/// frame per step.
///
/// Both the batch [`Hsmm::forward`] and the online [`crate::HsmmFilter`]
/// step this, so they agree to the last bit.
#[derive(Debug, Clone)]
pub(crate) struct ForwardCore {
    s: usize,
    dm: usize,
    /// Entry `d` of state `j` before frame `t`: `â_{t−d+1}(j) + L_j(t) − L_j(t−d+1)`,
    /// the normalised log-probability of a segment of `j` that started
    /// `d − 1` frames before `t`, emissions up to `t − 1` included.
    windows: Windows,
    /// `F̂_t(j)` of the last step.
    pub(crate) ends: Vec<f64>,
    /// `â_{t+1}(j)` of the last step.
    pub(crate) next_starts: Vec<f64>,
    /// Log of every state's share of `ℓ_t`.
    mass: Vec<f64>,
    col: Vec<f64>,
}

impl ForwardCore {
    pub(crate) fn new<E: Emission, D: Duration>(m: &Hsmm<E, D>) -> Self {
        let (s, dm) = (m.n_states(), m.max_duration());
        let mut core = ForwardCore {
            s,
            dm,
            windows: Windows::new(s, dm),
            ends: vec![NEG_INF; s],
            next_starts: vec![NEG_INF; s],
            mass: vec![NEG_INF; s],
            col: vec![0.0; s],
        };
        core.reset(m);
        core
    }

    /// Back to the state before the first frame: one segment start, `log π_j`.
    pub(crate) fn reset<E: Emission, D: Duration>(&mut self, m: &Hsmm<E, D>) {
        self.windows.clear();
        self.col.fill(0.0);
        self.windows.advance(&self.col, &m.tables.log_start);
    }

    /// Copies another core's state (same shape) without allocating.
    pub(crate) fn copy_from(&mut self, other: &ForwardCore) {
        self.windows.copy_from(&other.windows);
    }

    /// Filters one frame with log-densities `e` (length `S`): writes
    /// `h_t = p(z_t | x_{≤t})` into `filtered`, leaves `F̂_t` in `ends` and
    /// `â_{t+1}` in `next_starts`, and returns `ℓ_t = log p(x_t | x_{<t})`.
    /// An impossible frame returns `−inf`, zeroes `filtered` and leaves the
    /// recursion unchanged. No exponential per window entry: the sums are
    /// dot products of the linear windows with the duration tables.
    // The loops walk several per-state arrays in step; indices say so best.
    #[allow(clippy::needless_range_loop)]
    pub(crate) fn step<E: Emission, D: Duration>(
        &mut self,
        m: &Hsmm<E, D>,
        e: &[f64],
        filtered: &mut [f64],
    ) -> f64 {
        let (s, dm) = (self.s, self.dm);
        let tb = &m.tables;
        let mut gmax = NEG_INF;
        for j in 0..s {
            let rows = j * dm..(j + 1) * dm;
            let sums = if e[j] == NEG_INF {
                None
            } else {
                self.windows.forward_sums(
                    j,
                    (&tb.survival[rows.clone()], &tb.log_survival[rows.clone()]),
                    (&tb.pmf[rows.clone()], &tb.log_pmf[rows]),
                )
            };
            match sums {
                Some((going_on, ending)) => {
                    let c = self.windows.scale(j) + e[j];
                    self.mass[j] = c + going_on.log;
                    self.ends[j] = c + ending.log;
                    gmax = gmax.max(self.mass[j]);
                }
                None => {
                    self.mass[j] = NEG_INF;
                    self.ends[j] = NEG_INF;
                }
            }
        }
        if gmax == NEG_INF || gmax.is_nan() {
            filtered.fill(0.0);
            return NEG_INF;
        }
        for j in 0..s {
            self.col[j] = self.mass[j] - gmax;
        }
        exp_in_place(&mut self.col);
        let total = kernels::sum(&self.col);
        let lc = gmax + total.ln();
        let inv = 1.0 / total;
        for (f, c) in filtered.iter_mut().zip(&self.col) {
            *f = c * inv;
        }
        for v in self.ends.iter_mut() {
            *v -= lc;
        }
        // Segments starting at t + 1.
        for k in 0..s {
            let la = &tb.log_transition_t[k * s..(k + 1) * s];
            for ((c, f), a) in self.col.iter_mut().zip(&self.ends).zip(la) {
                *c = f + a;
            }
            self.next_starts[k] = log_sum_exp(&self.col);
        }
        // Advance the windows by one frame.
        for j in 0..s {
            self.col[j] = e[j] - lc;
        }
        self.windows.advance(&self.col, &self.next_starts);
        lc
    }
}

/// Buffers of one sequence's forward-backward, reused across sequences.
#[derive(Debug, Default)]
pub(crate) struct Workspace {
    pub(crate) log_b: Vec<f64>,
    /// `â_t(j)`, `T × S`.
    starts: Vec<f64>,
    /// `F̂_t(j)`, `T × S`.
    ends: Vec<f64>,
    /// `ℓ_t`.
    log_norm: Vec<f64>,
    /// Filtered marginals after the forward pass, `γ` after the backward pass.
    pub(crate) gamma: Vec<f64>,
    core: Option<ForwardCore>,
    // Backward scratch.
    windows: Option<Windows>,
    d_next: Vec<f64>,
    d_cur: Vec<f64>,
    e_hat: Vec<f64>,
    eps: Vec<f64>,
    sigma: Vec<f64>,
    sigma_next: Vec<f64>,
    x: Vec<f64>,
    r_new: Vec<f64>,
}

/// Expected segment statistics accumulated by the backward pass.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SegmentCounts {
    /// `Σ σ_0(i)`.
    pub(crate) start: Vec<f64>,
    /// `S × S`.
    pub(crate) transitions: Vec<f64>,
    /// `S × D` complete segments.
    pub(crate) durations: Vec<f64>,
    /// `S × D` right-censored last segments.
    pub(crate) censored: Vec<f64>,
}

impl SegmentCounts {
    pub(crate) fn zeros(s: usize, dm: usize) -> Self {
        SegmentCounts {
            start: vec![0.0; s],
            transitions: vec![0.0; s * s],
            durations: vec![0.0; s * dm],
            censored: vec![0.0; s * dm],
        }
    }
}

impl<E: Emission, D: Duration> Hsmm<E, D> {
    /// `log b_i(x_t)` for every frame, `T × S` row-major.
    pub fn emission_log_densities(&self, seq: Frames<'_>) -> Result<Vec<f64>> {
        self.check_sequence(seq)?;
        Ok(self.emission.log_density(seq)?)
    }

    /// Emission log-densities of `seq` into the workspace.
    pub(crate) fn fill_log_b(&self, seq: Frames<'_>, ws: &mut Workspace) -> Result<()> {
        ws.log_b.resize(seq.len() * self.n_states(), 0.0);
        self.emission.log_density_into(seq, &mut ws.log_b)?;
        Ok(())
    }

    /// The forward pass over `ws.log_b`; fills the starts, ends, normalisers
    /// and filtered marginals and returns `(log p(x), λ)`.
    pub(crate) fn forward_ws(&self, ws: &mut Workspace) -> Result<(f64, f64)> {
        let (s, dm) = (self.n_states(), self.max_duration());
        let t_len = ws.log_b.len() / s;
        ws.starts.resize(t_len * s, NEG_INF);
        ws.ends.resize(t_len * s, NEG_INF);
        ws.log_norm.resize(t_len, 0.0);
        ws.gamma.resize(t_len * s, 0.0);
        let core = match &mut ws.core {
            Some(c) if c.s == s && c.dm == dm => {
                c.reset(self);
                c
            }
            slot => slot.insert(ForwardCore::new(self)),
        };
        ws.starts[..s].copy_from_slice(&self.tables.log_start);
        let mut total = 0.0;
        for t in 0..t_len {
            let lc = core.step(
                self,
                &ws.log_b[t * s..(t + 1) * s],
                &mut ws.gamma[t * s..(t + 1) * s],
            );
            if lc == NEG_INF {
                return Err(self.impossible(t));
            }
            ws.log_norm[t] = lc;
            total += lc;
            ws.ends[t * s..(t + 1) * s].copy_from_slice(&core.ends);
            if t + 1 < t_len {
                ws.starts[(t + 1) * s..(t + 2) * s].copy_from_slice(&core.next_starts);
            }
        }
        let lambda = match self.censoring {
            Censoring::RightCensored => 0.0,
            Censoring::EndsWithSegment => {
                let l = log_sum_exp(&ws.ends[(t_len - 1) * s..]);
                if l == NEG_INF {
                    return Err(self.impossible(t_len - 1));
                }
                l
            }
        };
        Ok((total + lambda, lambda))
    }

    pub(crate) fn impossible(&self, frame: usize) -> HsmmError {
        HsmmError::ImpossibleSequence {
            sequence: 0,
            frame,
            max_duration: self.max_duration(),
        }
    }

    /// The backward pass after [`Hsmm::forward_ws`]: writes `γ` into
    /// `ws.gamma`, adds the segment statistics into `acc`, and, when given,
    /// writes the segment start and end posteriors (`T × S` each).
    pub(crate) fn backward_ws(
        &self,
        ws: &mut Workspace,
        lambda: f64,
        acc: &mut SegmentCounts,
        mut record: Option<(&mut [f64], &mut [f64])>,
    ) {
        let (s, dm) = (self.n_states(), self.max_duration());
        let t_len = ws.log_norm.len();
        let tb = &self.tables;
        let Workspace {
            log_b,
            starts,
            ends,
            log_norm,
            gamma,
            windows,
            d_next,
            d_cur,
            e_hat,
            eps,
            sigma,
            sigma_next,
            x,
            r_new,
            ..
        } = ws;
        let windows = match windows {
            Some(w) if w.shape() == (s, dm) => {
                w.clear();
                w
            }
            slot => slot.insert(Windows::new(s, dm)),
        };
        for v in [
            &mut *d_next,
            &mut *d_cur,
            &mut *e_hat,
            &mut *eps,
            &mut *sigma,
            &mut *sigma_next,
            &mut *x,
            &mut *r_new,
        ] {
            v.clear();
            v.resize(s, 0.0);
        }
        let last_row = (t_len - 1) * s;
        if self.censoring == Censoring::EndsWithSegment {
            for j in 0..s {
                gamma[last_row + j] = (ends[last_row + j] - lambda).exp();
            }
        }
        for t in (0..t_len).rev() {
            let e_row = &log_b[t * s..(t + 1) * s];
            let lc = log_norm[t];
            // Ê_t, the transitions out of segments ending at t, ε_t.
            if t == t_len - 1 {
                e_hat.fill(-lambda);
            } else {
                let end_row = &ends[t * s..(t + 1) * s];
                for i in 0..s {
                    let la = &tb.log_transition[i * s..(i + 1) * s];
                    let mut m = NEG_INF;
                    for ((xk, a), dn) in x.iter_mut().zip(la).zip(d_next.iter()) {
                        *xk = a + dn;
                        m = m.max(*xk);
                    }
                    if m == NEG_INF {
                        e_hat[i] = NEG_INF;
                        eps[i] = 0.0;
                        continue;
                    }
                    x.iter_mut().for_each(|v| *v -= m);
                    exp_in_place(x);
                    let sum: f64 = x.iter().sum();
                    e_hat[i] = m + sum.ln();
                    // e^{F̂_t(i) + m} is the posterior of the likeliest
                    // transition out of i at t, at most 1.
                    let f = (end_row[i] + m).exp();
                    eps[i] = f * sum;
                    if f > 0.0 {
                        let row = &mut acc.transitions[i * s..(i + 1) * s];
                        for (r, xk) in row.iter_mut().zip(x.iter()) {
                            *r += xk * f;
                        }
                    }
                }
            }
            // Advance the windows of segment ends by one frame (backwards):
            // entry d of state k is the segment of k on frames t..t+d−1,
            // `L_k(t+d) − L_k(t) + Ê_{t+d−1}(k)`.
            for k in 0..s {
                x[k] = e_row[k] - lc;
                r_new[k] = x[k] + e_hat[k];
            }
            windows.advance(x, r_new);
            // D̂_t, the segment starts σ_t and the duration counts.
            let n = windows.len();
            // The oldest entry is the segment reaching the last frame.
            let has_last = t_len - t <= dm;
            let start_row = &starts[t * s..(t + 1) * s];
            for k in 0..s {
                let rows = k * dm..(k + 1) * dm;
                // The last segment's weight beyond p(n): P(D ≥ n + 1) when censored.
                let extra = match (has_last, self.censoring) {
                    (true, Censoring::RightCensored) if n < dm => {
                        (tb.survival[k * dm + n], tb.log_survival[k * dm + n])
                    }
                    _ => (0.0, NEG_INF),
                };
                let Some(sum) = windows.backward_sum(
                    k,
                    (&tb.pmf[rows.clone()], &tb.log_pmf[rows.clone()]),
                    extra,
                ) else {
                    d_cur[k] = NEG_INF;
                    sigma[k] = 0.0;
                    continue;
                };
                let c = windows.scale(k);
                d_cur[k] = c + sum.log;
                sigma[k] = (start_row[k] + d_cur[k]).exp();
                if start_row[k] == NEG_INF {
                    continue;
                }
                // Each count is a posterior probability, e^{â_t(k) + c + u_d} p(d) ≤ 1.
                let lf = start_row[k] + c;
                let linear = !sum.exact_log && lf < 700.0;
                let censored_last = has_last && self.censoring == Censoring::RightCensored;
                let complete = if censored_last { n - 1 } else { n };
                windows.accumulate(
                    k,
                    complete,
                    &mut acc.durations[rows.clone()],
                    lf,
                    (&tb.pmf[rows.clone()], &tb.log_pmf[rows.clone()]),
                    linear,
                );
                if censored_last {
                    let (_, un) = windows.entry(k, n);
                    let v = lf + un + tb.log_survival[k * dm + n - 1];
                    if v > NEG_INF {
                        acc.censored[k * dm + n - 1] += v.exp();
                    }
                }
            }
            // γ_t from γ_{t+1}: segments covering t.
            if t < t_len - 1 {
                for k in 0..s {
                    let g = gamma[(t + 1) * s + k] - sigma_next[k] + eps[k];
                    gamma[t * s + k] = g.clamp(0.0, 1.0);
                }
            }
            if let Some((st, en)) = record.as_mut() {
                st[t * s..(t + 1) * s].copy_from_slice(sigma);
                if t == t_len - 1 {
                    en[t * s..(t + 1) * s].copy_from_slice(&gamma[t * s..(t + 1) * s]);
                } else {
                    en[t * s..(t + 1) * s].copy_from_slice(eps);
                }
            }
            std::mem::swap(d_cur, d_next);
            std::mem::swap(sigma, sigma_next);
        }
        for (a, v) in acc.start.iter_mut().zip(sigma_next.iter()) {
            *a += v;
        }
    }

    /// The forward pass: filtered marginals and `log p(x)`.
    ///
    /// Errors (naming the frame) when the sequence has probability zero.
    pub fn forward(&self, seq: Frames<'_>) -> Result<HsmmForward> {
        self.check_sequence(seq)?;
        let mut ws = Workspace::default();
        self.fill_log_b(seq, &mut ws)?;
        let (_, lambda) = self.forward_ws(&mut ws)?;
        Ok(HsmmForward {
            n_states: self.n_states(),
            filtered: ws.gamma,
            log_normalisers: ws.log_norm,
            final_term: lambda,
        })
    }

    /// `log p(x | λ)`; errors (naming the frame) when it is zero.
    pub fn log_likelihood(&self, seq: Frames<'_>) -> Result<f64> {
        Ok(self.forward(seq)?.log_likelihood())
    }

    /// Sum of the log-likelihoods of every sequence of a set.
    pub fn log_likelihood_all(&self, data: &SequenceSet) -> Result<f64> {
        let mut total = 0.0;
        for (k, seq) in data.iter().enumerate() {
            total += self.log_likelihood(seq).map_err(|e| e.in_sequence(k))?;
        }
        Ok(total)
    }

    /// State and duration posteriors of one sequence.
    pub fn posteriors(&self, seq: Frames<'_>) -> Result<HsmmPosteriors> {
        self.check_sequence(seq)?;
        let (s, dm) = (self.n_states(), self.max_duration());
        let mut ws = Workspace::default();
        self.fill_log_b(seq, &mut ws)?;
        let (log_likelihood, lambda) = self.forward_ws(&mut ws)?;
        let mut acc = SegmentCounts::zeros(s, dm);
        let mut starts = vec![0.0; seq.len() * s];
        let mut ends = vec![0.0; seq.len() * s];
        self.backward_ws(&mut ws, lambda, &mut acc, Some((&mut starts, &mut ends)));
        Ok(HsmmPosteriors {
            gamma: ws.gamma,
            segment_starts: starts,
            segment_ends: ends,
            expected_transitions: acc.transitions,
            expected_durations: acc.durations,
            censored_durations: acc.censored,
            log_likelihood,
        })
    }

    /// The most probable segmentation `argmax p(segments, x)` and its log-probability.
    ///
    /// Ties go to the lower state index and then to the shorter segment.
    /// Errors (naming the frame) when every segmentation is impossible.
    pub fn viterbi(&self, seq: Frames<'_>) -> Result<ViterbiSegmentation> {
        let log_b = self.emission_log_densities(seq)?;
        self.viterbi_from(&log_b)
    }

    #[allow(clippy::needless_range_loop)]
    pub(crate) fn viterbi_from(&self, log_b: &[f64]) -> Result<ViterbiSegmentation> {
        let (s, dm) = (self.n_states(), self.max_duration());
        let tb = &self.tables;
        let t_len = log_b.len() / s;
        // window[j·D + d − 1]: the best log-probability of a path whose
        // current segment of j started d − 1 frames before the next frame,
        // relative to Σ_u max_j e_j(u) (which keeps the numbers small).
        let mut window = vec![NEG_INF; s * dm];
        for j in 0..s {
            window[j * dm] = tb.log_start[j];
        }
        let mut active = 1;
        // Best duration of a segment of j ending at t, best predecessor of a
        // segment of k starting at t.
        let mut best_len = vec![0u32; t_len * s];
        let mut best_prev = vec![u32::MAX; t_len * s];
        let mut completion = vec![NEG_INF; s];
        let mut offset = 0.0;
        for t in 0..t_len {
            let e = &log_b[t * s..(t + 1) * s];
            let n_t = e.iter().copied().fold(NEG_INF, f64::max);
            if n_t == NEG_INF || n_t.is_nan() {
                return Err(self.impossible(t));
            }
            offset += n_t;
            // Add frame t's emissions; the best segment of every state ending at t.
            let mut alive = false;
            for j in 0..s {
                let base = j * dm;
                let row = &mut window[base..base + active];
                let (d, v) = kernels::add_argmax(row, e[j] - n_t, &tb.log_pmf[base..base + active]);
                completion[j] = v;
                best_len[t * s + j] = d as u32 + 1;
                // Some segment may still be going on (P(D ≥ d) ≥ p(d)).
                alive |= v > NEG_INF
                    || row
                        .iter()
                        .zip(&tb.log_survival[base..base + active])
                        .any(|(w, l)| w + l > NEG_INF);
            }
            if !alive {
                return Err(self.impossible(t));
            }
            if t == t_len - 1 {
                break;
            }
            let next = (active + 1).min(dm);
            for k in 0..s {
                let mut best = (u32::MAX, NEG_INF);
                for i in 0..s {
                    let v = completion[i] + tb.log_transition[i * s + k];
                    if v > best.1 {
                        best = (i as u32, v);
                    }
                }
                best_prev[(t + 1) * s + k] = best.0;
                let row = &mut window[k * dm..k * dm + next];
                row.copy_within(0..next - 1, 1);
                row[0] = best.1;
            }
            active = next;
        }
        let mut best = (0usize, 0usize, NEG_INF);
        for j in 0..s {
            let base = j * dm;
            for d in 0..active {
                let v = window[base + d] + tb.log_last[base + d];
                if v > best.2 {
                    best = (j, d + 1, v);
                }
            }
        }
        if best.2 == NEG_INF {
            return Err(self.impossible(t_len - 1));
        }
        let mut segments = Vec::new();
        let (mut state, mut len) = (best.0, best.1);
        let mut end = t_len;
        loop {
            let start = end - len;
            segments.push(Segment { state, start, len });
            if start == 0 {
                break;
            }
            let prev = best_prev[start * s + state] as usize;
            state = prev;
            len = best_len[(start - 1) * s + prev] as usize;
            end = start;
        }
        segments.reverse();
        let mut states = Vec::with_capacity(t_len);
        for seg in &segments {
            states.extend(std::iter::repeat_n(seg.state, seg.len));
        }
        Ok(ViterbiSegmentation {
            states,
            segments,
            log_probability: best.2 + offset,
        })
    }
}
