//! The multivariate Student-t distribution (full scale matrix), robust to
//! outlying frames such as the marker glitches of motion capture; written on
//! the per-state route ([`crate::StateDistribution`]) as its worked example:
//! `PerState<StudentT>` is the emission.
//!
//! `log t(x; μ, Σ, ν) = log Γ((ν + D)/2) − log Γ(ν/2) − (D/2) log(νπ) − ½ log|Σ|
//! − ((ν + D)/2) log(1 + δ/ν)`, with `δ = (x − μ)ᵀ Σ⁻¹ (x − μ)` computed as
//! `‖L⁻¹ (x − μ)‖²` for the Cholesky factor `Σ = L Lᵀ`.
//!
//! The t is a scale mixture of Gaussians, `x | u ~ N(μ, Σ/u)`,
//! `u ~ Gamma(ν/2, ν/2)`; its weighted fit is one ECME step (Liu & Rubin 1995):
//!
//! * E: `u_t = (ν + p_t)/(ν + δ_t)` under the current parameters (`p_t` the
//!   number of observed values of frame `t`, `δ_t` on their marginal; the
//!   missing values take their conditional mean `x̂_m = μ_m + Σ_mo Σ_oo⁻¹ (x_o − μ_o)`
//!   and add their conditional covariance `C_t = Σ_mm − Σ_mo Σ_oo⁻¹ Σ_om`);
//! * CM 1: `μ = Σ_t w_t u_t x̂_t / Σ_t w_t u_t`,
//!   `Σ = (Σ_t w_t [u_t (x̂_t − μ)(x̂_t − μ)ᵀ + C_t]) / Σ_t w_t` (regularised
//!   like every covariance, [`crate::regularised_covariance`]);
//! * CM 2 (when ν is estimated): `ν = argmax Σ_t w_t log t(x_{t,o}; μ, Σ, ν)`,
//!   the observed-data likelihood itself, by golden-section search on `log ν`
//!   in `[0.5, 1000]`, kept only if it does not lower that likelihood.
//!
//! Each step increases the weighted observed-data log-likelihood, so EM over
//! an HMM or a mixture of Student-t states stays monotone.
//!
//! The conditional of output dims `O` given input dims `I` is again a
//! Student-t, with `ν' = ν + |I|`, location `μ_O + Σ_OI Σ_II⁻¹ (x_I − μ_I)` and
//! scale `(ν + δ_I)/(ν + |I|) (Σ_OO − Σ_OI Σ_II⁻¹ Σ_IO)`; its covariance,
//! `ν'/(ν' − 2)` times the scale, `= (ν + δ_I)/(ν + |I| − 2) Σ_O|I`, grows with
//! the input's Mahalanobis distance `δ_I` (finite when `ν + |I| > 2`).

