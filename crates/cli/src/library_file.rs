//! The versioned library file written by `phasekit fit --library` and read by
//! `recognise`, `stream` and `plot recognition`.
//!
//! ```json
//! {"format": "phasekit-library", "version": 1, "phasekit": "0.1.0",
//!  "layout": {...}, "feature_spec": {...}, "standardisation": null | {...},
//!  "method": {"spec": "hmm", "settings": {...}},
//!  "actions": [{"name": "handshake", "demonstrations": [...], "frames": 2281, "fit": {...}}, ...],
//!  "library": {"actions": [{"name", "model", "exit", "end", "demonstrations"}, ...],
//!              "roles", "prior", "rest", "calibration"}}
//! ```
//!
//! The version follows the model files' ([`crate::model_file::VERSION`]): a
//! library is written with the lowest version whose readers know every
//! action's model and method (and its recognition model's), so that a
//! phasekit too old for an HSMM or a mean of several models says so by
//! version instead of failing to parse; a hidden-Markov-only library stays
//! version 1. (Libraries written before 2026-12-07 say 1 whatever they hold;
//! they read as before.)
//!
//! A single model file (`"format": "phasekit-model"`) is refused with a
//! message saying what it is, and the model file reader refuses a library
//! the same way. Numbers are written so that they read back bit for bit.

use crate::data::{FeatureSpec, Layout, Table, Velocity};
use crate::error::{CliError, Result};
use crate::file_header::{check_header, FileKind};
use crate::model_file::{version_for, MethodInfo, Standardisation};
use crate::pipeline::{column_indices, Differencer};
use phasekit_recognition::Library;
use phasekit_tsc::{FitSummary, Method};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The `format` field of a library file.
pub const FORMAT: &str = "phasekit-library";
/// The newest library file version this build writes and reads: the model
/// files' ([`crate::model_file::VERSION`]; see the module docs).
pub const VERSION: u64 = crate::model_file::VERSION;

/// The lowest library version whose readers know every action's model
/// fitted by `methods[i]` (in the library's order) and, with `recognition`,
/// every action's recognition model: the highest
/// [`crate::model_file::version_for`] among them.
pub fn version_for_library(
    library: &Library,
    methods: &[&Method],
    recognition: Option<&Method>,
) -> u64 {
    library
        .actions()
        .iter()
        .zip(methods)
        .flat_map(|(a, m)| {
            let own = version_for(&a.model, m);
            let second = match (&a.recognition, recognition) {
                (Some(r), Some(rm)) => version_for(r, rm),
                _ => 1,
            };
            [own, second]
        })
        .max()
        .unwrap_or(1)
}

/// What was fitted for one action.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ActionInfo {
    /// The action's name (its folder's).
    pub name: String,
    /// Its training files.
    pub demonstrations: Vec<PathBuf>,
    /// Training frames.
    pub frames: usize,
    /// What the fit did.
    pub fit: FitSummary,
    /// The action's own method (`--action-method`), when not the library's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method: Option<String>,
}

/// A library file's content.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LibraryFile {
    /// Always [`FORMAT`].
    pub format: String,
    /// The lowest version that describes it when written by this build
    /// ([`version_for_library`], at most [`VERSION`]).
    pub version: u64,
    /// The phasekit version that wrote it.
    #[serde(default)]
    pub phasekit: String,
    /// The features every action's model sees.
    pub layout: Layout,
    /// The column selection the layout was resolved from.
    pub feature_spec: FeatureSpec,
    /// Z-scoring applied to the features before the models (one for all actions), if any.
    pub standardisation: Option<Standardisation>,
    /// The method every action was fitted with.
    pub method: MethodInfo,
    /// The method of the second model per action that recognises
    /// (`--recognition-method`), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recognition_method: Option<String>,
    /// What was fitted for each action, in the library's order.
    pub actions: Vec<ActionInfo>,
    /// The library.
    pub library: Library,
}

/// `Some(format)` of a JSON file that has a string `format` field.
pub use crate::file_header::file_format;

/// The error of a command that needs a single model and was given a library.
pub fn not_a_model(path: &Path) -> CliError {
    CliError::new(format!(
        "{}: this is a library of interactions (made by `fit --library`), not a single model: \
         use it with `phasekit recognise`, `phasekit stream` or `phasekit plot recognition`; \
         this command needs a model file made by `phasekit fit` without --library",
        path.display()
    ))
}

