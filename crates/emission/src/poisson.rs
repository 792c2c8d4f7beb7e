//! Independent Poisson counts per dimension:
//! `log b_i(x) = Σ_d (x_d log λ_{i,d} − λ_{i,d} − log Γ(x_d + 1))`.

use crate::error::{EmissionError, Result};
use crate::regularisation::{MStepEvent, MStepReport, Regularisation};
use crate::{
    check_dim, check_dims, check_len, check_state, Emission, Frames, Marginal, SufficientStatistics,
};
use rand::Rng;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
struct PoissonParams {
    dim: usize,
    rates: Vec<f64>,
}

/// `S` states of `D` independent Poisson counts.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "PoissonParams", into = "PoissonParams")]
pub struct Poisson {
    dim: usize,
    /// `S × D` rates `λ`, row-major.
    rates: Vec<f64>,
    log_rates: Vec<f64>,
}

impl TryFrom<PoissonParams> for Poisson {
    type Error = EmissionError;
    fn try_from(p: PoissonParams) -> Result<Self> {
        Poisson::new(p.dim, p.rates)
    }
}

impl From<Poisson> for PoissonParams {
    fn from(p: Poisson) -> Self {
        PoissonParams {
            dim: p.dim,
            rates: p.rates,
        }
    }
}

impl Poisson {
    /// `S = rates.len() / dim` states; every rate finite and non-negative.
    pub fn new(dim: usize, rates: Vec<f64>) -> Result<Self> {
        if dim == 0 || rates.is_empty() || rates.len() % dim != 0 {
            return Err(EmissionError::InvalidParameter {
                name: "rates",
                reason: format!(
                    "{} values do not form states of dimension {dim}",
                    rates.len()
                ),
            });
        }
        if let Some(k) = rates.iter().position(|r| !(r.is_finite() && *r >= 0.0)) {
            return Err(EmissionError::InvalidParameter {
                name: "rates",
                reason: format!(
                    "state {}, dim {}: rate {} is not finite and non-negative",
                    k / dim,
                    k % dim,
                    rates[k]
                ),
            });
        }
        let log_rates = rates.iter().map(|r| r.ln()).collect();
        Ok(Poisson {
            dim,
            rates,
            log_rates,
        })
    }

    /// `S × D` rates, row-major.
    pub fn rates(&self) -> &[f64] {
        &self.rates
    }

    /// Unit rates (a template for initialisation).
    pub fn unit(n_states: usize, dim: usize) -> Result<Self> {
        Self::new(dim, vec![1.0; n_states * dim])
    }
}

fn is_count(x: f64) -> bool {
    x >= 0.0 && x.fract() == 0.0
}

/// Weighted count sums per state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoissonStats {
    dim: usize,
    weight: Vec<f64>,
    sum: Vec<f64>,
}

impl PoissonStats {
    /// True when the arrays fit `s` states of dimension `d` (deserialised statistics may not).
    fn has_shape(&self, s: usize, d: usize) -> bool {
        self.dim == d && self.weight.len() == s && self.sum.len() == s * d
    }
}

impl SufficientStatistics for PoissonStats {
    fn merge(&mut self, other: &Self) -> Result<()> {
        let s = self.weight.len();
        if !self.has_shape(s, self.dim) || !other.has_shape(s, self.dim) {
            return Err(EmissionError::StatsMismatch(
                "Poisson statistics of another shape".into(),
            ));
        }
        for (a, b) in self.weight.iter_mut().zip(&other.weight) {
            *a += b;
        }
        for (a, b) in self.sum.iter_mut().zip(&other.sum) {
            *a += b;
        }
        Ok(())
    }

    fn total_weight(&self) -> f64 {
        self.weight.iter().sum()
    }
}

impl Emission for Poisson {
    type Stats = PoissonStats;

    fn n_states(&self) -> usize {
        self.rates.len() / self.dim
    }

    fn dim(&self) -> usize {
        self.dim
    }

    fn check_frames(&self, frames: Frames<'_>) -> Result<()> {
        check_dim(self.dim, frames.dim())?;
        for (k, x) in frames.as_slice().iter().enumerate() {
            // NaN: the count was not observed.
            if !x.is_nan() && !is_count(*x) {
                return Err(EmissionError::InvalidValue {
                    frame: k / self.dim,
                    column: k % self.dim,
                    value: *x,
                    reason: "not a non-negative whole count",
                });
            }
        }
        Ok(())
    }

