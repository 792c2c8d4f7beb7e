//! A mixture of `M` components per state:
//! `b_i(x) = Σ_m w_{i,m} c_{i,m}(x)`, `log b_i(x) = logsumexp_m (log w_{i,m} + log c_{i,m}(x))`.
//!
//! Each state's components are themselves an [`Emission`] with `M` states, so
//! `MixtureEmission<Gaussian>` is hmmlearn's GMMHMM emission and any other emission can
//! be mixed the same way. The E-step splits the state posterior `γ_t(i)` over the
//! components in proportion to `w_{i,m} c_{i,m}(x_t)`.

use crate::error::{EmissionError, Result};
use crate::linalg::log_sum_exp;
use crate::regularisation::{MStepEvent, MStepReport, Regularisation};
use crate::{check_len, check_state, Emission, Frames, SufficientStatistics};
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
    pub fn components(&self, i: usize) -> &E {
        &self.components[i]
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

    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        let components = self
            .components
            .iter()
            .map(|c| c.marginal(dims))
            .collect::<Result<Vec<_>>>()?;
        MixtureEmission::new(self.weights.clone(), components)
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

    fn n_parameters(&self) -> usize {
        self.n_states() * (self.n_components() - 1)
            + self
                .components
                .iter()
                .map(|c| c.n_parameters())
                .sum::<usize>()
    }
}
