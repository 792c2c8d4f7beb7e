//! `phasekit evaluate`: the paper's experiment.

use super::{column_hint, feature_spec, preset_options, setup_threads, split_methods};
use crate::bail;
use crate::cli::{EvaluateArgs, Format};
use crate::data::{self, Action, FeatureSpec};
use crate::error::{CliError, Result};
use crate::experiment::{
    constant_mean_mse, evaluate_action, paired, parse_method, prepare, NamedMethod, Protocol, Row,
    TestDemonstrationSummary, TimeBinSummary,
};
use crate::output::{self, csv_number};
use crate::units::{mean_pm, sig4, Unit};
use phasekit_tsc::PresetOptions;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Label of the constant baseline rows.
pub const BASELINE: &str = "constant-mean";

/// A row of the results with its paired comparison to the first method.
#[derive(Debug, Clone, Serialize)]
pub struct ResultRow {
    /// The row.
    #[serde(flatten)]
    pub row: Row,
    /// Whether this is the constant-mean-pose baseline.
    pub baseline: bool,
    /// Method compared with (the first one).
    pub reference: Option<String>,
    /// Mean over paired seeds of (MSE − MSE_ref) / MSE_ref.
    pub paired_change: Option<f64>,
    /// Fraction of paired seeds where this method's MSE is lower.
    pub paired_won: Option<f64>,
    /// Seeds in the comparison.
    pub paired_seeds: Option<usize>,
    /// Second method compared with (the second one given), if any.
    pub second_reference: Option<String>,
    /// Mean over paired seeds of (MSE − MSE_second) / MSE_second.
    pub paired_change_second: Option<f64>,
    /// Fraction of paired seeds where this method's MSE is lower than the second method's.
    pub paired_won_second: Option<f64>,
}

/// How the experiment was run, for the JSON output.
#[derive(Debug, Clone, Serialize)]
pub struct ProtocolReport {
    /// The data folder.
    pub data: PathBuf,
    /// Actions evaluated.
    pub actions: Vec<String>,
    /// Methods, as given.
    pub methods: Vec<String>,
    /// Seeds, training subset size, unit scale, standardisation.
    #[serde(flatten)]
    pub protocol: Protocol,
    /// Name of the unit of the MSE (squared) and RMSE: data units × `unit_scale`.
    pub unit: String,
    /// Columns and velocities.
    pub columns: FeatureSpec,
    /// Defaults of every method's settings.
    pub options: PresetOptions,
}

/// The whole result, `--format json`.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// How it was run.
    pub protocol: ProtocolReport,
    /// What is measured.
    pub metric: String,
    /// One row per action and method, and a baseline row per action.
    pub results: Vec<ResultRow>,
    /// The error over normalised time, one entry per action × method × bin (the
    /// rows of `PREFIX_error_by_time.csv`, MSE in the unit²); only when `-o` writes files.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error_by_time: Option<Vec<ErrorByTimeRow>>,
}

/// One bin of the error over normalised time of an action and method.
#[derive(Debug, Clone, Serialize)]
pub struct ErrorByTimeRow {
    /// Action.
    pub action: String,
    /// Method label.
    pub method: String,
    /// The bin over seeds.
    #[serde(flatten)]
    pub bin: TimeBinSummary,
}

/// The error-over-time rows of `results` (every method, not the baseline), in
/// the order of the results table, bins in order.
pub fn error_by_time_rows(results: &[ResultRow]) -> Vec<ErrorByTimeRow> {
    results
        .iter()
        .filter(|x| !x.baseline)
        .flat_map(|x| {
            x.row.error_by_time.iter().map(|b| ErrorByTimeRow {
                action: x.row.action.clone(),
                method: x.row.method.clone(),
                bin: b.clone(),
            })
        })
        .collect()
}

/// The unit² as a column-name suffix: `cm2` for `cm`; a name that is not one
/// word becomes `data_units_squared`.
fn squared_suffix(unit: &Unit) -> String {
    if !unit.name.is_empty() && unit.name.chars().all(char::is_alphanumeric) {
        format!("{}2", unit.name)
    } else {
        let mut s = String::new();
        for c in unit.name.chars() {
            if c.is_alphanumeric() {
                s.push(c);
            } else if !s.ends_with('_') && !s.is_empty() {
                s.push('_');
            }
        }
        format!("{}_squared", s.trim_end_matches('_'))
    }
}

