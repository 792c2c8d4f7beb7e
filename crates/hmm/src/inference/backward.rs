//! The backward recursion in scaled form: [`super::formulas::backward_variable`]
//! carried as the normalised message `β̂_t = β_t / Σ_i β_t(i)`.
//!
//! One step back takes `β̂_{t+1}` and the densities of frame `t + 1` to
//! `u_j ∝ b_j(x_{t+1}) β̂_{t+1}(j)` (shifted by `m = max_j log b_j(x_{t+1})`
//! and normalised to `Σ_j u_j = 1`) and `next_i = Σ_j a_ij u_j ∝ β_t(i)`,
//! then `β̂_t = next / Σ_i next_i`. The posteriors
//! ([`super::posteriors`]) need `u` and `next` of every frame, so the step
//! writes them out.
//!
//! As in the forward recursion ([`super::forward`]), linear arithmetic is
//! used while every state that can still explain the rest of the sequence
//! holds at least [`SAFE`] of the message; otherwise the message is carried in
//! log form, and only the entries whose linear value fell below [`SAFE`] are
//! recomputed by log-sum-exp. The fast form of the step (linear mode, every
//! state alive and every `a_ij > 0`, every density positive, no re-scaling,
//! every next entry at least [`SAFE`]) skips the per-state bookkeeping and
//! does, on such a frame, the same arithmetic as the general form.
//!
//! The backward recursion does not depend on the forward one, so the two are
//! run interleaved, frame `k` forward and frame `T − 2 − k` backward in the
//! same loop: two independent dependency chains that the CPU overlaps.

use super::kernels::{
    all_at_least, chunks, exp_shifted, padded, padded_rows, scale_lanes, sum_lanes, vec_mat,
    vec_mat_dyn, vec_mat_into, Lanes, RESCALE, SAFE, W,
};
use crate::model::Hmm;
use phasekit_emission::linalg::{exp_slice, log_sum_exp};
use phasekit_emission::Emission;

/// The backward recursion between two frames (see the module documentation).
/// Per-state vectors are padded chunks, as in [`super::forward::ForwardCore`].
#[derive(Debug, Clone)]
pub(crate) struct BackwardCore {
    s: usize,
    /// `A` row-major (for the structural checks), the rows of `Aᵀ` padded
    /// (so that `A u` is a sequence of fused multiply-adds over chunks) and
    /// `log A`, row-major.
    transition: Vec<f64>,
    transition_t: Vec<Lanes>,
    log_transition: Vec<f64>,
    /// `SAFE` on the lanes of real states, 0 on the padding.
    floor: Vec<Lanes>,
    /// Every `a_ij > 0`.
    dense: bool,
    /// `β̂_{t+1}`, linear (valid when `!log_mode`, zero padding) and log (when `log_mode`).
    beta: Vec<Lanes>,
    log_beta: Vec<f64>,
    /// Where `β_{t+1}` is exactly positive.
    alive: Vec<bool>,
    all_alive: bool,
    log_mode: bool,
    /// Frames that took the fast form and the general form (diagnostics:
    /// tests check that the fast form runs, `Hmm::step_counts` reports them).
    pub(crate) fast_steps: usize,
    pub(crate) general_steps: usize,
    // Scratch.
    carry: Vec<bool>,
    w: Vec<f64>,
    terms: Vec<f64>,
    odd: Vec<Lanes>,
}

impl BackwardCore {
    /// The recursion of `hmm` after the last frame (`β_{T−1} = 1`).
    pub(crate) fn new<E: Emission>(hmm: &Hmm<E>) -> Self {
        let s = hmm.n_states();
        let c = chunks(s);
        let a = &hmm.transition;
        let a_t: Vec<f64> = (0..s * s).map(|k| a[(k % s) * s + k / s]).collect();
        let mut floor = vec![[0.0; W]; c];
        padded(&vec![SAFE; s], 0.0, &mut floor);
        let mut core = BackwardCore {
            s,
            transition: a.clone(),
            transition_t: padded_rows(&a_t, s),
            log_transition: hmm.log_transition.clone(),
            floor,
            dense: a.iter().all(|v| *v > 0.0),
            beta: vec![[0.0; W]; c],
            log_beta: vec![0.0; s],
            alive: vec![true; s],
            all_alive: true,
            log_mode: false,
            fast_steps: 0,
            general_steps: 0,
            carry: vec![false; s],
            w: vec![f64::NEG_INFINITY; s],
            terms: vec![0.0; s],
            odd: vec![[0.0; W]; c],
        };
        core.reset();
        core
    }

    /// Back to `β̂_{T−1} = 1/S` (before the first step back).
    pub(crate) fn reset(&mut self) {
        let s = self.s;
        padded(&vec![1.0 / s as f64; s], 0.0, &mut self.beta);
        self.log_beta.fill(0.0);
        self.alive.fill(true);
        self.all_alive = true;
        self.log_mode = false;
    }

