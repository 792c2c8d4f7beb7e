//! Command-line arguments of `phasekit` (clap derive).

use clap::{Args, Parser, Subcommand, ValueEnum};
use std::path::PathBuf;

const TOP_EXAMPLES: &str = "\
Examples:
  phasekit demo                    # the whole pipeline on generated data, in seconds
  phasekit fit --data nuisi/handshake --method tsc-hmm -o handshake.json
  phasekit predict --model handshake.json --data nuisi/handshake/test_00.csv
  phasekit evaluate --data nuisi --methods hmm,tsc-hmm --seeds 20 -o results
  phasekit <COMMAND> --help        # every command's options and examples";

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

/// Formats of predictions and segmentations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DataFormat {
    /// CSV with a header.
    Csv,
    /// JSON.
    Json,
    /// A 2-D float array (NumPy's .npy), the CSV's columns in order.
    Npy,
}

/// `stream --on-bad-line` values: what a line that is not a frame does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BadLine {
    /// Stop with an error naming the line.
    Error,
    /// A frame with nothing observed (predicted from the dynamics; status `unobserved`).
    Missing,
    /// Ignored: no frame, no output line.
    Skip,
}

/// An emission name (`full`, `diag`, `spherical`, `tied`, `student-t`, `gmm-K`).
fn parse_emission(s: &str) -> std::result::Result<phasekit_tsc::EmissionKind, String> {
    s.parse()
}

/// A covariance regularisation: a finite number in `[0, 1e100]`, parsed as such
/// (so that `-1` is a number, refused for what it is).
fn parse_reg(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))?;
    if !v.is_finite() || v < 0.0 {
        return Err(format!(
            "must be a finite number ≥ 0 (it is added to every variance), not {s}"
        ));
    }
    if v > 1e100 {
        return Err(format!(
            "{s} is far too large: the regularisation is added to every variance, in data units² \
             (1e-2 is (10 cm)² on data in metres), and phasekit takes at most 1e100; use a value on \
             the scale of the data's variance, or --standardise with a value like 1e-2"
        ));
    }
    Ok(v)
}

/// A number of worker threads: at least 1, at most [`max_threads`].
fn parse_threads(s: &str) -> Result<usize, String> {
    let n: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a whole number"))?;
    let max = max_threads();
    if n == 0 {
        return Err("must be at least 1".into());
    }
    if n > max {
        return Err(format!(
            "{n} threads cannot help: phasekit takes at most 4 per core of this machine (and 64 on any) \
             — more only adds the cost of starting them, and the results do not depend on the number"
        ));
    }
    Ok(n)
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The most worker threads `--threads` accepts: 4 per core, at least 64.
pub fn max_threads() -> usize {
    (4 * cores()).max(64)
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
    #[arg(
        long,
        value_name = "X",
        default_value_t = 0.5,
        allow_negative_numbers = true
    )]
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
    #[arg(
        long,
        value_name = "X",
        default_value_t = 1e-4,
        allow_negative_numbers = true
    )]
    pub tol: f64,
    /// Added to every covariance diagonal (data units²: 1e-2 on metres is (10 cm)²)
    #[arg(long, value_name = "X", default_value = "0.01", value_parser = parse_reg, allow_negative_numbers = true)]
    pub reg: f64,
    /// EM runs from different initialisations (the best is kept)
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub restarts: usize,
    /// Seed of every random choice of the fit
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub seed: u64,
    /// Emission of every HMM state or mixture component: full (default), diag, spherical, tied (Gaussians),
    /// student-t (robust to outlying frames), gmm-K (K full Gaussians per state, e.g. gmm-2)
    #[arg(long, value_name = "NAME", default_value = "full", value_parser = parse_emission)]
    pub emission: phasekit_tsc::EmissionKind,
    /// Z-score every feature with the training frames' mean and std (stored in the model file)
    #[arg(long, alias = "standardize")]
    pub standardise: bool,
    /// Worker threads [default: all cores; at most 4 per core]
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    pub threads: Option<usize>,
}

