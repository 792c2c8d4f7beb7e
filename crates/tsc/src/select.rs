//! Automatic choice of a number of mixture components or HMM states, by the
//! selectors of `phasekit-gmm` (Krishnan et al. use a Dirichlet-process GMM;
//! BIC and G-means are the automatic choices offered here).

use crate::error::{Result, TscError};
use phasekit_emission::{CovarianceType, Frames, Gaussian, Shape};
use phasekit_gmm::{gmeans, select_mixture_bic, Em, GMeans};
use serde::{Deserialize, Serialize};
use std::ops::RangeInclusive;

/// How a number of components (or states) is chosen automatically.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Selector {
    /// The count `k` in a range with the lowest `BIC(k) = −2 log p(X | θ̂_k) + p_k log N`
    /// (`p_k` free parameters, `N` frames), each candidate fitted by EM.
    #[default]
    Bic,
    /// G-means (Hamerly & Elkan 2003): start with one k-means cluster and split a
    /// cluster while the Anderson–Darling test rejects (at `α = 1e-4`) that its frames,
    /// projected on the axis joining its two 2-means children, are Gaussian;
    /// the count found is clamped to the range.
    GMeans,
}

impl Selector {
    /// The selector named `bic` or `gmeans` (also `g-means`).
    pub fn parse(name: &str) -> Result<Selector> {
        match name {
            "bic" => Ok(Selector::Bic),
            "gmeans" | "g-means" => Ok(Selector::GMeans),
            other => Err(TscError::InvalidSetting {
                name: "select",
                reason: format!("unknown selector `{other}`; known: bic, gmeans"),
            }),
        }
    }

    /// The name `parse` reads.
    pub fn name(self) -> &'static str {
        match self {
            Selector::Bic => "bic",
            Selector::GMeans => "gmeans",
        }
    }
}

/// Checks a range of candidate counts: `1 ≤ lo ≤ hi`.
pub fn check_range(name: &'static str, range: &RangeInclusive<usize>) -> Result<()> {
    if *range.start() == 0 || range.start() > range.end() {
        return Err(TscError::InvalidSetting {
            name,
            reason: format!(
                "the range of candidate counts must satisfy 1 ≤ min ≤ max, got {}..={}",
                range.start(),
                range.end()
            ),
        });
    }
    Ok(())
}

/// The number of full-covariance Gaussian components for `frames`, chosen by
/// `selector` within `range` (whose upper end is first capped at the number of frames:
/// a mixture cannot have more components than frames).
pub fn mixture_components(
    selector: Selector,
    em: &Em,
    frames: Frames<'_>,
    range: RangeInclusive<usize>,
) -> Result<usize> {
    let hi = (*range.end()).min(frames.len()).max(1);
    let lo = (*range.start()).min(hi).max(1);
    let d = frames.dim();
    Ok(match selector {
        Selector::Bic => {
            select_mixture_bic(
                em,
                |k| {
                    Gaussian::standard(
                        CovarianceType::Full,
                        Shape {
                            n_states: k,
                            dim: d,
                        },
                    )
                },
                frames,
                lo..=hi,
            )?
            .best
        }
        // G-means is deterministic (its splits start along the principal axis), so the
        // choice needs no seed; the default settings are Hamerly & Elkan's α = 1e-4.
        Selector::GMeans => gmeans(frames, GMeans::default())?.k.clamp(lo, hi),
    })
}
