//! A method with all its settings, and fitting it to demonstrations.

use crate::cross_validation::{fit_cross_validated, Halving};
use crate::emission_choice::{AnyEmission, EmissionKind};
use crate::error::{Result, TscError};
use crate::hmm_settings::HmmSettings;
use crate::hsmm_gmr::HsmmSettings;
use crate::krishnan::KrishnanSettings;
use crate::model::Model;
use crate::reg_units::{feature_variances, position_scales, scale_data, scale_model, RegUnits};
use crate::roles::Roles;
use crate::summary::FitSummary;
use crate::tsc_hmm::{TscHmm, TscSettings};
use phasekit_emission::{
    CovarianceType, Emission, Frames, Gaussian, Regularisation, ScaleFeatures, SequenceSet,
};
use phasekit_gmm::{Em, Gmm};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::fmt;

/// Settings of a static GMM (the `gmm` preset and the base of `gmm-tsc`),
/// validated once by [`GmmSettingsBuilder::build`] (and on deserialisation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "GmmSettingsRaw")]
pub struct GmmSettings {
    components: usize,
    reg: f64,
    max_iter: usize,
    tol: f64,
    restarts: usize,
    seed: u64,
    /// The emission of every component (full Gaussians by default; not
    /// written then, so that older files and new ones agree).
    #[serde(default, skip_serializing_if = "EmissionKind::is_default")]
    emission: EmissionKind,
    /// The unit of `reg` (written only when relative: files without it are absolute).
    #[serde(default, skip_serializing_if = "RegUnits::is_absolute")]
    reg_units: RegUnits,
}

/// The serialised form of [`GmmSettings`], before validation.
#[derive(Deserialize)]
struct GmmSettingsRaw {
    components: usize,
    reg: f64,
    max_iter: usize,
    tol: f64,
    restarts: usize,
    seed: u64,
    #[serde(default)]
    emission: EmissionKind,
    #[serde(default)]
    reg_units: RegUnits,
}

impl TryFrom<GmmSettingsRaw> for GmmSettings {
    type Error = TscError;
    fn try_from(r: GmmSettingsRaw) -> Result<Self> {
        GmmSettingsBuilder(GmmSettings {
            components: r.components,
            reg: r.reg,
            max_iter: r.max_iter,
            tol: r.tol,
            restarts: r.restarts,
            seed: r.seed,
            emission: r.emission,
            reg_units: r.reg_units,
        })
        .build()
    }
}

impl Default for GmmSettings {
    /// 4 components, `reg = 1e-2`, 100 iterations, tolerance `1e-3` on the mean
    /// log-likelihood per frame, 3 k-means++ runs, seed 0 (the presets' GMM).
    fn default() -> Self {
        GmmSettings {
            components: 4,
            reg: 1e-2,
            max_iter: 100,
            tol: 1e-3,
            restarts: 3,
            seed: 0,
            emission: EmissionKind::default(),
            reg_units: RegUnits::Absolute,
        }
    }
}

/// Builder of [`GmmSettings`]; [`GmmSettingsBuilder::build`] validates once.
#[derive(Debug, Clone)]
pub struct GmmSettingsBuilder(GmmSettings);

