//! The recognition experiment behind `phasekit evaluate --task recognition`.
//!
//! Protocol (`../shared/PROTOCOL.md`, extended to a library): seed `s` trains
//! every action's model on the same random subset of its training
//! demonstrations as the prediction experiment (all but two by default,
//! [`subset`]), assembles the library, and then:
//!
//! * **recognition**: runs the per-action recogniser (rejection off) over every
//!   test demonstration of every action; the decision after observing `k/10` of
//!   a demonstration of `T` frames is the one at frame `⌈kT/10⌉`; accuracy is
//!   the fraction of test demonstrations decided right (per action, and over
//!   all test demonstrations: `all`); the decision *settles* at the first frame
//!   from which it is right to the end ([`crate::metrics::settled_frame`]);
//! * **end to end**: the robot-prediction MSE (cm², the protocol's metric) of
//!   the method told the action (the *oracle*: the true action's own
//!   predictor, exactly the prediction experiment), of the most probable
//!   action's prediction and of the posterior-weighted mixture, with and
//!   without rejection (rejected frames predict the rest pose);
//! * **unknown motions**: for each action in turn, the library of the others
//!   (no refit, [`Library::assemble`]) on every test demonstration: how often
//!   the left-out action's demonstrations are rejected and the known ones are;
//! * **continuous streams**: a stream chains `stream_length` test
//!   demonstrations of random actions (seeded by `s`; features computed per
//!   demonstration, so the rest that ends one and starts the next is theirs);
//!   scored per frame (decision = the demonstration's action) for the composed
//!   HMM and for per-action filters with automatic resets, with resets at the
//!   true starts (an oracle segmentation) and with no reset; an interaction's
//!   decision settles when it is right for `stream_hold_frames` frames in a row
//!   ([`crate::metrics::held_frame`]: its end is rest, where the decision may
//!   rightly move on).
//!
//! Seeds run in parallel; every number depends on the seed only.

use crate::composed::ComposedRecogniser;
use crate::error::{RecognitionError, Result};
use crate::library::{FittedAction, Library, LibrarySettings};
use crate::metrics::{
    correct_from_first_third, frames_observed, held_frame, median_or_never, settled_frame,
    Confusion,
};
use crate::recogniser::{AutoReset, Decision, PredictionMode, Recogniser, RecogniserSettings};
use crate::rejection::Rejection;
use phasekit_emission::SequenceSet;
use phasekit_tsc::{Method, Roles};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One action's demonstrations: joint features `T × D` each, in data units.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionSplit {
    /// The action's name.
    pub name: String,
    /// Training demonstrations.
    pub train: Vec<Vec<f64>>,
    /// Test demonstrations.
    pub test: Vec<Vec<f64>>,
}

/// The data of the experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// The actions.
    pub actions: Vec<ActionSplit>,
    /// Joint feature dimension `D`.
    pub dim: usize,
    /// The human's and the robot's features.
    pub roles: Roles,
    /// Indices, within the robot's features, of those the metric scores (positions).
    pub scored: Vec<usize>,
    /// Factor from data units to reported units (100: metres → cm).
    pub unit_scale: f64,
}

/// How the experiment runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct ExperimentSettings {
    /// Number of seeds.
    pub seeds: usize,
    /// Training demonstrations per action and seed (`None`: all but two).
    pub train_size: Option<usize>,
    /// Z-score the features with the training subsets' mean and std (pooled over actions).
    pub standardise: bool,
    /// How each seed's library is built.
    pub library: LibrarySettings,
    /// Test demonstrations chained into one continuous stream.
    pub stream_length: usize,
    /// Frames per second of the data (for times).
    pub frame_rate: f64,
    /// Automatic resets of the per-action filters in streams.
    pub auto_reset: AutoReset,
    /// A method (label, settings) whose models recognise the actions for every
    /// method evaluated (which still predicts); `None`: each method recognises itself.
    pub recognition: Option<(String, Method)>,
    /// Actions fitted with their own method (action name, label, method) in
    /// place of the method evaluated, for prediction and recognition alike.
    pub action_methods: Vec<(String, String, Method)>,
    /// A stream's decision settles on an interaction when it is right for this
    /// many frames in a row (or to the interaction's end).
    pub stream_hold_frames: usize,
}

