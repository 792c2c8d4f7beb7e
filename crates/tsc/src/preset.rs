//! Named methods (presets), fitted models, their predictors and segmentations.
//!
//! * `hmm`: the paper's baseline, an HMM on joint frames with HMM-GMR;
//! * `tsc-hmm`: the paper's TSC-HMM with the default composition (see [`DEFAULT_COMPOSITION`]);
//!   `tsc-hmm-union`, `tsc-hmm-frozen`, `tsc-hmm-gated` and `tsc-hmm-worst`
//!   (λ_T trained on the frames the base predicts worst) name the alternatives;
//! * `gmm-tsc`: Krishnan-style TSC over a GMM; its kept transition clusters join
//!   the GMM's components and static GMR predicts;
//! * `gmm`: static GMR from a GMM.

use crate::detect::{dilate, runs, select, Labeller, ViterbiLabeller};
use crate::error::{Result, TscError};
use crate::krishnan::{KrishnanSettings, KrishnanTsc, Segmentation, TimeClustering};
use crate::select::Selector;
use crate::tsc_hmm::{
    disagreement_flags, AutoStates, Composition, Detector, HmmSettings, Roles, TscHmm, TscSettings,
};
use phasekit_emission::{
    CovarianceType, Emission, Frames, Gaussian, Regularisation, SequenceSet, Shape,
};
use phasekit_gmm::{Em, Gmm};
use phasekit_gmr::{GmmRegression, HmmRegression, OnlineRegression, Prediction};
use phasekit_hmm::Hmm;
use serde::{Deserialize, Serialize};

/// The composition used by the `tsc-hmm` preset.
pub const DEFAULT_COMPOSITION: Composition = Composition::Union;

/// Settings of a static GMM (the `gmm` preset and the base of `gmm-tsc`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GmmSettings {
    /// Components.
    pub components: usize,
    /// `r` added to the covariance diagonals.
    pub reg: f64,
    /// At most this many M-steps.
    pub max_iter: usize,
    /// Tolerance on the mean log-likelihood per frame.
    pub tol: f64,
    /// Runs from k-means++ seeds.
    pub restarts: usize,
    /// Seed.
    pub seed: u64,
}

impl GmmSettings {
    /// Checks the settings: at least one component, iteration and run; finite
    /// non-negative `reg` and `tol`.
    pub fn validate(&self) -> Result<()> {
        if self.components == 0 || self.max_iter == 0 || self.restarts == 0 {
            return Err(TscError::InvalidSetting {
                name: "gmm",
                reason: format!(
                    "components, max_iter and restarts must be ≥ 1, got {}, {} and {}",
                    self.components, self.max_iter, self.restarts
                ),
            });
        }
        if !(self.reg.is_finite() && self.reg >= 0.0 && self.tol.is_finite() && self.tol >= 0.0) {
            return Err(TscError::InvalidSetting {
                name: "gmm",
                reason: format!(
                    "reg and tol must be finite numbers ≥ 0, got {} and {}",
                    self.reg, self.tol
                ),
            });
        }
        Ok(())
    }

    fn em(&self) -> Result<Em> {
        Ok(Em::builder()
            .max_iter(self.max_iter)
            .tol(self.tol)
            .regularisation(Regularisation::add_diagonal(self.reg)?)
            .restarts(self.restarts.max(1))
            .seed(self.seed)
            .build()?)
    }
}

/// A method with all its settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "kebab-case")]
pub enum Method {
    /// HMM on joint frames, HMM-GMR.
    Hmm(HmmSettings),
    /// TSC-HMM.
    TscHmm(TscSettings),
    /// Krishnan-style TSC over a GMM, static GMR over the GMM and the kept transition clusters.
    /// With an automatic frame mixture (`tsc.components = None`) the GMM it extends takes
    /// the number of components chosen for the frame mixture (`gmm.components` is then unused).
    GmmTsc {
        /// The base mixture.
        gmm: GmmSettings,
        /// The TSC settings.
        tsc: KrishnanSettings,
    },
    /// Static GMR.
    Gmm(GmmSettings),
    /// Chooses among `candidates` by K-fold cross-validated prediction error of
    /// the robot's dims from the human's on the training demonstrations (folds of
    /// whole demonstrations), then refits the winner on all of them.
    CrossValidated {
        /// Labels and methods to choose from.
        candidates: Vec<(String, Method)>,
        /// Number of folds (leave-one-demonstration-out when ≥ the number of demonstrations).
        folds: usize,
    },
}

