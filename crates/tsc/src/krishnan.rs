//! Krishnan-style transition state clustering (Krishnan et al., IJRR 2017).
//!
//! 1. Fit a mixture to the frames (optionally windows of `w` consecutive frames,
//!    stacked); label each frame with its most responsible component. The number
//!    of components is given or chosen automatically ([`Selector`]: BIC over a
//!    range, or G-means).
//! 2. A transition is a frame where the label changes (runs shorter than
//!    `min_run` frames are ignored).
//! 3. The transition states (the frames at the transitions) are clustered by a
//!    second mixture, its size given or chosen automatically.
//! 4. Clusters holding transitions from fewer than a fraction `ρ` of the
//!    demonstrations are pruned; the others are the segment boundaries.
//! 5. Optionally, the transitions of every kept cluster are sub-clustered by their
//!    normalised time `τ = t / (T − 1)` (a 1-D GMM, its size chosen by BIC), and
//!    sub-clusters supported by fewer than `ρ` of the demonstrations are pruned
//!    too: one place in state space visited at two moments of the task gives two
//!    transition clusters.

use crate::detect::{label_changes, Labeller, MixtureLabeller};
use crate::error::{Result, TscError};
use crate::select::{check_range, mixture_components, Selector};
use phasekit_emission::{CovarianceType, Frames, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit_gmm::{select_mixture_bic, Em, Gmm};
use serde::{Deserialize, Serialize};

/// Largest window (frames stacked into one feature vector) accepted: the windowed
/// dimension `w·D` beyond `64·D` only dilutes the mixture (and its covariances
/// grow as `(w·D)²`).
pub const MAX_WINDOW: usize = 64;

/// Settings of the optional time sub-clustering (step 5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimeClustering {
    /// Sub-clusters per transition cluster, at most (BIC chooses in `1..=max_clusters`).
    pub max_clusters: usize,
    /// Variance added to the 1-D time Gaussians (`τ ∈ [0, 1]`; `1e-4` is a standard
    /// deviation of 1 % of a demonstration's duration).
    pub reg: f64,
}

impl Default for TimeClustering {
    fn default() -> Self {
        TimeClustering {
            max_clusters: 3,
            reg: 1e-4,
        }
    }
}

/// Settings of Krishnan-style TSC.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KrishnanSettings {
    /// Components of the frame mixture (`None`: chosen by `selector` in `2..=max_components`;
    /// one component has no label change).
    pub components: Option<usize>,
    /// Largest number of components an automatic choice may give.
    pub max_components: usize,
    /// How automatic counts are chosen (frame mixture and transition clusters).
    #[serde(default)]
    pub selector: Selector,
    /// Frames stacked into one feature vector (1: the frame alone), `1..=MAX_WINDOW`.
    pub window: usize,
    /// Label runs shorter than this are ignored as flips.
    pub min_run: usize,
    /// Clusters of transition states (`None`: chosen by `selector` in `1..=max_components`).
    pub transition_clusters: Option<usize>,
    /// `ρ`: keep a transition cluster only if at least this fraction of demonstrations has a transition in it.
    pub prune_fraction: f64,
    /// Sub-clustering of every kept cluster's transitions by normalised time (`None`: off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_clusters: Option<TimeClustering>,
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
            selector: Selector::Bic,
            window: 1,
            min_run: 2,
            transition_clusters: None,
            prune_fraction: 0.5,
            time_clusters: None,
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

/// The time sub-clusters of one kept transition cluster.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TimeSubclusters {
    /// 1-D mixture over the normalised time `τ` of the cluster's training transitions
    /// (`None` when it had a single transition: one sub-cluster).
    pub mixture: Option<Gmm>,
    /// Sub-clusters kept after pruning.
    pub kept: Vec<usize>,
}

impl TimeSubclusters {
    /// Sub-cluster of a transition at normalised time `tau`.
    fn assign(&self, tau: f64) -> Result<usize> {
        Ok(match &self.mixture {
            None => 0,
            Some(m) => m.predict(Frames::new(&[tau], 1)?)?[0],
        })
    }
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
    /// Time sub-clusters of every kept cluster (same order as `kept`); empty when off.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub time_clusters: Vec<TimeSubclusters>,
}

/// Stacks `w` consecutive frames, oldest first: row `t` is
/// `[x_{t−w+1}, …, x_{t−1}, x_t]` with `x_s = x_0` for `s < 0` (causal: the start
/// repeats the first frame), `T × (w·D)`.
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

/// Normalised time `τ = t / (T − 1)` of frame `t` of `T` (`0` for `T = 1`).
pub fn normalised_time(t: usize, len: usize) -> f64 {
    if len > 1 {
        t as f64 / (len - 1) as f64
    } else {
        0.0
    }
}

fn invalid(name: &'static str, reason: String) -> TscError {
    TscError::InvalidSetting { name, reason }
}

