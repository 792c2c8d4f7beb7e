//! Forward, backward, posteriors and Viterbi for one sequence.
//!
//! Where each formula lives:
//!
//! | formula | reference (log space, textbook) | fast path |
//! |---|---|---|
//! | forward variable `α_t(j)` | [`formulas::forward_variable`] | `forward`: the scaled filter `h_t`, `log c_t` ([`Hmm::forward`], the E-step, [`crate::ForwardFilter`]) |
//! | backward variable `β_t(i)` | [`formulas::backward_variable`] | `backward`: the normalised message `β̂_t`, run interleaved with the forward pass |
//! | state posteriors `γ_t(i)` | [`formulas::state_posteriors`] | `posteriors`: `h_t β̂_t / z_t` |
//! | expected transitions `Σ_t ξ_t(i, j)` | [`formulas::transition_posterior`], [`formulas::expected_transitions`] | `posteriors`: `a_ij Σ_t (h_t(i)/z_t) u_{t+1}(j)` |
//! | likelihood `log p(x)` | [`formulas::log_likelihood`] | `Σ_t log c_t` |
//! | Viterbi variable `δ_t(j)` | [`formulas::viterbi_variable`] | `viterbi` (the same recursion, vectorised over states) |
//! | M-step of `π` and `A` | [`formulas::start_update`], [`formulas::transition_update`] | the same functions ([`Hmm::maximise`]) |
//!
//! The fast paths stay exact for 10⁶ frames and densities far below `e^{−745}`
//! (each module says how); they are tested against the references
//! (`tests/hmm_formulas.rs`) and against the enumeration of every state path
//! (`tests/hmm_properties.rs`). Every fast path runs through
//! [`phasekit_emission::linalg::dispatch`] and gives the same bits with every
//! instruction set.

mod backward;
pub mod formulas;
mod forward;
mod interleaved;
mod kernels;
mod posteriors;
mod viterbi;

pub(crate) use forward::ForwardCore;
pub(crate) use interleaved::{LaneWorkspace, MAX_FRAMES as LANE_MAX_FRAMES};
pub(crate) use posteriors::PosteriorWorkspace;
pub use viterbi::ViterbiPath;

use crate::error::Result;
use crate::model::Hmm;
use phasekit_emission::linalg::dispatch;
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

    /// `log α_t(i) = log p(x_{1:t}, z_t = i)`, `T × S` row-major
    /// ([`formulas::forward_variable`]).
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
#[non_exhaustive]
pub struct Posteriors {
    /// `γ_t(i) = p(z_t = i | x_{1:T})`, `T × S` row-major.
    pub gamma: Vec<f64>,
    /// `Σ_t ξ_t(i, j) = Σ_t p(z_t = i, z_{t+1} = j | x_{1:T})`, `S × S` row-major.
    pub expected_transitions: Vec<f64>,
    /// `log p(x_{1:T})`.
    pub log_likelihood: f64,
}

/// A sequence's padded log-density rows with their shifted densities
/// ([`kernels::shifted_rows`]), [`ShiftedRows::BLOCK`] frames at a time (a
/// few kilobytes whatever the sequence's length), for the forward steps.
struct ShiftedRows {
    s: usize,
    c: usize,
    fast: bool,
    rows: Vec<kernels::Lanes>,
    shifted: Vec<kernels::Lanes>,
    shift: Vec<f64>,
}

impl ShiftedRows {
    /// Frames per block: long enough for the exponentials of a block to
    /// overlap, short enough to stay in L1 with the recursion's data.
    const BLOCK: usize = 64;

    fn new(core: &ForwardCore, s: usize) -> Self {
        let c = kernels::chunks(s);
        ShiftedRows {
            s,
            c,
            fast: core.can_step_fast(),
            rows: vec![[0.0; kernels::W]; Self::BLOCK * c],
            shifted: vec![[0.0; kernels::W]; Self::BLOCK * c],
            shift: vec![0.0; Self::BLOCK],
        }
    }

