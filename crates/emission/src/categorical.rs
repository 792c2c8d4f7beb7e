//! Categorical (discrete-symbol) emissions: `b_i(x) = p_{i,x}` for a symbol `x ∈ {0, …, K−1}`.
//!
//! Frames are one-dimensional and hold the symbol as a whole number.

use crate::error::{EmissionError, Result};
use crate::regularisation::{MStepEvent, MStepReport, Regularisation};
use crate::{check_dim, check_len, check_state, Emission, Frames, Marginal, SufficientStatistics};
use rand::Rng;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
struct CategoricalParams {
    n_symbols: usize,
    probabilities: Vec<f64>,
}

/// `S` categorical distributions over `K` symbols.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "CategoricalParams", into = "CategoricalParams")]
pub struct Categorical {
    n_symbols: usize,
    /// `S × K` row-major, rows sum to 1.
    probabilities: Vec<f64>,
    log_probabilities: Vec<f64>,
}

impl TryFrom<CategoricalParams> for Categorical {
    type Error = EmissionError;
    fn try_from(p: CategoricalParams) -> Result<Self> {
        Categorical::new(p.n_symbols, p.probabilities)
    }
}

impl From<Categorical> for CategoricalParams {
    fn from(c: Categorical) -> Self {
        CategoricalParams {
            n_symbols: c.n_symbols,
            probabilities: c.probabilities,
        }
    }
}

/// Checks that `rows` (row-major, rows of length `k`) are probability vectors.
pub(crate) fn check_stochastic_rows(name: &'static str, rows: &[f64], k: usize) -> Result<()> {
    if k == 0 || rows.is_empty() || rows.len() % k != 0 {
        return Err(EmissionError::InvalidParameter {
            name,
            reason: format!("{} values do not form rows of length {k}", rows.len()),
        });
    }
    for (i, row) in rows.chunks_exact(k).enumerate() {
        if let Some(j) = row.iter().position(|p| !(p.is_finite() && *p >= 0.0)) {
            return Err(EmissionError::InvalidParameter {
                name,
                reason: format!("row {i}, entry {j}: {} is not a probability", row[j]),
            });
        }
        let sum: f64 = row.iter().sum();
        if (sum - 1.0).abs() > 1e-8 {
            return Err(EmissionError::InvalidParameter {
                name,
                reason: format!("row {i} sums to {sum}, not 1"),
            });
        }
    }
    Ok(())
}

fn ln0(p: f64) -> f64 {
    if p > 0.0 {
        p.ln()
    } else {
        f64::NEG_INFINITY
    }
}

impl Categorical {
    /// `S = probabilities.len() / n_symbols` distributions; rows must sum to 1.
    pub fn new(n_symbols: usize, probabilities: Vec<f64>) -> Result<Self> {
        check_stochastic_rows("probabilities", &probabilities, n_symbols)?;
        let log_probabilities = probabilities.iter().map(|p| ln0(*p)).collect();
        Ok(Categorical {
            n_symbols,
            probabilities,
            log_probabilities,
        })
    }

    /// `S` uniform distributions over `K` symbols (a template for initialisation).
    pub fn uniform(n_states: usize, n_symbols: usize) -> Result<Self> {
        if n_states == 0 || n_symbols == 0 {
            return Err(EmissionError::InvalidParameter {
                name: "n_states/n_symbols",
                reason: "must be at least 1".into(),
            });
        }
        Self::new(
            n_symbols,
            vec![1.0 / n_symbols as f64; n_states * n_symbols],
        )
    }

    /// Number of symbols `K`.
    pub fn n_symbols(&self) -> usize {
        self.n_symbols
    }

    /// `S × K` probabilities, row-major.
    pub fn probabilities(&self) -> &[f64] {
        &self.probabilities
    }

    #[inline]
    fn symbol(&self, x: f64) -> Option<usize> {
        (x >= 0.0 && x.fract() == 0.0 && x < self.n_symbols as f64).then_some(x as usize)
    }
}

/// Expected symbol counts per state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CategoricalStats {
    n_symbols: usize,
    /// `S × K` expected counts.
    counts: Vec<f64>,
}

impl SufficientStatistics for CategoricalStats {
    fn merge(&mut self, other: &Self) -> Result<()> {
        if self.n_symbols != other.n_symbols || self.counts.len() != other.counts.len() {
            return Err(EmissionError::StatsMismatch(
                "categorical statistics of another shape".into(),
            ));
        }
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        Ok(())
    }

    fn total_weight(&self) -> f64 {
        self.counts.iter().sum()
    }
}

impl Emission for Categorical {
    type Stats = CategoricalStats;

    fn n_states(&self) -> usize {
        self.probabilities.len() / self.n_symbols
    }

    fn dim(&self) -> usize {
        1
    }