impl KrishnanSettings {
    /// Checks every setting (not the data): window in `1..=MAX_WINDOW`, `ρ ∈ [0, 1]`,
    /// counts ≥ 1, `max_components ≥ 2` when a count is automatic, finite non-negative
    /// regularisation, and a usable time sub-clustering.
    pub fn validate(&self) -> Result<()> {
        if self.window == 0 || self.window > MAX_WINDOW {
            return Err(invalid(
                "window",
                format!(
                    "gmm-tsc stacks `window` frames into one vector: it must lie in 1..={MAX_WINDOW} \
                     (a windowed dimension of at most {MAX_WINDOW}× the frame's), got {}",
                    self.window
                ),
            ));
        }
        if !(0.0..=1.0).contains(&self.prune_fraction) {
            return Err(invalid(
                "rho",
                format!(
                    "the pruning fraction ρ must lie in [0, 1], got {}",
                    self.prune_fraction
                ),
            ));
        }
        if self.components == Some(0) || self.transition_clusters == Some(0) {
            return Err(invalid(
                "components",
                "a mixture needs at least one component".into(),
            ));
        }
        if self.components.is_none() {
            check_range("max-states", &(2..=self.max_components))?;
        }
        if self.transition_clusters.is_none() {
            check_range("max-states", &(1..=self.max_components))?;
        }
        if !(self.reg.is_finite() && self.reg >= 0.0) {
            return Err(invalid(
                "reg",
                format!("must be a finite number ≥ 0, got {}", self.reg),
            ));
        }
        if let Some(tc) = &self.time_clusters {
            if tc.max_clusters == 0 || !(tc.reg.is_finite() && tc.reg > 0.0) {
                return Err(invalid(
                    "time-clusters",
                    format!(
                        "time sub-clustering needs at least 1 sub-cluster and a finite variance floor > 0, got {} and {}",
                        tc.max_clusters, tc.reg
                    ),
                ));
            }
        }
        Ok(())
    }

    fn em(&self) -> Result<Em> {
        Ok(Em::builder()
            .regularisation(Regularisation::add_diagonal(self.reg)?)
            .restarts(self.restarts.max(1))
            .seed(self.seed)
            .build()?)
    }

    fn mixture(&self, frames: Frames<'_>, k: Option<usize>, min_auto: usize) -> Result<Gmm> {
        let em = self.em()?;
        let k = match k {
            Some(k) => k,
            None => mixture_components(self.selector, &em, frames, min_auto..=self.max_components)?,
        };
        Ok(em
            .fit(
                &Gaussian::standard(
                    CovarianceType::Full,
                    Shape {
                        n_states: k,
                        dim: frames.dim(),
                    },
                )?,
                frames,
            )?
            .model)
    }

    /// Fits the frame mixture and the transition clusters on demonstrations.
    pub fn fit(&self, data: &SequenceSet) -> Result<KrishnanTsc> {
        self.validate()?;
        if let Some((k, shortest)) = data.iter().map(|s| s.len()).enumerate().min_by_key(|x| x.1) {
            if self.window > shortest {
                return Err(invalid(
                    "window",
                    format!(
                        "a window of {} frames is longer than demonstration {k} ({shortest} frames)",
                        self.window
                    ),
                ));
            }
        }
        let d = data.dim();
        let stacked: Vec<Vec<f64>> = data.iter().map(|s| windowed(s, self.window)).collect();
        let all: Vec<f64> = stacked.concat();
        let mixture = self.mixture(Frames::new(&all, d * self.window)?, self.components, 2)?;
        let labeller = MixtureLabeller(&mixture);
        let mut points = Vec::new();
        let mut owner = Vec::new();
        let mut times = Vec::new();
        for (k, (seq, st)) in data.iter().zip(&stacked).enumerate() {
            let labels = labeller.label(Frames::new(st, d * self.window)?)?;
            for (t, f) in label_changes(&labels, self.min_run).iter().enumerate() {
                if *f {
                    points.extend_from_slice(seq.frame(t));
                    owner.push(k);
                    times.push(normalised_time(t, seq.len()));
                }
            }
        }
        if owner.is_empty() {
            return Err(TscError::NoTransitions { min_len: 1 });
        }
        let transition_mixture = self.mixture(
            Frames::new(&points, d)?,
            self.transition_clusters.map(|k| k.min(owner.len())),
            1,
        )?;
        let labels = transition_mixture.predict(Frames::new(&points, d)?)?;
        let n_demos = data.len();
        // ρ·n demonstrations must have a transition in a cluster for it to be kept.
        let supported = |demos: &[bool]| {
            demos.iter().filter(|x| **x).count() as f64 >= self.prune_fraction * n_demos as f64
        };
        let kc = transition_mixture.n_components();
        let mut demos_in = vec![vec![false; n_demos]; kc];
        for (l, k) in labels.iter().zip(&owner) {
            demos_in[*l][*k] = true;
        }
        let kept: Vec<usize> = (0..kc).filter(|&c| supported(&demos_in[c])).collect();
        let time_clusters = match &self.time_clusters {
            None => Vec::new(),
            Some(tc) => kept
                .iter()
                .map(|&c| {
                    let members: Vec<usize> =
                        (0..labels.len()).filter(|&i| labels[i] == c).collect();
                    self.time_subclusters(tc, &members, &times, &owner, n_demos, &supported)
                })
                .collect::<Result<_>>()?,
        };
        Ok(KrishnanTsc {
            mixture,
            transition_mixture,
            kept,
            window: self.window,
            min_run: self.min_run,
            time_clusters,
        })
    }

