//! `phasekit fit`.

use super::{check_lengths, column_hint, feature_spec, fit_files, preset_options, setup_threads};
use crate::bail;
use crate::cli::{FitArgs, Format};
use crate::data::{FeatureSpec, Layout, Table};
use crate::error::{CliError, Result};
use crate::experiment::parse_method;
use crate::model_file::{MethodInfo, ModelFile, Standardisation};
use crate::output;
use phasekit_emission::SequenceSet;
use phasekit_tsc::{FitStop, FitSummary, Method, Model, PresetOptions, RegUnits};
use serde::Serialize;
use std::path::PathBuf;

/// What `fit --format json` prints.
#[derive(Debug, Serialize)]
pub struct FitReport {
    /// The method as given.
    pub method: String,
    /// Total states (components) of the model that predicts.
    pub states: usize,
    /// The emission of every state (`full`, `diag`, `student-t`, `gmm-2`, …),
    /// as the model file records it.
    pub emission: String,
    /// Training files.
    pub demonstrations: Vec<PathBuf>,
    /// Training frames.
    pub frames: usize,
    /// Feature names, human's then robot's.
    pub features: Vec<String>,
    /// Whether features were z-scored.
    pub standardised: bool,
    /// The unit of the cross-validation table's MSE (with a table only):
    /// `data units²`, also on z-scores, where the choice judges the error in
    /// the file's units; `standardised units²` in files fitted before it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cv_error_unit: Option<String>,
    /// The unit of `regularisation`: `absolute` (the features' units², added
    /// to every covariance diagonal), `relative` (a fraction of each
    /// feature's variance) or `positions` (a fraction of each position's
    /// variance, a velocity's being its position's); with the last two
    /// `regularisation_per_feature` holds the amounts.
    pub regularisation_unit: String,
    /// What the fit did: `iterations`, `log_likelihood` (per iteration, summed over
    /// sequences), `stop` (why EM stopped), `fit_seconds`, `jitter`, `transition_segments`, …
    #[serde(flatten)]
    pub fit: FitSummary,
    /// Where the model was written.
    pub model_file: Option<PathBuf>,
    /// What the fit had to do beyond the plain algorithm and what to try, one
    /// sentence each: the same notes in every format (text, md, json).
    pub notes: Vec<String>,
}

impl FitReport {
    /// The report of a fitted model file, with its notes.
    pub fn new(
        mf: &ModelFile,
        demonstrations: Vec<PathBuf>,
        frames: usize,
        model_file: Option<PathBuf>,
    ) -> Self {
        let mut r = FitReport {
            method: mf.method.spec.clone(),
            states: mf.n_states(),
            emission: emission_name(&mf.model),
            demonstrations,
            frames,
            features: mf.layout.features.clone(),
            standardised: mf.standardisation.is_some(),
            cv_error_unit: (!mf.fit.cv_table.is_empty()).then(|| {
                if mf.standardisation.is_some() && mf.roles.error_units().is_none() {
                    "standardised units²".to_string()
                } else {
                    "data units²".to_string()
                }
            }),
            regularisation_unit: regularisation_unit(mf),
            fit: mf.fit.clone(),
            model_file,
            notes: Vec::new(),
        };
        r.notes = notes(&r.fit);
        r
    }
}

/// The unit of the regularisation of the model the file holds (`absolute`,
/// `relative`, `positions`); a mean whose members differ: theirs joined by
/// ` + ` in the members' order, each once.
fn regularisation_unit(mf: &ModelFile) -> String {
    let unit = |m: &Method| match m.regularisation() {
        Some((_, RegUnits::Positions, _)) => "positions",
        Some((_, RegUnits::Relative, _)) => "relative",
        _ => "absolute",
    };
    let labels: Vec<&str> = match &mf.model {
        Model::Ensemble(members) => members.iter().map(|m| m.label.as_str()).collect(),
        _ => mf.fit.chosen.as_deref().into_iter().collect(),
    };
    let mut units: Vec<&str> = Vec::new();
    for l in &labels {
        let u = unit(candidate(mf, l));
        if !units.contains(&u) {
            units.push(u);
        }
    }
    if units.is_empty() {
        units.push(match mf.method.settings.regularisation() {
            _ if mf.fit.regularisation_per_feature.is_empty() => "absolute",
            Some((_, RegUnits::Positions, _)) => "positions",
            _ => "relative",
        });
    }
    units.join(" + ")
}

