//! Initial parameters for EM, and the transition structure.
//!
//! Every initialisation assigns frames to states, fits the emission to that
//! assignment ([`fit_weighted`], any [`Emission`]), takes the durations from
//! the lengths of the assigned segments (smoothed, see [`duration_counts`],
//! and fitted by the duration family's own M-step, any [`Duration`]) and
//! builds the transitions allowed by the [`Structure`].

use crate::duration::{Duration, DurationRegularisation};
use crate::error::{invalid, HsmmError, Result};
use crate::model::{Censoring, Hsmm};
use phasekit_emission::kmeans::{kmeans, Seeding};
use phasekit_emission::{fit_weighted, Emission, Regularisation, SequenceSet};
use phasekit_hmm::kbins_edges;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Which transitions between segments the model may have. Forbidden ones are
/// structural zeros, which EM keeps.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Structure {
    /// Any state may follow any other (`a_ij`, `j ≠ i`); any state may start.
    #[default]
    Ergodic,
    /// Transitions only forward, `i → j` for `i < j ≤ i + 1 + skip`, for an
    /// interaction whose phases come in order (`skip` phases may be left
    /// out). The first segment is one of states `0..=skip`; the last state is
    /// terminal.
    LeftRight {
        /// How many states a transition may jump over (0: strictly `i → i + 1`).
        skip: usize,
    },
}

impl Structure {
    /// Whether `i → j` is allowed.
    pub fn allows(&self, i: usize, j: usize) -> bool {
        match *self {
            Structure::Ergodic => i != j,
            Structure::LeftRight { skip } => j > i && j <= i + 1 + skip,
        }
    }

    /// Whether a sequence may start in state `j`.
    pub fn allows_start(&self, j: usize) -> bool {
        match *self {
            Structure::Ergodic => true,
            Structure::LeftRight { skip } => j <= skip,
        }
    }

    /// `(1 − ε)·base + ε·(uniform over the allowed entries)`, renormalised;
    /// all zeros when nothing is allowed or the result is zero.
    fn mix(base: &[f64], allowed: impl Fn(usize) -> bool, eps: f64) -> Vec<f64> {
        let n_allowed = (0..base.len()).filter(|&j| allowed(j)).count();
        let mut row: Vec<f64> = (0..base.len())
            .map(|j| {
                if !allowed(j) {
                    0.0
                } else {
                    (1.0 - eps) * base[j] + eps / n_allowed as f64
                }
            })
            .collect();
        let total: f64 = row.iter().sum();
        if total > 0.0 {
            row.iter_mut().for_each(|v| *v /= total);
        }
        row
    }

    /// Start and transition probabilities: `base` pulled towards uniform over
    /// the allowed entries by `eps`.
    fn probabilities(
        &self,
        s: usize,
        base_start: &[f64],
        base_transition: &[f64],
        eps: f64,
    ) -> (Vec<f64>, Vec<f64>) {
        let mut start = Self::mix(base_start, |j| self.allows_start(j), eps);
        if start.iter().all(|v| *v == 0.0) {
            start = Self::mix(&vec![0.0; s], |j| self.allows_start(j), 1.0);
        }
        let mut transition = Vec::with_capacity(s * s);
        for i in 0..s {
            transition.extend(Self::mix(
                &base_transition[i * s..(i + 1) * s],
                |j| self.allows(i, j),
                eps,
            ));
        }
        (start, transition)
    }
}

/// How the first parameters are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum HsmmInit {
    /// Temporal k-bins (as the HMM's): split every sequence of length `T` at
    /// `round_half_even(linspace(0, T, S + 1))`; state `i` takes the
    /// maximum-likelihood emission of bin `i` and the durations of the bin
    /// lengths. Transitions `(1 − ε) (i → i + 1) + ε · uniform` over the
    /// allowed ones, start `(1 − ε) e_0 + ε · uniform`; `ε = 0` keeps only
    /// the left-right chain (the last state terminal).
    KBins {
        /// Mixing weight `ε` of the uniform distribution, also mixed into
        /// the initial duration pmfs (see [`duration_counts`]).
        smoothing: f64,
    },
    /// k-means++ on all frames, one state per cluster; durations from the
    /// lengths of the runs of equal labels; uniform start and transitions
    /// over the allowed ones.
    KMeans,
    /// Random soft assignment of frames to states, random start and
    /// transition rows over the allowed ones, random durations.
    Random,
}

impl Default for HsmmInit {
    /// Temporal k-bins with `ε = 0.01`.
    fn default() -> Self {
        HsmmInit::KBins { smoothing: 0.01 }
    }
}