impl Default for ExperimentSettings {
    /// 100 seeds, all but two training demonstrations, no standardisation, the
    /// default library, streams of 12 demonstrations, 30 Hz, default resets,
    /// each method recognising itself, decisions held 30 frames (1 s) in streams.
    fn default() -> Self {
        ExperimentSettings {
            seeds: 100,
            train_size: None,
            standardise: false,
            library: LibrarySettings::default(),
            stream_length: 12,
            frame_rate: 30.0,
            auto_reset: AutoReset::default(),
            recognition: None,
            action_methods: Vec::new(),
            stream_hold_frames: 30,
        }
    }
}

/// Training subset of seed `seed`: `size` of `n` indices, sorted; all when
/// `size ≥ n` (the prediction experiment's subsets, same seed, same subset).
pub fn subset(seed: u64, n: usize, size: usize) -> Vec<usize> {
    if size >= n {
        return (0..n).collect();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut idx = rand::seq::index::sample(&mut rng, n, size).into_vec();
    idx.sort_unstable();
    idx
}

/// Mean and population standard deviation (NaN for none).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    (
        m,
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt(),
    )
}

/// A mean and a standard deviation over seeds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct Stat {
    /// Mean over seeds.
    pub mean: f64,
    /// Population standard deviation over seeds.
    pub std: f64,
}

impl Stat {
    fn of(v: &[f64]) -> Stat {
        let (mean, std) = mean_std(v);
        Stat { mean, std }
    }
}

/// Accuracy after observing a fraction of the test demonstrations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct AccuracyRow {
    /// Method label.
    pub method: String,
    /// Action, or `all` for every test demonstration.
    pub action: String,
    /// Fraction of each demonstration observed (0.1, 0.2, …, 1).
    pub fraction: f64,
    /// Fraction of the test demonstrations decided right, mean over seeds.
    pub accuracy: f64,
    /// Its population standard deviation over seeds.
    pub std: f64,
    /// Seeds.
    pub seeds: usize,
}

/// When the decision becomes and stays right.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct SettledRow {
    /// Method label.
    pub method: String,
    /// Action, or `all`.
    pub action: String,
    /// Test demonstrations scored (over all seeds).
    pub demonstrations: usize,
    /// Fraction of them right from the first third on.
    pub correct_from_first_third: f64,
    /// Fraction whose final decision is wrong (never settled).
    pub never: f64,
    /// Median number of frames observed when the decision settles (never = +∞; `None` if the median is never).
    pub median_frames: Option<f64>,
    /// The same in seconds at the data's frame rate.
    pub median_seconds: Option<f64>,
    /// The same as a fraction of the demonstration.
    pub median_fraction: Option<f64>,
    /// Seeds.
    pub seeds: usize,
}

/// Decisions summed over seeds at one observed fraction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct ConfusionRow {
    /// Method label.
    pub method: String,
    /// Fraction observed.
    pub fraction: f64,
    /// Counts: rows true actions, columns decided actions then unknown, rest.
    pub confusion: Confusion,
}

/// End-to-end robot prediction error of one action.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct EndToEndRow {
    /// Method label.
    pub method: String,
    /// Action, or `all` (every test frame).
    pub action: String,
    /// MSE (unit²) of the method told the action.
    pub oracle: Stat,
    /// MSE with the most probable action's prediction.
    pub most_probable: Stat,
    /// MSE with the posterior-weighted mixture.
    pub mixture: Stat,
    /// MSE of the mixture with likelihood-per-frame rejection (rest pose while rejected).
    pub mixture_rejecting: Stat,
    /// Mean over seeds of `(most_probable − oracle) / oracle`.
    pub change_most_probable: f64,
    /// Mean over seeds of `(mixture − oracle) / oracle`.
    pub change_mixture: f64,
    /// Mean over seeds of `(mixture_rejecting − oracle) / oracle`.
    pub change_mixture_rejecting: f64,
    /// Seeds.
    pub seeds: usize,
}

/// Rejection of unknown motions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct UnknownRow {
    /// Method label.
    pub method: String,
    /// The action left out of the library (`none`: the full library; `all`: pooled over left-out actions).
    pub left_out: String,
    /// The rejection test.
    pub rejection: Rejection,
    /// Fraction of the left-out action's test demonstrations rejected after the whole demonstration.
    pub unknown_rejected: Option<f64>,
    /// Fraction of their frames rejected (the robot kept still).
    pub unknown_frames_rejected: Option<f64>,
    /// Fraction of the known actions' test demonstrations rejected after the whole demonstration.
    pub known_rejected: f64,
    /// Fraction of their frames rejected.
    pub known_frames_rejected: f64,
    /// Seeds.
    pub seeds: usize,
}

