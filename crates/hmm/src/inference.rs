//! Forward, backward, posteriors and Viterbi for one sequence.
//!
//! The forward pass keeps the filtered distribution `h_t(i) = p(z_t = i | x_{1:t})`
//! and the log normaliser `log c_t = log p(x_t | x_{1:t−1})`, so that
//! `log α_t(i) = log h_t(i) + Σ_{s ≤ t} log c_s` and `log p(x_{1:T}) = Σ_t log c_t`.
//! Each step shifts the emission log-densities by their maximum before
//! exponentiating, so densities far below `e^{−745}` (36-dimensional Gaussians)
//! never underflow. Linear (scaled) arithmetic is used only while it is exact:
//! when some reachable state's predicted probability drops below `1e-290`
//! (e.g. a glitch frame rules a state out by more than `e^{−745}`, and the
//! chain cannot re-enter it), the prediction is carried in log space until the
//! dynamic range is small again, so that a state ruled out by one frame can
//! still come back when later frames favour it. The backward pass is
//! normalised per frame likewise, checks the same bounds and otherwise falls
//! back to a (per-frame normalised) log-space pass for the whole sequence.
//! Forbidden transitions (`a_ij = 0`) give `−inf`, never NaN.

use crate::error::{HmmError, Result};
use crate::model::Hmm;
use phasekit_emission::linalg::{exp_in_place, log_sum_exp};
use phasekit_emission::{Emission, Frames};

/// Result of the forward pass on one sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct Forward {
    n_states: usize,
    /// `h_t(i)`, `T × S` row-major (rows sum to 1; all zero after an impossible frame).
    filtered: Vec<f64>,
    /// `log c_t = log p(x_t | x_{1:t−1})`.
    log_normalisers: Vec<f64>,
}

impl Forward {
    /// Normalised forward variable `h_t(i) = α_t(i) / Σ_j α_t(j) = p(z_t = i | x_{1:t})`, `T × S`.
    pub fn filtered(&self) -> &[f64] {
        &self.filtered
    }

    /// `log p(x_t | x_{1:t−1})` per frame.
    pub fn log_normalisers(&self) -> &[f64] {
        &self.log_normalisers
    }

    /// `log p(x_{1:T})`.
    pub fn log_likelihood(&self) -> f64 {
        self.log_normalisers.iter().sum()
    }

    /// `log α_t(i) = log p(x_{1:t}, z_t = i)`, `T × S` row-major.
    ///
    /// Computed from the filtered probabilities, so entries of states holding
    /// less than about `1e-300` of a frame's filtered mass are not exact (and
    /// are `−inf` below `~1e-323`); `logsumexp_i(log α_t(i) + log β_t(i))` is
    /// unaffected.
    pub fn log_alpha(&self) -> Vec<f64> {
        let s = self.n_states;
        let mut acc = 0.0;
        let mut out = Vec::with_capacity(self.filtered.len());
        for (row, lc) in self.filtered.chunks_exact(s).zip(&self.log_normalisers) {
            acc += lc;
            out.extend(row.iter().map(|h| {
                if *h > 0.0 {
                    h.ln() + acc
                } else {
                    f64::NEG_INFINITY
                }
            }));
        }
        out
    }
}

/// State posteriors and expected transitions of one sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct Posteriors {
    /// `γ_t(i) = p(z_t = i | x_{1:T})`, `T × S` row-major.
    pub gamma: Vec<f64>,
    /// `Σ_t ξ_t(i, j) = Σ_t p(z_t = i, z_{t+1} = j | x_{1:T})`, `S × S` row-major.
    pub expected_transitions: Vec<f64>,
    /// `log p(x_{1:T})`.
    pub log_likelihood: f64,
}

/// The most probable state path.
#[derive(Debug, Clone, PartialEq)]
pub struct ViterbiPath {
    /// `argmax_z p(z, x)`; ties go to the lower state index.
    pub states: Vec<usize>,
    /// `max_z log p(z, x)` (`−inf` if every path is impossible).
    pub log_probability: f64,
}

/// Probabilities at or above this keep full relative precision in the scaled
/// recursions: a term that underflowed carries an absolute error of at most
/// ~1e-308 after normalisation, negligible next to them.
const SAFE: f64 = 1e-290;

