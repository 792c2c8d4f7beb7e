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
use phasekit_emission::linalg::log_sum_exp;
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
    fn scaled(&self, log_b: &[f64], m: f64, out: &mut [f64]) -> f64 {
        let mut c = 0.0;
        for (j, o) in out.iter_mut().enumerate() {
            *o = if self.alive[j] {
                self.pred[j] * (log_b[j] - m).exp()
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
                *o = lh.exp();
            }
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

        // The prediction for the next frame: linear if that is exact, else in log space.
        let a = &hmm.transition;
        self.reach_next.fill(false);
        for i in 0..s {
            if self.alive[i] {
                for (r, aij) in self.reach_next.iter_mut().zip(&a[i * s..(i + 1) * s]) {
                    *r |= *aij > 0.0;
                }
            }
        }
        predict(h, a, &mut self.pred_next);
        let exact = self
            .reach_next
            .iter()
            .zip(&self.pred_next)
            .all(|(r, p)| !*r || *p >= SAFE);
        if exact {
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
                self.log_pred[j] = if self.reach_next[j] {
                    for i in 0..s {
                        self.terms[i] = self.log_h[i] + la[i * s + j];
                    }
                    log_sum_exp(&self.terms)
                } else {
                    f64::NEG_INFINITY
                };
            }
            self.log_mode = true;
        }
        std::mem::swap(&mut self.reachable, &mut self.reach_next);
        lc
    }
}

/// Subtracts the log-sum-exp of `row` from every entry (if it is finite).
fn shift_to_zero(row: &mut [f64]) {
    let z = log_sum_exp(row);
    if z.is_finite() {
        row.iter_mut().for_each(|v| *v -= z);
    }
}

/// `pred_j = Σ_i h_i a_ij`.
#[inline]
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

    /// Per-frame normalised backward pass combined with the filtered forward
    /// variable. `None` when linear arithmetic would not be exact (a state
    /// that carries backward mass gets less than `SAFE`, or the forward and
    /// backward messages barely overlap); then the log-space form is used.
    fn scaled_backward_posteriors(
        &self,
        fwd: &Forward,
        log_b: &[f64],
        gamma: &mut [f64],
    ) -> Option<Vec<f64>> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let a = &self.transition;
        let h = &fwd.filtered;
        let mut xi = vec![0.0; s * s];
        // beta: normalised backward variable of frame t+1 (then t); alive: where it
        // is exactly positive; u: b_j(x_{t+1}) β_{t+1}(j), normalised.
        let mut beta = vec![1.0 / s as f64; s];
        let mut alive = vec![true; s];
        let mut alive_next = vec![false; s];
        let mut next = vec![0.0; s];
        let mut u = vec![0.0; s];
        let last = (t_len - 1) * s;
        let z: f64 = h[last..].iter().zip(&beta).map(|(x, y)| x * y).sum();
        for i in 0..s {
            gamma[last + i] = h[last + i] * beta[i] / z;
        }
        for t in (0..t_len - 1).rev() {
            let lb = &log_b[(t + 1) * s..(t + 2) * s];
            let carries = |j: usize| alive[j] && lb[j] > f64::NEG_INFINITY;
            let mut m = f64::NEG_INFINITY;
            for j in 0..s {
                if carries(j) {
                    m = m.max(lb[j]);
                }
            }
            if m == f64::NEG_INFINITY {
                return None;
            }
            let fill = |m: f64, u: &mut [f64]| -> f64 {
                let mut total = 0.0;
                for j in 0..s {
                    u[j] = if carries(j) {
                        (lb[j] - m).exp() * beta[j]
                    } else {
                        0.0
                    };
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
            let mut total = 0.0;
            for i in 0..s {
                let row = &a[i * s..(i + 1) * s];
                next[i] = row.iter().zip(&u).map(|(x, y)| x * y).sum();
                alive_next[i] = (0..s).any(|j| row[j] > 0.0 && carries(j));
                if alive_next[i] && !(next[i] >= SAFE) {
                    return None;
                }
                total += next[i];
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
                for j in 0..s {
                    xi[i * s + j] += hi * a[i * s + j] * u[j];
                }
            }
            for i in 0..s {
                gamma[t * s + i] = ht[i] * next[i] * inv;
                beta[i] = next[i] / total;
            }
            std::mem::swap(&mut alive, &mut alive_next);
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
            for i in 0..s {
                gamma[t * s + i] = (row[i] - z).exp();
            }
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
            for (x, v) in xi.iter_mut().zip(&terms) {
                *x += (v - z).exp();
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
