//! A library of interactions: one fitted model per action, with the action
//! names, the prior `p(a)`, the rest state and the calibrated rejection
//! thresholds; serialisable, and checked whenever it is built or read.
//!
//! Building it has two steps, so that a library of a subset of the actions
//! (leave one action out) costs no refit:
//!
//! 1. [`FittedAction::fit`] (per action, independent of the others): the
//!    method's fit, the action's exit and end statistics for the composed HMM,
//!    its rest frames, and the held-out likelihood curves of its training
//!    demonstrations (K-fold: each fold's model scores the demonstrations it
//!    did not see) for calibrating the rejection of unknown motions;
//! 2. [`Library::assemble`] (cheap): the prior, the rest state from all
//!    actions' rest frames, and the rejection thresholds from the held-out curves.
//!
//! **Exit and end statistics.** With `γ^n_t(i)` the state posteriors of
//! training demonstration `n` under the action HMM ([`crate::parts::action_hmm`]),
//! the probability of leaving the interaction from state `i` at a frame is
//! `e_i = Σ_n γ^n_{T_n}(i) / Σ_n Σ_t γ^n_t(i)` (the maximum-likelihood rate if
//! every demonstration ends by leaving), and the end distribution is
//! `ε_i = (1/N) Σ_n γ^n_{T_n}(i)`.
//!
//! **Rest state.** The first and last `rest_frames` frames of every training
//! demonstration (the partners stand with their hands down: NuiSI's
//! demonstrations start and end there) give a joint Gaussian (maximum-likelihood
//! mean and covariance, plus `rest_reg · I`). Its robot part is the **rest
//! pose**: what the robot predicts when the motion is rejected as unknown.

use crate::error::{RecognitionError, Result};
use crate::parts::{action_hmm, ActionTrack};
use crate::rejection::{quantile, threshold_hmm};
use phasekit_emission::{Frames, Gaussian, SequenceSet};
use phasekit_hmm::Hmm;
use phasekit_tsc::{FitSummary, Method, Model, Roles};
use serde::{Deserialize, Serialize};

/// Fewest actions a library holds (one action is a single model: no choice to make).
pub const MIN_ACTIONS: usize = 2;

/// The prior `p(a)` over the actions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Prior {
    /// `1/A` for every action.
    Uniform,
    /// In proportion to the training demonstrations of each action.
    Demonstrations,
    /// These weights (positive, one per action in the library's order; normalised).
    Given(Vec<f64>),
}

/// How a library is built.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct LibrarySettings {
    /// The prior over actions.
    pub prior: Prior,
    /// Frames at the start and at the end of every training demonstration that
    /// form the rest state (fewer when a demonstration is shorter than twice this).
    pub rest_frames: usize,
    /// Added to the rest covariance's diagonal (data units², like a method's `reg`).
    pub rest_reg: f64,
    /// Expected frames in rest between two interactions, in the composed HMM
    /// (rest's self-transition is `1 − 1/rest_stay`).
    pub rest_stay: f64,
    /// Folds of the cross-validation that calibrates the rejection thresholds
    /// (clamped to the number of demonstrations); below 2: calibrated on the
    /// training demonstrations themselves (optimistic).
    pub calibration_folds: usize,
    /// Which quantile of the held-out statistics is the threshold (0: the lowest,
    /// so that no held-out known demonstration would have been rejected).
    pub calibration_quantile: f64,
    /// The posterior's temperature `τ` (`p(a | o) ∝ p(a) exp(ℓ_a / τ)`, see
    /// [`Calibration::temperature`]): a value ≥ 1, or `None` to choose it on the
    /// held-out demonstrations (the best log score of their true action).
    pub temperature: Option<f64>,
}

impl Default for LibrarySettings {
    /// Uniform prior; 5 rest frames at each end, `rest_reg = 1e-2`, rest stays
    /// 30 frames (1 s at 30 Hz); thresholds by 4-fold cross-validation at the
    /// lowest held-out value; temperature 1 (Bayes' rule as it is).
    fn default() -> Self {
        LibrarySettings {
            prior: Prior::Uniform,
            rest_frames: 5,
            rest_reg: 1e-2,
            rest_stay: 30.0,
            calibration_folds: 4,
            calibration_quantile: 0.0,
            temperature: Some(1.0),
        }
    }
}

