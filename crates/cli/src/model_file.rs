//! The versioned model file written by `phasekit fit` and read by every
//! command that takes `--model`.
//!
//! ```json
//! {"format": "phasekit-model", "version": 1, "phasekit": "0.1.0",
//!  "layout": {...}, "feature_spec": {...}, "standardisation": null | {"mean": [...], "std": [...]},
//!  "roles": {"human": [...], "robot": [...]}, "method": {"spec": "tsc-hmm", "settings": {...}},
//!  "fit": {...}, "model": {...}}
//! ```
//!
//! Numbers are written with enough digits to read back bit for bit, so a model
//! loaded from its file predicts exactly as the one that was fitted.
//!
//! `"novelty"` (optional: files written before it existed load without it, and
//! then nothing is flagged as out of distribution) holds the threshold that
//! flags human input unlike the training data; see [`Novelty`].

use crate::data::{FeatureSpec, Layout};
use crate::error::{CliError, Result};
use crate::file_header::{check_header, FileKind};
use phasekit_emission::Frames;
use phasekit_tsc::{Calibration, FitSummary, Method, Model, Roles, StateMoments};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The `format` field of a model file.
pub const FORMAT: &str = "phasekit-model";
/// The newest model file version this build writes and reads.
///
/// * 1: HMM, TSC-HMM, GMM and gmm-tsc models;
/// * 2: adds the `hsmm` model (a left-right HSMM, HSMM-GMR);
/// * 3: `auto`'s covariance calibrated by left-out demonstrations (its rule
///   written by name, `"calibration": "demonstrations"`, which version-2
///   readers, who know it as a flag, cannot read) and the regularisation
///   relative to the positions (`"reg_units": "positions"`);
/// * 4: `auto`'s covariance calibrated for a new demonstration
///   (`"calibration": "predictive"`), with a covariance added to the model's
///   before scaling (`added_covariance`), which version-3 readers would ignore;
/// * 5: the mean of several models (`"kind": "ensemble"`, `auto`'s
///   `ensemble=K`), and `auto` settings that ask for it.
///
/// A file is written with the lowest version that describes its model
/// ([`version_for`]), so a model an older phasekit can use stays readable by
/// it; this build reads every version from 1 to [`VERSION`].
pub const VERSION: u64 = 5;

/// The lowest model-file version that describes `model` fitted by `method`
/// (see [`VERSION`]): 5 for the mean of several models; 4 for a covariance calibrated for a new demonstration
/// (`auto`'s `predictive` rule, which adds a covariance to the model's); 3
/// for what version-2 readers do not know — a
/// regularisation relative to the positions (`reg_units: "positions"`) or a
/// covariance calibrated by left-out demonstrations; 2 for what version-1
/// readers do not know — an HSMM, a mixture (`gmm`, `gmm-tsc`) whose
/// components are not Gaussians, or a method whose settings hold such a choice
/// (an `auto` grid with HSMM candidates), a regularisation relative to the
/// features' variances (`reg_units`), or a calibrated predictive covariance
/// (`auto`).
pub fn version_for(model: &Model, method: &Method) -> u64 {
    let model_needs_2 = match model {
        Model::Hsmm(_) => true,
        Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => g.components().as_gaussian().is_none(),
        Model::Hmm(_) | Model::TscHmm { .. } => false,
        Model::Ensemble(_) => return 5,
    };
    method_version(method).max(if model_needs_2 { 2 } else { 1 })
}

/// The lowest version whose readers know everything `method`'s settings hold.
fn method_version(method: &Method) -> u64 {
    let own = match method.regularisation() {
        // A relative regularisation would be read as absolute by a version-1
        // reader (a different model); version-2 readers do not know `positions`.
        Some((_, phasekit_tsc::RegUnits::Positions, _)) => 3,
        Some((_, phasekit_tsc::RegUnits::Relative, _)) => 2,
        _ => 1,
    };
    let kind = match method {
        Method::Hsmm(_) => 2,
        Method::Gmm(s) | Method::GmmTsc { gmm: s, .. } if !s.emission().is_default() => 2,
        // A calibrated covariance (`auto`) would be ignored by a version-1
        // reader (the same mean with other bands); version-2 readers know the
        // calibration as a flag, not the rule by name.
        Method::CrossValidated(cv) => cv
            .candidates()
            .iter()
            .map(|(_, m)| method_version(m))
            .chain([match cv.calibration() {
                Calibration::Off => 1,
                Calibration::Frames => 2,
                Calibration::Demonstrations => 3,
                Calibration::Predictive => 4,
            }])
            .chain([match cv.selection() {
                phasekit_tsc::Selection::Mean(_) => 5,
                _ => 1,
            }])
            .max()
            .unwrap_or(1),
        _ => 1,
    };
    own.max(kind)
}

