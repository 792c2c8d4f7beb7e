//! The parts recognition takes from `phasekit_tsc`: every method's fitted
//! model, its online predictor, and the HMM that predictor filters with.
//!
//! This is the only module that looks inside [`Model`] and [`OnlinePredictor`]
//! (their variants), so that a change of the presets' API touches one file.
//!
//! * the **action HMM** of a model ([`action_hmm`]): the joint HMM whose human
//!   marginal the model's prediction filters with: the HMM itself (`hmm`), the
//!   union HMM of a union TSC-HMM, the base `λ` of the gated TSC-HMM (its `λ_T`
//!   only models transition segments, not whole demonstrations), and for the
//!   static mixtures (`gmm`, `gmm-tsc`) the mixture as an HMM whose every row of
//!   `A` is the mixture's weights (frames independent: the same likelihood and
//!   the same responsibilities as the mixture);
//! * an **action track** ([`ActionTrack`]): the model's own online predictor
//!   (`Model::predictor(..).online()`, exactly what `predict` and `stream` run)
//!   and the predictive likelihood `log p(o¹_{1:t} | λ_a) = Σ_τ log c_τ` that
//!   its forward filter accumulates; a static mixture has no filter, so its
//!   track filters the mixture-as-HMM alongside. An action may also have a
//!   separate *recognition model*: then the likelihood is that model's (its
//!   action HMM's human marginal, filtered alongside) and the prediction stays
//!   the predicting model's.

use crate::error::{RecognitionError, Result};
use phasekit_emission::Gaussian;
use phasekit_gmm::Gmm;
use phasekit_hmm::{ForwardFilter, Hmm};
use phasekit_tsc::{AnyEmission, Model, OnlinePredictor, Roles};

/// The joint HMM whose human marginal `model`'s prediction filters with (see
/// the module documentation).
///
/// The library composes its actions' Gaussian states (the composed HMM, the
/// threshold model): a model whose states emit another distribution
/// (`--emission student-t`, `gmm-K`) is refused here, by name, until those
/// compositions take any emission.
pub fn action_hmm(model: &Model) -> Result<Hmm<Gaussian>> {
    match model {
        Model::Hmm(h) => gaussian_hmm(h),
        Model::TscHmm { model, .. } => gaussian_hmm(model.union().unwrap_or(model.base())),
        Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => mixture_as_hmm(g),
        // The best-ranked member stands for the mean (its states and filter).
        Model::Ensemble(members) => match members.first() {
            Some(m) => action_hmm(&m.model),
            None => Err(RecognitionError::InvalidLibrary(
                "an ensemble model has no member".into(),
            )),
        },
        Model::Hsmm(_) => Err(RecognitionError::InvalidLibrary(
            "an hsmm model has explicit durations: a library of interactions composes HMMs \
             (fit the action with hmm or a tsc-hmm preset)"
                .into(),
        )),
    }
}

/// The same HMM with its Gaussian emission; an error for any other emission.
fn gaussian_hmm(h: &Hmm<AnyEmission>) -> Result<Hmm<Gaussian>> {
    let g = h.emission().as_gaussian().ok_or_else(|| {
        RecognitionError::InvalidLibrary(format!(
            "an action's states emit `{}`: a library of interactions takes Gaussian emissions \
             (full, diag, spherical, tied) for now",
            h.emission().kind()
        ))
    })?;
    Ok(Hmm::new(
        h.start().to_vec(),
        h.transition().to_vec(),
        g.clone(),
    )?)
}

/// A mixture as an HMM: `π = w`, every row of `A` equal to `w`, the
/// components as emissions. Its predicted state distribution is `w` at every
/// frame, so its filtered belief is the mixture's responsibilities and
/// `log p(x_{1:T}) = Σ_t log Σ_k w_k N(x_t; μ_k, Σ_k)`.
/// An error for components other than Gaussians, as [`action_hmm`] says.
pub fn mixture_as_hmm(g: &Gmm<AnyEmission>) -> Result<Hmm<Gaussian>> {
    let components = g.components().as_gaussian().ok_or_else(|| {
        RecognitionError::InvalidLibrary(format!(
            "an action's mixture components are `{}`: a library of interactions takes Gaussian \
             emissions (full, diag, spherical, tied) for now",
            g.components().kind()
        ))
    })?;
    let w = g.weights().to_vec();
    let rows = (0..w.len()).flat_map(|_| w.iter().copied()).collect();
    Ok(Hmm::new(w, rows, components.clone())?)
}

