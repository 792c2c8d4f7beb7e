//! The online forward filter: one frame in, the current belief out.
//!
//! `h_t(j) ∝ b_j(x_t) Σ_i h_{t−1}(i) a_ij` (with `h_0 ∝ π_j b_j(x_0)`), by the
//! same recursion as the batch [`Hmm::forward`] (including its switch to log
//! space when linear arithmetic would lose a state), so the two agree to the
//! last bit. No allocation happens per frame for complete frames.
//!
//! Missing values follow the rule of batch inference: a frame with NaN
//! entries goes to the emission's [`Emission::log_density_into`], which
//! evaluates it on the marginal of its observed values (density 1 when
//! nothing is observed, so that the filter only takes its transition step).

use crate::error::{HmmError, Result};
use crate::inference::ForwardCore;
use crate::model::Hmm;
use phasekit_emission::{Emission, EmissionError, Frames, Marginal};

/// Incremental forward filter over a (possibly marginal) HMM.
#[derive(Debug, Clone)]
pub struct ForwardFilter<E: Emission> {
    hmm: Hmm<E>,
    belief: Vec<f64>,
    core: ForwardCore,
    log_b: Vec<f64>,
    scratch: Vec<f64>,
    log_likelihood: f64,
    frames: usize,
}

impl<E: Emission> ForwardFilter<E> {
    /// A filter over `hmm`, before any frame.
    pub fn new(hmm: Hmm<E>) -> Self {
        let s = hmm.n_states();
        ForwardFilter {
            belief: hmm.start.clone(),
            core: ForwardCore::new(&hmm),
            log_b: vec![0.0; s],
            scratch: vec![0.0; s],
            log_likelihood: 0.0,
            frames: 0,
            hmm,
        }
    }

    /// The model the filter runs on.
    pub fn model(&self) -> &Hmm<E> {
        &self.hmm
    }

    /// Takes frame `x_t` (length `D` of the filtered model; NaN for a value
    /// not observed) and returns `h_t`.
    ///
    /// A frame of the wrong length, an infinite value or a value outside the
    /// emission's support is an error; so is an impossible frame (probability
    /// zero under every state). Either way the belief is left unchanged, so
    /// a controller can skip the frame and go on.
    pub fn step(&mut self, frame: &[f64]) -> Result<&[f64]> {
        let dim = self.hmm.dim();
        if frame.len() != dim {
            return Err(EmissionError::DimensionMismatch {
                context: "online filter frame",
                expected: dim,
                found: frame.len(),
            }
            .into());
        }
        let frames = Frames::new(frame, dim)?;
        self.hmm.emission.check_frames(frames)?;
        self.hmm
            .emission
            .log_density_into(frames, &mut self.log_b)?;
        let lc = self.core.step_row(&self.log_b, &mut self.scratch);
        if lc == f64::NEG_INFINITY {
            return Err(HmmError::ImpossibleSequence {
                sequence: 0,
                frame: self.frames,
            });
        }
        std::mem::swap(&mut self.belief, &mut self.scratch);
        self.log_likelihood += lc;
        self.frames += 1;
        Ok(&self.belief)
    }

    /// The current belief `h_t` (the initial distribution before the first frame).
    pub fn belief(&self) -> &[f64] {
        &self.belief
    }

    /// `log p(x_{1:t})` of the frames seen so far.
    pub fn log_likelihood(&self) -> f64 {
        self.log_likelihood
    }

    /// Number of frames taken.
    pub fn frames_seen(&self) -> usize {
        self.frames
    }

    /// Forgets all frames (a new demonstration begins).
    pub fn reset(&mut self) {
        self.belief.copy_from_slice(&self.hmm.start);
        self.core.reset();
        self.log_likelihood = 0.0;
        self.frames = 0;
    }
}

impl<E: Emission> Hmm<E> {
    /// An online filter over this model.
    pub fn filter(&self) -> ForwardFilter<E> {
        ForwardFilter::new(self.clone())
    }
}

impl<E: Marginal> ForwardFilter<E> {
    /// A filter over the marginal of `hmm` on the dimensions `dims` (e.g. the human's).
    pub fn on_dims(hmm: &Hmm<E>, dims: &[usize]) -> Result<Self> {
        Ok(Self::new(hmm.marginal(dims)?))
    }
}
