//! A fitted model of any method: its predictor and its segmentation of a
//! demonstration.

use crate::detect::{dilate, label_changes, runs, Labeller, ViterbiLabeller};
use crate::emission_choice::AnyEmission;
use crate::error::{Result, TscError};
use crate::krishnan::KrishnanTsc;
use crate::predictor::Predictor;
use crate::roles::Roles;
use crate::segmentation::Segmentation;
use crate::tsc_hmm::{disagreement_flags, TscHmm};
use phasekit_emission::{Frames, SequenceSet};
use phasekit_gmm::Gmm;
use phasekit_gmr::{GmmRegression, HmmRegression};
use phasekit_hmm::Hmm;
use phasekit_hsmm::Hsmm;
use serde::{Deserialize, Serialize};

/// A fitted model of any method (serialisable; a file whose parts disagree is
/// refused on deserialisation, see [`Model::validate`]).
///
/// Not `#[non_exhaustive]` on purpose: a new kind of model must be handled by
/// every `match` of the workspace (the command's plots and reports), so that
/// adding one is a compile error wherever it is not yet supported.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "ModelRaw", into = "ModelRaw")]
pub enum Model {
    /// An HMM on joint frames (of any emission the command can choose).
    Hmm(Hmm<AnyEmission>),
    /// A left-right HSMM on joint frames (any emission, any duration family).
    Hsmm(Hsmm<AnyEmission>),
    /// A TSC-HMM.
    TscHmm {
        /// The fitted model.
        model: TscHmm,
        /// The dilation used for its transition frames.
        window: usize,
    },
    /// A GMM on joint frames.
    Gmm(Gmm<AnyEmission>),
    /// Krishnan TSC and the joined mixture that predicts.
    GmmTsc {
        /// The TSC.
        tsc: KrishnanTsc,
        /// The GMM plus kept transition clusters.
        mixture: Gmm<AnyEmission>,
    },
    /// The weighted mean of several models' predictions (`auto:ensemble=K`):
    /// see [`EnsembleMember`] and [`Predictor`]. Its segmentation, evidence
    /// and states are its first member's (the best ranked).
    Ensemble(Vec<EnsembleMember>),
}

/// One model of an ensemble: its label (the method that made it), its weight
/// (`w_i > 0`, the weights sum to 1) and the fitted model (not itself an
/// ensemble).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EnsembleMember {
    /// The method specification that made it (`hmm:states=7,reg-rel=0.03`).
    pub label: String,
    /// Its weight in the mean.
    pub weight: f64,
    /// The fitted model.
    pub model: Model,
}

/// The serialised form of [`Model`], before the parts are checked against each other.
#[derive(Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
enum ModelRaw {
    Hmm(Hmm<AnyEmission>),
    Hsmm(Hsmm<AnyEmission>),
    TscHmm {
        model: TscHmm,
        window: usize,
    },
    Gmm(Gmm<AnyEmission>),
    GmmTsc {
        tsc: KrishnanTsc,
        mixture: Gmm<AnyEmission>,
    },
    Ensemble {
        members: Vec<EnsembleMember>,
    },
}

impl TryFrom<ModelRaw> for Model {
    type Error = TscError;
    fn try_from(r: ModelRaw) -> Result<Self> {
        let m = match r {
            ModelRaw::Hmm(h) => Model::Hmm(h),
            ModelRaw::Hsmm(h) => Model::Hsmm(h),
            ModelRaw::TscHmm { model, window } => Model::TscHmm { model, window },
            ModelRaw::Gmm(g) => Model::Gmm(g),
            ModelRaw::GmmTsc { tsc, mixture } => Model::GmmTsc { tsc, mixture },
            ModelRaw::Ensemble { members } => Model::Ensemble(members),
        };
        m.validate()?;
        Ok(m)
    }
}

impl From<Model> for ModelRaw {
    fn from(m: Model) -> Self {
        match m {
            Model::Hmm(h) => ModelRaw::Hmm(h),
            Model::Hsmm(h) => ModelRaw::Hsmm(h),
            Model::TscHmm { model, window } => ModelRaw::TscHmm { model, window },
            Model::Gmm(g) => ModelRaw::Gmm(g),
            Model::GmmTsc { tsc, mixture } => ModelRaw::GmmTsc { tsc, mixture },
            Model::Ensemble(members) => ModelRaw::Ensemble { members },
        }
    }
}

