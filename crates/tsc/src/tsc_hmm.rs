//! The seed paper's TSC-HMM, and the compositions of a base HMM `λ` with a
//! transition-state HMM `λ_T`.
//!
//! Algorithm 1 of Hahne et al. (HRI'24): train `λ` on joint human+robot frames;
//! on every training demonstration flag the frames where the state believed from
//! the human alone, `argmax_i h_i(o¹_{1:t})`, differs from the state believed from
//! both, `argmax_i h_i(o¹²_{1:t})`; dilate by ±w; every run of flagged frames
//! (≥ 2 frames) is one training sequence of `λ_T`, initialised by temporal
//! k-bins and trained by Baum-Welch like `λ`.
//!
//! The paper does not say how `λ` and `λ_T` are combined to predict; the
//! [`Composition`]s below are the candidates measured in the ablation.

use crate::detect::{dilate, runs, select, worst_fraction, Disagreement, FilterLabeller};
use crate::error::{NoTransitionCause, Result, TscError};
use crate::hmm_settings::{AutoStatesReport, HmmSettings};
use crate::roles::Roles;
use phasekit_emission::{Emission, Frames, Gaussian, Regularisation, SequenceSet};
use phasekit_gmr::HmmRegression;
use phasekit_hmm::{BaumWelch, Convergence, Hmm, HmmFitReport, Update};
use serde::{Deserialize, Serialize};
use std::fmt;

/// How transition frames are found on the training demonstrations.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Detector {
    /// The paper: the human-only and the joint filtered argmax states disagree.
    Disagreement,
    /// The frames where the base model's human-only prediction of the robot is worst
    /// (this fraction of all training frames, in `(0, 1]`).
    WorstPrediction {
        /// Fraction of frames flagged, in (0, 1].
        fraction: f64,
    },
}

/// How `λ` and `λ_T` are combined to predict.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Composition {
    /// One HMM whose states are `λ`'s and `λ_T`'s; start, transitions and emissions
    /// re-estimated on all training data from that warm start.
    Union,
    /// As `Union`, with the emissions frozen (only start and transitions re-estimated).
    UnionFrozen,
    /// `λ`'s prediction, replaced by `λ_T`'s at frames where the human-marginal
    /// predictive likelihood `p(o¹_t | o¹_{1:t−1})` under `λ_T` exceeds `λ`'s.
    Gated,
}

impl fmt::Display for Composition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Composition::Union => "union",
            Composition::UnionFrozen => "union with frozen emissions",
            Composition::Gated => "likelihood gate",
        })
    }
}

/// Settings of a TSC-HMM; [`TscSettings::paper`] is the paper's method.
///
/// Validated once, by [`TscSettingsBuilder::build`] (and on deserialisation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "TscSettingsRaw")]
pub struct TscSettings {
    base: HmmSettings,
    tsc_states: usize,
    window: usize,
    min_run: usize,
    detector: Detector,
    composition: Composition,
}

/// The serialised form of [`TscSettings`], before validation.
#[derive(Deserialize)]
struct TscSettingsRaw {
    base: HmmSettings,
    tsc_states: usize,
    window: usize,
    min_run: usize,
    detector: Detector,
    composition: Composition,
}

impl TryFrom<TscSettingsRaw> for TscSettings {
    type Error = TscError;
    fn try_from(r: TscSettingsRaw) -> Result<Self> {
        TscSettingsBuilder(TscSettings {
            base: r.base,
            tsc_states: r.tsc_states,
            window: r.window,
            min_run: r.min_run,
            detector: r.detector,
            composition: r.composition,
        })
        .build()
    }
}

impl Default for TscSettings {
    /// The paper's method: `λ` with 4 states ([`HmmSettings::default`]), `λ_T`
    /// with 3, window ±2, runs of at least 2 frames, the disagreement detector,
    /// the union composition.
    fn default() -> Self {
        TscSettings {
            base: HmmSettings::default(),
            tsc_states: 3,
            window: 2,
            min_run: 2,
            detector: Detector::Disagreement,
            composition: Composition::Union,
        }
    }
}

/// Builder of [`TscSettings`]; [`TscSettingsBuilder::build`] validates once.
#[derive(Debug, Clone)]
pub struct TscSettingsBuilder(TscSettings);