/// `auto`'s candidate of this label, or the file's method.
fn candidate<'a>(mf: &'a ModelFile, label: &str) -> &'a Method {
    match &mf.method.settings {
        Method::CrossValidated(cv) => cv
            .candidates()
            .iter()
            .find(|(l, _)| l == label)
            .map_or(&mf.method.settings, |(_, m)| m),
        m => m,
    }
}

/// The emission of every state of `model`, by its `--emission` name.
pub fn emission_name(model: &Model) -> String {
    match model {
        Model::Hmm(h) => h.emission().kind().to_string(),
        Model::Hsmm(h) => h.emission().kind().to_string(),
        Model::TscHmm { model, .. } => model.base().emission().kind().to_string(),
        Model::Gmm(g) | Model::GmmTsc { mixture: g, .. } => g.components().kind().to_string(),
        Model::Ensemble(members) => {
            let mut names: Vec<String> = Vec::new();
            for m in members {
                let name = emission_name(&m.model);
                if !names.contains(&name) {
                    names.push(name);
                }
            }
            names.join(" + ")
        }
    }
}

/// How a fit ended, in words.
pub fn stop_text(stop: FitStop) -> &'static str {
    match stop {
        FitStop::Converged => "converged",
        FitStop::MaxIter => "stopped at --max-iter",
        FitStop::LogLikelihoodFell => "stopped because the log-likelihood fell",
    }
}

/// Warnings about training features `seqs` (`T × d` each, as the model sees
/// them) for a regularisation `reg`: features never observed, and a
/// regularisation larger than every feature's variance (which leaves the
/// states indistinguishable: the data are on a much smaller scale than `reg`).
pub fn data_warnings(seqs: &[Vec<f64>], names: &[String], reg: f64) -> Vec<String> {
    let d = names.len();
    // Variance over the observed values of every feature (None: never observed).
    let frames = || seqs.iter().flat_map(|q| q.chunks_exact(d));
    let (mut n, mut sum) = (vec![0usize; d], vec![0.0; d]);
    for f in frames() {
        for k in 0..d {
            if !f[k].is_nan() {
                n[k] += 1;
                sum[k] += f[k];
            }
        }
    }
    let mut q = vec![0.0; d];
    for f in frames() {
        for k in 0..d {
            if !f[k].is_nan() {
                q[k] += (f[k] - sum[k] / n[k] as f64).powi(2);
            }
        }
    }
    let mut out = Vec::new();
    let never: Vec<&str> = (0..d)
        .filter(|&k| n[k] == 0)
        .map(|k| names[k].as_str())
        .collect();
    if !never.is_empty() {
        out.push(format!(
            "features never observed in the training data: {} (the model keeps their initial mean and the regularisation as variance)",
            never.join(", ")
        ));
    }
    // Constant and never-observed features do not count: the warning is about scale.
    let largest = (0..d)
        .filter(|&k| n[k] > 0)
        .map(|k| q[k] / n[k] as f64)
        .fold(0.0, f64::max);
    if reg > 0.0 && largest > 0.0 && reg > largest {
        out.push(format!(
            "the regularisation {reg:e} exceeds the variance of every feature (largest {largest:.3e}): \
             the states cannot be told apart at this scale; use --standardise or a --reg well below {largest:.1e}"
        ));
    }
    out
}

/// Features of training tables under a spec; errors name the file.
pub fn training_features(
    tables: &[Table],
    spec: &FeatureSpec,
    defaults: bool,
) -> Result<(Layout, Vec<Vec<f64>>)> {
    let mut layout = None;
    let mut seqs = Vec::with_capacity(tables.len());
    for t in tables {
        let (l, f) = spec.features(t).map_err(|e| column_hint(e, defaults))?;
        layout = Some(l);
        seqs.push(f);
    }
    let layout = layout.ok_or_else(|| CliError::new("no demonstration to fit"))?;
    Ok((layout, seqs))
}

