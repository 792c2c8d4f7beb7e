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

use crate::data::{FeatureSpec, Layout};
use crate::error::{CliError, Result};
use phasekit_tsc::{FitSummary, Method, Model, Roles};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The `format` field of a model file.
pub const FORMAT: &str = "phasekit-model";
/// The model file version this build writes and reads.
pub const VERSION: u64 = 1;

/// Z-scoring of the features: `z = (x − mean) / std`, per feature.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Standardisation {
    /// Mean of every feature over the training frames.
    pub mean: Vec<f64>,
    /// Population standard deviation of every feature (1 where constant).
    pub std: Vec<f64>,
}

impl Standardisation {
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
    /// Always [`VERSION`] when written by this build.
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
}

#[derive(Deserialize)]
struct Header {
    format: Option<serde_json::Value>,
    version: Option<serde_json::Value>,
}

impl ModelFile {
    /// Wraps a fitted model.
    pub fn new(
        layout: Layout,
        feature_spec: FeatureSpec,
        standardisation: Option<Standardisation>,
        method: MethodInfo,
        fit: FitSummary,
        model: Model,
    ) -> Self {
        let roles = Roles {
            human: layout.human.clone(),
            robot: layout.robot.clone(),
        };
        ModelFile {
            format: FORMAT.into(),
            version: VERSION,
            phasekit: env!("CARGO_PKG_VERSION").into(),
            layout,
            feature_spec,
            standardisation,
            roles,
            method,
            fit,
            model,
        }
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
        let p = path.display();
        let header: Header = serde_json::from_str(text).map_err(|e| {
            // A file cut in the middle of a number or a word fails on its last
            // character rather than at "end of input": call that truncated too.
            let end_line = 1 + text.matches('\n').count();
            let end_col = text.len() - text.rfind('\n').map_or(0, |i| i + 1);
            let at_end = e.line() == end_line && e.column() + 1 >= end_col;
            let what = if e.is_eof() || (e.is_syntax() && at_end) {
                "it is truncated or empty"
            } else {
                "it is not valid JSON"
            };
            CliError::new(format!("{p}: not a phasekit model file ({what}: {e})"))
        })?;
        match header.format.as_ref().and_then(|f| f.as_str()) {
            Some(FORMAT) => {}
            Some(crate::library_file::FORMAT) => {
                return Err(crate::library_file::not_a_model(path))
            }
            Some(other) => {
                return Err(CliError::new(format!(
                    "{p}: not a phasekit model file (its format is `{other}`, not `{FORMAT}`)"
                )))
            }
            None => {
                return Err(CliError::new(format!(
                    "{p}: not a phasekit model file (no \"format\": \"{FORMAT}\" field)"
                )))
            }
        }
        match header.version.as_ref().and_then(|v| v.as_u64()) {
            Some(VERSION) => {}
            Some(v) => {
                return Err(CliError::new(format!(
                    "{p}: model file version {v} is not supported; this phasekit ({}) reads version {VERSION} — refit the model with this version",
                    env!("CARGO_PKG_VERSION")
                )))
            }
            None => return Err(CliError::new(format!("{p}: model file has no valid \"version\" number"))),
        }
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
        let l = &self.layout;
        let d = l.features.len();
        if self.model.dim() != d {
            return Err(CliError::new(format!(
                "the model has dimension {}, the layout {} features",
                self.model.dim(),
                d
            )));
        }
        if self.roles.human != l.human || self.roles.robot != l.robot {
            return Err(CliError::new("roles and layout disagree"));
        }
        self.roles.check(d)?;
        // The model's parts must agree (e.g. a union composition needs its union HMM),
        // and its recorded settings must be valid ones.
        self.model.validate()?;
        self.method.settings.validate()?;
        let hv = matches!(
            l.velocity,
            crate::data::Velocity::Both | crate::data::Velocity::Human
        );
        let rv = matches!(
            l.velocity,
            crate::data::Velocity::Both | crate::data::Velocity::Robot
        );
        let nh = l.human_columns.len() * if hv { 2 } else { 1 };
        let nr = l.robot_columns.len() * if rv { 2 } else { 1 };
        if l.human != (0..nh).collect::<Vec<_>>()
            || l.robot != (nh..nh + nr).collect::<Vec<_>>()
            || d != nh + nr
        {
            return Err(CliError::new(
                "the layout's feature indices do not match its columns",
            ));
        }
        if l.robot_positions.iter().any(|&j| j >= l.robot.len()) {
            return Err(CliError::new("robot position index out of range"));
        }
        if let Some(s) = &self.standardisation {
            if s.mean.len() != d || s.std.len() != d {
                return Err(CliError::new("standardisation has the wrong length"));
            }
            if s.mean.iter().chain(&s.std).any(|v| !v.is_finite())
                || s.std.iter().any(|v| *v <= 0.0)
            {
                return Err(CliError::new(
                    "standardisation holds a non-finite or non-positive value",
                ));
            }
        }
        Ok(())
    }

    /// Total number of states (components) used to predict.
    pub fn n_states(&self) -> usize {
        self.model.n_states()
    }
}