impl TscSettingsBuilder {
    /// The base HMM `λ` (also the settings of `λ_T` and the union, but for the states).
    pub fn base(mut self, base: HmmSettings) -> Self {
        self.0.base = base;
        self
    }
    /// `n ≥ 1` states of `λ_T`.
    pub fn tsc_states(mut self, n: usize) -> Self {
        self.0.tsc_states = n;
        self
    }
    /// Dilation `±w` of the flagged frames (0: none).
    pub fn window(mut self, w: usize) -> Self {
        self.0.window = w;
        self
    }
    /// Runs of flagged frames shorter than `n ≥ 1` are dropped.
    pub fn min_run(mut self, n: usize) -> Self {
        self.0.min_run = n;
        self
    }
    /// How transition frames are found.
    pub fn detector(mut self, d: Detector) -> Self {
        self.0.detector = d;
        self
    }
    /// How `λ` and `λ_T` predict together.
    pub fn composition(mut self, c: Composition) -> Self {
        self.0.composition = c;
        self
    }
    /// Validates the settings: at least one transition state, runs of at least
    /// one frame, and a detector fraction in `(0, 1]` (the base settings were
    /// validated when built).
    pub fn build(self) -> Result<TscSettings> {
        let s = self.0;
        if s.tsc_states == 0 {
            return Err(TscError::InvalidSetting {
                name: "tsc_states",
                reason: "the transition HMM needs at least one state (0, i.e. automatic, chooses the transition clusters of gmm-tsc only)".into(),
            });
        }
        if s.min_run == 0 {
            return Err(TscError::InvalidSetting {
                name: "min_run",
                reason: "a transition segment has at least one frame".into(),
            });
        }
        if let Detector::WorstPrediction { fraction } = s.detector {
            if !(fraction > 0.0 && fraction <= 1.0) {
                return Err(TscError::InvalidSetting {
                    name: "fraction",
                    reason: format!("must lie in (0, 1], got {fraction}"),
                });
            }
        }
        Ok(s)
    }
}

impl TscSettings {
    /// A builder starting from [`TscSettings::default`] (the paper's method).
    pub fn builder() -> TscSettingsBuilder {
        TscSettingsBuilder(TscSettings::default())
    }

    /// A builder starting from these settings (to change some of them).
    pub fn to_builder(&self) -> TscSettingsBuilder {
        TscSettingsBuilder(self.clone())
    }

    /// The paper's method with 4 + 3 states, window `±window`, and the given composition.
    pub fn paper(window: usize, composition: Composition) -> Self {
        TscSettings {
            window,
            composition,
            ..TscSettings::default()
        }
    }

    /// The base HMM `λ`'s settings.
    pub fn base(&self) -> &HmmSettings {
        &self.base
    }
    /// States of `λ_T`.
    pub fn tsc_states(&self) -> usize {
        self.tsc_states
    }
    /// Dilation `±w` of the flagged frames.
    pub fn window(&self) -> usize {
        self.window
    }
    /// Shortest run of flagged frames kept as a transition segment.
    pub fn min_run(&self) -> usize {
        self.min_run
    }
    /// How transition frames are found.
    pub fn detector(&self) -> Detector {
        self.detector
    }
    /// How `λ` and `λ_T` predict together.
    pub fn composition(&self) -> Composition {
        self.composition
    }
}

/// Per training demonstration: the flagged transition frames.
pub type TransitionFlags = Vec<Vec<bool>>;

/// Flags where the human-only and joint filtered argmax states of `hmm` disagree:
/// `f_t = [argmax_i h_i(o¹²_{1:t}) ≠ argmax_i h_i(o¹_{1:t})]`, the paper's transition states.
///
/// A [`Disagreement`] of two [`FilterLabeller`]s (joint, and human marginal).
pub fn disagreement_flags(
    hmm: &Hmm<Gaussian>,
    roles: &Roles,
    data: &SequenceSet,
) -> Result<TransitionFlags> {
    roles.check(data.dim())?;
    let detector = Disagreement::new(
        FilterLabeller::joint(hmm),
        FilterLabeller::marginal(hmm, roles.human())?,
    );
    data.iter().map(|seq| detector.flags(seq)).collect()
}

