//! Choosing the number of mixture components: BIC over a range, and
//! G-means (Hamerly & Elkan, "Learning the k in k-means", NIPS 2003).
//!
//! The number of HMM states is chosen in `phasekit-hmm` (BIC,
//! `select_states_bic`) and, by G-means, in `phasekit-tsc`, which sees both
//! crates: this crate does not depend on the HMM.

use crate::em::Em;
use crate::error::{GmmError, Result};
use phasekit_emission::kmeans::lloyd;
use phasekit_emission::{Emission, Frames};
use serde::{Deserialize, Serialize};

/// The BIC of every candidate number of components and the one with the lowest.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct Selection {
    /// The number of components with the lowest BIC.
    pub best: usize,
    /// `(k, BIC)` for every candidate that could be fitted, in the order tried.
    pub scores: Vec<(usize, f64)>,
    /// `(k, why)` for every candidate that could not be fitted.
    pub failures: Vec<(usize, GmmError)>,
}

/// BIC `−2 log p(X) + p log N` ([`crate::Gmm::bic`]) of a mixture fitted by
/// `em` for every `k` in `candidates`; `template(k)` gives the component
/// structure with `k` states (its parameters are ignored).
///
/// A candidate that cannot be built or fitted is kept in
/// [`Selection::failures`] with its error; the others compete. Errors when
/// no candidate is given, or when none could be fitted (naming each and why).
pub fn select_mixture_bic<E: Emission>(
    em: &Em,
    template: impl Fn(usize) -> phasekit_emission::Result<E>,
    frames: Frames<'_>,
    candidates: impl IntoIterator<Item = usize>,
) -> Result<Selection> {
    let (mut scores, mut failures) = (Vec::new(), Vec::new());
    for k in candidates {
        match template(k)
            .map_err(GmmError::from)
            .and_then(|t| em.fit(&t, frames))
            .and_then(|f| f.model.bic(frames))
        {
            Ok(bic) => scores.push((k, bic)),
            Err(e) => failures.push((k, e)),
        }
    }
    let best = scores
        .iter()
        .filter(|(_, s)| s.is_finite())
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(k, _)| *k);
    match best {
        Some(best) => Ok(Selection {
            best,
            scores,
            failures,
        }),
        None if scores.is_empty() && failures.is_empty() => Err(GmmError::InvalidParameter {
            name: "candidates",
            reason: "no candidate number of components was given".into(),
        }),
        None => Err(GmmError::InvalidParameter {
            name: "candidates",
            reason: format!(
                "no candidate number of components could be fitted with a finite BIC: {}",
                scores
                    .iter()
                    .map(|(k, b)| format!("{k} components: BIC {b}"))
                    .chain(failures.iter().map(|(k, e)| format!("{k} components: {e}")))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        }),
    }
}