/// `PREFIX_error_by_time.csv`: one line per action × method × bin of normalised
/// time, `time_from`/`time_to` the bin's edges (`τ = t / (T − 1)`), `frames` the
/// scored frames summed over seeds, the bin MSE's mean, population sd and 5th/95th
/// percentiles over seeds in the unit² the header names (`mse_mean_cm2`), and
/// `coverage_mean` (fraction in [0, 1] of the 95 % region). Empty where there is
/// no value (a bin without frames; coverage undefined on every seed).
pub fn error_by_time_csv(r: &Report) -> String {
    let u = squared_suffix(&unit_of(&r.protocol));
    let mut s = format!(
        "action,method,bin,time_from,time_to,frames,mse_mean_{u},mse_sd_{u},mse_p05_{u},mse_p95_{u},coverage_mean\n"
    );
    for x in error_by_time_rows(&r.results) {
        let b = &x.bin;
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{}\n",
            output::csv_field(&x.action),
            output::csv_field(&x.method),
            b.bin,
            b.time_from,
            b.time_to,
            b.frames,
            csv_number(b.mse_mean),
            csv_number(b.mse_sd),
            csv_number(b.mse_p05),
            csv_number(b.mse_p95),
            csv_number(b.coverage_mean),
        ));
    }
    s
}

/// The files of the error over time beside `PREFIX.md` (`md`): the CSV and one SVG
/// per action of the report, with their contents.
pub fn error_by_time_files(r: &Report, md: &Path) -> Result<Vec<(PathBuf, String)>> {
    let beside = |suffix: &str| beside_markdown(md, suffix);
    let unit = unit_of(&r.protocol);
    let mut files = vec![(beside("_error_by_time.csv"), error_by_time_csv(r))];
    for action in &r.protocol.actions {
        let rows: Vec<&Row> = r
            .results
            .iter()
            .filter(|x| !x.baseline && &x.row.action == action)
            .map(|x| &x.row)
            .collect();
        let seeds = rows.iter().map(|r| r.per_seed_mse.len()).max().unwrap_or(0);
        let svg = crate::plot::error_by_time_svg(action, &rows, seeds, &unit)?;
        files.push((beside(&format!("_error_by_time_{action}.svg")), svg));
    }
    Ok(files)
}

/// The file `PREFIX{suffix}` beside `PREFIX.md` (`md`).
fn beside_markdown(md: &Path, suffix: &str) -> PathBuf {
    let text = md.as_os_str().to_string_lossy();
    let prefix = text.strip_suffix(".md").unwrap_or(&text);
    PathBuf::from(format!("{prefix}{suffix}"))
}