/// Squared prediction error of the robot dims by HMM-GMR from the human dims,
/// per frame, summed over the robot values that are observed.
pub fn prediction_errors(
    hmm: &Hmm<Gaussian>,
    roles: &Roles,
    data: &SequenceSet,
) -> Result<Vec<Vec<f64>>> {
    roles.check(data.dim())?;
    let gmr = HmmRegression::new(hmm, roles.human(), roles.robot())?;
    let o = roles.robot().len();
    data.iter()
        .map(|seq| {
            let sub = select(seq, roles.human());
            let pred = gmr.predict(Frames::new(&sub, roles.human().len())?, false)?;
            Ok(seq
                .iter()
                .enumerate()
                .map(|(t, x)| {
                    // Missing robot values (NaN) are not scored: such a frame is
                    // never "badly predicted" for lack of a value to compare with.
                    roles
                        .robot()
                        .iter()
                        .enumerate()
                        .filter(|(_, &r)| !x[r].is_nan())
                        .map(|(j, &r)| (pred.mean[t * o + j] - x[r]).powi(2))
                        .sum()
                })
                .collect())
        })
        .collect()
}

/// The runs of at least `min_run` flagged frames as sequences.
///
/// Errors when `flags` does not have one flag per frame of every sequence of
/// `data`, and ([`TscError::NoTransitions`], saying whether anything was
/// flagged) when there is no such run.
pub fn transition_sequences(
    data: &SequenceSet,
    flags: &TransitionFlags,
    min_run: usize,
) -> Result<SequenceSet> {
    if flags.len() != data.len() || data.lengths().zip(flags).any(|(len, f)| f.len() != len) {
        let list = |v: Vec<usize>| {
            v.iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        };
        return Err(TscError::InvalidSetting {
            name: "flags",
            reason: format!(
                "one flag per frame of every sequence is needed: {} sequences of {} frames, flags for {} sequences of {}",
                data.len(),
                list(data.lengths().collect()),
                flags.len(),
                list(flags.iter().map(Vec::len).collect())
            ),
        });
    }
    let d = data.dim();
    let mut seqs: Vec<&[f64]> = Vec::new();
    for (seq, f) in data.iter().zip(flags) {
        for r in runs(f, min_run) {
            seqs.push(&seq.as_slice()[r.start * d..r.end * d]);
        }
    }
    if seqs.is_empty() {
        let flagged = flags.iter().flatten().filter(|f| **f).count();
        let longest = flags
            .iter()
            .flat_map(|f| runs(f, 1))
            .map(|r| r.len())
            .max()
            .unwrap_or(0);
        return Err(TscError::NoTransitions {
            min_run,
            cause: if flagged == 0 {
                NoTransitionCause::NothingFlagged { swamped: None }
            } else {
                NoTransitionCause::RunsTooShort { flagged, longest }
            },
        });
    }
    Ok(SequenceSet::new(&seqs, d)?)
}

/// A fitted TSC-HMM: the base HMM `λ`, the transition HMM `λ_T` and their
/// composition (with the union HMM for the union compositions).
///
/// Its parts agree by construction ([`TscHmm::new`], and on deserialisation).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "TscHmmRaw")]
pub struct TscHmm {
    base: Hmm<Gaussian>,
    transition: Hmm<Gaussian>,
    union: Option<Hmm<Gaussian>>,
    composition: Composition,
}

/// The serialised form of [`TscHmm`], before validation.
#[derive(Deserialize)]
struct TscHmmRaw {
    base: Hmm<Gaussian>,
    transition: Hmm<Gaussian>,
    union: Option<Hmm<Gaussian>>,
    composition: Composition,
}

impl TryFrom<TscHmmRaw> for TscHmm {
    type Error = TscError;
    fn try_from(r: TscHmmRaw) -> Result<Self> {
        TscHmm::new(r.base, r.transition, r.union, r.composition)
    }
}