impl LibraryFile {
    /// Wraps a fitted library whose actions were fitted by `methods` (one per
    /// action, in the library's order: the library's method or the action's
    /// own) and recognised by `recognition`'s models, if any; the version is
    /// the lowest that describes them ([`version_for_library`]).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        layout: Layout,
        feature_spec: FeatureSpec,
        standardisation: Option<Standardisation>,
        method: MethodInfo,
        actions: Vec<ActionInfo>,
        library: Library,
        methods: &[&Method],
        recognition: Option<&Method>,
    ) -> Self {
        LibraryFile {
            format: FORMAT.into(),
            version: version_for_library(&library, methods, recognition),
            phasekit: env!("CARGO_PKG_VERSION").into(),
            layout,
            feature_spec,
            standardisation,
            method,
            recognition_method: None,
            actions,
            library,
        }
    }

    /// The methods in words: `hmm`, `hmm, recognised by hmm:states=12,reg=0.001`,
    /// `hmm (rocket: tsc-hmm)`.
    pub fn methods_text(&self) -> String {
        let mut s = self.method.spec.clone();
        let own: Vec<String> = self
            .actions
            .iter()
            .filter_map(|a| a.method.as_ref().map(|m| format!("{}: {m}", a.name)))
            .collect();
        if !own.is_empty() {
            s += &format!(" ({})", own.join(", "));
        }
        if let Some(r) = &self.recognition_method {
            s += &format!(", recognised by {r}");
        }
        s
    }

    /// Writes the file atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)
            .map_err(|e| CliError::new(format!("cannot serialise the library: {e}")))?;
        crate::output::write_string(path, &(text + "\n"))
    }

    /// Parses a library file's text; `path` names it in errors.
    pub fn from_json(text: &str, path: &Path) -> Result<Self> {
        check_header(
            text,
            path,
            &FileKind {
                format: FORMAT,
                oldest: 1,
                version: VERSION,
                noun: "library file",
                remedy: "refit the library",
            },
            &[(crate::model_file::FORMAT, &|p: &Path| {
                CliError::new(format!(
                    "{}: this is a single model (made by `phasekit fit`), not a library of interactions: \
                     fit a library with `phasekit fit --data DIR --library -o library.json` (DIR a folder of action folders)",
                    p.display()
                ))
            })],
        )?;
        let p = path.display();
        let file: LibraryFile = serde_json::from_str(text)
            .map_err(|e| CliError::new(format!("{p}: corrupted library file: {e}")))?;
        file.validate()
            .map_err(|e| e.context(format!("{p}: corrupted library file")))?;
        Ok(file)
    }

    /// Reads and checks a library file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            CliError::new(format!("{}: cannot read library file: {e}", path.display()))
        })?;
        Self::from_json(&text, path)
    }

    /// Checks that the parts agree (the library itself was checked when read).
    pub fn validate(&self) -> Result<()> {
        let l = &self.layout;
        let d = l.features.len();
        let roles = self.library.roles();
        if self.library.dim() != d {
            return Err(CliError::new(format!(
                "the library's models have dimension {}, the layout {d} features",
                self.library.dim()
            )));
        }
        if roles.human() != l.human || roles.robot() != l.robot {
            return Err(CliError::new("the library's roles and the layout disagree"));
        }
        l.check_indices().map_err(CliError::new)?;
        let names: Vec<&str> = self.actions.iter().map(|a| a.name.as_str()).collect();
        if names != self.library.names() {
            return Err(CliError::new(format!(
                "the actions ({}) are not the library's ({})",
                names.join(", "),
                self.library.names().join(", ")
            )));
        }
        // The method's settings were validated when read (the presets' settings deserialise checked).
        if let Some(s) = &self.standardisation {
            s.check(d)?;
        }
        Ok(())
    }

    /// The human's features of a table as the library's models see them
    /// (velocities computed causally, standardised if the library was), `T × H`.
    pub fn human_input(&self, table: &Table) -> Result<Vec<f64>> {
        let cols = column_indices(table, &self.layout.human_columns, "human")?;
        let velocity = matches!(self.layout.velocity, Velocity::Both | Velocity::Human);
        let width = table.columns.len();
        let mut diff = Differencer::new(velocity);
        let mut out = Vec::with_capacity(table.n_rows() * self.layout.human.len());
        let mut raw = vec![0.0; cols.len()];
        for row in table.data.chunks_exact(width) {
            for (r, &c) in raw.iter_mut().zip(&cols) {
                *r = row[c];
            }
            diff.push(&raw, &mut out);
        }
        if let Some(s) = &self.standardisation {
            s.apply(&mut out, &self.layout.human);
        }
        Ok(out)
    }

    /// Names of the robot's features.
    pub fn robot_features(&self) -> Vec<&str> {
        self.layout
            .robot
            .iter()
            .map(|&k| self.layout.features[k].as_str())
            .collect()
    }

    /// Maps a robot mean (and covariance) from the models' units back to the data's, in place.
    pub fn to_data_units(&self, mean: &mut [f64], covariance: Option<&mut [f64]>) {
        if let Some(s) = &self.standardisation {
            s.unapply_mean(mean, &self.layout.robot);
            if let Some(c) = covariance {
                s.unapply_cov(c, &self.layout.robot);
            }
        }
    }
}