/// The Markdown line that names the error-over-time files (`files` as
/// [`error_by_time_files`] gives them).
fn error_by_time_line(r: &Report, files: &[(PathBuf, String)]) -> String {
    let name = |p: &Path| {
        p.file_name().map_or_else(
            || p.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    let names: Vec<String> = files.iter().map(|(p, _)| name(p)).collect();
    format!(
        "Error against normalised time ({} bins of τ = t / (T − 1); per bin the MSE in {}, mean, sd and 5–95 % over seeds, and the coverage): {} (table); {} (plots).\n",
        r.protocol.protocol.time_bins,
        unit_of(&r.protocol).squared(),
        names.first().map_or("", String::as_str),
        names.get(1..).unwrap_or(&[]).join(", ")
    )
}

/// The unit of the metric.
pub fn unit_of(p: &ProtocolReport) -> Unit {
    Unit {
        name: p.unit.clone(),
        scale: p.protocol.unit_scale,
    }
}

fn metric_text(spec: &FeatureSpec, p: &Protocol, unit: &Unit) -> String {
    format!(
        "MSE: per frame, squared Euclidean error of the robot's position columns ({}; velocities excluded), \
         scaled by unit_scale² = {}², averaged over all frames of all test demonstrations of an action, in {}; \
         RMSE = √MSE per seed, in {}; mean ± population std over seeds, printed with at least four significant digits; \
         a seed whose MSE is not finite (an overflow) is a failure. \
         Seed s trains on a random subset ({} training demonstrations, drawn with ChaCha8 from seed s). \
         paired_change = mean over seeds of (MSE − MSE_reference) / MSE_reference; paired_won = fraction of seeds with a lower MSE; the same against the second method in the *_second fields. \
         constant-mean predicts the mean robot position of all training demonstrations at every frame (no uncertainty: no coverage, no NLPD). \
         coverage 95 %: fraction (printed in %) of the scored frames whose true robot position lies in the predicted 95 % region, \
         the χ² ellipsoid (y − μ)ᵀ Σ⁻¹ (y − μ) ≤ χ²_0.95(p) of the predictive mean μ and covariance Σ of the p position columns (7.815 for p = 3) \
         (a calibrated predictor covers 95 %; more means bands too wide, less too narrow). \
         NLPD: mean over the scored frames of −log N(y; μ, Σ), in nats, y in {} (a density per {}^p; lower is better). \
         fit: training time per seed, in seconds. Coverage, NLPD and fit time: mean ± population std over seeds.{}",
        spec.robot.join(", "),
        p.unit_scale,
        unit.squared(),
        unit.name,
        p.train_size.map_or("all but two".to_string(), |n| n.to_string()),
        unit.name,
        unit.name,
        p.removal.map_or(String::new(), |r| format!(
            " Robustness run: {:.0} % of the selected values removed at random ({}) from every seed's training \
             demonstrations and from the test demonstrations' human columns, before the velocities are computed; \
             the truth stays complete.",
            100.0 * r.fraction,
            match r.mode {
                crate::experiment::RemovalMode::Values => "each value independently",
                crate::experiment::RemovalMode::Frames => "whole frames",
                crate::experiment::RemovalMode::Occlusions => "runs of 10 frames of one side",
            }
        ))
    )
}

fn pm(m: f64, s: f64, seeds: usize) -> String {
    mean_pm(m, s, seeds > 1)
}

/// The Markdown table of a report.
pub fn markdown(r: &Report) -> String {
    let unit = unit_of(&r.protocol);
    let (u2, u) = (unit.squared(), &unit.name);
    let mut s = format!(
        "| action | method | states | MSE ({u2}) | RMSE ({u}) | seeds | failures | coverage 95 % (%) | NLPD (nats) | fit (s) | predict (µs/frame) | Δ MSE vs {0} | seeds won | Δ MSE vs {1} | seeds won |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        r.protocol.methods.first().map_or("first", |m| m.as_str()),
        r.protocol.methods.get(1).map_or("second", |m| m.as_str())
    );
    for x in &r.results {
        let row = &x.row;
        let (change, won) = match (x.paired_change, x.paired_won) {
            (Some(c), Some(w)) => (
                format!("{:+.1} %", 100.0 * c),
                format!("{:.0} %", 100.0 * w),
            ),
            _ => ("–".into(), "–".into()),
        };
        let (change2, won2) = match (x.paired_change_second, x.paired_won_second) {
            (Some(c), Some(w)) => (
                format!("{:+.1} %", 100.0 * c),
                format!("{:.0} %", 100.0 * w),
            ),
            _ => ("–".into(), "–".into()),
        };
        if x.baseline {
            s.push_str(&format!(
                "| {} | {} | – | {} | {} | – | – | – | – | – | – | – | – | – | – |\n",
                row.action,
                row.method,
                sig4(row.mse_mean),
                sig4(row.rmse_mean)
            ));
        } else {
            // A method that failed on every seed has no time and no state count to show.
            let (states, fit, predict) = if row.seeds == 0 {
                ("–".to_string(), "–".to_string(), "–".to_string())
            } else if row.seeds > 1 {
                (
                    row.states.to_string(),
                    format!("{:.3} ± {:.3}", row.fit_seconds, row.fit_seconds_std),
                    format!("{:.1}", row.predict_us_per_frame),
                )
            } else {
                (
                    row.states.to_string(),
                    format!("{:.3}", row.fit_seconds),
                    format!("{:.1}", row.predict_us_per_frame),
                )
            };
            let coverage = if row.coverage_mean.is_finite() {
                if row.seeds > 1 {
                    format!(
                        "{:.1} ± {:.1}",
                        100.0 * row.coverage_mean,
                        100.0 * row.coverage_std
                    )
                } else {
                    format!("{:.1}", 100.0 * row.coverage_mean)
                }
            } else {
                "–".to_string()
            };
            s.push_str(&format!(
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                row.action,
                row.method,
                states,
                pm(row.mse_mean, row.mse_std, row.seeds),
                pm(row.rmse_mean, row.rmse_std, row.seeds),
                row.seeds,
                row.failures.len(),
                coverage,
                pm(row.nlpd_mean, row.nlpd_std, row.seeds),
                fit,
                predict,
                change,
                won,
                change2,
                won2
            ));
        }
    }
    s
}

/// The Markdown document of a report: the table, then the metric's definition
/// (what `evaluate` prints and writes to PREFIX.md).
pub fn markdown_document(r: &Report) -> String {
    format!(
        "{}\n{}{}{}\n",
        markdown(r),
        choices(r),
        by_test_demonstration_markdown(r),
        r.metric
    )
}

/// The rows of the scores by test demonstration: (action, method, the
/// demonstration's summary), every method but the baseline, in the order of
/// the results table and of the test files.
pub fn by_test_demonstration_rows(
    results: &[ResultRow],
) -> Vec<(&str, &str, &TestDemonstrationSummary)> {
    results
        .iter()
        .filter(|x| !x.baseline)
        .flat_map(|x| {
            x.row
                .by_test_demonstration
                .iter()
                .map(|d| (x.row.action.as_str(), x.row.method.as_str(), d))
        })
        .collect()
}

/// The scores per test demonstration as Markdown: how many distinct training
/// subsets the seeds drew per action, then one line per action × method ×
/// test file. Empty when no row has them.
fn by_test_demonstration_markdown(r: &Report) -> String {
    let rows = by_test_demonstration_rows(&r.results);
    if rows.is_empty() {
        return String::new();
    }
    let unit = unit_of(&r.protocol);
    let mut subsets: Vec<String> = Vec::new();
    for x in r
        .results
        .iter()
        .filter(|x| !x.baseline && x.row.training_subsets > 0)
    {
        let line = format!(
            "{}: {} in {} seeds",
            x.row.action,
            x.row.training_subsets,
            x.row.per_seed_mse.len()
        );
        if !subsets.contains(&line) {
            subsets.push(line);
        }
    }
    let dash = || "–".to_string();
    let mut s = format!(
        "By test demonstration. The test files are the same on every seed: a seed draws only the training subset (distinct training subsets: {}). Mean ± population sd over seeds; an action's mean MSE, coverage and NLPD are these means weighted by frames.\n\n| action | method | test demonstration | frames | seeds | MSE ({}) | coverage 95 % (%) | NLPD (nats) |\n|---|---|---|---:|---:|---:|---:|---:|\n",
        subsets.join(", "),
        unit.squared()
    );
    for (action, method, d) in rows {
        let mse = if d.mse_mean.is_finite() {
            pm(d.mse_mean, d.mse_std, d.seeds)
        } else {
            dash()
        };
        let coverage = match (d.coverage_mean.is_finite(), d.seeds > 1) {
            (false, _) => dash(),
            (true, true) => format!(
                "{:.1} ± {:.1}",
                100.0 * d.coverage_mean,
                100.0 * d.coverage_std
            ),
            (true, false) => format!("{:.1}", 100.0 * d.coverage_mean),
        };
        let nlpd = if d.nlpd_mean.is_finite() {
            format!("{:.3}", d.nlpd_mean)
        } else {
            dash()
        };
        s.push_str(&format!(
            "| {action} | {method} | {} | {} | {} | {mse} | {coverage} | {nlpd} |\n",
            d.name, d.frames, d.seeds
        ));
    }
    s.push('\n');
    s
}

/// `PREFIX_by_test_demonstration.csv`: the rows of
/// [`by_test_demonstration_rows`], the MSE's mean and population sd over seeds
/// in the unit² the header names, the coverage of the 95 % region (fraction
/// in [0, 1]) and the NLPD (nats); empty where undefined.
pub fn by_test_demonstration_csv(r: &Report) -> String {
    let u = squared_suffix(&unit_of(&r.protocol));
    let mut s = format!(
        "action,method,test_demonstration,frames,seeds,mse_mean_{u},mse_sd_{u},coverage_mean,coverage_sd,nlpd_mean\n"
    );
    for (action, method, d) in by_test_demonstration_rows(&r.results) {
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{}\n",
            output::csv_field(action),
            output::csv_field(method),
            output::csv_field(&d.name),
            d.frames,
            d.seeds,
            csv_number(d.mse_mean),
            csv_number(d.mse_std),
            csv_number(d.coverage_mean),
            csv_number(d.coverage_std),
            csv_number(d.nlpd_mean),
        ));
    }
    s
}

