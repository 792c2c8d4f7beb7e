//! The library of interactions on the command line: `fit --library`,
//! `recognise`, `stream` with a library, and the arguments of `plot
//! recognition` and `evaluate --task recognition`.

use super::{
    action_dirs, check_lengths, feature_spec, fit_files, preset_options, read_tables, setup_threads,
};
use crate::bail;
use crate::cli::{FitArgs, Format};
use crate::commands::fit::training_features;
use crate::data::{read_table, Table};
use crate::error::{CliError, Result};
use crate::experiment::parse_method;
use crate::library_file::{ActionInfo, LibraryFile};
use crate::model_file::{MethodInfo, ModelFile, Standardisation};
use crate::output;
use crate::pipeline::{
    prediction_header, prediction_line, Differencer, FrameStatus, StreamPredictor,
};
use clap::{Args, ValueEnum};
use phasekit_emission::SequenceSet;
use phasekit_recognition::{
    AutoReset, ComposedRecogniser, Decision, Library, LibrarySettings, PredictionMode, Prior,
    Recogniser, RecogniserSettings, Rejection,
};
use phasekit_tsc::{Method, Roles};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// A recognition error as a command error.
pub fn rec_err(e: phasekit_recognition::RecognitionError) -> CliError {
    CliError::new(e.to_string())
}

/// `--prior` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PriorArg {
    /// The same for every action.
    Uniform,
    /// In proportion to each action's training demonstrations.
    Demonstrations,
}

/// How a library is built (`fit --library`, `evaluate --task recognition`).
#[derive(Debug, Clone, Args)]
pub struct LibraryArgs {
    /// Library: prior over the actions
    #[arg(long, value_enum, value_name = "HOW", default_value = "uniform")]
    pub prior: PriorArg,
    /// Library: frames at each end of every training demonstration that form the rest state
    /// (its robot part is the rest pose the robot keeps while a motion is rejected)
    #[arg(long, value_name = "N", default_value_t = 5)]
    pub rest_frames: usize,
    /// Library: folds of the cross-validation that calibrates the rejection thresholds
    /// (below 2: on the training demonstrations themselves)
    #[arg(long, value_name = "N", default_value_t = 4)]
    pub calibration_folds: usize,
    /// Library: quantile of the held-out demonstrations' lowest statistics taken as the
    /// rejection threshold (0: none of them would have been rejected)
    #[arg(long, value_name = "Q", default_value_t = 0.0)]
    pub calibration_quantile: f64,
    /// Library: recognise with a second model per action of this method (a preset with
    /// optional :key=value settings); the robot's prediction stays the --method's
    #[arg(long, value_name = "NAME")]
    pub recognition_method: Option<String>,
    /// Library: temperature τ ≥ 1 of the posterior p(a | o) ∝ p(a) exp(ℓ_a / τ), or auto (the best
    /// log score on the held-out demonstrations)
    #[arg(long, value_name = "X|auto", default_value = "1")]
    pub temperature: TemperatureArg,
    /// Library: fit this action with its own method, ACTION=NAME[:key=value,...] (repeatable;
    /// the others use --method)
    #[arg(long, value_name = "ACTION=NAME")]
    pub action_method: Vec<String>,
}

/// `--temperature` values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TemperatureArg {
    /// This temperature.
    Fixed(f64),
    /// Chosen on the held-out demonstrations.
    Auto,
}

impl std::str::FromStr for TemperatureArg {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "auto" => Ok(TemperatureArg::Auto),
            x => x
                .parse()
                .map(TemperatureArg::Fixed)
                .map_err(|_| format!("`{s}` is neither a number nor `auto`")),
        }
    }
}

impl LibraryArgs {
    /// The per-action methods, `(action, label, method)`.
    pub fn action_methods(
        &self,
        options: &phasekit_tsc::PresetOptions,
    ) -> Result<Vec<(String, String, Method)>> {
        self.action_method
            .iter()
            .map(|spec| {
                let (action, m) = spec.split_once('=').ok_or_else(|| {
                    CliError::new(format!(
                        "--action-method {spec}: expected ACTION=NAME[:key=value,...]"
                    ))
                })?;
                let named = parse_method(m, options)
                    .map_err(|e| CliError::new(format!("--action-method {spec}: {e}")))?;
                Ok((action.trim().to_string(), named.label, named.method))
            })
            .collect()
    }

    /// The recognition method, parsed on top of the command line's options.
    pub fn recognition(
        &self,
        options: &phasekit_tsc::PresetOptions,
    ) -> Result<Option<crate::experiment::NamedMethod>> {
        self.recognition_method
            .as_deref()
            .map(|spec| {
                parse_method(spec, options)
                    .map_err(|e| CliError::new(format!("--recognition-method: {e}")))
            })
            .transpose()
    }

