//! The paper's experiment: for each action and method, several seeds, each
//! training on a random subset of the training demonstrations and predicting
//! every test demonstration from the human's frames alone.
//!
//! Metric (`../shared/PROTOCOL.md`): per frame, the squared Euclidean error of
//! the robot's selected position columns (never the appended velocities),
//! scaled to cm² (`unit_scale = 100` for data in metres); MSE is the mean over
//! all frames of all test demonstrations; RMSE = √MSE per seed; mean ± std
//! (population std) over seeds.
//!
//! Calibration (the same frames, the same position columns): a frame is
//! covered when its true robot position lies in the predicted 95 % region, the
//! χ² ellipsoid `(y − μ)ᵀ Σ⁻¹ (y − μ) ≤ χ²_{0.95}(p)` of the predictive mean
//! `μ` and covariance `Σ` (the position block, `p` dims); coverage is the
//! fraction of frames covered (a calibrated predictor covers 95 %). NLPD is
//! the mean over frames of `−log N(y; μ, Σ)` in nats, with `y` in the reported
//! unit (cm for data in metres: the density is per unit^p). Both per seed,
//! then mean ± population std over seeds, as the MSE.
//!
//! Error over normalised time (issue 17): the same frames' squared errors and
//! coverage, binned by the frame's normalised time `τ = t / (T − 1)` in its test
//! demonstration (`T` frames; `τ = 0` when `T = 1`) into `B` equal bins
//! ([`time_bin`], [`TimeBins`]); per seed and bin the MSE and coverage, then per
//! bin mean, population std, 5th and 95th percentiles over seeds
//! ([`summarise_time_bins`]). Per seed, the frame-weighted mean of the bins' MSE
//! is the seed's MSE.

use crate::data::{Action, FeatureSpec, Layout, Table};
use phasekit_emission::{Frames, SequenceSet};
use phasekit_tsc::{Method, PresetOptions, Selector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// A method to evaluate, with the label it is reported under.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedMethod {
    /// Label in tables (e.g. `hmm:states=7`).
    pub label: String,
    /// The method.
    pub method: Method,
}

/// Parses `NAME[:key=value,...]` on top of `defaults`. Keys: `states` (a number or
/// `auto`), `tsc-states` (a number; `auto` or 0 for gmm-tsc's automatic transition
/// clusters), `window`, `reg`, `reg-units` (`absolute`, the default: data units²;
/// `relative`: a fraction of each feature's variance over the training frames;
/// `positions`: a fraction of the variance of each feature's position),
/// `reg-rel` (`reg-rel=R` = `reg=R,reg-units=relative`), `reg-pos` (`reg-pos=R` =
/// `reg=R,reg-units=positions`), `max-iter`, `tol`, `restarts`, `seed`, `select`
/// (`bic`|`gmeans`), `max-states`, `rho`, `time-clusters`, `emission` (`full`, `diag`,
/// `spherical`, `tied`, `student-t`, `gmm-K`), and for `hsmm` `duration` (`gaussian`,
/// `poisson`, `negative-binomial`, `non-parametric`) and `max-duration` (frames).
/// The preset checks the result.
pub fn parse_method(spec: &str, defaults: &PresetOptions) -> Result<NamedMethod, String> {
    let (name, rest) = spec.split_once(':').unwrap_or((spec, ""));
    let mut o = defaults.to_builder();
    let mut seen: Vec<&str> = Vec::new();
    let mut auto = phasekit_tsc::AutoSettings::builder();
    for kv in rest.split(',').filter(|s| !s.is_empty()) {
        let (k, v) = kv
            .split_once('=')
            .ok_or_else(|| format!("`{kv}` in `{spec}` is not key=value"))?;
        // A repeated key is a mistake (which one was meant?), not "the last wins".
        if seen.contains(&k) {
            return Err(format!(
                "`{k}` given twice in `{spec}`: give every setting once"
            ));
        }
        // `reg-rel=R` is `reg=R,reg-units=relative` (`reg-pos`: positions):
        // with any other of these, which was meant?
        let clash = match k {
            "reg-rel" | "reg-pos" | "reg" | "reg-units" => seen.iter().find(|s| {
                matches!(**s, "reg-rel" | "reg-pos" | "reg" | "reg-units")
                    && (matches!(k, "reg-rel" | "reg-pos") || matches!(**s, "reg-rel" | "reg-pos"))
            }),
            _ => None,
        };
        if let Some(other) = clash {
            return Err(format!(
                "`{k}` and `{other}` both given in `{spec}`: reg-rel=R is reg=R,reg-units=relative \
                 and reg-pos=R is reg=R,reg-units=positions; give one or the other"
            ));
        }
        seen.push(k);
        let bad = |e: &dyn std::fmt::Display| format!("`{kv}` in `{spec}`: {e}");
        if name == "auto" {
            // auto's own keys; the grid sets the model's, so giving one is a mistake.
            if phasekit_tsc::AutoSettings::is_key(k) {
                auto = phasekit_tsc::AutoSettings::set(auto, k, v)
                    .map_err(|e| bad(&crate::error::CliError::from(e).message))?;
                continue;
            }
            if matches!(
                k,
                "states" | "tsc-states" | "window" | "reg" | "reg-rel" | "reg-pos" | "emission"
            ) {
                return Err(bad(&format!(
                    "auto chooses `{k}` by cross-validation; narrow its search with grid=unit-free|small|default|relative|positions|mixed or families=hmm+tsc-hmm+gmm \
                     (reg-units=relative makes every candidate's reg a fraction of each feature's variance)"
                )));
            }
        }
        match k {
            "states" if v == "auto" => o = o.auto_states(),
            "states" => o = o.states(v.parse().map_err(|e| bad(&e))?),
            "tsc-states" if v == "auto" => o = o.tsc_states(0),
            "tsc-states" => o = o.tsc_states(v.parse().map_err(|e| bad(&e))?),
            "window" => o = o.window(v.parse().map_err(|e| bad(&e))?),
            "reg" => o = o.reg(v.parse().map_err(|e| bad(&e))?),
            "reg-units" => {
                o = o.reg_units(
                    v.parse::<phasekit_tsc::RegUnits>()
                        .map_err(|e| bad(&crate::error::CliError::from(e).message))?,
                )
            }
            "reg-rel" => {
                o = o
                    .reg(v.parse().map_err(|e| bad(&e))?)
                    .reg_units(phasekit_tsc::RegUnits::Relative)
            }
            "reg-pos" => {
                o = o
                    .reg(v.parse().map_err(|e| bad(&e))?)
                    .reg_units(phasekit_tsc::RegUnits::Positions)
            }
            "max-iter" => o = o.max_iter(v.parse().map_err(|e| bad(&e))?),
            "tol" => o = o.tol(v.parse().map_err(|e| bad(&e))?),
            "restarts" => o = o.restarts(v.parse().map_err(|e| bad(&e))?),
            "seed" => o = o.seed(v.parse().map_err(|e| bad(&e))?),
            "select" => o = o.select(v.parse::<Selector>().map_err(|e| bad(&e))?),
            "max-states" => o = o.max_states(v.parse().map_err(|e| bad(&e))?),
            "rho" => o = o.rho(v.parse().map_err(|e| bad(&e))?),
            "time-clusters" => o = o.time_clusters(v.parse().map_err(|e| bad(&e))?),
            "duration" => {
                o = o.duration(
                    v.parse::<phasekit_tsc::DurationFamily>()
                        .map_err(|e| bad(&e))?,
                )
            }
            "max-duration" => o = o.max_duration(Some(v.parse().map_err(|e| bad(&e))?)),
            "emission" => {
                o = o.emission(
                    v.parse::<phasekit_tsc::EmissionKind>()
                        .map_err(|e| bad(&e))?,
                )
            }
            other => return Err(format!("unknown key `{other}` in `{spec}`")),
        }
    }
    let cli = |e: phasekit_tsc::TscError| crate::error::CliError::from(e).message;
    let o = o.build().map_err(|e| format!("`{spec}`: {}", cli(e)))?;
    let preset = name.parse::<phasekit_tsc::Preset>().map_err(cli)?;
    let method = if preset == phasekit_tsc::Preset::Auto {
        auto.build()
            .and_then(|a| a.method(&o))
            .map_err(|e| format!("`{spec}`: {}", cli(e)))?
    } else {
        Method::preset(preset, &o).map_err(cli)?
    };
    Ok(NamedMethod {
        label: spec.to_string(),
        method,
    })
}