/// Knobs shared by the presets (the command line's flags).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PresetOptions {
    /// Base states (components for `gmm`); not used when `auto_states` is set.
    pub states: usize,
    /// Choose the base states automatically (`states=auto`): `hmm` and the `tsc-hmm`
    /// presets λ's states, `gmm-tsc` the frame mixture (and the GMM it extends), by
    /// `select` over `AUTO_MIN_STATES..=max_states`.
    #[serde(default)]
    pub auto_states: bool,
    /// How automatic counts are chosen (`select=bic|gmeans`).
    #[serde(default)]
    pub select: Selector,
    /// Largest count an automatic choice may give.
    #[serde(default = "default_max_states")]
    pub max_states: usize,
    /// Transition states (TSC-HMM) or transition clusters (`gmm-tsc`, 0 = automatic by `select`).
    pub tsc_states: usize,
    /// Dilation `±w` of transition frames (TSC-HMM), window of stacked frames (`gmm-tsc`; 0 and 1: the frame alone).
    pub window: usize,
    /// `ρ` of `gmm-tsc`: transition clusters with transitions from fewer than this
    /// fraction of the demonstrations are pruned.
    #[serde(default = "default_rho")]
    pub rho: f64,
    /// `gmm-tsc`: sub-cluster every kept transition cluster by normalised time into at
    /// most this many sub-clusters (chosen by BIC); 0 = off.
    #[serde(default)]
    pub time_clusters: usize,
    /// Covariance regularisation.
    pub reg: f64,
    /// Maximum iterations.
    pub max_iter: usize,
    /// Tolerance.
    pub tol: f64,
    /// Restarts.
    pub restarts: usize,
    /// Seed.
    pub seed: u64,
}

/// Fewest states an automatic choice of states tries (one state has no transitions).
pub const AUTO_MIN_STATES: usize = 2;

fn default_max_states() -> usize {
    10
}

fn default_rho() -> f64 {
    0.5
}

impl Default for PresetOptions {
    /// The paper-compatible values: 4 states, 3 transition states, window ±2, `reg = 1e-2`,
    /// 40 iterations, tolerance `1e-4`, one run, seed 0; automatic choices (when asked
    /// for) by BIC up to 10; `ρ = 0.5`; no time sub-clustering.
    fn default() -> Self {
        PresetOptions {
            states: 4,
            auto_states: false,
            select: Selector::Bic,
            max_states: default_max_states(),
            tsc_states: 3,
            window: 2,
            rho: default_rho(),
            time_clusters: 0,
            reg: 1e-2,
            max_iter: 40,
            tol: 1e-4,
            restarts: 1,
            seed: 0,
        }
    }
}

/// Names of the presets.
pub const PRESETS: &[&str] = &[
    "hmm",
    "hmm-cv",
    "tsc-hmm-cv",
    "tsc-hmm",
    "tsc-hmm-union",
    "tsc-hmm-frozen",
    "tsc-hmm-gated",
    "tsc-hmm-worst",
    "gmm-tsc",
    "gmm",
];

