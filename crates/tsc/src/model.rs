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
        }
    }

    /// Total number of states (components) of the model that predicts.
    pub fn n_states(&self) -> usize {
        match self {
            Model::Hmm(h) => h.n_states(),
            Model::Hsmm(h) => h.n_states(),
            Model::TscHmm { model, .. } => model.n_states(),
            Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => g.n_components(),
        }
    }

    /// Checks that the parts of a model built from its variants agree: the
    /// predicting mixture of `gmm-tsc` has the frame dimension of its TSC and
    /// more components than the kept clusters. (A [`TscHmm`] and a
    /// [`KrishnanTsc`] check their own parts when made or read.)
    pub fn validate(&self) -> Result<()> {
        match self {
            Model::Hmm(_) | Model::Hsmm(_) | Model::Gmm(_) | Model::TscHmm { .. } => Ok(()),
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
        }
    }
}
