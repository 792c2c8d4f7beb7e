//! Mixtures of conditionals: GMR weighted by GMM responsibilities or by the HMM
//! forward variable, batch and frame by frame.
//!
//! With weights `h_k` (responsibilities of the input marginal, or the forward
//! variable `h_t` of the input-marginal HMM), per-state conditional means
//! `m_k(x) = μ_k^o + R_k (x − μ_k^i)` and covariances `C_k`:
//! mean `m = Σ_k h_k m_k(x)` and the moment-matched covariance
//! `Σ_k h_k (C_k + (m_k − m)(m_k − m)ᵀ)` (within-state covariance plus the
//! spread of the state means).
//!
//! Missing inputs: a NaN in an input frame means "not observed". The weights
//! then come from the marginal of the observed inputs (the emissions handle
//! that), and each state's conditional is taken on the observed inputs only,
//! `μ_o + Σ_{o,i'} Σ_{i'i'}⁻¹ (x_{i'} − μ_{i'})` over the observed subset `i'`
//! (the outputs' marginal when nothing is observed). These conditionals are
//! built once per missing pattern and cached by the batch and online predictors.
//!
//! Frames no state can explain: a frame whose input density is zero under
//! every state the belief allows (in floating point: a value so far from every
//! state, e.g. `1e200`, that its log-density is `−inf`) would zero the forward
//! variable and, with it, every later prediction. Such a frame is *rejected*:
//! reported in [`Prediction::rejected`] (online: [`FrameEvidence::rejected`]),
//! and taken as not observed — the belief takes its transition step only and
//! the outputs are predicted from the outputs' marginals — so that the next
//! frames are predicted exactly as if its inputs had been missing.
//!
//! Evidence: every prediction also carries the log predictive density of each
//! frame's observed inputs, `log p(x_t | x_{1:t−1})` under the HMM (the forward
//! normaliser `log c_t`) or `log p(x_t)` under the mixture: 0 for a frame with
//! nothing observed, `−inf` for a rejected one. A caller compares it with what
//! the training data gave to tell input unlike the training demonstrations.

use crate::conditional::check_io;
use crate::conditional::Conditional as GaussianConditional;
use crate::error::Result;
use phasekit_emission::{
    Conditional, ConditionalSplit, Emission, EmissionError, Frames, Gaussian, Marginal,
};
use phasekit_gmm::Gmm;
use phasekit_hmm::{ForwardFilter, Hmm, HmmError};
use std::collections::HashMap;

/// Predicted outputs of a sequence.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct Prediction {
    /// Number of output dims `O`.
    pub n_out: usize,
    /// Predicted means, `T × O` row-major.
    pub mean: Vec<f64>,
    /// Predictive covariances, `T × O × O` row-major, when requested.
    pub covariance: Option<Vec<f64>>,
    /// The weights used at every frame, `T × K` row-major.
    pub weights: Vec<f64>,
    /// Per frame, the log predictive density of its observed inputs:
    /// `log p(x_t | x_{1:t−1})` (HMM-GMR) or `log p(x_t)` (static GMR); 0 when
    /// nothing is observed, `−inf` for a rejected frame.
    pub log_predictive: Vec<f64>,
    /// Frames whose inputs have density zero under every state the belief
    /// allowed, in order: each was taken as not observed (see the module
    /// documentation).
    pub rejected: Vec<usize>,
}

/// What one frame told about its inputs (online prediction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameEvidence {
    /// `log p(x_t | x_{1:t−1})` of the frame's observed inputs (static GMR:
    /// `log p(x_t)`); 0 when nothing is observed, `−inf` when rejected.
    pub log_predictive: f64,
    /// The frame's inputs had density zero under every state the belief
    /// allowed, and the frame was taken as not observed.
    pub rejected: bool,
}

impl FrameEvidence {
    /// Before any frame: nothing observed, nothing rejected.
    pub const NONE: FrameEvidence = FrameEvidence {
        log_predictive: 0.0,
        rejected: false,
    };
}