/// What fitting a TSC-HMM did.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct TscReport {
    /// Fit of `λ`.
    pub base: HmmFitReport,
    /// Fit of `λ_T`.
    pub transition: HmmFitReport,
    /// Fit of the union HMM, if any.
    pub union: Option<HmmFitReport>,
    /// Flagged frames of every training demonstration.
    pub flags: TransitionFlags,
    /// Number of transition segments `λ_T` was trained on.
    pub segments: usize,
    /// The automatic choice of `λ`'s number of states, if any.
    pub selection: Option<AutoStatesReport>,
}

/// The union of two HMMs' states: emissions side by side, transitions block-diagonal
/// with `ε` spread uniformly to the other block, start `(1 − ε) π_λ ⊕ ε/S_T`.
pub fn union_of(a: &Hmm<Gaussian>, b: &Hmm<Gaussian>, epsilon: f64) -> Result<Hmm<Gaussian>> {
    let (sa, sb, d) = (a.n_states(), b.n_states(), a.dim());
    let (ea, eb) = (a.emission(), b.emission());
    let mut means = ea.means().to_vec();
    means.extend_from_slice(eb.means());
    let mut covs = Vec::with_capacity((sa + sb) * d * d);
    for g in [ea, eb] {
        for k in 0..g.n_states() {
            covs.extend(g.covariance(k).transpose().iter().copied());
        }
    }
    let emission = Gaussian::full(d, means, covs)?;
    let s = sa + sb;
    let mut trans = vec![0.0; s * s];
    for i in 0..s {
        let (own, own_s, off, other_s) = if i < sa {
            (a, sa, 0, sb)
        } else {
            (b, sb, sa, sa)
        };
        let li = i - off;
        for j in 0..own_s {
            trans[i * s + off + j] = (1.0 - epsilon) * own.transition()[li * own_s + j];
        }
        let other_off = if i < sa { sa } else { 0 };
        for j in 0..other_s {
            trans[i * s + other_off + j] = epsilon / other_s as f64;
        }
    }
    let mut start: Vec<f64> = a.start().iter().map(|p| (1.0 - epsilon) * p).collect();
    start.extend(std::iter::repeat_n(epsilon / sb as f64, sb));
    Ok(Hmm::new(start, trans, emission)?)
}

/// The largest variance of any feature over the observed values of `data`
/// (`0` if nothing is observed).
fn largest_variance(data: &SequenceSet) -> f64 {
    let d = data.dim();
    let (mut n, mut sum, mut sq) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    for x in data.all_frames().iter() {
        for (k, v) in x.iter().enumerate().filter(|(_, v)| !v.is_nan()) {
            n[k] += 1.0;
            sum[k] += v;
            sq[k] += v * v;
        }
    }
    (0..d)
        .filter(|&k| n[k] > 0.0)
        .map(|k| (sq[k] / n[k] - (sum[k] / n[k]).powi(2)).max(0.0))
        .fold(0.0, f64::max)
}

impl TscHmm {
    /// A TSC-HMM from its parts: `λ` and `λ_T` (and the union) have the same
    /// dimension; a union composition has its union HMM of `S + S_T` states,
    /// the gate none.
    pub fn new(
        base: Hmm<Gaussian>,
        transition: Hmm<Gaussian>,
        union: Option<Hmm<Gaussian>>,
        composition: Composition,
    ) -> Result<TscHmm> {
        let bad = |reason: String| {
            Err(TscError::InvalidModel {
                model: "tsc-hmm model",
                reason,
            })
        };
        let d = base.dim();
        if transition.dim() != d {
            return bad(format!(
                "the transition HMM has dimension {}, the base HMM {d}",
                transition.dim()
            ));
        }
        let s = base.n_states() + transition.n_states();
        match (composition, &union) {
            (Composition::Union | Composition::UnionFrozen, None) => {
                return bad(format!(
                    "the composition is the {composition}, which predicts with the union HMM, but the model has no union HMM (`union: null`)"
                ))
            }
            (Composition::Union | Composition::UnionFrozen, Some(u))
                if u.dim() != d || u.n_states() != s =>
            {
                return bad(format!(
                    "the union HMM has {} states of dimension {}, not the {s} states of dimension {d} of λ and λ_T",
                    u.n_states(),
                    u.dim()
                ))
            }
            (Composition::Gated, Some(_)) => {
                return bad(
                    "the composition is the likelihood gate, which predicts with λ and λ_T, but the model holds a union HMM".into(),
                )
            }
            _ => {}
        }
        Ok(TscHmm {
            base,
            transition,
            union,
            composition,
        })
    }