impl Method {
    /// The preset `name` with the given options, every setting checked (an invalid
    /// combination is refused here, before any fit).
    pub fn preset(name: &str, o: &PresetOptions) -> Result<Method> {
        let refuse = |reason: String| {
            Err(TscError::InvalidSetting {
                name: "method",
                reason,
            })
        };
        if !PRESETS.contains(&name) {
            return refuse(format!(
                "unknown preset `{name}`; known: {}",
                PRESETS.join(", ")
            ));
        }
        // `-cv` presets choose their states by cross-validation.
        let auto_ok = matches!(name, "hmm" | "gmm-tsc")
            || (name.starts_with("tsc-hmm") && !name.ends_with("-cv"));
        if o.auto_states && !auto_ok {
            return refuse(format!(
                "states=auto is offered for hmm, the tsc-hmm presets (not tsc-hmm-cv) and gmm-tsc, not `{name}`"
            ));
        }
        let auto_hmm = o.auto_states && name != "gmm-tsc";
        let hmm = HmmSettings {
            states: o.states,
            reg: o.reg,
            max_iter: o.max_iter,
            tol: o.tol,
            restarts: o.restarts,
            seed: o.seed,
            covariance: CovarianceType::Full,
            auto_states: auto_hmm.then_some(AutoStates {
                min: AUTO_MIN_STATES,
                max: o.max_states,
                selector: o.select,
            }),
        };
        let tsc = |composition, detector| {
            Method::TscHmm(TscSettings {
                base: hmm.clone(),
                tsc_states: o.tsc_states,
                window: o.window,
                min_run: 2,
                detector,
                composition,
            })
        };
        let gmm = GmmSettings {
            components: o.states,
            reg: o.reg,
            max_iter: o.max_iter.max(100),
            tol: 1e-3,
            restarts: o.restarts.max(3),
            seed: o.seed,
        };
        let method = match name {
            "hmm" => Method::Hmm(hmm),
            "tsc-hmm" => tsc(DEFAULT_COMPOSITION, Detector::Disagreement),
            "tsc-hmm-union" => tsc(Composition::Union, Detector::Disagreement),
            "tsc-hmm-frozen" => tsc(Composition::UnionFrozen, Detector::Disagreement),
            "tsc-hmm-gated" => tsc(Composition::Gated, Detector::Disagreement),
            "tsc-hmm-worst" => tsc(
                Composition::Union,
                Detector::WorstPrediction { fraction: 0.15 },
            ),
            "gmm" => Method::Gmm(gmm),
            "hmm-cv" | "tsc-hmm-cv" => {
                let mut candidates: Vec<(String, Method)> = (o.states..=o.states + o.tsc_states)
                    .map(|s| {
                        let mut h = hmm.clone();
                        h.states = s;
                        (format!("hmm:states={s}"), Method::Hmm(h))
                    })
                    .collect();
                if name == "tsc-hmm-cv" {
                    for w in [0, 2, 5] {
                        let mut t = o.clone();
                        t.window = w;
                        candidates.push((
                            format!("tsc-hmm-union:window={w}"),
                            Method::preset("tsc-hmm-union", &t)?,
                        ));
                    }
                }
                Method::CrossValidated {
                    candidates,
                    folds: 5,
                }
            }
            "gmm-tsc" => Method::GmmTsc {
                gmm: gmm.clone(),
                tsc: KrishnanSettings {
                    components: (!o.auto_states).then_some(o.states),
                    max_components: o.max_states,
                    selector: o.select,
                    window: o.window.max(1),
                    transition_clusters: (o.tsc_states > 0).then_some(o.tsc_states),
                    prune_fraction: o.rho,
                    time_clusters: (o.time_clusters > 0).then(|| TimeClustering {
                        max_clusters: o.time_clusters,
                        ..TimeClustering::default()
                    }),
                    reg: o.reg,
                    seed: o.seed,
                    ..KrishnanSettings::default()
                },
            },
            other => unreachable!("`{other}` is in PRESETS but has no settings"),
        };
        method.validate()?;
        Ok(method)
    }

    /// Checks every setting of the method (called by [`Method::preset`]; call it on a
    /// method built by hand or read from a file).
    pub fn validate(&self) -> Result<()> {
        let bad = |name, reason: String| Err(TscError::InvalidSetting { name, reason });
        match self {
            Method::Hmm(s) => s.validate(),
            Method::TscHmm(s) => s.validate(),
            Method::Gmm(s) => s.validate(),
            Method::GmmTsc { gmm, tsc } => {
                gmm.validate()?;
                tsc.validate()
            }
            Method::CrossValidated { candidates, folds } => {
                if candidates.is_empty() {
                    return bad("candidates", "no candidate to choose from".into());
                }
                if *folds < 2 {
                    return bad("folds", format!("at least 2 folds are needed, got {folds}"));
                }
                candidates.iter().try_for_each(|(_, m)| m.validate())
            }
        }
    }

    /// Fits the method to joint training sequences (NaN values are missing).
    pub fn fit(&self, data: &SequenceSet, roles: &Roles) -> Result<(Model, FitSummary)> {
        let (model, mut summary) = self.fit_inner(data, roles)?;
        summary.missing_values = data.all_frames().missing_count();
        Ok((model, summary))
    }