    /// The library settings (the rest regularisation is the method's `reg`).
    pub fn settings(&self, reg: f64) -> Result<LibrarySettings> {
        let mut s = LibrarySettings::default();
        s.prior = match self.prior {
            PriorArg::Uniform => Prior::Uniform,
            PriorArg::Demonstrations => Prior::Demonstrations,
        };
        s.rest_frames = self.rest_frames;
        s.rest_reg = reg;
        s.calibration_folds = self.calibration_folds;
        s.calibration_quantile = self.calibration_quantile;
        s.temperature = match self.temperature {
            TemperatureArg::Fixed(t) => Some(t),
            TemperatureArg::Auto => None,
        };
        s.validate().map_err(rec_err)?;
        Ok(s)
    }
}

/// `evaluate --task` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Task {
    /// The paper's experiment: the robot's prediction told the action.
    Prediction,
    /// Which interaction is it? Recognition, end to end, unknown motions, streams.
    Recognition,
}

/// `--reject` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum RejectArg {
    /// Never reject.
    Off,
    /// Reject while the best action's log-likelihood per frame is below the calibrated threshold.
    LikelihoodPerFrame,
    /// Reject while Lee & Kim's threshold model explains the motion better (calibrated).
    ThresholdModel,
    /// Reject while either test rejects.
    Either,
}

impl From<RejectArg> for Rejection {
    fn from(r: RejectArg) -> Self {
        match r {
            RejectArg::Off => Rejection::Off,
            RejectArg::LikelihoodPerFrame => Rejection::LikelihoodPerFrame,
            RejectArg::ThresholdModel => Rejection::ThresholdModel,
            RejectArg::Either => Rejection::Either,
        }
    }
}

/// `--prediction` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PredictionArg {
    /// The posterior-weighted mixture of the actions' predictions.
    Mixture,
    /// The most probable action's prediction.
    MostProbable,
}

impl From<PredictionArg> for PredictionMode {
    fn from(p: PredictionArg) -> Self {
        match p {
            PredictionArg::Mixture => PredictionMode::Mixture,
            PredictionArg::MostProbable => PredictionMode::MostProbable,
        }
    }
}

/// `stream --recogniser` values (with a library).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum StreamMode {
    /// One filter per action, reset automatically when the decided interaction ends.
    PerAction,
    /// The library as one composed HMM with a rest state.
    Composed,
}

/// The examples of `phasekit recognise --help`.
pub const RECOGNISE_EXAMPLES: &str = "\
Examples:
  phasekit fit --data nuisi --library --method hmm -o library.json
  phasekit recognise --model library.json --data nuisi/waving/test_00.csv
  phasekit recognise --model library.json --data nuisi/rocket --robot -o decisions/
  phasekit recognise --model library.json --data stream.csv --composed --format json

Output (CSV): file,frame,decision,p_<action> for every action (p_rest with --composed),
and with --robot the robot's predicted features. decision is an action's name, unknown
(the motion is rejected: the robot keeps its rest pose) or rest (--composed). Each file
is one demonstration: the filters start again at its first frame. Only the human's
columns are needed.";

/// `phasekit recognise`.
#[derive(Debug, Args)]
pub struct RecogniseArgs {
    /// Library file written by `phasekit fit --library`
    #[arg(long, value_name = "PATH")]
    pub model: PathBuf,
    /// Demonstration files, or a folder (all its CSV/NPY files)
    #[arg(long, value_name = "DIR|FILE", num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// How motions of no known action are rejected (off, likelihood-per-frame, threshold-model, either)
    #[arg(
        long,
        value_enum,
        value_name = "HOW",
        default_value = "likelihood-per-frame"
    )]
    pub reject: RejectArg,
    /// The robot's prediction: mixture (posterior-weighted) or most-probable
    #[arg(long, value_enum, value_name = "HOW", default_value = "mixture")]
    pub prediction: PredictionArg,
    /// Use the library as one composed HMM with a rest state (continuous streams; no rejection)
    #[arg(long, conflicts_with = "auto_reset")]
    pub composed: bool,
    /// Reset the per-action filters when the decided interaction ends (files holding several interactions)
    #[arg(long)]
    pub auto_reset: bool,
    /// Add the robot's predicted features
    #[arg(long)]
    pub robot: bool,
    /// Output file (one input) or folder (any number); stdout if absent
    #[arg(short, long, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// csv (default) or json
    #[arg(long, value_enum, default_value = "csv")]
    pub format: Format,
    /// Shorthand for --format json
    #[arg(long)]
    pub json: bool,
}

