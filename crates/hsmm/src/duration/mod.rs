//! State duration distributions `p_i(d)`, `d = 1, …, D` (`D` = the maximum duration).
//!
//! A [`Duration`] is the set of `S` per-state distributions of how many
//! frames a visit to a state lasts, on the support `1..=D`. The HSMM is
//! generic over it, like it is over the emission; built in are
//!
//! * [`NonParametricDuration`]: a free probability vector per state;
//! * [`PoissonDuration`]: `p(d) ∝ λ^{d−1} / (d−1)!` (a Poisson shifted to start at 1);
//! * [`NegativeBinomialDuration`]: `p(d) ∝ Γ(d−1+r) / (Γ(r) (d−1)!) q^{d−1}` (over-dispersed);
//! * [`GaussianDuration`]: pbdlib's `p(d) ∝ exp(−(d − μ)² / (2σ²))`;
//! * [`AnyDuration`]: one of the above, chosen at run time (the default of [`crate::Hsmm`]).
//!
//! Every parametric family is truncated to `1..=D` and renormalised there
//! (as pbdlib does), so that the model is exactly the one the recursions use.
//!
//! **M-step.** The E-step gives, per state, the expected number `c_i(d)` of
//! complete visits lasting `d` frames (right-censored last visits already
//! imputed, see [`crate::Censoring`]). [`Duration::m_step`] maximises
//! `Q_i = Σ_d c_i(d) log p_i(d)` over the family's parameters:
//! `p_i(d) = (c_i(d) + α) / Σ_d' (c_i(d') + α)` for the non-parametric pmf
//! (`α` the Dirichlet pseudo-count), and the exact maximum of the truncated
//! likelihood for the parametric ones (which is not the untruncated moment
//! estimate): a safeguarded Newton solve of `E_θ[d] = Σ c d / Σ c` in the
//! natural parameter for the Poisson, a concave profile search in `σ` for
//! the Gaussian, a profile search in `r` for the negative binomial. A new
//! parameter is kept only when `Q_i` did not decrease (so EM stays monotone
//! even where a search is not exact).

mod gaussian;
mod negative_binomial;
mod nonparametric;
mod poisson;

pub use gaussian::GaussianDuration;
pub use negative_binomial::NegativeBinomialDuration;
pub use nonparametric::NonParametricDuration;
pub use poisson::PoissonDuration;

use crate::error::{invalid, Result};
use serde::{Deserialize, Serialize};
use std::fmt::Debug;

/// The duration distributions `p_i(d)`, `i = 0..S`, `d = 1..=D`, of an HSMM.
pub trait Duration: Clone + Debug + Send + Sync {
    /// Number of states `S`.
    fn n_states(&self) -> usize;

    /// The maximum duration `D` (frames); the support is `1..=D`.
    fn max_duration(&self) -> usize;

    /// Writes `out[d − 1] = log p_i(d)` for `d = 1..=D` (`out` holds `D` values).
    ///
    /// Errors when `state` is out of range or `out` has another length.
    fn log_pmf_into(&self, state: usize, out: &mut [f64]) -> Result<()>;

    /// Re-estimates the parameters from expected duration counts `counts`
    /// (`S × D` row-major, `counts[i·D + d − 1] = c_i(d)`), maximising
    /// `Σ_d c_i(d) log p_i(d)` (plus the log-prior of `reg`) for every state.
    /// A state with total count below `reg.min_weight()` keeps its parameters.
    /// On error `self` is left unchanged.
    fn m_step(&mut self, counts: &[f64], reg: &DurationRegularisation) -> Result<DurationReport>;

    /// Log-density of the prior implied by `reg` at the current parameters, up
    /// to a constant (0 when `reg` is not a prior). EM increases
    /// `log p(X) + log_prior` monotonically.
    fn log_prior(&self, reg: &DurationRegularisation) -> f64 {
        let _ = reg;
        0.0
    }

    /// Number of free parameters (for AIC/BIC).
    fn n_parameters(&self) -> usize;
}

/// Regularisation of the duration M-step, validated at construction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "DurationRegularisationRaw")]
pub struct DurationRegularisation {
    pseudo_count: f64,
    min_std: f64,
    min_weight: f64,
}

#[derive(Deserialize)]
struct DurationRegularisationRaw {
    pseudo_count: f64,
    min_std: f64,
    min_weight: f64,
}

impl TryFrom<DurationRegularisationRaw> for DurationRegularisation {
    type Error = crate::HsmmError;
    fn try_from(r: DurationRegularisationRaw) -> Result<Self> {
        DurationRegularisation::default()
            .with_pseudo_count(r.pseudo_count)?
            .with_min_std(r.min_std)?
            .with_min_weight(r.min_weight)
    }
}