impl LibrarySettings {
    /// Checks every setting.
    pub fn validate(&self) -> Result<()> {
        let bad = |name, reason: String| Err(RecognitionError::InvalidSetting { name, reason });
        if self.rest_frames == 0 {
            return bad("rest_frames", "at least one rest frame is needed".into());
        }
        if !(self.rest_reg.is_finite() && self.rest_reg >= 0.0) {
            return bad(
                "rest_reg",
                format!("must be a finite number ≥ 0, got {}", self.rest_reg),
            );
        }
        if !(self.rest_stay.is_finite() && self.rest_stay >= 1.0) {
            return bad(
                "rest_stay",
                format!(
                    "must be a finite number of frames ≥ 1, got {}",
                    self.rest_stay
                ),
            );
        }
        if !(0.0..=1.0).contains(&self.calibration_quantile) {
            return bad(
                "calibration_quantile",
                format!("must lie in [0, 1], got {}", self.calibration_quantile),
            );
        }
        if let Prior::Given(w) = &self.prior {
            check_weights(w)?;
        }
        if let Some(t) = self.temperature {
            if !(t.is_finite() && t >= 1.0) {
                return bad(
                    "temperature",
                    format!("must be a finite number ≥ 1 (or chosen on held-out demonstrations), got {t}"),
                );
            }
        }
        Ok(())
    }
}

/// Temperatures tried when the temperature is chosen on held-out demonstrations.
pub const TEMPERATURES: [f64; 14] = [
    1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0, 96.0,
];

fn check_weights(w: &[f64]) -> Result<()> {
    if w.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(RecognitionError::InvalidSetting {
            name: "prior",
            reason: format!("every prior weight must be a finite number > 0, got {w:?}"),
        });
    }
    Ok(())
}

/// One held-out demonstration of the calibration: the human's frames and the
/// running log-likelihood `ℓ(1..t)` under the model of a fold that did not see it.
#[derive(Debug, Clone, PartialEq)]
struct HeldOut {
    human: Vec<f64>,
    own: Vec<f64>,
    /// Index in `fold_hmms` of the model that scored it.
    fold: usize,
}

/// One action, fitted and ready to join a library ([`Library::assemble`]).
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct FittedAction {
    /// The action's name.
    pub name: String,
    /// The fitted model (it predicts).
    pub model: Model,
    /// The model whose likelihood recognises the action, when it is not `model`.
    pub recognition: Option<Model>,
    /// What the fit did.
    pub summary: FitSummary,
    /// Training demonstrations.
    pub demonstrations: usize,
    exit: Vec<f64>,
    end: Vec<f64>,
    /// Complete joint rest frames, `n × D`.
    rest_frames: Vec<f64>,
    held_out: Vec<HeldOut>,
    /// Human marginals of the action HMMs of the models that scored `held_out`
    /// (the threshold model of a held-out demonstration takes its action's
    /// states from them, so that it has not seen the demonstration either).
    fold_hmms: Vec<Hmm<Gaussian>>,
    /// Folds whose fit failed (their demonstrations are not in `held_out`).
    failed_folds: usize,
    /// Whether `held_out` holds the training demonstrations scored by the full model.
    in_sample: bool,
    dim: usize,
}