/// How the experiment is run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Protocol {
    /// Number of seeds (seed `s` draws the training subset with `ChaCha8Rng::seed_from_u64(s)`).
    pub seeds: usize,
    /// Training demonstrations per seed; `None`: all but two (the protocol). Equal
    /// to the number of training demonstrations: one deterministic run.
    pub train_size: Option<usize>,
    /// Factor from data units to the reported unit (100: metres → cm).
    pub unit_scale: f64,
    /// Standardise features (z-score with the training subset's mean and std) before fitting.
    pub standardise: bool,
    /// Values removed at random from every seed's data (a robustness experiment;
    /// the paper's protocol removes none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub removal: Option<Removal>,
    /// Bins of normalised time the error is also reported in ([`TimeBins`]), at least 1.
    #[serde(default = "default_time_bins")]
    pub time_bins: usize,
}

/// Bins of normalised time by default (`--time-bins`).
pub const DEFAULT_TIME_BINS: usize = 20;

fn default_time_bins() -> usize {
    DEFAULT_TIME_BINS
}

impl Default for Protocol {
    fn default() -> Self {
        Protocol {
            seeds: 100,
            train_size: None,
            unit_scale: 100.0,
            standardise: false,
            removal: None,
            time_bins: DEFAULT_TIME_BINS,
        }
    }
}

/// Which values [`Removal`] takes away.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum RemovalMode {
    /// Every selected value independently (sensor noise, sparse dropouts).
    Values,
    /// Whole frames: every selected value of the frame (dropped packets).
    Frames,
    /// Runs of 10 frames of one side's selected columns (a hand occluded).
    Occlusions,
}

/// Removes a fraction of the selected raw values (NaN = missing) before the
/// features are computed, so a velocity is missing where either of its
/// positions is: from the training demonstrations both sides' columns, from
/// the test demonstrations the human's only (the robot's are the truth).
/// Seed `s`, demonstration `k` draws from `ChaCha8Rng::seed_from_u64(s · 2³² + k)`
/// (test demonstrations `k + 2³¹`), the same for every method.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Removal {
    /// Expected fraction of the values removed, in [0, 1).
    pub fraction: f64,
    /// Which values.
    pub mode: RemovalMode,
}

/// A seed's training and test features (`T × D` each) with values removed.
type SeedFeatures = (Vec<Vec<f64>>, Vec<Vec<f64>>);

/// Frames of an occlusion.
const OCCLUSION_FRAMES: usize = 10;

impl Removal {
    /// Checks `0 ≤ fraction < 1`.
    pub fn new(fraction: f64, mode: RemovalMode) -> Result<Self, String> {
        if !(0.0..1.0).contains(&fraction) {
            return Err(format!(
                "the fraction of values to remove must lie in [0, 1), got {fraction}"
            ));
        }
        Ok(Removal { fraction, mode })
    }