impl Model {
    /// Joint frame dimension.
    pub fn dim(&self) -> usize {
        match self {
            Model::Hmm(h) => h.dim(),
            Model::Hsmm(h) => h.dim(),
            Model::TscHmm { model, .. } => model.base().dim(),
            Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => g.dim(),
            Model::Ensemble(members) => members.first().map_or(0, |m| m.model.dim()),
        }
    }

    /// Total number of states (components) of the model that predicts (an
    /// ensemble: summed over its members).
    pub fn n_states(&self) -> usize {
        match self {
            Model::Hmm(h) => h.n_states(),
            Model::Hsmm(h) => h.n_states(),
            Model::TscHmm { model, .. } => model.n_states(),
            Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => g.n_components(),
            Model::Ensemble(members) => members.iter().map(|m| m.model.n_states()).sum(),
        }
    }

    /// The model whose states, segmentation and evidence stand for this one:
    /// itself, or an ensemble's first member (the best ranked; an ensemble
    /// without members, which [`Model::validate`] refuses, stands for itself).
    pub fn representative(&self) -> &Model {
        match self {
            Model::Ensemble(members) if !members.is_empty() => &members[0].model,
            m => m,
        }
    }

    /// An ensemble of `members` (label, model) with weights `weights`,
    /// checked ([`Model::validate`]).
    pub fn ensemble(members: Vec<(String, Model)>, weights: &[f64]) -> Result<Model> {
        if members.len() != weights.len() {
            return Err(TscError::InvalidModel {
                model: "ensemble",
                reason: format!("{} members and {} weights", members.len(), weights.len()),
            });
        }
        let m = Model::Ensemble(
            members
                .into_iter()
                .zip(weights)
                .map(|((label, model), &weight)| EnsembleMember {
                    label,
                    weight,
                    model,
                })
                .collect(),
        );
        m.validate()?;
        Ok(m)
    }

    /// Checks that the parts of a model built from its variants agree: the
    /// predicting mixture of `gmm-tsc` has the frame dimension of its TSC and
    /// more components than the kept clusters. (A [`TscHmm`] and a
    /// [`KrishnanTsc`] check their own parts when made or read.)
    ///
    /// An ensemble has at least one member, none of them an ensemble, all of
    /// one frame dimension, with finite positive weights summing to 1 (to
    /// `1e-9`).
    pub fn validate(&self) -> Result<()> {
        match self {
            Model::Hmm(_) | Model::Hsmm(_) | Model::Gmm(_) | Model::TscHmm { .. } => Ok(()),
            Model::Ensemble(members) => {
                let bad = |reason: String| {
                    Err(TscError::InvalidModel {
                        model: "ensemble",
                        reason,
                    })
                };
                let Some(first) = members.first() else {
                    return bad("it has no member".into());
                };
                let total: f64 = members.iter().map(|m| m.weight).sum();
                for (i, m) in members.iter().enumerate() {
                    if matches!(m.model, Model::Ensemble(_)) {
                        return bad(format!("member {i} ({}) is itself an ensemble", m.label));
                    }
                    if m.model.dim() != first.model.dim() {
                        return bad(format!(
                            "member {i} ({}) has frames of dimension {}, member 0 of {}",
                            m.label,
                            m.model.dim(),
                            first.model.dim()
                        ));
                    }
                    if !(m.weight.is_finite() && m.weight > 0.0) {
                        return bad(format!(
                            "member {i} ({}) has weight {} (must be finite and > 0)",
                            m.label, m.weight
                        ));
                    }
                    m.model.validate()?;
                }
                if (total - 1.0).abs() > 1e-9 {
                    return bad(format!("the weights sum to {total}, not 1"));
                }
                Ok(())
            }
            Model::GmmTsc { tsc, mixture } => {
                if mixture.dim() != tsc.transition_mixture().dim()
                    || mixture.n_components() <= tsc.kept().len()
                {
                    return Err(TscError::InvalidModel {
                        model: "gmm-tsc model",
                        reason: format!(
                            "the predicting mixture has {} components of dimension {}: it needs more than the {} kept clusters, of dimension {}",
                            mixture.n_components(),
                            mixture.dim(),
                            tsc.kept().len(),
                            tsc.transition_mixture().dim()
                        ),
                    });
                }
                Ok(())
            }
        }
    }

