//! The interaction pipeline of the `phasekit` command, through the
//! `phasekit_cli` library: fitting a method (`hmm`, `tsc-hmm`, …) to
//! demonstrations with named columns, predicting the robot from the human,
//! segmenting, the frame-by-frame predictor, model files, and the readers of
//! demonstration files. Every call into `phasekit_cli` is in this file.

use crate::arrays::{array1, array2, array3, matrix, pool, runtime_error, value_error};
use crate::gmr::{read_frame, MeanAndCovariance};
use numpy::{PyArray1, PyArray2, PyReadonlyArray2};
use phasekit::tsc::{OnlinePredictor, Predictor, PresetOptions};
use phasekit_cli::commands::fit::fit_tables;
use phasekit_cli::data::{self, FeatureSpec, Table, Velocity};
use phasekit_cli::model_file::{ModelFile, Standardisation};
use phasekit_cli::pipeline::{self, Differencer};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::path::{Path, PathBuf};

fn cli_error(e: impl std::fmt::Display) -> PyErr {
    value_error(e)
}

/// A table (one demonstration) from a name, column names and `(T, C)` values.
fn table(name: String, columns: Vec<String>, x: &PyReadonlyArray2<'_, f64>) -> PyResult<Table> {
    let (values, t, c) = matrix(x, &name)?;
    if c != columns.len() {
        return Err(PyValueError::new_err(format!(
            "{name}: {c} columns of values but {} column names",
            columns.len()
        )));
    }
    if let Some(i) = values.iter().position(|v| v.is_infinite()) {
        return Err(PyValueError::new_err(format!(
            "{name}: frame {}, column `{}`: not a finite number ({}); write NaN for a missing value",
            i / c,
            columns[i % c],
            values[i]
        )));
    }
    let _ = t;
    Ok(Table {
        path: PathBuf::from(name),
        header: columns.clone(),
        columns,
        data: values.to_vec(),
    })
}

fn velocity(v: &str) -> PyResult<Velocity> {
    Ok(match v {
        "both" => Velocity::Both,
        "human" => Velocity::Human,
        "robot" => Velocity::Robot,
        "none" => Velocity::None,
        other => {
            return Err(PyValueError::new_err(format!(
                "velocity must be 'both', 'human', 'robot' or 'none', not {other:?}"
            )))
        }
    })
}