    /// A copy of `table` with values of the column groups `sides` removed.
    fn apply(&self, table: &Table, sides: &[&[usize]], seed: u64) -> Table {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut out = table.clone();
        let width = table.columns.len();
        let f = self.fraction;
        match self.mode {
            RemovalMode::Values => {
                for row in out.data.chunks_exact_mut(width) {
                    for &c in sides.iter().flat_map(|s| s.iter()) {
                        if rng.random::<f64>() < f {
                            row[c] = f64::NAN;
                        }
                    }
                }
            }
            RemovalMode::Frames => {
                for row in out.data.chunks_exact_mut(width) {
                    if rng.random::<f64>() < f {
                        for &c in sides.iter().flat_map(|s| s.iter()) {
                            row[c] = f64::NAN;
                        }
                    }
                }
            }
            RemovalMode::Occlusions => {
                // Runs start with the probability that occludes a fraction `f` of the frames.
                let n = OCCLUSION_FRAMES as f64;
                let start = f / (n * (1.0 - f) + f);
                for side in sides {
                    let mut left = 0;
                    for row in out.data.chunks_exact_mut(width) {
                        if left == 0 && rng.random::<f64>() < start {
                            left = OCCLUSION_FRAMES;
                        }
                        if left > 0 {
                            for &c in side.iter() {
                                row[c] = f64::NAN;
                            }
                            left -= 1;
                        }
                    }
                }
            }
        }
        out
    }

    /// The features of seed `seed`'s training demonstrations `idx` and of every
    /// test demonstration, with values removed.
    fn features(
        &self,
        action: &Action,
        spec: &FeatureSpec,
        seed: u64,
        idx: &[usize],
    ) -> Result<SeedFeatures, String> {
        let one = |t: &Table, human_only: bool, k: u64| -> Result<Vec<f64>, String> {
            let (_, h, r) = spec.layout(t).map_err(|e| e.to_string())?;
            let sides: Vec<&[usize]> = if human_only { vec![&h] } else { vec![&h, &r] };
            let blanked = self.apply(t, &sides, (seed << 32) + k);
            Ok(spec.features(&blanked).map_err(|e| e.to_string())?.1)
        };
        let train = idx
            .iter()
            .map(|&i| one(&action.train[i], false, i as u64))
            .collect::<Result<_, _>>()?;
        let test = action
            .test
            .iter()
            .enumerate()
            .map(|(k, t)| one(t, true, (1 << 31) + k as u64))
            .collect::<Result<_, _>>()?;
        Ok((train, test))
    }
}

/// One row of the results table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Row {
    /// Action (data set folder).
    pub action: String,
    /// Method label.
    pub method: String,
    /// Mean over seeds of the MSE (unit²); NaN (`null` in JSON) when every seed failed.
    #[serde(deserialize_with = "nan_if_null")]
    pub mse_mean: f64,
    /// Population std over seeds of the MSE.
    #[serde(deserialize_with = "nan_if_null")]
    pub mse_std: f64,
    /// Mean over seeds of √MSE (unit).
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_mean: f64,
    /// Population std over seeds of √MSE.
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_std: f64,
    /// Seeds that succeeded.
    pub seeds: usize,
    /// Seeds whose fit failed, with the first error.
    pub failures: Vec<(u64, String)>,
    /// MSE of every seed, in seed order (`None` where the fit failed).
    pub per_seed_mse: Vec<Option<f64>>,
    /// Mean training time per seed, seconds.
    pub fit_seconds: f64,
    /// Population std over seeds of the training time, seconds.
    #[serde(default)]
    pub fit_seconds_std: f64,
    /// Mean over seeds of the fraction of scored frames whose true robot
    /// position lies in the predicted 95 % region (χ² ellipsoid), in [0, 1].
    /// Undefined (NaN, `null` in JSON) when no seed's could be scored.
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub coverage_mean: f64,
    /// Population std over seeds of the coverage.
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub coverage_std: f64,
    /// Mean over seeds of the mean negative log predictive density per frame
    /// (nats, robot position in the reported unit).
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub nlpd_mean: f64,
    /// Population std over seeds of the NLPD.
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub nlpd_std: f64,
    /// Every seed's coverage of the 95 % region, in seed order (`None` where
    /// the fit failed or the predictive covariance could not be scored).
    #[serde(default)]
    pub per_seed_coverage: Vec<Option<f64>>,
    /// Every seed's NLPD, in seed order (`None` as for the coverage).
    #[serde(default)]
    pub per_seed_nlpd: Vec<Option<f64>>,
    /// Every seed's calibration factor of the predictive covariance (`auto`:
    /// [`phasekit_tsc::FitSummary::covariance_scale`]), in seed order; empty
    /// when no seed's fit calibrated.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub per_seed_covariance_scale: Vec<Option<f64>>,
    /// Mean prediction time per test frame, microseconds (batch path).
    pub predict_us_per_frame: f64,
    /// Total states of the predicting model (first successful seed).
    pub states: usize,
    /// What a choosing method (`auto`, the `-cv` presets, `states=auto`) chose
    /// on every seed, in seed order (`None` where the fit failed or chose nothing);
    /// empty when it chose nothing on any seed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub per_seed_chosen: Vec<Option<String>>,
    /// The error over normalised time, aggregated over seeds: one entry per bin
    /// ([`TimeBins`], [`TimeBinSummary`]). Not serialised with the row: `evaluate`
    /// writes it as its own table (`PREFIX_error_by_time.csv`, the JSON's `error_by_time`).
    #[serde(skip)]
    pub error_by_time: Vec<TimeBinSummary>,
    /// Every seed's binned error, in seed order (`None` where the fit failed);
    /// not serialised (the aggregate is [`Row::error_by_time`]).
    #[serde(skip)]
    pub per_seed_time_bins: Vec<Option<TimeBins>>,
    /// The same scores per test demonstration, in the order of the test files
    /// ([`TestDemonstrationSummary`]); empty in files written before it existed
    /// and for the constant-mean baseline.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub by_test_demonstration: Vec<TestDemonstrationSummary>,
    /// How many distinct training subsets the seeds drew (a seed is a subset,
    /// and `C(n, size)` bounds them: seeds beyond it repeat subsets); 0 for
    /// the constant-mean baseline (it trains on every demonstration) and in
    /// files written before it existed.
    #[serde(default)]
    pub training_subsets: usize,
}

