//! State posteriors `γ` and expected transitions `Σ_t ξ_t` of one sequence:
//! [`super::formulas::state_posteriors`] and
//! [`super::formulas::expected_transitions`] from the scaled recursions.
//!
//! With the filtered `h_t` of the forward recursion and `u_{t+1}`,
//! `next_t ∝ β_t` of the backward recursion (each up to a factor per frame):
//!
//! * `γ_t(i) = h_t(i) next_t(i) / z_t` with `z_t = Σ_i h_t(i) next_t(i)`, and
//!   `γ_{T−1} = h_{T−1}`;
//! * `ξ_t(i, j) = h_t(i) a_ij u_{t+1}(j) / z_t`, so that
//!   `Σ_t ξ_t(i, j) = a_ij Σ_t (h_t(i) / z_t) u_{t+1}(j)`: an `S × S` sum of
//!   outer products over the frames, multiplied by `a_ij` once.
//!
//! `z_t` is the overlap of the two messages; when it is below
//! [`SAFE`](super::kernels::SAFE) the scaled form would lose precision, and
//! the whole sequence is computed in log space instead, with every frame's
//! messages normalised ([`log_space_posteriors`]).

use super::backward::BackwardCore;
use super::forward::ForwardCore;
use super::kernels::{chunks, dot_lanes, shifted_rows, Lanes, SAFE, W};
use crate::error::{HmmError, Result};
use crate::model::Hmm;
use phasekit_emission::linalg::{dispatch, exp_slice, log_sum_exp};
use phasekit_emission::Emission;

/// Buffers for the posteriors of sequences under one model, reused from one
/// sequence to the next (no allocation per sequence once they have grown).
#[derive(Debug, Clone)]
pub(crate) struct PosteriorWorkspace {
    s: usize,
    c: usize,
    forward: ForwardCore,
    backward: BackwardCore,
    transition: Vec<f64>,
    log_start: Vec<f64>,
    log_transition: Vec<f64>,
    /// `log b_j(x_t)`, `T × S`: filled by the caller before [`Self::run`].
    pub(crate) log_b: Vec<f64>,
    /// `γ_t(i)`, `T × S` (after [`Self::run`]).
    pub(crate) gamma: Vec<f64>,
    /// `Σ_t ξ_t(i, j)`, `S × S` (after [`Self::run`]).
    pub(crate) xi: Vec<f64>,
    /// The padded rows (`T × C` chunks) of `log b`, of the filtered `h_t`,
    /// of `u_t` (row `t ≥ 1`), and of `next_t`, then `h_t / z_t`.
    log_b_padded: Vec<Lanes>,
    h: Vec<Lanes>,
    u: Vec<Lanes>,
    next: Vec<Lanes>,
    /// `e^{log b_t − m_t}` (padded rows) and `m_t = max_j log b_t(j)`, or
    /// NaN where frame `t` cannot take the fast form of the steps: taken for
    /// every frame in one pass before the recursions, which then use them
    /// twice (the forward step at `t`, the backward step at `t − 1`).
    shifted: Vec<Lanes>,
    shift: Vec<f64>,
    /// `log c_t`.
    lc: Vec<f64>,
}

impl PosteriorWorkspace {
    /// Empty buffers for `hmm`.
    pub(crate) fn new<E: Emission>(hmm: &Hmm<E>) -> Self {
        let s = hmm.n_states();
        PosteriorWorkspace {
            s,
            c: chunks(s),
            forward: ForwardCore::new(hmm),
            backward: BackwardCore::new(hmm),
            transition: hmm.transition.clone(),
            log_start: hmm.log_start.clone(),
            log_transition: hmm.log_transition.clone(),
            log_b: Vec::new(),
            gamma: Vec::new(),
            xi: vec![0.0; s * s],
            log_b_padded: Vec::new(),
            h: Vec::new(),
            u: Vec::new(),
            next: Vec::new(),
            shifted: Vec::new(),
            shift: Vec::new(),
            lc: Vec::new(),
        }
    }

    /// Steps of the forward and backward recursions so far, in their fast
    /// and general forms: `[forward fast, forward general, backward fast,
    /// backward general]`.
    pub(crate) fn step_counts(&self) -> [usize; 4] {
        [
            self.forward.fast_steps,
            self.forward.general_steps,
            self.backward.fast_steps,
            self.backward.general_steps,
        ]
    }

    /// Sizes the buffers for `t_len` frames and returns `log_b` to fill.
    pub(crate) fn log_b_for(&mut self, t_len: usize) -> &mut [f64] {
        self.log_b.resize(t_len * self.s, 0.0);
        self.gamma.resize(t_len * self.s, 0.0);
        for v in [
            &mut self.log_b_padded,
            &mut self.h,
            &mut self.u,
            &mut self.next,
            &mut self.shifted,
        ] {
            v.resize(t_len * self.c, [0.0; W]);
        }
        self.shift.resize(t_len, 0.0);
        self.lc.resize(t_len, 0.0);
        &mut self.log_b
    }