use crate::error::{EmissionError, Result};
use crate::linalg::{self, packed_len, packed_lower_mul, packed_lower_sq_norm};
use crate::missing::{observed_dims, PatternCache};
use crate::per_state::{StateConditional, StateDistribution, StateSplit};
use crate::regularisation::{
    regularised_covariance, CovarianceRegularisation, MStepReport, Regularisation,
};
use crate::Frames;
use nalgebra::DMatrix;
use rand::Rng;
use rand_distr::{ChiSquared, Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Smallest and largest degrees of freedom the estimation considers.
pub const DOF_RANGE: (f64, f64) = (0.5, 1000.0);

/// Whether the degrees of freedom `ν` are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StudentTDof {
    /// `ν` stays as given.
    Fixed,
    /// `ν` is re-estimated by every fit (ECME), within [`DOF_RANGE`].
    Estimated,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct StudentTParams {
    mean: Vec<f64>,
    scale: Vec<f64>,
    dof: f64,
    dof_mode: StudentTDof,
}

/// One multivariate Student-t state: location `μ`, scale matrix `Σ`
/// (full, `D × D`), degrees of freedom `ν`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "StudentTParams", into = "StudentTParams")]
pub struct StudentT {
    mean: Vec<f64>,
    /// Row-major, symmetric positive definite.
    scale: Vec<f64>,
    dof: f64,
    dof_mode: StudentTDof,
    /// Packed `L⁻¹`.
    whiten: Vec<f64>,
    /// Packed `L`.
    factor: Vec<f64>,
    log_det: f64,
    /// `log Γ((ν + D)/2) − log Γ(ν/2) − (D/2) log(νπ) − ½ log|Σ|`.
    log_norm: f64,
}

impl TryFrom<StudentTParams> for StudentT {
    type Error = EmissionError;
    fn try_from(p: StudentTParams) -> Result<Self> {
        StudentT::new(p.mean, p.scale, p.dof, p.dof_mode)
    }
}

impl From<StudentT> for StudentTParams {
    fn from(t: StudentT) -> Self {
        StudentTParams {
            mean: t.mean,
            scale: t.scale,
            dof: t.dof,
            dof_mode: t.dof_mode,
        }
    }
}

fn invalid(name: &'static str, reason: String) -> EmissionError {
    EmissionError::InvalidParameter { name, reason }
}

/// `log Γ((ν + p)/2) − log Γ(ν/2) − (p/2) log(νπ)`.
fn t_constant(nu: f64, p: usize) -> f64 {
    libm::lgamma(0.5 * (nu + p as f64)) - libm::lgamma(0.5 * nu) - 0.5 * p as f64 * (nu * PI).ln()
}

impl StudentT {
    /// A Student-t with location `mean` (length `D ≥ 1`), scale `scale`
    /// (`D × D` row-major, symmetric to `1e-9` relative, positive definite)
    /// and `dof` degrees of freedom (finite, `> 0`; within [`DOF_RANGE`] when
    /// estimated).
    pub fn new(mean: Vec<f64>, scale: Vec<f64>, dof: f64, dof_mode: StudentTDof) -> Result<Self> {
        let d = mean.len();
        if d == 0 {
            return Err(invalid("mean", "must have at least one value".into()));
        }
        if let Some(k) = mean.iter().position(|v| !v.is_finite()) {
            return Err(invalid(
                "mean",
                format!("dim {k}: {} is not finite", mean[k]),
            ));
        }
        if scale.len() != d * d {
            return Err(invalid(
                "scale",
                format!("{} values for a {d} × {d} matrix", scale.len()),
            ));
        }
        if let Some(k) = scale.iter().position(|v| !v.is_finite()) {
            return Err(invalid(
                "scale",
                format!("entry {k}: {} is not finite", scale[k]),
            ));
        }
        for r in 0..d {
            for c in 0..r {
                let (a, b) = (scale[r * d + c], scale[c * d + r]);
                let tol = 1e-9 * scale[r * d + r].abs().max(scale[c * d + c].abs());
                if (a - b).abs() > tol.max(f64::MIN_POSITIVE) {
                    return Err(invalid(
                        "scale",
                        format!("not symmetric at ({r}, {c}): {a} vs {b}"),
                    ));
                }
            }
        }
        if !(dof.is_finite() && dof > 0.0) {
            return Err(invalid(
                "dof",
                format!("degrees of freedom must be finite and positive, got {dof}"),
            ));
        }
        if dof_mode == StudentTDof::Estimated && !(DOF_RANGE.0..=DOF_RANGE.1).contains(&dof) {
            return Err(invalid(
                "dof",
                format!(
                    "estimated degrees of freedom must start within [{}, {}], got {dof}",
                    DOF_RANGE.0, DOF_RANGE.1
                ),
            ));
        }
        let m = DMatrix::from_row_slice(d, d, &scale);
        let l = linalg::cholesky(&m).ok_or_else(|| EmissionError::NotPositiveDefinite {
            state: 0,
            component: None,
            detail: " (Student-t scale matrix)".into(),
        })?;
        let log_det = 2.0 * l.diagonal().iter().map(|v| v.ln()).sum::<f64>();
        let mut whiten = Vec::with_capacity(packed_len(d));
        let mut factor = Vec::with_capacity(packed_len(d));
        linalg::pack_lower(&linalg::lower_triangular_inverse(&l), &mut whiten);
        linalg::pack_lower(&l, &mut factor);
        Ok(StudentT {
            log_norm: t_constant(dof, d) - 0.5 * log_det,
            mean,
            scale,
            dof,
            dof_mode,
            whiten,
            factor,
            log_det,
        })
    }

    /// Location 0, scale `I`, `dof` degrees of freedom: a template for an
    /// initialisation ([`StateDistribution::initialise`] starts from the data).
    pub fn standard(dim: usize, dof: f64, dof_mode: StudentTDof) -> Result<Self> {
        let eye = (0..dim * dim)
            .map(|k| if k % (dim + 1) == 0 { 1.0 } else { 0.0 })
            .collect();
        Self::new(vec![0.0; dim], eye, dof, dof_mode)
    }

    /// Location `μ`.
    pub fn mean(&self) -> &[f64] {
        &self.mean
    }

    /// Scale matrix `Σ`, `D × D` row-major (the covariance is `ν/(ν − 2) Σ` for `ν > 2`).
    pub fn scale(&self) -> &[f64] {
        &self.scale
    }

    /// Degrees of freedom `ν`.
    pub fn dof(&self) -> f64 {
        self.dof
    }

    /// Whether `ν` is estimated.
    pub fn dof_mode(&self) -> StudentTDof {
        self.dof_mode
    }

    /// `log|Σ|`.
    pub fn log_det(&self) -> f64 {
        self.log_det
    }

    /// The same distribution with `ν` replaced (used by the ν step).
    fn with_dof(&self, dof: f64) -> Self {
        let mut t = self.clone();
        t.dof = dof;
        t.log_norm = t_constant(dof, self.mean.len()) - 0.5 * self.log_det;
        t
    }

    /// `δ = (x − μ)ᵀ Σ⁻¹ (x − μ)` of a complete frame.
    pub fn mahalanobis(&self, x: &[f64]) -> f64 {
        let d = self.mean.len();
        if d <= 64 {
            let mut buf = [0.0; 64];
            for k in 0..d {
                buf[k] = x[k] - self.mean[k];
            }
            packed_lower_sq_norm(&self.whiten, &buf[..d])
        } else {
            let v: Vec<f64> = x.iter().zip(&self.mean).map(|(a, b)| a - b).collect();
            packed_lower_sq_norm(&self.whiten, &v)
        }
    }

    /// The pattern machinery of one missing pattern under these parameters.
    fn pattern(&self, x: &[f64]) -> Result<Pattern> {
        let d = self.mean.len();
        let mut obs = Vec::with_capacity(d);
        observed_dims(x, &mut obs);
        let mis: Vec<usize> = (0..d).filter(|k| x[*k].is_nan()).collect();
        let s = DMatrix::from_row_slice(d, d, &self.scale);
        let sub = |rows: &[usize], cols: &[usize]| {
            DMatrix::from_fn(rows.len(), cols.len(), |r, c| s[(rows[r], cols[c])])
        };
        let marginal = self.marginal_on(&obs)?;
        let s_oo = sub(&obs, &obs);
        let chol =
            nalgebra::Cholesky::new(s_oo).ok_or_else(|| EmissionError::NotPositiveDefinite {
                state: 0,
                component: None,
                detail: format!(" (scale sub-block of the observed dims {obs:?})"),
            })?;
        let s_om = sub(&obs, &mis);
        let rt = chol.solve(&s_om); // Σ_oo⁻¹ Σ_om, |o| × |m|
        let cond = sub(&mis, &mis) - rt.transpose() * &s_om;
        Ok(Pattern {
            obs,
            mis,
            regression: rt.transpose(),
            conditional: (&cond + cond.transpose()) * 0.5,
            marginal,
        })
    }

    fn marginal_on(&self, dims: &[usize]) -> Result<StudentT> {
        let d = self.mean.len();
        let mean = dims.iter().map(|&k| self.mean[k]).collect();
        let scale = dims
            .iter()
            .flat_map(|&r| dims.iter().map(move |&c| self.scale[r * d + c]))
            .collect();
        StudentT::new(mean, scale, self.dof, self.dof_mode)
    }

    /// `Σ_t w_t log t(x_{t,o})` over weighted frames (missing values on their
    /// marginals), the quantity every fit increases.
    pub fn weighted_log_likelihood(&self, frames: Frames<'_>, weights: &[f64]) -> Result<f64> {
        let mut cache: PatternCache<Option<StudentT>> = PatternCache::new();
        let mut xo = Vec::new();
        let mut total = 0.0;
        for (x, &w) in frames.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            if !frames.has_missing() || !x.iter().any(|v| v.is_nan()) {
                total += w * self.log_density(x);
                continue;
            }
            let m = cache.get_or_try_insert(x, || {
                let mut obs = Vec::new();
                observed_dims(x, &mut obs);
                if obs.is_empty() {
                    Ok(None)
                } else {
                    self.marginal_on(&obs).map(Some)
                }
            })?;
            if let Some(m) = m {
                xo.clear();
                xo.extend(x.iter().filter(|v| !v.is_nan()));
                total += w * m.log_density(&xo);
            }
        }
        Ok(total)
    }

    /// One ECME step (see the module documentation).
    fn ecme_step(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        reg: &Regularisation,
        report: &mut MStepReport,
    ) -> Result<StudentT> {
        let d = self.mean.len();
        let nu = self.dof;
        let mut patterns: PatternCache<Pattern> = PatternCache::new();
        // E: weights u_t, completed frames x̂_t, summed conditional covariances.
        let mut u = Vec::with_capacity(frames.len());
        let mut xhat: Vec<f64> = Vec::new();
        let mut correction = DMatrix::<f64>::zeros(d, d);
        let (mut sw, mut swu) = (0.0, 0.0);
        let mut sum = vec![0.0; d];
        for (t, (x, &w)) in frames.iter().zip(weights).enumerate() {
            if frames.has_missing() {
                xhat.extend_from_slice(x);
            }
            if w == 0.0 || x.iter().all(|v| v.is_nan()) {
                u.push(0.0);
                continue;
            }
            let ut = if frames.has_missing() && x.iter().any(|v| v.is_nan()) {
                let p = patterns.get_or_try_insert(x, || self.pattern(x))?;
                let xo: Vec<f64> = p.obs.iter().map(|&k| x[k]).collect();
                let delta = p.marginal.mahalanobis(&xo);
                let row = &mut xhat[t * d..(t + 1) * d];
                for (a, &m) in p.mis.iter().enumerate() {
                    let mut v = self.mean[m];
                    for (b, &o) in p.obs.iter().enumerate() {
                        v += p.regression[(a, b)] * (x[o] - self.mean[o]);
                    }
                    row[m] = v;
                }
                for (a, &ma) in p.mis.iter().enumerate() {
                    for (b, &mb) in p.mis.iter().enumerate() {
                        correction[(ma, mb)] += w * p.conditional[(a, b)];
                    }
                }
                (nu + p.obs.len() as f64) / (nu + delta)
            } else {
                (nu + d as f64) / (nu + self.mahalanobis(x))
            };
            u.push(ut);
            sw += w;
            swu += w * ut;
            let xr = if frames.has_missing() {
                &xhat[t * d..(t + 1) * d]
            } else {
                x
            };
            for k in 0..d {
                sum[k] += w * ut * xr[k];
            }
        }
        if swu.is_nan() || swu <= 0.0 {
            return Err(EmissionError::plugin(
                Self::NAME,
                "no frame with positive weight to fit",
            ));
        }
        // CM 1: location and scale.
        let mean: Vec<f64> = sum.iter().map(|s| s / swu).collect();
        let mut scatter = correction;
        let data = if frames.has_missing() {
            &xhat[..]
        } else {
            frames.as_slice()
        };
        let mut e = vec![0.0; d];
        for ((x, &w), &ut) in data.chunks_exact(d).zip(weights).zip(&u) {
            let c = w * ut;
            if c == 0.0 {
                continue;
            }
            for k in 0..d {
                e[k] = x[k] - mean[k];
            }
            for r in 0..d {
                for cc in 0..=r {
                    scatter[(r, cc)] += c * e[r] * e[cc];
                }
            }
        }
        for r in 0..d {
            for cc in r + 1..d {
                scatter[(r, cc)] = scatter[(cc, r)];
            }
        }
        let cov = regularised_covariance(scatter, sw, reg, 0, &mut report.events)?;
        let scale: Vec<f64> = (0..d * d).map(|k| cov[(k / d, k % d)]).collect();
        let next = StudentT::new(mean, scale, nu, self.dof_mode)?;
        if self.dof_mode == StudentTDof::Fixed {
            return Ok(next);
        }
        // CM 2: ν maximising the observed-data likelihood at the new μ, Σ.
        let mut terms: Vec<(f64, f64, f64)> = Vec::with_capacity(frames.len()); // (w, p, δ)
        let mut marg: PatternCache<Option<StudentT>> = PatternCache::new();
        for (x, &w) in frames.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            if !frames.has_missing() || !x.iter().any(|v| v.is_nan()) {
                terms.push((w, d as f64, next.mahalanobis(x)));
                continue;
            }
            let m = marg.get_or_try_insert(x, || {
                let mut obs = Vec::new();
                observed_dims(x, &mut obs);
                if obs.is_empty() {
                    Ok(None)
                } else {
                    next.marginal_on(&obs).map(Some)
                }
            })?;
            if let Some(m) = m {
                let xo: Vec<f64> = x.iter().copied().filter(|v| !v.is_nan()).collect();
                terms.push((w, xo.len() as f64, m.mahalanobis(&xo)));
            }
        }
        // The terms that do not depend on the frame's distance, summed per
        // number of observed dims once (one on complete data) instead of per
        // frame: the golden-section search evaluates the objective ~80 times.
        let mut by_dims: Vec<(f64, f64)> = Vec::new(); // (p, Σ w)
        for &(w, p, _) in &terms {
            match by_dims.iter_mut().find(|(q, _)| *q == p) {
                Some((_, sw)) => *sw += w,
                None => by_dims.push((p, w)),
            }
        }
        let objective = |nu: f64| -> f64 {
            let constant: f64 = by_dims
                .iter()
                .map(|&(p, sw)| {
                    sw * (libm::lgamma(0.5 * (nu + p)) - libm::lgamma(0.5 * nu) - 0.5 * p * nu.ln())
                })
                .sum();
            constant
                - terms
                    .iter()
                    .map(|&(w, p, delta)| 0.5 * w * (nu + p) * (delta / nu).ln_1p())
                    .sum::<f64>()
        };
        let best = golden_section_max(DOF_RANGE.0.ln(), DOF_RANGE.1.ln(), |x| objective(x.exp()));
        let candidate = best.exp();
        Ok(if objective(candidate) >= objective(nu) {
            next.with_dof(candidate)
        } else {
            next
        })
    }

    /// The weighted Gaussian fit (`u_t = 1`): full scatter on complete data,
    /// per-dimension variances of the observed values otherwise (the ECME
    /// iterations then treat the missing values exactly).
    fn gaussian_start(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        reg: &Regularisation,
        report: &mut MStepReport,
    ) -> Result<StudentT> {
        let d = self.mean.len();
        let (mut n, mut sum) = (vec![0.0; d], vec![0.0; d]);
        for (x, &w) in frames.iter().zip(weights) {
            for k in 0..d {
                if !x[k].is_nan() {
                    n[k] += w;
                    sum[k] += w * x[k];
                }
            }
        }
        // A dimension never observed keeps the template's location.
        let mean: Vec<f64> = (0..d)
            .map(|k| {
                if n[k] > 0.0 {
                    sum[k] / n[k]
                } else {
                    self.mean[k]
                }
            })
            .collect();
        let total: f64 = weights.iter().sum();
        let mut scatter = DMatrix::<f64>::zeros(d, d);
        for (x, &w) in frames.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            let complete = !x.iter().any(|v| v.is_nan());
            for r in 0..d {
                if x[r].is_nan() {
                    continue;
                }
                for c in 0..=r {
                    if c == r || complete {
                        scatter[(r, c)] += w * (x[r] - mean[r]) * (x[c] - mean[c]);
                    }
                }
            }
        }
        if frames.has_missing() {
            // Variances of the observed values, rescaled to the total weight.
            for r in 0..d {
                for c in 0..d {
                    scatter[(r, c)] = if r == c && n[r] > 0.0 {
                        scatter[(r, r)] * total / n[r]
                    } else if r == c {
                        total
                    } else {
                        0.0
                    };
                }
            }
        }
        for r in 0..d {
            for c in r + 1..d {
                scatter[(r, c)] = scatter[(c, r)];
            }
        }
        let cov = regularised_covariance(scatter, total, reg, 0, &mut report.events)?;
        let scale = (0..d * d).map(|k| cov[(k / d, k % d)]).collect();
        StudentT::new(mean, scale, self.dof, self.dof_mode)
    }
}

