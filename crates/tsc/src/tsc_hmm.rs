//! The seed paper's HMM and TSC-HMM, and the compositions of a base HMM `λ`
//! with a transition-state HMM `λ_T`.
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
use crate::error::{Result, TscError};
use crate::select::{check_range, Selector};
use phasekit_emission::{
    CovarianceType, Emission, Frames, Gaussian, Regularisation, SequenceSet, Shape,
};
use phasekit_gmm::{select_hmm_states_bic, select_hmm_states_gmeans, GMeans, Selection};
use phasekit_gmr::HmmRegression;
use phasekit_hmm::{BaumWelch, Convergence, Hmm, HmmFitReport, HmmInit, Update};
use serde::{Deserialize, Serialize};

/// Which dims of a joint frame are the human's (observed at test time) and the robot's (predicted).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Roles {
    /// The human's dims (inputs).
    pub human: Vec<usize>,
    /// The robot's dims (outputs).
    pub robot: Vec<usize>,
}

impl Roles {
    /// Checks that the roles are disjoint, non-empty and within `dim`.
    pub fn check(&self, dim: usize) -> Result<()> {
        phasekit_gmr::check_io(&self.human, &self.robot, dim)?;
        Ok(())
    }
}

/// Settings of one HMM fit, as in the paper-compatible protocol by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HmmSettings {
    /// Number of states.
    pub states: usize,
    /// `r` added to every covariance diagonal at initialisation and after every M-step
    /// (in the data's units squared: `1e-2` on data in metres is (10 cm)²).
    pub reg: f64,
    /// At most this many M-steps.
    pub max_iter: usize,
    /// Stop when the gain of the mean log-likelihood per sequence is below this.
    pub tol: f64,
    /// Runs from different initialisations (the first from k-bins, then k-means++).
    pub restarts: usize,
    /// Seed of the random initialisations.
    pub seed: u64,
    /// Covariance structure of the emissions.
    pub covariance: CovarianceType,
    /// Choose the number of states automatically (then `states` is not used).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub auto_states: Option<AutoStates>,
}

/// An automatic choice of the number of HMM states in `min..=max`: by BIC, the
/// count whose HMM, fitted by the same Baum-Welch settings, has the lowest
/// `BIC(S) = −2 log p(O | λ̂_S) + p_S log N` (`p_S` free parameters, `N` frames;
/// `phasekit_gmm::select_hmm_states_bic`); by G-means, the number of Gaussian
/// clusters G-means finds in the pooled frames (`phasekit_gmm::gmeans`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct AutoStates {
    /// Fewest states tried.
    pub min: usize,
    /// Most states tried.
    pub max: usize,
    /// How the count is chosen.
    #[serde(default)]
    pub selector: Selector,
}

impl AutoStates {
    /// BIC over `min..=max` states.
    pub fn bic(min: usize, max: usize) -> Self {
        AutoStates {
            min,
            max,
            selector: Selector::Bic,
        }
    }
}

impl HmmSettings {
    /// The paper-compatible setting: `states` full-covariance states, `reg = 1e-2`,
    /// 40 iterations, tolerance `1e-4` on the mean log-likelihood per sequence, one k-bins run.
    pub fn paper(states: usize) -> Self {
        HmmSettings {
            states,
            reg: 1e-2,
            max_iter: 40,
            tol: 1e-4,
            restarts: 1,
            seed: 0,
            covariance: CovarianceType::Full,
            auto_states: None,
        }
    }

    /// Checks the settings: at least one state (or a valid automatic range), finite
    /// non-negative `reg` and `tol`, at least one iteration and one run.
    pub fn validate(&self) -> Result<()> {
        let bad = |name, reason: String| Err(TscError::InvalidSetting { name, reason });
        match self.auto_states {
            None if self.states == 0 => {
                return bad("states", "at least one state is needed".into());
            }
            None => {}
            Some(a) => check_range("max-states", &(a.min..=a.max))?,
        }
        if !(self.reg.is_finite() && self.reg >= 0.0) {
            return bad(
                "reg",
                format!("must be a finite number ≥ 0, got {}", self.reg),
            );
        }
        if !(self.tol.is_finite() && self.tol >= 0.0) {
            return bad(
                "tol",
                format!("must be a finite number ≥ 0, got {}", self.tol),
            );
        }
        if self.max_iter == 0 || self.restarts == 0 {
            return bad(
                "max-iter/restarts",
                "at least one iteration and one run are needed".into(),
            );
        }
        Ok(())
    }

