//! `phasekit predict`.

use super::data_files;
use crate::bail;
use crate::cli::{DataFormat, PredictArgs};
use crate::data::Select;
use crate::error::Result;
use crate::inputs::read_tables_select;
use crate::model_file::ModelFile;
use crate::output::{self, csv_header};
use crate::pipeline::{
    predict_table, prediction_header, prediction_line, predictor, FrameStatus, RobotPrediction,
};
use std::path::{Path, PathBuf};

/// The CSV text of a prediction.
pub fn prediction_csv(mf: &ModelFile, p: &RobotPrediction) -> String {
    let mut s = csv_header(&prediction_header(mf, p.covariance.is_some()));
    s.push('\n');
    let o = p.n_out;
    let mut line = String::new();
    for t in 0..p.len() {
        let cov = p
            .covariance
            .as_ref()
            .map(|c| &c[t * o * o..(t + 1) * o * o]);
        prediction_line(t, &p.mean[t * o..(t + 1) * o], cov, &mut line);
        s.push_str(&line);
        s.push('\n');
    }
    s
}

/// The NPY bytes of a prediction: the CSV's columns (frame, the robot's
/// features, the covariance entries) as a `T × C` float array.
pub fn prediction_npy(mf: &ModelFile, p: &RobotPrediction) -> Vec<u8> {
    let cols = prediction_header(mf, p.covariance.is_some()).len();
    let o = p.n_out;
    let mut data = Vec::with_capacity(p.len() * cols);
    for t in 0..p.len() {
        data.push(t as f64);
        data.extend_from_slice(&p.mean[t * o..(t + 1) * o]);
        if let Some(c) = &p.covariance {
            let c = &c[t * o * o..(t + 1) * o * o];
            for i in 0..o {
                data.extend_from_slice(&c[i * o + i..(i + 1) * o]);
            }
        }
    }
    crate::npy::write(p.len(), cols, &data)
}

/// The JSON text of a prediction.
pub fn prediction_json(mf: &ModelFile, file: &Path, p: &RobotPrediction) -> Result<String> {
    let o = p.n_out;
    let features: Vec<&String> = mf
        .layout
        .robot
        .iter()
        .map(|&k| &mf.layout.features[k])
        .collect();
    let mean: Vec<&[f64]> = p.mean.chunks_exact(o).collect();
    let covariance: Option<Vec<Vec<&[f64]>>> = p.covariance.as_ref().map(|c| {
        c.chunks_exact(o * o)
            .map(|m| m.chunks_exact(o).collect())
            .collect()
    });
    let v = serde_json::json!({
        "file": file.display().to_string(),
        "features": features,
        "mean": mean,
        "covariance": covariance,
        "out_of_distribution": p.frames_with(FrameStatus::OutOfDistribution),
        "rejected": p.frames_with(FrameStatus::Rejected),
    });
    Ok(serde_json::to_string(&v).map_err(|e| crate::CliError::new(e.to_string()))? + "\n")
}

fn output_name(input: &Path, ext: &str) -> String {
    let stem = input
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("prediction");
    format!("{stem}.predicted.{ext}")
}

/// Frames as a short list: `3, 7–9, 12 (and 40 more)`.
pub fn frame_list(frames: &[usize]) -> String {
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for &f in frames {
        match runs.last_mut() {
            Some((_, b)) if *b + 1 == f => *b = f,
            _ => runs.push((f, f)),
        }
    }
    const SHOWN: usize = 6;
    let mut parts: Vec<String> = runs
        .iter()
        .take(SHOWN)
        .map(|&(a, b)| {
            if a == b {
                a.to_string()
            } else {
                format!("{a}–{b}")
            }
        })
        .collect();
    if runs.len() > SHOWN {
        let rest: usize = runs[SHOWN..].iter().map(|(a, b)| b - a + 1).sum();
        parts.push(format!("and {rest} more"));
    }
    parts.join(", ")
}