    /// One step back from frame `t + 1` (padded log-densities `log_b`):
    /// writes the padded `u` and `next` (see the module documentation) and
    /// carries `β̂_t`. Returns false when no state can explain the frames from
    /// `t + 1` on (the sequence is impossible).
    ///
    /// The frame's shifted densities come computed: `shifted = e^{log b − m}`
    /// with `m` = [`super::kernels::fast_shift`]`(log_b)` (NaN when the frame cannot take the
    /// fast form), as the forward step's
    /// ([`super::forward::ForwardCore::step_shifted_inline`]); the caller, which
    /// has every frame at once, takes all their exponentials in one pass and
    /// both recursions use them.
    #[inline(always)]
    pub(crate) fn step_shifted_inline(
        &mut self,
        log_b: &[Lanes],
        shifted: &[Lanes],
        m: f64,
        u: &mut [Lanes],
        next: &mut [Lanes],
    ) -> bool {
        if !self.log_mode && self.all_alive && self.dense && !m.is_nan() {
            u.copy_from_slice(shifted);
            let fast = match self.beta.len() {
                1 => self.fast_rest::<1>(u, next),
                2 => self.fast_rest::<2>(u, next),
                3 => self.fast_rest::<3>(u, next),
                4 => self.fast_rest::<4>(u, next),
                _ => self.fast_dyn_rest(u, next),
            };
            if fast {
                self.fast_steps += 1;
                return true;
            }
        }
        self.general_steps += 1;
        self.general_step(log_b, u, next)
    }

    /// The common frame without bookkeeping from `u = e^{log b − m}`, with `C`
    /// chunks in registers; false (nothing changed but `u` and `next`) when
    /// one of its conditions fails (then the general step redoes the frame).
    #[inline(always)]
    fn fast_rest<const C: usize>(&mut self, u: &mut [Lanes], next: &mut [Lanes]) -> bool {
        let u: &mut [Lanes; C] = u.try_into().expect("C chunks");
        let next: &mut [Lanes; C] = next.try_into().expect("C chunks");
        let beta: &[Lanes; C] = self.beta.as_slice().try_into().expect("C chunks");
        for (uk, bk) in u.iter_mut().zip(beta) {
            for l in 0..W {
                uk[l] *= bk[l];
            }
        }
        let total = sum_lanes(u);
        if total.is_nan() || total < RESCALE {
            return false;
        }
        let inv = 1.0 / total;
        scale_lanes(u, inv);
        *next = vec_mat::<C>(&u.as_flattened()[..self.s], &self.transition_t);
        if !all_at_least(next, &self.floor) {
            return false;
        }
        let inv = 1.0 / sum_lanes(next);
        for (bk, nk) in self.beta.iter_mut().zip(next.iter()) {
            for l in 0..W {
                bk[l] = nk[l] * inv;
            }
        }
        true
    }

    /// [`BackwardCore::fast_rest`] for more than four chunks (through memory).
    #[inline(always)]
    fn fast_dyn_rest(&mut self, u: &mut [Lanes], next: &mut [Lanes]) -> bool {
        for (uk, bk) in u.iter_mut().zip(&self.beta) {
            for l in 0..W {
                uk[l] *= bk[l];
            }
        }
        let total = sum_lanes(u);
        if total.is_nan() || total < RESCALE {
            return false;
        }
        let inv = 1.0 / total;
        scale_lanes(u, inv);
        vec_mat_dyn(
            &u.as_flattened()[..self.s],
            &self.transition_t,
            next,
            &mut self.odd,
        );
        if !all_at_least(next, &self.floor) {
            return false;
        }
        let inv = 1.0 / sum_lanes(next);
        for (bk, nk) in self.beta.iter_mut().zip(next.iter()) {
            for l in 0..W {
                bk[l] = nk[l] * inv;
            }
        }
        true
    }

    /// `u_j = e^{log b_j − m} β̂_j` over the carrying states (0 elsewhere and
    /// on the padding), one vectorised pass of exponentials; returns `Σ_j u_j`.
    #[inline(always)]
    fn fill(&self, log_b: &[Lanes], m: f64, u: &mut [Lanes]) -> f64 {
        exp_shifted(log_b, m, u);
        let beta = self.beta.as_flattened();
        for (j, uj) in u.as_flattened_mut().iter_mut().enumerate() {
            *uj = if j < self.s && self.carry[j] {
                *uj * beta[j]
            } else {
                0.0
            };
        }
        sum_lanes(u)
    }