/// `phasekit plot recognition`.
#[derive(Debug, Args)]
pub struct PlotRecognitionArgs {
    /// Library file (with --data): the posterior over time of one demonstration
    #[arg(
        long,
        value_name = "PATH",
        requires = "data",
        conflicts_with = "results"
    )]
    pub model: Option<PathBuf>,
    /// One demonstration file (with --model)
    #[arg(long, value_name = "FILE", requires = "model")]
    pub data: Option<PathBuf>,
    /// How unknown motions are rejected (with --model)
    #[arg(
        long,
        value_enum,
        value_name = "HOW",
        default_value = "likelihood-per-frame"
    )]
    pub reject: RejectArg,
    /// The JSON of `evaluate --task recognition` (-o PREFIX writes PREFIX.json): the accuracy curve
    #[arg(long, value_name = "PATH")]
    pub results: Option<PathBuf>,
    /// The SVG file to write
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
}

/// The examples of `phasekit plot recognition --help`.
pub const PLOT_RECOGNITION_EXAMPLES: &str = "\
Examples:
  phasekit plot recognition --model library.json --data nuisi/waving/test_00.csv -o posterior.svg
  phasekit evaluate --data nuisi --task recognition -o results/recognition
  phasekit plot recognition --results results/recognition.json -o accuracy.svg";

/// What `fit --library --format json` prints.
#[derive(Debug, Serialize)]
struct LibraryReport<'a> {
    library: bool,
    method: &'a str,
    recognition_method: Option<&'a str>,
    actions: Vec<ActionReport<'a>>,
    features: &'a [String],
    standardised: bool,
    prior: &'a [f64],
    rest_pose: Vec<f64>,
    rest_frames: usize,
    calibration: &'a phasekit_recognition::Calibration,
    model_file: Option<&'a Path>,
}

#[derive(Debug, Serialize)]
struct ActionReport<'a> {
    action: &'a str,
    states: usize,
    demonstrations: usize,
    frames: usize,
    #[serde(flatten)]
    fit: &'a phasekit_tsc::FitSummary,
}

