//! Shifted negative binomial durations, truncated to `1..=D`.

use super::{
    check_counts, check_pmf_call, check_shape, expected_log_pmf, golden_max, log_normalise,
    solve_natural, table_row, Duration, DurationEvent, DurationRegularisation, DurationReport,
};
use crate::error::{invalid, HsmmError, Result};
use serde::{Deserialize, Serialize};

/// Search range of `ln r` in the M-step (`r ∈ [0.01, 10⁴]`; at the top the
/// family is a Poisson to within the truncation).
const LN_SHAPE_RANGE: (f64, f64) = (-4.605_170_185_988_091, 9.210_340_371_976_184);
/// Search range of `ln q` for a given `r` (`q ∈ [e^{−30}, 1 − 10⁻¹²]`).
const LN_PROB_RANGE: (f64, f64) = (-30.0, -1e-12);

#[derive(Serialize, Deserialize)]
struct NegativeBinomialParams {
    max_duration: usize,
    shapes: Vec<f64>,
    probs: Vec<f64>,
}

/// Negative binomial durations shifted to start at one frame and truncated
/// to `1..=D`: `p_i(d) ∝ Γ(d − 1 + r_i) / (Γ(r_i) (d − 1)!) · q_i^{d−1}`,
/// `r_i > 0`, `0 < q_i < 1`.
///
/// Before truncation the mean is `1 + r q / (1 − q)` and the variance
/// `r q / (1 − q)²`, larger than the mean − 1 (over-dispersed, unlike the
/// Poisson, which it tends to as `r → ∞`). The M-step maximises the truncated
/// likelihood: for fixed `r` exactly (an exponential family in `ln q`,
/// safeguarded Newton), over `r` by a grid and golden-section search of the
/// profile in `ln r`; a new value is kept only when it is not worse.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "NegativeBinomialParams", into = "NegativeBinomialParams")]
pub struct NegativeBinomialDuration {
    max_duration: usize,
    shapes: Vec<f64>,
    probs: Vec<f64>,
    log_pmf: Vec<f64>,
}

impl TryFrom<NegativeBinomialParams> for NegativeBinomialDuration {
    type Error = HsmmError;
    fn try_from(p: NegativeBinomialParams) -> Result<Self> {
        NegativeBinomialDuration::new(p.max_duration, p.shapes, p.probs)
    }
}

impl From<NegativeBinomialDuration> for NegativeBinomialParams {
    fn from(d: NegativeBinomialDuration) -> Self {
        NegativeBinomialParams {
            max_duration: d.max_duration,
            shapes: d.shapes,
            probs: d.probs,
        }
    }
}

/// The base log-measure `ln Γ(d − 1 + r) − ln Γ(r) − ln (d − 1)!`, `d = 1..=D`.
fn base_measure(shape: f64, out: &mut [f64]) {
    let lg_r = libm::lgamma(shape);
    for (k, o) in out.iter_mut().enumerate() {
        *o = libm::lgamma(k as f64 + shape) - lg_r - libm::lgamma(k as f64 + 1.0);
    }
}

fn log_pmf_row(shape: f64, prob: f64, out: &mut [f64]) {
    base_measure(shape, out);
    let lq = prob.ln();
    for (k, o) in out.iter_mut().enumerate() {
        *o += k as f64 * lq;
    }
    log_normalise(out);
}

impl NegativeBinomialDuration {
    /// Durations with shapes `r_i > 0` and success probabilities `q_i ∈ (0, 1)`.
    pub fn new(max_duration: usize, shapes: Vec<f64>, probs: Vec<f64>) -> Result<Self> {
        check_shape(shapes.len(), max_duration)?;
        if probs.len() != shapes.len() {
            return Err(invalid(
                "probs",
                format!("{} probabilities for {} shapes", probs.len(), shapes.len()),
            ));
        }
        if let Some(i) = shapes.iter().position(|r| !(r.is_finite() && *r > 0.0)) {
            return Err(invalid(
                "shapes",
                format!(
                    "state {i}: the shape {} is not positive and finite",
                    shapes[i]
                ),
            ));
        }
        if let Some(i) = probs.iter().position(|q| !(*q > 0.0 && *q < 1.0)) {
            return Err(invalid(
                "probs",
                format!("state {i}: the probability {} is not in (0, 1)", probs[i]),
            ));
        }
        let mut d = NegativeBinomialDuration {
            max_duration,
            shapes,
            probs,
            log_pmf: Vec::new(),
        };
        d.refresh();
        Ok(d)
    }