    /// Every rule of the module documentation, state by state.
    // `j` indexes several per-state arrays (densities, reachability, predictions) at once.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn general_step(
        &mut self,
        log_b_padded: &[Lanes],
        u_padded: &mut [Lanes],
        next_padded: &mut [Lanes],
    ) -> bool {
        let s = self.s;
        let log_b = &log_b_padded.as_flattened()[..s];
        let mut any = false;
        for j in 0..s {
            self.carry[j] = self.alive[j] && log_b[j] > f64::NEG_INFINITY;
            any |= self.carry[j];
        }
        if !any {
            return false;
        }
        // u_j = e^{w_j}, w_j = log b_j + log β̂_j − shift.
        let mut shift = 0.0;
        if self.log_mode {
            let mut m = f64::NEG_INFINITY;
            for j in 0..s {
                self.w[j] = if self.carry[j] {
                    log_b[j] + self.log_beta[j]
                } else {
                    f64::NEG_INFINITY
                };
                m = m.max(self.w[j]);
            }
            self.w.iter_mut().for_each(|v| *v -= m);
            u_padded.fill([0.0; W]);
            let u = &mut u_padded.as_flattened_mut()[..s];
            u.copy_from_slice(&self.w);
            exp_slice(u);
        } else {
            let mut m = f64::NEG_INFINITY;
            for j in 0..s {
                if self.carry[j] {
                    m = m.max(log_b[j]);
                }
            }
            // Every carrying state has β̂ ≥ SAFE / S, so the sum is positive.
            let mut total = self.fill(log_b_padded, m, u_padded);
            if total < RESCALE {
                m += total.ln();
                total = self.fill(log_b_padded, m, u_padded);
            }
            let inv = 1.0 / total;
            for v in u_padded.as_flattened_mut() {
                *v *= inv;
            }
            // `w` is only needed if some entry turns out inexact (below).
            shift = m + total.ln();
        }
        let u = &u_padded.as_flattened()[..s];
        vec_mat_into(u, &self.transition_t, next_padded, &mut self.odd);
        let next = &next_padded.as_flattened()[..s];
        // β_t: linear if every structurally positive entry is ≥ SAFE.
        let a = &self.transition;
        let mut any_inexact = false;
        for i in 0..s {
            if next[i] >= SAFE {
                self.alive[i] = true;
            } else {
                let mut r = false;
                for j in 0..s {
                    r |= self.carry[j] && a[i * s + j] > 0.0;
                }
                self.alive[i] = r;
                any_inexact |= r;
            }
        }
        if !any_inexact {
            let inv = 1.0 / sum_lanes(next_padded);
            for (bk, nk) in self.beta.iter_mut().zip(next_padded.iter()) {
                for l in 0..W {
                    bk[l] = nk[l] * inv;
                }
            }
            self.log_mode = false;
        } else {
            if !self.log_mode {
                // Exact: every carrying state had β̂_j ≥ SAFE / S.
                let beta = self.beta.as_flattened();
                for j in 0..s {
                    self.w[j] = if self.carry[j] {
                        log_b[j] + beta[j].ln() - shift
                    } else {
                        f64::NEG_INFINITY
                    };
                }
            }
            let la = &self.log_transition;
            for i in 0..s {
                self.log_beta[i] = if !self.alive[i] {
                    f64::NEG_INFINITY
                } else if next[i] >= SAFE {
                    next[i].ln()
                } else {
                    for j in 0..s {
                        self.terms[j] = la[i * s + j] + self.w[j];
                    }
                    log_sum_exp(&self.terms)
                };
            }
            self.log_mode = true;
        }
        self.all_alive = self.alive.iter().all(|v| *v);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inference::forward::tests::random_case;
    use crate::inference::kernels::{fast_shift, shifted_arguments, PAD_LOG_B};

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The fast form where it applies and the general form everywhere give
    /// the same `u`, `next` and message, frame by frame.
    #[test]
    fn the_fast_step_is_the_general_step_where_it_applies() {
        let mut fast_total = 0;
        for seed in 0..240 {
            let s = 1 + (seed as usize % 40);
            let c = chunks(s);
            let (hmm, log_b) = random_case(seed, s, 120, seed % 3 == 0);
            let mut a = BackwardCore::new(&hmm);
            let mut b = a.clone();
            let z = vec![[0.0; W]; c];
            let (mut ua, mut ub, mut na, mut nb) = (z.clone(), z.clone(), z.clone(), z.clone());
            let (mut row, mut e) = (z.clone(), z.clone());
            for (t, lb) in log_b.chunks_exact(s).enumerate().rev() {
                padded(lb, PAD_LOG_B, &mut row);
                let m = fast_shift(&row);
                shifted_arguments(&row, m, &mut e);
                exp_slice(e.as_flattened_mut());
                let oka = a.step_shifted_inline(&row, &e, m, &mut ua, &mut na);
                let okb = b.general_step(&row, &mut ub, &mut nb);
                assert_eq!(oka, okb, "seed {seed}, frame {t}");
                if !okb {
                    break;
                }
                assert_eq!(
                    bits(ua.as_flattened()),
                    bits(ub.as_flattened()),
                    "seed {seed}, frame {t}"
                );
                assert_eq!(
                    bits(na.as_flattened()),
                    bits(nb.as_flattened()),
                    "seed {seed}, frame {t}"
                );
                assert_eq!(a.log_mode, b.log_mode);
                assert_eq!(a.alive, b.alive);
                if a.log_mode {
                    assert_eq!(bits(&a.log_beta), bits(&b.log_beta));
                } else {
                    assert_eq!(bits(a.beta.as_flattened()), bits(b.beta.as_flattened()));
                }
            }
            fast_total += a.fast_steps;
        }
        assert!(
            fast_total > 8000,
            "the fast form ran on {fast_total} frames only"
        );
    }
}