    fn fit_inner(&self, data: &SequenceSet, roles: &Roles) -> Result<(Model, FitSummary)> {
        roles.check(data.dim())?;
        match self {
            Method::Hmm(s) => {
                let clock = std::time::Instant::now();
                let (hmm, r, selection) = s.fit_selected(data)?;
                let mut summary = FitSummary::from_hmm(&r);
                if let Some(sel) = selection {
                    summary.fit_seconds = clock.elapsed().as_secs_f64();
                    summary.with_selection(&sel, s);
                }
                Ok((Model::Hmm(hmm), summary))
            }
            Method::TscHmm(s) => {
                let clock = std::time::Instant::now();
                let (m, r) = TscHmm::fit(data, roles, s)?;
                let mut summary = FitSummary::from_hmm(r.union.as_ref().unwrap_or(&r.base));
                summary.fit_seconds = r.base.fit_seconds
                    + r.transition.fit_seconds
                    + r.union.as_ref().map_or(0.0, |u| u.fit_seconds);
                if let Some(sel) = &r.selection {
                    // The choice of λ's states costs one fit per candidate.
                    summary.fit_seconds = clock.elapsed().as_secs_f64();
                    summary.with_selection(sel, &s.base);
                }
                summary.transition_segments = Some(r.segments);
                Ok((
                    Model::TscHmm {
                        model: m,
                        window: s.window,
                    },
                    summary,
                ))
            }
            Method::Gmm(s) => {
                s.validate()?;
                let f = s.em()?.fit(
                    &Gaussian::standard(
                        CovarianceType::Full,
                        Shape {
                            n_states: s.components,
                            dim: data.dim(),
                        },
                    )?,
                    data.all_frames(),
                )?;
                Ok((Model::Gmm(f.model), FitSummary::from_gmm(&f.report)))
            }
            Method::CrossValidated { candidates, folds } => {
                let clock = std::time::Instant::now();
                let scores = cross_validate(candidates, *folds, data, roles)?;
                let best = scores
                    .iter()
                    .enumerate()
                    .filter(|(_, e)| e.is_finite())
                    .min_by(|a, b| a.1.total_cmp(b.1))
                    .map(|(i, _)| i)
                    .ok_or_else(|| TscError::InvalidSetting {
                        name: "candidates",
                        reason: "no candidate could be fitted on every fold".into(),
                    })?;
                let (model, mut summary) = candidates[best].1.fit(data, roles)?;
                summary.fit_seconds = clock.elapsed().as_secs_f64();
                summary.chosen = Some(candidates[best].0.clone());
                summary.cv_errors = candidates.iter().map(|c| c.0.clone()).zip(scores).collect();
                Ok((model, summary))
            }
            Method::GmmTsc { gmm, tsc } => {
                gmm.validate()?;
                let ktsc = tsc.fit(data)?;
                let components = match tsc.components {
                    Some(_) => gmm.components,
                    None => ktsc.mixture.n_components(),
                };
                let base = gmm.em()?.fit(
                    &Gaussian::standard(
                        CovarianceType::Full,
                        Shape {
                            n_states: components,
                            dim: data.dim(),
                        },
                    )?,
                    data.all_frames(),
                )?;
                let joined = join_mixtures(&base.model, &ktsc.transition_mixture, &ktsc.kept)?;
                let f = gmm.em()?.fit_from(joined, data.all_frames())?;
                let mut summary = FitSummary::from_gmm(&f.report);
                summary.fit_seconds += base.report.fit_seconds;
                if tsc.components.is_none() || tsc.transition_clusters.is_none() {
                    summary.chosen = Some(format!(
                        "{} frame components ({}), {} transition clusters kept of {}",
                        ktsc.mixture.n_components(),
                        tsc.selector.name(),
                        ktsc.reported_clusters().len(),
                        ktsc.transition_mixture.n_components()
                    ));
                }
                Ok((
                    Model::GmmTsc {
                        tsc: ktsc,
                        mixture: f.model,
                    },
                    summary,
                ))
            }
        }
    }
}

/// Mean squared prediction error of the robot's dims (all of them, in data units)
/// per frame over held-out demonstrations, for every candidate; `inf` for a
/// candidate that failed on some fold. Folds are `k mod folds` of the demonstrations.
pub fn cross_validate(
    candidates: &[(String, Method)],
    folds: usize,
    data: &SequenceSet,
    roles: &Roles,
) -> Result<Vec<f64>> {
    let n = data.len();
    let folds = folds.clamp(2, n.max(2));
    if n < 2 {
        return Err(TscError::InvalidSetting {
            name: "folds",
            reason: format!("cross-validation needs at least 2 demonstrations, got {n}"),
        });
    }
    let o = roles.robot.len();
    Ok(candidates
        .iter()
        .map(|(_, method)| {
            let mut se = 0.0;
            let mut frames = 0usize;
            for f in 0..folds {
                let train: Vec<usize> = (0..n).filter(|k| k % folds != f).collect();
                let held: Vec<usize> = (0..n).filter(|k| k % folds == f).collect();
                if held.is_empty() || train.is_empty() {
                    continue;
                }
                let Ok(subset) = data.subset(&train) else {
                    return f64::INFINITY;
                };
                let Ok((model, _)) = method.fit(&subset, roles) else {
                    return f64::INFINITY;
                };
                let Ok(predictor) = model.predictor(roles) else {
                    return f64::INFINITY;
                };
                for &k in &held {
                    let seq = data.get(k);
                    let human = select(seq, &roles.human);
                    let Ok(frames_in) = Frames::new(&human, roles.human.len()) else {
                        return f64::INFINITY;
                    };
                    let Ok(pred) = predictor.predict(frames_in, false) else {
                        return f64::INFINITY;
                    };
                    for (t, x) in seq.iter().enumerate() {
                        // A frame whose robot values are not all observed is not scored.
                        if roles.robot.iter().any(|&r| x[r].is_nan()) {
                            continue;
                        }
                        se += roles
                            .robot
                            .iter()
                            .enumerate()
                            .map(|(j, &r)| (pred.mean[t * o + j] - x[r]).powi(2))
                            .sum::<f64>();
                        frames += 1;
                    }
                }
            }
            // A candidate with no scorable held-out frame has no error to compare.
            if frames == 0 {
                f64::INFINITY
            } else {
                se / frames as f64
            }
        })
        .collect())
}