/// A normaliser below this is not divided out but absorbed by re-shifting the
/// exponent, so that underflowed terms are never magnified by more than `1/ε`.
const RESCALE: f64 = f64::EPSILON;

/// The forward recursion between two frames: the prediction
/// `p(z_t = j | x_{1:t−1})` for the next frame, kept in linear form while every
/// reachable state's predicted probability is at least [`SAFE`] (then linear
/// arithmetic is exact), and in log form otherwise.
///
/// Both the batch [`Hmm::forward`] and the online [`crate::ForwardFilter`] step
/// this, so they agree to the last bit.
#[derive(Debug, Clone)]
pub(crate) struct ForwardCore {
    /// Linear prediction (valid when `!log_mode`).
    pred: Vec<f64>,
    /// Log prediction (valid when `log_mode`).
    log_pred: Vec<f64>,
    /// Where the prediction is exactly positive (structural reachability).
    reachable: Vec<bool>,
    log_mode: bool,
    // Scratch.
    alive: Vec<bool>,
    reach_next: Vec<bool>,
    pred_next: Vec<f64>,
    log_h: Vec<f64>,
    terms: Vec<f64>,
    /// `e^{log b_j − m}` of the current shift `m`.
    e: Vec<f64>,
}

impl ForwardCore {
    /// The recursion before the first frame of `hmm`.
    pub(crate) fn new<E: Emission>(hmm: &Hmm<E>) -> Self {
        let s = hmm.n_states();
        let mut core = ForwardCore {
            pred: vec![0.0; s],
            log_pred: vec![f64::NEG_INFINITY; s],
            reachable: vec![false; s],
            log_mode: false,
            alive: vec![false; s],
            reach_next: vec![false; s],
            pred_next: vec![0.0; s],
            log_h: vec![f64::NEG_INFINITY; s],
            terms: vec![f64::NEG_INFINITY; s],
            e: vec![0.0; s],
        };
        core.reset(hmm);
        core
    }

    /// Back to the initial distribution (before the first frame).
    pub(crate) fn reset<E: Emission>(&mut self, hmm: &Hmm<E>) {
        self.pred.copy_from_slice(&hmm.start);
        self.log_pred.copy_from_slice(&hmm.log_start);
        for (r, p) in self.reachable.iter_mut().zip(&hmm.start) {
            *r = *p > 0.0;
        }
        self.log_mode = hmm.start.iter().any(|p| *p > 0.0 && *p < SAFE);
    }

    /// `out_j = pred_j e^{log b_j − m}` over the possible states; returns their sum.
    ///
    /// The `S` exponentials are taken in one vectorised pass over every state
    /// (branch-free; the impossible ones are masked afterwards).
    #[inline(always)]
    fn scaled(&mut self, log_b: &[f64], m: f64, out: &mut [f64]) -> f64 {
        for (e, l) in self.e.iter_mut().zip(log_b) {
            *e = l - m;
        }
        exp_in_place(&mut self.e);
        let mut c = 0.0;
        for (j, o) in out.iter_mut().enumerate() {
            *o = if self.alive[j] {
                self.pred[j] * self.e[j]
            } else {
                0.0
            };
            c += *o;
        }
        c
    }

