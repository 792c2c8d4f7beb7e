//! Online recognition with one filter per action: which interaction is the
//! human starting, and what should the robot do?
//!
//! Every action's own online predictor runs on each human frame (the forward
//! filter on the human marginal of its HMM and its GMR); the filter's
//! normalisers are the predictive likelihoods, so after `t` frames
//!
//! `p(a | o¹_{1:t}) = p(a) exp ℓ_a(t) / Σ_b p(b) exp ℓ_b(t)`, with
//! `ℓ_a(t) = log p(o¹_{1:t} | λ_a) = Σ_{s ≤ t} log c^a_s` ([`action_posterior`]);
//! the library may temper it, `ℓ_a / τ` in place of `ℓ_a`
//! ([`crate::library::Calibration::temperature`]; `τ = 1` by default).
//!
//! The decision is the most probable action, or *unknown* while the
//! [`Rejection`] test rejects the motion. The robot's prediction is the most
//! probable action's GMR (`PredictionMode::MostProbable`) or the
//! posterior-weighted mixture of every action's prediction
//! (`PredictionMode::Mixture`), `m = Σ_a p_a m_a` with the moment-matched
//! covariance `Σ_a p_a (C_a + (m_a − m)(m_a − m)ᵀ)` ([`mix_predictions`]); while
//! the motion is rejected, the robot keeps still: it predicts the library's
//! rest pose (with the rest state's robot covariance).
//!
//! For continuous streams, `#reset`-style resets start every filter again;
//! [`AutoReset`] does it when the decided action's filter believes its
//! interaction has ended: its belief has left its end states (the states where
//! its training demonstrations ended) and come back to them. No allocation per frame.

use crate::error::{check_frame, RecognitionError, Result};
use crate::library::Library;
use crate::parts::ActionTrack;
use crate::rejection::Rejection;
use phasekit_emission::Gaussian;
use phasekit_hmm::ForwardFilter;
use serde::{Deserialize, Serialize};

/// What the recogniser decided after a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Decision {
    /// The action of this index in the library.
    Action(usize),
    /// The motion is none of the library's actions (rejected).
    Unknown,
    /// The human is at rest between interactions (composed HMM only).
    Rest,
}

impl Decision {
    /// The action, if one was decided.
    pub fn action(self) -> Option<usize> {
        match self {
            Decision::Action(a) => Some(a),
            Decision::Unknown | Decision::Rest => None,
        }
    }
}

/// How the robot's prediction is made from the actions' predictions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PredictionMode {
    /// The most probable action's GMR.
    MostProbable,
    /// The posterior-weighted mixture of every action's GMR.
    Mixture,
}

impl PredictionMode {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            PredictionMode::MostProbable => "most-probable",
            PredictionMode::Mixture => "mixture",
        }
    }
}

/// Automatic resets for continuous streams: every filter starts again after a
/// frame where the decided action's belief on its end states reaches
/// `end_probability`, having been below it since the last reset, at least
/// `min_frames` frames after the last reset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AutoReset {
    /// Reset when the decided action's belief on its end states reaches this.
    pub end_probability: f64,
    /// …and at least this many frames have passed since the last reset.
    pub min_frames: usize,
}

impl Default for AutoReset {
    /// 0.5 and 15 frames (0.5 s at 30 Hz).
    fn default() -> Self {
        AutoReset {
            end_probability: 0.5,
            min_frames: 15,
        }
    }
}

/// How a [`Recogniser`] decides and predicts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct RecogniserSettings {
    /// The robot's prediction.
    pub prediction: PredictionMode,
    /// The test that rejects unknown motions.
    pub rejection: Rejection,
    /// Compute the predictive covariance every frame.
    pub with_covariance: bool,
    /// Reset automatically when an interaction ends (continuous streams).
    pub auto_reset: Option<AutoReset>,
    /// Also run the threshold model when the rejection test does not need it,
    /// so that [`Recogniser::statistics`] reports both statistics.
    pub both_statistics: bool,
}