/// Anderson–Darling statistic `A²` of `x` against a normal with mean and variance
/// estimated from `x`, with the small-sample correction
/// `A*² = A² (1 + 0.75/n + 2.25/n²)` (D'Agostino & Stephens 1986, table 4.7), and its
/// p-value (ibid., table 4.9; `0` for `A*² > 13`, where the fitted formula is below
/// `5e-31` and would turn upwards past `A*² ≈ 153`), as `statsmodels`' `normal_ad`.
///
/// (Stephens' older correction `1 + 4/n − 25/n²`, used by Hamerly & Elkan with
/// critical values, does not match the table-4.9 p-values: with it the test
/// rejects a true normal at `α = 0.05` about 7% of the time for `n = 20`.)
///
/// `A² = −n − (1/n) Σ_i (2i − 1) [ln Φ(z_(i)) + ln(1 − Φ(z_(n+1−i)))]` over the
/// sorted standardised values `z_(i)`. Returns `None` for fewer than 3 values or zero variance.
pub fn anderson_darling_normal(x: &[f64]) -> Option<(f64, f64)> {
    let n = x.len();
    if n < 3 {
        return None;
    }
    let nf = n as f64;
    let mean = x.iter().sum::<f64>() / nf;
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (nf - 1.0);
    // Zero or NaN variance: no test.
    if var.is_nan() || var <= 0.0 {
        return None;
    }
    let sd = var.sqrt();
    let mut z: Vec<f64> = x.iter().map(|v| (v - mean) / sd).collect();
    z.sort_by(f64::total_cmp);
    // ln Φ(z) and ln(1 − Φ(z)) = ln Φ(−z), via erfc for accuracy in the tails.
    let ln_cdf = |v: f64| (0.5 * libm::erfc(-v / std::f64::consts::SQRT_2)).ln();
    let s: f64 = (0..n)
        .map(|i| (2 * i + 1) as f64 * (ln_cdf(z[i]) + ln_cdf(-z[n - 1 - i])))
        .sum();
    let a2 = -nf - s / nf;
    let a = a2 * (1.0 + 0.75 / nf + 2.25 / (nf * nf));
    let p = if a > 13.0 {
        0.0
    } else if a >= 0.6 {
        (1.2937 - 5.709 * a + 0.0186 * a * a).exp()
    } else if a >= 0.34 {
        (0.9177 - 4.279 * a - 1.38 * a * a).exp()
    } else if a >= 0.2 {
        1.0 - (-8.318 + 42.796 * a - 59.938 * a * a).exp()
    } else {
        1.0 - (-13.436 + 101.14 * a - 223.73 * a * a).exp()
    };
    Some((a, p.clamp(0.0, 1.0)))
}

/// Checked settings of [`gmeans`]; build with [`GMeans::builder`] (or take
/// [`GMeans::default`]). Every setting is validated once, by
/// [`GMeansBuilder::build`] and on deserialisation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "GMeansRaw")]
pub struct GMeans {
    alpha: f64,
    max_k: usize,
    min_cluster: usize,
    max_iter: usize,
}

/// The serialised form of [`GMeans`], before validation.
#[derive(Deserialize)]
struct GMeansRaw {
    alpha: f64,
    max_k: usize,
    min_cluster: usize,
    max_iter: usize,
}

impl TryFrom<GMeansRaw> for GMeans {
    type Error = GmmError;
    fn try_from(r: GMeansRaw) -> Result<Self> {
        GMeansBuilder(GMeans {
            alpha: r.alpha,
            max_k: r.max_k,
            min_cluster: r.min_cluster,
            max_iter: r.max_iter,
        })
        .build()
    }
}

impl Default for GMeans {
    /// `α = 1e-4` (Hamerly & Elkan), at most 32 clusters, clusters of fewer
    /// than 8 frames not split, 100 Lloyd iterations per refinement.
    fn default() -> Self {
        GMeans {
            alpha: 1e-4,
            max_k: 32,
            min_cluster: 8,
            max_iter: 100,
        }
    }
}

impl GMeans {
    /// A builder starting from [`GMeans::default`].
    pub fn builder() -> GMeansBuilder {
        GMeansBuilder(GMeans::default())
    }
    /// A builder starting from these settings (to change some of them).
    pub fn to_builder(&self) -> GMeansBuilder {
        GMeansBuilder(*self)
    }
    /// Significance level `α` of the Anderson–Darling test: a cluster is split when `p < α`.
    pub fn alpha(&self) -> f64 {
        self.alpha
    }
    /// Never grow beyond this many clusters.
    pub fn max_k(&self) -> usize {
        self.max_k
    }
    /// Clusters with fewer frames than this are not split.
    pub fn min_cluster(&self) -> usize {
        self.min_cluster
    }
    /// Lloyd iterations per refinement.
    pub fn max_iter(&self) -> usize {
        self.max_iter
    }
}

/// Builder of [`GMeans`]; [`GMeansBuilder::build`] validates once.
#[derive(Debug, Clone, Copy)]
pub struct GMeansBuilder(GMeans);