/// Runs `phasekit fit --library`.
pub fn fit_library(a: &FitArgs, settings: &LibraryArgs) -> Result<()> {
    let format = if a.json { Some(Format::Json) } else { a.format };
    if a.output.is_none() && format.is_none() {
        bail!("nothing to do: give -o LIBRARY.json to save the library (and/or --format json to print the fit report)");
    }
    if a.action.is_some() {
        bail!("--library fits every action folder of --data; --action picks one: leave it out");
    }
    let dir = match a.data.as_slice() {
        [d] if d.is_dir() => d,
        _ => bail!(
            "--library needs --data DIR: one folder of action folders (each with train_* files), as evaluate reads them"
        ),
    };
    setup_threads(a.model.threads)?;
    let options = preset_options(&a.model)?;
    let (spec, defaults) = feature_spec(&a.columns);
    let named =
        parse_method(&a.method, &options).map_err(|e| CliError::new(format!("--method: {e}")))?;
    let lib_settings = settings.settings(options.reg())?;
    let dirs = action_dirs(dir)?;
    let name_of = |d: &Path| {
        d.file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("?")
            .to_string()
    };
    if dirs.len() < phasekit_recognition::MIN_ACTIONS {
        bail!(
            "{}: a library needs at least {} action folders (each with train_* files), found {}{}; one action is a single model: fit it without --library",
            dir.display(),
            phasekit_recognition::MIN_ACTIONS,
            dirs.len(),
            if dirs.is_empty() {
                String::new()
            } else {
                format!(" ({})", dirs.iter().map(|d| name_of(d)).collect::<Vec<_>>().join(", "))
            }
        );
    }
    // Every action's training features, on one layout.
    let mut layout = None;
    // Per action: name, training files, frames, features.
    struct Training {
        name: String,
        files: Vec<PathBuf>,
        frames: usize,
        seqs: Vec<Vec<f64>>,
    }
    let mut per_action: Vec<Training> = Vec::new();
    for d in &dirs {
        let name = name_of(d);
        let files = fit_files(std::slice::from_ref(d), None)?;
        let tables = read_tables(&files, true)?;
        check_lengths(&tables, &named.method, &named.label)?;
        let (l, seqs) = training_features(&tables, &spec, defaults)?;
        match &layout {
            None => layout = Some((name.clone(), l)),
            Some((first, l0)) if *l0 != l => bail!(
                "action `{name}`: its features ({}) differ from those of action `{first}` ({}): every action of a library needs the same columns",
                l.features.join(", "),
                l0.features.join(", ")
            ),
            Some(_) => {}
        }
        let frames = tables.iter().map(Table::n_rows).sum();
        per_action.push(Training {
            name,
            files,
            frames,
            seqs,
        });
    }
    let (_, layout) = layout.ok_or_else(|| CliError::new("no action to fit"))?;
    let dim = layout.features.len();
    let standardisation = a.model.standardise.then(|| {
        let all: Vec<&Vec<f64>> = per_action.iter().flat_map(|p| &p.seqs).collect();
        Standardisation::fit(&all, dim)
    });
    if let Some(s) = &standardisation {
        let all: Vec<usize> = (0..dim).collect();
        per_action
            .iter_mut()
            .flat_map(|p| p.seqs.iter_mut())
            .for_each(|q| s.apply(q, &all));
    }
    let sets = per_action
        .iter()
        .map(|p| SequenceSet::new(&p.seqs, dim))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let roles = Roles::new(layout.human.clone(), layout.robot.clone())?;
    // On z-scores, an action fitted by cross-validation (`auto`) still judges
    // the error in the files' units, as `fit --standardise` does.
    let roles = match &standardisation {
        Some(s) => s.error_units_of(roles)?,
        None => roles,
    };
    let frames: usize = per_action.iter().map(|p| p.frames).sum();
    let bar = output::spinner(&format!(
        "fitting {} to {} actions ({frames} frames)",
        named.label,
        per_action.len()
    ));
    let own = settings.action_methods(&options)?;
    for (a, _, _) in &own {
        if !per_action.iter().any(|p| &p.name == a) {
            bail!(
                "--action-method: no action `{a}` in {} (actions: {})",
                dir.display(),
                per_action
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    let actions: Vec<(&str, &SequenceSet, &Method)> = per_action
        .iter()
        .zip(&sets)
        .map(|(p, s)| {
            let m = own
                .iter()
                .find(|o| o.0 == p.name)
                .map_or(&named.method, |o| &o.2);
            (p.name.as_str(), s, m)
        })
        .collect();
    let recognition = settings.recognition(&options)?;
    if let Some(r) = &recognition {
        for d in &dirs {
            let tables = read_tables(&fit_files(std::slice::from_ref(d), None)?, true)?;
            check_lengths(&tables, &r.method, &r.label)?;
        }
    }
    let fitted = Library::fit(
        &actions,
        recognition.as_ref().map(|r| &r.method),
        &roles,
        &lib_settings,
    );
    bar.finish_and_clear();
    // Each action's method, for the file's version (the actions borrow the
    // training data, which the report takes next).
    let methods: Vec<Method> = actions.iter().map(|a| a.2.clone()).collect();
    let (library, summaries) = fitted.map_err(|e| {
        CliError::new(format!(
            "fitting the library with `{}` failed: {e}",
            named.label
        ))
    })?;
    let infos: Vec<ActionInfo> = per_action
        .into_iter()
        .zip(summaries)
        .map(|(p, fit)| ActionInfo {
            method: own.iter().find(|o| o.0 == p.name).map(|o| o.1.clone()),
            name: p.name,
            demonstrations: p.files,
            frames: p.frames,
            fit,
        })
        .collect();
    let mut file = LibraryFile::new(
        layout,
        spec,
        standardisation,
        MethodInfo {
            spec: named.label,
            settings: named.method,
        },
        infos,
        library,
        &methods.iter().collect::<Vec<_>>(),
        recognition.as_ref().map(|r| &r.method),
    );
    file.recognition_method = recognition.map(|r| r.label);
    if let Some(path) = &a.output {
        file.save(path)?;
    }
    let mut rest_pose = file.library.rest_pose();
    file.to_data_units(&mut rest_pose, None);
    let report = LibraryReport {
        library: true,
        method: &file.method.spec,
        recognition_method: file.recognition_method.as_deref(),
        actions: file
            .actions
            .iter()
            .zip(file.library.actions())
            .map(|(i, a)| ActionReport {
                action: &i.name,
                states: a.model.n_states(),
                demonstrations: i.demonstrations.len(),
                frames: i.frames,
                fit: &i.fit,
            })
            .collect(),
        features: &file.layout.features,
        standardised: file.standardisation.is_some(),
        prior: file.library.prior(),
        rest_pose,
        rest_frames: file.library.rest().frames,
        calibration: file.library.calibration(),
        model_file: a.output.as_deref(),
    };
    match format {
        Some(Format::Json) => {
            let text =
                serde_json::to_string_pretty(&report).map_err(|e| CliError::new(e.to_string()))?;
            output::print_stdout(&(text + "\n"))?;
        }
        Some(Format::Csv) => {
            let mut s =
                String::from("action,states,demonstrations,frames,iterations,stop,fit_seconds\n");
            for r in &report.actions {
                s.push_str(&format!(
                    "{},{},{},{},{},{},{}\n",
                    output::csv_field(r.action),
                    r.states,
                    r.demonstrations,
                    r.frames,
                    r.fit.iterations,
                    crate::commands::fit::stop_text(r.fit.stop),
                    r.fit.fit_seconds
                ));
            }
            output::print_stdout(&s)?;
        }
        Some(Format::Md) => {
            let mut s = String::from("| action | states | demonstrations | frames | iterations | stop | fit (s) |\n|---|---:|---:|---:|---:|---|---:|\n");
            for r in &report.actions {
                s.push_str(&format!(
                    "| {} | {} | {} | {} | {} | {} | {:.3} |\n",
                    r.action,
                    r.states,
                    r.demonstrations,
                    r.frames,
                    r.fit.iterations,
                    crate::commands::fit::stop_text(r.fit.stop),
                    r.fit.fit_seconds
                ));
            }
            output::print_stdout(&s)?;
        }
        None => {
            if output::stderr_is_terminal() {
                eprintln!(
                    "phasekit: fitted a library of {} actions ({}) with {} to {frames} frames{}",
                    report.actions.len(),
                    report
                        .actions
                        .iter()
                        .map(|r| r.action)
                        .collect::<Vec<_>>()
                        .join(", "),
                    report.method,
                    a.output
                        .as_ref()
                        .map(|p| format!("; written to {}", p.display()))
                        .unwrap_or_default()
                );
            }
        }
    }
    Ok(())
}

/// Either recogniser, behind one interface.
enum Engine {
    PerAction(Box<Recogniser>),
    Composed(Box<ComposedRecogniser>),
}

impl Engine {
    fn new(lib: &Library, composed: bool, settings: RecogniserSettings) -> Result<Self> {
        Ok(if composed {
            Engine::Composed(Box::new(
                ComposedRecogniser::new(lib, settings.with_covariance).map_err(rec_err)?,
            ))
        } else {
            Engine::PerAction(Box::new(Recogniser::new(lib, settings).map_err(rec_err)?))
        })
    }

    fn step(&mut self, x: &[f64]) -> Result<Decision> {
        match self {
            Engine::PerAction(r) => r.step(x),
            Engine::Composed(r) => r.step(x),
        }
        .map_err(rec_err)
    }

    fn reset(&mut self) {
        match self {
            Engine::PerAction(r) => r.reset(),
            Engine::Composed(r) => r.reset(),
        }
    }

    fn frame_rejected(&self) -> bool {
        match self {
            Engine::PerAction(r) => r.frame_rejected(),
            Engine::Composed(r) => r.frame_rejected(),
        }
    }

    fn posterior(&self) -> &[f64] {
        match self {
            Engine::PerAction(r) => r.posterior(),
            Engine::Composed(r) => r.posterior(),
        }
    }

    fn rest(&self) -> Option<f64> {
        match self {
            Engine::PerAction(_) => None,
            Engine::Composed(r) => Some(r.rest_probability()),
        }
    }

    fn robot(&self) -> (&[f64], Option<&[f64]>) {
        match self {
            Engine::PerAction(r) => (r.robot(), r.robot_covariance()),
            Engine::Composed(r) => (r.robot(), r.robot_covariance()),
        }
    }
}

/// The name of a decision in outputs.
pub fn decision_name(lib: &Library, d: Decision) -> &str {
    match d {
        Decision::Action(a) => &lib.actions()[a].name,
        Decision::Unknown => "unknown",
        Decision::Rest => "rest",
    }
}

/// Per-frame recognition of one demonstration.
#[derive(Debug, Clone, Serialize)]
pub struct Recognition {
    /// The file.
    pub file: PathBuf,
    /// The library's actions.
    pub actions: Vec<String>,
    /// The decision of every frame.
    pub decision: Vec<String>,
    /// `p(a | frames so far)` of every frame, `T × A`.
    pub posterior: Vec<Vec<f64>>,
    /// The belief in rest of every frame (composed HMM).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rest: Option<Vec<f64>>,
    /// The robot's predicted features of every frame, in data units.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robot: Option<Vec<Vec<f64>>>,
    /// Names of the robot's features.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robot_features: Option<Vec<String>>,
}

/// Recognises every frame of a table with a library.
pub fn recognise_table(
    file: &LibraryFile,
    table: &Table,
    reject: Rejection,
    prediction: PredictionMode,
    composed: bool,
    auto_reset: bool,
    robot: bool,
) -> Result<Recognition> {
    let lib = &file.library;
    let mut s = RecogniserSettings::default();
    s.rejection = reject;
    s.prediction = prediction;
    s.auto_reset = auto_reset.then(AutoReset::default);
    let mut engine = Engine::new(lib, composed, s)?;
    let h = file.human_input(table)?;
    let n_h = file.layout.human.len();
    let mut out = Recognition {
        file: table.path.clone(),
        actions: lib.names().iter().map(|n| n.to_string()).collect(),
        decision: Vec::new(),
        posterior: Vec::new(),
        rest: composed.then(Vec::new),
        robot: robot.then(Vec::new),
        robot_features: robot.then(|| {
            file.robot_features()
                .iter()
                .map(|s| s.to_string())
                .collect()
        }),
    };
    engine.reset();
    for (t, x) in h.chunks_exact(n_h).enumerate() {
        let d = engine
            .step(x)
            .map_err(|e| e.context(format!("{}: frame {t}", table.path.display())))?;
        out.decision.push(decision_name(lib, d).to_string());
        out.posterior.push(engine.posterior().to_vec());
        if let Some(r) = out.rest.as_mut() {
            r.push(engine.rest().unwrap_or(0.0));
        }
        if let Some(r) = out.robot.as_mut() {
            let mut m = engine.robot().0.to_vec();
            file.to_data_units(&mut m, None);
            r.push(m);
        }
    }
    Ok(out)
}

fn recognition_csv(r: &Recognition) -> String {
    let mut s = String::from("file,frame,decision");
    for a in &r.actions {
        s.push_str(&format!(",{}", output::csv_field(&format!("p_{a}"))));
    }
    if r.rest.is_some() {
        s.push_str(",p_rest");
    }
    if let Some(names) = &r.robot_features {
        for n in names {
            s.push_str(&format!(",{}", output::csv_field(n)));
        }
    }
    s.push('\n');
    let file = output::csv_field(&r.file.display().to_string());
    for (t, d) in r.decision.iter().enumerate() {
        s.push_str(&format!("{file},{t},{}", output::csv_field(d)));
        // Probabilities in the shortest round-trip form with an exponent when
        // tiny (`{:?}`): 1e-300 is not 300 zeros.
        for p in &r.posterior[t] {
            s.push_str(&format!(",{p:?}"));
        }
        if let Some(rest) = &r.rest {
            s.push_str(&format!(",{:?}", rest[t]));
        }
        if let Some(robot) = &r.robot {
            for v in &robot[t] {
                s.push_str(&format!(",{}", output::num(*v)));
            }
        }
        s.push('\n');
    }
    s
}

/// Runs `phasekit recognise`.
pub fn run(a: &RecogniseArgs) -> Result<()> {
    let file = LibraryFile::load(&a.model)?;
    let files = super::data_files(&a.data)?;
    let format = if a.json { Format::Json } else { a.format };
    if format == Format::Md {
        bail!("recognise writes csv or json, not md");
    }
    if let Some(o) = &a.output {
        let ins: Vec<&Path> = std::iter::once(a.model.as_path())
            .chain(files.iter().map(|p| p.as_path()))
            .collect();
        output::refuse_inputs(&[o], &ins)?;
    }
    let tables = read_tables(&files, false)?;
    if a.composed && a.reject != RejectArg::LikelihoodPerFrame && a.reject != RejectArg::Off {
        bail!("--composed does not reject unknown motions (its rest state absorbs the time between interactions): leave --reject out");
    }
    let reject = if a.composed {
        Rejection::Off
    } else {
        a.reject.into()
    };
    let results = tables
        .iter()
        .map(|t| {
            recognise_table(
                &file,
                t,
                reject,
                a.prediction.into(),
                a.composed,
                a.auto_reset,
                a.robot,
            )
        })
        .collect::<Result<Vec<_>>>()?;
    let render = |r: &Recognition| -> Result<String> {
        Ok(if format == Format::Json {
            serde_json::to_string_pretty(r).map_err(|e| CliError::new(e.to_string()))? + "\n"
        } else {
            recognition_csv(r)
        })
    };
    let ext = if format == Format::Json {
        "json"
    } else {
        "csv"
    };
    match &a.output {
        None if results.len() > 1 && format == Format::Json => {
            let text =
                serde_json::to_string_pretty(&results).map_err(|e| CliError::new(e.to_string()))?;
            output::print_stdout(&(text + "\n"))
        }
        None => {
            // Several CSVs on stdout: one header, then every file's rows.
            let mut s = String::new();
            for (i, r) in results.iter().enumerate() {
                let text = render(r)?;
                s.push_str(if i == 0 {
                    &text
                } else {
                    text.split_once('\n').map_or("", |x| x.1)
                });
            }
            output::print_stdout(&s)
        }
        Some(o) if results.len() > 1 || o.is_dir() => {
            output::create_dir(o)?;
            let files = results
                .iter()
                .map(|r| {
                    let stem = r
                        .file
                        .file_stem()
                        .and_then(|s| s.to_str())
                        .unwrap_or("demonstration");
                    Ok((o.join(format!("{stem}.recognition.{ext}")), render(r)?))
                })
                .collect::<Result<Vec<_>>>()?;
            output::write_files_atomic(&files)
        }
        Some(o) => output::write_string(o, &render(&results[0])?),
    }
}

/// Before any work (`fit --library`): the library file is JSON and none of
/// the training files.
pub fn check_fit_output(a: &FitArgs) -> Result<()> {
    let Some(o) = &a.output else { return Ok(()) };
    output::check_extension(o, &["json"], true, "a library file is JSON")?;
    let mut files = Vec::new();
    for d in &a.data {
        if d.is_dir() {
            for action in action_dirs(d)? {
                files.extend(fit_files(std::slice::from_ref(&action), None)?);
            }
        }
    }
    let ins: Vec<&Path> = files.iter().map(|p| p.as_path()).collect();
    output::refuse_inputs(&[o], &ins)
}

/// Before any work (`plot recognition`): an SVG that is none of the inputs.
pub fn check_plot_output(a: &PlotRecognitionArgs) -> Result<()> {
    output::check_extension(&a.output, &["svg"], false, "plot writes SVG")?;
    let ins: Vec<&Path> = [&a.model, &a.data, &a.results]
        .into_iter()
        .flatten()
        .map(|p| p.as_path())
        .collect();
    output::refuse_inputs(&[&a.output], &ins)
}

/// Runs `phasekit plot recognition`.
pub fn plot(a: &PlotRecognitionArgs) -> Result<()> {
    let svg = match (&a.model, &a.data, &a.results) {
        (Some(model), Some(data), None) => {
            let file = LibraryFile::load(model)?;
            let table = read_table(data)?;
            let r = recognise_table(&file, &table, a.reject.into(), PredictionMode::Mixture, false, false, false)?;
            crate::recognition_plot::posterior_svg(&file, &r)?
        }
        (None, None, Some(results)) => {
            let text = std::fs::read_to_string(results)
                .map_err(|e| CliError::new(format!("{}: cannot read: {e}", results.display())))?;
            let report: crate::recognition_report::RecognitionJson = serde_json::from_str(&text).map_err(|e| {
                CliError::new(format!(
                    "{}: not the JSON of `phasekit evaluate --task recognition` ({e})",
                    results.display()
                ))
            })?;
            crate::recognition_plot::accuracy_svg(&report.report)?
        }
        _ => bail!("plot recognition needs either --model LIBRARY --data FILE (the posterior over time) or --results EVALUATE.json (the accuracy curve)"),
    };
    output::write_string(&a.output, &svg)
}

/// What `stream --model` reads: a single model or a library.
pub enum StreamTarget {
    /// A model file.
    Model(Box<ModelFile>),
    /// A library file.
    Library(Box<LibraryFile>),
}

impl StreamTarget {
    /// Reads the file at `path`, whichever it is.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            CliError::new(format!("{}: cannot read model file: {e}", path.display()))
        })?;
        if crate::library_file::file_format(&text).as_deref() == Some(crate::library_file::FORMAT) {
            Ok(StreamTarget::Library(Box::new(LibraryFile::from_json(
                &text, path,
            )?)))
        } else {
            Ok(StreamTarget::Model(Box::new(ModelFile::from_json(
                &text, path,
            )?)))
        }
    }

    /// The human's raw columns a frame holds, in order.
    pub fn human_columns(&self) -> &[String] {
        match self {
            StreamTarget::Model(m) => &m.layout.human_columns,
            StreamTarget::Library(l) => &l.layout.human_columns,
        }
    }

    /// Whether the target is a model file without an out-of-distribution
    /// threshold (written by an older phasekit). A library flags a frame `ood`
    /// when its rejection test rejects the motion.
    pub fn lacks_novelty(&self) -> bool {
        matches!(self, StreamTarget::Model(m) if m.novelty.is_none())
    }

    /// The frame-by-frame predictor; `mode` chooses a library's recogniser.
    pub fn predictor(
        &self,
        mode: Option<StreamMode>,
        with_covariance: bool,
    ) -> Result<Streamer<'_>> {
        match self {
            StreamTarget::Model(m) => {
                if mode.is_some() {
                    bail!("--recogniser needs a library (made by `fit --library`), not a single model");
                }
                Ok(Streamer::Model(Box::new(StreamPredictor::new(m)?), m))
            }
            StreamTarget::Library(l) => {
                // The composed HMM by default: it did better on continuous
                // streams (README, "Which interaction?").
                let composed = mode != Some(StreamMode::PerAction);
                let mut s = RecogniserSettings::default();
                s.with_covariance = with_covariance;
                s.auto_reset = Some(AutoReset::default());
                let engine = Engine::new(&l.library, composed, s)?;
                let o = l.layout.robot.len();
                Ok(Streamer::Library(Box::new(LibraryStream {
                    file: l,
                    engine,
                    diff: Differencer::new(matches!(
                        l.layout.velocity,
                        crate::data::Velocity::Both | crate::data::Velocity::Human
                    )),
                    features: Vec::with_capacity(l.layout.human.len()),
                    mean: vec![0.0; o],
                    covariance: vec![0.0; o * o],
                    decision: Decision::Unknown,
                    with_covariance,
                })))
            }
        }
    }
}

