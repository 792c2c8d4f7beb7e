//! How an M-step is regularised, and the report of what it had to do.

use crate::error::{EmissionError, Result};
use serde::{Deserialize, Serialize};

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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MStepReport {
    /// Amount added to every covariance diagonal by [`CovarianceRegularisation::AddDiagonal`].
    pub added_diagonal: f64,
    /// States that were kept or jittered.
    pub events: Vec<MStepEvent>,
}

impl MStepReport {
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