/// How a continuous stream is recognised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StreamRecogniser {
    /// The composed HMM.
    Composed,
    /// Per-action filters, reset automatically when the decided action ends.
    AutoReset,
    /// Per-action filters reset at every true start (an oracle segmentation).
    OracleReset,
    /// Per-action filters never reset.
    NoReset,
}

impl StreamRecogniser {
    /// Every variant.
    pub const ALL: [StreamRecogniser; 4] = [
        StreamRecogniser::Composed,
        StreamRecogniser::AutoReset,
        StreamRecogniser::OracleReset,
        StreamRecogniser::NoReset,
    ];

    /// Its description in reports.
    pub fn describe(self) -> &'static str {
        match self {
            StreamRecogniser::Composed => "composed HMM",
            StreamRecogniser::AutoReset => "per-action filters, automatic resets",
            StreamRecogniser::OracleReset => "per-action filters, reset at each true start",
            StreamRecogniser::NoReset => "per-action filters, no reset",
        }
    }
}

/// Continuous streams, scored per frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct StreamRow {
    /// Method label.
    pub method: String,
    /// The recogniser.
    pub recogniser: StreamRecogniser,
    /// Fraction of frames whose decision is the true action.
    pub frame_accuracy: Stat,
    /// Median frames of an interaction observed until the decision settles on it:
    /// right for `stream_hold_frames` frames in a row or to the interaction's end (never = +∞).
    pub median_delay_frames: Option<f64>,
    /// The same in seconds.
    pub median_delay_seconds: Option<f64>,
    /// Fraction of interactions whose decision never settles on the right action.
    pub never: f64,
    /// Robot-prediction MSE (unit²) over the stream (per-action filters: the mixture).
    pub mse: Stat,
    /// The same when told the action and its start (the oracle).
    pub oracle_mse: Stat,
    /// Seeds.
    pub seeds: usize,
}

/// What the libraries' calibration set, over seeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct CalibrationRow {
    /// Method label.
    pub method: String,
    /// The posterior's temperature.
    pub temperature: Stat,
    /// Mean held-out log score of the true action at that temperature.
    pub log_score: Stat,
    /// The likelihood-per-frame threshold (nats per frame; seeds where it could be set).
    pub likelihood_per_frame: Stat,
    /// The threshold-model threshold (nats).
    pub threshold_model: Stat,
    /// Seeds.
    pub seeds: usize,
}

/// Everything the experiment measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct Report {
    /// The actions.
    pub actions: Vec<String>,
    /// The methods' labels.
    pub methods: Vec<String>,
    /// The settings.
    pub settings: ExperimentSettings,
    /// Seeds run (1 when every training demonstration is used).
    pub seeds: usize,
    /// Factor from data units to the reported units of the MSEs.
    pub unit_scale: f64,
    /// Accuracy rows `{method, action, fraction, accuracy, std, seeds}`.
    pub recognition: Vec<AccuracyRow>,
    /// When decisions settle.
    pub settled: Vec<SettledRow>,
    /// Confusion matrices after a third and after all of each demonstration.
    pub confusion: Vec<ConfusionRow>,
    /// End-to-end prediction error.
    pub end_to_end: Vec<EndToEndRow>,
    /// Unknown motions.
    pub unknown: Vec<UnknownRow>,
    /// Continuous streams.
    pub streams: Vec<StreamRow>,
    /// The libraries' calibration.
    pub calibration: Vec<CalibrationRow>,
    /// Failed (method, seed, message).
    pub failures: Vec<(String, u64, String)>,
}

/// Outcome of one test demonstration under the full library.
struct Demo {
    action: usize,
    decisions: Vec<Decision>,
    /// Rejected at each frame by (likelihood per frame, threshold model, either).
    rejected: Vec<[bool; 3]>,
    /// Squared errors summed over frames: oracle, most probable, mixture, mixture rejecting.
    se: [f64; 4],
    frames: usize,
}

/// Rejections of one (left-out action, test demonstration).
struct Rejections {
    left_out: usize,
    action: usize,
    at_end: [bool; 3],
    frames: [usize; 3],
    length: usize,
}

/// One stream under one recogniser.
struct StreamScore {
    correct: usize,
    frames: usize,
    delays: Vec<Option<f64>>,
    se: f64,
    oracle_se: f64,
    scored: usize,
}

struct SeedOutcome {
    demos: Vec<Demo>,
    rejections: Vec<Rejections>,
    streams: Vec<StreamScore>,
    calibration: crate::library::Calibration,
}

/// Features made comparable: `(x − shift) / scale`.
struct Scaling {
    shift: Vec<f64>,
    scale: Vec<f64>,
}