/// Maximiser of a unimodal `f` on `[a, b]` by golden-section search (to
/// within `1e-12` of the interval).
fn golden_section_max(mut a: f64, mut b: f64, f: impl Fn(f64) -> f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    while (b - a).abs() > 1e-12 * (1.0 + a.abs() + b.abs()) {
        if fc >= fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    0.5 * (a + b)
}

/// What one missing pattern needs under the current parameters.
#[derive(Debug)]
struct Pattern {
    obs: Vec<usize>,
    mis: Vec<usize>,
    /// `Σ_mo Σ_oo⁻¹`, `|m| × |o|`.
    regression: DMatrix<f64>,
    /// `Σ_mm − Σ_mo Σ_oo⁻¹ Σ_om`.
    conditional: DMatrix<f64>,
    /// The marginal on the observed dims (for `δ_t` and `p_t`).
    marginal: StudentT,
}

/// Weighted log-likelihood gain below which [`StudentT::initialise`] stops.
const INIT_TOL: f64 = 1e-10;
/// Most ECME steps of [`StudentT::initialise`].
const INIT_MAX_STEPS: usize = 200;

impl StateDistribution for StudentT {
    const NAME: &'static str = "Student-t";
    const MISSING_VALUES: bool = true;

    fn dim(&self) -> usize {
        self.mean.len()
    }

    fn log_density(&self, x: &[f64]) -> f64 {
        let p = self.mean.len() as f64;
        self.log_norm - 0.5 * (self.dof + p) * (self.mahalanobis(x) / self.dof).ln_1p()
    }

    /// `x = μ + L z √(ν/g)` with `z ~ N(0, I)` and `g ~ χ²_ν`.
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R, out: &mut [f64]) {
        let d = self.mean.len();
        let z: Vec<f64> = (0..d).map(|_| rng.sample(StandardNormal)).collect();
        let g = ChiSquared::new(self.dof)
            .expect("ν > 0 is checked at construction")
            .sample(rng);
        let s = (self.dof / g).sqrt();
        packed_lower_mul(&self.factor, &z, out);
        for (o, m) in out.iter_mut().zip(&self.mean) {
            *o = m + s * *o;
        }
    }

    fn fit(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        reg: &Regularisation,
        report: &mut MStepReport,
    ) -> Result<Self> {
        self.ecme_step(frames, weights, reg, report)
    }

    fn n_parameters(&self) -> usize {
        let d = self.mean.len();
        d + d * (d + 1) / 2 + usize::from(self.dof_mode == StudentTDof::Estimated)
    }

    /// From the weighted Gaussian fit, ECME steps while the weighted
    /// log-likelihood gains more than `1e-10` relative (at most 200).
    fn initialise<R: Rng + ?Sized>(
        &self,
        frames: Frames<'_>,
        weights: &[f64],
        reg: &Regularisation,
        report: &mut MStepReport,
        rng: &mut R,
    ) -> Result<Self> {
        let _ = rng;
        let mut model = self.gaussian_start(frames, weights, reg, report)?;
        let mut best = model.weighted_log_likelihood(frames, weights)?;
        for _ in 0..INIT_MAX_STEPS {
            let mut r = MStepReport::default();
            let next = model.ecme_step(frames, weights, reg, &mut r)?;
            let obj = next.weighted_log_likelihood(frames, weights)?;
            if obj.is_nan() || obj <= best {
                break;
            }
            let gain = obj - best;
            model = next;
            best = obj;
            *report = r;
            if gain <= INIT_TOL * (1.0 + obj.abs()) {
                break;
            }
        }
        Ok(model)
    }

    /// `log IW(Σ; ψ I, ν₀) = −(ν₀ + D + 1)/2 log|Σ| − ψ/2 tr(Σ⁻¹)` under an
    /// inverse-Wishart regularisation, 0 otherwise.
    fn log_prior(&self, reg: &Regularisation) -> f64 {
        let CovarianceRegularisation::InverseWishart { scale, dof } = reg.covariance() else {
            return 0.0;
        };
        let d = self.mean.len() as f64;
        let tr_inv: f64 = self.whiten.iter().map(|v| v * v).sum();
        -0.5 * (dof + d + 1.0) * self.log_det - 0.5 * scale * tr_inv
    }

    fn marginal(&self, dims: &[usize]) -> Result<Self> {
        crate::check_dims(dims, self.mean.len())?;
        self.marginal_on(dims)
    }
}