impl GmmSettingsBuilder {
    /// `k ≥ 1` components.
    pub fn components(mut self, k: usize) -> Self {
        self.0.components = k;
        self
    }
    /// `r ≥ 0` added to the covariance diagonals after every M-step.
    pub fn reg(mut self, reg: f64) -> Self {
        self.0.reg = reg;
        self
    }
    /// The unit of `reg` ([`RegUnits::Relative`]: `reg · diag(v)`, `v` the
    /// features' variances over the training frames; applied by
    /// [`Method::fit`], see [`crate::reg_units`]). For `gmm-tsc` it is the
    /// unit of the whole method (the TSC's mixtures too).
    pub fn reg_units(mut self, units: RegUnits) -> Self {
        self.0.reg_units = units;
        self
    }
    /// At most `n ≥ 1` M-steps.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.0.max_iter = n;
        self
    }
    /// Tolerance `≥ 0` on the gain of the mean log-likelihood per frame.
    pub fn tol(mut self, tol: f64) -> Self {
        self.0.tol = tol;
        self
    }
    /// `n ≥ 1` runs from k-means++ seeds.
    pub fn restarts(mut self, n: usize) -> Self {
        self.0.restarts = n;
        self
    }
    /// Seed of the first run (run `r` uses `seed + r`).
    pub fn seed(mut self, seed: u64) -> Self {
        self.0.seed = seed;
        self
    }
    /// The emission of every component (the `emission=` key).
    pub fn emission(mut self, emission: EmissionKind) -> Self {
        self.0.emission = emission;
        self
    }
    /// Validates the settings, naming the first bad one.
    pub fn build(self) -> Result<GmmSettings> {
        let s = self.0;
        let bad = |name, reason: String| Err(TscError::InvalidSetting { name, reason });
        if s.components == 0 {
            return bad("states", "a mixture needs at least one component".into());
        }
        if s.max_iter == 0 {
            return bad("max_iter", "at least one iteration is needed".into());
        }
        if s.restarts == 0 {
            return bad("restarts", "at least one run is needed".into());
        }
        if !(s.reg.is_finite() && s.reg >= 0.0) {
            return bad("reg", format!("must be a finite number ≥ 0, got {}", s.reg));
        }
        if !(s.tol.is_finite() && s.tol >= 0.0) {
            return bad("tol", format!("must be a finite number ≥ 0, got {}", s.tol));
        }
        Ok(s)
    }
}

impl GmmSettings {
    /// A builder starting from [`GmmSettings::default`].
    pub fn builder() -> GmmSettingsBuilder {
        GmmSettingsBuilder(GmmSettings::default())
    }
    /// A builder starting from these settings (to change some of them).
    pub fn to_builder(&self) -> GmmSettingsBuilder {
        GmmSettingsBuilder(self.clone())
    }
    /// Components.
    pub fn components(&self) -> usize {
        self.components
    }
    /// `r` added to the covariance diagonals.
    pub fn reg(&self) -> f64 {
        self.reg
    }
    /// The unit of `reg` (see [`GmmSettingsBuilder::reg_units`]).
    pub fn reg_units(&self) -> RegUnits {
        self.reg_units
    }
    /// At most this many M-steps.
    pub fn max_iter(&self) -> usize {
        self.max_iter
    }
    /// Tolerance on the mean log-likelihood per frame.
    pub fn tol(&self) -> f64 {
        self.tol
    }
    /// Runs from k-means++ seeds.
    pub fn restarts(&self) -> usize {
        self.restarts
    }
    /// Seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }
    /// The emission of every component.
    pub fn emission(&self) -> EmissionKind {
        self.emission
    }

    /// The EM settings.
    fn em(&self) -> Result<Em> {
        Ok(Em::builder()
            .max_iter(self.max_iter)
            .tol(self.tol)
            .regularisation(Regularisation::add_diagonal(self.reg)?)
            .restarts(self.restarts)
            .seed(self.seed)
            .build()?)
    }
}