/// A mixture of `a`'s components and the `kept` components of `b`, weights in proportion.
fn join_mixtures(a: &Gmm, b: &Gmm, kept: &[usize]) -> Result<Gmm> {
    let (ga, gb, d) = (a.components(), b.components(), a.dim());
    let mut means = ga.means().to_vec();
    let mut covs = Vec::new();
    let mut weights: Vec<f64> = a.weights().to_vec();
    for k in 0..ga.n_states() {
        covs.extend(ga.covariance(k).iter().copied());
    }
    for &k in kept {
        means.extend_from_slice(gb.mean(k));
        covs.extend(gb.covariance(k).iter().copied());
        weights.push(b.weights()[k]);
    }
    let total: f64 = weights.iter().sum();
    weights.iter_mut().for_each(|w| *w /= total);
    Ok(Gmm::new(weights, Gaussian::full(d, means, covs)?)?)
}

/// What a fit did, in a form common to every method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitSummary {
    /// M-steps of the model that predicts.
    pub iterations: usize,
    /// Its log-likelihood (summed over sequences or frames) at every E-step.
    pub log_likelihood: Vec<f64>,
    /// Why it stopped. Serialised as `"stop": "converged" | "max-iter" |
    /// "log-likelihood fell"`; summaries written with the earlier `converged` and
    /// `stopped_on_decrease` fields are read as the same reason.
    #[serde(flatten, with = "stop_fields")]
    pub stop: FitStop,
    /// Wall-clock seconds of the whole fit.
    pub fit_seconds: f64,
    /// Largest diagonal jitter any M-step needed.
    pub jitter: f64,
    /// Number of transition segments, for TSC-HMMs.
    pub transition_segments: Option<usize>,
    /// The candidate chosen by cross-validation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chosen: Option<String>,
    /// Mean cross-validated squared prediction error of every candidate (`inf` if it failed).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cv_errors: Vec<(String, f64)>,
    /// `(states, BIC)` of every candidate of an automatic choice of states.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub bic: Vec<(usize, f64)>,
    /// Added to every covariance diagonal at every M-step (the `reg` setting; in
    /// the features' units squared: m² for NuiSI, 1 for standardised features).
    #[serde(default)]
    pub regularisation: f64,
    /// States (components) that received no weight in the last M-step and kept
    /// their previous parameters: fewer states would do.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub empty_states: Vec<usize>,
    /// States whose covariance was not positive definite at some M-step even
    /// after the regularisation and got the `jitter` on its diagonal.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub jittered_states: Vec<usize>,
    /// Values of the training data that were missing (NaN, an empty cell).
    #[serde(default)]
    pub missing_values: usize,
    /// What looks wrong with the training data for this model (set by callers
    /// that know the data's meaning, e.g. the command line).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// Why EM stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum FitStop {
    /// The gain of the log-likelihood fell below the tolerance.
    #[serde(rename = "converged")]
    Converged,
    /// The iteration cap was reached first.
    #[serde(rename = "max-iter")]
    MaxIter,
    /// The log-likelihood fell: the regularisation added after every M-step makes
    /// EM non-monotone, and the protocol's tolerance test stops at the first fall.
    #[serde(rename = "log-likelihood fell")]
    LogLikelihoodFell,
}

impl FitStop {
    /// The reason from the tolerance test's verdict and the log-likelihood trace.
    pub fn from_trace(converged: bool, log_likelihood: &[f64]) -> Self {
        match (converged, log_likelihood) {
            (false, _) => FitStop::MaxIter,
            (true, [.., a, b]) if b < a => FitStop::LogLikelihoodFell,
            (true, _) => FitStop::Converged,
        }
    }
}