impl Default for RecogniserSettings {
    /// Mixture prediction, likelihood-per-frame rejection, no covariance, no automatic reset.
    fn default() -> Self {
        RecogniserSettings {
            prediction: PredictionMode::Mixture,
            rejection: Rejection::LikelihoodPerFrame,
            with_covariance: false,
            auto_reset: None,
            both_statistics: false,
        }
    }
}

/// `p(a | o) ∝ p(a) exp ℓ_a` into `out` from `log p(a)` and `ℓ_a` (an action
/// with `ℓ_a = −inf` gets 0; all zero if every action has). Returns the log
/// normaliser `log Σ_a p(a) exp ℓ_a`.
pub fn action_posterior(log_prior: &[f64], log_likelihood: &[f64], out: &mut [f64]) -> f64 {
    let mut top = f64::NEG_INFINITY;
    for ((o, p), l) in out.iter_mut().zip(log_prior).zip(log_likelihood) {
        *o = p + l;
        top = top.max(*o);
    }
    if top == f64::NEG_INFINITY {
        out.fill(0.0);
        return top;
    }
    let mut total = 0.0;
    for o in out.iter_mut() {
        *o = (*o - top).exp();
        total += *o;
    }
    out.iter_mut().for_each(|o| *o /= total);
    top + total.ln()
}

/// The posterior-weighted mixture of predictions: `means` is `A × O`
/// row-major, `covariances` (if given) `A × O × O`; writes `m = Σ_a p_a m_a`
/// and, with covariances, `Σ_a p_a (C_a + (m_a − m)(m_a − m)ᵀ)`. Actions of
/// weight 0 are skipped.
pub fn mix_predictions(
    weights: &[f64],
    means: &[f64],
    covariances: Option<&[f64]>,
    mean: &mut [f64],
    covariance: Option<&mut [f64]>,
) {
    let o = mean.len();
    mean.fill(0.0);
    for (w, m) in weights.iter().zip(means.chunks_exact(o)) {
        if *w > 0.0 {
            mean.iter_mut().zip(m).for_each(|(x, v)| *x += w * v);
        }
    }
    if let (Some(cs), Some(cov)) = (covariances, covariance) {
        cov.fill(0.0);
        for ((w, m), c) in weights
            .iter()
            .zip(means.chunks_exact(o))
            .zip(cs.chunks_exact(o * o))
        {
            if *w == 0.0 {
                continue;
            }
            for r in 0..o {
                let dr = m[r] - mean[r];
                for q in 0..o {
                    cov[r * o + q] += w * (c[r * o + q] + dr * (m[q] - mean[q]));
                }
            }
        }
    }
}

/// Online recognition over a library with one filter per action (see the
/// module documentation).
#[derive(Debug, Clone)]
pub struct Recogniser {
    tracks: Vec<ActionTrack>,
    log_prior: Vec<f64>,
    prior: Vec<f64>,
    alive: Vec<bool>,
    failed: Vec<bool>,
    log_likelihood: Vec<f64>,
    scaled: Vec<f64>,
    temperature: f64,
    posterior: Vec<f64>,
    threshold: Option<ForwardFilter<Gaussian>>,
    threshold_dead: bool,
    settings: RecogniserSettings,
    limits: (Option<f64>, Option<f64>),
    n_human: usize,
    n_out: usize,
    means: Vec<f64>,
    covariances: Vec<f64>,
    robot: Vec<f64>,
    robot_covariance: Vec<f64>,
    rest_pose: Vec<f64>,
    rest_covariance: Vec<f64>,
    end_states: Vec<Vec<usize>>,
    decision: Decision,
    rejected: bool,
    /// The last frame was impossible under every action: taken as not observed.
    frame_rejected: bool,
    /// A human frame with nothing observed.
    nothing: Vec<f64>,
    statistics: (f64, f64),
    frames: usize,
    pending_reset: bool,
    /// The decided action's belief has left its end states since the last reset.
    moved: bool,
    /// Human values observed (not NaN) since the last reset.
    observed: usize,
}

