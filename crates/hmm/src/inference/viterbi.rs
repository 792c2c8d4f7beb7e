//! The most probable state path: [`super::formulas::viterbi_variable`] and
//! its trace-back, in log space (`max` and `+` are exact there, so there is
//! no scaled form to switch to).

use crate::model::Hmm;
use phasekit_emission::linalg::dispatch;
use phasekit_emission::Emission;

/// The most probable state path.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct ViterbiPath {
    /// `argmax_z p(z, x)`; ties go to the lower state index.
    pub states: Vec<usize>,
    /// `max_z log p(z, x)` (`−inf` if every path is impossible).
    pub log_probability: f64,
}

impl<E: Emission> Hmm<E> {
    /// The Viterbi recursion over precomputed log-densities (`T × S`, `T ≥ 1`).
    pub(crate) fn viterbi_from(&self, log_b: &[f64]) -> ViterbiPath {
        dispatch(
            #[inline(always)]
            || self.viterbi_inline(log_b),
        )
    }

    #[inline(always)]
    fn viterbi_inline(&self, log_b: &[f64]) -> ViterbiPath {
        let s = self.n_states();
        let t_len = log_b.len() / s;
        let la = &self.log_transition;
        let mut delta: Vec<f64> = (0..s).map(|j| self.log_start[j] + log_b[j]).collect();
        let mut best = vec![0.0; s];
        let mut arg = vec![0u32; s];
        let mut back = vec![0u32; t_len * s];
        for t in 1..t_len {
            // best_j = max_i (δ_i + log a_ij), i in increasing order with a
            // strict comparison (ties to the lower i), row by row so that the
            // comparisons over j vectorise.
            best.fill(f64::NEG_INFINITY);
            arg.fill(0);
            for (i, (di, row)) in delta.iter().zip(la.chunks_exact(s)).enumerate() {
                for ((b, a), l) in best.iter_mut().zip(arg.iter_mut()).zip(row) {
                    let v = di + l;
                    if v > *b {
                        *b = v;
                        *a = i as u32;
                    }
                }
            }
            back[t * s..(t + 1) * s].copy_from_slice(&arg);
            for ((d, b), l) in delta.iter_mut().zip(&best).zip(&log_b[t * s..(t + 1) * s]) {
                *d = b + l;
            }
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
