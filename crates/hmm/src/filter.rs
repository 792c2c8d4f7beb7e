//! The online forward filter: one frame in, the current belief out.
//!
//! `h_t(j) ∝ b_j(x_t) Σ_i h_{t−1}(i) a_ij` (with `h_0 ∝ π_j b_j(x_0)`), by the
//! same recursion as the batch [`Hmm::forward`] (including its switch to log
//! space when linear arithmetic would lose a state), so the two agree to the last bit.
//! No allocation happens per frame.

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

    /// Takes frame `x_t` (length `D` of the filtered model) and returns `h_t`.
    ///
    /// An impossible frame (probability zero under every state) is an error and
    /// leaves the belief unchanged, so a controller can skip the frame and go on.
    pub fn step(&mut self, frame: &[f64]) -> Result<&[f64]> {
        let frames = Frames::new(frame, self.hmm.dim().max(1)).and_then(|f| {
            if f.len() == 1 {
                Ok(f)
            } else {
                Err(EmissionError::DimensionMismatch {
                    context: "online filter frame",
                    expected: self.hmm.dim(),
                    found: frame.len(),
                })
            }
        })?;
        self.hmm.emission.check_frames(frames)?;
        // Every emission evaluates a frame with missing values (NaN) on the
        // marginal of its observed values (the rule of `Emission`).
        self.hmm
            .emission
            .log_density_into(frames, &mut self.log_b)?;
        let lc = self.core.step(&self.hmm, &self.log_b, &mut self.scratch);
        if lc > f64::NEG_INFINITY {
            std::mem::swap(&mut self.belief, &mut self.scratch);
        }
        if lc == f64::NEG_INFINITY {
            return Err(HmmError::ImpossibleSequence {
                sequence: 0,
                frame: self.frames,
            });
        }
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
        self.core.reset(&self.hmm);
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