impl Default for DurationRegularisation {
    /// No pseudo-count, Gaussian durations at least 0.5 frame wide, states
    /// with total count below `1e-10` kept unchanged.
    fn default() -> Self {
        DurationRegularisation {
            pseudo_count: 0.0,
            min_std: 0.5,
            min_weight: 1e-10,
        }
    }
}

fn nonneg(name: &'static str, v: f64) -> Result<f64> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(invalid(
            name,
            format!("must be finite and non-negative, got {v}"),
        ))
    }
}

impl DurationRegularisation {
    /// No pseudo-count (maximum likelihood), `min_std = 0.5`, `min_weight = 1e-10`.
    pub fn none() -> Self {
        Self::default()
    }

    /// Dirichlet pseudo-count `α ≥ 0` added to every count of a non-parametric
    /// pmf: `p(d) = (c(d) + α) / (Σ c + α D)`, the posterior mode under a
    /// symmetric Dirichlet(`α + 1`) prior (EM then increases the penalised
    /// objective monotonically). It keeps every duration possible.
    pub fn with_pseudo_count(mut self, alpha: f64) -> Result<Self> {
        self.pseudo_count = nonneg("duration pseudo_count", alpha)?;
        Ok(self)
    }

    /// The smallest standard deviation `σ` (frames, > 0) a Gaussian duration
    /// may take. A constraint of the M-step (the maximum over `σ ≥ min_std`),
    /// not a prior: EM stays monotone in the likelihood.
    pub fn with_min_std(mut self, s: f64) -> Result<Self> {
        let s = nonneg("duration min_std", s)?;
        if s == 0.0 {
            return Err(invalid(
                "duration min_std",
                "must be positive (a zero width is a point mass)",
            ));
        }
        self.min_std = s;
        Ok(self)
    }

    /// States whose total duration count is below `w` keep their parameters.
    pub fn with_min_weight(mut self, w: f64) -> Result<Self> {
        self.min_weight = nonneg("duration min_weight", w)?;
        Ok(self)
    }

    /// The Dirichlet pseudo-count of non-parametric pmfs.
    pub fn pseudo_count(&self) -> f64 {
        self.pseudo_count
    }

    /// The smallest standard deviation of a Gaussian duration.
    pub fn min_std(&self) -> f64 {
        self.min_std
    }

    /// Minimum total count for a state to be re-estimated.
    pub fn min_weight(&self) -> f64 {
        self.min_weight
    }
}

/// One thing a duration M-step had to do beyond the plain update.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum DurationEvent {
    /// The state's total count was below the minimum; it kept its parameters.
    KeptEmptyState {
        /// State index.
        state: usize,
        /// Its total expected count.
        weight: f64,
    },
    /// The maximum lies on a bound of the parameter's search range (e.g. every
    /// visit lasts one frame: a Poisson rate at its lower bound).
    AtBound {
        /// State index.
        state: usize,
        /// Which parameter.
        parameter: String,
        /// Its value.
        value: f64,
    },
    /// The search did not improve `Σ c log p`; the state kept its parameters.
    KeptNoImprovement {
        /// State index.
        state: usize,
    },
}

/// What a duration M-step did.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct DurationReport {
    /// States that were kept or sit on a bound.
    pub events: Vec<DurationEvent>,
}

// ---------------------------------------------------------------------------
// Shared helpers of the families
// ---------------------------------------------------------------------------

/// Checks the shape shared by every family: `S ≥ 1` states, `D ≥ 1`.
pub(crate) fn check_shape(n_states: usize, max_duration: usize) -> Result<()> {
    if n_states == 0 {
        return Err(invalid("durations", "at least one state is needed"));
    }
    if max_duration == 0 {
        return Err(invalid(
            "max_duration",
            "the maximum duration must be at least 1 frame",
        ));
    }
    // Every table of the model is `S × D` (the pmf, the forward variable's
    // duration axis): refuse a size that cannot be allocated before it is
    // (a hand-edited file or `max-duration=10^12` is an error, not an abort).
    match n_states.checked_mul(max_duration) {
        Some(cells) if cells <= MAX_DURATION_CELLS => Ok(()),
        _ => Err(invalid(
            "max_duration",
            format!(
                "{n_states} states × a maximum duration of {max_duration} frames exceed \
                 {MAX_DURATION_CELLS} cells of the duration tables"
            ),
        )),
    }
}

/// The largest `S · D` the duration tables may have (2²⁴ cells, 128 MiB of f64).
pub const MAX_DURATION_CELLS: usize = 1 << 24;

