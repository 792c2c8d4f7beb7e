//! Shifted Poisson durations, truncated to `1..=D`.

use super::{
    check_counts, check_pmf_call, check_shape, expected_log_pmf, ln_factorials, log_normalise,
    solve_natural, table_row, Duration, DurationEvent, DurationRegularisation, DurationReport,
};
use crate::error::{invalid, HsmmError, Result};
use serde::{Deserialize, Serialize};

/// Search range of `ln λ` in the M-step: `λ ∈ [e^{−20}, e^{20}]` (beyond it
/// the truncated pmf is a point mass at 1 or at `D` to within `1e-8`).
const LN_RATE_RANGE: (f64, f64) = (-20.0, 20.0);

#[derive(Serialize, Deserialize)]
struct PoissonParams {
    max_duration: usize,
    rates: Vec<f64>,
}

/// Poisson durations shifted to start at one frame and truncated to `1..=D`:
/// `p_i(d) = λ_i^{d−1} / (d−1)! / Z_i`, `Z_i = Σ_{d=1}^{D} λ_i^{d−1} / (d−1)!`.
///
/// Before truncation the mean is `1 + λ_i` and the variance `λ_i`. The
/// M-step is the exact maximum of the truncated likelihood: the root of
/// `E_λ[d] = Σ_d c(d) d / Σ_d c(d)` (an exponential family in `ln λ`, whose
/// expected log-likelihood is concave), found by safeguarded Newton.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "PoissonParams", into = "PoissonParams")]
pub struct PoissonDuration {
    max_duration: usize,
    rates: Vec<f64>,
    log_pmf: Vec<f64>,
}

impl TryFrom<PoissonParams> for PoissonDuration {
    type Error = HsmmError;
    fn try_from(p: PoissonParams) -> Result<Self> {
        PoissonDuration::new(p.max_duration, p.rates)
    }
}

impl From<PoissonDuration> for PoissonParams {
    fn from(d: PoissonDuration) -> Self {
        PoissonParams {
            max_duration: d.max_duration,
            rates: d.rates,
        }
    }
}

/// `log p(d)`, `d = 1..=D`, of the truncated shifted Poisson with rate `rate`.
fn log_pmf_row(rate: f64, ln_fact: &[f64], out: &mut [f64]) {
    let lr = rate.ln();
    for (k, o) in out.iter_mut().enumerate() {
        *o = if k == 0 {
            0.0
        } else {
            k as f64 * lr - ln_fact[k]
        };
    }
    log_normalise(out);
}

impl PoissonDuration {
    /// Durations with rates `λ_i > 0` (one per state; mean `1 + λ_i` before truncation).
    pub fn new(max_duration: usize, rates: Vec<f64>) -> Result<Self> {
        check_shape(rates.len(), max_duration)?;
        if let Some(i) = rates.iter().position(|r| !(r.is_finite() && *r > 0.0)) {
            return Err(invalid(
                "rates",
                format!(
                    "state {i}: the Poisson rate {} is not positive and finite",
                    rates[i]
                ),
            ));
        }
        let mut d = PoissonDuration {
            max_duration,
            rates,
            log_pmf: Vec::new(),
        };
        d.refresh();
        Ok(d)
    }

    /// A template for fitting: `S` states, every rate `D / 2`.
    pub fn template(n_states: usize, max_duration: usize) -> Result<Self> {
        check_shape(n_states, max_duration)?;
        Self::new(
            max_duration,
            vec![(max_duration as f64 / 2.0).max(1.0); n_states],
        )
    }

    /// The rates `λ_i`.
    pub fn rates(&self) -> &[f64] {
        &self.rates
    }

    fn refresh(&mut self) {
        let dm = self.max_duration;
        let ln_fact = ln_factorials(dm);
        self.log_pmf = vec![0.0; self.rates.len() * dm];
        for (rate, row) in self.rates.iter().zip(self.log_pmf.chunks_exact_mut(dm)) {
            log_pmf_row(*rate, &ln_fact, row);
        }
    }
}

impl Duration for PoissonDuration {
    fn n_states(&self) -> usize {
        self.rates.len()
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
        let mut report = DurationReport::default();
        if dm == 1 {
            // Only d = 1 is possible: there is nothing to estimate.
            return Ok(report);
        }
        let ln_fact = ln_factorials(dm);
        let h: Vec<f64> = (0..dm).map(|k| -ln_fact[k]).collect();
        let t: Vec<f64> = (0..dm).map(|k| k as f64).collect();
        let mut rates = self.rates.clone();
        let mut row = vec![0.0; dm];
        for i in 0..s {
            let c = &counts[i * dm..(i + 1) * dm];
            let total: f64 = c.iter().sum();
            if total < reg.min_weight() || total <= 0.0 {
                report.events.push(DurationEvent::KeptEmptyState {
                    state: i,
                    weight: total,
                });
                continue;
            }
            let tbar = c.iter().zip(&t).map(|(c, t)| c * t).sum::<f64>() / total;
            let (lo, hi) = LN_RATE_RANGE;
            let (eta, at_bound) = solve_natural(&h, &t, tbar, lo, hi, self.rates[i].ln());
            let rate = eta.exp();
            log_pmf_row(rate, &ln_fact, &mut row);
            let q_new = expected_log_pmf(c, &row);
            let q_old = expected_log_pmf(c, table_row(&self.log_pmf, dm, i));
            if q_new >= q_old || q_old.is_nan() {
                rates[i] = rate;
                if at_bound {
                    report.events.push(DurationEvent::AtBound {
                        state: i,
                        parameter: "rate".into(),
                        value: rate,
                    });
                }
            } else {
                report
                    .events
                    .push(DurationEvent::KeptNoImprovement { state: i });
            }
        }
        self.rates = rates;
        self.refresh();
        Ok(report)
    }

    /// One rate per state (none when `D = 1`: the pmf is then fixed).
    fn n_parameters(&self) -> usize {
        if self.max_duration > 1 {
            self.rates.len()
        } else {
            0
        }
    }
}
