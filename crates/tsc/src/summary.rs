//! What a fit did, in a form common to every method.

use crate::cross_validation::CvRow;
use crate::hmm_settings::AutoStatesReport;
use phasekit_emission::{MStepEvent, MStepReport};
use phasekit_gmm::GmmFitReport;
use phasekit_hmm::HmmFitReport;
use serde::{Deserialize, Serialize};

/// What a fit did, in a form common to every method (made by `Method::fit`;
/// the command line writes it into the model file and the fit report).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
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
    /// What an automatic choice chose: the candidate chosen by
    /// cross-validation, the number of states (`states=5 (BIC)`), or the
    /// counts of `gmm-tsc` — with what bounded the candidates, if anything did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chosen: Option<String>,
    /// Mean cross-validated squared prediction error of every candidate that
    /// could be scored on every fold.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cv_errors: Vec<(String, f64)>,
    /// Every candidate of a cross-validation that could not be scored, and why.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cv_failures: Vec<(String, String)>,
    /// The whole cross-validation table of a choice by cross-validation
    /// (`auto`, the `-cv` presets): every candidate, abandoned or failed ones included.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cv_table: Vec<CvRow>,
    /// `(states, BIC)` of every candidate of an automatic choice of states.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub bic: Vec<(usize, f64)>,
    /// The `reg` setting. Absolute (the default): added to every covariance
    /// diagonal at every M-step, in the features' units squared (m² for NuiSI,
    /// 1 for standardised features). Relative (`reg-rel`): the fraction `R` of
    /// each feature's variance, whose amounts in data units are
    /// [`FitSummary::regularisation_per_feature`]; `jitter` is then in the
    /// scaled units the fit ran in.
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
    /// The calibration of the predictive covariance fitted on held-out
    /// demonstrations (a choice by cross-validation with calibration on:
    /// `auto`); its [`CovarianceCalibration::scale`] multiplies every predicted
    /// covariance ([`FitSummary::covariance_scale`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance_calibration: Option<CovarianceCalibration>,
    /// With a regularisation relative to the data (`reg-units=relative` or
    /// `positions`): the amount `R · s_j²` the fit added to the variance of
    /// every feature `j`, in the data's units squared (`s_j² = v_j`, the
    /// feature's variance over the training frames, 1 for a constant one;
    /// for a velocity under `positions`, its position's variance in the
    /// velocity's unit: [`crate::position_scales`];
    /// [`FitSummary::regularisation`] then holds `R`, a fraction). Empty for
    /// an absolute regularisation.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub regularisation_per_feature: Vec<f64>,
}

impl FitSummary {
    /// The factor every predicted covariance is multiplied by: the
    /// calibration's scale, 1 without one.
    pub fn covariance_scale(&self) -> f64 {
        self.covariance_calibration
            .as_ref()
            .map_or(1.0, |c| c.scale)
    }

    /// The covariance added to every predicted one before scaling (`O × O`,
    /// row-major, the robot's dims in model order): the calibration's
    /// [`CovarianceCalibration::added_covariance`], `None` without one.
    pub fn covariance_added(&self) -> Option<&[f64]> {
        self.covariance_calibration
            .as_ref()
            .map(|c| c.added_covariance.as_slice())
            .filter(|a| !a.is_empty())
    }
}

/// A predictive covariance calibrated on held-out demonstrations,
/// `Σ'_t = c · (Σ_t + A)`: `A` a covariance added to the model's
/// ([`CovarianceCalibration::added_covariance`], none but with the
/// `predictive` rule), `c = λ · q / χ²_level(p)` with `q` the `level` quantile
/// of the held-out frames' squared Mahalanobis distances under `Σ_t + A`
/// (`phasekit_gmr::coverage_scale`) and `λ` the widening (or narrowing) that
/// a new demonstration needs ([`CovarianceCalibration::demonstration_inflation`]),
/// and what it did to those frames' coverage and NLPD (scored dims, data units).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct CovarianceCalibration {
    /// `c`: multiplies every predicted covariance (> 0).
    pub scale: f64,
    /// The region's level (0.95).
    pub level: f64,
    /// `λ`: how much the factor of the pooled held-out frames was
    /// widened so that a left-out demonstration is covered at `level`: with
    /// the `predictive` rule `f` of `phasekit_gmr::new_demonstration_factor`
    /// (may be below 1); otherwise `≥ 1`
    /// (`Calibration::Demonstrations`, `phasekit_gmr::demonstration_inflation`;
    /// `scale = λ · Q_level(m²) / χ²_level(p)`); 1 when the frames are pooled
    /// (`Calibration::Frames`), in files written before it existed, and when
    /// it could not be computed (fewer than two held-out demonstrations with
    /// scored frames: the summary's `warnings` then say so).
    #[serde(default = "no_inflation")]
    pub demonstration_inflation: f64,
    /// Held-out frames it was fitted on.
    pub frames: usize,
    /// `A`, added to every predicted covariance before the scale multiplies
    /// it: `Σ'_t = scale · (Σ_t + A)` (`O × O`, row-major, the robot's dims in
    /// model order, in the model's units squared; nonzero only in the scored
    /// dims' block). `w s R` of `phasekit_gmr::residual_shape` with the
    /// `predictive` rule; empty (nothing added) with the others.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub added_covariance: Vec<f64>,
    /// `w`: the share of the held-out errors' covariance in `A` (0: the
    /// model's own shape; `predictive` rule only).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub residual_weight: f64,
    /// The standard deviation of the held-out demonstrations' log-difficulty
    /// (`σ` of `phasekit_gmr::new_demonstration_factor`; `predictive` rule only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub demonstration_spread: Option<f64>,
    /// Their share inside the `level` region before scaling.
    pub coverage_before: f64,
    /// And after: at least `level` by construction, except with the
    /// `predictive` rule when its factor for a new demonstration is below 1.
    pub coverage_after: f64,
    /// Their mean negative log predictive density before scaling (nats).
    pub nlpd_before: f64,
    /// And after.
    pub nlpd_after: f64,
}

fn no_inflation() -> f64 {
    1.0
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
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
    /// Records an automatic choice of the number of states.
    pub(crate) fn with_selection(&mut self, sel: &AutoStatesReport) {
        self.chosen = Some(sel.summary());
        self.bic = sel.scores.clone();
    }

    /// The summary of an HMM fit.
    pub(crate) fn from_hmm(r: &HmmFitReport) -> Self {
        Self::from_parts(
            r.iterations,
            &r.log_likelihood,
            r.converged,
            r.fit_seconds,
            &r.m_steps,
        )
    }

    /// The summary of an HSMM fit.
    pub(crate) fn from_hsmm(r: &phasekit_hsmm::HsmmFitReport) -> Self {
        Self::from_parts(
            r.iterations,
            &r.log_likelihood,
            r.converged,
            r.fit_seconds,
            &r.m_steps,
        )
    }

    /// The summary of a mixture fit.
    pub(crate) fn from_gmm(r: &GmmFitReport) -> Self {
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
        m_steps: &[MStepReport],
    ) -> Self {
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
            cv_failures: Vec::new(),
            cv_table: Vec::new(),
            bic: Vec::new(),
            regularisation: m_steps.iter().map(|m| m.added_diagonal).fold(0.0, f64::max),
            empty_states: empty,
            jittered_states: jittered,
            missing_values: 0,
            warnings: Vec::new(),
            covariance_calibration: None,
            regularisation_per_feature: Vec::new(),
        }
    }
}