/// Fits `method_spec` to training tables and returns the model file.
pub fn fit_tables(
    tables: &[Table],
    spec: &FeatureSpec,
    defaults: bool,
    method_spec: &str,
    options: &PresetOptions,
    standardise: bool,
) -> Result<ModelFile> {
    let named =
        parse_method(method_spec, options).map_err(|e| CliError::new(format!("--method: {e}")))?;
    let (layout, mut seqs) = training_features(tables, spec, defaults)?;
    check_lengths(tables, &named.method, &named.label)?;
    let d = layout.features.len();
    let frames: usize = tables.iter().map(Table::n_rows).sum();
    crate::data::check_fit_size(d, frames, super::min_frames(&named.method).0)
        .map_err(CliError::new)?;
    let standardisation = standardise.then(|| Standardisation::fit(&seqs, d));
    if let Some(s) = &standardisation {
        let all: Vec<usize> = (0..d).collect();
        seqs.iter_mut().for_each(|q| s.apply(q, &all));
    }
    let data = SequenceSet::new(&seqs, d)?;
    let roles = layout.roles()?;
    // On z-scores, a cross-validated choice (`auto`) still judges the error in
    // the file's units: the choice made without `--standardise`.
    let roles = match &standardisation {
        Some(s) => s.error_units_of(roles)?,
        None => roles,
    };
    // The library's message names the settings as flags (`CliError::from`),
    // including its advice when the transition segments are too few or short.
    let (model, mut summary) = named
        .method
        .fit(&data, &roles)
        .map_err(|e| CliError::from(e).context(format!("fitting `{}` failed", named.label)))?;
    // A relative regularisation is below every feature's variance unless R > 1.
    let absolute_reg = if summary.regularisation_per_feature.is_empty() {
        summary.regularisation
    } else {
        0.0
    };
    summary.warnings = data_warnings(&seqs, &layout.features, absolute_reg);
    ModelFile::new(
        layout,
        spec.clone(),
        standardisation,
        roles,
        MethodInfo {
            spec: named.label,
            settings: named.method,
        },
        summary,
        model,
    )
    .calibrated(&seqs)
}

/// Runs `phasekit fit`.
pub fn run(a: &FitArgs) -> Result<()> {
    if a.library {
        return super::recognise::fit_library(a, &a.library_settings);
    }
    let format = if a.json { Some(Format::Json) } else { a.format };
    if a.output.is_none() && format.is_none() {
        bail!("nothing to do: give -o MODEL.json to save the model (and/or --format json to print the fit report)");
    }
    setup_threads(a.model.threads)?;
    let options = preset_options(&a.model)?;
    let (spec, defaults) = feature_spec(&a.columns);
    let files = fit_files(&a.data, a.action.as_deref())?;
    // Only the selected columns are parsed (a text column such as a timestamp does not matter).
    let patterns = [spec.human.clone(), spec.robot.clone()].concat();
    let tables =
        crate::inputs::read_tables_select(&files, true, crate::data::Select::Globs(&patterns))
            .map_err(|e| column_hint(e, defaults))?;
    let frames: usize = tables.iter().map(Table::n_rows).sum();
    let bar = output::spinner(&format!(
        "fitting {} to {} demonstrations ({frames} frames)",
        a.method,
        tables.len()
    ));
    let result = fit_tables(
        &tables,
        &spec,
        defaults,
        &a.method,
        &options,
        a.model.standardise,
    );
    bar.finish_and_clear();
    let mf = result?;
    if let Some(path) = &a.output {
        mf.save(path)?;
    }
    let report = FitReport::new(&mf, files.clone(), frames, a.output.clone());
    match format {
        Some(Format::Json) => {
            let text =
                serde_json::to_string_pretty(&report).map_err(|e| CliError::new(e.to_string()))?;
            output::print_stdout(&(text + "\n"))?;
        }
        Some(Format::Csv) => {
            let mut s = String::from("iteration,log_likelihood\n");
            for (i, ll) in report.fit.log_likelihood.iter().enumerate() {
                s.push_str(&format!("{},{}\n", i + 1, ll));
            }
            output::print_stdout(&s)?;
        }
        Some(Format::Md) => output::print_stdout(&markdown(&report))?,
        None => {
            if output::stderr_is_terminal() {
                eprintln!("{}", summary_line(&report));
            }
        }
    }
    Ok(())
}

fn summary_line(r: &FitReport) -> String {
    format!(
        "phasekit: fitted {}{} ({} states, {} emissions) to {} demonstrations ({} frames, {} features) in {:.2} s: {} EM iterations, {}; reg {}{}",
        r.method,
        r.fit.chosen.as_ref().map(|c| format!(" (chose {c}{})", cv_note(&r.fit))).unwrap_or_default(),
        r.states,
        r.emission,
        r.demonstrations.len(),
        r.frames,
        r.features.len(),
        r.fit.fit_seconds,
        r.fit.iterations,
        stop_text(r.fit.stop),
        reg_text(r),
        r.model_file.as_ref().map(|p| format!("; model written to {}", p.display())).unwrap_or_default()
    ) + &r
        .notes
        .iter()
        .map(|n| format!("\nphasekit: note: {n}"))
        .collect::<String>()
}