/// Warnings about a prediction's frames: rejected ones and those out of distribution.
pub fn prediction_warnings(mf: &ModelFile, file: &Path, p: &RobotPrediction) -> Vec<String> {
    let mut out = Vec::new();
    let rejected = p.frames_with(FrameStatus::Rejected);
    if !rejected.is_empty() {
        out.push(format!(
            "{}: frame{} {} {} density zero under every state of the model (a value far outside the training range, e.g. 1e200): taken as not observed, predicted from the dynamics alone",
            file.display(),
            if rejected.len() == 1 { "" } else { "s" },
            frame_list(&rejected),
            if rejected.len() == 1 { "has" } else { "have" },
        ));
    }
    let ood = p.frames_with(FrameStatus::OutOfDistribution);
    if let (false, Some(n)) = (ood.is_empty(), &mf.novelty) {
        let lowest = ood
            .iter()
            .map(|&t| p.log_predictive[t] / p.observed[t] as f64)
            .fold(f64::INFINITY, f64::min);
        out.push(format!(
            "{}: {} of {} frames are out of distribution ({}): the human's input is far less likely under the model than the training data \
             (down to {lowest:.3} nats per value; the threshold calibrated on the training demonstrations is {:.3}, their median {:.3}): \
             another coordinate frame, unit or person? Their predictions are extrapolations",
            file.display(),
            ood.len(),
            p.len(),
            frame_list(&ood),
            n.threshold,
            n.median,
        ));
    }
    out
}

/// The note for a model file without an out-of-distribution threshold.
pub fn no_novelty_note(model: &Path) -> String {
    format!(
        "{}: no out-of-distribution threshold (written by an older phasekit): unusual input is not flagged; refit the model to have it flagged",
        model.display()
    )
}

/// Runs `phasekit predict`.
pub fn run(a: &PredictArgs) -> Result<()> {
    let files = data_files(&a.data)?;
    let into_dir = |o: &PathBuf| {
        !output::is_stdout(o)
            && (o.is_dir()
                || files.len() > 1
                || o.as_os_str()
                    .to_string_lossy()
                    .ends_with(std::path::MAIN_SEPARATOR))
    };
    let folder = a.output.as_ref().filter(|o| into_dir(o));
    let format = output::data_format(a.format, a.json, a.output.as_deref(), folder.is_some())?;
    let ext = match format {
        DataFormat::Csv => "csv",
        DataFormat::Json => "json",
        DataFormat::Npy => "npy",
    };
    // Where every prediction goes, checked against the inputs before any work.
    let targets: Vec<PathBuf> = match (&a.output, folder) {
        (None, _) if files.len() > 1 => bail!(
            "{} inputs: give -o FOLDER for one prediction file each",
            files.len()
        ),
        (None, _) => Vec::new(),
        (Some(_), Some(o)) => {
            let names: Vec<String> = files.iter().map(|f| output_name(f, ext)).collect();
            for (i, n) in names.iter().enumerate() {
                if let Some(j) = names[..i].iter().position(|m| m == n) {
                    bail!(
                        "{} and {} would both be written to {}; predict them separately",
                        files[j].display(),
                        files[i].display(),
                        o.join(n).display()
                    );
                }
            }
            names.iter().map(|n| o.join(n)).collect()
        }
        (Some(o), None) => vec![o.clone()],
    };
    let inputs: Vec<&Path> = std::iter::once(a.model.as_path())
        .chain(files.iter().map(PathBuf::as_path))
        .collect();
    output::refuse_inputs(
        &targets.iter().map(PathBuf::as_path).collect::<Vec<_>>(),
        &inputs,
    )?;
    let mf = ModelFile::load(&a.model)?;
    // Only the human's columns are read: others (a timestamp, a label) do not matter.
    let tables = read_tables_select(
        &files,
        false,
        Select::Names {
            names: &mf.layout.human_columns,
            side: &["human's"],
        },
    )?;
    let predictor = predictor(&mf)?;
    let preds = tables
        .iter()
        .map(|t| predict_table(&mf, &predictor, t, a.covariance))
        .collect::<Result<Vec<_>>>()?;
    if mf.novelty.is_none() {
        eprintln!("phasekit: note: {}", no_novelty_note(&a.model));
    }
    for (t, p) in tables.iter().zip(&preds) {
        for w in prediction_warnings(&mf, &t.path, p) {
            eprintln!("phasekit: warning: {w}");
        }
    }
    let render = |i: usize| -> Result<Vec<u8>> {
        Ok(match format {
            DataFormat::Json => prediction_json(&mf, &tables[i].path, &preds[i])?.into_bytes(),
            DataFormat::Csv => prediction_csv(&mf, &preds[i]).into_bytes(),
            DataFormat::Npy => prediction_npy(&mf, &preds[i]),
        })
    };
    match (&a.output, folder) {
        (None, _) => output::write_bytes(Path::new("-"), &render(0)?),
        (Some(o), Some(_)) => {
            let texts = (0..tables.len()).map(render).collect::<Result<Vec<_>>>()?;
            output::create_dir(o)?;
            // All files or none: an interrupted run leaves no partial set.
            let files: Vec<(PathBuf, Vec<u8>)> = targets.into_iter().zip(texts).collect();
            output::write_files_atomic(&files)
        }
        (Some(o), None) => output::write_bytes(o, &render(0)?),
    }
}
