//! A mixture of `M` components per state:
//! `b_i(x) = Σ_m w_{i,m} c_{i,m}(x)`, `log b_i(x) = logsumexp_m (log w_{i,m} + log c_{i,m}(x))`.
//!
//! Each state's components are themselves an [`Emission`] with `M` states, so
//! `MixtureEmission<Gaussian>` is hmmlearn's GMMHMM emission and any other emission can
//! be mixed the same way. The E-step splits the state posterior `γ_t(i)` over the
//! components in proportion to `w_{i,m} c_{i,m}(x_t)`.
//!
//! Initialisation ([`Emission::initialise`]): every state's components are
//! seeded by weighted k-means++ on the frames that state owns (its weights
//! from time bins, k-means or a random assignment), each component then
//! initialised from its cluster by its own [`Emission::initialise`], and the
//! mixture weights are the clusters' shares of the state's weight. (Starting
//! every component of a state from the same template would give them equal
//! responsibilities for ever: they would never separate.) The random draws of
//! k-means++ come from the caller's generator, so restarts differ.

use crate::capability::{check_split, ConcatStates, Conditional, ConditionalSplit};
use crate::error::{EmissionError, Result};
use crate::linalg::log_sum_exp;
use crate::regularisation::{MStepEvent, MStepReport, Regularisation};
use crate::{check_len, check_state, Emission, Frames, Marginal, SufficientStatistics};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;

thread_local! {
    /// Reused per-thread scratch for component log-densities (taken, not borrowed,
    /// so that nested mixtures simply allocate their own).
    static SCRATCH: RefCell<Vec<f64>> = const { RefCell::new(Vec::new()) };
}

fn with_scratch<T>(len: usize, f: impl FnOnce(&mut [f64]) -> T) -> T {
    let mut buf = SCRATCH.with(|s| s.take());
    buf.clear();
    buf.resize(len, 0.0);
    let r = f(&mut buf);
    SCRATCH.with(|s| s.replace(buf));
    r
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct MixtureParams<E> {
    weights: Vec<f64>,
    components: Vec<E>,
}

/// `S` states, each a mixture of the `M` states of its own component emission.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(
    try_from = "MixtureParams<E>",
    into = "MixtureParams<E>",
    bound = "E: Emission + Serialize + for<'a> Deserialize<'a>"
)]
pub struct MixtureEmission<E: Emission> {
    /// `S × M` mixture weights, rows sum to 1.
    weights: Vec<f64>,
    log_weights: Vec<f64>,
    components: Vec<E>,
}

impl<E: Emission> TryFrom<MixtureParams<E>> for MixtureEmission<E> {
    type Error = EmissionError;
    fn try_from(p: MixtureParams<E>) -> Result<Self> {
        MixtureEmission::new(p.weights, p.components)
    }
}

impl<E: Emission> From<MixtureEmission<E>> for MixtureParams<E> {
    fn from(m: MixtureEmission<E>) -> Self {
        MixtureParams {
            weights: m.weights,
            components: m.components,
        }
    }
}

impl<E: Emission> MixtureEmission<E> {
    /// One mixture per entry of `components` (each with `M` states, all of one
    /// dimension); `weights` is `S × M` row-major with rows summing to 1.
    pub fn new(weights: Vec<f64>, components: Vec<E>) -> Result<Self> {
        let first = components
            .first()
            .ok_or_else(|| EmissionError::InvalidParameter {
                name: "components",
                reason: "a mixture emission needs at least one state".into(),
            })?;
        let (m, d) = (first.n_states(), first.dim());
        for (i, c) in components.iter().enumerate() {
            if c.n_states() != m || c.dim() != d {
                return Err(EmissionError::InvalidParameter {
                    name: "components",
                    reason: format!(
                        "state {i} has {} components of dim {}, state 0 has {m} of dim {d}",
                        c.n_states(),
                        c.dim()
                    ),
                });
            }
        }
        check_len(
            "mixture weights (states × components)",
            components.len() * m,
            weights.len(),
        )?;
        crate::categorical::check_stochastic_rows("weights", &weights, m)?;
        let log_weights = weights
            .iter()
            .map(|w| if *w > 0.0 { w.ln() } else { f64::NEG_INFINITY })
            .collect();
        Ok(MixtureEmission {
            weights,
            log_weights,
            components,
        })
    }

    /// Number of components `M` per state.
    pub fn n_components(&self) -> usize {
        self.components[0].n_states()
    }

    /// `S × M` weights, row-major.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// The component emission of state `i`.
    ///
    /// # Panics
    /// If `i ≥ S` (like slice indexing); [`MixtureEmission::state_components`]
    /// is the checked form.
    pub fn components(&self, i: usize) -> &E {
        &self.components[i]
    }