const FIT_EXAMPLES: &str = "\
Examples:
  phasekit fit --data nuisi/handshake -o handshake.json
  phasekit fit --data nuisi --action rocket --method hmm:states=7 -o rocket.json
  phasekit fit --data 'demos/*.csv' --human 'h_*' --robot 'r_*' --velocity none \\
      --method gmm -o m.json
  phasekit fit --data nuisi/handshake --method tsc-hmm --format json > report.json

Data: files, quoted patterns ('demos/train_*.csv'), or a folder (all its
train_*.csv|npy files); for a folder of action folders, pick one with --action.
Each file is given once. Columns default to the human's p1_wrist_* and the robot's
p2_wrist_* with velocities of both (NuiSI); give --human/--robot otherwise; other
columns (a timestamp, a label) are not read. The model file is JSON (-o NAME.json);
it also records the out-of-distribution threshold of predict and stream, calibrated
on the training demonstrations.

Methods (presets): see the list below; settings per method with NAME:key=value,...
(keys: states, tsc-states, window, reg, reg-units = absolute|relative|positions, reg-rel
(reg-rel=R is reg=R,reg-units=relative: R × each feature's variance), reg-pos (reg-pos=R is
reg=R,reg-units=positions: R × the variance of each feature's position, a velocity's being its
position's: the same fit in any unit), max-iter, tol, restarts, seed, select,
max-states, rho, time-clusters, emission; hsmm: duration = gaussian|poisson|negative-binomial|
non-parametric, max-duration = frames), e.g. tsc-hmm:states=5,window=2,
gmm-tsc:states=auto,select=gmeans,rho=0.6 or hsmm:states=7,duration=poisson.
The command-line flags set the defaults of every key.
states=auto (--states auto) chooses the base states over 2..=max-states by BIC,
or by G-means with select=gmeans (hmm, tsc-hmm*: λ's states; gmm-tsc: its mixture).
auto chooses the family, states, reg and emission by cross-validated prediction error
on the training demonstrations and predicts with the mean of the best 5 (keys:
grid=unit-free|small|default|relative|positions|mixed (unit-free, the default: every reg a
fraction of a variance of the data, each candidate the same in any unit; default: reg in the data's units),
folds=K, families=hmm+tsc-hmm+gmm, halving=on|off, ensemble=K (the mean of the best K; 1: the
best alone), choose=best|one-se (one candidate: the lowest error, or the most
regularised within one standard error of it), calibrate=on|predictive|demonstrations|frames|off
(on = predictive: its 95 % regions shaped by the held-out errors and sized to cover 95 % of a
new demonstration in expectation; demonstrations: widened to cover a left-out one; frames: the
pooled held-out frames); reg-units=relative makes every candidate's reg relative);
fit --format md shows its cross-validation table.";

/// The help text after a command's options: examples, then the presets.
fn with_presets(examples: &str) -> String {
    format!("{examples}\n\nPresets: {}", phasekit_tsc::Preset::names())
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
    /// Write the model file here (JSON: NAME.json)
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
  phasekit segment --model handshake.json --data nuisi/handshake -o seg.json
  phasekit segment --model handshake.json --data 'nuisi/handshake/test_*.csv' -o seg.npy

CSV columns: file,frame,state,transition,cluster — state is the Viterbi state of the
frame, transition is 1 on transition frames, cluster the transition cluster (empty
when none). NPY: the same columns as numbers, file as the index of the input (in the
order given) and a missing cluster as NaN. The output's extension (.csv, .json, .npy)
chooses the format unless --format does. The files need the human's and the robot's
columns; other columns are not read. A frame with a value so far from every state that
its density is zero (e.g. 1e200) is taken as not observed, with a warning.";

/// `phasekit segment`.
#[derive(Debug, Args)]
pub struct SegmentArgs {
    /// Model file written by `phasekit fit`
    #[arg(long, value_name = "PATH")]
    pub model: PathBuf,
    /// Demonstration files, or a folder (all its CSV/NPY files)
    #[arg(long, value_name = "DIR|FILE", num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Write here instead of stdout (`-`: stdout)
    #[arg(short, long, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// csv, json or npy [default: by the output's extension, else csv]
    #[arg(long, value_enum)]
    pub format: Option<DataFormat>,
    /// Shorthand for --format json
    #[arg(long, conflicts_with = "format")]
    pub json: bool,
}

const PREDICT_EXAMPLES: &str = "\
Examples:
  phasekit predict --model handshake.json --data nuisi/handshake/test_00.csv > robot.csv
  phasekit predict --model handshake.json --data 'nuisi/handshake/test_*' -o predictions/
  phasekit predict --model handshake.json --data test_00.csv --covariance -o robot.npy

Output: CSV with a header: frame, the robot's features (as named in the model), and
with --covariance var_X and cov_X_Y entries of the predictive covariance; NPY holds
the same columns; JSON also lists the flagged frames. The output's extension (.csv,
.json, .npy) chooses the format unless --format does. Several inputs: one
<name>.predicted.csv (.json, .npy) each in the -o folder. Prediction is causal:
frame t uses the human's frames 0..=t only. The files need only the human's columns
(the others are not read).

Warnings (stderr): frames whose human input is out of distribution (its likelihood
under the model, per value, below the threshold calibrated on the training data:
another coordinate frame or unit?), and frames whose values no state can explain
(e.g. 1e200), which are taken as not observed.";

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
    /// Output file (one input) or folder (any number of inputs); stdout if absent or `-`
    #[arg(short, long, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// csv, json ({"file", "features", "mean", "covariance", "out_of_distribution",
    /// "rejected"}) or npy [default: by the output's extension, else csv]
    #[arg(long, value_enum)]
    pub format: Option<DataFormat>,
    /// Shorthand for --format json
    #[arg(long, conflicts_with = "format")]
    pub json: bool,
}

const STREAM_EXAMPLES: &str = "\
Examples:
  cut -d, -f7-9 demo.csv | phasekit stream --model handshake.json
  my_tracker | phasekit stream --model handshake.json --covariance > robot.csv
  my_tracker | phasekit stream --model handshake.json --columns wx,wy,wz

Input: comma-separated lines. A first line with names is a header: it must name
every human column of the model (exact names; a UTF-8 byte order mark is ignored),
which are then picked by name from lines of any width; other columns are not read.
Without a header, each line holds exactly the model's human columns, in its order.
--columns maps other names (or 1-based column numbers) to the model's human
columns, in the model's order. An empty cell, `NaN` or `NA` is a missing value
(the frame is used with what is observed). A line `#reset` starts a new
demonstration; other lines starting with `#` are comments.

A line that is not a frame (wrong number of values, a value that is not a number
or is infinite, a blank line, text that is not UTF-8, a banner before the header)
stops the stream with an error naming the line, unless --on-bad-line says to take
it as a frame with nothing observed (missing) or to ignore it (skip); either is
reported on stderr.

Output: one CSV line per input frame, flushed at once, after a header line (see
`predict`), ending with a status column: ok; unobserved (nothing observed:
predicted from the dynamics alone); ood (out of distribution: the human's input is
far less likely under the model than the training data, per value; the prediction
is an extrapolation); rejected (a value no state can explain, e.g. 1e200: taken as
not observed). At exit, on stderr: frames, statuses, and latency per frame (mean,
p50, p99, max; a fixed-size histogram keeps memory flat however long the stream).";

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
    /// The input columns holding the model's human columns, in the model's order:
    /// header names, or 1-based column numbers
    #[arg(long, value_name = "NAME|N,...", value_delimiter = ',')]
    pub columns: Option<Vec<String>>,
    /// What a line that is not a frame does: error (stop, naming the line), missing
    /// (a frame with nothing observed) or skip (no frame)
    #[arg(long, value_enum, value_name = "WHAT", default_value = "error")]
    pub on_bad_line: BadLine,
    /// With a library: composed (one HMM with a rest state; the default) or per-action (one filter per action,
    /// reset when an interaction ends, unknown motions rejected)
    #[arg(long, value_enum, value_name = "HOW")]
    pub recogniser: Option<crate::commands::recognise::StreamMode>,
}

const EVALUATE_EXAMPLES: &str = "\
Examples:
  phasekit evaluate --data nuisi          # PROTOCOL.md: 100 seeds, all actions
  phasekit evaluate --data nuisi --action handshake --methods hmm,tsc-hmm --seeds 20
  phasekit evaluate --data nuisi --train-size 1000 --methods hmm   # one run on all
  phasekit evaluate --data nuisi --format json -o results  # results.md, results.json
  phasekit evaluate --data angles --human 'h_*' --robot 'r_*' \
    --unit rad --unit-scale 1

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
    /// Reported unit (--unit, --unit-scale).
    #[command(flatten)]
    pub unit: crate::units::UnitArgs,
    /// Also write PREFIX.md and PREFIX.json (a folder DIR/: DIR/evaluate.md and .json; both or
    /// neither), and beside them PREFIX_error_by_time.csv, one SVG per action and
    /// PREFIX_by_test_demonstration.csv
    #[arg(short, long, value_name = "PREFIX")]
    pub output: Option<PathBuf>,
    /// What to print: md (default, the table and the metric's definition), json or csv
    #[arg(long, value_enum, default_value = "md")]
    pub format: Format,
    /// Shorthand for --format json
    #[arg(long)]
    pub json: bool,
    /// Exit with an error (after printing) if any method's mean MSE is not finite or above X (reported units²)
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    pub fail_above: Option<f64>,
    /// Robustness experiment: remove this fraction of the selected values at random (seeded), from
    /// the training demonstrations and from the test demonstrations' human columns, before the
    /// velocities are computed
    #[arg(long, value_name = "FRAC", allow_negative_numbers = true)]
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
    /// Bins of normalised time (0 = first frame, 1 = last frame of a test demonstration) for
    /// the error over time that -o writes (PREFIX_error_by_time.csv and one SVG per action)
    #[arg(long, value_name = "N", default_value_t = crate::experiment::DEFAULT_TIME_BINS)]
    pub time_bins: usize,
}

const PLOT_EXAMPLES: &str = "\
Examples:
  phasekit plot segmentation --model m.json --data nuisi/handshake/test_00.csv -o seg.svg
  phasekit plot prediction --model m.json --data nuisi/handshake/test_00.csv -o pred.svg
  phasekit plot states --model m.json --data nuisi/handshake -o states.svg \\
      --x p2_wrist_x --y p2_wrist_z";

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
        after_help = "Examples:\n  phasekit plot states --model m.json --data demos/ -o states.svg\n  phasekit plot states --model m.json --data a.csv b.csv --x p1_wrist_x --y p1_wrist_y \\\n      -o states.svg\n  phasekit plot states --model m.json --data demos/ --view 3d -o states3d.svg\n\nThe ellipses are those of the model that predicts: a union TSC-HMM's re-trained states,\nλ_T's drawn dashed as transition states; gmm-tsc's mixture, its kept clusters dashed.\nThe 3-D view is an oblique (cabinet) projection of --x, --y (depth) and --z [default:\nthe robot's x, y, z columns], with the outlines of the projected 2σ ellipsoids."
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
    /// The SVG file to write (NAME.svg)
    #[arg(short, long, value_name = "PATH")]
    pub output: PathBuf,
    /// Unit of the axes (--unit, --unit-scale).
    #[command(flatten)]
    pub unit: crate::units::UnitArgs,
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
    /// Unit of the axes (--unit, --unit-scale).
    #[command(flatten)]
    pub unit: crate::units::UnitArgs,
}

const DEMO_EXAMPLES: &str = "\
Examples:
  phasekit demo
  phasekit demo -o /tmp/demo --seed 3

Generates two-agent interactions with known phases (idle, reach, shake, retract),
fits hmm, hmm:states=7 (the control with as many states as the TSC-HMM) and tsc-hmm
on 12 of them, predicts the other 4 from the human's hand, compares with a
constant-pose baseline and over --seeds random training subsets, checks the
transitions found against the true phase boundaries, and writes the data, the
models and three plots to the folder (replacing an earlier demo's folder only).";

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
    /// Random training subsets (all but two demonstrations each) of the comparison over seeds; 0: none
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub seeds: usize,
}