/// A Student-t state's conditional of output dims given input dims.
#[derive(Debug, Clone)]
pub struct StudentTSplit {
    input: Vec<usize>,
    nu: f64,
    mu_in: Vec<f64>,
    mu_out: Vec<f64>,
    /// Packed `L_II⁻¹`.
    whiten_in: Vec<f64>,
    /// Log-density constant of the input marginal.
    log_norm_in: f64,
    /// `Σ_OI Σ_II⁻¹`, `|O| × |I|` row-major.
    regression: Vec<f64>,
    /// `Σ_OO − Σ_OI Σ_II⁻¹ Σ_IO`, `|O| × |O|` row-major.
    conditional: Vec<f64>,
    diff: Vec<f64>,
}

impl StudentTSplit {
    fn delta(&mut self, input: &[f64]) -> f64 {
        if self.input.is_empty() {
            // No input: the outputs' marginal (see `Conditional::conditional`).
            return 0.0;
        }
        for (k, v) in input.iter().enumerate() {
            self.diff[k] = v - self.mu_in[k];
        }
        packed_lower_sq_norm(&self.whiten_in, &self.diff)
    }
}

impl StateSplit for StudentTSplit {
    fn input_log_density(&mut self, input: &[f64]) -> f64 {
        let p = self.input.len() as f64;
        let delta = self.delta(input);
        self.log_norm_in - 0.5 * (self.nu + p) * (delta / self.nu).ln_1p()
    }

