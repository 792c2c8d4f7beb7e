//! k-means clustering (Lloyd's algorithm with k-means++ or random seeding),
//! used to initialise HMMs and mixtures.

use crate::error::{EmissionError, Result};
use crate::Frames;
use rand::Rng;

/// How the first centroids are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Seeding {
    /// k-means++ (Arthur & Vassilvitskii 2007): each next centroid drawn with
    /// probability proportional to the squared distance to the nearest chosen one.
    PlusPlus,
    /// `k` distinct frames drawn uniformly.
    Random,
}

/// Result of [`kmeans`], [`lloyd`] and [`weighted_kmeans`].
///
/// `#[non_exhaustive]`: read its fields, it is built only here.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct KMeans {
    /// `k × D` centroids, row-major.
    pub centroids: Vec<f64>,
    /// Cluster of every frame.
    pub labels: Vec<usize>,
    /// Sum of squared distances of the frames to their centroids.
    pub inertia: f64,
    /// Lloyd iterations run.
    pub iterations: usize,
}

fn sq_dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

fn nearest(x: &[f64], centroids: &[f64], d: usize) -> (usize, f64) {
    let mut best = (0, f64::INFINITY);
    for (j, c) in centroids.chunks_exact(d).enumerate() {
        let dist = sq_dist(x, c);
        if dist < best.1 {
            best = (j, dist);
        }
    }
    best
}

/// A copy of `frames` whose missing values (NaN) are replaced by the mean of
/// the observed values of their dimension (0 where a dimension is never
/// observed); `None` when nothing is missing.
///
/// k-means only seeds EM, which then treats the missing values exactly, so
/// the simplest imputation that keeps distances finite is enough here (and
/// for G-means, which only counts clusters).
pub fn mean_imputed(frames: Frames<'_>) -> Option<Vec<f64>> {
    if !frames.has_missing() {
        return None;
    }
    let d = frames.dim();
    let (mut sum, mut count) = (vec![0.0; d], vec![0usize; d]);
    for x in frames.iter() {
        for k in 0..d {
            if !x[k].is_nan() {
                sum[k] += x[k];
                count[k] += 1;
            }
        }
    }
    let mean: Vec<f64> = (0..d)
        .map(|k| {
            if count[k] > 0 {
                sum[k] / count[k] as f64
            } else {
                0.0
            }
        })
        .collect();
    Some(
        frames
            .as_slice()
            .iter()
            .enumerate()
            .map(|(i, v)| if v.is_nan() { mean[i % d] } else { *v })
            .collect(),
    )
}

/// Clusters `frames` into `k` groups; deterministic for a given `rng` state.
///
/// Errors when there are fewer frames than clusters. A cluster that empties
/// during the iterations is re-seeded at the frame farthest from its centroid.
/// Missing values (NaN) take the mean of their dimension's observed values.
pub fn kmeans<R: Rng + ?Sized>(
    frames: Frames<'_>,
    k: usize,
    seeding: Seeding,
    max_iter: usize,
    rng: &mut R,
) -> Result<KMeans> {
    if let Some(filled) = mean_imputed(frames) {
        return kmeans(
            Frames::new(&filled, frames.dim())?,
            k,
            seeding,
            max_iter,
            rng,
        );
    }
    let (n, d) = (frames.len(), frames.dim());
    if k == 0 || n < k {
        return Err(EmissionError::InvalidParameter {
            name: "k",
            reason: format!("cannot form {k} clusters from {n} frames"),
        });
    }
    let mut centroids = Vec::with_capacity(k * d);
    match seeding {
        Seeding::Random => {
            for idx in rand::seq::index::sample(rng, n, k) {
                centroids.extend_from_slice(frames.frame(idx));
            }
        }
        Seeding::PlusPlus => {
            centroids.extend_from_slice(frames.frame(rng.random_range(0..n)));
            let mut dist: Vec<f64> = frames.iter().map(|x| sq_dist(x, &centroids[..d])).collect();
            for _ in 1..k {
                let total: f64 = dist.iter().sum();
                let idx = if total > 0.0 {
                    let u = rng.random::<f64>() * total;
                    let mut acc = 0.0;
                    dist.iter()
                        .position(|v| {
                            acc += v;
                            u < acc
                        })
                        .unwrap_or(n - 1)
                } else {
                    rng.random_range(0..n)
                };
                let start = centroids.len();
                centroids.extend_from_slice(frames.frame(idx));
                for (x, dv) in frames.iter().zip(dist.iter_mut()) {
                    *dv = dv.min(sq_dist(x, &centroids[start..start + d]));
                }
            }
        }
    }
    lloyd(frames, centroids, max_iter)
}