/// Checks the arguments of [`Duration::log_pmf_into`].
pub(crate) fn check_pmf_call(
    n_states: usize,
    max_duration: usize,
    state: usize,
    out: &[f64],
) -> Result<()> {
    if state >= n_states {
        return Err(invalid(
            "state",
            format!("state {state} out of range (the durations have {n_states} states)"),
        ));
    }
    if out.len() != max_duration {
        return Err(invalid(
            "out",
            format!(
                "{} values for a duration pmf of {max_duration} entries",
                out.len()
            ),
        ));
    }
    Ok(())
}

/// Checks the counts given to an M-step: `S × D`, finite and non-negative.
pub(crate) fn check_counts(n_states: usize, max_duration: usize, counts: &[f64]) -> Result<()> {
    if counts.len() != n_states * max_duration {
        return Err(invalid(
            "duration counts",
            format!(
                "{} entries, expected {n_states} states × {max_duration} durations = {}",
                counts.len(),
                n_states * max_duration
            ),
        ));
    }
    if let Some(k) = counts.iter().position(|c| !(c.is_finite() && *c >= 0.0)) {
        return Err(invalid(
            "duration counts",
            format!(
                "state {}, duration {}: {} is not a finite non-negative count",
                k / max_duration,
                k % max_duration + 1,
                counts[k]
            ),
        ));
    }
    Ok(())
}

/// `log Σ_i e^{x_i}` (exact for `−inf` entries; `−inf` when all are).
pub(crate) fn lse(x: &[f64]) -> f64 {
    let m = x.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + x.iter().map(|v| (v - m).exp()).sum::<f64>().ln()
}

/// Shifts `log_w` so that it is a log-pmf (its log-sum-exp becomes 0).
pub(crate) fn log_normalise(log_w: &mut [f64]) {
    let z = lse(log_w);
    if z.is_finite() {
        log_w.iter_mut().for_each(|v| *v -= z);
    }
}

/// `Σ_d c(d) log p(d)`, with `0 · log 0 = 0`.
pub(crate) fn expected_log_pmf(counts: &[f64], log_pmf: &[f64]) -> f64 {
    counts
        .iter()
        .zip(log_pmf)
        .filter(|(c, _)| **c > 0.0)
        .map(|(c, l)| c * l)
        .sum()
}

/// `ln (n!)` for `n = 0..len`, by summing logarithms (exact to rounding).
pub(crate) fn ln_factorials(len: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(len);
    let mut acc = 0.0;
    for n in 0..len {
        if n > 1 {
            acc += (n as f64).ln();
        }
        out.push(acc);
    }
    out
}

/// The maximiser of the concave `q(η) = η Σ_d c_d t_d − N log Σ_d e^{η t_d + h_d}`
/// over `[lo, hi]`, i.e. the root of `t̄ = E_η[t]` with `t̄ = Σ c t / N`, for an
/// exponential family on a finite support with base log-measure `h` and
/// statistic `t`. Safeguarded Newton (the derivative `−Var_η[t]` is known):
/// a step that leaves the bracket, or does not halve it, is replaced by a
/// bisection. Returns the root and whether it sits on a bound.
pub(crate) fn solve_natural(
    h: &[f64],
    t: &[f64],
    tbar: f64,
    lo: f64,
    hi: f64,
    start: f64,
) -> (f64, bool) {
    // g(η) = t̄ − E_η[t] is decreasing in η.
    let moments = |eta: f64| -> (f64, f64) {
        let m = h
            .iter()
            .zip(t)
            .map(|(h, t)| eta * t + h)
            .fold(f64::NEG_INFINITY, f64::max);
        let (mut z, mut s1, mut s2) = (0.0, 0.0, 0.0);
        for (h, t) in h.iter().zip(t) {
            let w = (eta * t + h - m).exp();
            z += w;
            s1 += w * t;
            s2 += w * t * t;
        }
        let mean = s1 / z;
        (mean, (s2 / z - mean * mean).max(0.0))
    };
    let (g_lo, _) = moments(lo);
    if tbar - g_lo <= 0.0 {
        return (lo, true);
    }
    let (g_hi, _) = moments(hi);
    if tbar - g_hi >= 0.0 {
        return (hi, true);
    }
    let (mut a, mut b) = (lo, hi);
    let mut eta = start.clamp(lo, hi);
    for _ in 0..200 {
        let (mean, var) = moments(eta);
        let g = tbar - mean;
        if g == 0.0 {
            return (eta, false);
        }
        if g > 0.0 {
            a = eta;
        } else {
            b = eta;
        }
        let width = b - a;
        if width <= 1e-14 * (1.0 + eta.abs()) {
            break;
        }
        let newton = if var > 0.0 { eta + g / var } else { f64::NAN };
        eta = if newton > a && newton < b && (newton - eta).abs() < 0.5 * width {
            newton
        } else {
            0.5 * (a + b)
        };
    }
    (eta, false)
}