    fn predict(&mut self, input: &[f64], mean: &mut [f64], covariance: &mut [f64]) -> Result<()> {
        let p = self.input.len() as f64;
        if self.nu + p <= 2.0 {
            return Err(EmissionError::plugin(
                StudentT::NAME,
                format!(
                    "the conditional covariance is infinite for ν + |I| = {} ≤ 2",
                    self.nu + p
                ),
            ));
        }
        let delta = self.delta(input);
        let ni = self.input.len();
        for (o, m) in mean.iter_mut().enumerate() {
            let row = &self.regression[o * ni..(o + 1) * ni];
            *m = self.mu_out[o] + row.iter().zip(&self.diff).map(|(a, b)| a * b).sum::<f64>();
        }
        let f = (self.nu + delta) / (self.nu + p - 2.0);
        for (c, v) in covariance.iter_mut().zip(&self.conditional) {
            *c = f * v;
        }
        Ok(())
    }
}

impl StateConditional for StudentT {
    type Split = StudentTSplit;

    fn conditional(&self, input: &[usize], output: &[usize]) -> Result<StudentTSplit> {
        let d = self.mean.len();
        crate::capability::check_split(input, output, d)?;
        let s = DMatrix::from_row_slice(d, d, &self.scale);
        let (r, c) = regression_of(&s, input, output)?;
        // No input: the outputs' marginal, whose input density is 1.
        let (whiten_in, log_norm_in) = if input.is_empty() {
            (Vec::new(), 0.0)
        } else {
            let marg = self.marginal_on(input)?;
            (marg.whiten, marg.log_norm)
        };
        Ok(StudentTSplit {
            input: input.to_vec(),
            nu: self.dof,
            mu_in: input.iter().map(|&k| self.mean[k]).collect(),
            mu_out: output.iter().map(|&k| self.mean[k]).collect(),
            whiten_in,
            log_norm_in,
            regression: r,
            conditional: c,
            diff: vec![0.0; input.len()],
        })
    }
}