    /// Filters one frame with log-densities `log_b` (length `S`): writes
    /// `h_t = p(z_t | x_{1:t})` into `h` and returns `log c_t = log p(x_t | x_{1:t−1})`.
    /// An impossible frame returns `−inf`, zeroes `h` and leaves the recursion unchanged.
    pub(crate) fn step<E: Emission>(&mut self, hmm: &Hmm<E>, log_b: &[f64], h: &mut [f64]) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if avx2() {
            // SAFETY: the CPU supports AVX2 (checked at run time).
            return unsafe { self.step_avx2(hmm, log_b, h) };
        }
        self.step_body(hmm, log_b, h)
    }

    /// [`ForwardCore::step`] compiled for AVX2: the same operations in the same
    /// order (Rust never contracts to FMA), so the results are bit-identical.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn step_avx2<E: Emission>(&mut self, hmm: &Hmm<E>, log_b: &[f64], h: &mut [f64]) -> f64 {
        self.step_body(hmm, log_b, h)
    }

    #[inline(always)]
    fn step_body<E: Emission>(&mut self, hmm: &Hmm<E>, log_b: &[f64], h: &mut [f64]) -> f64 {
        let s = self.pred.len();
        let mut any = false;
        for j in 0..s {
            self.alive[j] = self.reachable[j] && log_b[j] > f64::NEG_INFINITY;
            any |= self.alive[j];
        }
        if !any {
            h.fill(0.0);
            return f64::NEG_INFINITY;
        }
        let was_log = self.log_mode;
        let lc = if was_log {
            for j in 0..s {
                self.log_h[j] = if self.alive[j] {
                    self.log_pred[j] + log_b[j]
                } else {
                    f64::NEG_INFINITY
                };
            }
            let lc = log_sum_exp(&self.log_h);
            for (lh, o) in self.log_h.iter_mut().zip(h.iter_mut()) {
                *lh -= lc;
                *o = *lh;
            }
            exp_in_place(h);
            lc
        } else {
            // Shift by the largest density among the possible states; their
            // predicted probabilities are at least SAFE, so c ≥ SAFE > 0.
            let mut m = f64::NEG_INFINITY;
            for j in 0..s {
                if self.alive[j] {
                    m = m.max(log_b[j]);
                }
            }
            let mut c = self.scaled(log_b, m, h);
            if c < RESCALE {
                m += c.ln();
                c = self.scaled(log_b, m, h);
            }
            let inv = 1.0 / c;
            h.iter_mut().for_each(|o| *o *= inv);
            m + c.ln()
        };

        // The prediction for the next frame, linear where that is exact. A
        // column whose linear value is below SAFE may have lost precision (or
        // underflowed) although the state is reachable: only such columns are
        // recomputed in log space, and the prediction is then carried in log
        // form (exact columns as `ln p_j`).
        let a = &hmm.transition;
        predict(h, a, &mut self.pred_next);
        let mut any_inexact = false;
        for j in 0..s {
            if self.pred_next[j] >= SAFE {
                self.reach_next[j] = true;
            } else {
                let mut r = false;
                for i in 0..s {
                    r |= self.alive[i] && a[i * s + j] > 0.0;
                }
                self.reach_next[j] = r;
                any_inexact |= r;
            }
        }
        if !any_inexact {
            std::mem::swap(&mut self.pred, &mut self.pred_next);
            self.log_mode = false;
        } else {
            if !was_log {
                // log h_t exactly: in linear mode every possible state's pred_j ≥ SAFE.
                for j in 0..s {
                    self.log_h[j] = if self.alive[j] {
                        self.pred[j].ln() + log_b[j] - lc
                    } else {
                        f64::NEG_INFINITY
                    };
                }
            }
            let la = &hmm.log_transition;
            for j in 0..s {
                self.log_pred[j] = if !self.reach_next[j] {
                    f64::NEG_INFINITY
                } else if self.pred_next[j] >= SAFE {
                    self.pred_next[j].ln()
                } else {
                    for i in 0..s {
                        self.terms[i] = self.log_h[i] + la[i * s + j];
                    }
                    log_sum_exp(&self.terms)
                };
            }
            self.log_mode = true;
        }
        std::mem::swap(&mut self.reachable, &mut self.reach_next);
        lc
    }
}

/// Whether the CPU has AVX2 (detected once; `std` caches the answer).
#[cfg(target_arch = "x86_64")]
#[inline]
fn avx2() -> bool {
    std::is_x86_feature_detected!("avx2")
}

/// Subtracts the log-sum-exp of `row` from every entry (if it is finite).
fn shift_to_zero(row: &mut [f64]) {
    let z = log_sum_exp(row);
    if z.is_finite() {
        row.iter_mut().for_each(|v| *v -= z);
    }
}

/// `pred_j = Σ_i h_i a_ij`.
#[inline(always)]
pub(crate) fn predict(h: &[f64], transition: &[f64], pred: &mut [f64]) {
    let s = h.len();
    pred.fill(0.0);
    for (i, hi) in h.iter().enumerate() {
        if *hi == 0.0 {
            continue;
        }
        for (p, a) in pred.iter_mut().zip(&transition[i * s..(i + 1) * s]) {
            *p += hi * a;
        }
    }
}

