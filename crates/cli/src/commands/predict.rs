//! `phasekit predict`.

use super::{data_files, read_tables};
use crate::bail;
use crate::cli::{Format, PredictArgs};
use crate::error::Result;
use crate::model_file::ModelFile;
use crate::output;
use crate::pipeline::{
    predict_table, prediction_header, prediction_line, predictor, RobotPrediction,
};
use std::path::{Path, PathBuf};

/// The CSV text of a prediction.
pub fn prediction_csv(mf: &ModelFile, p: &RobotPrediction) -> String {
    let mut s = prediction_header(mf, p.covariance.is_some()).join(",");
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

/// Runs `phasekit predict`.
pub fn run(a: &PredictArgs) -> Result<()> {
    let mf = ModelFile::load(&a.model)?;
    let files = data_files(&a.data)?;
    let tables = read_tables(&files, false)?;
    let predictor = predictor(&mf)?;
    let preds = tables
        .iter()
        .map(|t| predict_table(&mf, &predictor, t, a.covariance))
        .collect::<Result<Vec<_>>>()?;
    let format = if a.json { Format::Json } else { a.format };
    if format == Format::Md {
        bail!("predict writes csv or json, not md");
    }
    let json = format == Format::Json;
    let render = |i: usize| -> Result<String> {
        if json {
            prediction_json(&mf, &tables[i].path, &preds[i])
        } else {
            Ok(prediction_csv(&mf, &preds[i]))
        }
    };
    let into_dir = |o: &PathBuf| {
        o.is_dir()
            || tables.len() > 1
            || o.as_os_str()
                .to_string_lossy()
                .ends_with(std::path::MAIN_SEPARATOR)
    };
    match &a.output {
        None if tables.len() > 1 => bail!(
            "{} inputs: give -o FOLDER for one prediction file each",
            tables.len()
        ),
        None => output::print_stdout(&render(0)?),
        Some(o) if into_dir(o) => {
            let mut names: Vec<String> = tables
                .iter()
                .map(|t| output_name(&t.path, if json { "json" } else { "csv" }))
                .collect();
            let mut seen = std::collections::HashSet::new();
            for (n, t) in names.iter_mut().zip(&tables) {
                if !seen.insert(n.clone()) {
                    bail!("two inputs would both be written to {} ({} and another); predict them separately", o.join(&n).display(), t.path.display());
                }
            }
            let texts = (0..tables.len()).map(render).collect::<Result<Vec<_>>>()?;
            output::create_dir(o)?;
            // All files or none: an interrupted run leaves no partial set.
            let files: Vec<(PathBuf, String)> =
                names.iter().map(|n| o.join(n)).zip(texts).collect();
            output::write_files_atomic(&files)
        }
        Some(o) => output::write_string(o, &render(0)?),
    }
}