    /// `γ` into `self.gamma`, `Σ_t ξ_t` into `self.xi` and `log p(x)` from
    /// `self.log_b` (at least one frame). Errors, naming the first frame no
    /// state can explain, when the sequence is impossible.
    pub(crate) fn run(&mut self) -> Result<f64> {
        dispatch(
            #[inline(always)]
            || self.run_inline(),
        )
    }

    #[inline(always)]
    fn run_inline(&mut self) -> Result<f64> {
        let (s, c) = (self.s, self.c);
        let t_len = self.lc.len();
        debug_assert!(t_len > 0 && self.log_b.len() == t_len * s);
        shifted_rows(
            &self.log_b,
            s,
            self.forward.can_step_fast(),
            &mut self.log_b_padded,
            &mut self.shifted,
            &mut self.shift,
        );
        self.forward.reset();
        self.backward.reset();
        let mut backward_ok = true;
        // Frame k forward and frame T − 2 − k backward: two independent chains.
        for k in 0..t_len {
            let row = k * c..(k + 1) * c;
            self.lc[k] = self.forward.step_shifted_inline(
                &self.log_b_padded[row.clone()],
                &self.shifted[row.clone()],
                self.shift[k],
                &mut self.h[row],
            );
            if k + 1 < t_len {
                let t = t_len - 2 - k;
                let next_rows = (t + 1) * c..(t + 2) * c;
                backward_ok &= self.backward.step_shifted_inline(
                    &self.log_b_padded[next_rows.clone()],
                    &self.shifted[next_rows.clone()],
                    self.shift[t + 1],
                    &mut self.u[next_rows],
                    &mut self.next[t * c..(t + 1) * c],
                );
            }
        }
        if let Some(frame) = self.lc.iter().position(|v| *v == f64::NEG_INFINITY) {
            return Err(HmmError::ImpossibleSequence { sequence: 0, frame });
        }
        let ll: f64 = self.lc.iter().sum();
        let scaled = backward_ok
            && match c {
                1 => self.scaled_posteriors::<1>(),
                2 => self.scaled_posteriors::<2>(),
                3 => self.scaled_posteriors::<3>(),
                4 => self.scaled_posteriors::<4>(),
                _ => self.scaled_posteriors::<0>(),
            };
        if !scaled {
            self.xi = log_space_posteriors(
                &self.log_start,
                &self.log_transition,
                &self.log_b,
                &mut self.gamma,
            );
        }
        Ok(ll)
    }

    /// `γ` and `Σ ξ` from the stored messages (`C` chunks known at compile
    /// time, or `C = 0` for any number); false when some overlap `z_t` is
    /// below [`SAFE`] (then the log-space form is needed).
    #[inline(always)]
    fn scaled_posteriors<const C: usize>(&mut self) -> bool {
        let (s, c) = (self.s, self.c);
        let t_len = self.lc.len();
        for t in 0..t_len - 1 {
            let rows = t * c..(t + 1) * c;
            let (ht, nt) = (&self.h[rows.clone()], &mut self.next[rows]);
            let z = dot_lanes(ht, nt);
            if z.is_nan() || z < SAFE || z == f64::INFINITY {
                return false;
            }
            let inv = 1.0 / z;
            let g = &mut self.gamma[t * s..(t + 1) * s];
            for ((gj, hj), nj) in g.iter_mut().zip(ht.as_flattened()).zip(nt.as_flattened()) {
                *gj = (hj * inv) * nj;
            }
            // `next_t` is not needed any more: keep `h_t / z_t` for ξ.
            for (hk, nk) in ht.iter().zip(nt.iter_mut()) {
                for l in 0..W {
                    nk[l] = hk[l] * inv;
                }
            }
        }
        let last = (t_len - 1) * c;
        self.gamma[(t_len - 1) * s..].copy_from_slice(&self.h[last..last + c].as_flattened()[..s]);
        // Σ_t ξ_t(i, j) = a_ij Σ_{t < T−1} (h_t(i) / z_t) u_{t+1}(j): one row
        // `i` at a time, the sum over t by fused multiply-adds in increasing t.
        // With `C` known, two rows go together: each row's `C` chains alone
        // wait on the latency of the fused multiply-add (4 cycles on current
        // cores), two rows keep twice as many in flight and share the loads
        // of `u_{t+1}`; every entry's chain is the same, so are its bits.
        let hs = &self.next[..(t_len - 1) * c];
        let us = &self.u[c..];
        let mut acc = vec![[0.0; W]; if C == 0 { c } else { 0 }];
        let mut i = 0;
        while i < s {
            let a = &self.transition[i * s..];
            if C == 0 {
                let (k, l) = (i / W, i % W);
                acc.fill([0.0; W]);
                for (r, ut) in hs.chunks_exact(c).zip(us.chunks_exact(c)) {
                    let x = r[k][l];
                    for (ak, uk) in acc.iter_mut().zip(ut) {
                        for q in 0..W {
                            ak[q] = x.mul_add(uk[q], ak[q]);
                        }
                    }
                }
                let xi = &mut self.xi[i * s..(i + 1) * s];
                for ((x, m), a) in xi.iter_mut().zip(acc.as_flattened()).zip(a) {
                    *x = a * m;
                }
                i += 1;
            } else if i + 1 < s {
                let ((k0, l0), (k1, l1)) = ((i / W, i % W), ((i + 1) / W, (i + 1) % W));
                let mut f0 = [[0.0; W]; C];
                let mut f1 = [[0.0; W]; C];
                for (r, ut) in hs.chunks_exact(c).zip(us.chunks_exact(c)) {
                    let (x0, x1) = (r[k0][l0], r[k1][l1]);
                    let ut: &[Lanes; C] = ut.try_into().expect("C chunks");
                    for k in 0..C {
                        for q in 0..W {
                            f0[k][q] = x0.mul_add(ut[k][q], f0[k][q]);
                            f1[k][q] = x1.mul_add(ut[k][q], f1[k][q]);
                        }
                    }
                }
                let xi = &mut self.xi[i * s..(i + 2) * s];
                let (x0, x1) = xi.split_at_mut(s);
                for ((x, m), a) in x0.iter_mut().zip(f0.as_flattened()).zip(&a[..s]) {
                    *x = a * m;
                }
                for ((x, m), a) in x1.iter_mut().zip(f1.as_flattened()).zip(&a[s..2 * s]) {
                    *x = a * m;
                }
                i += 2;
            } else {
                let (k, l) = (i / W, i % W);
                let mut fixed = [[0.0; W]; C];
                for (r, ut) in hs.chunks_exact(c).zip(us.chunks_exact(c)) {
                    let x = r[k][l];
                    let ut: &[Lanes; C] = ut.try_into().expect("C chunks");
                    for (ak, uk) in fixed.iter_mut().zip(ut) {
                        for q in 0..W {
                            ak[q] = x.mul_add(uk[q], ak[q]);
                        }
                    }
                }
                let xi = &mut self.xi[i * s..(i + 1) * s];
                for ((x, m), a) in xi.iter_mut().zip(fixed.as_flattened()).zip(a) {
                    *x = a * m;
                }
                i += 1;
            }
        }
        true
    }
}