/// What the choosing methods chose, per action: every choice and on how many
/// seeds, most frequent first (the JSON has it per seed: `per_seed_chosen`).
fn choices(r: &Report) -> String {
    let mut s = String::new();
    for x in r
        .results
        .iter()
        .filter(|x| !x.row.per_seed_chosen.is_empty())
    {
        let mut counts: Vec<(&str, usize)> = Vec::new();
        for c in x.row.per_seed_chosen.iter().flatten() {
            match counts.iter_mut().find(|(l, _)| *l == c.as_str()) {
                Some((_, n)) => *n += 1,
                None => counts.push((c.as_str(), 1)),
            }
        }
        counts.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
        let list: Vec<String> = counts.iter().map(|(l, n)| format!("{l} ×{n}")).collect();
        s.push_str(&format!(
            "Chosen by {} on {} ({} seeds): {}.\n",
            x.row.method,
            x.row.action,
            x.row.seeds,
            list.join(", ")
        ));
    }
    if !s.is_empty() {
        s.push('\n');
    }
    s
}

/// The CSV of a report: one line per row, with both paired comparisons (against the
/// first method: `reference`, `paired_change`, `paired_won`, `paired_seeds`; against the
/// second: `second_reference`, `paired_change_second`, `paired_won_second`), then
/// the calibration: `coverage95_mean`/`_std` (fraction in [0, 1]), `nlpd_mean`/`_std`
/// (nats, `nlpd_unit` the unit the density is per), `fit_seconds_std`. Empty where
/// there is no value (the constant-mean baseline has no uncertainty).
pub fn csv(r: &Report) -> String {
    let mut s = String::from("action,method,states,mse_mean,mse_std,rmse_mean,rmse_std,seeds,failures,fit_seconds,predict_us_per_frame,paired_change,paired_won,baseline,reference,paired_seeds,second_reference,paired_change_second,paired_won_second,unit,coverage95_mean,coverage95_std,nlpd_mean,nlpd_std,nlpd_unit,fit_seconds_std\n");
    let unit = output::csv_field(&unit_of(&r.protocol).name);
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
    let name = |v: &Option<String>| v.as_deref().map_or(String::new(), output::csv_field);
    for x in &r.results {
        let row = &x.row;
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{unit},{},{},{},{},{unit},{}\n",
            output::csv_field(&row.action),
            output::csv_field(&row.method),
            row.states,
            row.mse_mean,
            row.mse_std,
            row.rmse_mean,
            row.rmse_std,
            row.seeds,
            row.failures.len(),
            row.fit_seconds,
            row.predict_us_per_frame,
            opt(x.paired_change),
            opt(x.paired_won),
            x.baseline,
            name(&x.reference),
            x.paired_seeds.map_or(String::new(), |n| n.to_string()),
            name(&x.second_reference),
            opt(x.paired_change_second),
            opt(x.paired_won_second),
            csv_number(row.coverage_mean),
            csv_number(row.coverage_std),
            csv_number(row.nlpd_mean),
            csv_number(row.nlpd_std),
            row.fit_seconds_std,
        ));
    }
    s
}