/// The command's preset options with the given overrides (a JSON object whose
/// keys are the options' names: `states`, `tsc_states`, `window`, `reg`,
/// `max_iter`, `tol`, `restarts`, `seed`, …); an unknown key is an error.
fn preset_options(overrides: &str) -> PyResult<PresetOptions> {
    let mut base = option_defaults()?;
    let given: serde_json::Map<String, serde_json::Value> = serde_json::from_str(overrides)
        .map_err(|e| PyValueError::new_err(format!("options: {e}")))?;
    let fields = base
        .as_object_mut()
        .ok_or_else(|| runtime_error("preset options are not an object"))?;
    for (k, v) in given {
        if !fields.contains_key(&k) {
            let mut known: Vec<&String> = fields.keys().collect();
            known.sort();
            return Err(PyValueError::new_err(format!(
                "unknown option `{k}` (options: {})",
                known
                    .iter()
                    .map(|s| s.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
        fields.insert(k, v);
    }
    serde_json::from_value(base).map_err(|e| PyValueError::new_err(format!("options: {e}")))
}

/// Every option and its default value, as a JSON object: the serialised
/// defaults, plus the options whose default the serialisation leaves out (so
/// that files written before they existed stay as they were) — `emission`,
/// `duration`, `max_duration`, `reg_units` — which are options all the same.
fn option_defaults() -> PyResult<serde_json::Value> {
    let d = PresetOptions::default();
    let mut base = serde_json::to_value(&d).map_err(runtime_error)?;
    let fields = base
        .as_object_mut()
        .ok_or_else(|| runtime_error("preset options are not an object"))?;
    let value = |v: serde_json::Result<serde_json::Value>| v.map_err(runtime_error);
    for (k, v) in [
        ("emission", value(serde_json::to_value(d.emission()))?),
        ("duration", value(serde_json::to_value(d.duration()))?),
        (
            "max_duration",
            value(serde_json::to_value(d.max_duration()))?,
        ),
        ("reg_units", value(serde_json::to_value(d.reg_units()))?),
    ] {
        fields.entry(k).or_insert(v);
    }
    Ok(base)
}

/// Option names and default values of the command's methods, as JSON.
#[pyfunction]
pub fn default_options() -> PyResult<String> {
    serde_json::to_string(&option_defaults()?).map_err(runtime_error)
}

/// A fitted interaction model: a model file's content and its predictor.
#[pyclass(module = "phasekit._core", frozen)]
pub struct InteractionCore {
    file: ModelFile,
    predictor: Predictor,
}

impl InteractionCore {
    fn from_file(file: ModelFile) -> PyResult<Self> {
        let predictor = pipeline::predictor(&file).map_err(cli_error)?;
        Ok(InteractionCore { file, predictor })
    }
}

/// `(names, values)` of a table.
type NamedTable<'py> = (String, Vec<String>, PyReadonlyArray2<'py, f64>);

#[pymethods]
impl InteractionCore {
    /// Fits `method` (the command's `--method`, e.g. `"tsc-hmm"`,
    /// `"hmm:states=7"`) to demonstrations `(name, columns, values)`, with
    /// the human's and the robot's columns chosen by name or glob pattern.
    #[staticmethod]
    #[pyo3(signature = (demos, human, robot, method, velocity_="both", standardise=false, options="{}", n_threads=1))]
    #[allow(clippy::too_many_arguments)]
    fn fit(
        py: Python<'_>,
        demos: Vec<NamedTable<'_>>,
        human: Vec<String>,
        robot: Vec<String>,
        method: &str,
        velocity_: &str,
        standardise: bool,
        options: &str,
        n_threads: usize,
    ) -> PyResult<Self> {
        if demos.is_empty() {
            return Err(PyValueError::new_err("no demonstration to fit"));
        }
        let tables = demos
            .into_iter()
            .map(|(name, cols, x)| table(name, cols, &x))
            .collect::<PyResult<Vec<_>>>()?;
        data::check_same_columns(&tables).map_err(cli_error)?;
        let spec = FeatureSpec {
            human,
            robot,
            velocity: velocity(velocity_)?,
        };
        let options = preset_options(options)?;
        let pool = pool(n_threads)?;
        let file = py
            .allow_threads(|| {
                pool.install(|| fit_tables(&tables, &spec, false, method, &options, standardise))
            })
            .map_err(cli_error)?;
        Self::from_file(file)
    }

    /// Reads a model file written by `phasekit fit` or [`InteractionCore::save`].
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Self::from_file(ModelFile::load(&path).map_err(cli_error)?)
    }

    /// Parses a model file's text (`name` appears in errors).
    #[staticmethod]
    #[pyo3(signature = (text, name="<model>"))]
    fn from_json(text: &str, name: &str) -> PyResult<Self> {
        Self::from_file(ModelFile::from_json(text, Path::new(name)).map_err(cli_error)?)
    }

    /// Writes the model file (atomically), as `phasekit fit -o` does.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.file.save(&path).map_err(cli_error)
    }

    /// The model file's text.
    fn to_json(&self) -> PyResult<String> {
        self.file.to_json().map_err(cli_error)
    }

    /// The method as given (`tsc-hmm`, `hmm:states=7`).
    #[getter]
    fn method(&self) -> String {
        self.file.method.spec.clone()
    }

    /// Total states (components) of the model that predicts.
    #[getter]
    fn n_states(&self) -> usize {
        self.file.n_states()
    }

    /// Names of the human's raw columns the model reads.
    #[getter]
    fn human_columns(&self) -> Vec<String> {
        self.file.layout.human_columns.clone()
    }

    /// Names of the robot's raw columns.
    #[getter]
    fn robot_columns(&self) -> Vec<String> {
        self.file.layout.robot_columns.clone()
    }

    /// Names of the model's features (columns, then velocities `d_…`).
    #[getter]
    fn features(&self) -> Vec<String> {
        self.file.layout.features.clone()
    }

    /// Names of the predicted robot features.
    #[getter]
    fn robot_features(&self) -> Vec<String> {
        self.file
            .layout
            .robot
            .iter()
            .map(|&k| self.file.layout.features[k].clone())
            .collect()
    }

    /// Whether features are z-scored inside the model.
    #[getter]
    fn standardised(&self) -> bool {
        self.file.standardisation.is_some()
    }

    /// What the fit did (iterations, log-likelihoods, warnings…), as JSON.
    fn fit_summary(&self) -> PyResult<String> {
        serde_json::to_string(&self.file.fit).map_err(runtime_error)
    }

    /// `(mean (T, O), covariance (T, O, O) or None)` of the robot's features
    /// in data units, from a table holding (at least) the human's columns.
    #[pyo3(signature = (name, columns, x, with_covariance=true))]
    #[allow(clippy::type_complexity)]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        name: String,
        columns: Vec<String>,
        x: PyReadonlyArray2<'py, f64>,
        with_covariance: bool,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Option<Bound<'py, PyAny>>)> {
        let t = table(name, columns, &x)?;
        let p = py
            .allow_threads(|| {
                pipeline::predict_table(&self.file, &self.predictor, &t, with_covariance)
            })
            .map_err(cli_error)?;
        let (n, o) = (p.len(), p.n_out);
        let cov = match p.covariance {
            Some(c) => Some(array3(py, c, (n, o, o))?.into_any()),
            None => None,
        };
        Ok((array2(py, p.mean, n, o)?, cov))
    }

    /// `(states (T,), transition frames, their clusters (-1: none))` of a
    /// demonstration holding the human's and the robot's columns.
    #[allow(clippy::type_complexity)]
    fn segment<'py>(
        &self,
        py: Python<'py>,
        name: String,
        columns: Vec<String>,
        x: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<(
        Bound<'py, PyArray1<i64>>,
        Bound<'py, PyArray1<i64>>,
        Bound<'py, PyArray1<i64>>,
    )> {
        let t = table(name, columns, &x)?;
        let s = py
            .allow_threads(|| pipeline::segment_table(&self.file, &t))
            .map_err(cli_error)?;
        let labels = s.labels.iter().map(|&v| v as i64).collect();
        let transitions = s.transitions.iter().map(|&v| v as i64).collect();
        let clusters = s
            .clusters
            .iter()
            .map(|c| c.map_or(-1, |v| v as i64))
            .collect();
        Ok((
            array1(py, labels),
            array1(py, transitions),
            array1(py, clusters),
        ))
    }

    /// A frame-by-frame predictor taking raw human frames (the model's human
    /// columns, in order), as `phasekit stream` does.
    fn online(&self) -> OnlineInteraction {
        let l = &self.file.layout;
        let o = l.robot.len();
        let human_velocity = matches!(l.velocity, Velocity::Both | Velocity::Human);
        OnlineInteraction {
            online: self.predictor.online(),
            diff: Differencer::new(human_velocity),
            standardisation: self.file.standardisation.clone(),
            human: l.human.clone(),
            robot: l.robot.clone(),
            n_in: l.human_columns.len(),
            raw: Vec::with_capacity(l.human_columns.len()),
            features: Vec::with_capacity(l.human.len()),
            mean: vec![0.0; o],
            covariance: vec![0.0; o * o],
        }
    }
}

/// The online predictor of an interaction model: one raw human frame in, the
/// robot's frame out, in data units (velocities computed causally inside,
/// standardisation applied and undone). The same steps as `phasekit stream`
/// (`phasekit_cli::pipeline::StreamPredictor`, which borrows its model file
/// and so cannot live in a Python object).
#[pyclass(module = "phasekit._core")]
pub struct OnlineInteraction {
    online: OnlinePredictor,
    diff: Differencer,
    standardisation: Option<Standardisation>,
    human: Vec<usize>,
    robot: Vec<usize>,
    n_in: usize,
    raw: Vec<f64>,
    features: Vec<f64>,
    mean: Vec<f64>,
    covariance: Vec<f64>,
}

impl OnlineInteraction {
    fn advance(&mut self, frame: &Bound<'_, PyAny>, with_covariance: bool) -> PyResult<()> {
        read_frame(frame, self.n_in, &mut self.raw)?;
        self.features.clear();
        self.diff.push(&self.raw, &mut self.features);
        if let Some(s) = &self.standardisation {
            s.apply(&mut self.features, &self.human);
        }
        let mean = self
            .online
            .step(&self.features, with_covariance)
            .map_err(value_error)?;
        self.mean.copy_from_slice(mean);
        if with_covariance {
            self.covariance.copy_from_slice(self.online.covariance());
        }
        if let Some(s) = &self.standardisation {
            s.unapply_mean(&mut self.mean, &self.robot);
            if with_covariance {
                s.unapply_cov(&mut self.covariance, &self.robot);
            }
        }
        Ok(())
    }
}

#[pymethods]
impl OnlineInteraction {
    /// The robot's predicted frame `(O,)` after the human's raw frame `frame`
    /// (a 1-D array or sequence of the model's human columns; NaN = missing).
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        frame: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        self.advance(frame, false)?;
        Ok(array1(py, self.mean.clone()))
    }

    /// `(mean (O,), covariance (O, O))` after the human's raw frame `frame`.
    fn step_with_covariance<'py>(
        &mut self,
        py: Python<'py>,
        frame: &Bound<'py, PyAny>,
    ) -> PyResult<MeanAndCovariance<'py>> {
        self.advance(frame, true)?;
        let o = self.mean.len();
        Ok((
            array1(py, self.mean.clone()),
            array2(py, self.covariance.clone(), o, o)?,
        ))
    }

    /// Starts a new interaction (the belief and the velocity history are reset).
    fn reset(&mut self) {
        self.online.reset();
        self.diff.reset();
    }

    /// Number of raw human values a frame has.
    #[getter]
    fn n_in(&self) -> usize {
        self.n_in
    }
}