/// What the fit had to do beyond the plain algorithm and what to try, one sentence each.
pub fn notes(fit: &FitSummary) -> Vec<String> {
    let mut notes = Vec::new();
    if fit.missing_values > 0 {
        notes.push(format!(
            "{} feature values missing (the fit used their expected values given the observed ones)",
            fit.missing_values
        ));
    }
    if !fit.jittered_states.is_empty() {
        notes.push(format!(
            "states {:?} needed extra jitter (up to {:e}) to stay positive definite: consider a larger --reg",
            fit.jittered_states, fit.jitter
        ));
    }
    if fit.stop == FitStop::LogLikelihoodFell {
        let fall = match fit.log_likelihood.as_slice() {
            [.., a, b] => format!(" by {:.3e} (from {a:.4} to {b:.4})", a - b),
            _ => String::new(),
        };
        notes.push(format!(
            "EM stopped after {} iteration{} because the log-likelihood fell{fall}: the regularisation added after \
             every M-step makes EM non-monotone, and the protocol stops at the first fall{}; a smaller --reg or \
             --standardise lets EM run on",
            fit.iterations,
            if fit.iterations == 1 { "" } else { "s" },
            if fit.iterations <= 2 { " (the model is barely fitted)" } else { "" }
        ));
    }
    notes.extend(fit.warnings.iter().cloned());
    if !fit.empty_states.is_empty() {
        notes.push(format!(
            "states {:?} received no frame and kept their initial parameters: fewer --states would do",
            fit.empty_states
        ));
    }
    notes
}

/// The regularisation with its unit, the same words in every format:
/// `1e-2 × each feature's variance (…)` or `1e-2 data units² on every covariance diagonal`.
fn reg_text(r: &FitReport) -> String {
    let text = reg_text_of_one(r);
    if r.fit
        .chosen
        .as_deref()
        .is_some_and(|c| c.starts_with("mean of "))
    {
        // A mean's summary is its first member's; each member's `reg` is in its label.
        format!("{text}, the first member's (each member's is in its label)")
    } else {
        text
    }
}

fn reg_text_of_one(r: &FitReport) -> String {
    let f = &r.fit;
    if f.regularisation_per_feature.is_empty() {
        format!(
            "{:e} {}² on every covariance diagonal",
            f.regularisation,
            if r.standardised {
                "standardised units"
            } else {
                "data units"
            }
        )
    } else {
        let (lo, hi) = f
            .regularisation_per_feature
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(*v), b.max(*v)));
        let of_what = if r.regularisation_unit.starts_with("positions") {
            "each position's variance (a velocity: its position's)"
        } else {
            "each feature's variance"
        };
        format!(
            "{:e} × {of_what} (added to the feature's variance: {lo:.3e} to {hi:.3e} {}²)",
            f.regularisation,
            if r.standardised {
                "standardised units"
            } else {
                "data units"
            }
        )
    }
}

fn markdown(r: &FitReport) -> String {
    let ll = r
        .fit
        .log_likelihood
        .last()
        .map_or("–".to_string(), |v| format!("{v:.4}"));
    let mut s = String::from("| | |\n|---|---|\n");
    for (k, v) in [
        ("method", r.method.clone()),
        ("states", r.states.to_string()),
        ("emission", r.emission.clone()),
        ("demonstrations", r.demonstrations.len().to_string()),
        ("frames", r.frames.to_string()),
        ("features", r.features.join(", ")),
        ("standardised", r.standardised.to_string()),
        (
            "chosen (cross-validation or BIC)",
            r.fit.chosen.clone().unwrap_or_else(|| "–".into()),
        ),
        ("iterations", r.fit.iterations.to_string()),
        ("stop", stop_text(r.fit.stop).to_string()),
        ("regularisation", reg_text(r)),
        (
            "extra jitter (largest)",
            if r.fit.jittered_states.is_empty() {
                "none".into()
            } else {
                format!("{:e} on states {:?}", r.fit.jitter, r.fit.jittered_states)
            },
        ),
        (
            "states with no weight (kept unchanged)",
            if r.fit.empty_states.is_empty() {
                "none".into()
            } else {
                format!("{:?}: fewer states would do", r.fit.empty_states)
            },
        ),
        ("missing values", r.fit.missing_values.to_string()),
        (
            "warnings",
            if r.fit.warnings.is_empty() {
                "none".into()
            } else {
                r.fit.warnings.join("; ")
            },
        ),
        ("final log-likelihood", ll),
        ("fit time (s)", format!("{:.3}", r.fit.fit_seconds)),
        (
            "transition segments",
            r.fit
                .transition_segments
                .map_or("–".into(), |n| n.to_string()),
        ),
        (
            "model file",
            r.model_file
                .as_ref()
                .map_or("–".into(), |p| p.display().to_string()),
        ),
    ] {
        s.push_str(&format!("| {k} | {v} |\n"));
    }
    s.push_str(&cv_table_markdown(
        &r.fit,
        r.cv_error_unit.as_deref().unwrap_or("data units²"),
    ));
    for n in &r.notes {
        s.push_str(&format!("\nNote: {n}\n"));
    }
    s
}

