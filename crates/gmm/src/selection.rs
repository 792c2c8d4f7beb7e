//! Choosing the number of components (or HMM states): BIC over a range, and
//! G-means (Hamerly & Elkan, "Learning the k in k-means", NIPS 2003).

use crate::em::Em;
use crate::error::{GmmError, Result};
use phasekit_emission::kmeans::lloyd;
use phasekit_emission::{Emission, Frames, SequenceSet};
use phasekit_hmm::BaumWelch;
use serde::{Deserialize, Serialize};

/// Scores of every candidate and the chosen one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    /// The number of components (states) with the lowest score.
    pub best: usize,
    /// `(k, BIC)` for every candidate that could be fitted, in the order tried.
    pub scores: Vec<(usize, f64)>,
    /// `(k, error message)` for candidates that could not be fitted.
    pub failures: Vec<(usize, String)>,
}

fn pick(scores: Vec<(usize, f64)>, failures: Vec<(usize, String)>) -> Result<Selection> {
    let best = scores
        .iter()
        .filter(|(_, s)| s.is_finite())
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(k, _)| *k)
        .ok_or_else(|| GmmError::InvalidParameter {
            name: "candidates",
            reason: format!("no candidate could be fitted: {failures:?}"),
        })?;
    Ok(Selection {
        best,
        scores,
        failures,
    })
}

/// BIC `−2 log p(X) + p log N` of a mixture fitted for every `k` in `candidates`;
/// `template(k)` gives the component structure with `k` states.
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
            Err(e) => failures.push((k, e.to_string())),
        }
    }
    pick(scores, failures)
}

/// BIC of an HMM fitted by `bw` for every state count in `candidates`.
pub fn select_hmm_states_bic<E: Emission>(
    bw: &BaumWelch,
    template: impl Fn(usize) -> phasekit_emission::Result<E>,
    data: &SequenceSet,
    candidates: impl IntoIterator<Item = usize>,
) -> Result<Selection> {
    let (mut scores, mut failures) = (Vec::new(), Vec::new());
    for k in candidates {
        let r = template(k)
            .map_err(GmmError::from)
            .and_then(|t| Ok(bw.fit(&t, data)?))
            .and_then(|f| Ok(f.model.bic(data)?));
        match r {
            Ok(bic) => scores.push((k, bic)),
            Err(e) => failures.push((k, e.to_string())),
        }
    }
    pick(scores, failures)
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
    if !(var > 0.0) {
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

/// Settings of [`gmeans`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GMeans {
    /// Significance level of the Anderson–Darling test (Hamerly & Elkan use `1e-4`).
    pub alpha: f64,
    /// Never grow beyond this many clusters.
    pub max_k: usize,
    /// Clusters with fewer frames than this are not split.
    pub min_cluster: usize,
    /// Lloyd iterations per refinement.
    pub max_iter: usize,
}

impl Default for GMeans {
    fn default() -> Self {
        GMeans {
            alpha: 1e-4,
            max_k: 32,
            min_cluster: 8,
            max_iter: 100,
        }
    }
}

/// Result of [`gmeans`].
#[derive(Debug, Clone, PartialEq)]
pub struct GMeansResult {
    /// Number of clusters found.
    pub k: usize,
    /// `k × D` centroids.
    pub centroids: Vec<f64>,
    /// Cluster of every frame.
    pub labels: Vec<usize>,
}

/// G-means: start from one cluster; split a cluster while the projection of its
/// frames onto the axis joining its two 2-means children is not Gaussian by the
/// Anderson–Darling test at level `alpha`. Deterministic (no random choice:
/// children start at `c ± s √(2λ/π)` along the principal axis `s`, `λ` its variance).
pub fn gmeans(frames: Frames<'_>, settings: GMeans) -> Result<GMeansResult> {
    let (n, d) = (frames.len(), frames.dim());
    if n == 0 {
        return Err(GmmError::TooFewFrames("G-means needs frames".into()));
    }
    if !(settings.alpha > 0.0 && settings.alpha < 1.0) || settings.max_k == 0 {
        return Err(GmmError::InvalidParameter {
            name: "gmeans",
            reason: format!("alpha must lie in (0, 1) and max_k ≥ 1, got {settings:?}"),
        });
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
            let members: Vec<f64> = frames
                .iter()
                .zip(&km.labels)
                .filter(|(_, l)| **l == j)
                .flat_map(|(x, _)| x.iter().copied())
                .collect();
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
    Ok(GMeansResult {
        k: km.centroids.len() / d,
        centroids: km.centroids,
        labels: km.labels,
    })
}

/// The two children of a cluster if the Anderson–Darling test rejects its Gaussianity.
fn split_cluster(members: &[f64], c: &[f64], d: usize, settings: GMeans) -> Option<Vec<f64>> {
    let m = members.len() / d;
    if m < settings.min_cluster.max(3) {
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
    if !(lambda > 0.0) {
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
    if !(vv > 0.0) {
        return None;
    }
    let proj: Vec<f64> = members
        .chunks_exact(d)
        .map(|x| x.iter().zip(&v).map(|(a, b)| a * b).sum::<f64>() / vv)
        .collect();
    let (_, p) = anderson_darling_normal(&proj)?;
    (p < settings.alpha).then_some(children)
}