/// Z-scoring of the features: `z = (x − mean) / std`, per feature.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Standardisation {
    /// Mean of every feature over the training frames.
    pub mean: Vec<f64>,
    /// Population standard deviation of every feature (1 where constant).
    pub std: Vec<f64>,
}

impl Standardisation {
    /// Checks a standardisation read from a file against `d` features: one
    /// finite mean and one finite positive std per feature.
    pub fn check(&self, d: usize) -> Result<()> {
        if self.mean.len() != d || self.std.len() != d {
            return Err(CliError::new("standardisation has the wrong length"));
        }
        if self.mean.iter().chain(&self.std).any(|v| !v.is_finite())
            || self.std.iter().any(|v| *v <= 0.0)
        {
            return Err(CliError::new(
                "standardisation holds a non-finite or non-positive value",
            ));
        }
        Ok(())
    }

    /// Per-feature mean and std of all frames of `seqs` (`T × d` each), over
    /// the observed values (NaN = missing is left out; a feature never
    /// observed gets mean 0 and std 1).
    pub fn fit<S: AsRef<[f64]>>(seqs: &[S], d: usize) -> Self {
        let frames = || seqs.iter().flat_map(|s| s.as_ref().chunks_exact(d));
        let mut mean = vec![0.0; d];
        let mut n = vec![0.0; d];
        for f in frames() {
            for k in 0..d {
                if !f[k].is_nan() {
                    mean[k] += f[k];
                    n[k] += 1.0;
                }
            }
        }
        mean.iter_mut()
            .zip(&n)
            .for_each(|(m, n)| *m /= f64::max(*n, 1.0));
        let mut var = vec![0.0; d];
        for f in frames() {
            for k in 0..d {
                if !f[k].is_nan() {
                    var[k] += (f[k] - mean[k]).powi(2);
                }
            }
        }
        let std = var
            .iter()
            .zip(&n)
            .map(|(q, n)| (q / f64::max(*n, 1.0)).sqrt())
            .map(|s| if s > 1e-12 && s.is_finite() { s } else { 1.0 })
            .collect();
        Standardisation { mean, std }
    }

    /// Standardises, in place, frames whose dims are the features `dims`.
    pub fn apply(&self, frames: &mut [f64], dims: &[usize]) {
        for f in frames.chunks_exact_mut(dims.len()) {
            for (v, &k) in f.iter_mut().zip(dims) {
                *v = (*v - self.mean[k]) / self.std[k];
            }
        }
    }

    /// Maps standardised means of the features `dims` back to data units, in place.
    pub fn unapply_mean(&self, frames: &mut [f64], dims: &[usize]) {
        for f in frames.chunks_exact_mut(dims.len()) {
            for (v, &k) in f.iter_mut().zip(dims) {
                *v = *v * self.std[k] + self.mean[k];
            }
        }
    }

    /// `roles` with the deviations of the robot's features as their error
    /// units ([`Roles::with_error_units`]): a cross-validated choice (`auto`)
    /// fitted on the z-scores then judges its error in the data's units, the
    /// choice made without z-scoring.
    pub fn error_units_of(&self, roles: Roles) -> Result<Roles> {
        let units = roles.robot().iter().map(|&k| self.std[k]).collect();
        Ok(roles.with_error_units(units)?)
    }

    /// Maps standardised `O × O` covariances of the features `dims` back to data units, in place.
    pub fn unapply_cov(&self, covs: &mut [f64], dims: &[usize]) {
        let o = dims.len();
        for c in covs.chunks_exact_mut(o * o) {
            for i in 0..o {
                for j in 0..o {
                    c[i * o + j] *= self.std[dims[i]] * self.std[dims[j]];
                }
            }
        }
    }
}

/// Calibration of the out-of-distribution flag of `predict` and `stream`.
///
/// Every frame is scored by the log predictive density of its observed human
/// features, `log p(x_t | x_{1:t−1})` under the forward filter of the model
/// that predicts (`log p(x_t)` for a mixture), divided by the number of
/// observed feature values (nats per value, so that frames with missing values
/// compare with complete ones). At fit time every frame of the training
/// demonstrations is scored the same way; with `low` their 0.1 % quantile and
/// `median` their median,
///
/// `threshold = low − max(median − low, 1)`,
///
/// i.e. a frame is flagged when it is as far below the least likely training
/// frames as those are below the typical one (at least one nat per value, a
/// density e times lower per value, when the training frames are all alike).
/// Test data of the training distribution stays above it; data in another
/// coordinate frame or unit falls far below (see `crates/cli/tests/novelty.rs`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Novelty {
    /// Frames scoring below this (nats per observed value) are flagged.
    pub threshold: f64,
    /// The training frames' 0.1 % quantile of the score.
    pub low: f64,
    /// Their median score.
    pub median: f64,
    /// How many training frames were scored (those with something observed).
    pub frames: usize,
}