/// The conditionals of every state of a joint emission `E` (any emission
/// with [`Conditional`]: Gaussian, Student-t, mixtures of either, a
/// plug-in's), for one `(input, output)` split.
///
/// Each state's conditional is the emission's own ([`Conditional::conditional`]):
/// for Gaussian states `μ_o + Σ_oi Σ_ii⁻¹ (x_i − μ_i)` and `Σ_oo − Σ_oi Σ_ii⁻¹ Σ_io`;
/// for Student-t states the same mean and `(ν + δ)/(ν + |I| − 2)` times that
/// covariance (the conditional is a Student-t with `ν + |I|` degrees of
/// freedom; `δ` the input's Mahalanobis distance); for a mixture per state the
/// moment-matched mixture of its components' conditionals.
#[derive(Debug, Clone)]
pub struct Regression<E: Conditional = Gaussian> {
    input: Vec<usize>,
    output: Vec<usize>,
    /// The joint emission, from which the conditionals on a subset of the
    /// inputs are built when some inputs are missing.
    joint: E,
    /// The conditionals on every input.
    split: E::Split,
}

impl<E: Conditional> Regression<E> {
    /// Conditions every state of `joint` on `input`, predicting `output`.
    pub fn new(joint: &E, input: &[usize], output: &[usize]) -> Result<Self> {
        check_io(input, output, joint.dim())?;
        let split = joint.conditional(input, output)?;
        Ok(Regression {
            input: input.to_vec(),
            output: output.to_vec(),
            joint: joint.clone(),
            split,
        })
    }

    /// The conditionals on the observed (non-NaN) values of the input frame
    /// `x_in` only: the emission's conditional on that subset of the input
    /// dims, the outputs' marginals when no input is observed.
    fn for_observed(&self, x_in: &[f64]) -> Result<E::Split> {
        let observed: Vec<usize> = self
            .input
            .iter()
            .zip(x_in)
            .filter(|(_, v)| !v.is_nan())
            .map(|(&k, _)| k)
            .collect();
        Ok(self.joint.conditional(&observed, &self.output)?)
    }

    /// Input dims of the joint model.
    pub fn input(&self) -> &[usize] {
        &self.input
    }

    /// Output dims of the joint model.
    pub fn output(&self) -> &[usize] {
        &self.output
    }

    /// The joint emission the conditionals come from.
    pub fn joint(&self) -> &E {
        &self.joint
    }

    /// Number of states `K`.
    pub fn n_states(&self) -> usize {
        self.split.n_states()
    }

    /// Number of outputs `O`.
    pub fn n_out(&self) -> usize {
        self.output.len()
    }

    /// Mixes the conditionals at input `x_in` (length `I`) with weights `h` (length `K`)
    /// into `mean` (length `O`) and, if given, `cov` (`O × O`). `scratch` must hold
    /// `K × O` values. States with zero weight are skipped.
    ///
    /// A buffer of the wrong length is an error and nothing is written.
    /// Missing inputs (NaN) are conditioned out (see the module documentation).
    /// This convenience call copies the conditionals (and builds those of a
    /// missing pattern) on every call; a loop over frames uses a [`Mixer`],
    /// which does neither.
    #[inline]
    pub fn mix_into(
        &self,
        x_in: &[f64],
        h: &[f64],
        mean: &mut [f64],
        cov: Option<&mut [f64]>,
        scratch: &mut [f64],
    ) -> Result<()> {
        self.mixer().mix(self, x_in, h, mean, cov, scratch)
    }

    /// A mixer for this regression: mixes frame after frame without
    /// allocating (a missing pattern's conditionals are built once, when the
    /// pattern is first seen).
    pub fn mixer(&self) -> Mixer<E> {
        let (k, o) = (self.n_states(), self.n_out());
        Mixer {
            full: self.split.clone(),
            map: HashMap::new(),
            key: Vec::new(),
            observed: Vec::new(),
            covariances: vec![0.0; k * o * o],
        }
    }

    fn check_buffers(
        &self,
        x_in: &[f64],
        h: &[f64],
        mean: &[f64],
        cov: Option<&[f64]>,
        scratch: &[f64],
    ) -> Result<()> {
        let (k, o) = (self.n_states(), self.n_out());
        check_len("GMR input frame", self.input.len(), x_in.len())?;
        check_len("GMR weights", k, h.len())?;
        check_len("GMR mean buffer", o, mean.len())?;
        check_len("GMR scratch buffer", k * o, scratch.len())?;
        if let Some(c) = cov {
            check_len("GMR covariance buffer", o * o, c.len())?;
        }
        Ok(())
    }