impl Scaling {
    fn apply(&self, x: &[f64]) -> Vec<f64> {
        let d = self.shift.len();
        x.iter()
            .enumerate()
            .map(|(i, v)| (v - self.shift[i % d]) / self.scale[i % d])
            .collect()
    }
}

/// Squared error (reported units²) of a predicted robot frame `p` (model
/// units) against the joint frame `truth` (data units), over the scored
/// features; `None` when a scored truth value is missing.
fn squared_error(ds: &Dataset, sc: &Scaling, p: &[f64], truth: &[f64]) -> Option<f64> {
    let mut se = 0.0;
    for &j in &ds.scored {
        let k = ds.roles.robot()[j];
        if truth[k].is_nan() {
            return None;
        }
        let v = p[j] * sc.scale[k] + sc.shift[k];
        se += ((v - truth[k]) * ds.unit_scale).powi(2);
    }
    Some(se)
}

fn human_of(ds: &Dataset, joint: &[f64]) -> Vec<f64> {
    joint
        .chunks_exact(ds.dim)
        .flat_map(|x| ds.roles.human().iter().map(move |&k| x[k]))
        .collect()
}

fn settings_for(both: bool, auto_reset: Option<AutoReset>) -> RecogniserSettings {
    RecogniserSettings {
        rejection: Rejection::Off,
        prediction: PredictionMode::Mixture,
        both_statistics: both,
        auto_reset,
        ..RecogniserSettings::default()
    }
}

/// Whether the statistics reject under the library's thresholds: likelihood
/// per frame, threshold model, either.
fn rejects(library: &Library, stats: (f64, f64)) -> [bool; 3] {
    let c = library.calibration();
    let pf = c.likelihood_per_frame.is_some_and(|l| stats.0 < l);
    let tm = c.threshold_model.is_some_and(|l| stats.1 < l);
    [pf, tm, pf || tm]
}