/// How a cross-validated choice calibrates the winner's predictive covariance
/// on the held-out frames of its folds ([`crate::cross_validation`]).
///
/// Serialised as `false`, `true`, `"demonstrations"` and `"predictive"`: the first two are
/// what files wrote when calibration was a flag (and the rule was
/// [`Calibration::Frames`]), so that those files and their readers keep their
/// meaning; `"off"` and `"frames"` are read too.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(from = "CalibrationRaw")]
pub enum Calibration {
    /// The predictive covariance as the model gives it.
    #[default]
    Off,
    /// The factor that makes 95 % of the held-out frames, pooled, fall inside
    /// their 95 % regions ([`phasekit_gmr::coverage_scale`]).
    Frames,
    /// The factor that makes 95 % of the frames of a *left-out
    /// demonstration* fall inside: the [`Calibration::Frames`] factor widened
    /// by what leaving each held-out demonstration out of the calibration in
    /// turn shows it lacks ([`phasekit_gmr::demonstration_inflation`]; never
    /// narrower).
    Demonstrations,
    /// The model's covariance plus a share of its held-out errors'
    /// covariance chosen by held-out likelihood
    /// ([`phasekit_gmr::residual_shape`]), scaled so that a *new
    /// demonstration* is covered at 95 % in expectation, with how hard a
    /// demonstration is as a random effect whose spread is measured on the
    /// held-out demonstrations ([`phasekit_gmr::new_demonstration_factor`]).
    Predictive,
}

impl Calibration {
    /// No calibration (not written in files).
    pub fn is_off(&self) -> bool {
        *self == Calibration::Off
    }
}

/// What a file may hold for [`Calibration`]: the rule, or the flag of older files.
#[derive(Deserialize)]
#[serde(untagged)]
enum CalibrationRaw {
    Flag(bool),
    Rule(CalibrationName),
}

#[derive(Deserialize)]
#[serde(rename_all = "lowercase")]
enum CalibrationName {
    Off,
    Frames,
    Demonstrations,
    Predictive,
}

impl From<CalibrationRaw> for Calibration {
    fn from(r: CalibrationRaw) -> Self {
        match r {
            CalibrationRaw::Flag(false) | CalibrationRaw::Rule(CalibrationName::Off) => {
                Calibration::Off
            }
            CalibrationRaw::Flag(true) | CalibrationRaw::Rule(CalibrationName::Frames) => {
                Calibration::Frames
            }
            CalibrationRaw::Rule(CalibrationName::Demonstrations) => Calibration::Demonstrations,
            CalibrationRaw::Rule(CalibrationName::Predictive) => Calibration::Predictive,
        }
    }
}

impl Serialize for Calibration {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            Calibration::Off => s.serialize_bool(false),
            Calibration::Frames => s.serialize_bool(true),
            Calibration::Demonstrations => s.serialize_str("demonstrations"),
            Calibration::Predictive => s.serialize_str("predictive"),
        }
    }
}

impl fmt::Display for Calibration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Calibration::Off => "off",
            Calibration::Frames => "frames",
            Calibration::Demonstrations => "demonstrations",
            Calibration::Predictive => "predictive",
        })
    }
}

/// How the winner is chosen from the cross-validation table
/// ([`crate::cross_validation::winner_by`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Selection {
    /// The lowest cross-validated error.
    #[default]
    Best,
    /// The one-standard-error rule (Breiman et al. 1984; Hastie, Tibshirani
    /// and Friedman, *Elements of Statistical Learning* §7.10): among the
    /// candidates whose error is within one standard error of the lowest
    /// (the sample standard deviation of its per-fold errors over `√K`), the
    /// most regularised: the largest `reg` (compared as numbers, so within
    /// one unit: a grid mixing `reg-pos` and `reg-rel` compares them as if
    /// alike), then the fewest states, then the earlier.
    OneStandardError,
    /// Not one candidate: the equally weighted mean of the `K ≥ 1` with the
    /// lowest cross-validated errors (among those [`Selection::Best`] may
    /// choose from), each refitted on all the data, a [`crate::Model::Ensemble`]
    /// (model averaging, "stacking" with equal weights: Breiman 1996;
    /// *ESL* §8.8). `K = 1` is [`Selection::Best`].
    Mean(usize),
}

impl Selection {
    /// The default rule (not written in files).
    pub fn is_best(&self) -> bool {
        *self == Selection::Best
    }
}

impl fmt::Display for Selection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Selection::Best => "best",
            Selection::OneStandardError => "one-se",
            Selection::Mean(k) => return write!(f, "mean of {k}"),
        })
    }
}