    fn check_frames(&self, frames: Frames<'_>) -> Result<()> {
        check_dim(1, frames.dim())?;
        for (t, x) in frames.as_slice().iter().enumerate() {
            // NaN: the symbol was not observed.
            if !x.is_nan() && self.symbol(*x).is_none() {
                return Err(EmissionError::InvalidValue {
                    frame: t,
                    column: 0,
                    value: *x,
                    reason: "not a symbol index in 0..K",
                });
            }
        }
        Ok(())
    }

    fn log_density_into(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()> {
        check_dim(1, frames.dim())?;
        let s = self.n_states();
        check_len("log-density output buffer", frames.len() * s, out.len())?;
        let k = self.n_symbols;
        for (x, row) in frames.as_slice().iter().zip(out.chunks_exact_mut(s)) {
            match self.symbol(*x) {
                Some(sym) => {
                    for (i, o) in row.iter_mut().enumerate() {
                        *o = self.log_probabilities[i * k + sym];
                    }
                }
                // Not observed: the marginal over all symbols is 1.
                None if x.is_nan() => row.fill(0.0),
                None => row.fill(f64::NEG_INFINITY),
            }
        }
        Ok(())
    }

    fn new_stats(&self) -> CategoricalStats {
        CategoricalStats {
            n_symbols: self.n_symbols,
            counts: vec![0.0; self.probabilities.len()],
        }
    }

    fn accumulate(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut CategoricalStats,
    ) -> Result<()> {
        check_dim(1, frames.dim())?;
        let (s, k) = (self.n_states(), self.n_symbols);
        check_len("accumulate weights", frames.len() * s, weights.len())?;
        if stats.n_symbols != k || stats.counts.len() != s * k {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        for (t, x) in frames.as_slice().iter().enumerate() {
            if let Some(sym) = self.symbol(*x) {
                for i in 0..s {
                    stats.counts[i * k + sym] += weights[t * s + i];
                }
            }
            // A missing symbol (NaN) has probability 1 under every state whatever
            // the parameters: it adds nothing to their statistics.
        }
        Ok(())
    }

    fn m_step(&mut self, stats: &CategoricalStats, reg: &Regularisation) -> Result<MStepReport> {
        let (s, k) = (self.n_states(), self.n_symbols);
        if stats.n_symbols != k || stats.counts.len() != s * k {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        let a = reg.pseudo_count();
        let mut report = MStepReport::default();
        let mut probs = self.probabilities.clone();
        for i in 0..s {
            let row = &stats.counts[i * k..(i + 1) * k];
            let n: f64 = row.iter().sum();
            if n < reg.min_weight().max(f64::MIN_POSITIVE) && a == 0.0 {
                report.events.push(MStepEvent::KeptEmptyState {
                    state: i,
                    component: None,
                    weight: n,
                });
                continue;
            }
            let denom = n + a * k as f64;
            for j in 0..k {
                probs[i * k + j] = (row[j] + a) / denom;
            }
        }
        *self = Categorical::new(k, probs)?;
        Ok(report)
    }

    fn log_prior(&self, reg: &Regularisation) -> f64 {
        let a = reg.pseudo_count();
        if a == 0.0 {
            return 0.0;
        }
        // Dirichlet(α + 1) prior, whose mode is the pseudo-count update.
        a * self.log_probabilities.iter().sum::<f64>()
    }

    fn sample_into<R: Rng + ?Sized>(
        &self,
        state: usize,
        rng: &mut R,
        out: &mut [f64],
    ) -> Result<()> {
        check_state(state, self.n_states())?;
        check_len("sample output buffer", 1, out.len())?;
        let k = self.n_symbols;
        out[0] = sample_index(&self.probabilities[state * k..(state + 1) * k], rng) as f64;
        Ok(())
    }

    fn n_parameters(&self) -> usize {
        self.n_states() * (self.n_symbols - 1)
    }
}

impl Marginal for Categorical {
    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        crate::check_dims(dims, 1)?;
        Ok(self.clone())
    }
}

/// Draws an index from the probability vector `p` (which sums to 1).
pub fn sample_index<R: Rng + ?Sized>(p: &[f64], rng: &mut R) -> usize {
    let u: f64 = rng.random();
    let mut acc = 0.0;
    for (j, pj) in p.iter().enumerate() {
        acc += pj;
        if u < acc {
            return j;
        }
    }
    p.iter().rposition(|v| *v > 0.0).unwrap_or(0)
}

impl crate::ConcatStates for Categorical {
    /// The same number of symbols on both sides.
    fn concat_states(&self, other: &Self) -> Result<Self> {
        if self.n_symbols != other.n_symbols {
            return Err(EmissionError::InvalidParameter {
                name: "n_symbols",
                reason: format!(
                    "cannot join categorical states over {} and {} symbols",
                    self.n_symbols, other.n_symbols
                ),
            });
        }
        let mut p = self.probabilities.clone();
        p.extend_from_slice(&other.probabilities);
        Categorical::new(self.n_symbols, p)
    }
}
