//! HSMM-GMR: the weights of the regression are the online forward variable
//! of a hidden semi-Markov model on the input dims (pbdlib's step-wise
//! forward variable with durations), so that how long the current phase has
//! lasted moves the prediction on to the next phase.
//!
//! `h_t(j) = p(z_t = j | x^i_{≤t})` under the HSMM's input marginal (see
//! `phasekit_hsmm::HsmmFilter`), then `m = Σ_j h_t(j) m_j(x^i_t)` and the
//! moment-matched covariance, as for HMM-GMR ([`crate::regression`]). A whole
//! sequence is predicted by the same online filter frame after frame, so the
//! batch and the online predictions are the same numbers by construction.
//!
//! A frame that no explanation allows (the filter's `ImpossibleSequence`,
//! e.g. a glitch of `1e200`, or a demonstration that outlasts every
//! segmentation the durations allow) is rejected, as in HMM-GMR: taken as not
//! observed (the belief takes its duration step only), reported in
//! [`Prediction::rejected`] and by [`OnlineHsmmRegression::evidence`]. When
//! even that has probability zero (every segment at its maximum duration in
//! the terminal state) the belief is kept and the frame reported rejected.

use crate::error::Result;
use crate::regression::{FrameEvidence, Mixer, Prediction, Regression};
use phasekit_emission::{Conditional, Frames, Marginal};
use phasekit_hsmm::{AnyDuration, Hsmm, HsmmError, HsmmFilter};

/// HSMM-GMR of `output` on `input` under a joint HSMM.
#[derive(Debug, Clone)]
pub struct HsmmRegression<E: Conditional + Marginal> {
    regression: Regression<E>,
    input_model: Hsmm<E, AnyDuration>,
}

impl<E: Conditional + Marginal> HsmmRegression<E> {
    /// Regression of `output` on `input` under the joint HSMM `hsmm`.
    pub fn new(hsmm: &Hsmm<E, AnyDuration>, input: &[usize], output: &[usize]) -> Result<Self> {
        let regression = Regression::new(hsmm.emission(), input, output)?;
        let input_model = hsmm.marginal(input)?;
        Ok(HsmmRegression {
            regression,
            input_model,
        })
    }

    /// The conditionals.
    pub fn regression(&self) -> &Regression<E> {
        &self.regression
    }

    /// The HSMM on the input dims.
    pub fn input_model(&self) -> &Hsmm<E, AnyDuration> {
        &self.input_model
    }

    /// Predicts a whole sequence (input dims only, in `input` order), causally,
    /// by the online filter (the batch prediction is the online one).
    pub fn predict(&self, input_frames: Frames<'_>, with_covariance: bool) -> Result<Prediction> {
        let (k, o, t) = (
            self.regression.n_states(),
            self.regression.n_out(),
            input_frames.len(),
        );
        if input_frames.dim() != self.regression.input().len() {
            return Err(crate::GmrError::InvalidDims(format!(
                "HSMM-GMR: input frames of {} values, the model takes {}",
                input_frames.dim(),
                self.regression.input().len()
            )));
        }
        let mut online = self.online();
        let mut mean = Vec::with_capacity(t * o);
        let mut cov = with_covariance.then(|| Vec::with_capacity(t * o * o));
        let mut weights = Vec::with_capacity(t * k);
        let mut log_predictive = Vec::with_capacity(t);
        let mut rejected = Vec::new();
        for (tt, x) in input_frames.iter().enumerate() {
            online.step_inner(x, with_covariance)?;
            mean.extend_from_slice(&online.mean);
            if let Some(c) = cov.as_mut() {
                c.extend_from_slice(&online.covariance);
            }
            weights.extend_from_slice(online.belief());
            log_predictive.push(online.evidence.log_predictive);
            if online.evidence.rejected {
                rejected.push(tt);
            }
        }
        Ok(Prediction {
            n_out: o,
            mean,
            covariance: cov,
            weights,
            log_predictive,
            rejected,
        })
    }

