//! Command-line arguments of `phasekit` (clap derive).

use clap::{Args, Parser, Subcommand, ValueEnum};
use std::path::PathBuf;

const TOP_EXAMPLES: &str = "\
Examples:
  phasekit demo                                   # the whole pipeline on generated data, in seconds
  phasekit fit --data nuisi/handshake --method tsc-hmm -o handshake.json
  phasekit predict --model handshake.json --data nuisi/handshake/test_00.csv
  phasekit evaluate --data nuisi --methods hmm,tsc-hmm --seeds 20 -o results
  phasekit <COMMAND> --help                       # every command's options and examples";

/// Learn human–robot interactions from demonstrations: segment them into
/// phases and predict the robot's motion from the human's.
#[derive(Debug, Parser)]
#[command(name = "phasekit", version, after_help = TOP_EXAMPLES, propagate_version = true, max_term_width = 100)]
pub struct Cli {
    /// The command.
    #[command(subcommand)]
    pub command: Command,
}

/// The commands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Fit a method to demonstrations and save the model file.
    #[command(after_help = with_presets(FIT_EXAMPLES))]
    Fit(FitArgs),
    /// Per-frame states, transition frames and transition clusters of demonstrations.
    #[command(after_help = SEGMENT_EXAMPLES)]
    Segment(SegmentArgs),
    /// Predict the robot's trajectory from the human's columns of demonstrations.
    #[command(after_help = PREDICT_EXAMPLES)]
    Predict(PredictArgs),
    /// Predict frame by frame from human frames on stdin (one CSV line each).
    #[command(after_help = STREAM_EXAMPLES)]
    Stream(StreamArgs),
    /// Run the paper's experiment: methods × seeds × actions, MSE in cm².
    #[command(after_help = with_presets(EVALUATE_EXAMPLES))]
    Evaluate(EvaluateArgs),
    /// Draw SVG pictures of segmentations, predictions and states.
    #[command(after_help = PLOT_EXAMPLES)]
    Plot(PlotArgs),
    /// The whole pipeline on generated interactions: fit, compare, plot.
    #[command(after_help = DEMO_EXAMPLES)]
    Demo(DemoArgs),
    /// Which interaction is it? Per-frame posterior of each action of a library, and the decision.
    #[command(after_help = crate::commands::recognise::RECOGNISE_EXAMPLES)]
    Recognise(crate::commands::recognise::RecogniseArgs),
}

/// `--velocity` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum VelocityArg {
    /// Velocities of the human's and the robot's columns (the paper).
    Both,
    /// The human's only.
    Human,
    /// The robot's only.
    Robot,
    /// No velocities.
    None,
}

impl From<VelocityArg> for crate::data::Velocity {
    fn from(v: VelocityArg) -> Self {
        match v {
            VelocityArg::Both => crate::data::Velocity::Both,
            VelocityArg::Human => crate::data::Velocity::Human,
            VelocityArg::Robot => crate::data::Velocity::Robot,
            VelocityArg::None => crate::data::Velocity::None,
        }
    }
}

/// Output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// JSON.
    Json,
    /// CSV.
    Csv,
    /// A Markdown table.
    Md,
}

/// Which columns are the human's and the robot's.
#[derive(Debug, Clone, Args)]
pub struct ColumnArgs {
    /// The human's columns (inputs), comma-separated globs over the header [default: p1_wrist_*]
    #[arg(long, value_name = "GLOB,...", value_delimiter = ',')]
    pub human: Option<Vec<String>>,
    /// The robot's columns (predicted), comma-separated globs [default: p2_wrist_*]
    #[arg(long, value_name = "GLOB,...", value_delimiter = ',')]
    pub robot: Option<Vec<String>>,
    /// Append first differences (v_t = x_t − x_{t−1}, v_0 = 0) of these columns; bare `--velocity` = both [default: both]
    #[arg(long, value_enum, value_name = "WHICH", num_args = 0..=1, default_missing_value = "both")]
    pub velocity: Option<VelocityArg>,
}

/// A number of states, or `auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Count {
    /// This many.
    Fixed(usize),
    /// Chosen automatically.
    Auto,
}

impl std::str::FromStr for Count {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "auto" => Ok(Count::Auto),
            n => n
                .parse()
                .map(Count::Fixed)
                .map_err(|_| format!("`{s}` is neither a whole number nor `auto`")),
        }
    }
}

impl std::fmt::Display for Count {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Count::Fixed(n) => write!(f, "{n}"),
            Count::Auto => f.write_str("auto"),
        }
    }
}

