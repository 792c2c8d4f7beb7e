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
use crate::emission_choice::{AnyEmission, EmissionKind};
use crate::error::{NoTransitionCause, Result, TscError};
use crate::segmentation::Segmentation;
use crate::select::{check_range, mixture_components_of, AutoCount, Selector};
use phasekit_emission::{CovarianceType, Frames, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit_gmm::{select_mixture_bic, Em, Gmm};
use serde::{Deserialize, Serialize};

/// Largest window (frames stacked into one feature vector) accepted: the windowed
/// dimension `w·D` beyond `64·D` only dilutes the mixture (and its covariances
/// grow as `(w·D)²`).
pub const MAX_WINDOW: usize = 64;

/// Settings of the optional time sub-clustering (step 5), validated at
/// construction ([`TimeClustering::new`]) and on deserialisation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "TimeClusteringRaw")]
pub struct TimeClustering {
    max_clusters: usize,
    reg: f64,
}

/// The serialised form of [`TimeClustering`], before validation.
#[derive(Deserialize)]
struct TimeClusteringRaw {
    max_clusters: usize,
    reg: f64,
}

impl TryFrom<TimeClusteringRaw> for TimeClustering {
    type Error = TscError;
    fn try_from(r: TimeClusteringRaw) -> Result<Self> {
        TimeClustering::new(r.max_clusters, r.reg)
    }
}

impl Default for TimeClustering {
    /// At most 3 sub-clusters, variance floor `1e-4`.
    fn default() -> Self {
        TimeClustering {
            max_clusters: 3,
            reg: 1e-4,
        }
    }
}

impl TimeClustering {
    /// At most `max_clusters ≥ 1` sub-clusters per transition cluster (BIC
    /// chooses in `1..=max_clusters`), with the variance `reg > 0` added to the
    /// 1-D time Gaussians (`τ ∈ [0, 1]`; `1e-4` is a standard deviation of 1 %
    /// of a demonstration's duration).
    pub fn new(max_clusters: usize, reg: f64) -> Result<Self> {
        if max_clusters == 0 || !(reg.is_finite() && reg > 0.0) {
            return Err(invalid(
                "time_clusters",
                format!(
                    "time sub-clustering needs at least 1 sub-cluster and a finite variance floor > 0, got {max_clusters} and {reg}"
                ),
            ));
        }
        Ok(TimeClustering { max_clusters, reg })
    }

    /// Sub-clusters per transition cluster, at most.
    pub fn max_clusters(&self) -> usize {
        self.max_clusters
    }

    /// Variance added to the 1-D time Gaussians.
    pub fn reg(&self) -> f64 {
        self.reg
    }
}

/// Settings of Krishnan-style TSC, validated once by
/// [`KrishnanSettingsBuilder::build`] (and on deserialisation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "KrishnanSettingsRaw")]
pub struct KrishnanSettings {
    components: Option<usize>,
    max_components: usize,
    selector: Selector,
    window: usize,
    min_run: usize,
    transition_clusters: Option<usize>,
    prune_fraction: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    time_clusters: Option<TimeClustering>,
    reg: f64,
    restarts: usize,
    seed: u64,
    /// The emission of every mixture component (full Gaussians by default;
    /// not written then, so that older files and new ones agree).
    #[serde(default, skip_serializing_if = "EmissionKind::is_default")]
    emission: EmissionKind,
}

/// The serialised form of [`KrishnanSettings`], before validation (the field
/// names of model files written since version 1).
#[derive(Deserialize)]
struct KrishnanSettingsRaw {
    components: Option<usize>,
    max_components: usize,
    #[serde(default)]
    selector: Selector,
    window: usize,
    min_run: usize,
    transition_clusters: Option<usize>,
    prune_fraction: f64,
    #[serde(default)]
    time_clusters: Option<TimeClustering>,
    reg: f64,
    restarts: usize,
    seed: u64,
    #[serde(default)]
    emission: EmissionKind,
}

impl TryFrom<KrishnanSettingsRaw> for KrishnanSettings {
    type Error = TscError;
    fn try_from(r: KrishnanSettingsRaw) -> Result<Self> {
        KrishnanSettingsBuilder(KrishnanSettings {
            components: r.components,
            max_components: r.max_components,
            selector: r.selector,
            window: r.window,
            min_run: r.min_run,
            transition_clusters: r.transition_clusters,
            prune_fraction: r.prune_fraction,
            time_clusters: r.time_clusters,
            reg: r.reg,
            restarts: r.restarts,
            seed: r.seed,
            emission: r.emission,
        })
        .build()
    }
}

impl Default for KrishnanSettings {
    /// Automatic counts by BIC up to 8, the frame alone (window 1), label runs
    /// of at least 2 frames, `ρ = 0.5`, no time sub-clustering, `reg = 1e-2`,
    /// 3 runs per mixture fit, seed 0.
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
            emission: EmissionKind::default(),
        }
    }
}