    /// A template for fitting: `S` states, `r = 2`, mean `D / 2` before truncation.
    pub fn template(n_states: usize, max_duration: usize) -> Result<Self> {
        check_shape(n_states, max_duration)?;
        let m = (max_duration as f64 / 2.0 - 1.0).max(0.5);
        // mean − 1 = r q / (1 − q)  ⇒  q = m / (m + r)
        Self::new(
            max_duration,
            vec![2.0; n_states],
            vec![m / (m + 2.0); n_states],
        )
    }

    /// The shapes `r_i`.
    pub fn shapes(&self) -> &[f64] {
        &self.shapes
    }

    /// The success probabilities `q_i`.
    pub fn probs(&self) -> &[f64] {
        &self.probs
    }

    fn refresh(&mut self) {
        let dm = self.max_duration;
        self.log_pmf = vec![0.0; self.shapes.len() * dm];
        for ((r, q), row) in self
            .shapes
            .iter()
            .zip(&self.probs)
            .zip(self.log_pmf.chunks_exact_mut(dm))
        {
            log_pmf_row(*r, *q, row);
        }
    }
}

/// The best `(r, q)` for counts `c`; returns `(r, q, at_bound)`.
fn fit_counts(c: &[f64], start_prob: f64) -> (f64, f64, bool) {
    let dm = c.len();
    let total: f64 = c.iter().sum();
    let t: Vec<f64> = (0..dm).map(|k| k as f64).collect();
    let tbar = c.iter().zip(&t).map(|(c, t)| c * t).sum::<f64>() / total;
    let mut h = vec![0.0; dm];
    let mut row = vec![0.0; dm];
    let mut best_for = |ln_shape: f64| -> (f64, f64) {
        let shape = ln_shape.exp();
        base_measure(shape, &mut h);
        let (lo, hi) = LN_PROB_RANGE;
        let (eta, _) = solve_natural(&h, &t, tbar, lo, hi, start_prob.ln());
        let prob = eta.exp().min(1.0 - 1e-12);
        log_pmf_row(shape, prob, &mut row);
        (prob, expected_log_pmf(c, &row))
    };
    // The profile in ln r need not be unimodal: a coarse grid finds the best
    // cell, and golden section refines within its neighbours.
    let (lo, hi) = LN_SHAPE_RANGE;
    const GRID: usize = 28;
    let step = (hi - lo) / GRID as f64;
    let mut best = (lo, f64::NEG_INFINITY);
    for g in 0..=GRID {
        let x = lo + g as f64 * step;
        let q = best_for(x).1;
        if q > best.1 {
            best = (x, q);
        }
    }
    let (a, b) = ((best.0 - step).max(lo), (best.0 + step).min(hi));
    let (x, q) = golden_max(|u| best_for(u).1, a, b, 1e-9);
    let ln_shape = if q >= best.1 { x } else { best.0 };
    let (prob, _) = best_for(ln_shape);
    (ln_shape.exp(), prob, ln_shape == lo || ln_shape == hi)
}

impl Duration for NegativeBinomialDuration {
    fn n_states(&self) -> usize {
        self.shapes.len()
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
        let (mut shapes, mut probs) = (self.shapes.clone(), self.probs.clone());
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
            let (shape, prob, at_bound) = fit_counts(c, self.probs[i]);
            log_pmf_row(shape, prob, &mut row);
            let q_new = expected_log_pmf(c, &row);
            let q_old = expected_log_pmf(c, table_row(&self.log_pmf, dm, i));
            if q_new >= q_old || q_old.is_nan() {
                shapes[i] = shape;
                probs[i] = prob;
                if at_bound {
                    report.events.push(DurationEvent::AtBound {
                        state: i,
                        parameter: "shape".into(),
                        value: shape,
                    });
                }
            } else {
                report
                    .events
                    .push(DurationEvent::KeptNoImprovement { state: i });
            }
        }
        self.shapes = shapes;
        self.probs = probs;
        self.refresh();
        Ok(report)
    }

    /// `r` and `q` per state (fewer when `D ≤ 2`).
    fn n_parameters(&self) -> usize {
        self.shapes.len() * 2.min(self.max_duration - 1)
    }
}
