//! pbdlib's Gaussian durations, discretised and truncated to `1..=D`.

use super::{
    check_counts, check_pmf_call, check_shape, expected_log_pmf, golden_max, log_normalise,
    solve_natural, table_row, Duration, DurationEvent, DurationRegularisation, DurationReport,
};
use crate::error::{invalid, HsmmError, Result};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize)]
struct GaussianParams {
    max_duration: usize,
    means: Vec<f64>,
    stds: Vec<f64>,
}

/// Gaussian durations as pbdlib defines them: `p_i(d) ∝ exp(−(d − μ_i)² / (2σ_i²))`
/// on `d = 1..=D`, renormalised there.
///
/// pbdlib estimates `μ, σ` from Viterbi segment lengths after fitting an HMM
/// (and adds 2 frames to `σ`); here they are learnt by EM with the emissions.
/// The M-step is the exact maximum of the truncated likelihood over `μ` and
/// `σ ≥ min_std` ([`DurationRegularisation::with_min_std`]): the family is
/// exponential in `(μ/σ², −1/(2σ²))`, so for fixed `σ` the expected
/// log-likelihood is concave in `μ` (solved by safeguarded Newton) and its
/// profile is unimodal in `σ` (golden-section search in `ln σ`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "GaussianParams", into = "GaussianParams")]
pub struct GaussianDuration {
    max_duration: usize,
    means: Vec<f64>,
    stds: Vec<f64>,
    log_pmf: Vec<f64>,
}

impl TryFrom<GaussianParams> for GaussianDuration {
    type Error = HsmmError;
    fn try_from(p: GaussianParams) -> Result<Self> {
        GaussianDuration::new(p.max_duration, p.means, p.stds)
    }
}

impl From<GaussianDuration> for GaussianParams {
    fn from(d: GaussianDuration) -> Self {
        GaussianParams {
            max_duration: d.max_duration,
            means: d.means,
            stds: d.stds,
        }
    }
}

/// `log p(d)`, `d = 1..=D`, of the truncated discretised Gaussian.
fn log_pmf_row(mean: f64, std: f64, out: &mut [f64]) {
    let c = -0.5 / (std * std);
    for (k, o) in out.iter_mut().enumerate() {
        let z = (k + 1) as f64 - mean;
        *o = c * z * z;
    }
    log_normalise(out);
}

impl GaussianDuration {
    /// Durations with means `μ_i` (finite, frames) and standard deviations `σ_i > 0`.
    pub fn new(max_duration: usize, means: Vec<f64>, stds: Vec<f64>) -> Result<Self> {
        check_shape(means.len(), max_duration)?;
        if stds.len() != means.len() {
            return Err(invalid(
                "stds",
                format!(
                    "{} standard deviations for {} means",
                    stds.len(),
                    means.len()
                ),
            ));
        }
        if let Some(i) = means.iter().position(|m| !m.is_finite()) {
            return Err(invalid(
                "means",
                format!("state {i}: the mean duration {} is not finite", means[i]),
            ));
        }
        if let Some(i) = stds.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(invalid(
                "stds",
                format!(
                    "state {i}: the standard deviation {} is not positive and finite",
                    stds[i]
                ),
            ));
        }
        let mut d = GaussianDuration {
            max_duration,
            means,
            stds,
            log_pmf: Vec::new(),
        };
        d.refresh();
        Ok(d)
    }

    /// A template for fitting: `S` states, every mean `D / 2`, every width `D / 4`.
    pub fn template(n_states: usize, max_duration: usize) -> Result<Self> {
        check_shape(n_states, max_duration)?;
        let dm = max_duration as f64;
        Self::new(
            max_duration,
            vec![dm / 2.0; n_states],
            vec![(dm / 4.0).max(1.0); n_states],
        )
    }

    /// The means `μ_i` (frames; of the untruncated Gaussian).
    pub fn means(&self) -> &[f64] {
        &self.means
    }

    /// The standard deviations `σ_i` (frames; of the untruncated Gaussian).
    pub fn stds(&self) -> &[f64] {
        &self.stds
    }

    fn refresh(&mut self) {
        let dm = self.max_duration;
        self.log_pmf = vec![0.0; self.means.len() * dm];
        for ((m, s), row) in self
            .means
            .iter()
            .zip(&self.stds)
            .zip(self.log_pmf.chunks_exact_mut(dm))
        {
            log_pmf_row(*m, *s, row);
        }
    }
}

/// The best `(μ, σ)` for counts `c` with `σ ∈ [min_std, σ_max]`; returns
/// `(μ, σ, at_bound)`.
fn fit_counts(c: &[f64], min_std: f64, start_mean: f64) -> (f64, f64, bool) {
    let dm = c.len();
    let total: f64 = c.iter().sum();
    let t: Vec<f64> = (1..=dm).map(|d| d as f64).collect();
    let tbar = c.iter().zip(&t).map(|(c, t)| c * t).sum::<f64>() / total;
    let max_std = (4.0 * dm as f64).max(10.0 * min_std);
    let mut h = vec![0.0; dm];
    let mut row = vec![0.0; dm];
    // The best mean for a given width, and the expected log-likelihood there.
    let mut best_for = |ln_std: f64| -> (f64, f64) {
        let std = ln_std.exp();
        let prec = 1.0 / (std * std);
        let theta2 = -0.5 * prec;
        for (h, t) in h.iter_mut().zip(&t) {
            *h = theta2 * t * t;
        }
        // θ1 = μ/σ²: wide enough for a mean anywhere in [1 − D, 2D] and for
        // a tilt of 40 nats per frame (a wide Gaussian whose mean lies far
        // outside the support is an exponential tilt on it).
        let (lo, hi) = (
            ((1.0 - dm as f64) * prec).min(-40.0),
            (2.0 * dm as f64 * prec).max(40.0),
        );
        let (theta1, _) = solve_natural(&h, &t, tbar, lo, hi, start_mean * prec);
        let mean = theta1 / prec;
        log_pmf_row(mean, std, &mut row);
        (mean, expected_log_pmf(c, &row))
    };
    let (lo, hi) = (min_std.ln(), max_std.ln());
    let (ln_std, _) = golden_max(|u| best_for(u).1, lo, hi, 1e-10);
    let (mean, _) = best_for(ln_std);
    let at_bound = ln_std == lo || ln_std == hi;
    (mean, ln_std.exp(), at_bound)
}

impl Duration for GaussianDuration {
    fn n_states(&self) -> usize {
        self.means.len()
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
            return Ok(report);
        }
        let (mut means, mut stds) = (self.means.clone(), self.stds.clone());
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
            let (mean, std, at_bound) = fit_counts(c, reg.min_std(), self.means[i]);
            log_pmf_row(mean, std, &mut row);
            let q_new = expected_log_pmf(c, &row);
            let q_old = expected_log_pmf(c, table_row(&self.log_pmf, dm, i));
            if q_new >= q_old || q_old.is_nan() {
                means[i] = mean;
                stds[i] = std;
                if at_bound {
                    report.events.push(DurationEvent::AtBound {
                        state: i,
                        parameter: "std".into(),
                        value: std,
                    });
                }
            } else {
                report
                    .events
                    .push(DurationEvent::KeptNoImprovement { state: i });
            }
        }
        self.means = means;
        self.stds = stds;
        self.refresh();
        Ok(report)
    }

    /// `μ` and `σ` per state (fewer when `D ≤ 2` leaves fewer free probabilities).
    fn n_parameters(&self) -> usize {
        self.means.len() * 2.min(self.max_duration - 1)
    }
}
