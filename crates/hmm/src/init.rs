//! Initial parameters for Baum-Welch.
//!
//! Every initialisation assigns frames to states (hard or soft), accumulates the
//! emission's own initialisation from those weights ([`Emission::initialise`]:
//! by default one accumulation and one M-step, iterated when values are
//! missing), so it works for any [`Emission`] without knowing its parameters.

use crate::error::{HmmError, Result};
use crate::model::Hmm;
use phasekit_emission::kmeans::{kmeans, Seeding};
use phasekit_emission::{Emission, Regularisation, SequenceSet};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// How the first parameters are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum HmmInit {
    /// Temporal k-bins: split every sequence of length `T` at
    /// `round_half_even(linspace(0, T, S + 1))`; state `i` takes the maximum-likelihood
    /// emission of all frames of bin `i` (plus the regularisation). Transitions
    /// `(1 − ε) LR + ε / S` where `LR` has `a_ii = 1 − p`, `a_{i,i+1} = p` with
    /// `p = min(S/T̄, 1)` (last state absorbing, `T̄` the mean length); start `(1 − ε) e_0 + ε / S`.
    /// `ε = 0` gives a strict left-right model whose zeros Baum-Welch keeps.
    KBins {
        /// Mixing weight `ε` of the uniform distribution.
        smoothing: f64,
    },
    /// k-means++ on all frames, one state per cluster; uniform start and transitions.
    KMeans,
    /// Random soft assignment of frames to states; random start and transition rows.
    Random,
}

impl Default for HmmInit {
    /// Temporal k-bins with `ε = 0.01`, the seed paper's setting.
    fn default() -> Self {
        HmmInit::KBins { smoothing: 0.01 }
    }
}

/// Bin edges `round_half_even(linspace(0, len, n_states + 1))`, as NumPy computes them.
pub fn kbins_edges(len: usize, n_states: usize) -> Vec<usize> {
    let step = len as f64 / n_states as f64;
    (0..=n_states)
        .map(|i| {
            if i == n_states {
                len
            } else {
                (i as f64 * step).round_ties_even() as usize
            }
        })
        .collect()
}

fn emission_from_weights<E: Emission, R: Rng + ?Sized>(
    template: &E,
    data: &SequenceSet,
    weights: &[Vec<f64>],
    reg: &Regularisation,
    rng: &mut R,
) -> Result<E> {
    let s = template.n_states();
    let mut per_state = vec![0.0; s];
    for w in weights {
        for row in w.chunks_exact(s) {
            for (p, v) in per_state.iter_mut().zip(row) {
                *p += v;
            }
        }
    }
    if let Some(i) = per_state.iter().position(|w| *w == 0.0) {
        return Err(HmmError::TooFewFrames(format!(
            "state {i} received no frame at initialisation ({} frames in {} sequences for {s} states)",
            data.total_frames(),
            data.len()
        )));
    }
    let parts: Vec<_> = data.iter().zip(weights).map(|(f, w)| (f, &w[..])).collect();
    let (emission, _) = template.initialise(&parts, reg, rng)?;
    Ok(emission)
}

/// Builds the initial model for `data` from an emission `template` with `S` states.
pub fn initialise<E: Emission, R: Rng + ?Sized>(
    template: &E,
    data: &SequenceSet,
    init: HmmInit,
    reg: &Regularisation,
    rng: &mut R,
) -> Result<Hmm<E>> {
    let s = template.n_states();
    if data.is_empty() {
        return Err(HmmError::NoData);
    }
    if data.total_frames() < s {
        return Err(HmmError::TooFewFrames(format!(
            "{} frames cannot initialise {s} states",
            data.total_frames()
        )));
    }
    match init {
        HmmInit::KBins { smoothing } => {
            if !(0.0..=1.0).contains(&smoothing) {
                return Err(HmmError::InvalidParameter {
                    name: "smoothing",
                    reason: format!("k-bins smoothing must lie in [0, 1], got {smoothing}"),
                });
            }
            let weights: Vec<Vec<f64>> = data
                .lengths()
                .map(|len| {
                    let edges = kbins_edges(len, s);
                    let mut w = vec![0.0; len * s];
                    for i in 0..s {
                        for t in edges[i]..edges[i + 1] {
                            w[t * s + i] = 1.0;
                        }
                    }
                    w
                })
                .collect();
            let emission = emission_from_weights(template, data, &weights, reg, rng)?;
            let mean_len = data.total_frames() as f64 / data.len() as f64;
            // Sequences shorter on average than the number of states would make
            // `a_ii = 1 − S/T̄` negative: leave every state after one frame then.
            let p = (s as f64 / mean_len).min(1.0);
            let u = smoothing / s as f64;
            let mut transition = vec![u; s * s];
            for i in 0..s {
                if i + 1 < s {
                    transition[i * s + i] += (1.0 - smoothing) * (1.0 - p);
                    transition[i * s + i + 1] += (1.0 - smoothing) * p;
                } else {
                    transition[i * s + i] += 1.0 - smoothing;
                }
            }
            let mut start = vec![u; s];
            start[0] += 1.0 - smoothing;
            Hmm::new(start, transition, emission)
        }
        HmmInit::KMeans => {
            let km = kmeans(data.all_frames(), s, Seeding::PlusPlus, 100, rng)?;
            let mut offset = 0;
            let weights: Vec<Vec<f64>> = data
                .lengths()
                .map(|len| {
                    let mut w = vec![0.0; len * s];
                    for t in 0..len {
                        w[t * s + km.labels[offset + t]] = 1.0;
                    }
                    offset += len;
                    w
                })
                .collect();
            let emission = emission_from_weights(template, data, &weights, reg, rng)?;
            Hmm::new(
                vec![1.0 / s as f64; s],
                vec![1.0 / s as f64; s * s],
                emission,
            )
        }
        HmmInit::Random => {
            let mut random_rows = |rows: usize| -> Vec<f64> {
                let mut v: Vec<f64> = (0..rows * s).map(|_| rng.random::<f64>() + 1e-3).collect();
                for row in v.chunks_exact_mut(s) {
                    let total: f64 = row.iter().sum();
                    row.iter_mut().for_each(|x| *x /= total);
                }
                v
            };
            let weights: Vec<Vec<f64>> = data.lengths().map(&mut random_rows).collect();
            let start = random_rows(1);
            let transition = random_rows(s);
            let emission = emission_from_weights(template, data, &weights, reg, rng)?;
            Hmm::new(start, transition, emission)
        }
    }
}
