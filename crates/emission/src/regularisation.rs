//! How an M-step is regularised, and the report of what it had to do.

use crate::error::{readable, EmissionError, Result};
use crate::linalg;
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};
use std::fmt;

/// Regularisation of covariance matrices in the M-step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum CovarianceRegularisation {
    /// Plain maximum likelihood: `Σ = S / n`.
    None,
    /// Add `r·I` after the maximum-likelihood update: `Σ = S / n + r I`
    /// (pbdlib, the seed paper and scikit-learn's `reg_covar`).
    ///
    /// This is not the mode of any posterior, so EM with it is not guaranteed
    /// to increase any objective monotonically.
    AddDiagonal(f64),
    /// Maximum a posteriori under an inverse-Wishart prior `IW(ψ I, ν)` on
    /// every covariance: `Σ = (S + ψ I) / (n + ν + D + 1)`.
    ///
    /// EM then increases the penalised objective `log p(X) + Σ_i log IW(Σ_i)`
    /// monotonically; see [`crate::Emission::log_prior`].
    InverseWishart {
        /// Scale `ψ` of the prior's scale matrix `ψ I` (> 0).
        scale: f64,
        /// Degrees of freedom `ν` (≥ 0 here; the prior is proper for `ν > D − 1`).
        dof: f64,
    },
}

impl fmt::Display for CovarianceRegularisation {
    /// As a message to a user: "no covariance regularisation",
    /// "regularisation: added diagonal 0.01", "inverse-Wishart prior (scale 1, 3
    /// degrees of freedom)".
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CovarianceRegularisation::None => write!(f, "no covariance regularisation"),
            CovarianceRegularisation::AddDiagonal(r) => {
                write!(f, "regularisation: added diagonal {}", readable(*r))
            }
            CovarianceRegularisation::InverseWishart { scale, dof } => write!(
                f,
                "inverse-Wishart prior (scale {}, {} degrees of freedom)",
                readable(*scale),
                readable(*dof)
            ),
        }
    }
}

/// Regularisation applied by every M-step, validated at construction.
///
/// Deserialisation runs the same checks as the constructors (a negative or
/// non-finite amount, or a non-positive inverse-Wishart scale, is refused with
/// the name of the offending setting), so settings read from a file are as
/// trustworthy as settings built in code.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RegularisationRaw")]
pub struct Regularisation {
    covariance: CovarianceRegularisation,
    max_jitter: f64,
    min_weight: f64,
    pseudo_count: f64,
}

/// The serialised form of [`Regularisation`], before validation.
#[derive(Deserialize)]
struct RegularisationRaw {
    covariance: CovarianceRegularisation,
    max_jitter: f64,
    min_weight: f64,
    pseudo_count: f64,
}

impl TryFrom<RegularisationRaw> for Regularisation {
    type Error = EmissionError;
    /// Rebuilds through the checked constructors, so that no unchecked value gets in.
    fn try_from(raw: RegularisationRaw) -> Result<Self> {
        let base = match raw.covariance {
            CovarianceRegularisation::None => Regularisation::none(),
            CovarianceRegularisation::AddDiagonal(r) => Regularisation::add_diagonal(r)?,
            CovarianceRegularisation::InverseWishart { scale, dof } => {
                Regularisation::inverse_wishart(scale, dof)?
            }
        };
        base.with_max_jitter(raw.max_jitter)?
            .with_min_weight(raw.min_weight)?
            .with_pseudo_count(raw.pseudo_count)
    }
}

impl Default for Regularisation {
    /// No covariance regularisation, no jitter, states with total weight below
    /// `1e-10` kept unchanged, no pseudo-counts.
    fn default() -> Self {
        Regularisation {
            covariance: CovarianceRegularisation::None,
            max_jitter: 0.0,
            min_weight: 1e-10,
            pseudo_count: 0.0,
        }
    }
}

fn nonneg(name: &'static str, v: f64) -> Result<f64> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(EmissionError::InvalidParameter {
            name,
            reason: format!("must be finite and non-negative, got {v}"),
        })
    }
}

impl Regularisation {
    /// Plain maximum likelihood (same as `default()`).
    pub fn none() -> Self {
        Self::default()
    }

    /// Add `r·I` to every covariance after the M-step (`r ≥ 0`).
    pub fn add_diagonal(r: f64) -> Result<Self> {
        Ok(Regularisation {
            covariance: CovarianceRegularisation::AddDiagonal(nonneg(
                "covariance regularisation",
                r,
            )?),
            ..Self::default()
        })
    }

    /// MAP covariance under an inverse-Wishart prior with scale `ψ I` and `ν` degrees of freedom.
    pub fn inverse_wishart(scale: f64, dof: f64) -> Result<Self> {
        let scale = nonneg("inverse-Wishart scale", scale)?;
        if scale == 0.0 {
            return Err(EmissionError::InvalidParameter {
                name: "inverse-Wishart scale",
                reason: "must be positive".into(),
            });
        }
        Ok(Regularisation {
            covariance: CovarianceRegularisation::InverseWishart {
                scale,
                dof: nonneg("inverse-Wishart degrees of freedom", dof)?,
            },
            ..Self::default()
        })
    }