fn run_seed(
    ds: &Dataset,
    method: &Method,
    seed: u64,
    s: &ExperimentSettings,
) -> Result<SeedOutcome> {
    let d = ds.dim;
    let chosen: Vec<Vec<&Vec<f64>>> = ds
        .actions
        .iter()
        .map(|a| {
            let n = a.train.len();
            let size = s.train_size.unwrap_or(n.saturating_sub(2)).min(n);
            subset(seed, n, size).iter().map(|&i| &a.train[i]).collect()
        })
        .collect();
    let sc = if s.standardise {
        let mut shift = vec![0.0; d];
        let mut count = vec![0.0; d];
        let frames = || chosen.iter().flatten().flat_map(|q| q.chunks_exact(d));
        for f in frames() {
            for k in 0..d {
                if !f[k].is_nan() {
                    shift[k] += f[k];
                    count[k] += 1.0;
                }
            }
        }
        shift
            .iter_mut()
            .zip(&count)
            .for_each(|(m, n)| *m /= f64::max(*n, 1.0));
        let mut var = vec![0.0; d];
        for f in frames() {
            for k in 0..d {
                if !f[k].is_nan() {
                    var[k] += (f[k] - shift[k]).powi(2);
                }
            }
        }
        let scale = var
            .iter()
            .zip(&count)
            .map(|(q, n)| (q / f64::max(*n, 1.0)).sqrt())
            .map(|v| if v > 1e-12 && v.is_finite() { v } else { 1.0 })
            .collect();
        Scaling { shift, scale }
    } else {
        Scaling {
            shift: vec![0.0; d],
            scale: vec![1.0; d],
        }
    };
    // On z-scores, an action fitted by cross-validation (`auto`) judges the
    // error in the files' units (the choice made without `--standardise`).
    let roles = if s.standardise {
        let units = ds.roles.robot().iter().map(|&k| sc.scale[k]).collect();
        ds.roles.clone().with_error_units(units)?
    } else {
        ds.roles.clone()
    };
    let fitted = ds
        .actions
        .iter()
        .zip(&chosen)
        .map(|(a, train)| {
            let train: Vec<Vec<f64>> = train.iter().map(|q| sc.apply(q)).collect();
            let set = SequenceSet::new(&train, d)?;
            let own = s.action_methods.iter().find(|m| m.0 == a.name);
            FittedAction::fit(
                &a.name,
                &set,
                own.map_or(method, |m| &m.2),
                s.recognition.as_ref().map(|r| &r.1),
                &roles,
                &s.library,
            )
        })
        .collect::<Result<Vec<_>>>()?;
    let library = Library::assemble(&fitted, &roles, &s.library)?;
    let rest_pose = library.rest_pose();
    // Test demonstrations: (action, human features as the models see them, joint data).
    let tests: Vec<(usize, Vec<f64>, &Vec<f64>)> = ds
        .actions
        .iter()
        .enumerate()
        .flat_map(|(a, x)| x.test.iter().map(move |t| (a, t)))
        .map(|(a, t)| (a, human_of(ds, &sc.apply(t)), t))
        .collect();
    let h = ds.roles.human().len();
    let mut rec = Recogniser::new(&library, settings_for(true, None))?;
    let mut demos = Vec::with_capacity(tests.len());
    for (a, human, joint) in &tests {
        rec.reset();
        let t = human.len() / h;
        let mut demo = Demo {
            action: *a,
            decisions: Vec::with_capacity(t),
            rejected: Vec::with_capacity(t),
            se: [0.0; 4],
            frames: 0,
        };
        for (x, truth) in human.chunks_exact(h).zip(joint.chunks_exact(d)) {
            let decision = rec.step(x)?;
            let best = decision.action().unwrap_or(0);
            let rejected = rejects(&library, rec.statistics());
            // Rejection off: the recogniser's own prediction is the mixture.
            let mixed = rec.robot();
            let predictions: [&[f64]; 4] = [
                rec.action_robot(*a),
                rec.action_robot(best),
                mixed,
                if rejected[0] { &rest_pose } else { mixed },
            ];
            let errors: Option<Vec<f64>> = predictions
                .iter()
                .map(|p| squared_error(ds, &sc, p, truth))
                .collect();
            if let Some(e) = errors {
                demo.se.iter_mut().zip(&e).for_each(|(s, e)| *s += e);
                demo.frames += 1;
            }
            demo.decisions.push(decision);
            demo.rejected.push(rejected);
        }
        demos.push(demo);
    }
    // Unknown motions: each action left out in turn (needs two actions left).
    let mut rejections = Vec::new();
    if fitted.len() > crate::library::MIN_ACTIONS {
        for left_out in 0..fitted.len() {
            let rest: Vec<FittedAction> = fitted
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != left_out)
                .map(|(_, f)| f.clone())
                .collect();
            let lib = Library::assemble(&rest, &roles, &s.library)?;
            let mut r = Recogniser::new(&lib, settings_for(true, None))?;
            for (a, human, _) in &tests {
                r.reset();
                let mut frames = [0usize; 3];
                let mut last = [false; 3];
                for x in human.chunks_exact(h) {
                    r.step(x)?;
                    last = rejects(&lib, r.statistics());
                    frames
                        .iter_mut()
                        .zip(&last)
                        .for_each(|(f, l)| *f += *l as usize);
                }
                rejections.push(Rejections {
                    left_out,
                    action: *a,
                    at_end: last,
                    frames,
                    length: human.len() / h,
                });
            }
        }
    }
    // Continuous streams.
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5354_5245_414d_5321);
    let with_tests: Vec<usize> = (0..ds.actions.len())
        .filter(|&a| !ds.actions[a].test.is_empty())
        .collect();
    let picks: Vec<usize> = (0..s.stream_length)
        .map(|_| {
            let a = with_tests[rng.random_range(0..with_tests.len())];
            let first = tests.iter().position(|t| t.0 == a).unwrap_or(0);
            first + rng.random_range(0..ds.actions[a].test.len())
        })
        .collect();
    let mut streams = Vec::new();
    for variant in StreamRecogniser::ALL {
        streams.push(score_stream(ds, &sc, &library, &tests, &picks, variant, s)?);
    }
    Ok(SeedOutcome {
        calibration: library.calibration().clone(),
        demos,
        rejections,
        streams,
    })
}