    /// The checked Baum-Welch settings.
    pub fn baum_welch(&self) -> Result<BaumWelch> {
        Ok(BaumWelch::builder()
            .max_iter(self.max_iter)
            .tol(self.tol)
            .convergence(Convergence::MeanPerSequence)
            .regularisation(Regularisation::add_diagonal(self.reg)?)
            .init(HmmInit::KBins { smoothing: 0.01 })
            .restarts(self.restarts)
            .seed(self.seed)
            .build()?)
    }

    /// Fits an HMM with these settings to `data`.
    pub fn fit(&self, data: &SequenceSet) -> Result<(Hmm<Gaussian>, HmmFitReport)> {
        let (hmm, report, _) = self.fit_selected(data)?;
        Ok((hmm, report))
    }

    /// Fits an HMM with these settings to `data`; with `auto_states`, first chooses
    /// the number of states and returns the scores of every candidate as well.
    pub fn fit_selected(
        &self,
        data: &SequenceSet,
    ) -> Result<(Hmm<Gaussian>, HmmFitReport, Option<Selection>)> {
        self.validate()?;
        let bw = self.baum_welch()?;
        let template = |k| {
            Gaussian::standard(
                self.covariance,
                Shape {
                    n_states: k,
                    dim: data.dim(),
                },
            )
        };
        let (states, selection) = match self.auto_states {
            None => (self.states, None),
            Some(a) => {
                // A demonstration shorter than the number of states cannot be k-binned:
                // candidates stop at the shortest demonstration's length.
                let shortest = data.iter().map(|s| s.len()).min().unwrap_or(0);
                let hi = a.max.min(shortest.max(1));
                let lo = a.min.min(hi);
                match a.selector {
                    Selector::Bic => {
                        let sel = select_hmm_states_bic(&bw, template, data, lo..=hi)?;
                        (sel.best, Some(sel))
                    }
                    // G-means on the pooled frames (deterministic: its splits start
                    // along the principal axis), clamped to the range.
                    Selector::GMeans => {
                        let g = select_hmm_states_gmeans(
                            &bw,
                            template,
                            data,
                            GMeans::default(),
                            lo..=hi,
                        )?;
                        return Ok((g.fitted.model, g.fitted.report, Some(g.selection)));
                    }
                }
            }
        };
        // Refitting the chosen count repeats the selection's fit exactly (same
        // initialisation and seed), so the model is the one that was scored.
        let fitted = bw.fit(&template(states)?, data)?;
        Ok((fitted.model, fitted.report, selection))
    }
}

/// How transition frames are found on the training demonstrations.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Detector {
    /// The paper: the human-only and the joint filtered argmax states disagree.
    Disagreement,
    /// The frames where the base model's human-only prediction of the robot is worst
    /// (this fraction of all training frames).
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

/// Settings of a TSC-HMM.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TscSettings {
    /// The base HMM `λ`.
    pub base: HmmSettings,
    /// States of `λ_T`.
    pub tsc_states: usize,
    /// Dilation `±w` of the flagged frames.
    pub window: usize,
    /// Runs shorter than this are dropped.
    pub min_run: usize,
    /// How transition frames are found.
    pub detector: Detector,
    /// How `λ` and `λ_T` predict together.
    pub composition: Composition,
}

impl TscSettings {
    /// Checks the settings: the base HMM's, at least one transition state, and a
    /// detector fraction in `(0, 1]`.
    pub fn validate(&self) -> Result<()> {
        self.base.validate()?;
        if self.tsc_states == 0 {
            return Err(TscError::InvalidSetting {
                name: "tsc-states",
                reason: "the transition HMM needs at least one state (tsc-states=0 or auto chooses the transition clusters of gmm-tsc only)".into(),
            });
        }
        if let Detector::WorstPrediction { fraction } = self.detector {
            if !(fraction > 0.0 && fraction <= 1.0) {
                return Err(TscError::InvalidSetting {
                    name: "fraction",
                    reason: format!("must lie in (0, 1], got {fraction}"),
                });
            }
        }
        Ok(())
    }