/// One action's online prediction and likelihood. No allocation per frame.
#[derive(Debug, Clone)]
pub struct ActionTrack {
    online: OnlinePredictor,
    /// The filter whose normalisers are the likelihood, when it is not the
    /// predictor's own: the recognition model's, or for a static GMR the
    /// mixture as an HMM on the human's dims.
    filter: Option<ForwardFilter<Gaussian>>,
    /// A human frame with nothing observed (what a rejected frame becomes).
    nothing: Vec<f64>,
    mean: Vec<f64>,
    with_covariance: bool,
}

impl ActionTrack {
    /// The track of `model` predicting `roles.robot()` from `roles.human()`, its
    /// likelihood from `recognition` when given (else from `model`); with
    /// `with_covariance` every step also computes the predictive covariance.
    pub fn new(
        model: &Model,
        recognition: Option<&Model>,
        roles: &Roles,
        with_covariance: bool,
    ) -> Result<Self> {
        let online = model.predictor(roles)?.online();
        let filter = match (recognition, online.log_likelihood()) {
            (Some(r), _) => Some(ForwardFilter::on_dims(&action_hmm(r)?, roles.human())?),
            (None, None) => Some(ForwardFilter::on_dims(&action_hmm(model)?, roles.human())?),
            (None, Some(_)) => None,
        };
        Ok(ActionTrack {
            online,
            filter,
            nothing: vec![f64::NAN; roles.human().len()],
            mean: vec![0.0; roles.robot().len()],
            with_covariance,
        })
    }

    /// Takes one human frame (the human's features, NaN = missing) and returns
    /// whether the likelihood model found it impossible (density zero under
    /// every state, e.g. a glitch of `1e200`). Such a frame is *rejected*, as
    /// the GMR rejects it (`phasekit_gmr`): taken as not observed, so the
    /// filter and the likelihood stay usable; the caller decides what it means
    /// for the action. An error (a frame of the wrong length) changes nothing
    /// useful: the action should be given up until the next reset.
    pub fn step(&mut self, human: &[f64]) -> Result<bool> {
        let evidence = self
            .online
            .step_with_evidence(human, self.with_covariance)?;
        self.mean.copy_from_slice(self.online.mean());
        match &mut self.filter {
            Some(f) => match f.step(human) {
                Ok(_) => Ok(false),
                Err(phasekit_hmm::HmmError::ImpossibleSequence { .. }) => {
                    // The belief is unchanged by the refused frame: step on nothing observed.
                    f.step(&self.nothing)?;
                    Ok(true)
                }
                Err(e) => Err(e.into()),
            },
            None => Ok(evidence.rejected),
        }
    }

    /// `log p(o¹_{1:t} | λ_a)` of the human frames since the last reset.
    pub fn log_likelihood(&self) -> f64 {
        match &self.filter {
            Some(f) => f.log_likelihood(),
            // A static GMR's track always has its filter (see `new`).
            None => self.online.log_likelihood().unwrap_or(f64::NEG_INFINITY),
        }
    }

    /// The predicting model's filtered belief over the states of its
    /// [`action_hmm`] (a static mixture's: the responsibilities of the last frame).
    pub fn belief(&self) -> &[f64] {
        self.online.belief()
    }

    /// The predicted robot features of the last frame.
    pub fn mean(&self) -> &[f64] {
        &self.mean
    }

    /// The predictive covariance of the last frame (`O × O`; meaningful only
    /// when the track computes covariances).
    pub fn covariance(&self) -> &[f64] {
        self.online.covariance()
    }

    /// Starts a new demonstration.
    pub fn reset(&mut self) {
        self.online.reset();
        if let Some(f) = &mut self.filter {
            f.reset();
        }
    }
}