/// Builder of [`KrishnanSettings`]; [`KrishnanSettingsBuilder::build`] validates once.
#[derive(Debug, Clone)]
pub struct KrishnanSettingsBuilder(KrishnanSettings);

impl KrishnanSettingsBuilder {
    /// Components of the frame mixture (`None`: chosen by the selector in
    /// `2..=max_components`; one component has no label change).
    pub fn components(mut self, k: Option<usize>) -> Self {
        self.0.components = k;
        self
    }
    /// Largest number of components (and transition clusters) an automatic choice may give.
    pub fn max_components(mut self, k: usize) -> Self {
        self.0.max_components = k;
        self
    }
    /// How automatic counts are chosen (frame mixture and transition clusters).
    pub fn selector(mut self, s: Selector) -> Self {
        self.0.selector = s;
        self
    }
    /// Frames stacked into one feature vector, `1..=MAX_WINDOW` (1: the frame alone).
    pub fn window(mut self, w: usize) -> Self {
        self.0.window = w;
        self
    }
    /// Label runs shorter than this are ignored as flips.
    pub fn min_run(mut self, n: usize) -> Self {
        self.0.min_run = n;
        self
    }
    /// Clusters of transition states (`None`: chosen by the selector in `1..=max_components`).
    pub fn transition_clusters(mut self, k: Option<usize>) -> Self {
        self.0.transition_clusters = k;
        self
    }
    /// `ρ ∈ [0, 1]`: keep a transition cluster only if at least this fraction of
    /// demonstrations has a transition in it.
    pub fn prune_fraction(mut self, rho: f64) -> Self {
        self.0.prune_fraction = rho;
        self
    }
    /// Sub-clustering of every kept cluster's transitions by normalised time (`None`: off).
    pub fn time_clusters(mut self, tc: Option<TimeClustering>) -> Self {
        self.0.time_clusters = tc;
        self
    }
    /// Covariance regularisation `r ≥ 0` added after every M-step.
    pub fn reg(mut self, reg: f64) -> Self {
        self.0.reg = reg;
        self
    }
    /// Runs (k-means++ seeds) of each mixture fit, at least 1.
    pub fn restarts(mut self, n: usize) -> Self {
        self.0.restarts = n;
        self
    }
    /// Seed of every mixture fit.
    pub fn seed(mut self, seed: u64) -> Self {
        self.0.seed = seed;
        self
    }

    /// The emission of the frame mixture's and the transition mixture's
    /// components (the `emission=` key; the time sub-clusters stay 1-D Gaussians).
    pub fn emission(mut self, emission: EmissionKind) -> Self {
        self.0.emission = emission;
        self
    }
    /// Checks every setting (not the data): window in `1..=MAX_WINDOW`, `ρ ∈ [0, 1]`,
    /// counts ≥ 1, `max_components ≥ 2` when the frame mixture's count is
    /// automatic, finite non-negative regularisation, at least one run.
    pub fn build(self) -> Result<KrishnanSettings> {
        let s = self.0;
        if s.window == 0 || s.window > MAX_WINDOW {
            return Err(invalid(
                "window",
                format!(
                    "gmm-tsc stacks `window` frames into one vector: it must lie in 1..={MAX_WINDOW} \
                     (a windowed dimension of at most {MAX_WINDOW}× the frame's), got {}",
                    s.window
                ),
            ));
        }
        if !(0.0..=1.0).contains(&s.prune_fraction) {
            return Err(invalid(
                "rho",
                format!(
                    "the pruning fraction ρ must lie in [0, 1], got {}",
                    s.prune_fraction
                ),
            ));
        }
        if s.components == Some(0) || s.transition_clusters == Some(0) {
            return Err(invalid(
                "components",
                "a mixture needs at least one component".into(),
            ));
        }
        if s.components.is_none() {
            check_range("max_states", &(2..=s.max_components))?;
        }
        if s.transition_clusters.is_none() {
            check_range("max_states", &(1..=s.max_components))?;
        }
        if !(s.reg.is_finite() && s.reg >= 0.0) {
            return Err(invalid(
                "reg",
                format!("must be a finite number ≥ 0, got {}", s.reg),
            ));
        }
        if s.restarts == 0 {
            return Err(invalid("restarts", "at least one run is needed".into()));
        }
        Ok(s)
    }
}