    /// The paper's method with 4 + 3 states, window `w`, and the given composition.
    pub fn paper(window: usize, composition: Composition) -> Self {
        TscSettings {
            base: HmmSettings::paper(4),
            tsc_states: 3,
            window,
            min_run: 2,
            detector: Detector::Disagreement,
            composition,
        }
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
    let detector = Disagreement::new(
        FilterLabeller::joint(hmm),
        FilterLabeller::marginal(hmm, &roles.human)?,
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
    let gmr = HmmRegression::new(hmm, &roles.human, &roles.robot)?;
    let o = roles.robot.len();
    data.iter()
        .map(|seq| {
            let sub = select(seq, &roles.human);
            let pred = gmr.predict(Frames::new(&sub, roles.human.len())?, false)?;
            Ok(seq
                .iter()
                .enumerate()
                .map(|(t, x)| {
                    // Missing robot values (NaN) are not scored: such a frame is
                    // never "badly predicted" for lack of a value to compare with.
                    roles
                        .robot
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

/// The runs of flagged frames as sequences.
pub fn transition_sequences(
    data: &SequenceSet,
    flags: &TransitionFlags,
    min_run: usize,
) -> Result<SequenceSet> {
    let d = data.dim();
    let mut seqs: Vec<&[f64]> = Vec::new();
    for (seq, f) in data.iter().zip(flags) {
        for r in runs(f, min_run) {
            seqs.push(&seq.as_slice()[r.start * d..r.end * d]);
        }
    }
    if seqs.is_empty() {
        return Err(TscError::NoTransitions { min_len: min_run });
    }
    Ok(SequenceSet::new(&seqs, d)?)
}

/// A fitted TSC-HMM: the base HMM, the transition HMM and their composition.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TscHmm {
    /// The base HMM `λ` (joint frames).
    pub base: Hmm<Gaussian>,
    /// The transition-state HMM `λ_T` (joint frames).
    pub transition: Hmm<Gaussian>,
    /// The union HMM, for the union compositions.
    pub union: Option<Hmm<Gaussian>>,
    /// How the two predict together.
    pub composition: Composition,
}

/// What fitting a TSC-HMM did.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
    pub selection: Option<Selection>,
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

impl TscHmm {
    /// Checks that the parts agree: `λ` and `λ_T` (and the union) have the same
    /// dimension; a union composition has its union HMM of `S + S_T` states, the gate none.
    pub fn validate(&self) -> Result<()> {
        let bad = |reason: String| {
            Err(TscError::InvalidSetting {
                name: "tsc-hmm model",
                reason,
            })
        };
        let d = self.base.dim();
        if self.transition.dim() != d {
            return bad(format!(
                "the transition HMM has dimension {}, the base HMM {d}",
                self.transition.dim()
            ));
        }
        let s = self.base.n_states() + self.transition.n_states();
        match (self.composition, &self.union) {
            (Composition::Union | Composition::UnionFrozen, None) => bad(format!(
                "the composition is {:?}, which predicts with the union HMM, but the model has no union HMM (`union: null`)",
                self.composition
            )),
            (Composition::Union | Composition::UnionFrozen, Some(u))
                if u.dim() != d || u.n_states() != s =>
            {
                bad(format!(
                    "the union HMM has {} states of dimension {}, not the {s} states of dimension {d} of λ and λ_T",
                    u.n_states(),
                    u.dim()
                ))
            }
            (Composition::Gated, Some(_)) => bad(
                "the composition is Gated, which predicts with λ and λ_T, but the model holds a union HMM".into(),
            ),
            _ => Ok(()),
        }
    }

    /// Algorithm 1 and the chosen composition, on joint training sequences.
    pub fn fit(
        data: &SequenceSet,
        roles: &Roles,
        settings: &TscSettings,
    ) -> Result<(Self, TscReport)> {
        roles.check(data.dim())?;
        settings.validate()?;
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
        let segments = transition_sequences(data, &flags, settings.min_run.max(1))?;
        let tsc = HmmSettings {
            states: settings.tsc_states,
            auto_states: None,
            ..settings.base.clone()
        };
        let (transition, transition_report) = tsc.fit(&segments)?;
        let (union, union_report) = match settings.composition {
            Composition::Gated => (None, None),
            Composition::Union | Composition::UnionFrozen => {
                let initial = union_of(&base, &transition, 0.01)?;
                let update = Update {
                    emission: settings.composition == Composition::Union,
                    ..Update::default()
                };
                let bw = BaumWelch::builder()
                    .max_iter(settings.base.max_iter)
                    .tol(settings.base.tol)
                    .convergence(Convergence::MeanPerSequence)
                    .regularisation(Regularisation::add_diagonal(settings.base.reg)?)
                    .update(update)
                    .build()?;
                let fitted = bw.fit_from(initial, data)?;
                (Some(fitted.model), Some(fitted.report))
            }
        };
        let n_segments = segments.len();
        Ok((
            TscHmm {
                base,
                transition,
                union,
                composition: settings.composition,
            },
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
