//! `phasekit evaluate --task recognition`: the recognition experiment of
//! `phasekit_recognition::experiment` on a data set folder, and its tables
//! (Markdown, JSON, CSV).

use crate::bail;
use crate::cli::{EvaluateArgs, Format};
use crate::commands::evaluate::output_files;
use crate::commands::recognise::rec_err;
use crate::commands::{column_hint, feature_spec, preset_options, setup_threads, split_methods};
use crate::data::{self, FeatureSpec};
use crate::error::{CliError, Result};
use crate::experiment::{parse_method, prepare};
use crate::output;
use phasekit_recognition::experiment::{
    self, ActionSplit, Dataset, ExperimentSettings, Report, Stat,
};
use phasekit_tsc::{PresetOptions, Roles};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Frames per second of the data (NuiSI: 30 Hz), for the times in the tables.
pub const FRAME_RATE: f64 = 30.0;

/// What `evaluate --task recognition --format json` prints and `-o PREFIX` writes to PREFIX.json.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RecognitionJson {
    /// Always `recognition`.
    pub task: String,
    /// The data set folder.
    pub data: PathBuf,
    /// The column selection.
    pub columns: FeatureSpec,
    /// The methods' shared options.
    pub options: PresetOptions,
    /// Wall-clock seconds of the run.
    pub seconds: f64,
    /// The reported unit's name (`--unit`; its factor from data units is `unit_scale`).
    #[serde(default = "default_unit")]
    pub unit: String,
    /// The results.
    #[serde(flatten)]
    pub report: Report,
}

fn default_unit() -> String {
    crate::units::Unit::default().name
}

/// Refuses recognition-only flags with the prediction task.
pub fn check_prediction_task(a: &EvaluateArgs) -> Result<()> {
    let d = LibraryArgsDefaults::default();
    let l = &a.library_settings;
    if l.prior != d.prior
        || l.rest_frames != d.rest_frames
        || l.calibration_folds != d.calibration_folds
        || l.calibration_quantile != d.calibration_quantile
        || l.recognition_method.is_some()
        || !l.action_method.is_empty()
        || l.temperature != crate::commands::recognise::TemperatureArg::Fixed(1.0)
    {
        bail!("--prior, --rest-frames, --calibration-*, --recognition-method, --temperature and --action-method set up a library of interactions: they need --task recognition");
    }
    Ok(())
}

/// The defaults of [`LibraryArgs`] (as clap sets them).
struct LibraryArgsDefaults {
    prior: crate::commands::recognise::PriorArg,
    rest_frames: usize,
    calibration_folds: usize,
    calibration_quantile: f64,
}

impl Default for LibraryArgsDefaults {
    fn default() -> Self {
        LibraryArgsDefaults {
            prior: crate::commands::recognise::PriorArg::Uniform,
            rest_frames: 5,
            calibration_folds: 4,
            calibration_quantile: 0.0,
        }
    }
}

/// The experiment's data from a data set folder.
pub fn dataset(
    actions: &[data::Action],
    spec: &FeatureSpec,
    defaults: bool,
    unit_scale: f64,
) -> Result<Dataset> {
    let mut layout: Option<(String, data::Layout)> = None;
    let mut splits = Vec::new();
    for action in actions {
        for t in action.train.iter().chain(&action.test) {
            spec.features(t).map_err(|e| column_hint(e, defaults))?;
        }
        if action.test.is_empty() {
            bail!("{}: no test_* demonstration to recognise", action.name);
        }
        let p = prepare(action, spec).map_err(CliError::new)?;
        match &layout {
            None => layout = Some((action.name.clone(), p.layout.clone())),
            Some((first, l)) if *l != p.layout => bail!(
                "action `{}`: its features ({}) differ from those of action `{first}` ({}): every action of a library needs the same columns",
                action.name,
                p.layout.features.join(", "),
                l.features.join(", ")
            ),
            Some(_) => {}
        }
        splits.push(ActionSplit {
            name: action.name.clone(),
            train: p.train,
            test: p.test,
        });
    }
    let (_, layout) = layout.ok_or_else(|| CliError::new("no action to evaluate"))?;
    Ok(Dataset {
        actions: splits,
        dim: layout.features.len(),
        roles: Roles::new(layout.human.clone(), layout.robot.clone())?,
        scored: layout.robot_positions.clone(),
        unit_scale,
    })
}