/// `(path, columns, values (T, C))` of a demonstration.
type PyTable<'py> = (String, Vec<String>, Bound<'py, PyArray2<f64>>);

fn table_tuple<'py>(
    py: Python<'py>,
    t: Table,
) -> PyResult<(String, Vec<String>, Bound<'py, PyArray2<f64>>)> {
    let (n, c) = (t.n_rows(), t.columns.len());
    let values = array2(py, t.data, n, c)?;
    Ok((t.path.display().to_string(), t.columns, values))
}

/// Reads a demonstration file (CSV with a header, or a 2-D NPY array) as the
/// command does: `(path, columns, values (T, C))`.
#[pyfunction]
pub fn read_table<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(String, Vec<String>, Bound<'py, PyArray2<f64>>)> {
    let t = py
        .allow_threads(|| data::read_table(&path))
        .map_err(cli_error)?;
    table_tuple(py, t)
}

type PyAction<'py> = (
    String,
    Vec<(String, Vec<String>, Bound<'py, PyArray2<f64>>)>,
    Vec<(String, Vec<String>, Bound<'py, PyArray2<f64>>)>,
);

fn action_tuple<'py>(py: Python<'py>, a: data::Action) -> PyResult<PyAction<'py>> {
    let train = a
        .train
        .into_iter()
        .map(|t| table_tuple(py, t))
        .collect::<PyResult<_>>()?;
    let test = a
        .test
        .into_iter()
        .map(|t| table_tuple(py, t))
        .collect::<PyResult<_>>()?;
    Ok((a.name, train, test))
}