/// Golden-section search for the maximum of a unimodal `f` over `[lo, hi]`;
/// returns the best point evaluated and its value.
pub(crate) fn golden_max(mut f: impl FnMut(f64) -> f64, lo: f64, hi: f64, tol: f64) -> (f64, f64) {
    const INV_PHI: f64 = 0.618_033_988_749_894_9;
    let (mut a, mut b) = (lo, hi);
    let mut c = b - INV_PHI * (b - a);
    let mut d = a + INV_PHI * (b - a);
    let (mut fc, mut fd) = (f(c), f(d));
    let (mut best_x, mut best_f) = if fc >= fd { (c, fc) } else { (d, fd) };
    // The ends too: the maximum of a monotone profile is on a bound.
    for x in [lo, hi] {
        let fx = f(x);
        if fx > best_f {
            best_x = x;
            best_f = fx;
        }
    }
    let mut iter = 0;
    while b - a > tol && iter < 200 {
        iter += 1;
        if fc >= fd {
            b = d;
            d = c;
            fd = fc;
            c = b - INV_PHI * (b - a);
            fc = f(c);
            if fc > best_f {
                best_x = c;
                best_f = fc;
            }
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + INV_PHI * (b - a);
            fd = f(d);
            if fd > best_f {
                best_x = d;
                best_f = fd;
            }
        }
    }
    (best_x, best_f)
}

/// Per-state table of log-pmfs (`S × D`), the form every family caches.
pub(crate) fn table_row(table: &[f64], max_duration: usize, state: usize) -> &[f64] {
    &table[state * max_duration..(state + 1) * max_duration]
}

/// One of the built-in duration families, chosen at run time.
///
/// Serialised with a `family` tag (`non_parametric`, `poisson`,
/// `negative_binomial`, `gaussian`) beside the family's own fields.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "family", rename_all = "snake_case")]
pub enum AnyDuration {
    /// A free pmf per state.
    NonParametric(NonParametricDuration),
    /// Shifted Poisson.
    Poisson(PoissonDuration),
    /// Shifted negative binomial.
    NegativeBinomial(NegativeBinomialDuration),
    /// pbdlib's discretised Gaussian.
    Gaussian(GaussianDuration),
}

impl AnyDuration {
    /// The family's name (`non_parametric`, `poisson`, `negative_binomial`, `gaussian`).
    pub fn family(&self) -> &'static str {
        match self {
            AnyDuration::NonParametric(_) => "non_parametric",
            AnyDuration::Poisson(_) => "poisson",
            AnyDuration::NegativeBinomial(_) => "negative_binomial",
            AnyDuration::Gaussian(_) => "gaussian",
        }
    }
}

macro_rules! dispatch {
    ($self:expr, $d:ident => $e:expr) => {
        match $self {
            AnyDuration::NonParametric($d) => $e,
            AnyDuration::Poisson($d) => $e,
            AnyDuration::NegativeBinomial($d) => $e,
            AnyDuration::Gaussian($d) => $e,
        }
    };
}

impl Duration for AnyDuration {
    fn n_states(&self) -> usize {
        dispatch!(self, d => d.n_states())
    }
    fn max_duration(&self) -> usize {
        dispatch!(self, d => d.max_duration())
    }
    fn log_pmf_into(&self, state: usize, out: &mut [f64]) -> Result<()> {
        dispatch!(self, d => d.log_pmf_into(state, out))
    }
    fn m_step(&mut self, counts: &[f64], reg: &DurationRegularisation) -> Result<DurationReport> {
        dispatch!(self, d => d.m_step(counts, reg))
    }
    fn log_prior(&self, reg: &DurationRegularisation) -> f64 {
        dispatch!(self, d => d.log_prior(reg))
    }
    fn n_parameters(&self) -> usize {
        dispatch!(self, d => d.n_parameters())
    }
}

impl From<NonParametricDuration> for AnyDuration {
    fn from(d: NonParametricDuration) -> Self {
        AnyDuration::NonParametric(d)
    }
}
impl From<PoissonDuration> for AnyDuration {
    fn from(d: PoissonDuration) -> Self {
        AnyDuration::Poisson(d)
    }
}
impl From<NegativeBinomialDuration> for AnyDuration {
    fn from(d: NegativeBinomialDuration) -> Self {
        AnyDuration::NegativeBinomial(d)
    }
}
impl From<GaussianDuration> for AnyDuration {
    fn from(d: GaussianDuration) -> Self {
        AnyDuration::Gaussian(d)
    }
}