/// Where `-o PATH` writes: `PATH.md` and `PATH.json`; a folder (existing, or given with
/// a trailing `/`) gets `evaluate.md` and `evaluate.json`; a `.md`/`.json` extension is dropped.
pub fn output_files(o: &Path) -> Result<(PathBuf, PathBuf)> {
    let text = o.as_os_str().to_string_lossy();
    let folder = o.is_dir() || text.ends_with('/') || text.ends_with(std::path::MAIN_SEPARATOR);
    let prefix = if folder {
        o.join("evaluate")
    } else {
        match o.extension().and_then(|e| e.to_str()) {
            Some("md") | Some("json") => o.with_extension(""),
            _ => o.to_path_buf(),
        }
    };
    if prefix.file_name().is_none_or(|n| n.is_empty() || n == ".") {
        bail!("-o {}: not a usable file prefix", o.display());
    }
    let with_ext = |ext: &str| {
        let mut s = prefix.clone().into_os_string();
        s.push(ext);
        PathBuf::from(s)
    };
    Ok((with_ext(".md"), with_ext(".json")))
}

fn baseline_row(action: &str, mse: f64) -> Row {
    Row {
        action: action.to_string(),
        method: BASELINE.into(),
        mse_mean: mse,
        mse_std: 0.0,
        rmse_mean: mse.sqrt(),
        rmse_std: 0.0,
        seeds: 1,
        failures: Vec::new(),
        per_seed_mse: vec![Some(mse)],
        fit_seconds: 0.0,
        fit_seconds_std: 0.0,
        coverage_mean: f64::NAN,
        coverage_std: f64::NAN,
        nlpd_mean: f64::NAN,
        nlpd_std: f64::NAN,
        per_seed_coverage: Vec::new(),
        per_seed_nlpd: Vec::new(),
        per_seed_covariance_scale: Vec::new(),
        predict_us_per_frame: 0.0,
        states: 0,
        per_seed_chosen: Vec::new(),
        error_by_time: Vec::new(),
        per_seed_time_bins: Vec::new(),
        by_test_demonstration: Vec::new(),
        training_subsets: 0,
    }
}

/// Number of runs of an action under a protocol (as `evaluate_action` does them).
fn runs(action: &Action, p: &Protocol) -> usize {
    let n = action.train.len();
    let size = p.train_size.unwrap_or(n.saturating_sub(2)).min(n);
    if size >= n {
        1
    } else {
        p.seeds.max(1)
    }
}

/// Checks that an action has training demonstrations left for every seed's subset
/// (the protocol trains on all but two), with a message that says what to do.
fn check_training_count(action: &Action, p: &Protocol) -> Result<()> {
    let n = action.train.len();
    if p.train_size.is_none() && n <= 2 {
        bail!(
            "action {}: {n} training demonstration{} (train_* files): each seed trains on all but two of them, \
             which leaves none; add training demonstrations (at least 3), or give --train-size {n} to train on \
             all of them in one run",
            action.name,
            if n == 1 { "" } else { "s" }
        );
    }
    Ok(())
}