/// A choice among candidate methods by K-fold cross-validated prediction error
/// ([`crate::cross_validate`]), validated at construction (and on deserialisation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "CrossValidationRaw")]
pub struct CrossValidation {
    candidates: Vec<(String, Method)>,
    folds: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    halving: Option<Halving>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fold_seed: Option<u64>,
    #[serde(default, skip_serializing_if = "Calibration::is_off")]
    calibration: Calibration,
    #[serde(default, skip_serializing_if = "Selection::is_best")]
    selection: Selection,
}

/// The serialised form of [`CrossValidation`], before validation.
#[derive(Deserialize)]
struct CrossValidationRaw {
    candidates: Vec<(String, Method)>,
    folds: usize,
    #[serde(default)]
    halving: Option<Halving>,
    #[serde(default)]
    fold_seed: Option<u64>,
    #[serde(default)]
    calibration: Calibration,
    #[serde(default)]
    selection: Selection,
}

impl TryFrom<CrossValidationRaw> for CrossValidation {
    type Error = TscError;
    fn try_from(r: CrossValidationRaw) -> Result<Self> {
        let mut cv = CrossValidation::new(r.candidates, r.folds)?;
        cv.halving = r.halving;
        cv.fold_seed = r.fold_seed;
        cv.calibration = r.calibration;
        if r.selection == Selection::Mean(0) {
            return Err(TscError::InvalidSetting {
                name: "selection",
                reason: "the mean of 0 candidates: K must be at least 1".into(),
            });
        }
        cv.selection = r.selection;
        Ok(cv)
    }
}

impl CrossValidation {
    /// Chooses among `candidates` (label, method; at least one) by `folds ≥ 2`
    /// folds of whole demonstrations (leave-one-demonstration-out when `folds`
    /// is at least the number of demonstrations).
    pub fn new(candidates: Vec<(String, Method)>, folds: usize) -> Result<Self> {
        if candidates.is_empty() {
            return Err(TscError::InvalidSetting {
                name: "candidates",
                reason: "no candidate to choose from".into(),
            });
        }
        if folds < 2 {
            return Err(TscError::InvalidSetting {
                name: "folds",
                reason: format!("at least 2 folds are needed, got {folds}"),
            });
        }
        Ok(CrossValidation {
            candidates,
            folds,
            halving: None,
            fold_seed: None,
            calibration: Calibration::Off,
            selection: Selection::Best,
        })
    }
    /// Early abandoning of hopeless candidates by successive halving (see
    /// [`crate::cross_validation`]); without it every candidate is scored on every fold.
    pub fn with_halving(mut self, halving: Halving) -> Self {
        self.halving = Some(halving);
        self
    }
    /// Shuffle the demonstrations into folds with this seed (without it,
    /// demonstration `k` is held out by fold `k mod folds`).
    pub fn with_fold_seed(mut self, seed: u64) -> Self {
        self.fold_seed = Some(seed);
        self
    }
    /// Calibrate the winner's predictive covariance on its held-out frames by
    /// this rule (see [`crate::cross_validation`] and [`Calibration`]).
    pub fn with_calibration(mut self, rule: Calibration) -> Self {
        self.calibration = rule;
        self
    }
    /// How the winner's predictive covariance is calibrated.
    pub fn calibration(&self) -> Calibration {
        self.calibration
    }
    /// Choose the winner by this rule ([`Selection::Best`] by default).
    pub fn with_selection(mut self, rule: Selection) -> Self {
        self.selection = rule;
        self
    }
    /// How the winner is chosen.
    pub fn selection(&self) -> Selection {
        self.selection
    }
    /// The rule of early abandoning, if any.
    pub fn halving(&self) -> Option<&Halving> {
        self.halving.as_ref()
    }
    /// The seed of the fold assignment, if shuffled.
    pub fn fold_seed(&self) -> Option<u64> {
        self.fold_seed
    }
    /// The labels and methods to choose from.
    pub fn candidates(&self) -> &[(String, Method)] {
        &self.candidates
    }
    /// The number of folds.
    pub fn folds(&self) -> usize {
        self.folds
    }
}