impl FittedAction {
    /// Fits `method` to the action's joint training demonstrations `data` and
    /// computes what the library needs from them (see the module documentation).
    /// With `recognition`, a second model fitted with that method gives the
    /// action's likelihood (and is the one calibrated); `method`'s predicts.
    pub fn fit(
        name: &str,
        data: &SequenceSet,
        method: &Method,
        recognition: Option<&Method>,
        roles: &Roles,
        settings: &LibrarySettings,
    ) -> Result<Self> {
        settings.validate()?;
        if name.trim().is_empty() {
            return Err(RecognitionError::InvalidLibrary(
                "an action needs a non-empty name".into(),
            ));
        }
        let action = |source| RecognitionError::Action {
            action: name.to_string(),
            source,
        };
        roles.check(data.dim()).map_err(action)?;
        let (model, summary) = method.fit(data, roles).map_err(action)?;
        let recognition_model = recognition
            .map(|m| m.fit(data, roles).map(|f| f.0))
            .transpose()
            .map_err(action)?;
        // The method whose likelihood is calibrated.
        let scored = recognition.unwrap_or(method);
        let hmm = action_hmm(&model)?;
        let (exit, end) = exit_and_end(&hmm, data)?;
        let rest_frames = rest_frames(data, settings.rest_frames);
        let n = data.len();
        let folds = settings.calibration_folds.min(n);
        let mut held_out = Vec::new();
        let mut fold_hmms = Vec::new();
        let mut failed_folds = 0;
        let human_hmm =
            |m: &Model| -> Result<Hmm<Gaussian>> { Ok(action_hmm(m)?.marginal(roles.human())?) };
        if folds >= 2 {
            for f in 0..folds {
                let train: Vec<usize> = (0..n).filter(|k| k % folds != f).collect();
                let fold_model = data
                    .subset(&train)
                    .map_err(RecognitionError::from)
                    .and_then(|d| Ok(scored.fit(&d, roles)?.0));
                let Ok(fold_model) = fold_model else {
                    failed_folds += 1;
                    continue;
                };
                for k in (0..n).filter(|k| k % folds == f) {
                    held_out.push(score(&fold_model, roles, data.get(k), fold_hmms.len())?);
                }
                fold_hmms.push(human_hmm(&fold_model)?);
            }
        }
        let in_sample = held_out.is_empty();
        if in_sample {
            let full = recognition_model.as_ref().unwrap_or(&model);
            for k in 0..n {
                held_out.push(score(full, roles, data.get(k), 0)?);
            }
            fold_hmms = vec![human_hmm(full)?];
        }
        Ok(FittedAction {
            name: name.to_string(),
            model,
            recognition: recognition_model,
            summary,
            demonstrations: n,
            exit,
            end,
            rest_frames,
            held_out,
            fold_hmms,
            failed_folds,
            in_sample,
            dim: data.dim(),
        })
    }
}

/// The human's frames of a joint demonstration and their running
/// log-likelihood under `model` (`−inf` from a frame the model finds impossible on).
fn score(model: &Model, roles: &Roles, seq: Frames<'_>, fold: usize) -> Result<HeldOut> {
    let mut track = ActionTrack::new(model, None, roles, false)?;
    let human: Vec<f64> = seq
        .iter()
        .flat_map(|x| roles.human().iter().map(move |&k| x[k]))
        .collect();
    let h = roles.human().len();
    let mut own = Vec::with_capacity(seq.len());
    let mut dead = false;
    for x in human.chunks_exact(h) {
        dead = dead || track.step(x).is_err();
        own.push(if dead {
            f64::NEG_INFINITY
        } else {
            track.log_likelihood()
        });
    }
    Ok(HeldOut { human, own, fold })
}

/// `e_i` and `ε_i` of the module documentation.
fn exit_and_end(hmm: &Hmm<Gaussian>, data: &SequenceSet) -> Result<(Vec<f64>, Vec<f64>)> {
    let s = hmm.n_states();
    let (mut last, mut occupancy) = (vec![0.0; s], vec![0.0; s]);
    for seq in data.iter() {
        let gamma = hmm.posteriors(seq)?.gamma;
        for row in gamma.chunks_exact(s) {
            occupancy.iter_mut().zip(row).for_each(|(o, g)| *o += g);
        }
        let end = &gamma[gamma.len() - s..];
        last.iter_mut().zip(end).for_each(|(l, g)| *l += g);
    }
    let exit = last
        .iter()
        .zip(&occupancy)
        .map(|(l, o)| {
            if *o > 0.0 {
                (l / o).clamp(0.0, 1.0)
            } else {
                0.0
            }
        })
        .collect();
    let total: f64 = last.iter().sum();
    let end = last.iter().map(|l| l / total).collect();
    Ok((exit, end))
}

/// The complete frames among the first and last `k` of every demonstration.
fn rest_frames(data: &SequenceSet, k: usize) -> Vec<f64> {
    let mut out = Vec::new();
    for seq in data.iter() {
        let t = seq.len();
        let idx: Vec<usize> = if t <= 2 * k {
            (0..t).collect()
        } else {
            (0..k).chain(t - k..t).collect()
        };
        for i in idx {
            let x = seq.frame(i);
            if x.iter().all(|v| v.is_finite()) {
                out.extend_from_slice(x);
            }
        }
    }
    out
}