impl Recogniser {
    /// A recogniser over `library`. A rejection test needs its threshold in the
    /// library's calibration.
    pub fn new(library: &Library, settings: RecogniserSettings) -> Result<Self> {
        let roles = library.roles();
        let cal = library.calibration();
        let limits = (cal.likelihood_per_frame, cal.threshold_model);
        let missing = match settings.rejection {
            Rejection::LikelihoodPerFrame => limits.0.is_none(),
            Rejection::ThresholdModel => limits.1.is_none(),
            Rejection::Either => limits.0.is_none() || limits.1.is_none(),
            Rejection::Off => false,
        };
        if missing {
            return Err(RecognitionError::InvalidSetting {
                name: "rejection",
                reason: format!(
                    "the library has no calibrated threshold for the {} test (a held-out demonstration was impossible under its own action's model); use rejection off",
                    settings.rejection.name()
                ),
            });
        }
        if let Some(r) = settings.auto_reset {
            if !(0.0..=1.0).contains(&r.end_probability) {
                return Err(RecognitionError::InvalidSetting {
                    name: "auto_reset",
                    reason: format!(
                        "the end probability must lie in [0, 1], got {}",
                        r.end_probability
                    ),
                });
            }
        }
        let tracks = library
            .actions()
            .iter()
            .map(|a| {
                ActionTrack::new(
                    &a.model,
                    a.recognition.as_ref(),
                    roles,
                    settings.with_covariance,
                )
                .map_err(|e| match e {
                    RecognitionError::Tsc(source) => RecognitionError::Action {
                        action: a.name.clone(),
                        source,
                    },
                    e => e,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let threshold = (matches!(
            settings.rejection,
            Rejection::ThresholdModel | Rejection::Either
        ) || settings.both_statistics)
            .then(|| library.threshold_model().map(|h| h.filter()))
            .transpose()?;
        let (a, o, d) = (library.len(), roles.robot().len(), library.dim());
        let rest = library.rest();
        let rest_covariance = roles
            .robot()
            .iter()
            .flat_map(|&i| {
                roles
                    .robot()
                    .iter()
                    .map(move |&j| rest.covariance[i * d + j])
            })
            .collect();
        let end_states = library
            .actions()
            .iter()
            .map(|a| {
                let top = a.end.iter().copied().fold(0.0, f64::max);
                (0..a.end.len())
                    .filter(|&i| a.end[i] > 0.0 && a.end[i] >= 0.5 * top)
                    .collect()
            })
            .collect();
        let prior = library.prior().to_vec();
        let mut r = Recogniser {
            tracks,
            log_prior: prior.iter().map(|p| p.ln()).collect(),
            prior,
            alive: vec![true; a],
            failed: vec![false; a],
            log_likelihood: vec![0.0; a],
            scaled: vec![0.0; a],
            temperature: cal.temperature,
            posterior: vec![0.0; a],
            threshold,
            threshold_dead: false,
            settings,
            limits,
            n_human: roles.human().len(),
            n_out: o,
            means: vec![0.0; a * o],
            covariances: vec![0.0; a * o * o],
            robot: vec![0.0; o],
            robot_covariance: vec![0.0; o * o],
            rest_pose: library.rest_pose(),
            rest_covariance,
            end_states,
            decision: Decision::Unknown,
            rejected: false,
            frame_rejected: false,
            nothing: vec![f64::NAN; roles.human().len()],
            statistics: (f64::NAN, f64::NAN),
            frames: 0,
            pending_reset: false,
            moved: false,
            observed: 0,
        };
        r.reset();
        Ok(r)
    }

    /// Takes one human frame (the human's features as the library's models see
    /// them; NaN = missing) and returns the decision. A frame impossible
    /// (zero probability) under every action is taken as not observed and
    /// reported by [`Recogniser::frame_rejected`]; under some actions only, it
    /// makes them impossible until the next reset. A frame of the wrong length
    /// is an error that leaves everything as it was.
    pub fn step(&mut self, human: &[f64]) -> Result<Decision> {
        check_frame("human frame", human, self.n_human)?;
        if self.pending_reset {
            self.reset();
        }
        // A track fails on an error, or rejects a frame its model finds
        // impossible (taken as not observed). A frame every action rejects is
        // a glitch: taken as not observed by all (as a single model's stream
        // does). A frame only some reject makes those impossible (p(a | o) = 0)
        // until the next reset.
        let (mut any, mut accepted) = (false, false);
        let mut glitch = true;
        for ((track, alive), failed) in self
            .tracks
            .iter_mut()
            .zip(&self.alive)
            .zip(&mut self.failed)
        {
            if *alive {
                let r = track.step(human);
                *failed = !matches!(r, Ok(false));
                any |= r.is_ok();
                accepted |= !*failed;
                glitch &= matches!(r, Ok(true));
            }
        }
        if !any {
            self.failed.fill(false);
            return Err(RecognitionError::ImpossibleFrame { frame: self.frames });
        }
        self.frame_rejected = glitch && !accepted;
        for (alive, failed) in self.alive.iter_mut().zip(&mut self.failed) {
            if !self.frame_rejected {
                *alive &= !*failed;
            }
            *failed = false;
        }
        if let Some(f) = &mut self.threshold {
            let x = if self.frame_rejected {
                &self.nothing[..]
            } else {
                human
            };
            self.threshold_dead = self.threshold_dead || f.step(x).is_err();
        }
        self.frames += 1;
        let o = self.n_out;
        for (a, track) in self.tracks.iter().enumerate() {
            self.log_likelihood[a] = if self.alive[a] {
                track.log_likelihood()
            } else {
                f64::NEG_INFINITY
            };
            self.means[a * o..(a + 1) * o].copy_from_slice(track.mean());
            if self.settings.with_covariance {
                self.covariances[a * o * o..(a + 1) * o * o].copy_from_slice(track.covariance());
            }
        }
        // p(a | o) ∝ p(a) exp(ℓ_a / τ).
        for (s, l) in self.scaled.iter_mut().zip(&self.log_likelihood) {
            *s = l / self.temperature;
        }
        action_posterior(&self.log_prior, &self.scaled, &mut self.posterior);
        let best = argmax(&self.posterior);
        let top = self
            .log_likelihood
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        if !self.frame_rejected {
            self.observed += human.iter().filter(|v| !v.is_nan()).count();
        }
        let n = self.observed as f64 / self.n_human as f64;
        let versus = match &self.threshold {
            None => f64::NAN,
            Some(_) if self.threshold_dead => f64::INFINITY,
            Some(f) => top - f.log_likelihood(),
        };
        // Nothing observed yet: no evidence either way.
        self.statistics = (if n > 0.0 { top / n } else { f64::NAN }, versus);
        let by_likelihood = self.limits.0.is_some_and(|l| self.statistics.0 < l);
        let by_threshold_model = self.limits.1.is_some_and(|l| self.statistics.1 < l);
        self.rejected = match self.settings.rejection {
            Rejection::Off => false,
            Rejection::LikelihoodPerFrame => by_likelihood,
            Rejection::ThresholdModel => by_threshold_model,
            Rejection::Either => by_likelihood || by_threshold_model,
        };
        self.decision = if self.rejected {
            Decision::Unknown
        } else {
            Decision::Action(best)
        };
        self.predict(best);
        if let Some(r) = self.settings.auto_reset {
            let mass: f64 = self.end_states[best]
                .iter()
                .map(|&i| self.tracks[best].belief()[i])
                .sum();
            // An interaction ends when the belief comes back to the end states
            // after it has left them (a model whose demonstrations start and
            // end at rest has one state for both: being there is not enough).
            self.moved |= mass < r.end_probability;
            self.pending_reset =
                self.moved && self.frames >= r.min_frames && mass >= r.end_probability;
        }
        Ok(self.decision)
    }

    /// The robot's prediction for the frame just taken.
    fn predict(&mut self, best: usize) {
        let (o, cov) = (self.n_out, self.settings.with_covariance);
        if self.rejected {
            self.robot.copy_from_slice(&self.rest_pose);
            if cov {
                self.robot_covariance.copy_from_slice(&self.rest_covariance);
            }
            return;
        }
        match self.settings.prediction {
            PredictionMode::MostProbable => {
                self.robot
                    .copy_from_slice(&self.means[best * o..(best + 1) * o]);
                if cov {
                    self.robot_covariance
                        .copy_from_slice(&self.covariances[best * o * o..(best + 1) * o * o]);
                }
            }
            PredictionMode::Mixture => mix_predictions(
                &self.posterior,
                &self.means,
                cov.then_some(&self.covariances[..]),
                &mut self.robot,
                cov.then_some(&mut self.robot_covariance[..]),
            ),
        }
    }

    /// Starts a new interaction: every filter back to its initial distribution,
    /// the posterior back to the prior, the robot at its rest pose.
    pub fn reset(&mut self) {
        self.tracks.iter_mut().for_each(ActionTrack::reset);
        if let Some(f) = &mut self.threshold {
            f.reset();
        }
        self.threshold_dead = false;
        self.alive.fill(true);
        self.log_likelihood.fill(0.0);
        self.posterior.copy_from_slice(&self.prior);
        self.robot.copy_from_slice(&self.rest_pose);
        self.robot_covariance.copy_from_slice(&self.rest_covariance);
        self.decision = Decision::Action(argmax(&self.prior));
        self.rejected = false;
        self.frame_rejected = false;
        self.statistics = (f64::NAN, f64::NAN);
        self.frames = 0;
        self.pending_reset = false;
        self.moved = false;
        self.observed = 0;
    }

    /// The decision after the last frame.
    pub fn decision(&self) -> Decision {
        self.decision
    }

    /// `p(a | o¹_{1:t})` per action (the prior before the first frame).
    pub fn posterior(&self) -> &[f64] {
        &self.posterior
    }

    /// `ℓ_a(t) = log p(o¹_{1:t} | λ_a)` per action (`−inf` for an action that
    /// found a frame impossible).
    pub fn log_likelihoods(&self) -> &[f64] {
        &self.log_likelihood
    }

    /// The robot's predicted features for the last frame (the rest pose before any).
    pub fn robot(&self) -> &[f64] {
        &self.robot
    }

    /// Its covariance (`O × O`), when the settings ask for covariances.
    pub fn robot_covariance(&self) -> Option<&[f64]> {
        self.settings
            .with_covariance
            .then_some(&self.robot_covariance[..])
    }

    /// Action `a`'s own prediction of the robot's features for the last frame.
    ///
    /// # Panics
    ///
    /// If `a` is not an action of the library (`a >= library.actions().len()`).
    pub fn action_robot(&self, a: usize) -> &[f64] {
        &self.means[a * self.n_out..(a + 1) * self.n_out]
    }

    /// Whether the last frame's motion was rejected as unknown.
    pub fn rejected(&self) -> bool {
        self.rejected
    }

    /// Whether the last frame was impossible under every action (a glitch,
    /// e.g. `1e200`): it was taken as not observed.
    pub fn frame_rejected(&self) -> bool {
        self.frame_rejected
    }

    /// The rejection statistics of the last frame: the best action's
    /// log-likelihood per frame, and its log-likelihood ratio against the
    /// threshold model (NaN when not computed); see [`crate::library::Calibration`].
    pub fn statistics(&self) -> (f64, f64) {
        self.statistics
    }

    /// Whether an automatic reset will happen before the next frame.
    pub fn reset_pending(&self) -> bool {
        self.pending_reset
    }

    /// Frames since the last reset.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Number of human features a frame has.
    pub fn n_human(&self) -> usize {
        self.n_human
    }

    /// Number of robot features predicted.
    pub fn n_out(&self) -> usize {
        self.n_out
    }

    /// The settings.
    pub fn settings(&self) -> &RecogniserSettings {
        &self.settings
    }
}

/// Index of the largest value (the first of ties; 0 for an empty slice).
pub(crate) fn argmax(v: &[f64]) -> usize {
    let mut best = 0;
    for (i, x) in v.iter().enumerate() {
        if *x > v[best] {
            best = i;
        }
    }
    best
}