/// Runs the experiment and returns the report (progress bar on a terminal).
#[allow(clippy::too_many_arguments)]
pub fn evaluate(
    data_dir: &std::path::Path,
    actions: Vec<Action>,
    spec: &FeatureSpec,
    defaults: bool,
    methods: &[NamedMethod],
    options: &PresetOptions,
    protocol: &Protocol,
    unit: &Unit,
) -> Result<Report> {
    for action in &actions {
        check_training_count(action, protocol)?;
        for t in action.train.iter().chain(&action.test) {
            spec.features(t).map_err(|e| column_hint(e, defaults))?;
        }
        if action.test.is_empty() {
            bail!("{}: no test_* demonstration to predict", action.name);
        }
        let all: Vec<data::Table> = action.train.to_vec();
        // Bounded work, as in `fit`: the smallest training subset of a seed
        // must support the covariances of the method's states, and fit in memory.
        let d = match action.train.first() {
            Some(t) => spec
                .features(t)
                .map_err(|e| column_hint(e, defaults))?
                .0
                .features
                .len(),
            None => 0,
        };
        let mut rows: Vec<usize> = action.train.iter().map(data::Table::n_rows).collect();
        rows.sort_unstable();
        let size = protocol
            .train_size
            .unwrap_or(rows.len().saturating_sub(2))
            .min(rows.len());
        let frames: usize = rows[..size].iter().sum();
        for m in methods {
            super::check_lengths(&all, &m.method, &m.label)?;
            data::check_fit_size(d, frames, super::min_frames(&m.method).0)
                .map_err(|e| CliError::new(format!("action {}, {}: {e}", action.name, m.label)))?;
        }
    }
    let total: usize = actions
        .iter()
        .map(|a| runs(a, protocol) * methods.len())
        .sum();
    let bar = output::progress_bar(total as u64, "evaluating");
    let mut results = Vec::new();
    for action in &actions {
        bar.set_message(action.name.clone());
        let rows = evaluate_action(action, spec, methods, protocol, &|| bar.inc(1))
            .map_err(CliError::new)?;
        let reference = rows.first().cloned();
        let second = rows.get(1).cloned();
        for (i, row) in rows.into_iter().enumerate() {
            // A reference compared with itself has no comparison (not "0 % won").
            let cmp = reference
                .as_ref()
                .filter(|_| i != 0)
                .and_then(|b| paired(&row, b));
            let cmp2 = second
                .as_ref()
                .filter(|_| i != 1)
                .and_then(|b| paired(&row, b));
            results.push(ResultRow {
                second_reference: second.as_ref().map(|b| b.method.clone()),
                paired_change_second: cmp2.map(|c| c.0),
                paired_won_second: cmp2.map(|c| c.1),
                reference: reference.as_ref().map(|b| b.method.clone()),
                paired_change: cmp.map(|c| c.0),
                paired_won: cmp.map(|c| c.1),
                paired_seeds: cmp.map(|c| c.2),
                baseline: false,
                row,
            });
        }
        let prep = prepare(action, spec).map_err(CliError::new)?;
        results.push(ResultRow {
            row: baseline_row(&action.name, constant_mean_mse(&prep, protocol.unit_scale)),
            baseline: true,
            reference: None,
            paired_change: None,
            paired_won: None,
            paired_seeds: None,
            second_reference: None,
            paired_change_second: None,
            paired_won_second: None,
        });
    }
    bar.finish_and_clear();
    Ok(Report {
        protocol: ProtocolReport {
            data: data_dir.to_path_buf(),
            actions: actions.iter().map(|a| a.name.clone()).collect(),
            methods: methods.iter().map(|m| m.label.clone()).collect(),
            protocol: protocol.clone(),
            unit: unit.name.clone(),
            columns: spec.clone(),
            options: options.clone(),
        },
        metric: metric_text(spec, protocol, unit),
        results,
        error_by_time: None,
    })
}