/// One test demonstration's scores over the seeds: its MSE, the coverage of
/// the 95 % region and the NLPD on its frames alone.
///
/// The test demonstrations are the same on every seed (only the training
/// subset changes), so an action's coverage is the frame-weighted mean of
/// two or three of these: one demonstration unlike the training ones moves
/// it by points, which this shows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TestDemonstrationSummary {
    /// The test file's name.
    pub name: String,
    /// Scored frames on one seed (the first that scored it; the same on
    /// every seed unless `--missing` removes values); 0 when no seed did.
    pub frames: usize,
    /// Seeds whose fit succeeded and scored at least one of its frames (its
    /// MSE's mean is over these; coverage and NLPD over those of them whose
    /// calibration could be scored, as the row's).
    #[serde(default)]
    pub seeds: usize,
    /// Mean over seeds of its MSE (unit²).
    #[serde(deserialize_with = "nan_if_null")]
    pub mse_mean: f64,
    /// Population sd over seeds of its MSE.
    #[serde(deserialize_with = "nan_if_null")]
    pub mse_std: f64,
    /// Mean over the seeds whose calibration could be scored of the fraction
    /// of its frames inside the predicted 95 % region, in [0, 1].
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub coverage_mean: f64,
    /// Population sd over those seeds of the coverage.
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub coverage_std: f64,
    /// Mean over those seeds of its mean NLPD per frame (nats).
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub nlpd_mean: f64,
}

fn nan() -> f64 {
    f64::NAN
}

/// Reads a number written from an undefined (NaN) value, which JSON writes
/// as `null`, back as NaN, so that a report reads back what it wrote.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The probability of the predicted region whose coverage is reported (the
/// level `auto` calibrates to).
pub use phasekit_gmr::COVERAGE_LEVEL;

/// The bin of normalised time of frame `t` of a demonstration of `frames` frames,
/// among `bins` equal bins: `τ = t / (T − 1)` (`τ = 0` when `T = 1`) falls in bin
/// `i = ⌊τ B⌋` of `[i/B, (i+1)/B)`, the last bin closed (`τ = 1` is in bin `B − 1`).
///
/// Computed in integers, `⌊t B / (T − 1)⌋`, so that a frame on a bin edge
/// (`τ B` a whole number) is never put one bin low by rounding.
///
/// # Panics
///
/// When `bins` is 0 or `t ≥ frames` (programmer errors: [`Protocol::time_bins`]
/// is checked before any seed runs).
pub fn time_bin(t: usize, frames: usize, bins: usize) -> usize {
    assert!(bins >= 1 && t < frames, "time_bin({t}, {frames}, {bins})");
    if frames == 1 {
        return 0;
    }
    let i = (t as u128 * bins as u128) / (frames as u128 - 1);
    (i as usize).min(bins - 1)
}

/// One seed's prediction error binned by normalised time ([`time_bin`]): per bin,
/// the scored frames, the sum of their squared errors (unit², the per-frame term
/// of the MSE) and how many were covered by the 95 % region.
///
/// A decomposition of the seed's MSE: `Σ_b squared_error[b] / Σ_b frames[b]` is
/// the MSE (to rounding), i.e. the frame-weighted mean of the bins' MSE.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeBins {
    /// Scored frames per bin.
    pub frames: Vec<usize>,
    /// Sum over the bin's scored frames of the squared error, unit².
    pub squared_error: Vec<f64>,
    /// Covered frames per bin; `None` when the seed's calibration is undefined.
    pub covered: Option<Vec<usize>>,
}

impl TimeBins {
    /// `bins` empty bins.
    pub fn new(bins: usize) -> Self {
        TimeBins {
            frames: vec![0; bins],
            squared_error: vec![0.0; bins],
            covered: Some(vec![0; bins]),
        }
    }

    /// Number of bins.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether there is no bin.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// MSE of bin `b`, `squared_error[b] / frames[b]` (unit²); NaN for a bin without frames.
    pub fn mse(&self, b: usize) -> f64 {
        if self.frames[b] == 0 {
            f64::NAN
        } else {
            self.squared_error[b] / self.frames[b] as f64
        }
    }

    /// Coverage of bin `b`, in [0, 1]; NaN for a bin without frames or an undefined calibration.
    pub fn coverage(&self, b: usize) -> f64 {
        match &self.covered {
            Some(c) if self.frames[b] > 0 => c[b] as f64 / self.frames[b] as f64,
            _ => f64::NAN,
        }
    }
}

/// One bin of normalised time over the seeds of an action and method.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TimeBinSummary {
    /// Bin index, from 0.
    pub bin: usize,
    /// Start of the bin in normalised time, `bin / B`.
    pub time_from: f64,
    /// End of the bin, `(bin + 1) / B` (excluded but for the last bin).
    pub time_to: f64,
    /// Scored frames in the bin, summed over the seeds.
    pub frames: usize,
    /// Mean over seeds of the bin's MSE (unit²); NaN where no seed has a frame in the bin.
    pub mse_mean: f64,
    /// Population standard deviation over seeds of the bin's MSE.
    pub mse_sd: f64,
    /// 5th percentile over seeds of the bin's MSE ([`percentile`]).
    pub mse_p05: f64,
    /// 95th percentile over seeds of the bin's MSE.
    pub mse_p95: f64,
    /// Mean over the seeds whose calibration is defined of the bin's coverage, in [0, 1].
    pub coverage_mean: f64,
}