/// `stop` as its own field, read also from the `converged` / `stopped_on_decrease`
/// pair of summaries written before it existed.
mod stop_fields {
    use super::FitStop;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize)]
    struct Out {
        stop: FitStop,
    }

    #[derive(Deserialize)]
    struct In {
        stop: Option<FitStop>,
        converged: Option<bool>,
        #[serde(default)]
        stopped_on_decrease: bool,
    }

    pub fn serialize<S: Serializer>(stop: &FitStop, s: S) -> Result<S::Ok, S::Error> {
        Out { stop: *stop }.serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<FitStop, D::Error> {
        let i = In::deserialize(d)?;
        match (i.stop, i.converged) {
            (Some(stop), _) => Ok(stop),
            (None, Some(false)) => Ok(FitStop::MaxIter),
            (None, Some(true)) if i.stopped_on_decrease => Ok(FitStop::LogLikelihoodFell),
            (None, Some(true)) => Ok(FitStop::Converged),
            (None, None) => Err(serde::de::Error::missing_field("stop")),
        }
    }
}

impl FitSummary {
    fn with_selection(&mut self, sel: &phasekit_gmm::Selection, settings: &HmmSettings) {
        let how = match settings.auto_states.map(|a| a.selector) {
            Some(Selector::GMeans) => "G-means",
            _ => "BIC",
        };
        self.chosen = Some(format!("states={} ({how})", sel.best));
        self.bic = sel.scores.clone();
    }

    fn from_hmm(r: &phasekit_hmm::HmmFitReport) -> Self {
        Self::from_parts(
            r.iterations,
            &r.log_likelihood,
            r.converged,
            r.fit_seconds,
            &r.m_steps,
        )
    }

    fn from_gmm(r: &phasekit_gmm::GmmFitReport) -> Self {
        Self::from_parts(
            r.iterations,
            &r.log_likelihood,
            r.converged,
            r.fit_seconds,
            &r.m_steps,
        )
    }

    fn from_parts(
        iterations: usize,
        log_likelihood: &[f64],
        converged: bool,
        fit_seconds: f64,
        m_steps: &[phasekit_emission::MStepReport],
    ) -> Self {
        use phasekit_emission::MStepEvent;
        let mut jittered: Vec<usize> = m_steps
            .iter()
            .flat_map(|m| &m.events)
            .filter_map(|e| match e {
                MStepEvent::Jitter { state, .. } => Some(*state),
                _ => None,
            })
            .collect();
        jittered.sort_unstable();
        jittered.dedup();
        let mut empty: Vec<usize> = m_steps
            .last()
            .map(|m| {
                m.events
                    .iter()
                    .filter_map(|e| match e {
                        MStepEvent::KeptEmptyState { state, .. } => Some(*state),
                        _ => None,
                    })
                    .collect()
            })
            .unwrap_or_default();
        empty.dedup();
        FitSummary {
            iterations,
            log_likelihood: log_likelihood.to_vec(),
            stop: FitStop::from_trace(converged, log_likelihood),
            fit_seconds,
            jitter: m_steps.iter().map(|m| m.total_jitter()).fold(0.0, f64::max),
            transition_segments: None,
            chosen: None,
            cv_errors: Vec::new(),
            bic: Vec::new(),
            regularisation: m_steps.iter().map(|m| m.added_diagonal).fold(0.0, f64::max),
            empty_states: empty,
            jittered_states: jittered,
            missing_values: 0,
            warnings: Vec::new(),
        }
    }
}

/// A fitted model of any method (serialisable).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Model {
    /// An HMM on joint frames.
    Hmm(Hmm<Gaussian>),
    /// A TSC-HMM.
    TscHmm {
        /// The fitted model.
        model: TscHmm,
        /// The dilation used for its transition frames.
        window: usize,
    },
    /// A GMM on joint frames.
    Gmm(Gmm),
    /// Krishnan TSC and the joined mixture that predicts.
    GmmTsc {
        /// The TSC.
        tsc: KrishnanTsc,
        /// The GMM plus kept transition clusters.
        mixture: Gmm,
    },
}

impl Model {
    /// Joint frame dimension.
    pub fn dim(&self) -> usize {
        match self {
            Model::Hmm(h) => h.dim(),
            Model::TscHmm { model, .. } => model.base.dim(),
            Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => g.dim(),
        }
    }

    /// Total number of states (components) used for prediction.
    pub fn n_states(&self) -> usize {
        match self {
            Model::Hmm(h) => h.n_states(),
            Model::TscHmm { model, .. } => model
                .union
                .as_ref()
                .map_or(model.base.n_states() + model.transition.n_states(), |u| {
                    u.n_states()
                }),
            Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => g.n_components(),
        }
    }