/// Runs `phasekit evaluate`.
pub fn run(a: &EvaluateArgs) -> Result<()> {
    if a.task == super::recognise::Task::Recognition {
        return crate::recognition_report::run(a);
    }
    crate::recognition_report::check_prediction_task(a)?;
    setup_threads(a.model.threads)?;
    let options = preset_options(&a.model)?;
    let (spec, defaults) = feature_spec(&a.columns);
    if a.seeds == 0 {
        bail!("--seeds must be at least 1");
    }
    if let Some(x) = a.fail_above {
        if !(x.is_finite() && x > 0.0) {
            bail!("--fail-above must be a positive number, not {x}");
        }
    }
    let unit = a.unit.resolve()?;
    if a.train_size == Some(0) {
        bail!("--train-size must be at least 1");
    }
    if a.time_bins == 0 {
        bail!("--time-bins must be at least 1 (bins of normalised time for the error over time)");
    }
    let labels = split_methods(&a.methods);
    if labels.is_empty() {
        bail!("--methods: no method given");
    }
    let methods = labels
        .iter()
        .map(|m| parse_method(m, &options).map_err(|e| CliError::new(format!("--methods: {e}"))))
        .collect::<Result<Vec<_>>>()?;
    let outputs = a.output.as_deref().map(output_files).transpose()?;
    if let (Some(o), Some((md, _))) = (&a.output, &outputs) {
        // Checked before the (long) run. A prefix needs an existing folder; a folder
        // given as `DIR/` is created at the end if its nearest existing ancestor is a folder.
        let dir = md
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let folder_form = md.parent() == Some(o.as_path());
        let creatable = dir
            .ancestors()
            .skip(1)
            .find(|p| p.as_os_str().is_empty() || p.exists())
            .is_some_and(|p| p.as_os_str().is_empty() || p.is_dir());
        if !(dir.is_dir() || folder_form && creatable) {
            bail!(
                "-o {}: folder {} does not exist",
                o.display(),
                dir.display()
            );
        }
    }
    if !a.data.is_dir() {
        bail!("{}: evaluate needs a folder of action folders (or one action folder) with train_* and test_* files", a.data.display());
    }
    let actions = load_actions(&a.data, a.action.as_deref()).map_err(|e| match e {
        Loading::Data(e) => column_hint(e, defaults),
        Loading::Other(e) => e,
    })?;
    let removal = a
        .missing
        .map(|f| crate::experiment::Removal::new(f, a.missing_mode))
        .transpose()
        .map_err(|e| CliError::new(format!("--missing: {e}")))?;
    let protocol = Protocol {
        seeds: a.seeds,
        train_size: a.train_size,
        unit_scale: unit.scale,
        standardise: a.model.standardise,
        removal,
        time_bins: a.time_bins,
    };
    let mut report = evaluate(
        &a.data, actions, &spec, defaults, &methods, &options, &protocol, &unit,
    )?;
    let mut md = markdown_document(&report);
    // The error over time goes with the files (-o): the JSON's array, the CSV, the SVGs.
    let extra = match &outputs {
        Some((md_path, _)) => {
            report.error_by_time = Some(error_by_time_rows(&report.results));
            let mut files = error_by_time_files(&report, md_path)?;
            md.push_str(&error_by_time_line(&report, &files));
            if !by_test_demonstration_rows(&report.results).is_empty() {
                let path = beside_markdown(md_path, "_by_test_demonstration.csv");
                md.push_str(&format!(
                    "Scores by test demonstration (the \"By test demonstration\" table, to the last digit): {}.\n",
                    path.file_name().map_or_else(
                        || path.display().to_string(),
                        |n| n.to_string_lossy().into_owned()
                    )
                ));
                files.push((path, by_test_demonstration_csv(&report)));
            }
            files
        }
        None => Vec::new(),
    };
    let json =
        serde_json::to_string_pretty(&report).map_err(|e| CliError::new(e.to_string()))? + "\n";
    if let Some((md_path, json_path)) = &outputs {
        if let Some(dir) = md_path.parent().filter(|p| !p.as_os_str().is_empty()) {
            output::create_dir(dir)?;
        }
        let mut files = vec![
            (md_path.clone(), md.clone()),
            (json_path.clone(), json.clone()),
        ];
        files.extend(extra);
        output::write_files_atomic(&files)?;
    }
    for r in report.results.iter().filter(|r| !r.row.failures.is_empty()) {
        let (seed, msg) = &r.row.failures[0];
        eprintln!(
            "phasekit: warning: {} / {}: {} seed(s) failed; seed {seed}: {msg}",
            r.row.action,
            r.row.method,
            r.row.failures.len()
        );
    }
    match if a.json { Format::Json } else { a.format } {
        Format::Json => output::print_stdout(&json)?,
        Format::Csv => output::print_stdout(&csv(&report))?,
        Format::Md => output::print_stdout(&md)?,
    }
    check(&report, a.fail_above)
}

/// Why [`load_actions`] failed: reading a demonstration, or the selection.
enum Loading {
    Data(data::DataError),
    Other(CliError),
}

/// The actions of a data folder: the folder itself when it holds `train_*` files,
/// else its action subfolders; with `wanted`, only those (the others are not read,
/// so a broken folder of another action does not stop the run).
fn load_actions(
    dir: &Path,
    wanted: Option<&[String]>,
) -> std::result::Result<Vec<Action>, Loading> {
    let other = |e: CliError| Loading::Other(e);
    let folders = if super::has_train_files(dir).map_err(other)? {
        vec![dir.to_path_buf()]
    } else {
        super::action_dirs(dir).map_err(other)?
    };
    if folders.is_empty() {
        // load_dataset says what is missing.
        return data::load_dataset(dir).map_err(Loading::Data);
    }
    let name = |d: &Path| {
        d.file_name()
            .map_or_else(|| "data".to_string(), |n| n.to_string_lossy().into_owned())
    };
    let chosen: Vec<&PathBuf> = match wanted {
        None => folders.iter().collect(),
        Some(w) => {
            let have: Vec<String> = folders.iter().map(|d| name(d)).collect();
            if let Some(x) = w.iter().find(|x| !have.contains(x)) {
                return Err(other(CliError::new(format!(
                    "--action {x}: no such action in {} (actions: {})",
                    dir.display(),
                    have.join(", ")
                ))));
            }
            folders.iter().filter(|d| w.contains(&name(d))).collect()
        }
    };
    chosen
        .into_iter()
        .map(|d| data::load_action(d).map_err(Loading::Data))
        .collect()
}