#[allow(clippy::too_many_arguments)]
fn score_stream(
    ds: &Dataset,
    sc: &Scaling,
    library: &Library,
    tests: &[(usize, Vec<f64>, &Vec<f64>)],
    picks: &[usize],
    variant: StreamRecogniser,
    s: &ExperimentSettings,
) -> Result<StreamScore> {
    let (h, d) = (ds.roles.human().len(), ds.dim);
    let mut score = StreamScore {
        correct: 0,
        frames: 0,
        delays: Vec::new(),
        se: 0.0,
        oracle_se: 0.0,
        scored: 0,
    };
    let mut composed = match variant {
        StreamRecogniser::Composed => Some(ComposedRecogniser::new(library, false)?),
        _ => None,
    };
    let auto = (variant == StreamRecogniser::AutoReset).then_some(s.auto_reset);
    let mut per_action = Recogniser::new(library, settings_for(false, auto))?;
    let mut oracle = Recogniser::new(library, settings_for(false, None))?;
    for &k in picks {
        let (a, human, joint) = &tests[k];
        if variant == StreamRecogniser::OracleReset {
            per_action.reset();
        }
        oracle.reset();
        let mut decisions = Vec::with_capacity(human.len() / h);
        for (x, truth) in human.chunks_exact(h).zip(joint.chunks_exact(d)) {
            oracle.step(x)?;
            let (decision, robot): (Decision, &[f64]) = match composed.as_mut() {
                Some(c) => {
                    let decision = c.step(x)?;
                    (decision, c.robot())
                }
                None => (per_action.step(x)?, per_action.robot()),
            };
            decisions.push(decision);
            score.frames += 1;
            score.correct += (decision == Decision::Action(*a)) as usize;
            if let (Some(e), Some(eo)) = (
                squared_error(ds, sc, robot, truth),
                squared_error(ds, sc, oracle.action_robot(*a), truth),
            ) {
                score.se += e;
                score.oracle_se += eo;
                score.scored += 1;
            }
        }
        score
            .delays
            .push(held_frame(&decisions, *a, s.stream_hold_frames).map(|f| (f + 1) as f64));
    }
    Ok(score)
}

/// Runs the experiment: every method on every seed (`progress` is called after
/// each); methods that fail on a seed are reported in `failures` and left out
/// of that seed's numbers.
pub fn run(
    ds: &Dataset,
    methods: &[(String, Method)],
    settings: &ExperimentSettings,
    progress: &(dyn Fn() + Sync),
) -> Result<Report> {
    check_dataset(ds)?;
    if settings.seeds == 0 || settings.stream_length == 0 {
        return Err(RecognitionError::InvalidSetting {
            name: "seeds",
            reason: "at least one seed and one demonstration per stream are needed".into(),
        });
    }
    if !(settings.frame_rate.is_finite() && settings.frame_rate > 0.0) {
        return Err(RecognitionError::InvalidSetting {
            name: "frame_rate",
            reason: format!("must be a positive number, got {}", settings.frame_rate),
        });
    }
    settings.library.validate()?;
    let all_used = ds.actions.iter().all(|a| {
        let n = a.train.len();
        settings.train_size.unwrap_or(n.saturating_sub(2)) >= n
    });
    let seeds = if all_used { 1 } else { settings.seeds };
    let outcomes: Vec<Vec<std::result::Result<SeedOutcome, String>>> = (0..seeds as u64)
        .into_par_iter()
        .map(|seed| {
            methods
                .iter()
                .map(|(_, m)| {
                    let r = run_seed(ds, m, seed, settings).map_err(|e| e.to_string());
                    progress();
                    r
                })
                .collect()
        })
        .collect();
    let mut report = Report {
        actions: ds.actions.iter().map(|a| a.name.clone()).collect(),
        methods: methods.iter().map(|m| m.0.clone()).collect(),
        settings: settings.clone(),
        seeds,
        unit_scale: ds.unit_scale,
        recognition: Vec::new(),
        settled: Vec::new(),
        confusion: Vec::new(),
        end_to_end: Vec::new(),
        unknown: Vec::new(),
        streams: Vec::new(),
        calibration: Vec::new(),
        failures: Vec::new(),
    };
    for (j, (label, _)) in methods.iter().enumerate() {
        let ok: Vec<&SeedOutcome> = outcomes
            .iter()
            .enumerate()
            .filter_map(|(seed, r)| match &r[j] {
                Ok(x) => Some(x),
                Err(e) => {
                    report
                        .failures
                        .push((label.clone(), seed as u64, e.clone()));
                    None
                }
            })
            .collect();
        aggregate(&mut report, ds, settings, label, &ok);
    }
    Ok(report)
}

fn check_dataset(ds: &Dataset) -> Result<()> {
    let bad = |m: String| Err(RecognitionError::InvalidLibrary(m));
    if ds.actions.len() < crate::library::MIN_ACTIONS {
        return bad(format!(
            "recognition needs at least {} actions, got {}",
            crate::library::MIN_ACTIONS,
            ds.actions.len()
        ));
    }
    ds.roles.check(ds.dim)?;
    if ds.scored.iter().any(|&j| j >= ds.roles.robot().len()) {
        return bad("a scored feature is not one of the robot's".into());
    }
    for a in &ds.actions {
        if a.test.is_empty() {
            return bad(format!("action `{}` has no test demonstration", a.name));
        }
        if a.train.is_empty() {
            return bad(format!("action `{}` has no training demonstration", a.name));
        }
        for q in a.train.iter().chain(&a.test) {
            if q.is_empty() || !q.len().is_multiple_of(ds.dim) {
                return bad(format!(
                    "action `{}`: a demonstration of {} values is not a whole number of {}-feature frames",
                    a.name,
                    q.len(),
                    ds.dim
                ));
            }
        }
    }
    Ok(())
}