/// One action of a library.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[non_exhaustive]
pub struct LibraryAction {
    /// The action's name.
    pub name: String,
    /// Its fitted model (any method): it predicts, and recognises unless
    /// `recognition` is given.
    pub model: Model,
    /// A second model whose likelihood recognises the action (the prediction stays `model`'s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recognition: Option<Model>,
    /// `e_i`: per state of the action HMM, the probability of leaving the interaction at a frame.
    pub exit: Vec<f64>,
    /// `ε_i`: where the training demonstrations end, per state of the action HMM.
    pub end: Vec<f64>,
    /// Training demonstrations it was fitted to.
    pub demonstrations: usize,
}

/// The rest state: a joint Gaussian over the human's and the robot's features.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct RestState {
    /// Mean (`D`): its robot part is the rest pose.
    pub mean: Vec<f64>,
    /// Covariance, `D × D` row-major (with `rest_reg` on the diagonal).
    pub covariance: Vec<f64>,
    /// Frames it was estimated from.
    pub frames: usize,
    /// Expected frames in rest in the composed HMM.
    pub stay: f64,
}

/// The rejection thresholds and how they were set.
///
/// Statistics at frame `t` (`ℓ_a(t) = log p(o¹_{1:t} | λ_a)`, `ℓ_T(t)` the
/// threshold model's): **likelihood per frame** `max_a ℓ_a(t) / n_t` (nats per
/// frame: the mean log-likelihood of the best action, with `n_t` the frames'
/// worth of observed values, `(observed values)/H`, so that a frame with
/// missing values, whose log-density is its observed values' marginal, counts
/// for what it holds); **threshold model** the
/// log-likelihood ratio `max_a ℓ_a(t) − ℓ_T(t)` (nats: Lee & Kim's test is this
/// ratio against 0; not divided by `t`, so that the evidence of a motion that
/// leaves the known order accumulates rather than being averaged away). A
/// motion is rejected as unknown while its statistic is below the threshold. Each threshold is the `calibration_quantile` of the lowest value
/// (over frames) the statistic takes on every held-out training demonstration;
/// `None` when it cannot be set (a held-out demonstration impossible under its
/// own action's model).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct Calibration {
    /// Threshold of the likelihood-per-frame test (nats per frame).
    pub likelihood_per_frame: Option<f64>,
    /// Threshold of the threshold-model test (nats).
    pub threshold_model: Option<f64>,
    /// Demonstrations the thresholds were set on.
    pub demonstrations: usize,
    /// Whether every action's demonstrations were held out (cross-validation);
    /// `false`: some were scored by the model fitted to them (optimistic).
    pub held_out: bool,
    /// Cross-validation folds whose fit failed (skipped).
    pub failed_folds: usize,
    /// The posterior's temperature `τ ≥ 1`: `p(a | o¹_{1:t}) ∝ p(a) exp(ℓ_a(t) / τ)`.
    /// Consecutive frames are far from independent, so the models' likelihood
    /// ratios overstate the evidence and `τ = 1` is overconfident; `τ` divides
    /// it back. The decision (with a uniform prior) does not depend on it, the
    /// posterior and the mixture's weights do.
    #[serde(default = "one")]
    pub temperature: f64,
    /// Mean log score `(1/N) Σ log p_τ(true action | o¹_{1:t})` of the held-out
    /// frames at that temperature.
    #[serde(default)]
    pub log_score: f64,
}

fn one() -> f64 {
    1.0
}

/// A library of interactions (see the module documentation). Every library,
/// built or read from a file, has been checked: at least two actions with
/// distinct non-empty names, models of one dimension valid for the roles, and
/// parts that agree.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "LibraryParams", into = "LibraryParams")]
pub struct Library {
    actions: Vec<LibraryAction>,
    roles: Roles,
    prior: Vec<f64>,
    rest: RestState,
    calibration: Calibration,
}

/// The serialised form of a [`Library`], checked on the way in.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[non_exhaustive]
pub struct LibraryParams {
    /// The actions.
    pub actions: Vec<LibraryAction>,
    /// The human's and the robot's features.
    pub roles: Roles,
    /// `p(a)`, in the actions' order.
    pub prior: Vec<f64>,
    /// The rest state.
    pub rest: RestState,
    /// The rejection thresholds.
    pub calibration: Calibration,
}