/// One action folder (`train_*`, `test_*` CSV/NPY files): `(name, train, test)`.
#[pyfunction]
pub fn load_action(py: Python<'_>, path: PathBuf) -> PyResult<PyAction<'_>> {
    let a = py
        .allow_threads(|| data::load_action(&path))
        .map_err(cli_error)?;
    action_tuple(py, a)
}

/// A folder of action folders (or one action folder), as `phasekit evaluate --data` reads it.
#[pyfunction]
pub fn load_dataset(py: Python<'_>, path: PathBuf) -> PyResult<Vec<PyAction<'_>>> {
    let actions = py
        .allow_threads(|| data::load_dataset(&path))
        .map_err(cli_error)?;
    actions.into_iter().map(|a| action_tuple(py, a)).collect()
}

/// The training demonstrations of `phasekit fit --data PATHS [--action NAME]`:
/// files as given, folders as their `train_*` CSV/NPY files (the action's
/// subfolder with `action`), all with the same columns.
#[pyfunction]
#[pyo3(signature = (paths, action=None))]
pub fn load_training(
    py: Python<'_>,
    paths: Vec<PathBuf>,
    action: Option<String>,
) -> PyResult<Vec<PyTable<'_>>> {
    use phasekit_cli::commands::{fit_files, read_tables};
    let tables = py
        .allow_threads(|| {
            let files = fit_files(&paths, action.as_deref())?;
            read_tables(&files, true)
        })
        .map_err(cli_error)?;
    tables.into_iter().map(|t| table_tuple(py, t)).collect()
}