/// Runs `phasekit evaluate --task recognition`.
pub fn run(a: &EvaluateArgs) -> Result<()> {
    setup_threads(a.model.threads)?;
    let options = preset_options(&a.model)?;
    let (spec, defaults) = feature_spec(&a.columns);
    if a.seeds == 0 {
        bail!("--seeds must be at least 1");
    }
    if a.fail_above.is_some() || a.missing.is_some() {
        bail!("--fail-above and --missing apply to --task prediction");
    }
    let unit = a.unit.resolve()?;
    if a.train_size == Some(0) {
        bail!("--train-size must be at least 1");
    }
    let labels = split_methods(&a.methods);
    if labels.is_empty() {
        bail!("--methods: no method given");
    }
    let methods = labels
        .iter()
        .map(|m| {
            parse_method(m, &options)
                .map(|n| (n.label, n.method))
                .map_err(|e| CliError::new(format!("--methods: {e}")))
        })
        .collect::<Result<Vec<_>>>()?;
    let outputs = a.output.as_deref().map(output_files).transpose()?;
    if let Some((md, _)) = &outputs {
        let dir = md
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if !dir.is_dir() {
            bail!(
                "-o {}: folder {} does not exist",
                md.display(),
                dir.display()
            );
        }
    }
    if !a.data.is_dir() {
        bail!(
            "{}: evaluate needs a folder of action folders with train_* and test_* files",
            a.data.display()
        );
    }
    let mut actions = data::load_dataset(&a.data).map_err(|e| column_hint(e, defaults))?;
    if let Some(wanted) = &a.action {
        let have: Vec<String> = actions.iter().map(|x| x.name.clone()).collect();
        for w in wanted {
            if !have.contains(w) {
                bail!(
                    "--action {w}: no such action in {} (actions: {})",
                    a.data.display(),
                    have.join(", ")
                );
            }
        }
        actions.retain(|x| wanted.contains(&x.name));
    }
    if actions.len() < phasekit_recognition::MIN_ACTIONS {
        bail!(
            "{}: recognition needs at least {} actions to choose from, found {} ({})",
            a.data.display(),
            phasekit_recognition::MIN_ACTIONS,
            actions.len(),
            actions
                .iter()
                .map(|x| x.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    for action in &actions {
        for (label, m) in &methods {
            crate::commands::check_lengths(&action.train, m, label)?;
        }
    }
    let ds = dataset(&actions, &spec, defaults, unit.scale)?;
    let mut settings = ExperimentSettings::default();
    settings.seeds = a.seeds;
    settings.train_size = a.train_size;
    settings.standardise = a.model.standardise;
    settings.library = a.library_settings.settings(options.reg())?;
    settings.frame_rate = FRAME_RATE;
    settings.recognition = a
        .library_settings
        .recognition(&options)?
        .map(|n| (n.label, n.method));
    settings.action_methods = a.library_settings.action_methods(&options)?;
    for (name, label, m) in &settings.action_methods {
        let Some(action) = actions.iter().find(|x| &x.name == name) else {
            bail!(
                "--action-method: no action `{name}` in {}",
                a.data.display()
            );
        };
        crate::commands::check_lengths(&action.train, m, label)?;
    }
    if let Some((label, m)) = &settings.recognition {
        for action in &actions {
            crate::commands::check_lengths(&action.train, m, label)?;
        }
    }
    let total = a.seeds * methods.len();
    let bar = output::progress_bar(total as u64, "recognition");
    let clock = Instant::now();
    let report = experiment::run(&ds, &methods, &settings, &|| bar.inc(1));
    bar.finish_and_clear();
    let report = report.map_err(rec_err)?;
    let json = RecognitionJson {
        task: "recognition".into(),
        data: a.data.clone(),
        columns: spec,
        options,
        seconds: clock.elapsed().as_secs_f64(),
        unit: unit.name,
        report,
    };
    let md = markdown(&json);
    let text =
        serde_json::to_string_pretty(&json).map_err(|e| CliError::new(e.to_string()))? + "\n";
    if let Some((md_path, json_path)) = &outputs {
        output::write_files_atomic(&[
            (md_path.clone(), md.clone()),
            (json_path.clone(), text.clone()),
        ])?;
    }
    for (method, seed, msg) in json.report.failures.iter().take(3) {
        eprintln!("phasekit: warning: {method}: seed {seed} failed: {msg}");
    }
    match if a.json { Format::Json } else { a.format } {
        Format::Json => output::print_stdout(&text)?,
        Format::Csv => output::print_stdout(&csv(&json.report))?,
        Format::Md => output::print_stdout(&md)?,
    }
    let dead: Vec<&String> = json
        .report
        .methods
        .iter()
        .filter(|m| {
            json.report
                .recognition
                .iter()
                .all(|r| &r.method != *m || r.seeds == 0)
        })
        .collect();
    if !dead.is_empty() {
        bail!(
            "{} failed on every seed",
            dead.iter()
                .map(|m| m.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(())
}

fn pct(v: f64) -> String {
    if v.is_finite() {
        format!("{:.0}", 100.0 * v)
    } else {
        "–".into()
    }
}

fn pct1(v: Option<f64>) -> String {
    v.map_or("–".into(), |v| format!("{:.1}", 100.0 * v))
}

fn stat(s: &Stat, seeds: usize) -> String {
    if !s.mean.is_finite() {
        "–".into()
    } else if seeds <= 1 {
        format!("{:.2}", s.mean)
    } else {
        format!("{:.2} ± {:.2}", s.mean, s.std)
    }
}

fn change(v: f64) -> String {
    if v.is_finite() {
        format!("{:+.1} %", 100.0 * v)
    } else {
        "–".into()
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("never".into(), |v| format!("{v:.digits$}"))
}

/// The Markdown document: every table, then the definitions.
pub fn markdown(j: &RecognitionJson) -> String {
    let r = &j.report;
    let u = crate::units::Unit {
        name: j.unit.clone(),
        scale: r.unit_scale,
    }
    .squared();
    let mut s = String::new();
    s.push_str(&format!(
        "Recognition on {} ({} actions: {}), {} seed{}, {:.0} s.\n\n",
        j.data.display(),
        r.actions.len(),
        r.actions.join(", "),
        r.seeds,
        if r.seeds == 1 { "" } else { "s" },
        j.seconds
    ));
    s.push_str("**Accuracy after observing a fraction of each test demonstration** (% of the test demonstrations decided right, mean over seeds; rejection off), and when the decision settles (becomes and stays right):\n\n");
    s.push_str("| method | action |");
    for k in 1..=10 {
        s.push_str(&format!(" {} % |", 10 * k));
    }
    s.push_str(" right from ⅓ on (%) | settles after (frames) | (s) | (% of the demonstration) | never settles (%) |\n|---|---|");
    s.push_str(&"---:|".repeat(15));
    s.push('\n');
    for m in &r.methods {
        for row in r.settled.iter().filter(|x| &x.method == m) {
            s.push_str(&format!("| {m} | {} |", row.action));
            for k in 1..=10 {
                let acc = r
                    .recognition
                    .iter()
                    .find(|x| {
                        &x.method == m
                            && x.action == row.action
                            && (x.fraction - k as f64 / 10.0).abs() < 1e-9
                    })
                    .map_or(f64::NAN, |x| x.accuracy);
                s.push_str(&format!(" {} |", pct(acc)));
            }
            s.push_str(&format!(
                " {} | {} | {} | {} | {} |\n",
                pct(row.correct_from_first_third),
                opt(row.median_frames, 0),
                opt(row.median_seconds, 2),
                row.median_fraction
                    .map_or("never".into(), |v| format!("{:.0}", 100.0 * v)),
                pct(row.never)
            ));
        }
    }
    for c in &r.confusion {
        let counts = &c.confusion.counts;
        let n = r.actions.len();
        let unknown = counts.iter().any(|row| row[n] > 0);
        let rest = counts.iter().any(|row| row[n + 1] > 0);
        s.push_str(&format!(
            "\n**Confusion of {} after observing {}** (% of each action's test demonstrations over all seeds; rows: true action, columns: decision):\n\n| true \\ decided |",
            c.method,
            if c.fraction < 1.0 { "a third" } else { "all" }
        ));
        for a in &r.actions {
            s.push_str(&format!(" {a} |"));
        }
        if unknown {
            s.push_str(" unknown |");
        }
        if rest {
            s.push_str(" rest |");
        }
        s.push_str("\n|---|");
        s.push_str(&"---:|".repeat(n + unknown as usize + rest as usize));
        s.push('\n');
        for (a, row) in r.actions.iter().zip(counts) {
            let total: usize = row.iter().sum();
            s.push_str(&format!("| {a} |"));
            let cols: Vec<usize> = (0..n)
                .chain(unknown.then_some(n))
                .chain(rest.then_some(n + 1))
                .collect();
            for k in cols {
                s.push_str(&format!(
                    " {:.0} |",
                    100.0 * row[k] as f64 / total.max(1) as f64
                ));
            }
            s.push('\n');
        }
    }
    s.push_str(&format!(
        "\n**End to end**: robot-prediction MSE ({u}) of each method told the action (the oracle, as in the prediction experiment) and with the recognised action: the most probable action's prediction, the posterior-weighted mixture, and the mixture with likelihood-per-frame rejection (the rest pose while rejected); Δ = mean over seeds of the relative change against the oracle:\n\n| action | method | oracle | most probable | Δ | mixture | Δ | mixture, rejecting | Δ | seeds |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n"
    ));
    let mut rows: Vec<&experiment::EndToEndRow> = r.end_to_end.iter().collect();
    let order = |a: &str| {
        r.actions
            .iter()
            .position(|x| x == a)
            .unwrap_or(r.actions.len())
    };
    rows.sort_by_key(|x| {
        (
            order(&x.action),
            r.methods.iter().position(|m| *m == x.method),
        )
    });
    for e in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            e.action,
            e.method,
            stat(&e.oracle, e.seeds),
            stat(&e.most_probable, e.seeds),
            change(e.change_most_probable),
            stat(&e.mixture, e.seeds),
            change(e.change_mixture),
            stat(&e.mixture_rejecting, e.seeds),
            change(e.change_mixture_rejecting),
            e.seeds
        ));
    }
    s.push_str("\n**Unknown motions**: each action left out of the library in turn; its test demonstrations should be rejected, the other actions' not (`none`: the full library; `all`: pooled over the left-out actions). Rejected = the decision after the whole demonstration is *unknown*; frames = the share of frames rejected (the robot kept its rest pose):\n\n| method | left out | rejection test | unknown rejected (%) | unknown frames rejected (%) | known rejected (%) | known frames rejected (%) | seeds |\n|---|---|---|---:|---:|---:|---:|---:|\n");
    for x in &r.unknown {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {:.1} | {:.1} | {} |\n",
            x.method,
            x.left_out,
            x.rejection.name(),
            pct1(x.unknown_rejected),
            pct1(x.unknown_frames_rejected),
            100.0 * x.known_rejected,
            100.0 * x.known_frames_rejected,
            x.seeds
        ));
    }
    s.push_str(&format!(
        "\n**Continuous streams** of {} test demonstrations of random actions (seeded), back to back, scored per frame: decision = the demonstration's action; delay = frames of an interaction observed until the decision is right for {} frames in a row ({:.1} s) or to the interaction's end; MSE of the robot's prediction ({u}; per-action filters: the mixture) and of the method told the action and its start:\n\n| method | recogniser | frame accuracy (%) | median delay (frames) | (s) | never settles (%) | MSE | oracle MSE | seeds |\n|---|---|---:|---:|---:|---:|---:|---:|---:|\n",
        r.settings.stream_length,
        r.settings.stream_hold_frames,
        r.settings.stream_hold_frames as f64 / FRAME_RATE
    ));
    for x in &r.streams {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            x.method,
            x.recogniser.describe(),
            if x.seeds > 1 {
                format!(
                    "{:.1} ± {:.1}",
                    100.0 * x.frame_accuracy.mean,
                    100.0 * x.frame_accuracy.std
                )
            } else {
                format!("{:.1}", 100.0 * x.frame_accuracy.mean)
            },
            opt(x.median_delay_frames, 0),
            opt(x.median_delay_seconds, 2),
            pct(x.never),
            stat(&x.mse, x.seeds),
            stat(&x.oracle_mse, x.seeds),
            x.seeds
        ));
    }
    s.push_str("\n**Calibration** of the libraries (mean ± std over seeds): the posterior's temperature and the held-out log score of the true action at it (nats per frame), the rejection thresholds (likelihood per frame: nats per frame; threshold model: nats):\n\n| method | temperature | held-out log score | likelihood-per-frame threshold | threshold-model threshold | seeds |\n|---|---:|---:|---:|---:|---:|\n");
    for c in &r.calibration {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            c.method,
            stat(&c.temperature, c.seeds),
            stat(&c.log_score, c.seeds),
            stat(&c.likelihood_per_frame, c.seeds),
            stat(&c.threshold_model, c.seeds),
            c.seeds
        ));
    }
    if !r.failures.is_empty() {
        s.push_str(&format!(
            "\n{} (method, seed) runs failed; the first: {} seed {}: {}\n",
            r.failures.len(),
            r.failures[0].0,
            r.failures[0].1,
            r.failures[0].2
        ));
    }
    for (action, label, _) in &r.settings.action_methods {
        s.push_str(&format!("\nAction `{action}` is fitted with `{label}` whatever the method (it predicts and recognises it).\n"));
    }
    if let Some((label, _)) = &r.settings.recognition {
        s.push_str(&format!("\nRecognition by a second model per action, `{label}` (its likelihood decides; each method still predicts).\n"));
    }
    s.push_str(&format!(
        "\nProtocol: seed s trains every action's model on the prediction experiment's random subset of its training demonstrations (all but two), and the library (prior {}, rest state from the first and last {} frames of every training demonstration, rejection thresholds from {}-fold cross-validation at quantile {}, posterior temperature {}); times at {FRAME_RATE} frames per second.\n",
        match r.settings.library.prior {
            phasekit_recognition::Prior::Uniform => "uniform".to_string(),
            phasekit_recognition::Prior::Demonstrations => "by demonstrations".to_string(),
            phasekit_recognition::Prior::Given(ref w) => format!("{w:?}"),
        },
        r.settings.library.rest_frames,
        r.settings.library.calibration_folds,
        r.settings.library.calibration_quantile,
        r.settings
            .library
            .temperature
            .map_or("chosen on the held-out demonstrations".to_string(), |t| t.to_string())
    ));
    s
}

/// The accuracy rows as CSV (`method,action,fraction,accuracy,std,seeds`).
pub fn csv(r: &Report) -> String {
    let mut s = String::from("method,action,fraction,accuracy,std,seeds\n");
    for x in &r.recognition {
        s.push_str(&format!(
            "{},{},{},{},{},{}\n",
            output::csv_field(&x.method),
            output::csv_field(&x.action),
            x.fraction,
            x.accuracy,
            x.std,
            x.seeds
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    #[test]
    fn recognition_draws_the_prediction_experiments_subsets() {
        for seed in 0..20 {
            for (n, size) in [(8, 6), (9, 7), (7, 5), (3, 5)] {
                assert_eq!(
                    phasekit_recognition::experiment::subset(seed, n, size),
                    crate::experiment::subset(seed, n, size)
                );
            }
        }
    }
}