impl From<Library> for LibraryParams {
    fn from(l: Library) -> Self {
        LibraryParams {
            actions: l.actions,
            roles: l.roles,
            prior: l.prior,
            rest: l.rest,
            calibration: l.calibration,
        }
    }
}

impl TryFrom<LibraryParams> for Library {
    type Error = RecognitionError;
    fn try_from(p: LibraryParams) -> Result<Self> {
        let l = Library {
            actions: p.actions,
            roles: p.roles,
            prior: p.prior,
            rest: p.rest,
            calibration: p.calibration,
        };
        l.validate()?;
        Ok(l)
    }
}

fn invalid<T>(msg: String) -> Result<T> {
    Err(RecognitionError::InvalidLibrary(msg))
}

/// Checks names: at least [`MIN_ACTIONS`], non-empty, distinct.
fn check_names<'a>(names: impl Iterator<Item = &'a str>) -> Result<()> {
    let names: Vec<&str> = names.collect();
    if names.len() < MIN_ACTIONS {
        return invalid(format!(
            "a library needs at least {MIN_ACTIONS} actions to choose from, got {} ({}); one action is a single model (fit it without a library)",
            names.len(),
            if names.is_empty() { "none".to_string() } else { names.join(", ") }
        ));
    }
    for (i, a) in names.iter().enumerate() {
        if a.trim().is_empty() {
            return invalid(format!("action {i} has an empty name"));
        }
        if names[..i].contains(a) {
            return invalid(format!("two actions are named `{a}`"));
        }
    }
    Ok(())
}

impl Library {
    /// Fits every action (`(name, joint demonstrations, method)`) and assembles
    /// the library: [`FittedAction::fit`] then [`Library::assemble`]. With
    /// `recognition`, every action also gets a recognition model of that method.
    pub fn fit(
        actions: &[(&str, &SequenceSet, &Method)],
        recognition: Option<&Method>,
        roles: &Roles,
        settings: &LibrarySettings,
    ) -> Result<(Library, Vec<FitSummary>)> {
        settings.validate()?;
        check_names(actions.iter().map(|a| a.0))?;
        check_same_dim(actions.iter().map(|a| (a.0, a.1.dim())))?;
        let fitted = actions
            .iter()
            .map(|(name, data, method)| {
                FittedAction::fit(name, data, method, recognition, roles, settings)
            })
            .collect::<Result<Vec<_>>>()?;
        let library = Library::assemble(&fitted, roles, settings)?;
        Ok((library, fitted.into_iter().map(|f| f.summary).collect()))
    }

    /// A library of fitted actions (any subset of those fitted: leave-one-out
    /// costs no refit): prior, rest state and rejection thresholds.
    pub fn assemble(
        actions: &[FittedAction],
        roles: &Roles,
        settings: &LibrarySettings,
    ) -> Result<Library> {
        settings.validate()?;
        check_names(actions.iter().map(|a| a.name.as_str()))?;
        check_same_dim(actions.iter().map(|a| (a.name.as_str(), a.dim)))?;
        let d = actions[0].dim;
        roles.check(d)?;
        let prior = match &settings.prior {
            Prior::Uniform => vec![1.0 / actions.len() as f64; actions.len()],
            Prior::Demonstrations => {
                let n: usize = actions.iter().map(|a| a.demonstrations).sum();
                actions
                    .iter()
                    .map(|a| a.demonstrations as f64 / n as f64)
                    .collect()
            }
            Prior::Given(w) => {
                if w.len() != actions.len() {
                    return Err(RecognitionError::InvalidSetting {
                        name: "prior",
                        reason: format!("{} weights for {} actions", w.len(), actions.len()),
                    });
                }
                let total: f64 = w.iter().sum();
                w.iter().map(|v| v / total).collect()
            }
        };
        let rest = rest_state(actions, d, settings)?;
        let calibration = calibrate(actions, roles, settings, &prior)?;
        let library = Library {
            actions: actions
                .iter()
                .map(|a| LibraryAction {
                    name: a.name.clone(),
                    model: a.model.clone(),
                    recognition: a.recognition.clone(),
                    exit: a.exit.clone(),
                    end: a.end.clone(),
                    demonstrations: a.demonstrations,
                })
                .collect(),
            roles: roles.clone(),
            prior,
            rest,
            calibration,
        };
        library.validate()?;
        Ok(library)
    }