    /// The component emission of state `i`, or the error naming it.
    pub fn state_components(&self, i: usize) -> Result<&E> {
        check_state(i, self.components.len())?;
        Ok(&self.components[i])
    }

    /// Writes into `scratch` (`T × M`) the joint log-terms `log w_{i,m} + log c_{i,m}(x_t)`.
    fn joint_terms(&self, i: usize, frames: Frames<'_>, scratch: &mut [f64]) -> Result<()> {
        let m = self.n_components();
        self.components[i].log_density_into(frames, scratch)?;
        for row in scratch.chunks_exact_mut(m) {
            for (v, lw) in row.iter_mut().zip(&self.log_weights[i * m..(i + 1) * m]) {
                *v += lw;
            }
        }
        Ok(())
    }
}

/// Statistics of a [`MixtureEmission`]: component weights and each state's inner statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MixtureEmissionStats<S> {
    /// `S × M` expected component counts.
    weight: Vec<f64>,
    inner: Vec<S>,
}

impl<S: SufficientStatistics> SufficientStatistics for MixtureEmissionStats<S> {
    fn merge(&mut self, other: &Self) -> Result<()> {
        if self.weight.len() != other.weight.len() || self.inner.len() != other.inner.len() {
            return Err(EmissionError::StatsMismatch(
                "mixture statistics of another shape".into(),
            ));
        }
        // Merge into a copy so that a mismatch found in a later state's inner
        // statistics leaves `self` untouched.
        let mut merged = self.clone();
        for (a, b) in merged.weight.iter_mut().zip(&other.weight) {
            *a += b;
        }
        for (a, b) in merged.inner.iter_mut().zip(&other.inner) {
            a.merge(b)?;
        }
        *self = merged;
        Ok(())
    }

    fn total_weight(&self) -> f64 {
        self.weight.iter().sum()
    }
}

impl<E: Emission> Emission for MixtureEmission<E> {
    type Stats = MixtureEmissionStats<E::Stats>;

    fn n_states(&self) -> usize {
        self.components.len()
    }

    fn dim(&self) -> usize {
        self.components[0].dim()
    }

    fn check_frames(&self, frames: Frames<'_>) -> Result<()> {
        self.components[0].check_frames(frames)
    }