impl<E: Emission> Hmm<E> {
    /// `log b_i(x_t)` for every frame, `T × S` row-major.
    pub fn emission_log_densities(&self, seq: Frames<'_>) -> Result<Vec<f64>> {
        self.check_sequence(seq)?;
        Ok(self.emission.log_density(seq)?)
    }

    /// Forward pass from precomputed log-densities.
    pub(crate) fn forward_from(&self, log_b: &[f64]) -> Forward {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let mut filtered = vec![0.0; log_b.len()];
        let mut log_normalisers = Vec::with_capacity(t_len);
        let mut core = ForwardCore::new(self);
        for t in 0..t_len {
            let lc = core.step(
                self,
                &log_b[t * s..(t + 1) * s],
                &mut filtered[t * s..(t + 1) * s],
            );
            log_normalisers.push(lc);
            if lc == f64::NEG_INFINITY {
                // Everything after an impossible frame is impossible too.
                log_normalisers.resize(t_len, f64::NEG_INFINITY);
                break;
            }
        }
        Forward {
            n_states: s,
            filtered,
            log_normalisers,
        }
    }

    /// The forward pass: filtered distributions `h_t` and `log p(x_{1:T})`.
    pub fn forward(&self, seq: Frames<'_>) -> Result<Forward> {
        let log_b = self.emission_log_densities(seq)?;
        Ok(self.forward_from(&log_b))
    }

    /// `log p(x_{1:T} | λ)` (`−inf` if the sequence is impossible).
    pub fn log_likelihood(&self, seq: Frames<'_>) -> Result<f64> {
        Ok(self.forward(seq)?.log_likelihood())
    }

    /// Sum of the log-likelihoods of every sequence of a set.
    pub fn log_likelihood_all(&self, data: &phasekit_emission::SequenceSet) -> Result<f64> {
        let mut total = 0.0;
        for (k, seq) in data.iter().enumerate() {
            total += self.log_likelihood(seq).map_err(|e| e.in_sequence(k))?;
        }
        Ok(total)
    }

    /// The backward variable `log β_t(i) = log p(x_{t+1:T} | z_t = i)`, `T × S` row-major.
    pub fn backward(&self, seq: Frames<'_>) -> Result<Vec<f64>> {
        let log_b = self.emission_log_densities(seq)?;
        Ok(self.log_backward(&log_b, false))
    }