    /// The forward steps of every frame of `log_b` (`T × S`) in order:
    /// `each(t, log c_t, h_t)` after frame `t`'s step (the same bits as
    /// [`ForwardCore::step_row_inline`] on row `t`); stops after a frame for
    /// which `each` returns false. In the build of the caller.
    #[inline(always)]
    fn run(
        &mut self,
        core: &mut ForwardCore,
        log_b: &[f64],
        h: &mut [kernels::Lanes],
        mut each: impl FnMut(usize, f64, &[kernels::Lanes]) -> bool,
    ) {
        let (s, c) = (self.s, self.c);
        for (b, block) in log_b.chunks(Self::BLOCK * s).enumerate() {
            kernels::shifted_rows(
                block,
                s,
                self.fast,
                &mut self.rows,
                &mut self.shifted,
                &mut self.shift,
            );
            for k in 0..block.len() / s {
                let r = k * c..(k + 1) * c;
                let lc = core.step_shifted_inline(
                    &self.rows[r.clone()],
                    &self.shifted[r],
                    self.shift[k],
                    h,
                );
                if !each(b * Self::BLOCK + k, lc, h) {
                    return;
                }
            }
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
        let mut log_normalisers = vec![f64::NEG_INFINITY; t_len];
        let mut core = ForwardCore::new(self);
        let mut rows = ShiftedRows::new(&core, s);
        let mut h = vec![[0.0; kernels::W]; rows.c];
        dispatch(
            #[inline(always)]
            || {
                rows.run(&mut core, log_b, &mut h, |t, lc, h| {
                    log_normalisers[t] = lc;
                    filtered[t * s..(t + 1) * s].copy_from_slice(&h.as_flattened()[..s]);
                    // Everything after an impossible frame is impossible too.
                    lc != f64::NEG_INFINITY
                });
            },
        );
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
        let log_b = self.emission_log_densities(seq)?;
        let s = self.n_states();
        let mut core = ForwardCore::new(self);
        let mut rows = ShiftedRows::new(&core, s);
        let mut h = vec![[0.0; kernels::W]; rows.c];
        Ok(dispatch(
            #[inline(always)]
            || {
                let mut ll = 0.0;
                rows.run(&mut core, &log_b, &mut h, |_, lc, _| {
                    if lc == f64::NEG_INFINITY {
                        ll = lc;
                        return false;
                    }
                    ll += lc;
                    true
                });
                ll
            },
        ))
    }

    /// Sum of the log-likelihoods of every sequence of a set.
    pub fn log_likelihood_all(&self, data: &phasekit_emission::SequenceSet) -> Result<f64> {
        let mut total = 0.0;
        for (k, seq) in data.iter().enumerate() {
            total += self.log_likelihood(seq).map_err(|e| e.in_sequence(k))?;
        }
        Ok(total)
    }

    /// The backward variable `log β_t(i) = log p(x_{t+1:T} | z_t = i)`, `T × S`
    /// row-major ([`formulas::backward_variable`], computed by that formula).
    pub fn backward(&self, seq: Frames<'_>) -> Result<Vec<f64>> {
        let log_b = self.emission_log_densities(seq)?;
        Ok(formulas::backward_variable(&self.log_transition, &log_b))
    }

    /// State posteriors `γ_t(i)` and expected transitions `Σ_t ξ_t(i,j)`.
    ///
    /// Errors if the sequence has probability zero under the model.
    pub fn posteriors(&self, seq: Frames<'_>) -> Result<Posteriors> {
        self.check_sequence(seq)?;
        let mut ws = PosteriorWorkspace::new(self);
        self.emission
            .log_density_into(seq, ws.log_b_for(seq.len()))?;
        let log_likelihood = ws.run()?;
        Ok(Posteriors {
            gamma: ws.gamma,
            expected_transitions: ws.xi,
            log_likelihood,
        })
    }

    /// The Viterbi path `argmax_z log p(z, x)` and its log-probability.
    pub fn viterbi(&self, seq: Frames<'_>) -> Result<ViterbiPath> {
        let log_b = self.emission_log_densities(seq)?;
        Ok(self.viterbi_from(&log_b))
    }
}