/// The smallest margin between the 0.1 % quantile and the threshold (nats per value).
const NOVELTY_MIN_MARGIN: f64 = 1.0;

impl Novelty {
    /// Calibrates on the scores of the training frames (see the type's documentation).
    pub fn from_scores(mut scores: Vec<f64>) -> Option<Novelty> {
        scores.retain(|s| s.is_finite());
        if scores.is_empty() {
            return None;
        }
        scores.sort_by(f64::total_cmp);
        let q = |p: f64| {
            scores[((p * (scores.len() - 1) as f64).round() as usize).min(scores.len() - 1)]
        };
        let (low, median) = (q(0.001), q(0.5));
        Some(Novelty {
            threshold: low - (median - low).max(NOVELTY_MIN_MARGIN),
            low,
            median,
            frames: scores.len(),
        })
    }
}

/// The method a model was fitted with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodInfo {
    /// As given on the command line (`tsc-hmm:states=5`).
    pub spec: String,
    /// Every setting.
    pub settings: Method,
}

/// A model file's content.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelFile {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`version_for`] the model when written by this build (at most [`VERSION`]).
    pub version: u64,
    /// The phasekit version that wrote it.
    #[serde(default)]
    pub phasekit: String,
    /// The features the model sees.
    pub layout: Layout,
    /// The column selection the layout was resolved from.
    pub feature_spec: FeatureSpec,
    /// Z-scoring applied to the features before the model, if any.
    pub standardisation: Option<Standardisation>,
    /// The human's (input) and robot's (output) features.
    pub roles: Roles,
    /// The method.
    pub method: MethodInfo,
    /// What the fit did.
    pub fit: FitSummary,
    /// The fitted model.
    pub model: Model,
    /// Calibration of the out-of-distribution flag (absent in older files).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub novelty: Option<Novelty>,
}

impl ModelFile {
    /// Wraps a fitted model.
    pub fn new(
        layout: Layout,
        feature_spec: FeatureSpec,
        standardisation: Option<Standardisation>,
        roles: Roles,
        method: MethodInfo,
        fit: FitSummary,
        model: Model,
    ) -> Self {
        ModelFile {
            format: FORMAT.into(),
            version: version_for(&model, &method.settings),
            phasekit: env!("CARGO_PKG_VERSION").into(),
            layout,
            feature_spec,
            standardisation,
            roles,
            method,
            fit,
            model,
            novelty: None,
        }
    }

    /// The same model file with its out-of-distribution threshold calibrated on
    /// the training demonstrations `seqs` (joint features as the model sees
    /// them, `T × D` each): see [`Novelty`].
    pub fn calibrated(mut self, seqs: &[Vec<f64>]) -> Result<Self> {
        let d = self.layout.features.len();
        let human = &self.layout.human;
        let predictor = self.model.predictor(&self.roles)?;
        let mut scores = Vec::new();
        for q in seqs {
            let h: Vec<f64> = q
                .chunks_exact(d)
                .flat_map(|f| human.iter().map(move |&k| f[k]))
                .collect();
            let frames = Frames::new(&h, human.len())?;
            let p = predictor.predict(frames, false)?;
            for (f, lp) in h.chunks_exact(human.len()).zip(&p.log_predictive) {
                let n = f.iter().filter(|v| !v.is_nan()).count();
                if let Some(s) = crate::pipeline::score(*lp, n) {
                    scores.push(s);
                }
            }
        }
        self.novelty = Novelty::from_scores(scores);
        Ok(self)
    }

    /// The JSON text of the file.
    pub fn to_json(&self) -> Result<String> {
        serde_json::to_string_pretty(self)
            .map_err(|e| CliError::new(format!("cannot serialise the model: {e}")))
    }