/// A method with all its settings; every setting was validated when built (or
/// read), so a `Method` can be fitted as it is.
///
/// Not `#[non_exhaustive]` on purpose: a new method must be handled by every
/// `match` of the workspace (the command's checks and reports).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "kebab-case")]
pub enum Method {
    /// HMM on joint frames, HMM-GMR.
    Hmm(HmmSettings),
    /// Left-right HSMM (explicit phase durations) on joint frames, HSMM-GMR.
    Hsmm(HsmmSettings),
    /// TSC-HMM.
    TscHmm(TscSettings),
    /// Krishnan-style TSC over a GMM, static GMR over the GMM and the kept transition clusters.
    /// With an automatic frame mixture (`tsc.components() = None`) the GMM it extends takes
    /// the number of components chosen for the frame mixture (`gmm.components()` is then unused).
    GmmTsc {
        /// The base mixture.
        gmm: GmmSettings,
        /// The TSC settings.
        tsc: KrishnanSettings,
    },
    /// Static GMR.
    Gmm(GmmSettings),
    /// Chooses among candidates by K-fold cross-validated prediction error of
    /// the robot's dims from the human's on the training demonstrations (folds of
    /// whole demonstrations), then refits the winner (or, with
    /// [`Selection::Mean`], the best `K`) on all of them.
    CrossValidated(CrossValidation),
}

impl Method {
    /// The fewest frames a demonstration needs for this method, and whether
    /// per demonstration (HMM states: every demonstration needs one frame per
    /// state) or in all (mixture components).
    pub fn min_frames(&self) -> (usize, bool) {
        match self {
            Method::Hmm(s) => (s.min_states(), true),
            Method::Hsmm(s) => (s.hmm().min_states(), true),
            Method::TscHmm(s) => (s.base().min_states(), true),
            Method::Gmm(s) => (s.components(), false),
            Method::GmmTsc { gmm, tsc } => {
                (tsc.components().map_or(2, |_| gmm.components()), false)
            }
            Method::CrossValidated(cv) => cv
                .candidates()
                .iter()
                .map(|(_, m)| m.min_frames())
                .fold((0, false), |(n, p), (m, q)| (n.max(m), p || q)),
        }
    }

    /// The regularisation `reg`, its unit and the emission of the method
    /// (`None` for a cross-validated choice: every candidate has its own).
    pub fn regularisation(&self) -> Option<(f64, RegUnits, EmissionKind)> {
        let hmm = |s: &HmmSettings| (s.reg(), s.reg_units(), s.emission());
        match self {
            Method::Hmm(s) => Some(hmm(s)),
            Method::Hsmm(s) => Some(hmm(s.hmm())),
            Method::TscHmm(s) => Some(hmm(s.base())),
            Method::Gmm(s) | Method::GmmTsc { gmm: s, .. } => {
                Some((s.reg(), s.reg_units(), s.emission()))
            }
            Method::CrossValidated(_) => None,
        }
    }

    /// Fits the method to joint training sequences (NaN values are missing).
    ///
    /// With a relative regularisation ([`RegUnits::Relative`], `reg = R`) the
    /// method is fitted unchanged on the features divided by their standard
    /// deviations `s_j = √v_j` over `data` and mapped back to the data's units
    /// ([`crate::reg_units`]): the regulariser is then `R · diag(v)`; with
    /// [`RegUnits::Positions`] the factors are [`crate::reg_units::position_scales`]
    /// (`R s_j²`: a velocity regularised by its position's variance). The
    /// summary's log-likelihoods and BIC values are those of the data's units
    /// (`log p(x) = log p(x / s) − Σ_observed log s_j`), and
    /// [`FitSummary::regularisation_per_feature`] holds `R · s_j²`.
    pub fn fit(&self, data: &SequenceSet, roles: &Roles) -> Result<(Model, FitSummary)> {
        let (model, mut summary) = match self.regularisation() {
            Some((reg, units @ (RegUnits::Relative | RegUnits::Positions), kind)) => {
                self.fit_relative(data, roles, reg, units, kind)?
            }
            _ => self.fit_inner(data, roles)?,
        };
        summary.missing_values = data.all_frames().missing_count();
        Ok((model, summary))
    }