/// The cross-validation table of a choice by cross-validation (`auto`, the
/// `-cv` presets), as Markdown, its MSE in `unit`; empty for other methods.
pub fn cv_table_markdown(fit: &FitSummary, unit: &str) -> String {
    if fit.cv_table.is_empty() {
        return String::new();
    }
    let mut s = format!(
        "\nCross-validation on the training demonstrations (MSE of the robot's scored features — its positions — per held-out frame, {unit}; \
         ± population sd over folds; coverage of the predicted 95 % region and mean negative log predictive density (nats) of the same frames, before calibration; \
         fit time summed over the candidate's folds):\n\n\
         | candidate | folds scored | CV MSE | coverage 95 % | NLPD | fit (s) | outcome |\n|---|---:|---:|---:|---:|---:|---|\n"
    );
    for row in &fit.cv_table {
        let outcome = match (&row.failure, row.abandoned) {
            (Some(e), _) => format!("failed: {e}"),
            (None, true) => "abandoned (successive halving)".to_string(),
            (None, false) if fit.chosen.as_deref() == Some(row.label.as_str()) => {
                "**chosen**".to_string()
            }
            (None, false) => "scored on every fold".to_string(),
        };
        let mse = if row.mse.is_finite() {
            format!("{:.4e} ± {:.2e}", row.mse, row.mse_sd)
        } else {
            "–".to_string()
        };
        let coverage = row
            .coverage
            .map_or("–".to_string(), |c| format!("{:.1} %", 100.0 * c));
        let nlpd = row.nlpd.map_or("–".to_string(), |v| format!("{v:.3}"));
        s.push_str(&format!(
            "| {} | {} | {mse} | {coverage} | {nlpd} | {:.3} | {outcome} |\n",
            row.label, row.folds_scored, row.fit_seconds
        ));
    }
    if let Some(c) = &fit.covariance_calibration {
        let shape = if c.added_covariance.is_empty() {
            String::new()
        } else {
            format!(
                "the held-out errors' covariance added with weight {:.3}, then ",
                c.residual_weight
            )
        };
        s.push_str(&format!(
            "\nCalibration of the chosen candidate's predictive covariance on its {} held-out frames: \
             {shape}multiplied by {:.4} ({:.3}× the pooled factor for a new demonstration), so that {:.1} % of them \
             (was {:.1} %) fall inside the {:.0} % region; NLPD {:.3} → {:.3} nats.\n",
            c.frames,
            c.scale,
            c.demonstration_inflation,
            100.0 * c.coverage_after,
            100.0 * c.coverage_before,
            100.0 * c.level,
            c.nlpd_before,
            c.nlpd_after
        ));
    }
    s
}

/// `, choosing among N candidates by cross-validation (A abandoned, F failed)`, or nothing.
fn cv_note(fit: &FitSummary) -> String {
    if fit.cv_table.is_empty() {
        return String::new();
    }
    let abandoned = fit.cv_table.iter().filter(|r| r.abandoned).count();
    let failed = fit.cv_table.iter().filter(|r| r.failure.is_some()).count();
    // The mean's own row (last, labelled as the choice) is not a candidate.
    let mean = fit
        .cv_table
        .last()
        .is_some_and(|r| r.label.starts_with("mean of ") && fit.chosen.as_ref() == Some(&r.label));
    format!(
        " by cross-validation among {} candidates ({abandoned} abandoned early, {failed} failed; --format md shows the table)",
        fit.cv_table.len() - usize::from(mean)
    )
}