    /// Writes the file atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = self.to_json()?;
        crate::output::write_string(path, &(text + "\n"))
    }

    /// Parses a model file's text; `path` names it in errors.
    pub fn from_json(text: &str, path: &Path) -> Result<Self> {
        check_header(
            text,
            path,
            &FileKind {
                format: FORMAT,
                oldest: 1,
                version: VERSION,
                noun: "model file",
                remedy: "refit the model",
            },
            &[(
                crate::library_file::FORMAT,
                &crate::library_file::not_a_model,
            )],
        )?;
        let p = path.display();
        let file: ModelFile = serde_json::from_str(text)
            .map_err(|e| CliError::new(format!("{p}: corrupted model file: {e}")))?;
        file.validate()
            .map_err(|e| e.context(format!("{p}: corrupted model file")))?;
        Ok(file)
    }

    /// Reads and checks a model file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            CliError::new(format!("{}: cannot read model file: {e}", path.display()))
        })?;
        Self::from_json(&text, path)
    }

    /// Checks that the parts agree with each other.
    pub fn validate(&self) -> Result<()> {
        if self.version < version_for(&self.model, &self.method.settings) {
            return Err(CliError::new(format!(
                "version {} does not describe its model and settings (they need version {} or later: \
                 an hsmm model, non-Gaussian mixtures or a relative regularisation 2, a covariance \
                 calibrated by left-out demonstrations or a regularisation in positions' variances 3, \
                 a covariance calibrated for a new demonstration 4, the mean of several models 5)",
                self.version,
                version_for(&self.model, &self.method.settings)
            )));
        }
        let l = &self.layout;
        let d = l.features.len();
        if self.model.dim() != d {
            return Err(CliError::new(format!(
                "the model has dimension {}, the layout {} features",
                self.model.dim(),
                d
            )));
        }
        if self.roles.human() != l.human || self.roles.robot() != l.robot {
            return Err(CliError::new("roles and layout disagree"));
        }
        self.roles.check(d)?;
        // The model's parts must agree (e.g. a union composition needs its union HMM;
        // its recorded settings were validated when read).
        self.model.validate()?;
        for (what, g) in gaussians(&self.model) {
            check_scale(what, g)?;
        }
        if let Some(n) = &self.novelty {
            if !(n.threshold.is_finite() && n.low.is_finite() && n.median.is_finite()) {
                return Err(CliError::new(
                    "the out-of-distribution threshold (\"novelty\") is not a finite number",
                ));
            }
        }
        l.check_indices().map_err(CliError::new)?;
        if let Some(s) = &self.standardisation {
            s.check(d)?;
        }
        // The calibration's scale and added covariance (finite, the robot's
        // size, symmetric positive semi-definite), which only version 4
        // readers apply.
        if let Some(c) = &self.fit.covariance_calibration {
            if !c.added_covariance.is_empty() && self.version < 4 {
                return Err(CliError::new(format!(
                    "version {} does not describe its calibration: an added covariance needs version 4",
                    self.version
                )));
            }
            self.model
                .predictor(&self.roles)
                .and_then(|p| p.with_calibration(&self.fit))
                .map_err(|e| CliError::new(format!("covariance calibration: {e}")))?;
        }
        Ok(())
    }

    /// Total number of states (components) used to predict.
    pub fn n_states(&self) -> usize {
        self.model.n_states()
    }
}

/// Every emission of a model, with what it is.
fn gaussians(model: &Model) -> Vec<(&'static str, &dyn StateMoments)> {
    match model {
        Model::Hmm(h) => vec![("the HMM", h.emission() as &dyn StateMoments)],
        Model::Hsmm(h) => vec![("the HSMM", h.emission() as &dyn StateMoments)],
        Model::TscHmm { model, .. } => {
            let mut v: Vec<(&'static str, &dyn StateMoments)> = vec![
                ("the base HMM", model.base().emission()),
                ("the transition HMM", model.transition().emission()),
            ];
            if let Some(u) = model.union() {
                v.push(("the union HMM", u.emission()));
            }
            v
        }
        Model::Gmm(g) => vec![("the mixture", g.components() as &dyn StateMoments)],
        Model::Ensemble(members) => members.iter().flat_map(|m| gaussians(&m.model)).collect(),
        Model::GmmTsc { tsc, mixture } => vec![
            ("the mixture", mixture.components() as &dyn StateMoments),
            ("the windowed mixture", tsc.mixture().components()),
            (
                "the transition mixture",
                tsc.transition_mixture().components(),
            ),
        ],
    }
}

/// Largest ratio of a mean's magnitude to its standard deviation: beyond
/// `2^52`, neighbouring floating-point numbers at the mean are farther apart
/// than the state is wide, and the state cannot describe any data.
const MAX_MEAN_TO_SPREAD: f64 = 4_503_599_627_370_496.0;

/// Refuses a state whose means are too large for its spread to be represented
/// (e.g. means of 1e200 with variances of 1e-2).
fn check_scale(what: &str, g: &dyn StateMoments) -> Result<()> {
    for k in 0..g.moment_states() {
        let (mean, cov) = (g.state_mean(k), g.state_covariance(k));
        for (d, m) in mean.iter().enumerate() {
            let sd = cov[(d, d)].sqrt();
            let resolvable = m.is_finite() && sd > 0.0 && m.abs() <= MAX_MEAN_TO_SPREAD * sd;
            if !resolvable {
                return Err(CliError::new(format!(
                    "{what}, state {k}, dimension {d}: mean {m:e} with standard deviation {sd:e}: \
                     floating-point numbers cannot resolve a state that narrow that far from zero"
                )));
            }
        }
    }
    Ok(())
}