    /// The base HMM `λ` (joint frames).
    pub fn base(&self) -> &Hmm<Gaussian> {
        &self.base
    }
    /// The transition-state HMM `λ_T` (joint frames).
    pub fn transition(&self) -> &Hmm<Gaussian> {
        &self.transition
    }
    /// The union HMM, for the union compositions (states `0..S` are `λ`'s,
    /// `S..S + S_T` `λ_T`'s).
    pub fn union(&self) -> Option<&Hmm<Gaussian>> {
        self.union.as_ref()
    }
    /// How the two predict together.
    pub fn composition(&self) -> Composition {
        self.composition
    }
    /// Number of states of the model that predicts: the union's `S + S_T`, or
    /// `S + S_T` of the gate's two models.
    pub fn n_states(&self) -> usize {
        self.base.n_states() + self.transition.n_states()
    }

    /// Algorithm 1 and the chosen composition, on joint training sequences.
    pub fn fit(
        data: &SequenceSet,
        roles: &Roles,
        settings: &TscSettings,
    ) -> Result<(Self, TscReport)> {
        roles.check(data.dim())?;
        if let Some((k, shortest)) = data.iter().map(|s| s.len()).enumerate().min_by_key(|x| x.1) {
            if settings.window >= shortest {
                return Err(TscError::InvalidSetting {
                    name: "window",
                    reason: format!(
                        "a dilation of ±{} frames is not shorter than demonstration {k} ({shortest} frames): \
                         a single transition frame would flag all of it",
                        settings.window
                    ),
                });
            }
        }
        let (base, base_report, selection) = settings.base.fit_selected(data)?;
        let flags = match settings.detector {
            Detector::Disagreement => disagreement_flags(&base, roles, data)?,
            Detector::WorstPrediction { fraction } => {
                worst_fraction(&prediction_errors(&base, roles, data)?, fraction)
            }
        };
        let flags: TransitionFlags = flags.iter().map(|f| dilate(f, settings.window)).collect();
        let segments =
            transition_sequences(data, &flags, settings.min_run).map_err(|e| match e {
                // Say why nothing was flagged when the regularisation hides the states.
                TscError::NoTransitions {
                    min_run,
                    cause: NoTransitionCause::NothingFlagged { swamped: None },
                } => {
                    let (reg, var) = (settings.base.reg(), largest_variance(data));
                    TscError::NoTransitions {
                        min_run,
                        cause: NoTransitionCause::NothingFlagged {
                            swamped: (var > 0.0 && reg > var).then_some((reg, var)),
                        },
                    }
                }
                e => e,
            })?;
        let tsc = settings
            .base
            .to_builder()
            .states(settings.tsc_states)
            .build()?;
        let (transition, transition_report) =
            tsc.fit(&segments).map_err(|e| TscError::TransitionModel {
                tsc_states: settings.tsc_states,
                window: settings.window,
                segments: segments.len(),
                frames: segments.total_frames(),
                shortest: segments.lengths().min().unwrap_or(0),
                source: Box::new(e),
            })?;
        let (union, union_report) = match settings.composition {
            Composition::Gated => (None, None),
            Composition::Union | Composition::UnionFrozen => {
                let initial = union_of(&base, &transition, 0.01)?;
                let update = Update {
                    emission: settings.composition == Composition::Union,
                    ..Update::default()
                };
                let bw = BaumWelch::builder()
                    .max_iter(settings.base.max_iter())
                    .tol(settings.base.tol())
                    .convergence(Convergence::MeanPerSequence)
                    .regularisation(Regularisation::add_diagonal(settings.base.reg())?)
                    .update(update)
                    .build()?;
                let fitted = bw.fit_from(initial, data)?;
                (Some(fitted.model), Some(fitted.report))
            }
        };
        let n_segments = segments.len();
        Ok((
            TscHmm::new(base, transition, union, settings.composition)?,
            TscReport {
                base: base_report,
                transition: transition_report,
                union: union_report,
                flags,
                segments: n_segments,
                selection,
            },
        ))
    }
}