    /// Checks that the parts of the model agree (a model read from a file may not):
    /// see [`TscHmm::validate`] and [`KrishnanTsc::validate`]; the predicting mixture
    /// of `gmm-tsc` holds its base components and the kept clusters.
    pub fn validate(&self) -> Result<()> {
        match self {
            Model::Hmm(_) | Model::Gmm(_) => Ok(()),
            Model::TscHmm { model, .. } => model.validate(),
            Model::GmmTsc { tsc, mixture } => {
                tsc.validate()?;
                if mixture.dim() != tsc.transition_mixture.dim()
                    || mixture.n_components() <= tsc.kept.len()
                {
                    return Err(TscError::InvalidSetting {
                        name: "gmm-tsc model",
                        reason: format!(
                            "the predicting mixture has {} components of dimension {}: it needs more than the {} kept clusters, of dimension {}",
                            mixture.n_components(),
                            mixture.dim(),
                            tsc.kept.len(),
                            tsc.transition_mixture.dim()
                        ),
                    });
                }
                Ok(())
            }
        }
    }

    /// The predictor of the robot's dims from the human's.
    pub fn predictor(&self, roles: &Roles) -> Result<Predictor> {
        roles.check(self.dim())?;
        self.validate()?;
        let hmm = |h: &Hmm<Gaussian>| HmmRegression::new(h, &roles.human, &roles.robot);
        Ok(match self {
            Model::Hmm(h) => Predictor::Hmm(hmm(h)?),
            // `validate` has checked that a union composition has its union HMM and the gate none.
            Model::TscHmm { model, .. } => match &model.union {
                Some(u) => Predictor::Hmm(hmm(u)?),
                None => Predictor::Gated {
                    base: hmm(&model.base)?,
                    transition: hmm(&model.transition)?,
                },
            },
            Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => {
                Predictor::Gmm(GmmRegression::new(g, &roles.human, &roles.robot)?)
            }
        })
    }

    /// Segments a joint demonstration: labels, transition frames and their clusters.
    ///
    /// HMMs label by Viterbi on joint frames and flag the paper's transition states
    /// (human-only vs joint filtered argmax disagree); a TSC-HMM dilates them by its window
    /// and names each run's `λ_T` Viterbi states as clusters; `gmm-tsc` uses
    /// Krishnan's label changes and kept clusters; `gmm` flags label changes.
    pub fn segment(&self, seq: Frames<'_>, roles: &Roles) -> Result<Segmentation> {
        let one = SequenceSet::single(seq.as_slice(), seq.dim())?;
        let flagged = |flags: &[bool]| {
            flags
                .iter()
                .enumerate()
                .filter_map(|(t, f)| f.then_some(t))
                .collect::<Vec<_>>()
        };
        match self {
            Model::Hmm(h) => {
                let labels = ViterbiLabeller(h).label(seq)?;
                let flags = &disagreement_flags(h, roles, &one)?[0];
                let transitions = flagged(flags);
                let clusters = vec![None; transitions.len()];
                Ok(Segmentation {
                    labels,
                    transitions,
                    clusters,
                })
            }
            Model::TscHmm { model, window } => {
                let labels = ViterbiLabeller(&model.base).label(seq)?;
                let flags = dilate(&disagreement_flags(&model.base, roles, &one)?[0], *window);
                let mut transitions = Vec::new();
                let mut clusters = Vec::new();
                for r in runs(&flags, 1) {
                    let sub = seq.slice(r.clone());
                    let states = model.transition.viterbi(sub)?.states;
                    transitions.extend(r.clone());
                    clusters.extend(states.into_iter().map(Some));
                }
                Ok(Segmentation {
                    labels,
                    transitions,
                    clusters,
                })
            }
            Model::Gmm(g) => {
                let labels = g.predict(seq)?;
                let transitions = flagged(&crate::detect::label_changes(&labels, 2));
                let clusters = vec![None; transitions.len()];
                Ok(Segmentation {
                    labels,
                    transitions,
                    clusters,
                })
            }
            Model::GmmTsc { tsc, .. } => tsc.segment(seq),
        }
    }
}

/// Predicts the robot's dims from the human's, over whole sequences.
#[derive(Debug, Clone)]
pub enum Predictor {
    /// HMM-GMR (the baseline and the union compositions).
    Hmm(HmmRegression),
    /// `λ`'s GMR, replaced by `λ_T`'s where `λ_T` explains the human's frame better.
    Gated {
        /// GMR of `λ`.
        base: HmmRegression,
        /// GMR of `λ_T`.
        transition: HmmRegression,
    },
    /// Static GMR.
    Gmm(GmmRegression),
}