/// The exit status of a finished run: an error (exit 1, after the table was printed and
/// written) when a method failed on every seed of an action, or, with `fail_above`,
/// when a method's mean MSE is not finite or exceeds it.
pub fn check(report: &Report, fail_above: Option<f64>) -> Result<()> {
    let rows = || {
        report
            .results
            .iter()
            .filter(|r| !r.baseline)
            .map(|r| &r.row)
    };
    let dead: Vec<String> = rows()
        .filter(|r| r.seeds == 0)
        .map(|r| {
            format!(
                "{} / {}{}",
                r.action,
                r.method,
                r.failures
                    .first()
                    .map_or(String::new(), |(s, m)| format!(" (seed {s}: {m})"))
            )
        })
        .collect();
    if !dead.is_empty() {
        bail!(
            "{} method/action pair{} failed on every seed: {}",
            dead.len(),
            if dead.len() == 1 { "" } else { "s" },
            dead.join("; ")
        );
    }
    // An overflowed baseline (or a row whose MSE is somehow not finite) is a failure too.
    let overflow: Vec<String> = report
        .results
        .iter()
        .filter(|r| r.row.seeds > 0 && !r.row.mse_mean.is_finite())
        .map(|r| format!("{} / {}", r.row.action, r.row.method))
        .collect();
    if !overflow.is_empty() {
        bail!(
            "MSE not finite for {} (unit scale {}: use a smaller --unit-scale)",
            overflow.join("; "),
            report.protocol.protocol.unit_scale
        );
    }
    if let Some(limit) = fail_above {
        let u = unit_of(&report.protocol).squared();
        let bad: Vec<String> = rows()
            .filter(|r| !(r.mse_mean.is_finite() && r.mse_mean <= limit))
            .map(|r| format!("{} / {}: {} {u}", r.action, r.method, r.mse_mean))
            .collect();
        if !bad.is_empty() {
            bail!(
                "--fail-above {limit}: mean MSE not finite or above {limit} {u} for {}",
                bad.join("; ")
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_csv_header_names_the_unit_squared() {
        let unit = |name: &str| Unit {
            name: name.into(),
            scale: 1.0,
        };
        assert_eq!(squared_suffix(&unit("cm")), "cm2");
        assert_eq!(squared_suffix(&unit("rad")), "rad2");
        assert_eq!(squared_suffix(&unit("data units")), "data_units_squared");
        assert_eq!(
            squared_suffix(&unit("data units × 2")),
            "data_units_2_squared"
        );
    }
    #[test]
    fn a_row_reads_back_what_it_wrote_undefined_values_included() {
        // The constant baseline has no coverage or NLPD: NaN, written as
        // `null`, read back as NaN (it used to be a parse error).
        let mut row = baseline_row("wave", 12.5);
        row.per_seed_coverage = vec![Some(0.9), None];
        row.per_seed_nlpd = vec![Some(3.0), None];
        row.per_seed_covariance_scale = vec![Some(1.5), None];
        let json = serde_json::to_string(&row).unwrap();
        assert!(json.contains("\"coverage_mean\":null"), "{json}");
        let back: Row = serde_json::from_str(&json).unwrap();
        assert!(back.coverage_mean.is_nan() && back.nlpd_std.is_nan());
        assert_eq!(back.per_seed_coverage, row.per_seed_coverage);
        assert_eq!(back.per_seed_nlpd, row.per_seed_nlpd);
        assert_eq!(
            back.per_seed_covariance_scale,
            row.per_seed_covariance_scale
        );
        assert_eq!(back.mse_mean, 12.5);
        // A method that failed on every seed has no MSE either.
        let mut failed = baseline_row("wave", f64::NAN);
        failed.mse_std = f64::NAN;
        failed.rmse_mean = f64::NAN;
        failed.rmse_std = f64::NAN;
        let json = serde_json::to_string(&failed).unwrap();
        assert!(json.contains("\"mse_mean\":null"), "{json}");
        let back: Row = serde_json::from_str(&json).unwrap();
        assert!(back.mse_mean.is_nan() && back.mse_std.is_nan());
        assert!(back.rmse_mean.is_nan() && back.rmse_std.is_nan());
    }
}