    /// A frame-by-frame predictor for a control loop.
    pub fn online(&self) -> OnlineHsmmRegression<E> {
        let (k, o) = (self.regression.n_states(), self.regression.n_out());
        OnlineHsmmRegression {
            filter: HsmmFilter::new(self.input_model.clone()),
            nothing: vec![f64::NAN; self.regression.input().len()],
            mixer: self.regression.mixer(),
            regression: self.regression.clone(),
            mean: vec![0.0; o],
            covariance: vec![0.0; o * o],
            scratch: vec![0.0; k * o],
            evidence: FrameEvidence::NONE,
        }
    }
}

/// Online HSMM-GMR: one input frame in, the predicted output (mean and
/// covariance) out; no allocation per frame (a frame with missing inputs
/// builds its pattern's conditionals the first time the pattern is seen).
#[derive(Debug, Clone)]
pub struct OnlineHsmmRegression<E: Conditional + Marginal> {
    filter: HsmmFilter<E, AnyDuration>,
    regression: Regression<E>,
    mixer: Mixer<E>,
    nothing: Vec<f64>,
    mean: Vec<f64>,
    covariance: Vec<f64>,
    scratch: Vec<f64>,
    evidence: FrameEvidence,
}

impl<E: Conditional + Marginal> OnlineHsmmRegression<E> {
    /// Takes input frame `x^i_t`, updates the belief and returns the predicted output mean.
    pub fn step(&mut self, input_frame: &[f64]) -> Result<&[f64]> {
        self.step_inner(input_frame, false)?;
        Ok(&self.mean)
    }

    /// Like [`OnlineHsmmRegression::step`], also computing the predictive covariance.
    pub fn step_with_covariance(&mut self, input_frame: &[f64]) -> Result<&[f64]> {
        self.step_inner(input_frame, true)?;
        Ok(&self.mean)
    }

    fn step_inner(&mut self, input_frame: &[f64], with_covariance: bool) -> Result<()> {
        if input_frame.iter().any(|v| v.is_infinite()) {
            return Err(crate::GmrError::InvalidDims(
                "HSMM-GMR: an input value is infinite".into(),
            ));
        }
        let before = self.filter.log_likelihood();
        let evidence = match self.filter.step(input_frame) {
            Ok(_) => FrameEvidence {
                log_predictive: self.filter.log_likelihood() - before,
                rejected: false,
            },
            Err(HsmmError::ImpossibleSequence { .. }) => {
                // The refused frame left the filter unchanged: take it as not observed
                // (the durations still advance); if even that is impossible, keep the belief.
                match self.filter.step(&self.nothing) {
                    Ok(_) | Err(HsmmError::ImpossibleSequence { .. }) => {}
                    Err(e) => return Err(e.into()),
                }
                FrameEvidence {
                    log_predictive: f64::NEG_INFINITY,
                    rejected: true,
                }
            }
            Err(e) => return Err(e.into()),
        };
        let x = if evidence.rejected {
            &self.nothing[..]
        } else {
            input_frame
        };
        self.mixer.mix(
            &self.regression,
            x,
            self.filter.belief(),
            &mut self.mean,
            with_covariance.then_some(&mut self.covariance[..]),
            &mut self.scratch,
        )?;
        self.evidence = evidence;
        Ok(())
    }

    /// What the last step's frame told about its inputs.
    pub fn evidence(&self) -> FrameEvidence {
        self.evidence
    }

    /// The predictive covariance of the last step with covariance, `O × O`.
    pub fn covariance(&self) -> &[f64] {
        &self.covariance
    }

    /// The current belief `h_t` over states.
    pub fn belief(&self) -> &[f64] {
        self.filter.belief()
    }

    /// The predicted output mean of the last step.
    pub fn mean(&self) -> &[f64] {
        &self.mean
    }

    /// `log p(x^i_{1:t})` of the input frames seen so far (rejected frames excluded).
    pub fn log_likelihood(&self) -> f64 {
        self.filter.log_likelihood()
    }

    /// Starts a new sequence.
    pub fn reset(&mut self) {
        self.filter.reset();
        self.evidence = FrameEvidence::NONE;
    }
}