impl Predictor {
    /// Number of predicted dims.
    pub fn n_out(&self) -> usize {
        match self {
            Predictor::Hmm(r) | Predictor::Gated { base: r, .. } => r.regression().n_out(),
            Predictor::Gmm(r) => r.regression().n_out(),
        }
    }

    /// Predicts a sequence of human frames (human dims only), causally.
    pub fn predict(&self, human: Frames<'_>, with_covariance: bool) -> Result<Prediction> {
        match self {
            Predictor::Hmm(r) => Ok(r.predict(human, with_covariance)?),
            Predictor::Gmm(r) => Ok(r.predict(human, with_covariance)?),
            Predictor::Gated { base, transition } => {
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
        match self {
            Predictor::Hmm(r) => OnlinePredictor::Hmm(r.online()),
            Predictor::Gated { base, transition } => OnlinePredictor::Gated {
                base: base.online(),
                transition: transition.online(),
                mean: vec![0.0; o],
                covariance: vec![0.0; o * o],
            },
            Predictor::Gmm(r) => {
                let k = r.regression().n_states();
                OnlinePredictor::Gmm {
                    regression: r.clone(),
                    weights: vec![0.0; k],
                    mean: vec![0.0; o],
                    covariance: vec![0.0; o * o],
                    scratch: vec![0.0; k * o],
                }
            }
        }
    }
}

/// Frame-by-frame prediction for a control loop; no allocation per frame.
#[derive(Debug, Clone)]
pub enum OnlinePredictor {
    /// Online HMM-GMR.
    Hmm(OnlineRegression),
    /// Two online HMM-GMRs and the likelihood gate.
    Gated {
        /// `λ`'s.
        base: OnlineRegression,
        /// `λ_T`'s.
        transition: OnlineRegression,
        /// Chosen mean.
        mean: Vec<f64>,
        /// Chosen covariance.
        covariance: Vec<f64>,
    },
    /// Static GMR, frame by frame.
    Gmm {
        /// The regression.
        regression: GmmRegression,
        /// Responsibilities of the last frame.
        weights: Vec<f64>,
        /// Mean of the last frame.
        mean: Vec<f64>,
        /// Covariance of the last frame.
        covariance: Vec<f64>,
        /// Scratch.
        scratch: Vec<f64>,
    },
}

impl OnlinePredictor {
    /// Takes one human frame and returns the predicted robot mean; with
    /// `with_covariance` also updates [`OnlinePredictor::covariance`].
    pub fn step(&mut self, human: &[f64], with_covariance: bool) -> Result<&[f64]> {
        match self {
            OnlinePredictor::Hmm(r) => Ok(if with_covariance {
                r.step_with_covariance(human)?
            } else {
                r.step(human)?
            }),
            OnlinePredictor::Gated {
                base,
                transition,
                mean,
                covariance,
            } => {
                let (la, lb) = (base.log_likelihood(), transition.log_likelihood());
                base.step_with_covariance(human)?;
                transition.step_with_covariance(human)?;
                let use_t = transition.log_likelihood() - lb > base.log_likelihood() - la;
                let src = if use_t { &*transition } else { &*base };
                mean.copy_from_slice(src.mean());
                covariance.copy_from_slice(src.covariance());
                Ok(mean)
            }
            OnlinePredictor::Gmm {
                regression,
                weights,
                mean,
                covariance,
                scratch,
            } => {
                regression.predict_one_into(
                    human,
                    weights,
                    mean,
                    with_covariance.then_some(&mut covariance[..]),
                    scratch,
                )?;
                Ok(mean)
            }
        }
    }

    /// Predictive covariance of the last step (when requested), `O × O`.
    pub fn covariance(&self) -> &[f64] {
        match self {
            OnlinePredictor::Hmm(r) => r.covariance(),
            OnlinePredictor::Gated { covariance, .. } | OnlinePredictor::Gmm { covariance, .. } => {
                covariance
            }
        }
    }

    /// Starts a new demonstration.
    pub fn reset(&mut self) {
        match self {
            OnlinePredictor::Hmm(r) => r.reset(),
            OnlinePredictor::Gated {
                base, transition, ..
            } => {
                base.reset();
                transition.reset();
            }
            OnlinePredictor::Gmm { .. } => {}
        }
    }
}

/// The predictor's input: the human's dims of joint frames.
pub fn human_frames(seq: Frames<'_>, roles: &Roles) -> Vec<f64> {
    select(seq, &roles.human)
}