    /// Sub-clusters the transitions `members` of one cluster by their normalised time.
    fn time_subclusters(
        &self,
        tc: &TimeClustering,
        members: &[usize],
        times: &[f64],
        owner: &[usize],
        n_demos: usize,
        supported: &dyn Fn(&[bool]) -> bool,
    ) -> Result<TimeSubclusters> {
        let tau: Vec<f64> = members.iter().map(|&i| times[i]).collect();
        if tau.len() < 2 {
            return Ok(TimeSubclusters {
                mixture: None,
                kept: vec![0],
            });
        }
        let em = Em::builder()
            .regularisation(Regularisation::add_diagonal(tc.reg)?)
            .restarts(self.restarts.max(1))
            .seed(self.seed)
            .build()?;
        let frames = Frames::new(&tau, 1)?;
        let k = select_mixture_bic(
            &em,
            |k| {
                Gaussian::standard(
                    CovarianceType::Full,
                    Shape {
                        n_states: k,
                        dim: 1,
                    },
                )
            },
            frames,
            1..=tc.max_clusters.min(tau.len()),
        )?
        .best;
        let mixture = em
            .fit(
                &Gaussian::standard(
                    CovarianceType::Full,
                    Shape {
                        n_states: k,
                        dim: 1,
                    },
                )?,
                frames,
            )?
            .model;
        let sub = mixture.predict(frames)?;
        let mut demos_in = vec![vec![false; n_demos]; k];
        for (j, &i) in sub.iter().zip(members) {
            demos_in[*j][owner[i]] = true;
        }
        Ok(TimeSubclusters {
            mixture: Some(mixture),
            kept: (0..k).filter(|&j| supported(&demos_in[j])).collect(),
        })
    }
}

impl KrishnanTsc {
    /// The reported transition clusters, in id order: `(c, None)` is the kept
    /// component `c` of the transition mixture (ids are then the component indices
    /// themselves); with time sub-clustering, `(c, Some(j))` is time sub-cluster `j`
    /// of component `c` and ids count `0, 1, …` over the kept pairs.
    pub fn reported_clusters(&self) -> Vec<(usize, Option<usize>)> {
        if self.time_clusters.is_empty() {
            return self.kept.iter().map(|&c| (c, None)).collect();
        }
        self.kept
            .iter()
            .zip(&self.time_clusters)
            .flat_map(|(&c, tc)| tc.kept.iter().map(move |&j| (c, Some(j))))
            .collect()
    }

    /// Checks that the parts agree: kept clusters exist, time sub-clusters (if any)
    /// match the kept clusters and are 1-D.
    pub fn validate(&self) -> Result<()> {
        let bad = |reason: String| Err(invalid("gmm-tsc model", reason));
        let kc = self.transition_mixture.n_components();
        if self.kept.iter().any(|&c| c >= kc) {
            return bad(format!(
                "a kept transition cluster is not among the {kc} components"
            ));
        }
        if self.window == 0 || self.mixture.dim() != self.transition_mixture.dim() * self.window {
            return bad("the frame mixture's dimension is not window × the frame's".into());
        }
        if !self.time_clusters.is_empty() {
            if self.time_clusters.len() != self.kept.len() {
                return bad("one set of time sub-clusters per kept cluster is needed".into());
            }
            for tc in &self.time_clusters {
                let n = tc.mixture.as_ref().map_or(1, |m| m.n_components());
                if tc.mixture.as_ref().is_some_and(|m| m.dim() != 1)
                    || tc.kept.iter().any(|&j| j >= n)
                {
                    return bad("time sub-clusters are inconsistent".into());
                }
            }
        }
        Ok(())
    }

    /// Labels, transitions and their (kept) clusters of one demonstration
    /// (cluster ids as in [`KrishnanTsc::reported_clusters`]).
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
            let states = self
                .transition_mixture
                .predict(Frames::new(&points, seq.dim())?)?;
            if self.time_clusters.is_empty() {
                states
                    .into_iter()
                    .map(|c| self.kept.contains(&c).then_some(c))
                    .collect()
            } else {
                let ids = self.reported_clusters();
                states
                    .iter()
                    .zip(&transitions)
                    .map(|(&c, &t)| {
                        let Some(i) = self.kept.iter().position(|&k| k == c) else {
                            return Ok(None);
                        };
                        let j = self.time_clusters[i].assign(normalised_time(t, seq.len()))?;
                        Ok(ids.iter().position(|&p| p == (c, Some(j))))
                    })
                    .collect::<Result<_>>()?
            }
        };
        Ok(Segmentation {
            labels,
            transitions,
            clusters,
        })
    }
}
