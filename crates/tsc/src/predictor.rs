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
    /// The weighted mean of members' predictions ([`Predictor::ensemble`]).
    Ensemble(Vec<(f64, Predictor)>),
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

    /// The weighted mean of `members` (weight `w_i`, predictor), as a mixture
    /// of their predictive Gaussians matched by its first two moments:
    ///
    /// `μ_t = Σ_i w_i μ_{i,t}`, `Σ_t = Σ_i w_i (Σ_{i,t} + (μ_{i,t} − μ_t)(μ_{i,t} − μ_t)ᵀ)`
    /// (frame by frame), each member's `Σ_{i,t}` as that member
    /// returns it. The evidence of a frame (log predictive density, rejected
    /// frames, the weights or belief) is the first member's. Errors when
    /// there is no member, the members predict different numbers of dims, or
    /// a weight is not finite and positive or they do not sum to 1 (to
    /// `1e-9`).
    pub fn ensemble(members: Vec<(f64, Predictor)>) -> Result<Self> {
        let bad = |reason: String| crate::error::TscError::InvalidModel {
            model: "ensemble",
            reason,
        };
        let Some((_, first)) = members.first() else {
            return Err(bad("it has no member".into()));
        };
        let o = first.n_out();
        for (i, (w, p)) in members.iter().enumerate() {
            if p.n_out() != o {
                return Err(bad(format!(
                    "member {i} predicts {} dims, member 0 {o}",
                    p.n_out()
                )));
            }
            if !(w.is_finite() && *w > 0.0) {
                return Err(bad(format!("member {i} has weight {w}")));
            }
        }
        let total: f64 = members.iter().map(|(w, _)| w).sum();
        if (total - 1.0).abs() > 1e-9 {
            return Err(bad(format!("the weights sum to {total}, not 1")));
        }
        Ok(Predictor::of(PredictorKind::Ensemble(members)))
    }

    /// Number of predicted dims.
    pub fn n_out(&self) -> usize {
        match &self.kind {
            PredictorKind::Hmm(r) | PredictorKind::Gated { base: r, .. } => r.regression().n_out(),
            PredictorKind::Gmm(r) => r.regression().n_out(),
            PredictorKind::Hsmm(r) => r.regression().n_out(),
            PredictorKind::Ensemble(m) => m.first().map_or(0, |(_, p)| p.n_out()),
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
            PredictorKind::Ensemble(members) => {
                let predictions = members
                    .iter()
                    .map(|(_, p)| p.predict(human, with_covariance))
                    .collect::<Result<Vec<_>>>()?;
                let weights: Vec<f64> = members.iter().map(|(w, _)| *w).collect();
                Ok(combine_predictions(&weights, predictions))
            }
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
            PredictorKind::Ensemble(members) => OnlineKind::Ensemble {
                members: members.iter().map(|(w, p)| (*w, p.online())).collect(),
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
    /// Every member's online predictor and their combination of the last
    /// step ([`Predictor::ensemble`]).
    Ensemble {
        members: Vec<(f64, OnlinePredictor)>,
        mean: Vec<f64>,
        covariance: Vec<f64>,
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
            OnlineKind::Ensemble {
                members,
                mean,
                covariance,
            } => {
                let mut evidence = None;
                for (_, m) in members.iter_mut() {
                    let e = m.step_with_evidence(human, with_covariance)?;
                    evidence.get_or_insert(e);
                }
                combine_step(
                    members,
                    mean,
                    with_covariance.then_some(&mut covariance[..]),
                );
                evidence.unwrap_or(FrameEvidence::NONE)
            }
        })
    }

    /// Predicted robot mean of the last step, `O` values.
    pub fn mean(&self) -> &[f64] {
        match &self.kind {
            OnlineKind::Hmm(r) => r.mean(),
            OnlineKind::Hsmm(r) => r.mean(),
            OnlineKind::Gated { mean, .. }
            | OnlineKind::Gmm { mean, .. }
            | OnlineKind::Ensemble { mean, .. } => mean,
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
            OnlineKind::Ensemble { members, .. } => members[0].1.belief(),
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
            OnlineKind::Ensemble { members, .. } => members[0].1.log_likelihood(),
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
            OnlineKind::Ensemble { members, .. } => {
                members.iter_mut().for_each(|(_, m)| m.reset());
            }
        }
    }
}

/// The unscaled predictive covariance of the last step of an online kind.
fn kind_covariance(kind: &OnlineKind) -> &[f64] {
    match kind {
        OnlineKind::Hmm(r) => r.covariance(),
        OnlineKind::Hsmm(r) => r.covariance(),
        OnlineKind::Gated { covariance, .. }
        | OnlineKind::Gmm { covariance, .. }
        | OnlineKind::Ensemble { covariance, .. } => covariance,
    }
}

/// The moment-matched mixture of members' predictions of a sequence
/// ([`Predictor::ensemble`]'s formula, frame by frame); the evidence
/// (weights, log predictive densities, rejected frames) is the first's.
fn combine_predictions(weights: &[f64], predictions: Vec<Prediction>) -> Prediction {
    let mut it = predictions.into_iter();
    let mut out = it
        .next()
        .expect("an ensemble has a member (checked when built)");
    let rest: Vec<Prediction> = it.collect();
    let o = out.n_out;
    let first = std::mem::take(&mut out.mean);
    let all: Vec<&Prediction> = std::iter::once(&out).chain(&rest).collect();
    let means: Vec<&[f64]> = std::iter::once(first.as_slice())
        .chain(rest.iter().map(|p| p.mean.as_slice()))
        .collect();
    let frames = first.len() / o.max(1);
    let mut mean = vec![0.0; first.len()];
    for (w, m) in weights.iter().zip(&means) {
        mean.iter_mut().zip(m.iter()).for_each(|(a, b)| *a += w * b);
    }
    let covariance = all
        .iter()
        .map(|p| p.covariance.as_deref())
        .collect::<Option<Vec<_>>>()
        .map(|covs| {
            let mut c = vec![0.0; frames * o * o];
            for t in 0..frames {
                let mu = &mean[t * o..(t + 1) * o];
                let ct = &mut c[t * o * o..(t + 1) * o * o];
                for ((w, m), s) in weights.iter().zip(&means).zip(&covs) {
                    add_moment(
                        ct,
                        *w,
                        &m[t * o..(t + 1) * o],
                        mu,
                        &s[t * o * o..(t + 1) * o * o],
                    );
                }
            }
            c
        });
    out.mean = mean;
    out.covariance = covariance;
    out
}

/// `c += w (Σ + (m − μ)(m − μ)ᵀ)`, `O × O` row-major.
fn add_moment(c: &mut [f64], w: f64, m: &[f64], mu: &[f64], sigma: &[f64]) {
    let o = m.len();
    for i in 0..o {
        for j in 0..o {
            c[i * o + j] += w * (sigma[i * o + j] + (m[i] - mu[i]) * (m[j] - mu[j]));
        }
    }
}

/// One online step of [`combine_predictions`], into preallocated buffers.
fn combine_step(
    members: &[(f64, OnlinePredictor)],
    mean: &mut [f64],
    covariance: Option<&mut [f64]>,
) {
    mean.fill(0.0);
    for (w, m) in members {
        mean.iter_mut().zip(m.mean()).for_each(|(a, b)| *a += w * b);
    }
    if let Some(c) = covariance {
        c.fill(0.0);
        for (w, m) in members {
            add_moment(c, *w, m.mean(), mean, m.covariance());
        }
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