/// Subtracts the log-sum-exp of `row` from every entry (if it is finite).
fn shift_to_zero(row: &mut [f64]) {
    let z = log_sum_exp(row);
    if z.is_finite() {
        row.iter_mut().for_each(|v| *v -= z);
    }
}

/// `γ` (into `gamma`) and `Σ_t ξ_t` by the log-space recursions with every
/// frame's forward and backward messages normalised (so that long sequences
/// keep full precision): the exact form for sequences whose forward and
/// backward messages barely overlap. `O(T S²)` exponentials.
pub(crate) fn log_space_posteriors(
    log_start: &[f64],
    log_transition: &[f64],
    log_b: &[f64],
    gamma: &mut [f64],
) -> Vec<f64> {
    let s = log_start.len();
    let t_len = log_b.len() / s;
    let mut terms = vec![0.0; s * s];
    // log h_t (normalised forward messages).
    let mut la = vec![0.0; log_b.len()];
    for j in 0..s {
        la[j] = log_start[j] + log_b[j];
    }
    shift_to_zero(&mut la[..s]);
    for t in 1..t_len {
        for j in 0..s {
            for i in 0..s {
                terms[i] = la[(t - 1) * s + i] + log_transition[i * s + j];
            }
            la[t * s + j] = log_sum_exp(&terms[..s]) + log_b[t * s + j];
        }
        shift_to_zero(&mut la[t * s..(t + 1) * s]);
    }
    // Normalised backward messages.
    let mut lb = vec![0.0; log_b.len()];
    for t in (0..t_len.saturating_sub(1)).rev() {
        for i in 0..s {
            for j in 0..s {
                terms[j] = log_transition[i * s + j] + log_b[(t + 1) * s + j] + lb[(t + 1) * s + j];
            }
            lb[t * s + i] = log_sum_exp(&terms[..s]);
        }
        shift_to_zero(&mut lb[t * s..(t + 1) * s]);
    }
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
        exp_slice(g);
    }
    let mut xi = vec![0.0; s * s];
    for t in 0..t_len.saturating_sub(1) {
        for i in 0..s {
            for j in 0..s {
                terms[i * s + j] = la[t * s + i]
                    + log_transition[i * s + j]
                    + log_b[(t + 1) * s + j]
                    + lb[(t + 1) * s + j];
            }
        }
        let z = log_sum_exp(&terms);
        terms.iter_mut().for_each(|v| *v -= z);
        exp_slice(&mut terms);
        for (x, v) in xi.iter_mut().zip(&terms) {
            *x += v;
        }
    }
    xi
}