impl GMeansBuilder {
    /// Significance level `α ∈ (0, 1)` of the Anderson–Darling test (Hamerly & Elkan use `1e-4`).
    pub fn alpha(mut self, alpha: f64) -> Self {
        self.0.alpha = alpha;
        self
    }
    /// Never grow beyond `max_k ≥ 1` clusters.
    pub fn max_k(mut self, max_k: usize) -> Self {
        self.0.max_k = max_k;
        self
    }
    /// Clusters with fewer than `min_cluster ≥ 3` frames are not split (the
    /// Anderson–Darling statistic needs at least 3 values).
    pub fn min_cluster(mut self, min_cluster: usize) -> Self {
        self.0.min_cluster = min_cluster;
        self
    }
    /// At most `max_iter ≥ 1` Lloyd iterations per refinement.
    pub fn max_iter(mut self, max_iter: usize) -> Self {
        self.0.max_iter = max_iter;
        self
    }
    /// Validates the settings, naming the first bad one.
    pub fn build(self) -> Result<GMeans> {
        let g = self.0;
        let bad = |name, reason: String| Err(GmmError::InvalidParameter { name, reason });
        if !(g.alpha > 0.0 && g.alpha < 1.0) {
            return bad(
                "alpha",
                format!(
                    "G-means significance level must lie in (0, 1), got {}",
                    g.alpha
                ),
            );
        }
        if g.max_k == 0 {
            return bad("max_k", "G-means needs at least one cluster, got 0".into());
        }
        if g.min_cluster < 3 {
            return bad(
                "min_cluster",
                format!(
                    "the Anderson–Darling test needs at least 3 frames per cluster, got {}",
                    g.min_cluster
                ),
            );
        }
        if g.max_iter == 0 {
            return bad(
                "max_iter",
                "G-means needs at least one Lloyd iteration, got 0".into(),
            );
        }
        Ok(g)
    }
}

/// Result of [`gmeans`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct GMeansResult {
    /// Number of clusters found.
    pub k: usize,
    /// `k × D` centroids.
    pub centroids: Vec<f64>,
    /// Cluster of every frame.
    pub labels: Vec<usize>,
    /// Whether [`GMeans::max_k`] stopped the splitting: some cluster still failed
    /// the normality test, so `k` is the cap rather than G-means' answer (which
    /// is larger).
    pub capped: bool,
}