/// Lloyd iterations from the given `k × D` centroids until the labels stop
/// changing or `max_iter` is reached. A cluster that empties is re-seeded at
/// the frame farthest from its centroid.
///
/// Errors when there is no frame, no centroid, or the centroids are not `k × D`
/// (or not finite). Missing values take the mean of their dimension's observed values.
pub fn lloyd(frames: Frames<'_>, mut centroids: Vec<f64>, max_iter: usize) -> Result<KMeans> {
    if let Some(filled) = mean_imputed(frames) {
        return lloyd(Frames::new(&filled, frames.dim())?, centroids, max_iter);
    }
    let (n, d) = (frames.len(), frames.dim());
    if centroids.iter().any(|c| !c.is_finite()) {
        return Err(EmissionError::InvalidParameter {
            name: "centroids",
            reason: "a centroid value is not finite".into(),
        });
    }
    if n == 0 || centroids.is_empty() || centroids.len() % d != 0 {
        return Err(EmissionError::InvalidParameter {
            name: "centroids",
            reason: format!(
                "{} centroid values for {n} frames of dimension {d}: need at least one frame and k × {d} values, k ≥ 1",
                centroids.len()
            ),
        });
    }
    let k = centroids.len() / d;
    let mut labels = vec![0; n];
    let mut iterations = 0;
    let mut inertia = f64::INFINITY;
    let max_iter = max_iter.max(1);
    for it in 0..max_iter {
        iterations = it + 1;
        let mut changed = false;
        inertia = 0.0;
        for (t, x) in frames.iter().enumerate() {
            let (j, dist) = nearest(x, &centroids, d);
            changed |= labels[t] != j || it == 0;
            labels[t] = j;
            inertia += dist;
        }
        // Stop after an assignment, never after a centroid update, so that the
        // labels and the inertia returned belong to the centroids returned.
        if !changed || it + 1 == max_iter {
            break;
        }
        let mut sums = vec![0.0; k * d];
        let mut counts = vec![0usize; k];
        for (t, x) in frames.iter().enumerate() {
            counts[labels[t]] += 1;
            for (s, v) in sums[labels[t] * d..(labels[t] + 1) * d].iter_mut().zip(x) {
                *s += v;
            }
        }
        for j in 0..k {
            if counts[j] == 0 {
                let far = (0..n)
                    .max_by(|&a, &b| {
                        let da = sq_dist(
                            frames.frame(a),
                            &centroids[labels[a] * d..(labels[a] + 1) * d],
                        );
                        let db = sq_dist(
                            frames.frame(b),
                            &centroids[labels[b] * d..(labels[b] + 1) * d],
                        );
                        da.total_cmp(&db)
                    })
                    .unwrap_or(0);
                centroids[j * d..(j + 1) * d].copy_from_slice(frames.frame(far));
                labels[far] = j;
            } else {
                for (c, s) in centroids[j * d..(j + 1) * d]
                    .iter_mut()
                    .zip(&sums[j * d..(j + 1) * d])
                {
                    *c = s / counts[j] as f64;
                }
            }
        }
    }
    Ok(KMeans {
        centroids,
        labels,
        inertia,
        iterations,
    })
}

