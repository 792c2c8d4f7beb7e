//! [`ScaleFeatures`]: an emission of frames whose features are multiplied by
//! constants, mapped exactly.
//!
//! If `x ~ b_i` then `y = S x` with `S = diag(s)`, `s_j > 0`, is distributed as
//! the mapped state: a Gaussian `N(μ, Σ)` becomes `N(S μ, S Σ S)`, a
//! Student-t `t_ν(μ, Ψ)` becomes `t_ν(S μ, S Ψ S)` (same `ν`), and a mixture
//! maps every component and keeps its weights. This is how a model fitted on
//! features divided by their standard deviations (a regularisation relative to
//! each feature's variance, `phasekit-tsc`'s `reg-units=relative`) is returned
//! in the data's units.
//!
//! Emissions whose family is not closed under a per-feature scaling refuse:
//! a spherical Gaussian `σ² I` stays spherical only when every `s_j` is the
//! same; a categorical takes symbols and a Poisson counts, which a scaling
//! does not map to symbols or counts.

use crate::error::{EmissionError, Result};
use crate::gaussian::{CovarianceType, Gaussian};
use crate::mixture::MixtureEmission;
use crate::per_state::{PerState, StateDistribution};
use crate::student_t::StudentT;
use crate::{Categorical, Emission, Poisson};

/// The same states for frames whose feature `j` is multiplied by `s[j]`.
pub trait ScaleFeatures: Sized {
    /// The emission of `y = diag(s) x` (means `× s`, covariances and scale
    /// matrices `S Σ S`; weights, degrees of freedom unchanged). Every `s_j`
    /// must be finite and positive, one per dimension; caches (Cholesky
    /// factors, normalising constants) are rebuilt by the constructors.
    fn scale_features(&self, s: &[f64]) -> Result<Self>;
}

/// Checks the factors of a [`ScaleFeatures::scale_features`] call on a
/// `dim`-dimensional emission: one per dimension, each finite and positive.
pub fn check_scales(s: &[f64], dim: usize) -> Result<()> {
    if s.len() != dim {
        return Err(EmissionError::InvalidParameter {
            name: "scales",
            reason: format!(
                "{} feature scales for an emission of dimension {dim}",
                s.len()
            ),
        });
    }
    if let Some(j) = s.iter().position(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(EmissionError::InvalidParameter {
            name: "scales",
            reason: format!(
                "the scale of feature {j} is {}: it must be finite and > 0",
                s[j]
            ),
        });
    }
    Ok(())
}

/// `S M S` of a `d × d` row-major matrix: entry `(r, c)` times `s_r s_c`
/// (the product `s_r s_c` is formed first, so a symmetric matrix stays
/// symmetric bit for bit).
fn scale_matrix(m: &[f64], s: &[f64]) -> Vec<f64> {
    let d = s.len();
    m.iter()
        .enumerate()
        .map(|(k, v)| v * (s[k / d] * s[k % d]))
        .collect()
}

impl ScaleFeatures for Gaussian {
    /// Full and tied: `S Σ S`; diagonal: `σ_j² s_j²`; spherical: `σ² s²` when
    /// every `s_j` equals `s` (otherwise the scaled covariance is not spherical:
    /// an error).
    fn scale_features(&self, s: &[f64]) -> Result<Self> {
        let d = self.dim();
        check_scales(s, d)?;
        let means: Vec<f64> = self
            .means()
            .iter()
            .enumerate()
            .map(|(k, m)| m * s[k % d])
            .collect();
        let raw = self.covariances_raw();
        let kind = self.covariance_type();
        let covariances = match kind {
            CovarianceType::Full | CovarianceType::Tied => raw
                .chunks_exact(d * d)
                .flat_map(|m| scale_matrix(m, s))
                .collect(),
            CovarianceType::Diagonal => raw
                .iter()
                .enumerate()
                .map(|(k, v)| v * (s[k % d] * s[k % d]))
                .collect(),
            CovarianceType::Spherical => {
                if s.iter().any(|v| *v != s[0]) {
                    return Err(EmissionError::Unsupported(format!(
                        "a spherical Gaussian σ²I cannot be mapped to features scaled by different factors \
                         ({} to {}): the result is not spherical; use diag, full or tied covariances",
                        s.iter().copied().fold(f64::INFINITY, f64::min),
                        s.iter().copied().fold(0.0, f64::max)
                    )));
                }
                raw.iter().map(|v| v * (s[0] * s[0])).collect()
            }
        };
        Gaussian::new(kind, d, means, covariances)
    }
}

impl ScaleFeatures for StudentT {
    /// `t_ν(S μ, S Ψ S)`: location times `s`, scale matrix `S Ψ S`, same `ν`.
    fn scale_features(&self, s: &[f64]) -> Result<Self> {
        check_scales(s, self.mean().len())?;
        let mean = self.mean().iter().zip(s).map(|(m, f)| m * f).collect();
        StudentT::new(
            mean,
            scale_matrix(self.scale(), s),
            self.dof(),
            self.dof_mode(),
        )
    }
}

impl<D: StateDistribution + ScaleFeatures> ScaleFeatures for PerState<D> {
    /// Every state's distribution mapped.
    fn scale_features(&self, s: &[f64]) -> Result<Self> {
        check_scales(s, self.dim())?;
        PerState::new(
            self.states()
                .iter()
                .map(|d| d.scale_features(s))
                .collect::<Result<_>>()?,
        )
    }
}

impl<E: Emission + ScaleFeatures> ScaleFeatures for MixtureEmission<E> {
    /// Every state's components mapped; the weights unchanged.
    fn scale_features(&self, s: &[f64]) -> Result<Self> {
        check_scales(s, self.dim())?;
        MixtureEmission::new(
            self.weights().to_vec(),
            (0..self.n_states())
                .map(|i| self.components(i).scale_features(s))
                .collect::<Result<_>>()?,
        )
    }
}

impl ScaleFeatures for Categorical {
    /// Always an error: a categorical's frames are symbols, which a scaling
    /// does not map to symbols.
    fn scale_features(&self, _s: &[f64]) -> Result<Self> {
        Err(EmissionError::Unsupported(
            "a categorical emission cannot be mapped to scaled features: its frames are symbols \
             0..K, not measurements (a regularisation relative to the features' variances does not apply)"
                .into(),
        ))
    }
}

impl ScaleFeatures for Poisson {
    /// Always an error: a Poisson's frames are counts, and scaled counts are
    /// not counts (nor Poisson).
    fn scale_features(&self, _s: &[f64]) -> Result<Self> {
        Err(EmissionError::Unsupported(
            "a Poisson emission cannot be mapped to scaled features: its frames are counts, and a \
             scaled count is neither a count nor Poisson (a regularisation relative to the features' \
             variances does not apply)"
                .into(),
        ))
    }
}