    fn log_density_into(&self, frames: Frames<'_>, out: &mut [f64]) -> Result<()> {
        check_dim(self.dim, frames.dim())?;
        let (s, d) = (self.n_states(), self.dim);
        check_len("log-density output buffer", frames.len() * s, out.len())?;
        for (x, row) in frames.iter().zip(out.chunks_exact_mut(s)) {
            // Missing counts (NaN) are left out: the dims are independent, so
            // the marginal of the observed ones is their product.
            let log_fact: f64 = x
                .iter()
                .filter(|v| !v.is_nan())
                .map(|v| libm::lgamma(v + 1.0))
                .sum();
            let valid = x.iter().all(|v| v.is_nan() || is_count(*v));
            for (i, o) in row.iter_mut().enumerate() {
                if !valid {
                    *o = f64::NEG_INFINITY;
                    continue;
                }
                let mut acc = -log_fact;
                for (k, &xk) in x.iter().enumerate() {
                    if xk.is_nan() {
                        continue;
                    }
                    let lam = self.rates[i * d + k];
                    // 0 · log 0 = 0: a zero count has probability e^{−λ} even when λ = 0.
                    if xk > 0.0 {
                        acc += xk * self.log_rates[i * d + k];
                    }
                    acc -= lam;
                }
                *o = acc;
            }
        }
        Ok(())
    }

    fn new_stats(&self) -> PoissonStats {
        PoissonStats {
            dim: self.dim,
            weight: vec![0.0; self.n_states()],
            sum: vec![0.0; self.rates.len()],
        }
    }

    fn accumulate(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        stats: &mut PoissonStats,
    ) -> Result<()> {
        check_dim(self.dim, frames.dim())?;
        let (s, d) = (self.n_states(), self.dim);
        check_len("accumulate weights", frames.len() * s, weights.len())?;
        if !stats.has_shape(s, d) {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        for (t, x) in frames.iter().enumerate() {
            // A frame with no count observed adds nothing (its probability is 1
            // whatever the rates).
            if frames.has_missing() && x.iter().all(|v| v.is_nan()) {
                continue;
            }
            for i in 0..s {
                let w = weights[t * s + i];
                stats.weight[i] += w;
                for (k, &xk) in x.iter().enumerate() {
                    // A missing count adds its expectation `λ_ik` under the current model.
                    let v = if xk.is_nan() {
                        self.rates[i * d + k]
                    } else {
                        xk
                    };
                    stats.sum[i * d + k] += w * v;
                }
            }
        }
        Ok(())
    }

    fn m_step(&mut self, stats: &PoissonStats, reg: &Regularisation) -> Result<MStepReport> {
        let (s, d) = (self.n_states(), self.dim);
        if !stats.has_shape(s, d) {
            return Err(EmissionError::StatsMismatch(
                "statistics shaped for another model".into(),
            ));
        }
        let mut report = MStepReport::default();
        let mut rates = self.rates.clone();
        for i in 0..s {
            let n = stats.weight[i];
            if n < reg.min_weight().max(f64::MIN_POSITIVE) {
                report.events.push(MStepEvent::KeptEmptyState {
                    state: i,
                    component: None,
                    weight: n,
                });
                continue;
            }
            for k in 0..d {
                rates[i * d + k] = stats.sum[i * d + k] / n;
            }
        }
        *self = Poisson::new(d, rates)?;
        Ok(report)
    }

    fn sample_into<R: Rng + ?Sized>(
        &self,
        state: usize,
        rng: &mut R,
        out: &mut [f64],
    ) -> Result<()> {
        check_state(state, self.n_states())?;
        check_len("sample output buffer", self.dim, out.len())?;
        for (k, o) in out.iter_mut().enumerate() {
            let lam = self.rates[state * self.dim + k];
            *o = if lam > 0.0 {
                rng.sample(rand_distr::Poisson::new(lam).map_err(|e| {
                    EmissionError::InvalidParameter {
                        name: "rates",
                        reason: format!("cannot sample rate {lam}: {e}"),
                    }
                })?)
            } else {
                0.0
            };
        }
        Ok(())
    }

    fn n_parameters(&self) -> usize {
        self.rates.len()
    }
}

impl Marginal for Poisson {
    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        check_dims(dims, self.dim)?;
        let rates = self
            .rates
            .chunks_exact(self.dim)
            .flat_map(|r| dims.iter().map(move |&k| r[k]))
            .collect();
        Poisson::new(dims.len(), rates)
    }
}

impl crate::ConcatStates for Poisson {
    /// The same dimension on both sides.
    fn concat_states(&self, other: &Self) -> Result<Self> {
        check_dim(self.dim, other.dim)?;
        let mut rates = self.rates.clone();
        rates.extend_from_slice(&other.rates);
        Poisson::new(self.dim, rates)
    }
}
