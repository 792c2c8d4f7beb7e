//! Predicting the robot's dims from the human's: over whole sequences
//! ([`Predictor`]) and frame by frame for a control loop ([`OnlinePredictor`]).

use crate::detect::select;
use crate::emission_choice::AnyEmission;
use crate::error::Result;
use crate::roles::Roles;
use phasekit_emission::Frames;
use phasekit_gmr::{FrameEvidence, Prediction};

type HmmRegression = phasekit_gmr::HmmRegression<AnyEmission>;
type OnlineRegression = phasekit_gmr::OnlineRegression<AnyEmission>;
type GmmRegression = phasekit_gmr::GmmRegression<AnyEmission>;
type HsmmRegression = phasekit_gmr::HsmmRegression<AnyEmission>;
type OnlineHsmmRegression = phasekit_gmr::OnlineHsmmRegression<AnyEmission>;

/// Predicts the robot's dims from the human's, over whole sequences, causally
/// (made by `Model::predictor`).
///
/// Every predicted covariance `Σ_t` is returned as `c · (Σ_t + A)`: `A` the
/// predictor's added covariance ([`Predictor::with_added_covariance`]; none
/// unless a calibration set it) and `c` its covariance scale
/// ([`Predictor::with_covariance_scale`]; 1 unless a calibration set it).
/// The mean never changes.
#[derive(Debug, Clone)]
pub struct Predictor {
    kind: PredictorKind,
    covariance_scale: f64,
    /// `A`, `O × O`, or empty.
    added_covariance: Vec<f64>,
}

#[derive(Debug, Clone)]
enum PredictorKind {
    /// HMM-GMR (the baseline and the union compositions).
    Hmm(HmmRegression),
    /// `λ`'s GMR, replaced by `λ_T`'s where `λ_T` explains the human's frame
    /// better (`λ_T`'s boxed: the variants stay of similar size).
    Gated {
        base: HmmRegression,
        transition: Box<HmmRegression>,
    },
    /// Static GMR.
    Gmm(GmmRegression),
    /// HSMM-GMR (boxed: the variants stay of similar size).
    Hsmm(Box<HsmmRegression>),
}

impl Predictor {
    fn of(kind: PredictorKind) -> Self {
        Predictor {
            kind,
            covariance_scale: 1.0,
            added_covariance: Vec::new(),
        }
    }