    fn fit_relative(
        &self,
        data: &SequenceSet,
        roles: &Roles,
        reg: f64,
        units: RegUnits,
        kind: EmissionKind,
    ) -> Result<(Model, FitSummary)> {
        roles.check(data.dim())?;
        let s: Vec<f64> = match units {
            RegUnits::Positions => position_scales(data, roles)?,
            _ => feature_variances(data).iter().map(|v| v.sqrt()).collect(),
        };
        // Refuse an emission the mapping cannot return before spending the fit on it.
        kind.template(1, data.dim())?.scale_features(&s)?;
        let (model, mut summary) = self.fit_inner(&scale_data(data, &s)?, roles)?;
        let model = scale_model(&model, &s)?;
        // The density of x = S y is the density of y over |S| = Π s_j, per
        // observed value: every log-likelihood loses Σ_observed log s_j.
        let log_s: Vec<f64> = s.iter().map(|v| v.ln()).collect();
        let d = data.dim();
        let jacobian: f64 = data
            .all_frames()
            .as_slice()
            .iter()
            .enumerate()
            .filter(|(_, x)| !x.is_nan())
            .map(|(k, _)| log_s[k % d])
            .sum();
        summary
            .log_likelihood
            .iter_mut()
            .for_each(|ll| *ll -= jacobian);
        summary
            .bic
            .iter_mut()
            .for_each(|(_, b)| *b += 2.0 * jacobian);
        summary.regularisation_per_feature = s.iter().map(|s| reg * s * s).collect();
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
                    summary.with_selection(&sel);
                }
                Ok((Model::Hmm(hmm), summary))
            }
            Method::Hsmm(s) => {
                let (hsmm, r) = s.fit(data)?;
                Ok((Model::Hsmm(hsmm), FitSummary::from_hsmm(&r)))
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
                    summary.with_selection(sel);
                }
                summary.transition_segments = Some(r.segments);
                Ok((
                    Model::TscHmm {
                        model: m,
                        window: s.window(),
                    },
                    summary,
                ))
            }
            Method::Gmm(s) => {
                let f = s.em()?.fit(
                    &s.emission.template(s.components(), data.dim())?,
                    data.all_frames(),
                )?;
                Ok((Model::Gmm(f.model), FitSummary::from_gmm(&f.report)))
            }
            Method::CrossValidated(cv) => fit_cross_validated(cv, data, roles),
            Method::GmmTsc { gmm, tsc } => {
                let (ktsc, report) = tsc.fit(data)?;
                let components = match tsc.components() {
                    Some(_) => gmm.components(),
                    None => ktsc.mixture().n_components(),
                };
                let em = gmm.em()?;
                let frames = data.all_frames();
                let base = em.fit(&gmm.emission.template(components, data.dim())?, frames)?;
                let joined = join_mixtures(
                    &base.model,
                    ktsc.transition_mixture(),
                    ktsc.kept(),
                    &em,
                    frames,
                )?;
                let f = em.fit_from(joined, frames)?;
                let mut summary = FitSummary::from_gmm(&f.report);
                summary.fit_seconds += base.report.fit_seconds;
                if tsc.components().is_none() || tsc.transition_clusters().is_none() {
                    let note = |a: &Option<crate::select::AutoCount>| {
                        a.as_ref().map_or(String::new(), |a| a.lowered_note())
                    };
                    summary.chosen = Some(format!(
                        "{} frame components ({}{}), {} transition clusters kept of {}{}",
                        ktsc.mixture().n_components(),
                        tsc.selector(),
                        note(&report.frame_components),
                        ktsc.reported_clusters().len(),
                        ktsc.transition_mixture().n_components(),
                        note(&report.transition_clusters),
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

/// The starting mixture of `gmm-tsc`: `a`'s components and the `kept`
/// components of `b`.
///
/// Gaussian components are joined as they are, with the mixture weights in
/// proportion: `π = (π_a, π_b[kept]) / Σ`. Other emissions cannot be
/// concatenated in general, so the joined mixture's responsibilities of the
/// frames, `r_tj ∝ π_j p_j(x_t)` over the same `K_a + |kept|` components, start
/// one initialisation of that many components of `a`'s emission
/// ([`Emission::initialise`]); EM then runs from it as from the Gaussian join.
fn join_mixtures(
    a: &Gmm<AnyEmission>,
    b: &Gmm<AnyEmission>,
    kept: &[usize],
    em: &Em,
    frames: Frames<'_>,
) -> Result<Gmm<AnyEmission>> {
    if let (Some(ga), Some(gb)) = (a.components().as_gaussian(), b.components().as_gaussian()) {
        if ga.covariance_type() == CovarianceType::Full
            && gb.covariance_type() == CovarianceType::Full
        {
            return join_gaussian_mixtures(a.weights(), ga, b.weights(), gb, kept);
        }
    }
    let (n, ka) = (frames.len(), a.n_components());
    let k = ka + kept.len();
    let (la, lb) = (
        a.components().log_density(frames)?,
        b.components().log_density(frames)?,
    );
    let kb = b.n_components();
    let mut r = vec![0.0; n * k];
    for t in 0..n {
        let row = &mut r[t * k..(t + 1) * k];
        for j in 0..ka {
            row[j] = a.weights()[j].ln() + la[t * ka + j];
        }
        for (j, &c) in kept.iter().enumerate() {
            row[ka + j] = b.weights()[c].ln() + lb[t * kb + c];
        }
        let top = row.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if top.is_finite() {
            row.iter_mut().for_each(|v| *v = (*v - top).exp());
        } else {
            // A frame no component explains: spread it evenly.
            row.iter_mut().for_each(|v| *v = 1.0);
        }
        let total: f64 = row.iter().sum();
        row.iter_mut().for_each(|v| *v /= total);
    }
    let mut counts = vec![0.0; k];
    for row in r.chunks_exact(k) {
        counts.iter_mut().zip(row).for_each(|(c, v)| *c += v);
    }
    let template = a.components().kind().template(k, a.dim())?;
    let mut rng = ChaCha8Rng::seed_from_u64(em.seed());
    let (components, _) = template.initialise(&[(frames, &r)], em.regularisation(), &mut rng)?;
    Ok(Gmm::new(
        counts.iter().map(|c| c / n as f64).collect(),
        components,
    )?)
}

/// [`join_mixtures`] of full-covariance Gaussian components, weights in proportion.
fn join_gaussian_mixtures(
    wa: &[f64],
    ga: &Gaussian,
    wb: &[f64],
    gb: &Gaussian,
    kept: &[usize],
) -> Result<Gmm<AnyEmission>> {
    let d = ga.dim();
    let mut means = ga.means().to_vec();
    let mut covs = Vec::new();
    let mut weights: Vec<f64> = wa.to_vec();
    for k in 0..ga.n_states() {
        covs.extend(ga.covariance(k).iter().copied());
    }
    for &k in kept {
        means.extend_from_slice(gb.mean(k));
        covs.extend(gb.covariance(k).iter().copied());
        weights.push(wb[k]);
    }
    let total: f64 = weights.iter().sum();
    weights.iter_mut().for_each(|w| *w /= total);
    Ok(Gmm::new(
        weights,
        AnyEmission::Gaussian(Gaussian::full(d, means, covs)?),
    )?)
}