    /// Checks that the parts agree (every library is checked when built or read).
    pub fn validate(&self) -> Result<()> {
        check_names(self.actions.iter().map(|a| a.name.as_str()))?;
        check_same_dim(
            self.actions
                .iter()
                .map(|a| (a.name.as_str(), a.model.dim())),
        )?;
        let d = self.dim();
        self.roles.check(d)?;
        for a in &self.actions {
            let at = |source| RecognitionError::Action {
                action: a.name.clone(),
                source,
            };
            a.model.validate().map_err(at)?;
            if let Some(r) = &a.recognition {
                r.validate().map_err(at)?;
                if r.dim() != d {
                    return invalid(format!(
                        "action `{}`: its recognition model has {} features, its model {d}",
                        a.name,
                        r.dim()
                    ));
                }
            }
            let s = action_hmm(&a.model)?.n_states();
            if a.exit.len() != s || a.end.len() != s {
                return invalid(format!(
                    "action `{}`: {} exit and {} end probabilities for {s} states",
                    a.name,
                    a.exit.len(),
                    a.end.len()
                ));
            }
            if a.exit
                .iter()
                .chain(&a.end)
                .any(|p| !(0.0..=1.0).contains(p))
            {
                return invalid(format!(
                    "action `{}`: an exit or end probability lies outside [0, 1]",
                    a.name
                ));
            }
            if (a.end.iter().sum::<f64>() - 1.0).abs() > 1e-6 {
                return invalid(format!(
                    "action `{}`: its end probabilities sum to {}, not 1",
                    a.name,
                    a.end.iter().sum::<f64>()
                ));
            }
            if a.demonstrations == 0 {
                return invalid(format!("action `{}`: no training demonstration", a.name));
            }
        }
        if self.prior.len() != self.actions.len()
            || self.prior.iter().any(|p| !(p.is_finite() && *p > 0.0))
            || (self.prior.iter().sum::<f64>() - 1.0).abs() > 1e-8
        {
            return invalid(format!(
                "the prior must hold one positive probability per action ({}), summing to 1; got {:?}",
                self.actions.len(),
                self.prior
            ));
        }
        let r = &self.rest;
        if r.mean.len() != d || r.covariance.len() != d * d {
            return invalid(format!(
                "the rest state has a mean of {} and a covariance of {} values, expected {d} and {}",
                r.mean.len(),
                r.covariance.len(),
                d * d
            ));
        }
        if !(r.stay.is_finite() && r.stay >= 1.0) {
            return invalid(format!(
                "the rest state's expected stay must be ≥ 1 frame, got {}",
                r.stay
            ));
        }
        // Finite, symmetric positive definite (the Gaussian checks it).
        self.rest_gaussian()?;
        let c = &self.calibration;
        if [c.likelihood_per_frame, c.threshold_model]
            .iter()
            .flatten()
            .any(|v| !v.is_finite())
        {
            return invalid("a rejection threshold is not a finite number".into());
        }
        if !(c.temperature.is_finite() && c.temperature >= 1.0) {
            return invalid(format!(
                "the posterior's temperature must be a finite number ≥ 1, got {}",
                c.temperature
            ));
        }
        Ok(())
    }

    /// The actions, in order.
    pub fn actions(&self) -> &[LibraryAction] {
        &self.actions
    }

    /// The actions' names, in order.
    pub fn names(&self) -> Vec<&str> {
        self.actions.iter().map(|a| a.name.as_str()).collect()
    }