    /// The same predictor with every predicted covariance multiplied by
    /// `scale` (finite, > 0): a calibration fitted on held-out demonstrations
    /// (`FitSummary::covariance_scale`). The mean is unchanged.
    pub fn with_covariance_scale(mut self, scale: f64) -> Result<Self> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(crate::error::TscError::InvalidSetting {
                name: "covariance_scale",
                reason: format!("must be finite and > 0, got {scale}"),
            });
        }
        self.covariance_scale = scale;
        Ok(self)
    }

    /// The factor every predicted covariance is multiplied by.
    pub fn covariance_scale(&self) -> f64 {
        self.covariance_scale
    }

    /// The same predictor with `added` (`O × O`, row-major: finite,
    /// symmetric, nonnegative diagonal) added to every predicted covariance
    /// before the scale multiplies it: a calibration's covariance shape
    /// (`FitSummary::covariance_added`). An empty `added` adds nothing.
    pub fn with_added_covariance(mut self, added: &[f64]) -> Result<Self> {
        let o = self.n_out();
        let bad = |reason: String| crate::error::TscError::InvalidSetting {
            name: "added_covariance",
            reason,
        };
        if !added.is_empty() {
            if added.len() != o * o {
                return Err(bad(format!(
                    "{} values for {o} predicted dims (needs {})",
                    added.len(),
                    o * o
                )));
            }
            for i in 0..o {
                for j in 0..o {
                    let (a, b) = (added[i * o + j], added[j * o + i]);
                    if !a.is_finite() || a != b || (i == j && a < 0.0) {
                        return Err(bad(format!(
                            "entry ({i}, {j}) is {a} (must be finite, symmetric, ≥ 0 on the diagonal)"
                        )));
                    }
                }
            }
            if !positive_semidefinite(added, o) {
                return Err(bad(
                    "not positive semi-definite: it could make a predicted covariance indefinite"
                        .into(),
                ));
            }
        }
        self.added_covariance = added.to_vec();
        Ok(self)
    }

    /// Both parts of a fit's calibration: [`Predictor::with_added_covariance`]
    /// and [`Predictor::with_covariance_scale`] (nothing without one).
    pub fn with_calibration(self, summary: &crate::summary::FitSummary) -> Result<Self> {
        self.with_added_covariance(summary.covariance_added().unwrap_or(&[]))?
            .with_covariance_scale(summary.covariance_scale())
    }

    /// HSMM-GMR of one HSMM.
    pub fn hsmm(r: HsmmRegression) -> Self {
        Predictor::of(PredictorKind::Hsmm(Box::new(r)))
    }

    /// HMM-GMR of one HMM.
    pub fn hmm(r: HmmRegression) -> Self {
        Predictor::of(PredictorKind::Hmm(r))
    }

    /// The likelihood gate of `λ`'s and `λ_T`'s HMM-GMR.
    pub(crate) fn gated(base: HmmRegression, transition: HmmRegression) -> Self {
        Predictor::of(PredictorKind::Gated {
            base,
            transition: Box::new(transition),
        })
    }

    /// Static GMR of a mixture.
    pub fn gmm(r: GmmRegression) -> Self {
        Predictor::of(PredictorKind::Gmm(r))
    }

    /// Number of predicted dims.
    pub fn n_out(&self) -> usize {
        match &self.kind {
            PredictorKind::Hmm(r) | PredictorKind::Gated { base: r, .. } => r.regression().n_out(),
            PredictorKind::Gmm(r) => r.regression().n_out(),
            PredictorKind::Hsmm(r) => r.regression().n_out(),
        }
    }

    /// Predicts a sequence of human frames (human dims only), causally.
    pub fn predict(&self, human: Frames<'_>, with_covariance: bool) -> Result<Prediction> {
        let mut p = self.predict_unscaled(human, with_covariance)?;
        if let Some(c) = p.covariance.as_mut() {
            if !self.added_covariance.is_empty() {
                for frame in c.chunks_exact_mut(self.added_covariance.len()) {
                    frame
                        .iter_mut()
                        .zip(&self.added_covariance)
                        .for_each(|(v, a)| *v += a);
                }
            }
            if self.covariance_scale != 1.0 {
                c.iter_mut().for_each(|v| *v *= self.covariance_scale);
            }
        }
        Ok(p)
    }

    fn predict_unscaled(&self, human: Frames<'_>, with_covariance: bool) -> Result<Prediction> {
        match &self.kind {
            PredictorKind::Hmm(r) => Ok(r.predict(human, with_covariance)?),
            PredictorKind::Gmm(r) => Ok(r.predict(human, with_covariance)?),
            PredictorKind::Hsmm(r) => Ok(r.predict(human, with_covariance)?),
            PredictorKind::Gated { base, transition } => {
                let mut a = base.predict(human, with_covariance)?;
                let b = transition.predict(human, with_covariance)?;
                let la = base.input_model().forward(human)?;
                let lb = transition.input_model().forward(human)?;
                let o = a.n_out;
                for (t, (x, y)) in la
                    .log_normalisers()
                    .iter()
                    .zip(lb.log_normalisers())
                    .enumerate()
                {
                    if y > x {
                        a.mean[t * o..(t + 1) * o].copy_from_slice(&b.mean[t * o..(t + 1) * o]);
                        if let (Some(ca), Some(cb)) = (a.covariance.as_mut(), b.covariance.as_ref())
                        {
                            ca[t * o * o..(t + 1) * o * o]
                                .copy_from_slice(&cb[t * o * o..(t + 1) * o * o]);
                        }
                    }
                }
                Ok(a)
            }
        }
    }

    /// A frame-by-frame predictor.
    pub fn online(&self) -> OnlinePredictor {
        let o = self.n_out();
        let kind = match &self.kind {
            PredictorKind::Hmm(r) => OnlineKind::Hmm(r.online()),
            PredictorKind::Hsmm(r) => OnlineKind::Hsmm(Box::new(r.online())),
            PredictorKind::Gated { base, transition } => OnlineKind::Gated {
                base: base.online(),
                transition: Box::new(transition.online()),
                mean: vec![0.0; o],
                covariance: vec![0.0; o * o],
            },
            PredictorKind::Gmm(r) => {
                let k = r.regression().n_states();
                OnlineKind::Gmm {
                    regression: r.clone(),
                    weights: vec![0.0; k],
                    mean: vec![0.0; o],
                    covariance: vec![0.0; o * o],
                    scratch: vec![0.0; k * o],
                }
            }
        };
        OnlinePredictor {
            kind,
            covariance_scale: self.covariance_scale,
            added_covariance: self.added_covariance.clone(),
            scaled_covariance: vec![0.0; o * o],
        }
    }
}