    /// The predictor of the robot's dims from the human's.
    pub fn predictor(&self, roles: &Roles) -> Result<Predictor> {
        roles.check(self.dim())?;
        self.validate()?;
        let hmm = |h: &Hmm<AnyEmission>| HmmRegression::new(h, roles.human(), roles.robot());
        Ok(match self {
            Model::Hmm(h) => Predictor::hmm(hmm(h)?),
            Model::Hsmm(h) => Predictor::hsmm(phasekit_gmr::HsmmRegression::new(
                h,
                roles.human(),
                roles.robot(),
            )?),
            Model::TscHmm { model, .. } => match model.union() {
                Some(u) => Predictor::hmm(hmm(u)?),
                None => Predictor::gated(hmm(model.base())?, hmm(model.transition())?),
            },
            Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => {
                Predictor::gmm(GmmRegression::new(g, roles.human(), roles.robot())?)
            }
            Model::Ensemble(members) => Predictor::ensemble(
                members
                    .iter()
                    .map(|m| Ok((m.weight, m.model.predictor(roles)?)))
                    .collect::<Result<Vec<_>>>()?,
            )?,
        })
    }

    /// Segments a joint demonstration: a state per frame, the transition
    /// frames and their clusters.
    ///
    /// * An HMM labels by Viterbi on joint frames and flags the paper's
    ///   transition states (human-only and joint filtered argmax disagree).
    /// * A TSC-HMM labels by the Viterbi path of the model that predicts: the
    ///   union HMM's `S + S_T` states (`S..S + S_T` are the transition states);
    ///   the likelihood gate, which predicts with `λ` or `λ_T` frame by frame,
    ///   by `λ`'s. [`Segmentation::base_labels`] holds `λ`'s Viterbi states in
    ///   both cases. Transitions are `λ`'s disagreement frames dilated by the
    ///   model's window, and each run's clusters are `λ_T`'s Viterbi states.
    /// * `gmm-tsc` uses Krishnan's label changes and kept clusters; `gmm`
    ///   flags label changes.
    /// * An ensemble segments by its first member (the best ranked).
    pub fn segment(&self, seq: Frames<'_>, roles: &Roles) -> Result<Segmentation> {
        roles.check(seq.dim())?;
        let one = SequenceSet::single(seq.as_slice(), seq.dim())?;
        let flagged = |flags: &[bool]| {
            flags
                .iter()
                .enumerate()
                .filter_map(|(t, f)| f.then_some(t))
                .collect::<Vec<_>>()
        };
        match self {
            Model::Hmm(h) => {
                let labels = ViterbiLabeller(h).label(seq)?;
                let flags = &disagreement_flags(h, roles, &one)?[0];
                let transitions = flagged(flags);
                let clusters = vec![None; transitions.len()];
                Ok(Segmentation {
                    labels,
                    transitions,
                    clusters,
                    base_labels: None,
                })
            }
            Model::Hsmm(h) => {
                // The most probable segmentation; its segment boundaries are the transitions.
                let path = h.viterbi(seq)?;
                let transitions: Vec<usize> = path
                    .segments
                    .iter()
                    .map(|s| s.start)
                    .filter(|&t| t > 0)
                    .collect();
                let labels = path.states;
                let clusters = vec![None; transitions.len()];
                Ok(Segmentation {
                    labels,
                    transitions,
                    clusters,
                    base_labels: None,
                })
            }
            Model::TscHmm { model, window } => {
                let base_labels = ViterbiLabeller(model.base()).label(seq)?;
                let labels = match model.union() {
                    Some(u) => ViterbiLabeller(u).label(seq)?,
                    None => base_labels.clone(),
                };
                let flags = dilate(&disagreement_flags(model.base(), roles, &one)?[0], *window);
                let mut transitions = Vec::new();
                let mut clusters = Vec::new();
                for r in runs(&flags, 1) {
                    let sub = seq.slice(r.clone());
                    let states = model.transition().viterbi(sub)?.states;
                    transitions.extend(r.clone());
                    clusters.extend(states.into_iter().map(Some));
                }
                Ok(Segmentation {
                    labels,
                    transitions,
                    clusters,
                    base_labels: Some(base_labels),
                })
            }
            Model::Gmm(g) => {
                let labels = g.predict(seq)?;
                let transitions = flagged(&label_changes(&labels, 2));
                let clusters = vec![None; transitions.len()];
                Ok(Segmentation {
                    labels,
                    transitions,
                    clusters,
                    base_labels: None,
                })
            }
            Model::GmmTsc { tsc, .. } => tsc.segment(seq),
            Model::Ensemble(members) => match members.first() {
                Some(m) => m.model.segment(seq, roles),
                None => Err(TscError::InvalidModel {
                    model: "ensemble",
                    reason: "it has no member".into(),
                }),
            },
        }
    }
}