    fn log_density_into(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()> {
        let (s, m, t) = (self.n_states(), self.n_components(), frames.len());
        check_len("log-density output buffer", t * s, out.len())?;
        with_scratch(t * m, |scratch| {
            for i in 0..s {
                self.joint_terms(i, frames, scratch)?;
                for (row, o) in scratch.chunks_exact(m).zip(out.chunks_exact_mut(s)) {
                    o[i] = log_sum_exp(row);
                }
            }
            Ok(())
        })
    }

    fn new_stats(&self) -> Self::Stats {
        MixtureEmissionStats {
            weight: vec![0.0; self.weights.len()],
            inner: self.components.iter().map(|c| c.new_stats()).collect(),
        }
    }

    fn accumulate(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut Self::Stats,
    ) -> Result<()> {
        let (s, m, t) = (self.n_states(), self.n_components(), frames.len());
        check_len("accumulate weights", t * s, weights.len())?;
        if stats.inner.len() != s || stats.weight.len() != s * m {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        // A frame with nothing observed adds nothing (its density is 1).
        let unobserved: Vec<bool> = if frames.has_missing() {
            frames
                .iter()
                .map(|x| x.iter().all(|v| v.is_nan()))
                .collect()
        } else {
            Vec::new()
        };
        with_scratch(t * m, |scratch| {
            for i in 0..s {
                self.joint_terms(i, frames, scratch)?;
                for (tt, row) in scratch.chunks_exact_mut(m).enumerate() {
                    let g = if unobserved.get(tt) == Some(&true) {
                        0.0
                    } else {
                        weights[tt * s + i]
                    };
                    let lse = log_sum_exp(row);
                    for (k, v) in row.iter_mut().enumerate() {
                        *v = if g == 0.0 || lse == f64::NEG_INFINITY {
                            0.0
                        } else {
                            g * (*v - lse).exp()
                        };
                        stats.weight[i * m + k] += *v;
                    }
                }
                self.components[i].accumulate(frames, scratch, &mut stats.inner[i])?;
            }
            Ok(())
        })
    }

    fn m_step(&mut self, stats: &Self::Stats, reg: &Regularisation) -> Result<MStepReport> {
        let (s, m) = (self.n_states(), self.n_components());
        if stats.inner.len() != s || stats.weight.len() != s * m {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        let a = reg.pseudo_count();
        let mut report = MStepReport::default();
        let mut weights = self.weights.clone();
        let mut components = self.components.clone();
        for i in 0..s {
            let row = &stats.weight[i * m..(i + 1) * m];
            let n: f64 = row.iter().sum();
            if n < reg.min_weight().max(f64::MIN_POSITIVE) {
                report.events.push(MStepEvent::KeptEmptyState {
                    state: i,
                    component: None,
                    weight: n,
                });
                continue;
            }
            for k in 0..m {
                weights[i * m + k] = (row[k] + a) / (n + a * m as f64);
            }
            let inner = components[i]
                .m_step(&stats.inner[i], reg)
                .map_err(|e| match e {
                    EmissionError::NotPositiveDefinite { state, detail, .. } => {
                        EmissionError::NotPositiveDefinite {
                            state: i,
                            component: Some(state),
                            detail,
                        }
                    }
                    other => other,
                })?;
            report.absorb_components(i, inner);
        }
        *self = MixtureEmission::new(weights, components)?;
        Ok(report)
    }

    fn log_prior(&self, reg: &Regularisation) -> f64 {
        let a = reg.pseudo_count();
        let w = if a > 0.0 {
            a * self.log_weights.iter().sum::<f64>()
        } else {
            0.0
        };
        w + self
            .components
            .iter()
            .map(|c| c.log_prior(reg))
            .sum::<f64>()
    }

    fn sample_into<R: Rng + ?Sized>(
        &self,
        state: usize,
        rng: &mut R,
        out: &mut [f64],
    ) -> Result<()> {
        check_state(state, self.n_states())?;
        let m = self.n_components();
        let k = crate::categorical::sample_index(&self.weights[state * m..(state + 1) * m], rng);
        self.components[state].sample_into(k, rng, out)
    }

    fn initialise<R: Rng + ?Sized>(
        &self,
        parts: &[(Frames<'_>, &[f64])],
        reg: &Regularisation,
        rng: &mut R,
    ) -> Result<(Self, MStepReport)> {
        let (s, m, d) = (self.n_states(), self.n_components(), self.dim());
        let mut report = MStepReport::added_diagonal(reg);
        let mut weights = Vec::with_capacity(s * m);
        let mut components = Vec::with_capacity(s);
        for i in 0..s {
            // The frames state i owns, with its weights.
            let (mut xs, mut ws) = (Vec::new(), Vec::new());
            for (frames, w) in parts {
                crate::check_dim(d, frames.dim())?;
                check_len("initialisation weights", frames.len() * s, w.len())?;
                for (x, wt) in frames.iter().zip(w.chunks_exact(s)) {
                    if wt[i] > 0.0 && !x.iter().all(|v| v.is_nan()) {
                        xs.extend_from_slice(x);
                        ws.push(wt[i]);
                    }
                }
            }
            let frames = Frames::new(&xs, d)?;
            let mut r = vec![0.0; ws.len() * m];
            if m == 1 {
                r.copy_from_slice(&ws);
            } else {
                let km = crate::kmeans::weighted_kmeans(frames, &ws, m, 100, rng).map_err(|e| {
                    EmissionError::InvalidParameter {
                        name: "mixture initialisation",
                        reason: format!("state {i}: {e}"),
                    }
                })?;
                for (t, &l) in km.labels.iter().enumerate() {
                    r[t * m + l] = ws[t];
                }
            }
            let mut counts = vec![0.0; m];
            for row in r.chunks_exact(m) {
                for (c, v) in counts.iter_mut().zip(row) {
                    *c += v;
                }
            }
            let total: f64 = counts.iter().sum();
            if total.is_nan() || total <= 0.0 {
                return Err(EmissionError::InvalidParameter {
                    name: "initialisation weights",
                    reason: format!("state {i} received no frame with positive weight"),
                });
            }
            let (c, inner) = self.components[i]
                .initialise(&[(frames, &r)], reg, rng)
                .map_err(|e| match e {
                    EmissionError::NotPositiveDefinite { state, .. } => e.at_state(i, Some(state)),
                    other => other,
                })?;
            report.absorb_components(i, inner);
            weights.extend(counts.iter().map(|c| c / total));
            components.push(c);
        }
        Ok((MixtureEmission::new(weights, components)?, report))
    }

    fn n_parameters(&self) -> usize {
        self.n_states() * (self.n_components() - 1)
            + self
                .components
                .iter()
                .map(|c| c.n_parameters())
                .sum::<usize>()
    }
}

impl<E: Marginal> Marginal for MixtureEmission<E> {
    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        let components = self
            .components
            .iter()
            .map(|c| c.marginal(dims))
            .collect::<Result<Vec<_>>>()?;
        MixtureEmission::new(self.weights.clone(), components)
    }
}

impl<E: Emission> ConcatStates for MixtureEmission<E> {
    /// The same number of components and dimension on both sides.
    fn concat_states(&self, other: &Self) -> Result<Self> {
        crate::check_dim(self.dim(), other.dim())?;
        if self.n_components() != other.n_components() {
            return Err(EmissionError::InvalidParameter {
                name: "components",
                reason: format!(
                    "cannot join mixtures of {} and {} components per state",
                    self.n_components(),
                    other.n_components()
                ),
            });
        }
        let mut weights = self.weights.clone();
        weights.extend_from_slice(&other.weights);
        let mut components = self.components.clone();
        components.extend(other.components.iter().cloned());
        MixtureEmission::new(weights, components)
    }
}

/// The conditionals of a [`MixtureEmission`]: per state, a mixture of the
/// components' conditionals with input-dependent weights
/// `π_m(x_I) ∝ w_m c_m(x_I)`, moment-matched:
/// `E[x_O | x_I] = Σ_m π_m μ_m(x_I)`,
/// `Cov[x_O | x_I] = Σ_m π_m (Σ_m(x_I) + μ_m μ_mᵀ) − E Eᵀ`.
#[derive(Debug, Clone)]
pub struct MixtureSplit<P> {
    input: Vec<usize>,
    output: Vec<usize>,
    n_components: usize,
    log_weights: Vec<f64>,
    splits: Vec<P>,
    log_terms: Vec<f64>,
    mean: Vec<f64>,
    cov: Vec<f64>,
}

impl<P: ConditionalSplit> MixtureSplit<P> {
    /// `log w_m + log c_m(x_I)` of every component of `state` into `log_terms`.
    fn terms(&mut self, state: usize, input: &[f64]) -> Result<f64> {
        let m = self.n_components;
        for k in 0..m {
            let lw = self.log_weights[state * m + k];
            self.log_terms[k] = if lw == f64::NEG_INFINITY {
                f64::NEG_INFINITY
            } else {
                lw + self.splits[state].input_log_density(k, input)?
            };
        }
        Ok(log_sum_exp(&self.log_terms))
    }
}

impl<P: ConditionalSplit> ConditionalSplit for MixtureSplit<P> {
    fn n_states(&self) -> usize {
        self.splits.len()
    }

    fn input_dims(&self) -> &[usize] {
        &self.input
    }

    fn output_dims(&self) -> &[usize] {
        &self.output
    }

    fn input_log_density(&mut self, state: usize, input: &[f64]) -> Result<f64> {
        check_state(state, self.splits.len())?;
        check_len("regression input", self.input.len(), input.len())?;
        self.terms(state, input)
    }

    fn predict(
        &mut self,
        state: usize,
        input: &[f64],
        mean: &mut [f64],
        covariance: &mut [f64],
    ) -> Result<()> {
        check_state(state, self.splits.len())?;
        let no = self.output.len();
        check_len("regression input", self.input.len(), input.len())?;
        check_len("regression mean", no, mean.len())?;
        check_len("regression covariance", no * no, covariance.len())?;
        let lse = self.terms(state, input)?;
        if lse == f64::NEG_INFINITY {
            return Err(EmissionError::InvalidParameter {
                name: "regression input",
                reason: format!(
                    "the input has density zero under every component of state {state}"
                ),
            });
        }
        mean.fill(0.0);
        covariance.fill(0.0);
        for k in 0..self.n_components {
            let p = (self.log_terms[k] - lse).exp();
            if p == 0.0 {
                continue;
            }
            self.splits[state].predict(k, input, &mut self.mean, &mut self.cov)?;
            for (a, v) in mean.iter_mut().zip(&self.mean) {
                *a += p * v;
            }
            for r in 0..no {
                for c in 0..no {
                    covariance[r * no + c] +=
                        p * (self.cov[r * no + c] + self.mean[r] * self.mean[c]);
                }
            }
        }
        for r in 0..no {
            for c in 0..no {
                covariance[r * no + c] -= mean[r] * mean[c];
            }
        }
        Ok(())
    }
}

impl<E: Conditional> Conditional for MixtureEmission<E> {
    type Split = MixtureSplit<E::Split>;

    fn conditional(&self, input: &[usize], output: &[usize]) -> Result<Self::Split> {
        check_split(input, output, self.dim())?;
        let splits = self
            .components
            .iter()
            .enumerate()
            .map(|(i, c)| {
                c.conditional(input, output).map_err(|e| match e {
                    EmissionError::NotPositiveDefinite { state, .. } => e.at_state(i, Some(state)),
                    other => other,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let (m, no) = (self.n_components(), output.len());
        Ok(MixtureSplit {
            input: input.to_vec(),
            output: output.to_vec(),
            n_components: m,
            log_weights: self.log_weights.clone(),
            splits,
            log_terms: vec![0.0; m],
            mean: vec![0.0; no],
            cov: vec![0.0; no * no],
        })
    }
}