/// G-means: start from one cluster; split a cluster while the projection of its
/// frames onto the axis joining its two 2-means children is not Gaussian by the
/// Anderson–Darling test at level `alpha`. Deterministic (no random choice:
/// children start at `c ± s √(2λ/π)` along the principal axis `s`, `λ` its variance).
pub fn gmeans(frames: Frames<'_>, settings: GMeans) -> Result<GMeansResult> {
    // With missing values (NaN), count clusters on the complete frames (values
    // missing at random leave them a fair sample); filling values with their
    // dimension's mean would line up fake frames along the axes, which the
    // normality test splits off as extra clusters. Too few complete frames:
    // the mean fill after all.
    if frames.has_missing() {
        let d = frames.dim();
        let complete: Vec<f64> = frames
            .iter()
            .filter(|x| x.iter().all(|v| !v.is_nan()))
            .flatten()
            .copied()
            .collect();
        let data = if complete.len() / d >= (4 * d).max(settings.min_cluster() * 2) {
            complete
        } else {
            phasekit_emission::kmeans::mean_imputed(frames).unwrap_or_default()
        };
        return gmeans(Frames::new(&data, d)?, settings);
    }
    let (n, d) = (frames.len(), frames.dim());
    // `settings` were validated when built (or deserialised).
    if n == 0 {
        return Err(GmmError::TooFewFrames("G-means needs frames".into()));
    }
    let mut centroids = vec![0.0; d];
    for x in frames.iter() {
        for (c, v) in centroids.iter_mut().zip(x) {
            *c += v / n as f64;
        }
    }
    loop {
        let km = lloyd(frames, centroids.clone(), settings.max_iter)?;
        centroids = km.centroids;
        let k = centroids.len() / d;
        let mut next = Vec::with_capacity(2 * centroids.len());
        let mut split_any = false;
        // Clusters after the splits decided so far in this round.
        let mut total = k;
        for j in 0..k {
            let members = members_of(frames, &km.labels, j);
            let c = &centroids[j * d..(j + 1) * d];
            let grow = total < settings.max_k;
            match (grow, split_cluster(&members, c, d, settings)) {
                (true, Some(children)) => {
                    next.extend_from_slice(&children);
                    split_any = true;
                    total += 1;
                }
                _ => next.extend_from_slice(c),
            }
        }
        centroids = next;
        if !split_any {
            break;
        }
        if centroids.len() / d >= settings.max_k {
            let km = lloyd(frames, centroids.clone(), settings.max_iter)?;
            centroids = km.centroids;
            break;
        }
    }
    let km = lloyd(frames, centroids, settings.max_iter)?;
    let k = km.centroids.len() / d;
    // At the cap, G-means' own answer is known only if no final cluster would split.
    let capped = k >= settings.max_k
        && (0..k).any(|j| {
            let members = members_of(frames, &km.labels, j);
            split_cluster(&members, &km.centroids[j * d..(j + 1) * d], d, settings).is_some()
        });
    Ok(GMeansResult {
        k,
        centroids: km.centroids,
        labels: km.labels,
        capped,
    })
}

/// The frames (`m × D`, row-major) labelled `j`.
fn members_of(frames: Frames<'_>, labels: &[usize], j: usize) -> Vec<f64> {
    frames
        .iter()
        .zip(labels)
        .filter(|(_, l)| **l == j)
        .flat_map(|(x, _)| x.iter().copied())
        .collect()
}

/// The two children of a cluster if the Anderson–Darling test rejects its Gaussianity.
fn split_cluster(members: &[f64], c: &[f64], d: usize, settings: GMeans) -> Option<Vec<f64>> {
    let m = members.len() / d;
    if m < settings.min_cluster {
        return None;
    }
    let cov = nalgebra::DMatrix::from_fn(d, d, |r, q| {
        members
            .chunks_exact(d)
            .map(|x| (x[r] - c[r]) * (x[q] - c[q]))
            .sum::<f64>()
            / m as f64
    });
    let eig = nalgebra::SymmetricEigen::new(cov);
    let (imax, lambda) =
        eig.eigenvalues
            .iter()
            .enumerate()
            .fold(
                (0, f64::NEG_INFINITY),
                |b, (i, v)| if *v > b.1 { (i, *v) } else { b },
            );
    if lambda.is_nan() || lambda <= 0.0 {
        return None;
    }
    let scale = (2.0 * lambda / std::f64::consts::PI).sqrt();
    let axis = eig.eigenvectors.column(imax);
    let mut init = Vec::with_capacity(2 * d);
    init.extend((0..d).map(|r| c[r] + scale * axis[r]));
    init.extend((0..d).map(|r| c[r] - scale * axis[r]));
    let frames = Frames::new(members, d).ok()?;
    let children = lloyd(frames, init, settings.max_iter).ok()?.centroids;
    let v: Vec<f64> = (0..d).map(|r| children[r] - children[d + r]).collect();
    let vv: f64 = v.iter().map(|x| x * x).sum();
    if vv.is_nan() || vv <= 0.0 {
        return None;
    }
    let proj: Vec<f64> = members
        .chunks_exact(d)
        .map(|x| x.iter().zip(&v).map(|(a, b)| a * b).sum::<f64>() / vv)
        .collect();
    let (_, p) = anderson_darling_normal(&proj)?;
    (p < settings.alpha).then_some(children)
}