/// The time sub-clusters of one kept transition cluster (made by
/// [`KrishnanSettings::fit`]; checked with the model that holds them).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TimeSubclusters {
    mixture: Option<Gmm>,
    kept: Vec<usize>,
}

impl TimeSubclusters {
    /// 1-D mixture over the normalised time `τ` of the cluster's training
    /// transitions (`None` when it had a single transition: one sub-cluster).
    pub fn mixture(&self) -> Option<&Gmm> {
        self.mixture.as_ref()
    }

    /// Sub-clusters kept after pruning.
    pub fn kept(&self) -> &[usize] {
        &self.kept
    }

    /// Sub-cluster of a transition at normalised time `tau`.
    fn assign(&self, tau: f64) -> Result<usize> {
        Ok(match &self.mixture {
            None => 0,
            Some(m) => m.predict(Frames::new(&[tau], 1)?)?[0],
        })
    }
}

/// A fitted Krishnan-style TSC (made by [`KrishnanSettings::fit`]; its parts
/// are checked to agree on deserialisation).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "KrishnanTscRaw")]
pub struct KrishnanTsc {
    mixture: Gmm<AnyEmission>,
    transition_mixture: Gmm<AnyEmission>,
    kept: Vec<usize>,
    window: usize,
    min_run: usize,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    time_clusters: Vec<TimeSubclusters>,
}

/// The serialised form of [`KrishnanTsc`], before validation.
#[derive(Deserialize)]
struct KrishnanTscRaw {
    mixture: Gmm<AnyEmission>,
    transition_mixture: Gmm<AnyEmission>,
    kept: Vec<usize>,
    window: usize,
    min_run: usize,
    #[serde(default)]
    time_clusters: Vec<TimeSubclusters>,
}

impl TryFrom<KrishnanTscRaw> for KrishnanTsc {
    type Error = TscError;
    fn try_from(r: KrishnanTscRaw) -> Result<Self> {
        let tsc = KrishnanTsc {
            mixture: r.mixture,
            transition_mixture: r.transition_mixture,
            kept: r.kept,
            window: r.window,
            min_run: r.min_run,
            time_clusters: r.time_clusters,
        };
        tsc.check()?;
        Ok(tsc)
    }
}

