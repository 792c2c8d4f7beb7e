//! A free probability vector over `1..=D` per state.

use super::{
    check_counts, check_pmf_call, check_shape, table_row, Duration, DurationEvent,
    DurationRegularisation, DurationReport,
};
use crate::error::{invalid, HsmmError, Result};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize)]
struct NonParametricParams {
    max_duration: usize,
    pmf: Vec<f64>,
}

/// Non-parametric durations: `p_i(d)` is a free probability vector over
/// `d = 1..=D` for every state (`S (D − 1)` parameters).
///
/// The M-step is `p_i(d) = (c_i(d) + α) / Σ_d' (c_i(d') + α)` with the
/// Dirichlet pseudo-count `α` of [`DurationRegularisation::with_pseudo_count`].
/// A zero of `p_i` stays zero under EM when `α = 0` (its expected count is
/// zero), like a structural zero of a transition matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "NonParametricParams", into = "NonParametricParams")]
pub struct NonParametricDuration {
    max_duration: usize,
    /// `S × D` row-major, rows sum to 1.
    pmf: Vec<f64>,
    log_pmf: Vec<f64>,
}

impl TryFrom<NonParametricParams> for NonParametricDuration {
    type Error = HsmmError;
    fn try_from(p: NonParametricParams) -> Result<Self> {
        NonParametricDuration::new(p.max_duration, p.pmf)
    }
}

impl From<NonParametricDuration> for NonParametricParams {
    fn from(d: NonParametricDuration) -> Self {
        NonParametricParams {
            max_duration: d.max_duration,
            pmf: d.pmf,
        }
    }
}

impl NonParametricDuration {
    /// Durations from a pmf table, `S × D` row-major (`pmf[i·D + d − 1] = p_i(d)`).
    /// Every row must be finite, non-negative and sum to 1 within `1e-8`
    /// (it is then renormalised; a row that sums to 1 up to rounding is kept bit for bit).
    pub fn new(max_duration: usize, pmf: Vec<f64>) -> Result<Self> {
        if max_duration == 0 || pmf.is_empty() || !pmf.len().is_multiple_of(max_duration) {
            check_shape(1, max_duration)?;
            return Err(invalid(
                "pmf",
                format!(
                    "{} values do not form rows of max_duration = {max_duration} entries",
                    pmf.len()
                ),
            ));
        }
        let mut d = NonParametricDuration {
            max_duration,
            pmf,
            log_pmf: Vec::new(),
        };
        for (i, row) in d.pmf.chunks_exact(max_duration).enumerate() {
            if let Some(k) = row.iter().position(|p| !(p.is_finite() && *p >= 0.0)) {
                return Err(invalid(
                    "pmf",
                    format!(
                        "state {i}, duration {}: {} is not a probability",
                        k + 1,
                        row[k]
                    ),
                ));
            }
            let sum: f64 = row.iter().sum();
            if (sum - 1.0).abs() > 1e-8 {
                return Err(invalid(
                    "pmf",
                    format!("state {i}: the duration probabilities sum to {sum}, not 1"),
                ));
            }
        }
        d.refresh();
        Ok(d)
    }

    /// Every duration `1..=D` equally likely, for every state (a template for fitting).
    pub fn uniform(n_states: usize, max_duration: usize) -> Result<Self> {
        check_shape(n_states, max_duration)?;
        Self::new(
            max_duration,
            vec![1.0 / max_duration as f64; n_states * max_duration],
        )
    }

    /// The pmf table, `S × D` row-major.
    pub fn pmf(&self) -> &[f64] {
        &self.pmf
    }

    /// Renormalises the rows (when they are off by more than rounding) and refreshes the logarithms.
    fn refresh(&mut self) {
        let dm = self.max_duration;
        for row in self.pmf.chunks_exact_mut(dm) {
            let total: f64 = row.iter().sum();
            if (total - 1.0).abs() > 4.0 * f64::EPSILON * dm as f64 {
                row.iter_mut().for_each(|v| *v /= total);
            }
        }
        self.log_pmf = self
            .pmf
            .iter()
            .map(|p| if *p > 0.0 { p.ln() } else { f64::NEG_INFINITY })
            .collect();
    }
}

impl Duration for NonParametricDuration {
    fn n_states(&self) -> usize {
        self.pmf.len() / self.max_duration
    }

    fn max_duration(&self) -> usize {
        self.max_duration
    }

    fn log_pmf_into(&self, state: usize, out: &mut [f64]) -> Result<()> {
        check_pmf_call(self.n_states(), self.max_duration, state, out)?;
        out.copy_from_slice(table_row(&self.log_pmf, self.max_duration, state));
        Ok(())
    }

    fn m_step(&mut self, counts: &[f64], reg: &DurationRegularisation) -> Result<DurationReport> {
        let (s, dm) = (self.n_states(), self.max_duration);
        check_counts(s, dm, counts)?;
        let alpha = reg.pseudo_count();
        let mut report = DurationReport::default();
        let mut pmf = self.pmf.clone();
        for i in 0..s {
            let c = &counts[i * dm..(i + 1) * dm];
            let total: f64 = c.iter().sum();
            if total < reg.min_weight() || total + alpha * dm as f64 <= 0.0 {
                report.events.push(DurationEvent::KeptEmptyState {
                    state: i,
                    weight: total,
                });
                continue;
            }
            let z = total + alpha * dm as f64;
            for (p, c) in pmf[i * dm..(i + 1) * dm].iter_mut().zip(c) {
                *p = (c + alpha) / z;
            }
        }
        self.pmf = pmf;
        self.refresh();
        Ok(report)
    }

    /// `α Σ_i Σ_d log p_i(d)`: the symmetric Dirichlet(`α + 1`) prior up to a constant.
    fn log_prior(&self, reg: &DurationRegularisation) -> f64 {
        let alpha = reg.pseudo_count();
        if alpha == 0.0 {
            return 0.0;
        }
        alpha * self.log_pmf.iter().sum::<f64>()
    }

    /// `Σ_i (nnz(p_i) − 1)`: a zero of the pmf is structural (EM keeps it).
    fn n_parameters(&self) -> usize {
        self.pmf
            .chunks_exact(self.max_duration)
            .map(|row| row.iter().filter(|p| **p > 0.0).count().saturating_sub(1))
            .sum()
    }
}
