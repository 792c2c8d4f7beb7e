//! The formulas of the HMM, one plain function each: the reference that
//! every fast path of this crate is documented as equal to and tested
//! against (`tests/hmm_formulas.rs`, and the brute-force enumeration of
//! `tests/hmm_properties.rs`).
//!
//! Notation: `S` states, frames `x_0 … x_{T−1}`, initial distribution `π_i`,
//! transitions `a_ij = p(z_{t+1} = j | z_t = i)` (row-major `S × S`),
//! emission densities `b_j(x_t)`. The parameters are passed in log space:
//! `log_start[i] = log π_i`, `log_transition[i·S + j] = log a_ij` and
//! `log_b[t·S + j] = log b_j(x_t)`, with `log 0 = −∞` for forbidden
//! transitions and impossible frames. Everything is computed in log space by
//! the textbook recursions: `O(T S²)`
//! exponentials, and no scaling, so that nothing but the formula is there to
//! be checked. The fast paths ([`crate::Hmm::forward`],
//! [`crate::Hmm::posteriors`], the E-step of [`crate::BaumWelch`], the
//! online [`crate::ForwardFilter`]) compute the same quantities with scaled
//! linear recursions and switch to log space only where that would lose
//! precision; they agree with these functions to rounding.

use phasekit_emission::linalg::log_sum_exp;

fn n_states(log_transition: &[f64]) -> usize {
    let s = (log_transition.len() as f64).sqrt().round() as usize;
    assert_eq!(s * s, log_transition.len(), "log_transition must be S × S");
    s
}

fn n_frames(s: usize, log_b: &[f64]) -> usize {
    assert!(
        s > 0 && log_b.len().is_multiple_of(s),
        "log_b must be T × S"
    );
    log_b.len() / s
}

/// The forward variable `log α_t(j) = log p(x_0 … x_t, z_t = j)`, `T × S`:
///
/// `α_0(j) = π_j b_j(x_0)`, `α_t(j) = b_j(x_t) Σ_i α_{t−1}(i) a_ij`.
pub fn forward_variable(log_start: &[f64], log_transition: &[f64], log_b: &[f64]) -> Vec<f64> {
    let s = log_start.len();
    let t_len = n_frames(s, log_b);
    let mut la = vec![f64::NEG_INFINITY; t_len * s];
    let mut terms = vec![0.0; s];
    for t in 0..t_len {
        for j in 0..s {
            let prior = if t == 0 {
                log_start[j]
            } else {
                for i in 0..s {
                    terms[i] = la[(t - 1) * s + i] + log_transition[i * s + j];
                }
                log_sum_exp(&terms)
            };
            la[t * s + j] = prior + log_b[t * s + j];
        }
    }
    la
}

/// The backward variable `log β_t(i) = log p(x_{t+1} … x_{T−1} | z_t = i)`, `T × S`:
///
/// `β_{T−1}(i) = 1`, `β_t(i) = Σ_j a_ij b_j(x_{t+1}) β_{t+1}(j)`.
pub fn backward_variable(log_transition: &[f64], log_b: &[f64]) -> Vec<f64> {
    let s = n_states(log_transition);
    let t_len = n_frames(s, log_b);
    let mut lb = vec![0.0; t_len * s];
    let mut terms = vec![0.0; s];
    for t in (0..t_len.saturating_sub(1)).rev() {
        for i in 0..s {
            for j in 0..s {
                terms[j] = log_transition[i * s + j] + log_b[(t + 1) * s + j] + lb[(t + 1) * s + j];
            }
            lb[t * s + i] = log_sum_exp(&terms);
        }
    }
    lb
}

/// The likelihood `log p(x_0 … x_{T−1}) = log Σ_j α_{T−1}(j)` from the
/// forward variable (`S` states).
pub fn log_likelihood(log_alpha: &[f64], s: usize) -> f64 {
    let t_len = n_frames(s, log_alpha);
    if t_len == 0 {
        return 0.0;
    }
    log_sum_exp(&log_alpha[(t_len - 1) * s..])
}

/// The state posteriors `γ_t(i) = p(z_t = i | x) = α_t(i) β_t(i) / Σ_j α_t(j) β_t(j)`, `T × S`
/// (NaN rows where the sequence is impossible).
pub fn state_posteriors(log_alpha: &[f64], log_beta: &[f64], s: usize) -> Vec<f64> {
    let t_len = n_frames(s, log_alpha);
    assert_eq!(log_alpha.len(), log_beta.len());
    let mut gamma = vec![0.0; t_len * s];
    let mut row = vec![0.0; s];
    for t in 0..t_len {
        for i in 0..s {
            row[i] = log_alpha[t * s + i] + log_beta[t * s + i];
        }
        let z = log_sum_exp(&row);
        for i in 0..s {
            gamma[t * s + i] = (row[i] - z).exp();
        }
    }
    gamma
}