/// How [`KrishnanSettings::fit`] chose its automatic counts.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct KrishnanReport {
    /// The frame mixture's count, when automatic.
    pub frame_components: Option<AutoCount>,
    /// The number of transition clusters, when automatic.
    pub transition_clusters: Option<AutoCount>,
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
    /// A builder starting from [`KrishnanSettings::default`].
    pub fn builder() -> KrishnanSettingsBuilder {
        KrishnanSettingsBuilder(KrishnanSettings::default())
    }

    /// A builder starting from these settings (to change some of them).
    pub fn to_builder(&self) -> KrishnanSettingsBuilder {
        KrishnanSettingsBuilder(self.clone())
    }

    /// Components of the frame mixture (`None`: automatic).
    pub fn components(&self) -> Option<usize> {
        self.components
    }
    /// Largest number an automatic count may give.
    pub fn max_components(&self) -> usize {
        self.max_components
    }
    /// How automatic counts are chosen.
    pub fn selector(&self) -> Selector {
        self.selector
    }
    /// Frames stacked into one feature vector.
    pub fn window(&self) -> usize {
        self.window
    }
    /// Label runs shorter than this are ignored as flips.
    pub fn min_run(&self) -> usize {
        self.min_run
    }
    /// Clusters of transition states (`None`: automatic).
    pub fn transition_clusters(&self) -> Option<usize> {
        self.transition_clusters
    }
    /// `ρ`, the fraction of demonstrations a kept transition cluster needs.
    pub fn prune_fraction(&self) -> f64 {
        self.prune_fraction
    }
    /// The time sub-clustering, if on.
    pub fn time_clusters(&self) -> Option<&TimeClustering> {
        self.time_clusters.as_ref()
    }
    /// Covariance regularisation added after every M-step.
    pub fn reg(&self) -> f64 {
        self.reg
    }
    /// Runs of each mixture fit.
    pub fn restarts(&self) -> usize {
        self.restarts
    }
    /// Seed of every mixture fit.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The emission of the mixtures' components.
    pub fn emission(&self) -> EmissionKind {
        self.emission
    }

    fn em(&self) -> Result<Em> {
        Ok(Em::builder()
            .regularisation(Regularisation::add_diagonal(self.reg)?)
            .restarts(self.restarts)
            .seed(self.seed)
            .build()?)
    }

    /// A mixture of `k` components, or of the number chosen automatically in
    /// `min_auto..=max_components` (and how it was chosen).
    fn mixture(
        &self,
        frames: Frames<'_>,
        k: Option<usize>,
        min_auto: usize,
    ) -> Result<(Gmm<AnyEmission>, Option<AutoCount>)> {
        let em = self.em()?;
        let auto = match k {
            Some(_) => None,
            None => Some(mixture_components_of(
                self.emission,
                self.selector,
                &em,
                frames,
                min_auto..=self.max_components,
            )?),
        };
        let k = auto.as_ref().map_or(k.unwrap_or(1), |a| a.count);
        let model = em
            .fit(&self.emission.template(k, frames.dim())?, frames)?
            .model;
        Ok((model, auto))
    }

    /// Fits the frame mixture and the transition clusters on demonstrations,
    /// and reports how automatic counts were chosen.
    pub fn fit(&self, data: &SequenceSet) -> Result<(KrishnanTsc, KrishnanReport)> {
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
        let (mixture, frame_components) =
            self.mixture(Frames::new(&all, d * self.window)?, self.components, 2)?;
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
            return Err(TscError::NoTransitions {
                min_run: self.min_run,
                cause: NoTransitionCause::NoLabelChange {
                    components: mixture.n_components(),
                },
            });
        }
        let (transition_mixture, transition_clusters) = self.mixture(
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
        Ok((
            KrishnanTsc {
                mixture,
                transition_mixture,
                kept,
                window: self.window,
                min_run: self.min_run,
                time_clusters,
            },
            KrishnanReport {
                frame_components,
                transition_clusters,
            },
        ))
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
            .restarts(self.restarts)
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

    /// Mixture over (windowed) frames.
    pub fn mixture(&self) -> &Gmm<AnyEmission> {
        &self.mixture
    }
    /// Mixture over transition states (un-windowed frames).
    pub fn transition_mixture(&self) -> &Gmm<AnyEmission> {
        &self.transition_mixture
    }
    /// Transition clusters kept after pruning (components of the transition mixture).
    pub fn kept(&self) -> &[usize] {
        &self.kept
    }
    /// Frames per window.
    pub fn window(&self) -> usize {
        self.window
    }
    /// Minimum label run.
    pub fn min_run(&self) -> usize {
        self.min_run
    }
    /// Time sub-clusters of every kept cluster (same order as [`KrishnanTsc::kept`]); empty when off.
    pub fn time_clusters(&self) -> &[TimeSubclusters] {
        &self.time_clusters
    }

    /// The same TSC with its two mixtures replaced (kept clusters, window,
    /// minimum run and the time sub-clusters, over unitless normalised time,
    /// unchanged), checked as a model read from a file is: the mapping of a
    /// model to scaled features ([`crate::reg_units::scale_model`]).
    pub(crate) fn with_mixtures(
        &self,
        mixture: Gmm<AnyEmission>,
        transition_mixture: Gmm<AnyEmission>,
    ) -> Result<Self> {
        let m = KrishnanTsc {
            mixture,
            transition_mixture,
            kept: self.kept.clone(),
            window: self.window,
            min_run: self.min_run,
            time_clusters: self.time_clusters.clone(),
        };
        m.check()?;
        Ok(m)
    }

    /// Checks that the parts agree: kept clusters exist, time sub-clusters (if any)
    /// match the kept clusters and are 1-D.
    fn check(&self) -> Result<()> {
        let bad = |reason: String| {
            Err(TscError::InvalidModel {
                model: "gmm-tsc model",
                reason,
            })
        };
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
            base_labels: None,
        })
    }
}