/// `--select` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SelectArg {
    /// Lowest BIC over 2..=--max-states.
    Bic,
    /// G-means (Anderson–Darling splits; gmm-tsc's mixtures only).
    Gmeans,
}

impl From<SelectArg> for phasekit_tsc::Selector {
    fn from(s: SelectArg) -> Self {
        match s {
            SelectArg::Bic => phasekit_tsc::Selector::Bic,
            SelectArg::Gmeans => phasekit_tsc::Selector::GMeans,
        }
    }
}

/// Model settings shared by `fit` and `evaluate` (defaults: the paper-compatible protocol).
#[derive(Debug, Clone, Args)]
pub struct ModelArgs {
    /// States of the base HMM (components of a GMM); `auto`: chosen by --select over 2..=--max-states
    /// (hmm, tsc-hmm*, gmm-tsc)
    #[arg(long, value_name = "N|auto", default_value = "4")]
    pub states: Count,
    /// How `auto` counts are chosen: bic (lowest BIC over the range) or gmeans (G-means on the frames)
    #[arg(long, value_enum, value_name = "HOW", default_value = "bic")]
    pub select: SelectArg,
    /// Largest count an automatic choice may give
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub max_states: usize,
    /// States of the transition HMM λ_T (TSC-HMM); transition clusters of gmm-tsc (0 or auto: by --select)
    #[arg(long, value_name = "N|auto", default_value = "3")]
    pub tsc_states: Count,
    /// gmm-tsc: prune transition clusters holding transitions of fewer than this fraction ρ of the demonstrations
    #[arg(long, value_name = "X", default_value_t = 0.5)]
    pub rho: f64,
    /// gmm-tsc: sub-cluster each transition cluster by normalised time into at most N clusters (0 = off)
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub time_clusters: usize,
    /// Dilation ±W of transition frames (TSC-HMM); frames per window (gmm-tsc)
    #[arg(long, value_name = "W", default_value_t = 2)]
    pub window: usize,
    /// Most EM iterations
    #[arg(long, value_name = "N", default_value_t = 40)]
    pub max_iter: usize,
    /// EM stops when the mean log-likelihood per sequence gains less than this
    #[arg(long, value_name = "X", default_value_t = 1e-4)]
    pub tol: f64,
    /// Added to every covariance diagonal (data units²: 1e-2 on metres is (10 cm)²)
    #[arg(long, value_name = "X", default_value_t = 1e-2)]
    pub reg: f64,
    /// EM runs from different initialisations (the best is kept)
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub restarts: usize,
    /// Seed of every random choice of the fit
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub seed: u64,
    /// Z-score every feature with the training frames' mean and std (stored in the model file)
    #[arg(long, alias = "standardize")]
    pub standardise: bool,
    /// Worker threads [default: all cores]
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
}