/// A maximum duration for `n_states` states on `data`: three times the
/// longest sequence divided by the number of states (a phase may last three
/// times its share of the longest demonstration), at most the longest
/// sequence and at least 1. The cost of every recursion grows linearly with it.
pub fn suggested_max_duration(data: &SequenceSet, n_states: usize) -> usize {
    let longest = data.lengths().max().unwrap_or(1);
    (3 * longest)
        .div_ceil(n_states.max(1))
        .clamp(1, longest.max(1))
}

/// Initial duration counts of one state from observed segment lengths:
/// a discretised Gaussian at their mean `m` with width
/// `max(standard deviation, m / 2, 1)` (wide, so that EM can move the
/// durations), mixed with weight `ε` with the uniform pmf over `1..=D`;
/// lengths above `D` count as `D`. With no length, the Gaussian sits at
/// `fallback`. Returns `D` counts summing to 1.
pub fn duration_counts(
    lengths: &[usize],
    fallback: f64,
    max_duration: usize,
    eps: f64,
) -> Vec<f64> {
    let dm = max_duration;
    let capped: Vec<f64> = lengths.iter().map(|&l| l.clamp(1, dm) as f64).collect();
    let (mean, sd) = if capped.is_empty() {
        (fallback.clamp(1.0, dm as f64), 0.0)
    } else {
        let n = capped.len() as f64;
        let mean = capped.iter().sum::<f64>() / n;
        let var = capped.iter().map(|l| (l - mean) * (l - mean)).sum::<f64>() / n;
        (mean, var.sqrt())
    };
    let width = sd.max(mean / 2.0).max(1.0);
    let mut counts: Vec<f64> = (1..=dm)
        .map(|d| {
            let z = (d as f64 - mean) / width;
            (-0.5 * z * z).exp()
        })
        .collect();
    let total: f64 = counts.iter().sum();
    for c in counts.iter_mut() {
        *c = (1.0 - eps) * *c / total + eps / dm as f64;
    }
    counts
}

/// Durations fitted to per-state segment lengths (see [`duration_counts`]).
fn durations_from_lengths<D: Duration>(
    template: &D,
    lengths: &[Vec<usize>],
    fallback: f64,
    eps: f64,
    reg: &DurationRegularisation,
) -> Result<D> {
    let dm = template.max_duration();
    let mut counts = Vec::with_capacity(lengths.len() * dm);
    for l in lengths {
        counts.extend(duration_counts(l, fallback, dm, eps));
    }
    let mut durations = template.clone();
    // The counts of a state sum to 1: make sure no state is skipped as empty.
    let reg = reg.with_min_weight(0.0)?;
    durations.m_step(&counts, &reg)?;
    Ok(durations)
}

fn emission_from_weights<E: Emission>(
    template: &E,
    data: &SequenceSet,
    weights: &[Vec<f64>],
    reg: &Regularisation,
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
        return Err(HsmmError::TooFewFrames(format!(
            "state {i} received no frame at initialisation ({} frames in {} sequences for {s} states)",
            data.total_frames(),
            data.len()
        )));
    }
    let parts: Vec<_> = data.iter().zip(weights).map(|(f, w)| (f, &w[..])).collect();
    let (emission, _) = fit_weighted(template, &parts, reg)?;
    Ok(emission)
}

/// Lengths of the runs of equal labels, per label.
fn run_lengths(labels: &[usize], s: usize, out: &mut [Vec<usize>]) {
    debug_assert_eq!(out.len(), s);
    let mut start = 0;
    for t in 1..=labels.len() {
        if t == labels.len() || labels[t] != labels[start] {
            out[labels[start]].push(t - start);
            start = t;
        }
    }
}

/// Everything an initialisation needs besides the data.
#[derive(Debug, Clone, Copy)]
pub struct InitSettings<'a> {
    /// How frames are assigned to states.
    pub init: HsmmInit,
    /// Which transitions are allowed.
    pub structure: Structure,
    /// How the last segment is scored.
    pub censoring: Censoring,
    /// Regularisation of the emission fit.
    pub regularisation: &'a Regularisation,
    /// Regularisation of the duration fit.
    pub duration_regularisation: &'a DurationRegularisation,
}