    /// Mixes over a whole sequence with per-frame weights (`T × K`); the
    /// evidence is passed through.
    fn mix_sequence(
        &self,
        frames: Frames<'_>,
        weights: Vec<f64>,
        with_covariance: bool,
        log_predictive: Vec<f64>,
        rejected: Vec<usize>,
    ) -> Result<Prediction> {
        let (k, o, t) = (self.n_states(), self.n_out(), frames.len());
        let mut mean = vec![0.0; t * o];
        let mut cov = with_covariance.then(|| vec![0.0; t * o * o]);
        let mut scratch = vec![0.0; k * o];
        let mut mixer = self.mixer();
        for (tt, x) in frames.iter().enumerate() {
            let c = cov.as_mut().map(|c| &mut c[tt * o * o..(tt + 1) * o * o]);
            mixer.mix(
                self,
                x,
                &weights[tt * k..(tt + 1) * k],
                &mut mean[tt * o..(tt + 1) * o],
                c,
                &mut scratch,
            )?;
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
}

impl Regression<Gaussian> {
    /// The per-state conditionals of a Gaussian joint model, as the
    /// reference [`GaussianConditional`] computes them (the regression itself uses
    /// the emission's [`phasekit_emission::GaussianSplit`], equal to these to
    /// the last bit; `gmr/tests/generic.rs` holds them to it).
    pub fn conditionals(&self) -> Vec<GaussianConditional> {
        (0..self.joint.n_states())
            .map(|k| {
                GaussianConditional::new(
                    self.joint.mean(k),
                    &self.joint.covariance(k),
                    &self.input,
                    &self.output,
                    k,
                )
                .expect("conditioned once already by Regression::new")
            })
            .collect()
    }
}

/// Mixes the conditionals of a [`Regression`] frame after frame: its own copy
/// of the conditionals (evaluating them needs scratch space), those on the
/// observed inputs cached by missing pattern, and buffers — no allocation per
/// frame once a pattern has been seen.
#[derive(Debug, Clone)]
pub struct Mixer<E: Conditional = Gaussian> {
    full: E::Split,
    map: HashMap<Vec<bool>, E::Split>,
    key: Vec<bool>,
    observed: Vec<f64>,
    /// Per state, the conditional covariance at the current input, `K × O × O`.
    covariances: Vec<f64>,
}

/// Patterns held before the cache is emptied (bounds its memory).
const PATTERN_CAPACITY: usize = 1024;

impl<E: Conditional> Mixer<E> {
    /// [`Regression::mix_into`] with this mixer's conditionals (`base` must be
    /// the regression the mixer was made by).
    #[inline]
    pub fn mix(
        &mut self,
        base: &Regression<E>,
        x_in: &[f64],
        h: &[f64],
        mean: &mut [f64],
        cov: Option<&mut [f64]>,
        scratch: &mut [f64],
    ) -> Result<()> {
        base.check_buffers(x_in, h, mean, cov.as_deref(), scratch)?;
        if !x_in.iter().any(|v| v.is_nan()) {
            return mix_unchecked(
                &mut self.full,
                x_in,
                h,
                mean,
                cov,
                scratch,
                &mut self.covariances,
            );
        }
        self.key.clear();
        self.key.extend(x_in.iter().map(|v| v.is_nan()));
        if !self.map.contains_key(self.key.as_slice()) {
            if self.map.len() >= PATTERN_CAPACITY {
                self.map.clear();
            }
            let r = base.for_observed(x_in)?;
            self.map.insert(self.key.clone(), r);
        }
        self.observed.clear();
        self.observed
            .extend(x_in.iter().copied().filter(|v| !v.is_nan()));
        let split = self
            .map
            .get_mut(self.key.as_slice())
            .expect("inserted above");
        mix_unchecked(
            split,
            &self.observed,
            h,
            mean,
            cov,
            scratch,
            &mut self.covariances,
        )
    }
}

/// Mixes the conditionals `split` at the complete input `x_in` with weights
/// `h` into `mean` and `cov` (buffers checked by the caller): the mean
/// `m = Σ_k h_k m_k(x)` and the moment-matched covariance
/// `Σ_k h_k (C_k(x) + (m_k − m)(m_k − m)ᵀ)`.
#[inline]
fn mix_unchecked<S: ConditionalSplit>(
    split: &mut S,
    x_in: &[f64],
    h: &[f64],
    mean: &mut [f64],
    cov: Option<&mut [f64]>,
    scratch: &mut [f64],
    covariances: &mut [f64],
) -> Result<()> {
    let o = mean.len();
    mean.fill(0.0);
    for (k, ((hk, mk), ck)) in h
        .iter()
        .zip(scratch.chunks_exact_mut(o))
        .zip(covariances.chunks_exact_mut(o * o))
        .enumerate()
    {
        if *hk == 0.0 {
            continue;
        }
        split.predict(k, x_in, mk, ck)?;
        for (m, v) in mean.iter_mut().zip(mk.iter()) {
            *m += hk * v;
        }
    }
    if let Some(cov) = cov {
        cov.fill(0.0);
        for ((hk, mk), ck) in h
            .iter()
            .zip(scratch.chunks_exact(o))
            .zip(covariances.chunks_exact(o * o))
        {
            if *hk == 0.0 {
                continue;
            }
            for r in 0..o {
                let dr = mk[r] - mean[r];
                for q in 0..o {
                    cov[r * o + q] += hk * (ck[r * o + q] + dr * (mk[q] - mean[q]));
                }
            }
        }
    }
    Ok(())
}

/// Errors unless a buffer has length `expected`.
fn check_len(context: &'static str, expected: usize, found: usize) -> Result<()> {
    if expected == found {
        Ok(())
    } else {
        Err(EmissionError::DimensionMismatch {
            context,
            expected,
            found,
        }
        .into())
    }
}

/// Static GMR: weights are the responsibilities of the input marginal of a GMM,
/// `h_k(x_i) = π_k N(x_i; μ_k^i, Σ_k^ii) / Σ_j π_j N(x_i; μ_j^i, Σ_j^ii)`.
#[derive(Debug, Clone)]
pub struct GmmRegression<E: Conditional + Marginal = Gaussian> {
    regression: Regression<E>,
    input_model: Gmm<E>,
}

impl<E: Conditional + Marginal> GmmRegression<E> {
    /// Regression of `output` on `input` under the joint mixture `gmm`.
    pub fn new(gmm: &Gmm<E>, input: &[usize], output: &[usize]) -> Result<Self> {
        let regression = Regression::new(gmm.components(), input, output)?;
        Ok(GmmRegression {
            regression,
            input_model: gmm.marginal(input)?,
        })
    }

    /// The conditionals.
    pub fn regression(&self) -> &Regression<E> {
        &self.regression
    }

    /// The mixture on the input dims, whose responsibilities weigh the conditionals.
    pub fn input_model(&self) -> &Gmm<E> {
        &self.input_model
    }

    /// Responsibilities of the frames' log-densities `row` (length `K`, each
    /// `log c_k(x_t)`), in place; returns `log p(x_t)`. A frame no component
    /// explains (`−inf`) gets the weights of a frame with nothing observed
    /// (the prior `π`) and is reported by the return value `−inf`.
    fn responsibilities_in_place(&self, row: &mut [f64]) -> f64 {
        let lse = self.normalise(row);
        if lse == f64::NEG_INFINITY {
            // log c_k = 0 for every k: the same arithmetic as a missing frame.
            row.fill(0.0);
            self.normalise(row);
        }
        lse
    }

    /// `row_k ← π_k e^{row_k} / Σ_j π_j e^{row_j}`; returns the log of the denominator.
    fn normalise(&self, row: &mut [f64]) -> f64 {
        for (w, pi) in row.iter_mut().zip(self.input_model.weights()) {
            *w += if *pi > 0.0 {
                pi.ln()
            } else {
                f64::NEG_INFINITY
            };
        }
        let lse = phasekit_emission::linalg::log_sum_exp(row);
        if lse == f64::NEG_INFINITY {
            row.fill(0.0);
        } else {
            row.iter_mut().for_each(|w| *w = (*w - lse).exp());
        }
        lse
    }

    /// Predicts the outputs of every frame of `input_frames` (input dims only, in `input` order).
    ///
    /// A frame that no component explains is rejected (see the module documentation):
    /// weighted by the prior `π` and predicted from the outputs' marginals.
    pub fn predict(&self, input_frames: Frames<'_>, with_covariance: bool) -> Result<Prediction> {
        self.input_model.check_frames(input_frames)?;
        let (k, d) = (self.regression.n_states(), input_frames.dim());
        let mut weights = vec![0.0; input_frames.len() * k];
        self.input_model
            .components()
            .log_density_into(input_frames, &mut weights)?;
        let mut log_predictive = Vec::with_capacity(input_frames.len());
        let mut rejected = Vec::new();
        for (t, row) in weights.chunks_exact_mut(k).enumerate() {
            let lse = self.responsibilities_in_place(row);
            if lse == f64::NEG_INFINITY {
                rejected.push(t);
            }
            log_predictive.push(lse);
        }
        if rejected.is_empty() {
            return self.regression.mix_sequence(
                input_frames,
                weights,
                with_covariance,
                log_predictive,
                rejected,
            );
        }
        let inputs = without_frames(input_frames, &rejected);
        self.regression.mix_sequence(
            Frames::new(&inputs, d)?,
            weights,
            with_covariance,
            log_predictive,
            rejected,
        )
    }

    /// Predicts one frame without allocating: `weights` (length `K`) receives the
    /// responsibilities, `mean` (`O`) and optionally `cov` (`O × O`) the prediction;
    /// `scratch` must hold `K × O` values. Returns the frame's evidence; a
    /// rejected frame is predicted as [`GmmRegression::predict`] does.
    pub fn predict_one_into(
        &self,
        input_frame: &[f64],
        weights: &mut [f64],
        mean: &mut [f64],
        cov: Option<&mut [f64]>,
        scratch: &mut [f64],
    ) -> Result<FrameEvidence> {
        let frame = Frames::new(input_frame, self.regression.input().len())?;
        self.input_model
            .components()
            .log_density_into(frame, weights)?;
        let lse = self.responsibilities_in_place(weights);
        let rejected = lse == f64::NEG_INFINITY;
        if rejected {
            // Taken as not observed: the outputs' marginals. (This exceptional
            // path builds the conditionals of the all-missing pattern, allocating.)
            let nothing = vec![f64::NAN; input_frame.len()];
            self.regression
                .mix_into(&nothing, weights, mean, cov, scratch)?;
        } else {
            self.regression
                .mix_into(input_frame, weights, mean, cov, scratch)?;
        }
        Ok(FrameEvidence {
            log_predictive: lse,
            rejected,
        })
    }
}

/// A copy of `frames` with the frames `drop` (sorted) set to missing (NaN).
fn without_frames(frames: Frames<'_>, drop: &[usize]) -> Vec<f64> {
    let d = frames.dim();
    let mut out = frames.as_slice().to_vec();
    for &t in drop {
        out[t * d..(t + 1) * d].fill(f64::NAN);
    }
    out
}

/// HMM-based GMR: weights are the forward variable `h_t` of the input-marginal HMM,
/// i.e. the belief from the input (the human's) frames `x^i_{1:t}` alone.
#[derive(Debug, Clone)]
pub struct HmmRegression<E: Conditional + Marginal = Gaussian> {
    regression: Regression<E>,
    input_model: Hmm<E>,
}

impl<E: Conditional + Marginal> HmmRegression<E> {
    /// Regression of `output` on `input` under the joint HMM `hmm`.
    pub fn new(hmm: &Hmm<E>, input: &[usize], output: &[usize]) -> Result<Self> {
        let regression = Regression::new(hmm.emission(), input, output)?;
        Ok(HmmRegression {
            regression,
            input_model: hmm.marginal(input)?,
        })
    }

    /// The conditionals.
    pub fn regression(&self) -> &Regression<E> {
        &self.regression
    }

    /// The HMM on the input dims.
    pub fn input_model(&self) -> &Hmm<E> {
        &self.input_model
    }

    /// Predicts a whole sequence (input dims only, in `input` order), causally:
    /// frame `t` uses `x^i_{1:t}` only.
    ///
    /// A frame that no state the belief allows can explain is rejected (see the
    /// module documentation): the frames are then filtered one by one with the
    /// online filter, which agrees with the batch forward pass to the last bit,
    /// so every other frame is predicted exactly as with that frame missing.
    pub fn predict(&self, input_frames: Frames<'_>, with_covariance: bool) -> Result<Prediction> {
        let forward = self.input_model.forward(input_frames)?;
        if forward
            .log_normalisers()
            .iter()
            .all(|l| *l > f64::NEG_INFINITY)
        {
            return self.regression.mix_sequence(
                input_frames,
                forward.filtered().to_vec(),
                with_covariance,
                forward.log_normalisers().to_vec(),
                Vec::new(),
            );
        }
        let (k, d) = (self.regression.n_states(), input_frames.dim());
        let mut filter = self.input_model.filter();
        let nothing = vec![f64::NAN; d];
        let mut weights = Vec::with_capacity(input_frames.len() * k);
        let mut log_predictive = Vec::with_capacity(input_frames.len());
        let mut rejected = Vec::new();
        for (t, x) in input_frames.iter().enumerate() {
            let e = filter_step(&mut filter, x, &nothing)?;
            if e.rejected {
                rejected.push(t);
            }
            log_predictive.push(e.log_predictive);
            weights.extend_from_slice(filter.belief());
        }
        let inputs = without_frames(input_frames, &rejected);
        self.regression.mix_sequence(
            Frames::new(&inputs, d)?,
            weights,
            with_covariance,
            log_predictive,
            rejected,
        )
    }

    /// A frame-by-frame predictor for a control loop.
    pub fn online(&self) -> OnlineRegression<E> {
        let (k, o) = (self.regression.n_states(), self.regression.n_out());
        OnlineRegression {
            filter: self.input_model.filter(),
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

/// One step of the forward filter with rejection: a frame impossible under
/// every state the belief allows is replaced by `nothing` (every input
/// missing), so that the belief takes its transition step only. The log
/// predictive density is the increment of the filter's running
/// log-likelihood (exact to the rounding of that sum).
fn filter_step<E: Marginal>(
    filter: &mut ForwardFilter<E>,
    x: &[f64],
    nothing: &[f64],
) -> Result<FrameEvidence> {
    let before = filter.log_likelihood();
    match filter.step(x) {
        Ok(_) => Ok(FrameEvidence {
            log_predictive: filter.log_likelihood() - before,
            rejected: false,
        }),
        Err(HmmError::ImpossibleSequence { .. }) => {
            // The belief is unchanged by the refused frame: step on nothing observed.
            filter.step(nothing)?;
            Ok(FrameEvidence {
                log_predictive: f64::NEG_INFINITY,
                rejected: true,
            })
        }
        Err(e) => Err(e.into()),
    }
}

/// Online HMM-GMR: one input frame in, the predicted output (mean and
/// covariance) out; no allocation per frame (a frame with missing inputs, NaN,
/// builds its pattern's conditionals the first time that pattern is seen).
///
/// A frame of the wrong length or with an infinite value is an error and
/// leaves the belief unchanged; a frame that no state explains is rejected
/// (taken as not observed, see the module documentation) and reported by
/// [`OnlineRegression::evidence`].
#[derive(Debug, Clone)]
pub struct OnlineRegression<E: Conditional + Marginal = Gaussian> {
    filter: ForwardFilter<E>,
    regression: Regression<E>,
    mixer: Mixer<E>,
    /// An input frame with nothing observed.
    nothing: Vec<f64>,
    mean: Vec<f64>,
    covariance: Vec<f64>,
    scratch: Vec<f64>,
    evidence: FrameEvidence,
}

impl<E: Conditional + Marginal> OnlineRegression<E> {
    /// Takes input frame `x^i_t`, updates the belief and returns the predicted output mean.
    pub fn step(&mut self, input_frame: &[f64]) -> Result<&[f64]> {
        self.step_inner(input_frame, false)
    }

    /// Like [`OnlineRegression::step`], also computing the predictive covariance
    /// (read it with [`OnlineRegression::covariance`]).
    pub fn step_with_covariance(&mut self, input_frame: &[f64]) -> Result<&[f64]> {
        self.step_inner(input_frame, true)
    }

    fn step_inner(&mut self, input_frame: &[f64], with_covariance: bool) -> Result<&[f64]> {
        let evidence = filter_step(&mut self.filter, input_frame, &self.nothing)?;
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
        Ok(&self.mean)
    }

    /// What the last step's frame told about its inputs: its log predictive
    /// density and whether it was rejected.
    pub fn evidence(&self) -> FrameEvidence {
        self.evidence
    }

    /// The predictive covariance of the last [`OnlineRegression::step_with_covariance`], `O × O`.
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

    /// `log p(x^i_{1:t})` of the input frames seen so far.
    pub fn log_likelihood(&self) -> f64 {
        self.filter.log_likelihood()
    }

    /// Starts a new sequence.
    pub fn reset(&mut self) {
        self.filter.reset();
        self.evidence = FrameEvidence::NONE;
    }
}
