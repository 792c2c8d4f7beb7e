//! The online forward filter with durations: one frame in, the state marginals out.
//!
//! This is pbdlib's step-wise forward variable for HSMM-GMR: the belief
//! `h_t(j) = p(z_t = j | x_{≤t})` accounts for how long the current
//! segment has lasted (a state near the end of its typical duration hands
//! over to the next one even before the frames say so), by the same
//! recursion as the batch [`Hsmm::forward`], so the two agree to the last
//! bit. No allocation happens per frame (a frame with missing values builds
//! the marginal of its missing pattern once and caches it).

use crate::duration::{AnyDuration, Duration};
use crate::error::{HsmmError, Result};
use crate::inference::ForwardCore;
use crate::model::Hsmm;
use phasekit_emission::{Emission, EmissionError, Frames};

/// Incremental forward filter over a (possibly marginal) HSMM.
#[derive(Debug, Clone)]
pub struct HsmmFilter<E: Emission, D: Duration = AnyDuration> {
    hsmm: Hsmm<E, D>,
    core: ForwardCore,
    /// Scratch copy of the recursion for looking ahead.
    ahead: ForwardCore,
    belief: Vec<f64>,
    scratch: Vec<f64>,
    log_b: Vec<f64>,
    zeros: Vec<f64>,
    log_likelihood: f64,
    frames: usize,
}

impl<E: Emission, D: Duration> HsmmFilter<E, D> {
    /// A filter over `hsmm`, before any frame.
    pub fn new(hsmm: Hsmm<E, D>) -> Self {
        let s = hsmm.n_states();
        HsmmFilter {
            core: ForwardCore::new(&hsmm),
            ahead: ForwardCore::new(&hsmm),
            belief: hsmm.start.clone(),
            scratch: vec![0.0; s],
            log_b: vec![0.0; s],
            zeros: vec![0.0; s],
            log_likelihood: 0.0,
            frames: 0,
            hsmm,
        }
    }

    /// A filter over the marginal of `hsmm` on the dimensions `dims` (e.g. the human's).
    pub fn on_dims(hsmm: &Hsmm<E, D>, dims: &[usize]) -> Result<Self>
    where
        E: phasekit_emission::Marginal,
    {
        Ok(Self::new(hsmm.marginal(dims)?))
    }

    /// The model the filter runs on.
    pub fn model(&self) -> &Hsmm<E, D> {
        &self.hsmm
    }

    /// Takes frame `x_t` (length `D` of the filtered model; NaN = not
    /// observed) and returns `h_t(j) = p(z_t = j | x_{≤t})`.
    ///
    /// An impossible frame (probability zero under every explanation, e.g.
    /// every segment has reached the maximum duration of a terminal state)
    /// is an error and leaves the filter unchanged, so a controller can skip
    /// the frame and go on.
    pub fn step(&mut self, frame: &[f64]) -> Result<&[f64]> {
        let frames = Frames::new(frame, self.hsmm.dim().max(1)).and_then(|f| {
            if f.len() == 1 {
                Ok(f)
            } else {
                Err(EmissionError::DimensionMismatch {
                    context: "online filter frame",
                    expected: self.hsmm.dim(),
                    found: frame.len(),
                })
            }
        })?;
        self.hsmm.emission.check_frames(frames)?;
        // Every emission evaluates a frame with missing values (NaN) on the
        // marginal of its observed values (the rule of `Emission`).
        self.hsmm
            .emission
            .log_density_into(frames, &mut self.log_b)?;
        let lc = self.core.step(&self.hsmm, &self.log_b, &mut self.scratch);
        if lc == f64::NEG_INFINITY {
            return Err(HsmmError::ImpossibleSequence {
                sequence: 0,
                frame: self.frames,
                max_duration: self.hsmm.max_duration(),
            });
        }
        std::mem::swap(&mut self.belief, &mut self.scratch);
        self.log_likelihood += lc;
        self.frames += 1;
        Ok(&self.belief)
    }

    /// The state marginals of the next `horizon` frames before they are seen,
    /// `p(z_{t+h} = j | x_{≤t})` for `h = 1..=horizon`, written into `out`
    /// (`horizon × S`): where the interaction is heading, from the durations
    /// and transitions alone. Does not change the filter; no allocation.
    pub fn predict_states(&mut self, horizon: usize, out: &mut [f64]) -> Result<()> {
        let s = self.hsmm.n_states();
        if out.len() != horizon * s {
            return Err(HsmmError::InvalidParameter {
                name: "out",
                reason: format!(
                    "{} values for {horizon} frames × {s} states = {}",
                    out.len(),
                    horizon * s
                ),
            });
        }
        self.ahead.copy_from(&self.core);
        for row in out.chunks_exact_mut(s) {
            // An unseen frame has density 1 under every state.
            let lc = self.ahead.step(&self.hsmm, &self.zeros, row);
            if lc == f64::NEG_INFINITY {
                // Every segment must have ended and none can follow: the
                // model says the interaction is over.
                row.fill(0.0);
            }
        }
        Ok(())
    }

    /// The current belief `h_t` (the initial distribution before the first frame).
    pub fn belief(&self) -> &[f64] {
        &self.belief
    }

    /// `log p(x_{≤t})` of the frames seen so far (the current segment right-censored).
    pub fn log_likelihood(&self) -> f64 {
        self.log_likelihood
    }

    /// Number of frames taken.
    pub fn frames_seen(&self) -> usize {
        self.frames
    }

    /// Forgets all frames (a new demonstration begins).
    pub fn reset(&mut self) {
        self.belief.copy_from_slice(&self.hsmm.start);
        self.core.reset(&self.hsmm);
        self.log_likelihood = 0.0;
        self.frames = 0;
    }
}

impl<E: Emission, D: Duration> Hsmm<E, D> {
    /// An online filter over this model.
    pub fn filter(&self) -> HsmmFilter<E, D> {
        HsmmFilter::new(self.clone())
    }
}
