//! Krishnan-style transition state clustering (Krishnan et al., IJRR 2017).
//!
//! 1. Fit a mixture to the frames (optionally windows of `w` consecutive frames,
//!    stacked); label each frame with its most responsible component.
//! 2. A transition is a frame where the label changes (runs shorter than
//!    `min_run` frames are ignored).
//! 3. The transition states (the frames at the transitions) are clustered by a
//!    second mixture, its size chosen by BIC.
//! 4. Clusters holding transitions from fewer than a fraction `ρ` of the
//!    demonstrations are pruned; the others are the segment boundaries.

use crate::detect::{label_changes, Labeller, MixtureLabeller};
use crate::error::{Result, TscError};
use phasekit_emission::{CovarianceType, Frames, Gaussian, Regularization, SequenceSet};
use phasekit_gmm::{select_mixture_bic, Em, Gmm};
use serde::{Deserialize, Serialize};

/// Settings of Krishnan-style TSC.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KrishnanSettings {
    /// Components of the frame mixture (`None`: BIC over `1..=max_components`).
    pub components: Option<usize>,
    /// Largest number of components tried by BIC.
    pub max_components: usize,
    /// Frames stacked into one feature vector (1: the frame alone).
    pub window: usize,
    /// Label runs shorter than this are ignored as flips.
    pub min_run: usize,
    /// Clusters of transition states (`None`: BIC over `1..=max_components`).
    pub transition_clusters: Option<usize>,
    /// Keep a transition cluster only if at least this fraction of demonstrations has a transition in it.
    pub prune_fraction: f64,
    /// Covariance regularisation added after every M-step.
    pub reg: f64,
    /// Restarts of each mixture fit.
    pub restarts: usize,
    /// Seed.
    pub seed: u64,
}

impl Default for KrishnanSettings {
    fn default() -> Self {
        KrishnanSettings {
            components: None,
            max_components: 8,
            window: 1,
            min_run: 2,
            transition_clusters: None,
            prune_fraction: 0.5,
            reg: 1e-2,
            restarts: 3,
            seed: 0,
        }
    }
}

/// Per-demonstration output of a segmentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Segmentation {
    /// State (component) of every frame.
    pub labels: Vec<usize>,
    /// Frames flagged as transitions, in order.
    pub transitions: Vec<usize>,
    /// Cluster of every transition frame (`None` if its cluster was pruned or there are none).
    pub clusters: Vec<Option<usize>>,
}

/// A fitted Krishnan-style TSC.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct KrishnanTsc {
    /// Mixture over (windowed) frames.
    pub mixture: Gmm,
    /// Mixture over transition states (un-windowed frames).
    pub transition_mixture: Gmm,
    /// Transition clusters kept after pruning.
    pub kept: Vec<usize>,
    /// Frames per window.
    pub window: usize,
    /// Minimum label run.
    pub min_run: usize,
}

/// Stacks `w` consecutive frames (repeating the first frame at the start, causally).
pub fn windowed(seq: Frames<'_>, w: usize) -> Vec<f64> {
    let d = seq.dim();
    let mut out = Vec::with_capacity(seq.len() * d * w);
    for t in 0..seq.len() {
        for k in (0..w).rev() {
            out.extend_from_slice(seq.frame(t.saturating_sub(k)));
        }
    }
    out
}

impl KrishnanSettings {
    fn em(&self) -> Result<Em> {
        Ok(Em::builder()
            .regularization(Regularization::add_diagonal(self.reg)?)
            .restarts(self.restarts.max(1))
            .seed(self.seed)
            .build()?)
    }

    fn mixture(&self, frames: Frames<'_>, k: Option<usize>) -> Result<Gmm> {
        let em = self.em()?;
        let d = frames.dim();
        let k = match k {
            Some(k) => k,
            None => {
                let max = self.max_components.min(frames.len()).max(1);
                select_mixture_bic(
                    &em,
                    |k| Gaussian::standard(CovarianceType::Full, k, d),
                    frames,
                    1..=max,
                )?
                .best
            }
        };
        Ok(em
            .fit(&Gaussian::standard(CovarianceType::Full, k, d)?, frames)?
            .model)
    }

    /// Fits the frame mixture and the transition clusters on demonstrations.
    pub fn fit(&self, data: &SequenceSet) -> Result<KrishnanTsc> {
        if self.window == 0 || !(0.0..=1.0).contains(&self.prune_fraction) {
            return Err(TscError::InvalidSetting {
                name: "window/prune_fraction",
                reason: format!(
                    "window must be ≥ 1 and prune_fraction in [0, 1], got {} and {}",
                    self.window, self.prune_fraction
                ),
            });
        }
        let d = data.dim();
        let stacked: Vec<Vec<f64>> = data.iter().map(|s| windowed(s, self.window)).collect();
        let all: Vec<f64> = stacked.concat();
        let mixture = self.mixture(Frames::new(&all, d * self.window)?, self.components)?;
        let labeller = MixtureLabeller(&mixture);
        let mut points = Vec::new();
        let mut owner = Vec::new();
        for (k, (seq, st)) in data.iter().zip(&stacked).enumerate() {
            let labels = labeller.label(Frames::new(st, d * self.window)?)?;
            for (t, f) in label_changes(&labels, self.min_run).iter().enumerate() {
                if *f {
                    points.extend_from_slice(seq.frame(t));
                    owner.push(k);
                }
            }
        }
        if owner.is_empty() {
            return Err(TscError::NoTransitions { min_len: 1 });
        }
        let transition_mixture = self.mixture(
            Frames::new(&points, d)?,
            self.transition_clusters.map(|k| k.min(owner.len())),
        )?;
        let labels = transition_mixture.predict(Frames::new(&points, d)?)?;
        let kc = transition_mixture.n_components();
        let mut demos_in = vec![vec![false; data.len()]; kc];
        for (l, k) in labels.iter().zip(&owner) {
            demos_in[*l][*k] = true;
        }
        let kept = (0..kc)
            .filter(|&c| {
                demos_in[c].iter().filter(|x| **x).count() as f64
                    >= self.prune_fraction * data.len() as f64
            })
            .collect();
        Ok(KrishnanTsc {
            mixture,
            transition_mixture,
            kept,
            window: self.window,
            min_run: self.min_run,
        })
    }
}

impl KrishnanTsc {
    /// Labels, transitions and their (kept) clusters of one demonstration.
    pub fn segment(&self, seq: Frames<'_>) -> Result<Segmentation> {
        let st = windowed(seq, self.window);
        let labels =
            MixtureLabeller(&self.mixture).label(Frames::new(&st, seq.dim() * self.window)?)?;
        let transitions: Vec<usize> = label_changes(&labels, self.min_run)
            .iter()
            .enumerate()
            .filter_map(|(t, f)| f.then_some(t))
            .collect();
        let points: Vec<f64> = transitions
            .iter()
            .flat_map(|&t| seq.frame(t).iter().copied())
            .collect();
        let clusters = if transitions.is_empty() {
            Vec::new()
        } else {
            self.transition_mixture
                .predict(Frames::new(&points, seq.dim())?)?
                .into_iter()
                .map(|c| self.kept.contains(&c).then_some(c))
                .collect()
        };
        Ok(Segmentation {
            labels,
            transitions,
            clusters,
        })
    }
}