/// Frame-by-frame prediction (a single model) or recognition (a library).
pub enum Streamer<'a> {
    /// A single model's predictor.
    Model(Box<StreamPredictor<'a>>, &'a ModelFile),
    /// A library's recogniser.
    Library(Box<LibraryStream<'a>>),
}

/// A library's recogniser on raw human frames (velocities computed inside).
pub struct LibraryStream<'a> {
    file: &'a LibraryFile,
    engine: Engine,
    diff: Differencer,
    features: Vec<f64>,
    mean: Vec<f64>,
    covariance: Vec<f64>,
    decision: Decision,
    with_covariance: bool,
}

impl Streamer<'_> {
    /// Number of raw human values a frame has.
    pub fn n_in(&self) -> usize {
        match self {
            Streamer::Model(p, _) => p.n_in(),
            Streamer::Library(l) => l.file.layout.human_columns.len(),
        }
    }

    /// The CSV header: a model's prediction header; a library's
    /// `frame,decision,p_<action>…[,p_rest],<robot features>[,var_…,cov_…]`.
    pub fn header(&self, with_covariance: bool) -> Vec<String> {
        match self {
            Streamer::Model(_, mf) => prediction_header(mf, with_covariance),
            Streamer::Library(l) => {
                let mut h = vec!["frame".to_string(), "decision".to_string()];
                h.extend(l.file.library.names().iter().map(|a| format!("p_{a}")));
                if matches!(l.engine, Engine::Composed(_)) {
                    h.push("p_rest".into());
                }
                let names = l.file.robot_features();
                h.extend(names.iter().map(|n| n.to_string()));
                if with_covariance {
                    for i in 0..names.len() {
                        for j in i..names.len() {
                            h.push(if i == j {
                                format!("var_{}", names[i])
                            } else {
                                format!("cov_{}_{}", names[i], names[j])
                            });
                        }
                    }
                }
                h
            }
        }
    }

    /// Takes one raw human frame (NaN = missing), predicts (and recognises),
    /// writes the output line of frame number `frame` (without newline and
    /// without the status) and returns the frame's status. A library's frame
    /// is `ood` while its rejection test rejects the motion (the decision is
    /// `unknown`), `rejected` when a value overflows (it is then taken as not
    /// observed), `unobserved` when nothing is observed.
    pub fn step_line(
        &mut self,
        raw: &[f64],
        frame: usize,
        with_covariance: bool,
        line: &mut String,
    ) -> Result<FrameStatus> {
        match self {
            Streamer::Model(p, _) => {
                let (mean, cov) = p.step(raw, with_covariance)?;
                prediction_line(frame, mean, cov, line);
                Ok(p.last().status)
            }
            Streamer::Library(l) => {
                let status = l.step(raw)?;
                l.line(frame, line);
                Ok(status)
            }
        }
    }

    /// Starts a new demonstration.
    pub fn reset(&mut self) {
        match self {
            Streamer::Model(p, _) => p.reset(),
            Streamer::Library(l) => {
                l.engine.reset();
                l.diff.reset();
            }
        }
    }
}