    /// Log-space backward pass (`S²` exponentials per frame). With `normalise`,
    /// every frame is shifted so that its log-sum-exp is 0 (the shifts are
    /// dropped), which keeps full precision on long sequences.
    fn log_backward(&self, log_b: &[f64], normalise: bool) -> Vec<f64> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let mut lb = vec![0.0; log_b.len()];
        let mut terms = vec![0.0; s];
        for t in (0..t_len.saturating_sub(1)).rev() {
            for i in 0..s {
                for j in 0..s {
                    terms[j] = self.log_transition[i * s + j]
                        + log_b[(t + 1) * s + j]
                        + lb[(t + 1) * s + j];
                }
                lb[t * s + i] = log_sum_exp(&terms);
            }
            if normalise {
                shift_to_zero(&mut lb[t * s..(t + 1) * s]);
            }
        }
        lb
    }

    /// Log-space forward pass, every frame shifted so that its log-sum-exp is 0
    /// (`log h_t`; the shifts are the log normalisers and are dropped).
    fn log_forward_normalised(&self, log_b: &[f64]) -> Vec<f64> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let mut la = vec![0.0; log_b.len()];
        let mut terms = vec![0.0; s];
        for j in 0..s {
            la[j] = self.log_start[j] + log_b[j];
        }
        shift_to_zero(&mut la[..s]);
        for t in 1..t_len {
            for j in 0..s {
                for i in 0..s {
                    terms[i] = la[(t - 1) * s + i] + self.log_transition[i * s + j];
                }
                la[t * s + j] = log_sum_exp(&terms) + log_b[t * s + j];
            }
            shift_to_zero(&mut la[t * s..(t + 1) * s]);
        }
        la
    }

    /// Posteriors `γ`, expected transitions and log-likelihood from log-densities,
    /// written into `gamma` (`T × S`); returns the expected transitions and `log p`.
    pub(crate) fn posteriors_into(
        &self,
        log_b: &[f64],
        gamma: &mut [f64],
    ) -> Result<(Vec<f64>, f64)> {
        let fwd = self.forward_from(log_b);
        let ll = fwd.log_likelihood();
        if ll == f64::NEG_INFINITY {
            let frame = fwd
                .log_normalisers
                .iter()
                .position(|v| *v == f64::NEG_INFINITY)
                .unwrap_or(0);
            return Err(HmmError::ImpossibleSequence { sequence: 0, frame });
        }
        if let Some(xi) = self.scaled_backward_posteriors(&fwd, log_b, gamma) {
            return Ok((xi, ll));
        }
        Ok((self.log_space_posteriors(log_b, gamma), ll))
    }

    /// Backward pass combined with the filtered forward variable.
    ///
    /// The backward message `β_{t+1}` is carried normalised, in linear form
    /// while every state that can still explain the rest of the sequence holds
    /// at least `SAFE` of it (then linear arithmetic is exact), and otherwise
    /// in log form, where only the rows whose linear value fell below `SAFE`
    /// are recomputed by log-sum-exp. With `u_j ∝ b_j(x_{t+1}) β_{t+1}(j)`:
    /// `β_t(i) ∝ Σ_j a_ij u_j`, `γ_t(i) ∝ h_t(i) β_t(i)` and
    /// `ξ_t(i,j) ∝ h_t(i) a_ij u_j`, both normalised by `Σ_i h_t(i) β_t(i)`.
    /// `None` when that normaliser is below `SAFE` (the forward and backward
    /// messages barely overlap); then the log-space form is used.
    fn scaled_backward_posteriors(
        &self,
        fwd: &Forward,
        log_b: &[f64],
        gamma: &mut [f64],
    ) -> Option<Vec<f64>> {
        #[cfg(target_arch = "x86_64")]
        if avx2() {
            // SAFETY: the CPU supports AVX2 (checked at run time).
            return unsafe { self.scaled_backward_posteriors_avx2(fwd, log_b, gamma) };
        }
        self.scaled_backward_posteriors_body(fwd, log_b, gamma)
    }

    /// Compiled for AVX2; bit-identical to the portable build (same operations,
    /// same order, no FMA contraction).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn scaled_backward_posteriors_avx2(
        &self,
        fwd: &Forward,
        log_b: &[f64],
        gamma: &mut [f64],
    ) -> Option<Vec<f64>> {
        self.scaled_backward_posteriors_body(fwd, log_b, gamma)
    }

    #[inline(always)]
    fn scaled_backward_posteriors_body(
        &self,
        fwd: &Forward,
        log_b: &[f64],
        gamma: &mut [f64],
    ) -> Option<Vec<f64>> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let a = &self.transition;
        let la = &self.log_transition;
        // Aᵀ, so that `A u` is a sequence of contiguous axpys (vectorised,
        // and summed in the same order as the row dot products).
        let mut a_t = vec![0.0; s * s];
        for i in 0..s {
            for j in 0..s {
                a_t[j * s + i] = a[i * s + j];
            }
        }
        let h = &fwd.filtered;
        let mut xi = vec![0.0; s * s];
        // beta / log_beta: the normalised backward message of frame t+1, in
        // linear or log form; alive: where it is exactly positive; carry:
        // alive and b_j(x_{t+1}) > 0; w: log(b_j β_j) relative to the shift of u.
        let mut beta = vec![1.0 / s as f64; s];
        let mut log_beta = vec![0.0; s];
        let mut log_mode = false;
        let mut alive = vec![true; s];
        let mut carry = vec![false; s];
        let mut next = vec![0.0; s];
        let mut u = vec![0.0; s];
        let mut w = vec![f64::NEG_INFINITY; s];
        let mut terms = vec![0.0; s];
        let mut shift = 0.0;
        let last = (t_len - 1) * s;
        let z: f64 = h[last..].iter().zip(&beta).map(|(x, y)| x * y).sum();
        for i in 0..s {
            gamma[last + i] = h[last + i] * beta[i] / z;
        }
        for t in (0..t_len - 1).rev() {
            let lb = &log_b[(t + 1) * s..(t + 2) * s];
            let mut any = false;
            for j in 0..s {
                carry[j] = alive[j] && lb[j] > f64::NEG_INFINITY;
                any |= carry[j];
            }
            if !any {
                return None;
            }
            // u_j = e^{w_j}, w_j = log b_j + log β_j − shift, max_j u_j ≈ 1.
            if log_mode {
                let mut m = f64::NEG_INFINITY;
                for j in 0..s {
                    w[j] = if carry[j] {
                        lb[j] + log_beta[j]
                    } else {
                        f64::NEG_INFINITY
                    };
                    m = m.max(w[j]);
                }
                w.iter_mut().for_each(|v| *v -= m);
                u.copy_from_slice(&w);
                exp_in_place(&mut u);
            } else {
                let mut m = f64::NEG_INFINITY;
                for j in 0..s {
                    if carry[j] {
                        m = m.max(lb[j]);
                    }
                }
                // One vectorised pass of S exponentials (all states,
                // branch-free), then the non-carrying ones are masked.
                let fill = |m: f64, u: &mut [f64]| -> f64 {
                    for (uj, l) in u.iter_mut().zip(lb) {
                        *uj = l - m;
                    }
                    exp_in_place(u);
                    let mut total = 0.0;
                    for j in 0..s {
                        u[j] = if carry[j] { u[j] * beta[j] } else { 0.0 };
                        total += u[j];
                    }
                    total
                };
                // Every carrying state has β ≥ SAFE / S, so the sum is positive.
                let mut total_u = fill(m, &mut u);
                if total_u < RESCALE {
                    m += total_u.ln();
                    total_u = fill(m, &mut u);
                }
                let inv_u = 1.0 / total_u;
                u.iter_mut().for_each(|v| *v *= inv_u);
                // w is only needed if some row turns out inexact (below).
                shift = m + total_u.ln();
            }
            // next = A u
            next.fill(0.0);
            for (j, uj) in u.iter().enumerate() {
                if *uj == 0.0 {
                    continue;
                }
                for (n, aji) in next.iter_mut().zip(&a_t[j * s..(j + 1) * s]) {
                    *n += aji * uj;
                }
            }
            // ξ_t(i,j) ∝ h_t(i) a_ij u_j; its normaliser is Σ_i h_t(i) next_i.
            let ht = &h[t * s..(t + 1) * s];
            let zx: f64 = ht.iter().zip(&next).map(|(x, y)| x * y).sum();
            if !(zx >= SAFE && zx.is_finite()) {
                return None;
            }
            let inv = 1.0 / zx;
            for i in 0..s {
                let hi = ht[i] * inv;
                if hi == 0.0 {
                    continue;
                }
                let row = &a[i * s..(i + 1) * s];
                let out = &mut xi[i * s..(i + 1) * s];
                for ((x, aij), uj) in out.iter_mut().zip(row).zip(&u) {
                    *x += hi * aij * uj;
                }
                gamma[t * s + i] = hi * next[i];
            }
            for i in 0..s {
                if ht[i] == 0.0 {
                    gamma[t * s + i] = 0.0;
                }
            }
            // β_t: linear if every structurally positive entry is ≥ SAFE.
            let mut any_inexact = false;
            for i in 0..s {
                if next[i] >= SAFE {
                    alive[i] = true;
                } else {
                    let mut r = false;
                    for j in 0..s {
                        r |= carry[j] && a[i * s + j] > 0.0;
                    }
                    alive[i] = r;
                    any_inexact |= r;
                }
            }
            if !any_inexact {
                let total: f64 = next.iter().sum();
                let inv_t = 1.0 / total;
                for (bi, ni) in beta.iter_mut().zip(&next) {
                    *bi = ni * inv_t;
                }
                log_mode = false;
            } else {
                if !log_mode {
                    // Exact: every carrying state had β_j ≥ SAFE / S.
                    for j in 0..s {
                        w[j] = if carry[j] {
                            lb[j] + beta[j].ln() - shift
                        } else {
                            f64::NEG_INFINITY
                        };
                    }
                }
                for i in 0..s {
                    log_beta[i] = if !alive[i] {
                        f64::NEG_INFINITY
                    } else if next[i] >= SAFE {
                        next[i].ln()
                    } else {
                        for j in 0..s {
                            terms[j] = la[i * s + j] + w[j];
                        }
                        log_sum_exp(&terms)
                    };
                }
                log_mode = true;
            }
        }
        Some(xi)
    }

    /// Log-space posteriors (used when the scaled pass would not be exact), with
    /// every frame's forward and backward messages normalised, so that long
    /// sequences keep full precision.
    fn log_space_posteriors(&self, log_b: &[f64], gamma: &mut [f64]) -> Vec<f64> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let la = self.log_forward_normalised(log_b);
        let lb = self.log_backward(log_b, true);
        let mut terms = vec![0.0; s * s];
        for t in 0..t_len {
            let row = &mut terms[..s];
            for i in 0..s {
                row[i] = la[t * s + i] + lb[t * s + i];
            }
            let z = log_sum_exp(row);
            let g = &mut gamma[t * s..(t + 1) * s];
            for (gi, v) in g.iter_mut().zip(row.iter()) {
                *gi = v - z;
            }
            exp_in_place(g);
        }
        let mut xi = vec![0.0; s * s];
        for t in 0..t_len - 1 {
            for i in 0..s {
                for j in 0..s {
                    terms[i * s + j] = la[t * s + i]
                        + self.log_transition[i * s + j]
                        + log_b[(t + 1) * s + j]
                        + lb[(t + 1) * s + j];
                }
            }
            let z = log_sum_exp(&terms);
            terms.iter_mut().for_each(|v| *v -= z);
            exp_in_place(&mut terms);
            for (x, v) in xi.iter_mut().zip(&terms) {
                *x += v;
            }
        }
        xi
    }

    /// State posteriors `γ_t(i)` and expected transitions `Σ_t ξ_t(i,j)`.
    ///
    /// Errors if the sequence has probability zero under the model.
    pub fn posteriors(&self, seq: Frames<'_>) -> Result<Posteriors> {
        let log_b = self.emission_log_densities(seq)?;
        let mut gamma = vec![0.0; log_b.len()];
        let (expected_transitions, log_likelihood) = self.posteriors_into(&log_b, &mut gamma)?;
        Ok(Posteriors {
            gamma,
            expected_transitions,
            log_likelihood,
        })
    }

    /// The Viterbi path `argmax_z log p(z, x)` and its log-probability.
    pub fn viterbi(&self, seq: Frames<'_>) -> Result<ViterbiPath> {
        let log_b = self.emission_log_densities(seq)?;
        Ok(self.viterbi_from(&log_b))
    }

    pub(crate) fn viterbi_from(&self, log_b: &[f64]) -> ViterbiPath {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let mut delta: Vec<f64> = (0..s).map(|j| self.log_start[j] + log_b[j]).collect();
        let mut next = vec![0.0; s];
        let mut back = vec![0u32; t_len * s];
        for t in 1..t_len {
            for j in 0..s {
                let mut best = (0usize, f64::NEG_INFINITY);
                for i in 0..s {
                    let v = delta[i] + self.log_transition[i * s + j];
                    if v > best.1 {
                        best = (i, v);
                    }
                }
                back[t * s + j] = best.0 as u32;
                next[j] = best.1 + log_b[t * s + j];
            }
            std::mem::swap(&mut delta, &mut next);
        }
        let mut last = (0usize, f64::NEG_INFINITY);
        for (j, v) in delta.iter().enumerate() {
            if *v > last.1 {
                last = (j, *v);
            }
        }
        let mut states = vec![0; t_len];
        states[t_len - 1] = last.0;
        for t in (1..t_len).rev() {
            states[t - 1] = back[t * s + states[t]] as usize;
        }
        ViterbiPath {
            states,
            log_probability: last.1,
        }
    }
}