const FIT_EXAMPLES: &str = "\
Examples:
  phasekit fit --data nuisi/handshake -o handshake.json
  phasekit fit --data nuisi --action rocket --method hmm:states=7 -o rocket.json
  phasekit fit --data demos/*.csv --human 'h_*' --robot 'r_*' --velocity none --method gmm -o m.json
  phasekit fit --data nuisi/handshake --method tsc-hmm --format json > report.json

Data: files, or a folder (all its train_*.csv|npy files); for a folder of action
folders, pick one with --action. Columns default to the human's p1_wrist_* and the
robot's p2_wrist_* with velocities of both (NuiSI); give --human/--robot otherwise.

Methods (presets): see the list below; settings per method with NAME:key=value,...
(keys: states, tsc-states, window, reg, max-iter, tol, restarts, seed, select,
max-states, rho, time-clusters), e.g. tsc-hmm:states=5,window=2 or
gmm-tsc:states=auto,select=gmeans,rho=0.6. The command-line flags set the defaults of every key.
states=auto (--states auto) chooses the base states over 2..=max-states by BIC,
or by G-means with select=gmeans (hmm, tsc-hmm*: λ's states; gmm-tsc: its mixture).";

/// The help text after a command's options: examples, then the presets.
fn with_presets(examples: &str) -> String {
    format!(
        "{examples}\n\nPresets: {}",
        phasekit_tsc::PRESETS.join(", ")
    )
}

/// `phasekit fit`.
#[derive(Debug, Args)]
pub struct FitArgs {
    /// Demonstration files (CSV with a header, or NPY), or a folder of train_* files
    #[arg(long, value_name = "DIR|FILE", num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// The action folder to use when --data is a folder of action folders
    #[arg(long, value_name = "NAME")]
    pub action: Option<String>,
    /// The method: a preset, optionally with NAME:key=value,... settings
    #[arg(long, value_name = "NAME", default_value = "tsc-hmm")]
    pub method: String,
    /// Column selection.
    #[command(flatten)]
    pub columns: ColumnArgs,
    /// Model settings.
    #[command(flatten)]
    pub model: ModelArgs,
    /// Write the model file here (JSON)
    #[arg(short, long, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// Print a fit report on stdout (json: iterations, log-likelihood per iteration, time, …)
    #[arg(long, value_enum)]
    pub format: Option<Format>,
    /// Shorthand for --format json
    #[arg(long, conflicts_with = "format")]
    pub json: bool,
    /// Fit a library of interactions: one model per action folder of --data, in one file
    #[arg(long)]
    pub library: bool,
    /// Library settings.
    #[command(flatten)]
    pub library_settings: crate::commands::recognise::LibraryArgs,
}

const SEGMENT_EXAMPLES: &str = "\
Examples:
  phasekit segment --model handshake.json --data nuisi/handshake/test_00.csv
  phasekit segment --model handshake.json --data nuisi/handshake --format json -o seg.json

CSV columns: file,frame,state,transition,cluster — state is the Viterbi state of the
frame, transition is 1 on transition frames, cluster the transition cluster (empty
when none). The files need the human's and the robot's columns.";

/// `phasekit segment`.
#[derive(Debug, Args)]
pub struct SegmentArgs {
    /// Model file written by `phasekit fit`
    #[arg(long, value_name = "PATH")]
    pub model: PathBuf,
    /// Demonstration files, or a folder (all its CSV/NPY files)
    #[arg(long, value_name = "DIR|FILE", num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Write here instead of stdout
    #[arg(short, long, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// csv (default) or json
    #[arg(long, value_enum, default_value = "csv")]
    pub format: Format,
    /// Shorthand for --format json
    #[arg(long)]
    pub json: bool,
}

const PREDICT_EXAMPLES: &str = "\
Examples:
  phasekit predict --model handshake.json --data nuisi/handshake/test_00.csv > robot.csv
  phasekit predict --model handshake.json --data nuisi/handshake/test_*.csv -o predictions/
  phasekit predict --model handshake.json --data test_00.csv --covariance -o robot.csv

Output: CSV with a header: frame, the robot's features (as named in the model), and
with --covariance var_X and cov_X_Y entries of the predictive covariance. Prediction
is causal: frame t uses the human's frames 0..=t only. The files need only the
human's columns. Several inputs: one <name>.predicted.csv (or .json) each in the -o folder.";

/// `phasekit predict`.
#[derive(Debug, Args)]
pub struct PredictArgs {
    /// Model file written by `phasekit fit`
    #[arg(long, value_name = "PATH")]
    pub model: PathBuf,
    /// Demonstration files, or a folder (all its CSV/NPY files)
    #[arg(long, value_name = "DIR|FILE", num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Add the predictive covariance's entries
    #[arg(long)]
    pub covariance: bool,
    /// Output file (one input) or folder (any number of inputs); stdout if absent
    #[arg(short, long, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// csv (default) or json ({"file", "features", "mean": [[…] per frame], "covariance": [[[…]]]})
    #[arg(long, value_enum, default_value = "csv")]
    pub format: Format,
    /// Shorthand for --format json
    #[arg(long)]
    pub json: bool,
}

const STREAM_EXAMPLES: &str = "\
Examples:
  cut -d, -f7-9 demo.csv | phasekit stream --model handshake.json
  my_tracker | phasekit stream --model handshake.json --covariance > robot.csv

Input: one human frame per line: the raw values of the model's human columns, in
the model's order (velocities are computed inside, causally). A first line with
names is a header: then lines may hold more columns, and the human's are picked
by name. An empty cell, `NaN` or `NA` is a missing value (the frame is used with
what is observed). An empty or malformed line is a frame with nothing observed:
it is reported on stderr and still predicted (from the dynamics alone). A line
`#reset` starts a new demonstration; other lines starting with `#` are ignored.
Output: one CSV line per input frame, flushed at once, after a header line (see
`predict`). At exit, per-frame latency on stderr.";

/// `phasekit stream`.
#[derive(Debug, Args)]
pub struct StreamArgs {
    /// Model file written by `phasekit fit`
    #[arg(long, value_name = "PATH")]
    pub model: PathBuf,
    /// Add the predictive covariance's entries
    #[arg(long)]
    pub covariance: bool,
    /// Do not write the header line
    #[arg(long)]
    pub no_header: bool,
    /// Do not report latency at exit
    #[arg(short, long)]
    pub quiet: bool,
    /// With a library: composed (one HMM with a rest state; the default) or per-action (one filter per action,
    /// reset when an interaction ends, unknown motions rejected)
    #[arg(long, value_enum, value_name = "HOW")]
    pub recogniser: Option<crate::commands::recognise::StreamMode>,
}

const EVALUATE_EXAMPLES: &str = "\
Examples:
  phasekit evaluate --data nuisi                      # PROTOCOL.md: 100 seeds, hmm vs tsc-hmm, all actions
  phasekit evaluate --data nuisi --action handshake --methods hmm,hmm:states=7,tsc-hmm --seeds 20
  phasekit evaluate --data nuisi --train-size 1000 --methods hmm   # all training demos, one run
  phasekit evaluate --data nuisi --format json -o results          # writes results.md and results.json

Protocol: seed s trains on a random subset of the training demonstrations (all but
two by default) and predicts every test_* demonstration from the human's frames.
Metric: per frame, squared Euclidean error of the robot's position columns (not
velocities) × unit-scale²; MSE = mean over frames of all test demonstrations;
mean ± std (population) over seeds. The paired columns compare each method with
the first and the second one on the same seeds. --seed seeds the fits' own random
choices (the subsets depend on the seed number only), so runs are reproducible.
Exit status 1 (after printing) when a method fails on every seed of an action, or,
with --fail-above X, when a method's mean MSE is not finite or above X (a CI guard).";

/// `phasekit evaluate`.
#[derive(Debug, Args)]
pub struct EvaluateArgs {
    /// A folder of action folders (each with train_* and test_* files), or one action folder
    #[arg(long, value_name = "DIR", required = true)]
    pub data: PathBuf,
    /// Only these actions (comma-separated folder names)
    #[arg(long, value_name = "NAME,...", value_delimiter = ',')]
    pub action: Option<Vec<String>>,
    /// Methods to compare (presets with optional :key=value,... settings); the first is the reference
    #[arg(
        long,
        alias = "method",
        value_name = "A,B,...",
        default_value = "hmm,hmm:states=7,tsc-hmm"
    )]
    pub methods: Vec<String>,
    /// Column selection.
    #[command(flatten)]
    pub columns: ColumnArgs,
    /// Model settings.
    #[command(flatten)]
    pub model: ModelArgs,
    /// Number of seeds (random training subsets)
    #[arg(long, value_name = "N", default_value_t = 100)]
    pub seeds: usize,
    /// Training demonstrations per seed [default: all but two]; ≥ their number: one run on all
    #[arg(long, value_name = "N")]
    pub train_size: Option<usize>,
    /// Factor from data units to reported units (100: metres → cm, MSE in cm²)
    #[arg(long, value_name = "X", default_value_t = 100.0)]
    pub unit_scale: f64,
    /// Also write PREFIX.md and PREFIX.json (a folder DIR/: DIR/evaluate.md and .json), both or neither
    #[arg(short, long, value_name = "PREFIX")]
    pub output: Option<PathBuf>,
    /// What to print: md (default, the table and the metric's definition), json or csv
    #[arg(long, value_enum, default_value = "md")]
    pub format: Format,
    /// Shorthand for --format json
    #[arg(long)]
    pub json: bool,
    /// Exit with an error (after printing) if any method's mean MSE is not finite or above X (reported units²)
    #[arg(long, value_name = "X")]
    pub fail_above: Option<f64>,
    /// Robustness experiment: remove this fraction of the selected values at random (seeded), from
    /// the training demonstrations and from the test demonstrations' human columns, before the
    /// velocities are computed
    #[arg(long, value_name = "FRAC")]
    pub missing: Option<f64>,
    /// What --missing removes: values (each independently), frames (whole frames), occlusions
    /// (runs of 10 frames of one side)
    #[arg(long, value_enum, value_name = "HOW", default_value = "values")]
    pub missing_mode: crate::experiment::RemovalMode,
    /// prediction (the paper's experiment, told the action) or recognition (which interaction is it?)
    #[arg(long, value_enum, default_value = "prediction")]
    pub task: crate::commands::recognise::Task,
    /// Library settings (--task recognition).
    #[command(flatten)]
    pub library_settings: crate::commands::recognise::LibraryArgs,
}

const PLOT_EXAMPLES: &str = "\
Examples:
  phasekit plot segmentation --model handshake.json --data nuisi/handshake/test_00.csv -o seg.svg
  phasekit plot prediction --model handshake.json --data nuisi/handshake/test_00.csv -o pred.svg
  phasekit plot states --model handshake.json --data nuisi/handshake -o states.svg --x p2_wrist_x --y p2_wrist_z";

/// `phasekit plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// What to draw.
    #[command(subcommand)]
    pub kind: PlotKind,
}

/// The pictures.
#[derive(Debug, Subcommand)]
pub enum PlotKind {
    /// A demonstration over time: states as colour bands, transition frames marked.
    #[command(
        after_help = "Example:\n  phasekit plot segmentation --model m.json --data test_00.csv -o seg.svg"
    )]
    Segmentation(PlotArgsCommon),
    /// Predicted vs true robot trajectories with ±2σ bands.
    #[command(
        after_help = "Example:\n  phasekit plot prediction --model m.json --data test_00.csv -o pred.svg"
    )]
    Prediction(PlotArgsCommon),
    /// Trajectories with the 2σ ellipses of the predicting model's states (a 2-D plane or an oblique 3-D view).
    #[command(
        after_help = "Examples:\n  phasekit plot states --model m.json --data demos/ -o states.svg\n  phasekit plot states --model m.json --data a.csv b.csv --x p1_wrist_x --y p1_wrist_y -o states.svg\n  phasekit plot states --model m.json --data demos/ --view 3d -o states3d.svg\n\nThe ellipses are those of the model that predicts: a union TSC-HMM's re-trained states,\nλ_T's drawn dashed as transition states; gmm-tsc's mixture, its kept clusters dashed.\nThe 3-D view is an oblique (cabinet) projection of --x, --y (depth) and --z [default:\nthe robot's x, y, z columns], with the outlines of the projected 2σ ellipsoids."
    )]
    States(PlotStatesArgs),
    /// Recognition: the posterior of each action over a demonstration, or the accuracy curve of an evaluation.
    #[command(after_help = crate::commands::recognise::PLOT_RECOGNITION_EXAMPLES)]
    Recognition(crate::commands::recognise::PlotRecognitionArgs),
}

/// Arguments of a plot of one demonstration.
#[derive(Debug, Args)]
pub struct PlotArgsCommon {
    /// Model file written by `phasekit fit`
    #[arg(long, value_name = "PATH")]
    pub model: PathBuf,
    /// One demonstration file
    #[arg(long, value_name = "FILE")]
    pub data: PathBuf,
    /// The SVG file to write
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
}

/// Arguments of `plot states`.
#[derive(Debug, Args)]
pub struct PlotStatesArgs {
    /// Model file written by `phasekit fit`
    #[arg(long, value_name = "PATH")]
    pub model: PathBuf,
    /// Demonstration files, or a folder (all its CSV/NPY files)
    #[arg(long, value_name = "DIR|FILE", num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Feature on the horizontal axis [default: the robot's x column]
    #[arg(long, value_name = "FEATURE")]
    pub x: Option<String>,
    /// Feature on the vertical axis (2d) or in depth (3d) [default: the robot's z column (2d), y column (3d)]
    #[arg(long, value_name = "FEATURE")]
    pub y: Option<String>,
    /// Feature pointing up in the 3-D view [default: the robot's z column]
    #[arg(long, value_name = "FEATURE")]
    pub z: Option<String>,
    /// 2d: a plane of two features; 3d: an oblique view of three
    #[arg(long, value_enum, default_value = "2d")]
    pub view: View,
    /// The SVG file to write
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
}

const DEMO_EXAMPLES: &str = "\
Examples:
  phasekit demo
  phasekit demo -o /tmp/demo --seed 3

Generates two-agent interactions with known phases (idle, reach, shake, retract),
fits hmm and tsc-hmm on 12 of them, predicts the other 4 from the human's hand,
compares with a constant-pose baseline, checks the transitions found against the
true phase boundaries, and writes the data, the models and three plots to the folder.";

/// `plot states --view` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum View {
    /// A plane of two features.
    #[value(name = "2d")]
    TwoD,
    /// An oblique projection of three features.
    #[value(name = "3d")]
    ThreeD,
}

/// `phasekit demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Folder for the generated data, models and plots
    #[arg(short, long, value_name = "DIR", default_value = "phasekit-demo")]
    pub output: PathBuf,
    /// Seed of the generated data and the fits
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub seed: u64,
    /// Training demonstrations
    #[arg(long, value_name = "N", default_value_t = 12)]
    pub train: usize,
    /// Test demonstrations
    #[arg(long, value_name = "N", default_value_t = 4)]
    pub test: usize,
}
