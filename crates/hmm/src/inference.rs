//! Forward, backward, posteriors and Viterbi for one sequence.
//!
//! The forward pass keeps the filtered distribution `h_t(i) = p(z_t = i | x_{1:t})`
//! and the log normaliser `log c_t = log p(x_t | x_{1:t−1})`, so that
//! `log α_t(i) = log h_t(i) + Σ_{s ≤ t} log c_s` and `log p(x_{1:T}) = Σ_t log c_t`.
//! Each step shifts the emission log-densities by their maximum before
//! exponentiating, so densities far below `e^{−745}` (36-dimensional Gaussians)
//! never underflow; if a step still underflows it is redone in log space. The
//! backward pass is normalised per frame likewise and falls back to a log-space
//! pass for the whole sequence if it ever underflows. Forbidden transitions
//! (`a_ij = 0`) give `−inf`, never NaN.

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
    pub fn log_alpha(&self) -> Vec<f64> {
        let s = self.n_states;
        let mut acc = 0.0;
        let mut out = Vec::with_capacity(self.filtered.len());
        for (row, lc) in self.filtered.chunks_exact(s).zip(&self.log_normalisers) {
            acc += lc;
            out.extend(row.iter().map(|h| if *h > 0.0 { h.ln() + acc } else { f64::NEG_INFINITY }));
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

/// One filtering step: `h_j ∝ pred_j b_j(x)` from the predicted distribution
/// `pred` and the log-densities `log_b`. Returns `log Σ_j pred_j b_j(x)`
/// (`−inf`, with `out` all zero, when the frame is impossible).
#[inline]
pub(crate) fn filter_step(pred: &[f64], log_b: &[f64], out: &mut [f64]) -> f64 {
    let m = log_b.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        out.fill(0.0);
        return f64::NEG_INFINITY;
    }
    let mut c = 0.0;
    for ((o, p), lb) in out.iter_mut().zip(pred).zip(log_b) {
        *o = p * (lb - m).exp();
        c += *o;
    }
    if c > 0.0 && c.is_finite() && c >= f64::MIN_POSITIVE * 1e6 {
        let inv = 1.0 / c;
        out.iter_mut().for_each(|o| *o *= inv);
        return m + c.ln();
    }
    // The predicted mass sits where the densities are negligible: redo the frame in log space.
    for ((o, p), lb) in out.iter_mut().zip(pred).zip(log_b) {
        *o = if *p > 0.0 { p.ln() + lb } else { f64::NEG_INFINITY };
    }
    let lse = log_sum_exp(out);
    if lse == f64::NEG_INFINITY {
        out.fill(0.0);
        return lse;
    }
    out.iter_mut().for_each(|o| *o = (*o - lse).exp());
    lse
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
        let mut pred = self.start.clone();
        for t in 0..t_len {
            if t > 0 {
                let (prev, _) = filtered.split_at(t * s);
                predict(&prev[(t - 1) * s..], &self.transition, &mut pred);
            }
            let lc = filter_step(&pred, &log_b[t * s..(t + 1) * s], &mut filtered[t * s..(t + 1) * s]);
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
        Ok(self.log_backward(&log_b))
    }

    /// Log-space backward pass (reference form; `S²` exponentials per frame).
    fn log_backward(&self, log_b: &[f64]) -> Vec<f64> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let mut lb = vec![0.0; log_b.len()];
        let mut terms = vec![0.0; s];
        for t in (0..t_len.saturating_sub(1)).rev() {
            for i in 0..s {
                for j in 0..s {
                    terms[j] = self.log_transition[i * s + j] + log_b[(t + 1) * s + j] + lb[(t + 1) * s + j];
                }
                lb[t * s + i] = log_sum_exp(&terms);
            }
        }
        lb
    }

    /// Log-space forward pass (reference form), `T × S` log α.
    fn log_forward(&self, log_b: &[f64]) -> Vec<f64> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let mut la = vec![0.0; log_b.len()];
        let mut terms = vec![0.0; s];
        for j in 0..s {
            la[j] = self.log_start[j] + log_b[j];
        }
        for t in 1..t_len {
            for j in 0..s {
                for i in 0..s {
                    terms[i] = la[(t - 1) * s + i] + self.log_transition[i * s + j];
                }
                la[t * s + j] = log_sum_exp(&terms) + log_b[t * s + j];
            }
        }
        la
    }

    /// Posteriors `γ`, expected transitions and log-likelihood from log-densities,
    /// written into `gamma` (`T × S`); returns the expected transitions and `log p`.
    pub(crate) fn posteriors_into(&self, log_b: &[f64], gamma: &mut [f64]) -> Result<(Vec<f64>, f64)> {
        let fwd = self.forward_from(log_b);
        let ll = fwd.log_likelihood();
        if ll == f64::NEG_INFINITY {
            let frame = fwd.log_normalisers.iter().position(|v| *v == f64::NEG_INFINITY).unwrap_or(0);
            return Err(HmmError::ImpossibleSequence { sequence: 0, frame });
        }
        if let Some(xi) = self.scaled_backward_posteriors(&fwd, log_b, gamma) {
            return Ok((xi, ll));
        }
        Ok((self.log_space_posteriors(log_b, gamma), ll))
    }

    /// Per-frame normalised backward pass combined with the filtered forward
    /// variable. `None` if it underflows (then the log-space form is used).
    fn scaled_backward_posteriors(&self, fwd: &Forward, log_b: &[f64], gamma: &mut [f64]) -> Option<Vec<f64>> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let a = &self.transition;
        let h = &fwd.filtered;
        let mut xi = vec![0.0; s * s];
        // beta: normalised backward variable of frame t+1 (then t); e: shifted densities of frame t+1.
        let mut beta = vec![1.0 / s as f64; s];
        let mut next = vec![0.0; s];
        let mut eb = vec![0.0; s];
        let last = (t_len - 1) * s;
        let z: f64 = h[last..].iter().zip(&beta).map(|(x, y)| x * y).sum();
        for i in 0..s {
            gamma[last + i] = h[last + i] * beta[i] / z;
        }
        for t in (0..t_len - 1).rev() {
            let lb = &log_b[(t + 1) * s..(t + 2) * s];
            let m = lb.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            for j in 0..s {
                eb[j] = (lb[j] - m).exp() * beta[j];
            }
            let ht = &h[t * s..(t + 1) * s];
            let mut total = 0.0;
            for i in 0..s {
                let row = &a[i * s..(i + 1) * s];
                let r: f64 = row.iter().zip(&eb).map(|(x, y)| x * y).sum();
                next[i] = r;
                total += r;
            }
            if !(total > 0.0 && total.is_finite()) {
                return None;
            }
            // ξ_t(i,j) ∝ h_t(i) a_ij e_j β_{t+1}(j); its normaliser is Σ_i h_t(i) r_i.
            let zx: f64 = ht.iter().zip(&next).map(|(x, y)| x * y).sum();
            if !(zx > 0.0 && zx.is_finite()) {
                return None;
            }
            let inv = 1.0 / zx;
            for i in 0..s {
                let hi = ht[i] * inv;
                if hi == 0.0 {
                    continue;
                }
                for j in 0..s {
                    xi[i * s + j] += hi * a[i * s + j] * eb[j];
                }
            }
            for i in 0..s {
                gamma[t * s + i] = ht[i] * next[i] * inv;
                beta[i] = next[i] / total;
            }
        }
        Some(xi)
    }

    /// Log-space posteriors (used when the scaled pass underflows).
    fn log_space_posteriors(&self, log_b: &[f64], gamma: &mut [f64]) -> Vec<f64> {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let la = self.log_forward(log_b);
        let lb = self.log_backward(log_b);
        let ll = log_sum_exp(&la[(t_len - 1) * s..]);
        for k in 0..la.len() {
            gamma[k] = (la[k] + lb[k] - ll).exp();
        }
        let mut xi = vec![0.0; s * s];
        for t in 0..t_len - 1 {
            for i in 0..s {
                for j in 0..s {
                    let v = la[t * s + i] + self.log_transition[i * s + j] + log_b[(t + 1) * s + j] + lb[(t + 1) * s + j] - ll;
                    xi[i * s + j] += v.exp();
                }
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