/// Frame-by-frame prediction for a control loop; no allocation per frame
/// (made by [`Predictor::online`]).
#[derive(Debug, Clone)]
pub struct OnlinePredictor {
    kind: OnlineKind,
    /// The predictor's covariance scale.
    covariance_scale: f64,
    /// The predictor's added covariance (`O × O`, or empty).
    added_covariance: Vec<f64>,
    /// `scale · (Σ + A)` of the last step (used when the scale is not 1 or
    /// something is added).
    scaled_covariance: Vec<f64>,
}

#[derive(Debug, Clone)]
enum OnlineKind {
    /// Online HMM-GMR.
    Hmm(OnlineRegression),
    /// Two online HMM-GMRs and the likelihood gate; `mean` and `covariance`
    /// hold the chosen one's (`λ_T`'s boxed: the variants stay of similar size).
    Gated {
        base: OnlineRegression,
        transition: Box<OnlineRegression>,
        mean: Vec<f64>,
        covariance: Vec<f64>,
    },
    /// Online HSMM-GMR (boxed: the variants stay of similar size).
    Hsmm(Box<OnlineHsmmRegression>),
    /// Static GMR, frame by frame: the responsibilities, mean and covariance
    /// of the last frame, and scratch space.
    Gmm {
        regression: GmmRegression,
        weights: Vec<f64>,
        mean: Vec<f64>,
        covariance: Vec<f64>,
        scratch: Vec<f64>,
    },
}

impl OnlinePredictor {
    /// Takes one human frame and returns the predicted robot mean; with
    /// `with_covariance` also updates [`OnlinePredictor::covariance`].
    pub fn step(&mut self, human: &[f64], with_covariance: bool) -> Result<&[f64]> {
        self.step_with_evidence(human, with_covariance)?;
        Ok(self.mean())
    }

    /// [`OnlinePredictor::step`], returning what the frame told the model:
    /// its log predictive density under the (base) model and whether no state
    /// explains it (the frame was then not used; see `phasekit_gmr`). The
    /// prediction is read with [`OnlinePredictor::mean`].
    pub fn step_with_evidence(
        &mut self,
        human: &[f64],
        with_covariance: bool,
    ) -> Result<FrameEvidence> {
        let evidence = self.step_unscaled(human, with_covariance)?;
        if with_covariance && self.transforms_covariance() {
            let c = self.covariance_scale;
            let src = kind_covariance(&self.kind);
            if self.added_covariance.is_empty() {
                for (d, s) in self.scaled_covariance.iter_mut().zip(src) {
                    *d = s * c;
                }
            } else {
                for ((d, s), a) in self
                    .scaled_covariance
                    .iter_mut()
                    .zip(src)
                    .zip(&self.added_covariance)
                {
                    *d = (s + a) * c;
                }
            }
        }
        Ok(evidence)
    }

    fn step_unscaled(&mut self, human: &[f64], with_covariance: bool) -> Result<FrameEvidence> {
        Ok(match &mut self.kind {
            OnlineKind::Hmm(r) => {
                if with_covariance {
                    r.step_with_covariance(human)?;
                } else {
                    r.step(human)?;
                }
                r.evidence()
            }
            OnlineKind::Hsmm(r) => {
                if with_covariance {
                    r.step_with_covariance(human)?;
                } else {
                    r.step(human)?;
                }
                r.evidence()
            }
            OnlineKind::Gated {
                base,
                transition,
                mean,
                covariance,
            } => {
                let (la, lb) = (base.log_likelihood(), transition.log_likelihood());
                base.step_with_covariance(human)?;
                transition.step_with_covariance(human)?;
                let use_t = transition.log_likelihood() - lb > base.log_likelihood() - la;
                let src = if use_t { &**transition } else { &*base };
                mean.copy_from_slice(src.mean());
                covariance.copy_from_slice(src.covariance());
                base.evidence()
            }
            OnlineKind::Gmm {
                regression,
                weights,
                mean,
                covariance,
                scratch,
            } => regression.predict_one_into(
                human,
                weights,
                mean,
                with_covariance.then_some(&mut covariance[..]),
                scratch,
            )?,
        })
    }