/// Builds the initial model for `data` from an emission template and a
/// duration template with `S` states (their parameter values are ignored;
/// their structure, the duration family and `D` are kept).
pub fn initialise<E: Emission, D: Duration, R: Rng + ?Sized>(
    emission: &E,
    durations: &D,
    data: &SequenceSet,
    settings: InitSettings<'_>,
    rng: &mut R,
) -> Result<Hsmm<E, D>> {
    let s = emission.n_states();
    if durations.n_states() != s {
        return Err(invalid(
            "durations",
            format!(
                "{} duration distributions for an emission with {s} states",
                durations.n_states()
            ),
        ));
    }
    if data.is_empty() {
        return Err(HsmmError::NoData);
    }
    if data.total_frames() < s {
        return Err(HsmmError::TooFewFrames(format!(
            "{} frames cannot initialise {s} states",
            data.total_frames()
        )));
    }
    let structure = settings.structure;
    let mean_len = data.total_frames() as f64 / data.len() as f64;
    let fallback = (mean_len / s as f64).max(1.0);
    let dreg = settings.duration_regularisation;
    let model = match settings.init {
        HsmmInit::KBins { smoothing } => {
            if !(0.0..=1.0).contains(&smoothing) {
                return Err(invalid(
                    "smoothing",
                    format!("k-bins smoothing must lie in [0, 1], got {smoothing}"),
                ));
            }
            let mut lengths = vec![Vec::new(); s];
            let weights: Vec<Vec<f64>> = data
                .lengths()
                .map(|len| {
                    let edges = kbins_edges(len, s);
                    let mut w = vec![0.0; len * s];
                    for i in 0..s {
                        if edges[i + 1] > edges[i] {
                            lengths[i].push(edges[i + 1] - edges[i]);
                        }
                        for t in edges[i]..edges[i + 1] {
                            w[t * s + i] = 1.0;
                        }
                    }
                    w
                })
                .collect();
            let emission =
                emission_from_weights(emission, data, &weights, settings.regularisation)?;
            let durations = durations_from_lengths(durations, &lengths, fallback, smoothing, dreg)?;
            let mut base_start = vec![0.0; s];
            base_start[0] = 1.0;
            let mut base = vec![0.0; s * s];
            for i in 0..s.saturating_sub(1) {
                base[i * s + i + 1] = 1.0;
            }
            let (start, transition) = structure.probabilities(s, &base_start, &base, smoothing);
            Hsmm::new(start, transition, durations, emission)?
        }
        HsmmInit::KMeans => {
            let km = kmeans(data.all_frames(), s, Seeding::PlusPlus, 100, rng)?;
            let mut offset = 0;
            let mut lengths = vec![Vec::new(); s];
            let weights: Vec<Vec<f64>> = data
                .lengths()
                .map(|len| {
                    let labels = &km.labels[offset..offset + len];
                    run_lengths(labels, s, &mut lengths);
                    let mut w = vec![0.0; len * s];
                    for (t, l) in labels.iter().enumerate() {
                        w[t * s + l] = 1.0;
                    }
                    offset += len;
                    w
                })
                .collect();
            let emission =
                emission_from_weights(emission, data, &weights, settings.regularisation)?;
            let durations = durations_from_lengths(durations, &lengths, fallback, 0.01, dreg)?;
            let (start, transition) =
                structure.probabilities(s, &vec![0.0; s], &vec![0.0; s * s], 1.0);
            Hsmm::new(start, transition, durations, emission)?
        }
        HsmmInit::Random => {
            let mut random_row = |allowed: &dyn Fn(usize) -> bool| -> Vec<f64> {
                let mut v: Vec<f64> = (0..s)
                    .map(|j| {
                        if allowed(j) {
                            rng.random::<f64>() + 1e-3
                        } else {
                            0.0
                        }
                    })
                    .collect();
                let total: f64 = v.iter().sum();
                if total > 0.0 {
                    v.iter_mut().for_each(|x| *x /= total);
                }
                v
            };
            let start = random_row(&|j| structure.allows_start(j));
            let mut transition = Vec::with_capacity(s * s);
            for i in 0..s {
                transition.extend(random_row(&|j| structure.allows(i, j)));
            }
            let weights: Vec<Vec<f64>> = data
                .lengths()
                .map(|len| {
                    let mut w = Vec::with_capacity(len * s);
                    for _ in 0..len {
                        w.extend(random_row(&|_| true));
                    }
                    w
                })
                .collect();
            let lengths: Vec<Vec<usize>> = (0..s)
                .map(|_| {
                    let hi = (2.0 * fallback).ceil().max(1.0) as usize;
                    vec![rng.random_range(1..=hi)]
                })
                .collect();
            let emission =
                emission_from_weights(emission, data, &weights, settings.regularisation)?;
            let durations = durations_from_lengths(durations, &lengths, fallback, 0.01, dreg)?;
            Hsmm::new(start, transition, durations, emission)?
        }
    };
    Ok(model.with_censoring(settings.censoring))
}