    /// When a regularised covariance is still not positive definite, add up to
    /// `max` more to its diagonal (in steps growing tenfold from `1e-12·(mean variance)`)
    /// and report it, instead of failing.
    pub fn with_max_jitter(mut self, max: f64) -> Result<Self> {
        self.max_jitter = nonneg("max_jitter", max)?;
        Ok(self)
    }

    /// States (or components) whose total posterior weight is below `w` keep
    /// their previous parameters and are reported.
    pub fn with_min_weight(mut self, w: f64) -> Result<Self> {
        self.min_weight = nonneg("min_weight", w)?;
        Ok(self)
    }

    /// Dirichlet pseudo-count added to every count of discrete emissions and mixture weights.
    pub fn with_pseudo_count(mut self, a: f64) -> Result<Self> {
        self.pseudo_count = nonneg("pseudo_count", a)?;
        Ok(self)
    }

    /// The covariance regularisation.
    pub fn covariance(&self) -> CovarianceRegularisation {
        self.covariance
    }

    /// Maximum extra diagonal jitter allowed.
    pub fn max_jitter(&self) -> f64 {
        self.max_jitter
    }

    /// Minimum total weight for a state to be re-estimated.
    pub fn min_weight(&self) -> f64 {
        self.min_weight
    }

    /// Dirichlet pseudo-count for discrete distributions and mixture weights.
    pub fn pseudo_count(&self) -> f64 {
        self.pseudo_count
    }
}

/// One thing an M-step had to do beyond the plain update.
///
/// `#[non_exhaustive]`: match with a wildcard arm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum MStepEvent {
    /// The state received total weight below the minimum and kept its parameters.
    KeptEmptyState {
        /// State index.
        state: usize,
        /// Mixture component, for mixture emissions.
        component: Option<usize>,
        /// Its total posterior weight.
        weight: f64,
    },
    /// Extra diagonal jitter was needed to make a covariance positive definite.
    Jitter {
        /// State index.
        state: usize,
        /// Mixture component, for mixture emissions.
        component: Option<usize>,
        /// Amount added to the diagonal on top of the regularisation.
        amount: f64,
    },
}

/// What an M-step did: the regularisation it applied to every covariance and
/// the states that needed special treatment.
///
/// `#[non_exhaustive]`: build one with `MStepReport::default()` (or
/// [`MStepReport::added_diagonal`]) and push events.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct MStepReport {
    /// Amount added to every covariance diagonal by [`CovarianceRegularisation::AddDiagonal`].
    pub added_diagonal: f64,
    /// States that were kept or jittered.
    pub events: Vec<MStepEvent>,
}

impl MStepReport {
    /// An empty report of an M-step that added `r` to every covariance
    /// diagonal (the amount [`CovarianceRegularisation::AddDiagonal`] adds, 0
    /// for the others).
    pub fn added_diagonal(reg: &Regularisation) -> Self {
        MStepReport {
            added_diagonal: match reg.covariance() {
                CovarianceRegularisation::AddDiagonal(r) => r,
                _ => 0.0,
            },
            events: Vec::new(),
        }
    }

    /// Appends the events of a one-state report as events of `state`: the
    /// per-state route fits every state alone, as its state 0.
    pub fn absorb_state(&mut self, state: usize, inner: MStepReport) {
        self.added_diagonal = self.added_diagonal.max(inner.added_diagonal);
        for e in inner.events {
            self.events.push(match e {
                MStepEvent::KeptEmptyState {
                    component, weight, ..
                } => MStepEvent::KeptEmptyState {
                    state,
                    component,
                    weight,
                },
                MStepEvent::Jitter {
                    component, amount, ..
                } => MStepEvent::Jitter {
                    state,
                    component,
                    amount,
                },
            });
        }
    }

    /// Appends the events of an inner model whose "states" are the components of `state`.
    pub fn absorb_components(&mut self, state: usize, inner: MStepReport) {
        self.added_diagonal = self.added_diagonal.max(inner.added_diagonal);
        for e in inner.events {
            self.events.push(match e {
                MStepEvent::KeptEmptyState {
                    state: c, weight, ..
                } => MStepEvent::KeptEmptyState {
                    state,
                    component: Some(c),
                    weight,
                },
                MStepEvent::Jitter {
                    state: c, amount, ..
                } => MStepEvent::Jitter {
                    state,
                    component: Some(c),
                    amount,
                },
            });
        }
    }

    /// Total jitter added over all states.
    pub fn total_jitter(&self) -> f64 {
        self.events
            .iter()
            .map(|e| match e {
                MStepEvent::Jitter { amount, .. } => *amount,
                _ => 0.0,
            })
            .sum()
    }
}