/// For a covariance (or scale) `s`: the regression `Σ_OI Σ_II⁻¹` (`|O| × |I|`
/// row-major) and the conditional `Σ_OO − Σ_OI Σ_II⁻¹ Σ_IO` (`|O| × |O|`
/// row-major, symmetrised), by a Cholesky solve (no inverse).
pub(crate) fn regression_of(
    s: &DMatrix<f64>,
    input: &[usize],
    output: &[usize],
) -> Result<(Vec<f64>, Vec<f64>)> {
    let sub = |rows: &[usize], cols: &[usize]| {
        DMatrix::from_fn(rows.len(), cols.len(), |r, c| s[(rows[r], cols[c])])
    };
    let chol = nalgebra::Cholesky::new(sub(input, input)).ok_or_else(|| {
        EmissionError::NotPositiveDefinite {
            state: 0,
            component: None,
            detail: format!(" (sub-block of the input dims {input:?})"),
        }
    })?;
    let s_io = sub(input, output);
    let rt = chol.solve(&s_io); // Σ_II⁻¹ Σ_IO, |I| × |O|
    let cond = sub(output, output) - s_io.transpose() * &rt;
    let (ni, no) = (input.len(), output.len());
    // Row-major R = (Σ_II⁻¹ Σ_IO)ᵀ: the column-major storage of `rt`.
    let regression = rt.as_slice().to_vec();
    debug_assert_eq!(regression.len(), ni * no);
    let conditional = (0..no * no)
        .map(|k| {
            let (r, c) = (k / no, k % no);
            0.5 * (cond[(r, c)] + cond[(c, r)])
        })
        .collect();
    Ok((regression, conditional))
}