impl LibraryStream<'_> {
    fn step(&mut self, raw: &[f64]) -> Result<FrameStatus> {
        let f = self.file;
        if raw.len() != f.layout.human_columns.len() {
            bail!(
                "a frame has {} values; the library's human columns are {} ({})",
                raw.len(),
                f.layout.human_columns.len(),
                f.layout.human_columns.join(", ")
            );
        }
        self.features.clear();
        self.diff.push(raw, &mut self.features);
        if let Some(s) = &f.standardisation {
            s.apply(&mut self.features, &f.layout.human);
        }
        // A value infinite once standardised is explained by no state of any
        // action: the frame is taken as not observed, as a single model's
        // stream does; so is a frame every action finds impossible (the
        // recognisers report it).
        let mut rejected = self.features.iter().any(|v| v.is_infinite());
        if rejected {
            self.features.fill(f64::NAN);
        }
        let observed = self.features.iter().any(|v| !v.is_nan());
        self.decision = self.engine.step(&self.features)?;
        if self.engine.frame_rejected() {
            rejected = true;
        }
        if rejected {
            self.diff.forget_last();
        }
        let (m, c) = self.engine.robot();
        self.mean.copy_from_slice(m);
        if let (Some(c), true) = (c, self.with_covariance) {
            self.covariance.copy_from_slice(c);
        }
        let cov = self.with_covariance.then_some(&mut self.covariance[..]);
        f.to_data_units(&mut self.mean, cov);
        Ok(if rejected {
            FrameStatus::Rejected
        } else if !observed {
            FrameStatus::Unobserved
        } else if self.decision == Decision::Unknown {
            FrameStatus::OutOfDistribution
        } else {
            FrameStatus::Ok
        })
    }

    fn line(&self, frame: usize, line: &mut String) {
        use std::fmt::Write;
        line.clear();
        let _ = write!(
            line,
            "{frame},{}",
            decision_name(&self.file.library, self.decision)
        );
        for p in self.engine.posterior() {
            let _ = write!(line, ",{p:?}");
        }
        if let Some(r) = self.engine.rest() {
            let _ = write!(line, ",{r:?}");
        }
        for v in &self.mean {
            let _ = write!(line, ",{v}");
        }
        if self.with_covariance {
            let o = self.mean.len();
            for i in 0..o {
                for j in i..o {
                    let _ = write!(line, ",{}", self.covariance[i * o + j]);
                }
            }
        }
    }
}