    /// Index of the action named `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.actions.iter().position(|a| a.name == name)
    }

    /// Number of actions `A`.
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    /// Always `false` (a library holds at least [`MIN_ACTIONS`] actions).
    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }

    /// The human's (input) and the robot's (output) features.
    pub fn roles(&self) -> &Roles {
        &self.roles
    }

    /// Joint feature dimension `D`.
    pub fn dim(&self) -> usize {
        self.actions[0].model.dim()
    }

    /// `p(a)`.
    pub fn prior(&self) -> &[f64] {
        &self.prior
    }

    /// The rest state.
    pub fn rest(&self) -> &RestState {
        &self.rest
    }

    /// The rest pose: the robot's features of the rest state's mean.
    pub fn rest_pose(&self) -> Vec<f64> {
        self.roles
            .robot()
            .iter()
            .map(|&k| self.rest.mean[k])
            .collect()
    }

    /// The rest state as a one-state joint Gaussian.
    pub fn rest_gaussian(&self) -> Result<Gaussian> {
        Ok(Gaussian::full(
            self.dim(),
            self.rest.mean.clone(),
            self.rest.covariance.clone(),
        )?)
    }

    /// The rejection thresholds.
    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }

    /// The threshold model over every action's human-marginal states (of the
    /// recognition models; see [`crate::rejection::threshold_hmm`]).
    pub fn threshold_model(&self) -> Result<Hmm<Gaussian>> {
        let marginals = self
            .actions
            .iter()
            .map(|a| {
                let m = a.recognition.as_ref().unwrap_or(&a.model);
                Ok(action_hmm(m)?.marginal(self.roles.human())?)
            })
            .collect::<Result<Vec<_>>>()?;
        threshold_hmm(&marginals)
    }

    /// A copy with another prior (same actions, thresholds and rest state).
    pub fn with_prior(&self, prior: &Prior) -> Result<Library> {
        let mut l = self.clone();
        l.prior = match prior {
            Prior::Uniform => vec![1.0 / self.len() as f64; self.len()],
            Prior::Demonstrations => {
                let n: usize = self.actions.iter().map(|a| a.demonstrations).sum();
                self.actions
                    .iter()
                    .map(|a| a.demonstrations as f64 / n as f64)
                    .collect()
            }
            Prior::Given(w) => {
                check_weights(w)?;
                let total: f64 = w.iter().sum();
                w.iter().map(|v| v / total).collect()
            }
        };
        l.validate()?;
        Ok(l)
    }
}

fn check_same_dim<'a>(mut dims: impl Iterator<Item = (&'a str, usize)>) -> Result<()> {
    let Some((first, d)) = dims.next() else {
        return Ok(());
    };
    for (name, e) in dims {
        if e != d {
            return invalid(format!(
                "action `{name}` has {e} features, action `{first}` {d}: every action must be fitted to the same features"
            ));
        }
    }
    Ok(())
}

fn rest_state(actions: &[FittedAction], d: usize, settings: &LibrarySettings) -> Result<RestState> {
    let frames: Vec<&[f64]> = actions
        .iter()
        .flat_map(|a| a.rest_frames.chunks_exact(d))
        .collect();
    if frames.is_empty() {
        return invalid(
            "no complete rest frame (the first and last frames of the training demonstrations all have missing values)".into(),
        );
    }
    let n = frames.len() as f64;
    let mut mean = vec![0.0; d];
    for f in &frames {
        mean.iter_mut().zip(f.iter()).for_each(|(m, v)| *m += v);
    }
    mean.iter_mut().for_each(|m| *m /= n);
    let mut covariance = vec![0.0; d * d];
    for f in &frames {
        for i in 0..d {
            for j in 0..d {
                covariance[i * d + j] += (f[i] - mean[i]) * (f[j] - mean[j]);
            }
        }
    }
    covariance.iter_mut().for_each(|c| *c /= n);
    for i in 0..d {
        covariance[i * d + i] += settings.rest_reg;
    }
    let rest = RestState {
        mean,
        covariance,
        frames: frames.len(),
        stay: settings.rest_stay,
    };
    Gaussian::full(d, rest.mean.clone(), rest.covariance.clone()).map_err(|e| {
        RecognitionError::InvalidLibrary(format!(
            "the rest state ({} frames) has no usable covariance: {e}; increase the rest regularisation",
            frames.len()
        ))
    })?;
    Ok(rest)
}