/// The `q`-quantile (`q ∈ [0, 1]`) of `v` by linear interpolation between order
/// statistics (NumPy's default, Hyndman & Fan type 7): with `x` sorted and
/// `h = (n − 1) q`, `x[⌊h⌋] + (h − ⌊h⌋)(x[⌊h⌋ + 1] − x[⌊h⌋])`. NaN for no value.
pub fn percentile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut x = v.to_vec();
    x.sort_by(f64::total_cmp);
    let h = (x.len() - 1) as f64 * q;
    let lo = h.floor() as usize;
    match x.get(lo + 1) {
        Some(&next) => x[lo] + (h - lo as f64) * (next - x[lo]),
        None => x[lo],
    }
}

/// The per-bin summary over seeds of `seeds` (the successful ones), `bins` bins:
/// per bin, mean, population sd and 5th/95th percentiles of the seeds' bin MSE
/// (seeds without a frame in the bin left out), mean coverage over the seeds
/// whose calibration is defined, total frames.
pub fn summarise_time_bins(seeds: &[&TimeBins], bins: usize) -> Vec<TimeBinSummary> {
    (0..bins)
        .map(|b| {
            let mses: Vec<f64> = seeds
                .iter()
                .map(|s| s.mse(b))
                .filter(|v| v.is_finite())
                .collect();
            let coverages: Vec<f64> = seeds
                .iter()
                .map(|s| s.coverage(b))
                .filter(|v| v.is_finite())
                .collect();
            let (mse_mean, mse_sd) = mean_std(&mses);
            TimeBinSummary {
                bin: b,
                time_from: b as f64 / bins as f64,
                time_to: (b + 1) as f64 / bins as f64,
                frames: seeds.iter().map(|s| s.frames[b]).sum(),
                mse_mean,
                mse_sd,
                mse_p05: percentile(&mses, 0.05),
                mse_p95: percentile(&mses, 0.95),
                coverage_mean: mean_std(&coverages).0,
            }
        })
        .collect()
}

/// Features of every demonstration of an action, and the layout.
pub struct Prepared {
    /// Layout of the features.
    pub layout: Layout,
    /// Training demonstrations, `T × D` each.
    pub train: Vec<Vec<f64>>,
    /// Test demonstrations.
    pub test: Vec<Vec<f64>>,
    /// The test files' names, in the order of `test`.
    pub test_names: Vec<String>,
}

/// Builds the features of an action's demonstrations.
pub fn prepare(action: &Action, spec: &FeatureSpec) -> Result<Prepared, String> {
    let mut layout = None;
    let mut feats = |tables: &[crate::data::Table]| -> Result<Vec<Vec<f64>>, String> {
        tables
            .iter()
            .map(|t| {
                let (l, f) = spec.features(t).map_err(|e| e.to_string())?;
                layout = Some(l);
                Ok(f)
            })
            .collect()
    };
    let train = feats(&action.train)?;
    let test = feats(&action.test)?;
    let layout = layout.ok_or_else(|| format!("action {} has no demonstration", action.name))?;
    let test_names = action
        .test
        .iter()
        .map(|t| {
            t.path.file_name().map_or_else(
                || t.path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            )
        })
        .collect();
    Ok(Prepared {
        layout,
        train,
        test,
        test_names,
    })
}

/// Mean and population standard deviation.
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

/// Training subset of seed `seed`: `size` of `n` indices, sorted; all when `size ≥ n`.
pub fn subset(seed: u64, n: usize, size: usize) -> Vec<usize> {
    if size >= n {
        return (0..n).collect();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut idx = rand::seq::index::sample(&mut rng, n, size).into_vec();
    idx.sort_unstable();
    idx
}

/// How many distinct training subsets seeds `0 .. seeds` draw ([`subset`]).
pub fn distinct_subsets(seeds: u64, n: usize, size: usize) -> usize {
    let mut all: Vec<Vec<usize>> = (0..seeds).map(|s| subset(s, n, size)).collect();
    all.sort_unstable();
    all.dedup();
    all.len()
}

/// Per test demonstration, its scores over the seeds that succeeded (`ok`):
/// MSE over all of them, coverage and NLPD over those whose calibration could
/// be scored (as the row's).
fn summarise_test_demonstrations(
    names: &[String],
    ok: &[&SeedResult],
) -> Vec<TestDemonstrationSummary> {
    names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            // A demonstration without a scored frame has nothing to average.
            let seeds = ok.iter().filter(|r| r.by_demonstration[k].frames > 0);
            let sums: Vec<DemonstrationSums> =
                seeds.clone().map(|r| r.by_demonstration[k]).collect();
            let scored: Vec<DemonstrationSums> = seeds
                .clone()
                .filter(|r| r.coverage.is_finite())
                .map(|r| r.by_demonstration[k])
                .collect();
            // The row's NLPD is over the seeds whose NLPD is finite.
            let with_nlpd: Vec<DemonstrationSums> = seeds
                .filter(|r| r.nlpd.is_finite())
                .map(|r| r.by_demonstration[k])
                .collect();
            let (mse_mean, mse_std) =
                mean_std(&sums.iter().map(DemonstrationSums::mse).collect::<Vec<_>>());
            let (coverage_mean, coverage_std) = mean_std(
                &scored
                    .iter()
                    .map(|d| d.inside as f64 / d.frames as f64)
                    .collect::<Vec<_>>(),
            );
            let nlpd_mean = mean_std(
                &with_nlpd
                    .iter()
                    .map(|d| d.nlpd / d.frames as f64)
                    .collect::<Vec<_>>(),
            )
            .0;
            TestDemonstrationSummary {
                name: name.clone(),
                frames: sums.first().map_or(0, |d| d.frames),
                seeds: sums.len(),
                mse_mean,
                mse_std,
                coverage_mean,
                coverage_std,
                nlpd_mean,
            }
        })
        .collect()
}

