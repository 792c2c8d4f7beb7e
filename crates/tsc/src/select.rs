//! Automatic choice of a number of mixture components or HMM states: BIC
//! (`phasekit_gmm::select_mixture_bic`, `phasekit_hmm::select_states_bic`)
//! or G-means (`phasekit_gmm::gmeans`), over a range bounded by what the data
//! can support. Krishnan et al. use a Dirichlet-process GMM; BIC and G-means
//! are the automatic choices offered here.
//!
//! G-means answers with the number of Gaussian clusters it finds; when that
//! is more than the largest count allowed, the answer would only be the cap,
//! so the automatic choices refuse it ([`TscError::GMeansAboveRange`]) rather
//! than return the cap as if it had been chosen.

use crate::emission_choice::EmissionKind;
use crate::error::{Result, TscError};
use phasekit_emission::{Emission, Frames, SequenceSet};
use phasekit_gmm::{gmeans, select_mixture_bic, Em, GMeans, GMeansResult};
use phasekit_hmm::{BaumWelch, HmmFit};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::ops::RangeInclusive;
use std::str::FromStr;

/// How a number of components (or states) is chosen automatically.
///
/// Parsed from and displayed as `bic` and `gmeans` (`g-means` is read too).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Selector {
    /// The count `k` in a range with the lowest `BIC(k) = −2 log p(X | θ̂_k) + p_k log N`
    /// (`p_k` free parameters, `N` frames), each candidate fitted by EM.
    #[default]
    Bic,
    /// G-means (Hamerly & Elkan 2003): start with one k-means cluster and split a
    /// cluster while the Anderson–Darling test rejects (at `α = 1e-4`) that its frames,
    /// projected on the axis joining its two 2-means children, are Gaussian.
    GMeans,
}

impl FromStr for Selector {
    type Err = TscError;
    fn from_str(name: &str) -> Result<Selector> {
        match name {
            "bic" => Ok(Selector::Bic),
            "gmeans" | "g-means" => Ok(Selector::GMeans),
            other => Err(TscError::InvalidSetting {
                name: "select",
                reason: format!("unknown selector `{other}`; known: bic, gmeans"),
            }),
        }
    }
}

impl fmt::Display for Selector {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Selector::Bic => "bic",
            Selector::GMeans => "gmeans",
        })
    }
}

/// Checks a range of candidate counts: `1 ≤ lo ≤ hi`; `name` is the parameter
/// that sets its upper end.
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

/// A count chosen automatically, the candidates it was chosen from, and why
/// they stop below the largest count asked for (if they do).
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct AutoCount {
    /// The count chosen.
    pub count: usize,
    /// The candidates (after the limits of the data).
    pub range: RangeInclusive<usize>,
    /// `(asked, why)` when the largest candidate is below the largest count asked for.
    pub lowered: Option<(usize, String)>,
}

impl AutoCount {
    /// `"; at most N: why"` when the range was lowered, else nothing.
    pub fn lowered_note(&self) -> String {
        self.lowered.as_ref().map_or(String::new(), |(asked, why)| {
            format!(
                "; at most {} of the {asked} asked for: {why}",
                self.range.end()
            )
        })
    }
}

/// The largest number of full-covariance Gaussian components of dimension `d`
/// that `n` frames support: every component must own at least `d + 1` frames
/// on average, the fewest that determine a full covariance without
/// regularisation (`k ≤ n / (d + 1)`, at least 1).
pub fn max_supported_components(n: usize, d: usize) -> usize {
    (n / (d + 1)).max(1)
}

/// G-means' count of the clusters of `frames` when it is at most `max`;
/// [`TscError::GMeansAboveRange`] when G-means finds more (or is still
/// splitting at `max + 1`), since the count would then only be the cap.
/// `lowered` says why `max` is below the count asked for, if it is (for the
/// error). G-means is deterministic (its splits start along the principal
/// axis): the count needs no seed.
pub fn gmeans_count(
    frames: Frames<'_>,
    max: usize,
    counting: &'static str,
    lowered: Option<(usize, String)>,
) -> Result<GMeansResult> {
    let settings = GMeans::default()
        .to_builder()
        .max_k(max.saturating_add(1))
        .build()?;
    let clusters = gmeans(frames, settings)?;
    if clusters.k > max || clusters.capped {
        return Err(TscError::GMeansAboveRange {
            counting,
            found: clusters.k,
            capped: clusters.capped,
            max,
            lowered,
        });
    }
    Ok(clusters)
}