fn aggregate(
    report: &mut Report,
    ds: &Dataset,
    settings: &ExperimentSettings,
    label: &str,
    ok: &[&SeedOutcome],
) {
    let n_actions = ds.actions.len();
    let seeds = ok.len();
    let groups: Vec<(String, Option<usize>)> = ds
        .actions
        .iter()
        .enumerate()
        .map(|(a, x)| (x.name.clone(), Some(a)))
        .chain(std::iter::once(("all".to_string(), None)))
        .collect();
    let member = |g: Option<usize>, a: usize| g.is_none_or(|g| g == a);
    // Accuracy after k/10 of each demonstration.
    for (name, g) in &groups {
        for tenths in 1..=10 {
            let per_seed: Vec<f64> = ok
                .iter()
                .map(|o| {
                    let ds: Vec<&Demo> = o.demos.iter().filter(|d| member(*g, d.action)).collect();
                    let right = ds
                        .iter()
                        .filter(|d| {
                            let n = frames_observed(d.decisions.len(), tenths);
                            d.decisions[n - 1] == Decision::Action(d.action)
                        })
                        .count();
                    right as f64 / ds.len().max(1) as f64
                })
                .collect();
            let (accuracy, std) = mean_std(&per_seed);
            report.recognition.push(AccuracyRow {
                method: label.to_string(),
                action: name.clone(),
                fraction: tenths as f64 / 10.0,
                accuracy,
                std,
                seeds,
            });
        }
        let demos: Vec<&Demo> = ok
            .iter()
            .flat_map(|o| &o.demos)
            .filter(|d| member(*g, d.action))
            .collect();
        let n = demos.len().max(1) as f64;
        let settled: Vec<Option<usize>> = demos
            .iter()
            .map(|d| settled_frame(&d.decisions, d.action))
            .collect();
        let frames: Vec<Option<f64>> = settled.iter().map(|s| s.map(|f| (f + 1) as f64)).collect();
        let fractions: Vec<Option<f64>> = settled
            .iter()
            .zip(&demos)
            .map(|(s, d)| s.map(|f| (f + 1) as f64 / d.decisions.len() as f64))
            .collect();
        let median_frames = median_or_never(&frames);
        report.settled.push(SettledRow {
            method: label.to_string(),
            action: name.clone(),
            demonstrations: demos.len(),
            correct_from_first_third: demos
                .iter()
                .filter(|d| correct_from_first_third(&d.decisions, d.action))
                .count() as f64
                / n,
            never: settled.iter().filter(|s| s.is_none()).count() as f64 / n,
            median_frames,
            median_seconds: median_frames.map(|f| f / settings.frame_rate),
            median_fraction: median_or_never(&fractions),
            seeds,
        });
        // End to end.
        let mses: Vec<[f64; 4]> = ok
            .iter()
            .map(|o| {
                let mut se = [0.0; 4];
                let mut frames = 0usize;
                for d in o.demos.iter().filter(|d| member(*g, d.action)) {
                    se.iter_mut().zip(&d.se).for_each(|(s, x)| *s += x);
                    frames += d.frames;
                }
                se.map(|s| s / frames as f64)
            })
            .collect();
        let column = |i: usize| mses.iter().map(|m| m[i]).collect::<Vec<_>>();
        let change = |i: usize| {
            mean_std(
                &mses
                    .iter()
                    .map(|m| (m[i] - m[0]) / m[0])
                    .collect::<Vec<_>>(),
            )
            .0
        };
        report.end_to_end.push(EndToEndRow {
            method: label.to_string(),
            action: name.clone(),
            oracle: Stat::of(&column(0)),
            most_probable: Stat::of(&column(1)),
            mixture: Stat::of(&column(2)),
            mixture_rejecting: Stat::of(&column(3)),
            change_most_probable: change(1),
            change_mixture: change(2),
            change_mixture_rejecting: change(3),
            seeds,
        });
    }
    // Confusion after a third and after the whole demonstration.
    for (fraction, at) in [(1.0 / 3.0, 0usize), (1.0, 1)] {
        let mut c = Confusion::new(n_actions);
        for d in ok.iter().flat_map(|o| &o.demos) {
            let t = d.decisions.len();
            let n = if at == 0 { t.div_ceil(3).max(1) } else { t };
            c.add(d.action, d.decisions[n - 1]);
        }
        report.confusion.push(ConfusionRow {
            method: label.to_string(),
            fraction,
            confusion: c,
        });
    }
    // Unknown motions.
    for (k, rejection) in [
        Rejection::LikelihoodPerFrame,
        Rejection::ThresholdModel,
        Rejection::Either,
    ]
    .into_iter()
    .enumerate()
    {
        let full: Vec<&Demo> = ok.iter().flat_map(|o| &o.demos).collect();
        let frames: usize = full.iter().map(|d| d.rejected.len()).sum();
        report.unknown.push(UnknownRow {
            method: label.to_string(),
            left_out: "none".into(),
            rejection,
            unknown_rejected: None,
            unknown_frames_rejected: None,
            known_rejected: full
                .iter()
                .filter(|d| d.rejected.last().is_some_and(|r| r[k]))
                .count() as f64
                / full.len().max(1) as f64,
            known_frames_rejected: full
                .iter()
                .map(|d| d.rejected.iter().filter(|r| r[k]).count())
                .sum::<usize>() as f64
                / frames.max(1) as f64,
            seeds,
        });
        let any = ok.iter().any(|o| !o.rejections.is_empty());
        if !any {
            continue;
        }
        let left: Vec<(String, Option<usize>)> = groups.clone();
        for (name, g) in &left {
            let rows: Vec<&Rejections> = ok
                .iter()
                .flat_map(|o| &o.rejections)
                .filter(|r| member(*g, r.left_out))
                .collect();
            let (unknown, known): (Vec<&Rejections>, Vec<&Rejections>) =
                rows.iter().partition(|r| r.action == r.left_out);
            let rate = |v: &[&Rejections]| {
                v.iter().filter(|r| r.at_end[k]).count() as f64 / v.len().max(1) as f64
            };
            let frame_rate = |v: &[&Rejections]| {
                v.iter().map(|r| r.frames[k]).sum::<usize>() as f64
                    / v.iter().map(|r| r.length).sum::<usize>().max(1) as f64
            };
            report.unknown.push(UnknownRow {
                method: label.to_string(),
                left_out: name.clone(),
                rejection,
                unknown_rejected: Some(rate(&unknown)),
                unknown_frames_rejected: Some(frame_rate(&unknown)),
                known_rejected: rate(&known),
                known_frames_rejected: frame_rate(&known),
                seeds,
            });
        }
    }
    let cal = |f: &dyn Fn(&crate::library::Calibration) -> Option<f64>| {
        Stat::of(
            &ok.iter()
                .filter_map(|o| f(&o.calibration))
                .collect::<Vec<_>>(),
        )
    };
    report.calibration.push(CalibrationRow {
        method: label.to_string(),
        temperature: cal(&|c| Some(c.temperature)),
        log_score: cal(&|c| Some(c.log_score)),
        likelihood_per_frame: cal(&|c| c.likelihood_per_frame),
        threshold_model: cal(&|c| c.threshold_model),
        seeds,
    });
    // Streams.
    for (v, variant) in StreamRecogniser::ALL.into_iter().enumerate() {
        let scores: Vec<&StreamScore> = ok.iter().map(|o| &o.streams[v]).collect();
        let delays: Vec<Option<f64>> = scores
            .iter()
            .flat_map(|s| s.delays.iter().copied())
            .collect();
        let median = median_or_never(&delays);
        report.streams.push(StreamRow {
            method: label.to_string(),
            recogniser: variant,
            frame_accuracy: Stat::of(
                &scores
                    .iter()
                    .map(|s| s.correct as f64 / s.frames.max(1) as f64)
                    .collect::<Vec<_>>(),
            ),
            median_delay_frames: median,
            median_delay_seconds: median.map(|f| f / settings.frame_rate),
            never: delays.iter().filter(|d| d.is_none()).count() as f64
                / delays.len().max(1) as f64,
            mse: Stat::of(
                &scores
                    .iter()
                    .map(|s| s.se / s.scored.max(1) as f64)
                    .collect::<Vec<_>>(),
            ),
            oracle_mse: Stat::of(
                &scores
                    .iter()
                    .map(|s| s.oracle_se / s.scored.max(1) as f64)
                    .collect::<Vec<_>>(),
            ),
            seeds,
        });
    }
}