/// Outcome of one seed of one method.
struct SeedResult {
    mse: f64,
    coverage: f64,
    nlpd: f64,
    fit_seconds: f64,
    predict_seconds: f64,
    frames: usize,
    states: usize,
    chosen: Option<String>,
    /// The calibration factor of the predictive covariance, when the fit calibrated.
    covariance_scale: Option<f64>,
    time_bins: TimeBins,
    /// The same sums per test demonstration, in the order of the test files.
    by_demonstration: Vec<DemonstrationSums>,
}

/// One test demonstration's sums on one seed.
#[derive(Debug, Clone, Copy, Default)]
struct DemonstrationSums {
    squared_error: f64,
    frames: usize,
    inside: usize,
    nlpd: f64,
}

impl DemonstrationSums {
    fn mse(&self) -> f64 {
        self.squared_error / self.frames as f64
    }
}

/// One seed of one method; `removed` holds the seed's training and test
/// features with values removed ([`Removal`]), when the protocol asks for it.
fn run_seed(
    prep: &Prepared,
    method: &Method,
    train_idx: &[usize],
    protocol: &Protocol,
    removed: Option<&SeedFeatures>,
) -> Result<SeedResult, String> {
    let layout = &prep.layout;
    let d = layout.features.len();
    let chosen: Vec<&Vec<f64>> = match removed {
        Some((train, _)) => train.iter().collect(),
        None => train_idx.iter().map(|&i| &prep.train[i]).collect(),
    };
    let standardisation = protocol
        .standardise
        .then(|| crate::model_file::Standardisation::fit(&chosen, d));
    let (shift, scale) = match &standardisation {
        Some(s) => (s.mean.clone(), s.std.clone()),
        None => (vec![0.0; d], vec![1.0; d]),
    };
    let norm = |s: &Vec<f64>| -> Vec<f64> {
        s.chunks_exact(d)
            .flat_map(|f| {
                (0..d)
                    .map(|k| (f[k] - shift[k]) / scale[k])
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let train: Vec<Vec<f64>> = chosen.iter().map(|s| norm(s)).collect();
    let data = SequenceSet::new(&train, d).map_err(|e| e.to_string())?;
    let roles = layout.roles().map_err(|e| e.to_string())?;
    // On z-scores, a cross-validated choice still judges the error in the
    // file's units (the choice made without `--standardise`).
    let roles = match &standardisation {
        Some(s) => s.error_units_of(roles).map_err(|e| e.message)?,
        None => roles,
    };
    let clock = Instant::now();
    let (model, fit_summary) = method
        .fit(&data, &roles)
        .map_err(|e| crate::error::CliError::from(e).message)?;
    let fit_seconds = clock.elapsed().as_secs_f64();
    // A calibrated method (`auto`) multiplies its predicted covariances by the
    // factor fitted on its training folds.
    let predictor = model
        .predictor(&roles)
        .and_then(|p| p.with_calibration(&fit_summary))
        .map_err(|e| e.to_string())?;
    let o = layout.robot.len();
    let (mut se, mut frames, mut predict_seconds) = (0.0, 0usize, 0.0);
    let p = layout.robot_positions.len();
    let limit = phasekit_gmr::chi_squared_quantile(COVERAGE_LEVEL, p).map_err(|e| e.to_string())?;
    let jacobian: f64 = layout
        .robot_positions
        .iter()
        .map(|&j| (scale[layout.robot[j]] * protocol.unit_scale).ln())
        .sum();
    let (mut residual, mut block, mut scratch) =
        (vec![0.0; p], vec![0.0; p * p], vec![0.0; p * (p + 1)]);
    let (mut inside, mut nlpd) = (0usize, 0.0);
    // The same frames' terms binned by normalised time (`--time-bins`).
    let mut by_time = TimeBins::new(protocol.time_bins);
    // Calibration is scored on a best-effort basis: a predictive covariance that
    // cannot be scored (not positive definite, e.g. with reg = 0) leaves this
    // seed's coverage and NLPD undefined (NaN, left out of their means) but
    // never costs the seed its MSE.
    let mut calibration_error: Option<String> = None;
    let mut by_demonstration = vec![DemonstrationSums::default(); prep.test.len()];
    for (k, test) in prep.test.iter().enumerate() {
        let normed = norm(removed.map_or(test, |(_, t)| &t[k]));
        let human =
            phasekit_tsc::human_frames(Frames::new(&normed, d).map_err(|e| e.to_string())?, &roles)
                .map_err(|e| e.to_string())?;
        let input = Frames::new(&human, roles.human().len()).map_err(|e| e.to_string())?;
        // The timed prediction is the mean only (what a controller asks for every
        // frame); the covariance for the calibration columns comes from a second,
        // untimed pass (its mean is the same to the bit).
        let clock = Instant::now();
        let pred = predictor.predict(input, false).map_err(|e| e.to_string())?;
        predict_seconds += clock.elapsed().as_secs_f64();
        let with_covariance = match predictor.predict(input, true) {
            Ok(p) if p.covariance.is_some() => Some(p),
            Ok(_) => {
                calibration_error.get_or_insert("the predictor returned no covariance".into());
                None
            }
            Err(e) => {
                calibration_error.get_or_insert(e.to_string());
                None
            }
        };
        let cov = with_covariance
            .as_ref()
            .and_then(|p| p.covariance.as_deref());
        let length = test.len() / d;
        for (t, f) in test.chunks_exact(d).enumerate() {
            // A frame whose true robot position is not fully observed cannot be scored.
            if layout
                .robot_positions
                .iter()
                .any(|&j| f[layout.robot[j]].is_nan())
            {
                continue;
            }
            // Beside the MSE's sum, not instead of it (its order of additions stays
            // as it was): the frame's squared error, the same terms, in its time bin.
            let bin = time_bin(t, length, by_time.len());
            by_time.squared_error[bin] += layout
                .robot_positions
                .iter()
                .map(|&j| {
                    let c = layout.robot[j];
                    let predicted = pred.mean[t * o + j] * scale[c] + shift[c];
                    ((predicted - f[c]) * protocol.unit_scale).powi(2)
                })
                .sum::<f64>();
            by_time.frames[bin] += 1;
            for &j in &layout.robot_positions {
                let c = layout.robot[j];
                let predicted = pred.mean[t * o + j] * scale[c] + shift[c];
                let squared = ((predicted - f[c]) * protocol.unit_scale).powi(2);
                se += squared;
                by_demonstration[k].squared_error += squared;
            }
            by_demonstration[k].frames += 1;
            // Calibration in the model's (standardised) space, where the covariance
            // lives: Mahalanobis² does not depend on the units; the log density
            // is moved to the reported unit by the Jacobian Σ_j log(scale_j · unit_scale).
            frames += 1;
            let Some(cov) = cov.filter(|_| calibration_error.is_none()) else {
                continue;
            };
            for (a, &j) in layout.robot_positions.iter().enumerate() {
                let c = layout.robot[j];
                residual[a] = (f[c] - shift[c]) / scale[c] - pred.mean[t * o + j];
            }
            phasekit_gmr::covariance_block(
                &cov[t * o * o..(t + 1) * o * o],
                o,
                &layout.robot_positions,
                &mut block,
            );
            match phasekit_gmr::score_gaussian(&residual, &block, &mut scratch) {
                Ok(score) => {
                    inside += usize::from(score.mahalanobis2 <= limit);
                    by_demonstration[k].inside += usize::from(score.mahalanobis2 <= limit);
                    by_demonstration[k].nlpd -= score.log_density - jacobian;
                    if let Some(c) = by_time.covered.as_mut() {
                        c[bin] += usize::from(score.mahalanobis2 <= limit);
                    }
                    nlpd -= score.log_density - jacobian;
                }
                Err(e) => {
                    calibration_error = Some(format!("test demonstration {k}, frame {t}: {e}"));
                }
            }
        }
    }
    if frames == 0 {
        return Err(
            "no test frame has the robot's position fully observed: nothing to score".into(),
        );
    }
    let mse = se / frames as f64;
    if !mse.is_finite() {
        // An overflow must not pass as a result (nor print as a blank): it is a failure.
        return Err(format!(
            "the MSE is not finite ({mse}): the squared errors overflow at unit scale {} \
             (use a smaller --unit-scale), or a prediction is not finite",
            protocol.unit_scale
        ));
    }
    let (coverage, nlpd) = match calibration_error {
        None => (inside as f64 / frames as f64, nlpd / frames as f64),
        Some(_) => (f64::NAN, f64::NAN),
    };
    if calibration_error.is_some() {
        by_time.covered = None;
    }
    Ok(SeedResult {
        mse,
        coverage,
        nlpd,
        fit_seconds,
        predict_seconds,
        frames,
        states: model.n_states(),
        covariance_scale: fit_summary.covariance_calibration.as_ref().map(|c| c.scale),
        chosen: fit_summary.chosen,
        time_bins: by_time,
        by_demonstration,
    })
}

/// Evaluates `methods` on one action; `progress` is called after every (seed, method).
pub fn evaluate_action(
    action: &Action,
    spec: &FeatureSpec,
    methods: &[NamedMethod],
    protocol: &Protocol,
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<Row>, String> {
    let prep = prepare(action, spec)?;
    if prep.test.is_empty() {
        return Err(format!(
            "action {} has no test_* demonstration to predict",
            action.name
        ));
    }
    if protocol.time_bins == 0 {
        return Err("the number of time bins must be at least 1, got 0".into());
    }
    let n = prep.train.len();
    let size = protocol.train_size.unwrap_or(n.saturating_sub(2)).min(n);
    if size == 0 {
        return Err(format!(
            "action {}: no training demonstration left for a subset of size {size}",
            action.name
        ));
    }
    let seeds = if size >= n { 1 } else { protocol.seeds.max(1) };
    let training_subsets = distinct_subsets(seeds as u64, n, size);
    let results: Vec<Vec<Result<SeedResult, String>>> = (0..seeds as u64)
        .into_par_iter()
        .map(|seed| {
            let idx = subset(seed, n, size);
            let removed = protocol
                .removal
                .map(|r| r.features(action, spec, seed, &idx))
                .transpose();
            methods
                .iter()
                .map(|m| {
                    let r = removed
                        .as_ref()
                        .map_err(Clone::clone)
                        .and_then(|rm| run_seed(&prep, &m.method, &idx, protocol, rm.as_ref()));
                    progress();
                    r
                })
                .collect()
        })
        .collect();
    Ok(methods
        .iter()
        .enumerate()
        .map(|(j, m)| {
            let per_seed: Vec<&Result<SeedResult, String>> =
                results.iter().map(|r| &r[j]).collect();
            let ok: Vec<&SeedResult> = per_seed.iter().filter_map(|r| r.as_ref().ok()).collect();
            let mses: Vec<f64> = ok.iter().map(|r| r.mse).collect();
            let rmses: Vec<f64> = mses.iter().map(|v| v.sqrt()).collect();
            let (mse_mean, mse_std) = mean_std(&mses);
            let (rmse_mean, rmse_std) = mean_std(&rmses);
            let stat =
                |f: fn(&SeedResult) -> f64| mean_std(&ok.iter().map(|r| f(r)).collect::<Vec<_>>());
            // Over the seeds whose calibration could be scored (see `run_seed`).
            let scored = |f: fn(&SeedResult) -> f64| {
                mean_std(
                    &ok.iter()
                        .map(|r| f(r))
                        .filter(|v| v.is_finite())
                        .collect::<Vec<_>>(),
                )
            };
            let (coverage_mean, coverage_std) = scored(|r| r.coverage);
            let (nlpd_mean, nlpd_std) = scored(|r| r.nlpd);
            let fit_seconds_std = if ok.is_empty() {
                0.0
            } else {
                stat(|r| r.fit_seconds).1
            };
            let frames: usize = ok.iter().map(|r| r.frames).sum();
            Row {
                action: action.name.clone(),
                method: m.label.clone(),
                mse_mean,
                mse_std,
                rmse_mean,
                rmse_std,
                seeds: ok.len(),
                failures: per_seed
                    .iter()
                    .enumerate()
                    .filter_map(|(s, r)| r.as_ref().err().map(|e| (s as u64, e.clone())))
                    .collect(),
                per_seed_mse: per_seed
                    .iter()
                    .map(|r| r.as_ref().ok().map(|x| x.mse))
                    .collect(),
                // Folds from +0.0: `Sum` of no f64 is −0.0, printed "-0.000".
                fit_seconds: ok.iter().fold(0.0, |a, r| a + r.fit_seconds) / ok.len().max(1) as f64,
                fit_seconds_std,
                coverage_mean,
                coverage_std,
                nlpd_mean,
                nlpd_std,
                predict_us_per_frame: 1e6 * ok.iter().fold(0.0, |a, r| a + r.predict_seconds)
                    / frames.max(1) as f64,
                states: ok.first().map_or(0, |r| r.states),
                per_seed_coverage: per_seed
                    .iter()
                    .map(|r| {
                        r.as_ref()
                            .ok()
                            .map(|x| x.coverage)
                            .filter(|v| v.is_finite())
                    })
                    .collect(),
                per_seed_nlpd: per_seed
                    .iter()
                    .map(|r| r.as_ref().ok().map(|x| x.nlpd).filter(|v| v.is_finite()))
                    .collect(),
                per_seed_covariance_scale: if ok.iter().any(|r| r.covariance_scale.is_some()) {
                    per_seed
                        .iter()
                        .map(|r| r.as_ref().ok().and_then(|x| x.covariance_scale))
                        .collect()
                } else {
                    Vec::new()
                },
                per_seed_chosen: if ok.iter().any(|r| r.chosen.is_some()) {
                    per_seed
                        .iter()
                        .map(|r| r.as_ref().ok().and_then(|x| x.chosen.clone()))
                        .collect()
                } else {
                    Vec::new()
                },
                error_by_time: summarise_time_bins(
                    &ok.iter().map(|r| &r.time_bins).collect::<Vec<_>>(),
                    protocol.time_bins,
                ),
                per_seed_time_bins: per_seed
                    .iter()
                    .map(|r| r.as_ref().ok().map(|x| x.time_bins.clone()))
                    .collect(),
                by_test_demonstration: summarise_test_demonstrations(&prep.test_names, &ok),
                training_subsets,
            }
        })
        .collect())
}

/// Paired comparison of `row` against `baseline` over the seeds both completed:
/// mean relative change of the MSE and fraction of seeds where `row` is lower.
pub fn paired(row: &Row, baseline: &Row) -> Option<(f64, f64, usize)> {
    let pairs: Vec<(f64, f64)> = row
        .per_seed_mse
        .iter()
        .zip(&baseline.per_seed_mse)
        .filter_map(|(a, b)| Some(((*a)?, (*b)?)))
        .collect();
    if pairs.is_empty() {
        return None;
    }
    let n = pairs.len() as f64;
    let change = pairs.iter().map(|(a, b)| (a - b) / b).sum::<f64>() / n;
    let won = pairs.iter().filter(|(a, b)| a < b).count() as f64 / n;
    Some((change, won, pairs.len()))
}

/// The constant-mean baseline: predict the mean robot position of the training
/// demonstrations at every frame (all training demonstrations).
pub fn constant_mean_mse(prep: &Prepared, unit_scale: f64) -> f64 {
    let layout = &prep.layout;
    let d = layout.features.len();
    let cols: Vec<usize> = layout
        .robot_positions
        .iter()
        .map(|&j| layout.robot[j])
        .collect();
    let mut mean = vec![0.0; cols.len()];
    let mut n = vec![0.0; cols.len()];
    for s in &prep.train {
        for f in s.chunks_exact(d) {
            for ((m, n), &c) in mean.iter_mut().zip(&mut n).zip(&cols) {
                if !f[c].is_nan() {
                    *m += f[c];
                    *n += 1.0;
                }
            }
        }
    }
    mean.iter_mut().zip(&n).for_each(|(m, n)| *m /= n);
    let (mut se, mut frames) = (0.0, 0.0);
    for s in &prep.test {
        for f in s.chunks_exact(d) {
            if cols.iter().any(|&c| f[c].is_nan()) {
                continue;
            }
            se += cols
                .iter()
                .zip(&mean)
                .map(|(&c, m)| ((f[c] - m) * unit_scale).powi(2))
                .sum::<f64>();
            frames += 1.0;
        }
    }
    se / frames
}