/// The covariance of one state from its scatter `S = Σ_t w_t (x_t − μ)(x_t − μ)ᵀ`
/// about the new mean and its weight `n = Σ_t w_t`, regularised by `reg`:
///
/// * none: `Σ = S / n`;
/// * added diagonal: `Σ = S / n + r I`;
/// * inverse-Wishart `IW(ψ I, ν)`: `Σ = (S + ψ I) / (n + ν + D + 1)`;
///
/// symmetrised, and made positive definite by the smallest jitter
/// `10^k · 10⁻¹² · (mean variance)` on the diagonal up to `reg.max_jitter()`
/// (reported as an [`MStepEvent::Jitter`] of `state` in `events`), or the
/// error naming `state`. Every emission with a covariance uses it (Gaussian,
/// Student-t, plug-ins), so that they regularise alike.
pub fn regularised_covariance(
    scatter: DMatrix<f64>,
    n: f64,
    reg: &Regularisation,
    state: usize,
    events: &mut Vec<MStepEvent>,
) -> Result<DMatrix<f64>> {
    let d = scatter.nrows();
    let mut cov = match reg.covariance() {
        CovarianceRegularisation::None => scatter / n,
        CovarianceRegularisation::AddDiagonal(r) => {
            let mut c = scatter / n;
            for k in 0..d {
                c[(k, k)] += r;
            }
            c
        }
        CovarianceRegularisation::InverseWishart { scale, dof } => {
            let mut c = scatter;
            for k in 0..d {
                c[(k, k)] += scale;
            }
            c / (n + dof + d as f64 + 1.0)
        }
    };
    cov = (&cov + cov.transpose()) * 0.5;
    if linalg::cholesky(&cov).is_some() {
        return Ok(cov);
    }
    let mean_var = (cov.trace() / d as f64).abs();
    let mut jitter = 1e-12
        * if mean_var > 0.0 && mean_var.is_finite() {
            mean_var
        } else {
            1.0
        };
    while jitter <= reg.max_jitter() {
        let mut c = cov.clone();
        for k in 0..d {
            c[(k, k)] += jitter;
        }
        if linalg::cholesky(&c).is_some() {
            events.push(MStepEvent::Jitter {
                state,
                component: None,
                amount: jitter,
            });
            return Ok(c);
        }
        jitter *= 10.0;
    }
    Err(EmissionError::NotPositiveDefinite {
        state,
        component: None,
        detail: format!(
            " after the M-step ({}, total weight {}, {})",
            reg.covariance(),
            readable(n),
            jitter_allowed(reg)
        ),
    })
}

/// "no jitter allowed" or "jitter allowed up to 1e-6", for messages.
fn jitter_allowed(reg: &Regularisation) -> String {
    if reg.max_jitter() > 0.0 {
        format!("jitter allowed up to {}", readable(reg.max_jitter()))
    } else {
        "no jitter allowed".into()
    }
}

/// Makes the variances of one diagonal/spherical state positive, adding the
/// same jitter to all of them (as [`regularised_covariance`] does to a full
/// diagonal) when `reg` allows, reported in `events`, or errors naming `state`.
pub fn jitter_variances(
    vars: &mut [f64],
    reg: &Regularisation,
    state: usize,
    events: &mut Vec<MStepEvent>,
) -> Result<()> {
    let bad = |vars: &[f64]| vars.iter().position(|v| !(*v > 0.0 && v.is_finite()));
    let Some(k) = bad(vars) else {
        return Ok(());
    };
    if vars.iter().all(|v| v.is_finite()) {
        let mean_var = (vars.iter().sum::<f64>() / vars.len() as f64).abs();
        let mut jitter = 1e-12
            * if mean_var > 0.0 && mean_var.is_finite() {
                mean_var
            } else {
                1.0
            };
        while jitter <= reg.max_jitter() {
            let jittered: Vec<f64> = vars.iter().map(|v| v + jitter).collect();
            if bad(&jittered).is_none() {
                vars.copy_from_slice(&jittered);
                events.push(MStepEvent::Jitter {
                    state,
                    component: None,
                    amount: jitter,
                });
                return Ok(());
            }
            jitter *= 10.0;
        }
    }
    Err(EmissionError::NotPositiveDefinite {
        state,
        component: None,
        detail: format!(
            " (variance {} after the M-step, {}; a constant dimension needs covariance regularisation)",
            readable(vars[k]),
            jitter_allowed(reg)
        ),
    })
}

/// Variance update of a diagonal/spherical state: scatter `q` (sum of the
/// weighted squared deviations over the `k` pooled dimensions), weight `n`,
/// frame dimension `d`:
///
/// * none: `q / (n k)`;
/// * added diagonal: `q / (n k) + r`;
/// * inverse-Wishart: `(q + k ψ) / (k (n + ν + d + 1))`.
pub fn regularised_variance(q: f64, n: f64, k: f64, d: f64, reg: &Regularisation) -> f64 {
    let q = q.max(0.0);
    match reg.covariance() {
        CovarianceRegularisation::None => q / (n * k),
        CovarianceRegularisation::AddDiagonal(r) => q / (n * k) + r,
        CovarianceRegularisation::InverseWishart { scale, dof } => {
            (q + k * scale) / (k * (n + dof + d + 1.0))
        }
    }
}