    /// Predicted robot mean of the last step, `O` values.
    pub fn mean(&self) -> &[f64] {
        match &self.kind {
            OnlineKind::Hmm(r) => r.mean(),
            OnlineKind::Hsmm(r) => r.mean(),
            OnlineKind::Gated { mean, .. } | OnlineKind::Gmm { mean, .. } => mean,
        }
    }

    /// Predictive covariance of the last step (when requested), `O × O`,
    /// times the predictor's covariance scale.
    pub fn covariance(&self) -> &[f64] {
        if self.transforms_covariance() {
            &self.scaled_covariance
        } else {
            self.unscaled_covariance()
        }
    }

    /// Whether the returned covariance differs from the model's.
    fn transforms_covariance(&self) -> bool {
        self.covariance_scale != 1.0 || !self.added_covariance.is_empty()
    }

    fn unscaled_covariance(&self) -> &[f64] {
        kind_covariance(&self.kind)
    }

    /// The filtered belief over the states of the HMM the prediction filters
    /// with (the gated TSC-HMM's: `λ`'s); a static GMR's: the responsibilities
    /// of the last frame.
    pub fn belief(&self) -> &[f64] {
        match &self.kind {
            OnlineKind::Hmm(r) | OnlineKind::Gated { base: r, .. } => r.belief(),
            OnlineKind::Hsmm(r) => r.belief(),
            OnlineKind::Gmm { weights, .. } => weights,
        }
    }

    /// `log p(x^h_{1:t})` of the human frames since the last reset under the
    /// HMM the prediction filters with (the gated TSC-HMM's: `λ`'s); `None`
    /// for a static GMR, which has no filter.
    pub fn log_likelihood(&self) -> Option<f64> {
        match &self.kind {
            OnlineKind::Hmm(r) | OnlineKind::Gated { base: r, .. } => Some(r.log_likelihood()),
            OnlineKind::Hsmm(r) => Some(r.log_likelihood()),
            OnlineKind::Gmm { .. } => None,
        }
    }

    /// Starts a new demonstration.
    pub fn reset(&mut self) {
        match &mut self.kind {
            OnlineKind::Hmm(r) => r.reset(),
            OnlineKind::Hsmm(r) => r.reset(),
            OnlineKind::Gated {
                base, transition, ..
            } => {
                base.reset();
                transition.reset();
            }
            OnlineKind::Gmm { .. } => {}
        }
    }
}

/// The unscaled predictive covariance of the last step of an online kind.
fn kind_covariance(kind: &OnlineKind) -> &[f64] {
    match kind {
        OnlineKind::Hmm(r) => r.covariance(),
        OnlineKind::Hsmm(r) => r.covariance(),
        OnlineKind::Gated { covariance, .. } | OnlineKind::Gmm { covariance, .. } => covariance,
    }
}

/// The predictor's input: the human's dims of joint frames, `T × |human|`
/// row-major; errors when the roles do not fit the frames' dimension.
pub fn human_frames(seq: Frames<'_>, roles: &Roles) -> Result<Vec<f64>> {
    roles.check(seq.dim())?;
    Ok(select(seq, roles.human()))
}

/// Whether a symmetric `o × o` matrix is positive semi-definite: its
/// Cholesky factorisation succeeds after adding `1e-12` of its largest
/// diagonal entry (rounding) to the diagonal.
fn positive_semidefinite(a: &[f64], o: usize) -> bool {
    let jitter = 1e-12 * (0..o).map(|i| a[i * o + i]).fold(0.0, f64::max) + f64::MIN_POSITIVE;
    let mut l = vec![0.0; o * o];
    for i in 0..o {
        for j in 0..=i {
            let mut s = a[i * o + j] - (0..j).map(|k| l[i * o + k] * l[j * o + k]).sum::<f64>();
            if i == j {
                s += jitter;
                if s.is_nan() || s <= 0.0 {
                    return false;
                }
                l[i * o + i] = s.sqrt();
            } else {
                l[i * o + j] = s / l[j * o + j];
            }
        }
    }
    true
}