/// Weighted k-means: clusters the frames with positive weight into `k`
/// groups, minimising `Σ_t w_t ‖x_t − c_{label(t)}‖²`; k-means++ seeding with
/// probabilities `∝ w_t · (squared distance to the nearest chosen centroid)`
/// (the first `∝ w_t`), then Lloyd iterations with weighted means. Frames of
/// zero weight are labelled with their nearest centroid and move nothing.
/// Deterministic for a given `rng` state.
///
/// Errors when fewer than `k` frames have positive weight, or a weight is
/// negative or not finite. A cluster that empties is re-seeded at the
/// weighted frame farthest from its centroid. Missing values (NaN) take the
/// mean of their dimension's observed values.
pub fn weighted_kmeans<R: Rng + ?Sized>(
    frames: Frames<'_>,
    weights: &[f64],
    k: usize,
    max_iter: usize,
    rng: &mut R,
) -> Result<KMeans> {
    if let Some(filled) = mean_imputed(frames) {
        return weighted_kmeans(
            Frames::new(&filled, frames.dim())?,
            weights,
            k,
            max_iter,
            rng,
        );
    }
    let (n, d) = (frames.len(), frames.dim());
    crate::check_len("k-means weights", n, weights.len())?;
    if let Some(t) = weights.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
        return Err(EmissionError::InvalidParameter {
            name: "weights",
            reason: format!(
                "frame {t}: weight {} is not finite and non-negative",
                weights[t]
            ),
        });
    }
    let live: Vec<usize> = (0..n).filter(|&t| weights[t] > 0.0).collect();
    if k == 0 || live.len() < k {
        return Err(EmissionError::InvalidParameter {
            name: "k",
            reason: format!(
                "cannot form {k} clusters from {} frames with positive weight",
                live.len()
            ),
        });
    }
    let draw = |p: &[f64], rng: &mut R| -> usize {
        let total: f64 = live.iter().map(|&t| p[t]).sum();
        if total.is_nan() || total <= 0.0 {
            return live[rng.random_range(0..live.len())];
        }
        let u = rng.random::<f64>() * total;
        let mut acc = 0.0;
        for &t in &live {
            acc += p[t];
            if u < acc {
                return t;
            }
        }
        *live.last().unwrap_or(&0)
    };
    let mut centroids = Vec::with_capacity(k * d);
    let first = draw(weights, rng);
    centroids.extend_from_slice(frames.frame(first));
    let mut dist: Vec<f64> = frames.iter().map(|x| sq_dist(x, &centroids[..d])).collect();
    for _ in 1..k {
        let p: Vec<f64> = dist.iter().zip(weights).map(|(a, w)| a * w).collect();
        let idx = draw(&p, rng);
        let start = centroids.len();
        centroids.extend_from_slice(frames.frame(idx));
        for (x, dv) in frames.iter().zip(dist.iter_mut()) {
            *dv = dv.min(sq_dist(x, &centroids[start..start + d]));
        }
    }
    let mut labels = vec![0; n];
    let (mut inertia, mut iterations) = (f64::INFINITY, 0);
    let max_iter = max_iter.max(1);
    for it in 0..max_iter {
        iterations = it + 1;
        let mut changed = false;
        inertia = 0.0;
        for (t, x) in frames.iter().enumerate() {
            let (j, dist) = nearest(x, &centroids, d);
            changed |= labels[t] != j || it == 0;
            labels[t] = j;
            inertia += weights[t] * dist;
        }
        if !changed || it + 1 == max_iter {
            break;
        }
        let mut sums = vec![0.0; k * d];
        let mut mass = vec![0.0; k];
        for &t in &live {
            let (j, w) = (labels[t], weights[t]);
            mass[j] += w;
            for (s, v) in sums[j * d..(j + 1) * d].iter_mut().zip(frames.frame(t)) {
                *s += w * v;
            }
        }
        for j in 0..k {
            if mass[j] > 0.0 {
                for (c, s) in centroids[j * d..(j + 1) * d]
                    .iter_mut()
                    .zip(&sums[j * d..(j + 1) * d])
                {
                    *c = s / mass[j];
                }
            } else {
                let far = live
                    .iter()
                    .copied()
                    .max_by(|&a, &b| {
                        let da = sq_dist(
                            frames.frame(a),
                            &centroids[labels[a] * d..(labels[a] + 1) * d],
                        );
                        let db = sq_dist(
                            frames.frame(b),
                            &centroids[labels[b] * d..(labels[b] + 1) * d],
                        );
                        da.total_cmp(&db)
                    })
                    .unwrap_or(0);
                centroids[j * d..(j + 1) * d].copy_from_slice(frames.frame(far));
                labels[far] = j;
            }
        }
    }
    Ok(KMeans {
        centroids,
        labels,
        inertia,
        iterations,
    })
}