/// The transition posterior of one frame pair,
/// `ξ_t(i, j) = p(z_t = i, z_{t+1} = j | x) = α_t(i) a_ij b_j(x_{t+1}) β_{t+1}(j) / p(x)`,
/// `S × S`, for `t < T − 1`.
pub fn transition_posterior(
    log_alpha: &[f64],
    log_beta: &[f64],
    log_transition: &[f64],
    log_b: &[f64],
    t: usize,
) -> Vec<f64> {
    let s = n_states(log_transition);
    let t_len = n_frames(s, log_b);
    assert!(t + 1 < t_len, "ξ_t needs a frame t + 1");
    let ll = log_likelihood(log_alpha, s);
    let mut xi = vec![0.0; s * s];
    for i in 0..s {
        for j in 0..s {
            let v = log_alpha[t * s + i]
                + log_transition[i * s + j]
                + log_b[(t + 1) * s + j]
                + log_beta[(t + 1) * s + j];
            xi[i * s + j] = (v - ll).exp();
        }
    }
    xi
}

/// The expected transition counts `Σ_{t < T−1} ξ_t(i, j)`, `S × S`.
pub fn expected_transitions(
    log_alpha: &[f64],
    log_beta: &[f64],
    log_transition: &[f64],
    log_b: &[f64],
) -> Vec<f64> {
    let s = n_states(log_transition);
    let t_len = n_frames(s, log_b);
    let mut total = vec![0.0; s * s];
    for t in 0..t_len.saturating_sub(1) {
        let xi = transition_posterior(log_alpha, log_beta, log_transition, log_b, t);
        for (a, b) in total.iter_mut().zip(&xi) {
            *a += b;
        }
    }
    total
}

/// The M-step of the initial distribution, `π_i = Σ_k γ^k_0(i) / Σ_j Σ_k γ^k_0(j)`
/// from the summed first-frame posteriors of every sequence; `None` when
/// they sum to zero (nothing to re-estimate from).
pub fn start_update(first_frame_posteriors: &[f64]) -> Option<Vec<f64>> {
    let total: f64 = first_frame_posteriors.iter().sum();
    (total > 0.0).then(|| first_frame_posteriors.iter().map(|v| v / total).collect())
}

/// The M-step of the transition matrix, `a_ij = Σ ξ(i, j) / Σ_j' Σ ξ(i, j')`
/// from the expected transition counts (`S × S`): row `i` is `None` when
/// state `i` is never expected to be left (no count to re-estimate from).
/// Zero counts give zero transitions, so a forbidden transition stays forbidden.
pub fn transition_update(expected_transitions: &[f64], s: usize) -> Vec<Option<Vec<f64>>> {
    assert_eq!(expected_transitions.len(), s * s);
    expected_transitions
        .chunks_exact(s)
        .map(|row| {
            let total: f64 = row.iter().sum();
            (total > 0.0).then(|| row.iter().map(|v| v / total).collect())
        })
        .collect()
}

/// The Viterbi variable `log δ_t(j) = max_{z_0 … z_{t−1}} log p(z_0 … z_{t−1}, z_t = j, x_0 … x_t)`, `T × S`:
///
/// `δ_0(j) = log π_j + log b_j(x_0)`, `δ_t(j) = log b_j(x_t) + max_i (δ_{t−1}(i) + log a_ij)`;
/// the most probable path ends in `argmax_j δ_{T−1}(j)` and is traced back
/// through the maximising `i`.
pub fn viterbi_variable(log_start: &[f64], log_transition: &[f64], log_b: &[f64]) -> Vec<f64> {
    let s = log_start.len();
    let t_len = n_frames(s, log_b);
    let mut delta = vec![f64::NEG_INFINITY; t_len * s];
    for t in 0..t_len {
        for j in 0..s {
            let prior = if t == 0 {
                log_start[j]
            } else {
                (0..s)
                    .map(|i| delta[(t - 1) * s + i] + log_transition[i * s + j])
                    .fold(f64::NEG_INFINITY, f64::max)
            };
            delta[t * s + j] = prior + log_b[t * s + j];
        }
    }
    delta
}