/// The number of full-covariance Gaussian components for `frames`, chosen by
/// `selector` within `range` ([`mixture_components_of`] with full Gaussians).
pub fn mixture_components(
    selector: Selector,
    em: &Em,
    frames: Frames<'_>,
    range: RangeInclusive<usize>,
) -> Result<AutoCount> {
    mixture_components_of(EmissionKind::default(), selector, em, frames, range)
}

/// The number of components of emission `kind` for `frames`, chosen by
/// `selector` within `range`, whose upper end is first lowered to what the
/// frames support ([`max_supported_components`]: the count a full covariance
/// needs, the most demanding kind). BIC fits mixtures of `kind`; G-means
/// counts Gaussian clusters whatever the kind. A G-means count below the
/// range is raised to its lower end; one above it is refused
/// ([`gmeans_count`]).
pub fn mixture_components_of(
    kind: EmissionKind,
    selector: Selector,
    em: &Em,
    frames: Frames<'_>,
    range: RangeInclusive<usize>,
) -> Result<AutoCount> {
    let d = frames.dim();
    let supported = max_supported_components(frames.len(), d);
    let hi = (*range.end()).min(supported).max(1);
    let lo = (*range.start()).min(hi).max(1);
    let lowered = (hi < *range.end()).then(|| {
        (
            *range.end(),
            format!(
                "{} frames of dimension {d} support at most {supported} full-covariance components ({} frames each)",
                frames.len(),
                d + 1
            ),
        )
    });
    let count = match selector {
        Selector::Bic => select_mixture_bic(em, |k| kind.template(k, d), frames, lo..=hi)?.best,
        Selector::GMeans => gmeans_count(frames, hi, "mixture components", lowered.clone())?
            .k
            .max(lo),
    };
    Ok(AutoCount {
        count,
        range: lo..=hi,
        lowered,
    })
}

/// The number of HMM states chosen by G-means, and the HMM fitted with it.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct GMeansStates<E: Emission> {
    /// The number of states `K`: the G-means count, clamped to the range.
    pub best: usize,
    /// `BIC = −2 log p(X) + p log N` of the fitted HMM (`phasekit_hmm::Hmm::bic`).
    pub bic: f64,
    /// The G-means clustering of the frames of all sequences.
    pub clusters: GMeansResult,
    /// The HMM with `K` states fitted by the given Baum-Welch settings.
    pub fitted: HmmFit<E>,
}

/// The number of HMM states by G-means (Hamerly & Elkan 2003), as the seed
/// paper proposes: `K` is the number of clusters [`gmeans`] finds on the frames
/// of all sequences pooled (time order ignored), then an HMM with structure
/// `template(K)` is fitted by `bw` (its initialisation, restarts and seed).
///
/// `K` is clamped to `range`; [`GMeansStates::clusters`] keeps G-means' own
/// count (and whether its `max_k` stopped it), so that a caller can tell a
/// choice from a cap — the presets refuse a count above their range
/// ([`gmeans_count`]). Errors if the data or the range are empty, if
/// `template(K)` cannot be built, or if the fit fails (naming `K`).
pub fn hmm_states_gmeans<E: Emission>(
    bw: &BaumWelch,
    template: impl Fn(usize) -> phasekit_emission::Result<E>,
    data: &SequenceSet,
    settings: GMeans,
    range: RangeInclusive<usize>,
) -> Result<GMeansStates<E>> {
    if data.is_empty() {
        return Err(phasekit_hmm::HmmError::NoData.into());
    }
    check_range("range", &range)?;
    let clusters = gmeans(data.all_frames(), settings)?;
    fit_gmeans_states(bw, template, data, clusters, range)
}

/// Fits the HMM with the G-means count of `clusters`, clamped to `range`.
pub(crate) fn fit_gmeans_states<E: Emission>(
    bw: &BaumWelch,
    template: impl Fn(usize) -> phasekit_emission::Result<E>,
    data: &SequenceSet,
    clusters: GMeansResult,
    range: RangeInclusive<usize>,
) -> Result<GMeansStates<E>> {
    let k = clusters.k.clamp(*range.start(), *range.end());
    let context = |e: String| TscError::InvalidSetting {
        name: "states",
        reason: format!("G-means chose {k} states, but the HMM cannot be fitted: {e}"),
    };
    let t = template(k).map_err(|e| context(e.to_string()))?;
    let fitted = bw.fit(&t, data).map_err(|e| context(e.to_string()))?;
    let bic = fitted.model.bic(data)?;
    Ok(GMeansStates {
        best: k,
        bic,
        clusters,
        fitted,
    })
}