/// The thresholds and the temperature of [`Calibration`] from the held-out curves.
fn calibrate(
    actions: &[FittedAction],
    roles: &Roles,
    settings: &LibrarySettings,
    prior: &[f64],
) -> Result<Calibration> {
    let marginals = actions
        .iter()
        .map(|a| {
            let m = a.recognition.as_ref().unwrap_or(&a.model);
            Ok(action_hmm(m)?.marginal(roles.human())?)
        })
        .collect::<Result<Vec<_>>>()?;
    let h = roles.human().len();
    let (mut per_frame, mut versus) = (Vec::new(), Vec::new());
    // The threshold model of a held-out demonstration of action `a` takes
    // `a`'s states from the model that did not see it.
    let mut thresholds = Vec::new();
    for (a, action) in actions.iter().enumerate() {
        for fold in &action.fold_hmms {
            let mut parts = marginals.clone();
            parts[a] = fold.clone();
            thresholds.push(threshold_hmm(&parts)?);
        }
    }
    let mut first_fold = 0;
    let held = actions.iter().flat_map(|a| {
        let base = first_fold;
        first_fold += a.fold_hmms.len();
        a.held_out.iter().map(move |h| (base + h.fold, h))
    });
    for (model, held) in held {
        let mut filter = thresholds[model].filter();
        let (mut lo_pf, mut lo_tm) = (f64::INFINITY, f64::INFINITY);
        let mut observed = 0usize;
        let mut dead = false;
        for (x, own) in held.human.chunks_exact(h).zip(&held.own) {
            observed += x.iter().filter(|v| !v.is_nan()).count();
            if observed > 0 {
                lo_pf = lo_pf.min(own / (observed as f64 / h as f64));
            }
            dead = dead || filter.step(x).is_err();
            // A frame impossible under the threshold model cannot count against the action.
            let lt = if dead {
                f64::NEG_INFINITY
            } else {
                filter.log_likelihood()
            };
            let v = if lt == f64::NEG_INFINITY {
                f64::INFINITY
            } else {
                own - lt
            };
            lo_tm = lo_tm.min(v);
        }
        per_frame.push(lo_pf);
        versus.push(lo_tm);
    }
    let (temperature, log_score) = temperature(actions, roles, settings, prior)?;
    let q = settings.calibration_quantile;
    let finite = |v: f64| v.is_finite().then_some(v);
    Ok(Calibration {
        temperature,
        log_score,
        likelihood_per_frame: quantile(&per_frame, q).and_then(finite),
        threshold_model: quantile(&versus, q).and_then(finite),
        demonstrations: per_frame.len(),
        held_out: actions.iter().all(|a| !a.in_sample),
        failed_folds: actions.iter().map(|a| a.failed_folds).sum(),
    })
}

/// The temperature (given, or the best of [`TEMPERATURES`] by the held-out
/// log score) and its mean log score. A held-out demonstration of action `a`
/// is scored by `a`'s fold model and by the other actions' full models, none
/// of which saw it.
fn temperature(
    actions: &[FittedAction],
    roles: &Roles,
    settings: &LibrarySettings,
    prior: &[f64],
) -> Result<(f64, f64)> {
    let h = roles.human().len();
    let n = actions.len();
    let log_prior: Vec<f64> = prior.iter().map(|p| p.ln()).collect();
    // Per held-out demonstration: its action and the running ℓ_b(t) of every action, T × A.
    let mut curves: Vec<(usize, Vec<f64>)> = Vec::new();
    for (a, action) in actions.iter().enumerate() {
        for held in &action.held_out {
            let t = held.own.len();
            let mut ll = vec![0.0; t * n];
            for (b, other) in actions.iter().enumerate() {
                if b == a {
                    (0..t).for_each(|i| ll[i * n + b] = held.own[i]);
                    continue;
                }
                let mut track =
                    ActionTrack::new(&other.model, other.recognition.as_ref(), roles, false)?;
                let mut dead = false;
                for (i, x) in held.human.chunks_exact(h).enumerate() {
                    dead = dead || track.step(x).is_err();
                    ll[i * n + b] = if dead {
                        f64::NEG_INFINITY
                    } else {
                        track.log_likelihood()
                    };
                }
            }
            curves.push((a, ll));
        }
    }
    let score = |tau: f64| {
        let (mut total, mut frames) = (0.0, 0usize);
        let mut scaled = vec![0.0; n];
        let mut p = vec![0.0; n];
        for (a, ll) in &curves {
            for row in ll.chunks_exact(n) {
                scaled.iter_mut().zip(row).for_each(|(s, l)| *s = l / tau);
                crate::recogniser::action_posterior(&log_prior, &scaled, &mut p);
                total += p[*a].max(1e-300).ln();
                frames += 1;
            }
        }
        total / frames.max(1) as f64
    };
    Ok(match settings.temperature {
        Some(t) => (t, score(t)),
        None => {
            TEMPERATURES
                .iter()
                .map(|&t| (t, score(t)))
                .fold((1.0, f64::NEG_INFINITY), |best, x| {
                    if x.1 > best.1 {
                        x
                    } else {
                        best
                    }
                })
        }
    })
}
