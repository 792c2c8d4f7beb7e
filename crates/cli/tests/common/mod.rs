//! Helpers shared by the command-line tests: the binary, and generated
//! demonstrations written as CSV files.

// Every test file uses a part of this module.
#![allow(dead_code)]

use assert_cmd::Command;
use phasekit_tsc::synthetic;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

/// The `phasekit` binary of this build (or, to show that a test fails on an
/// older build, the one `PHASEKIT_BIN` names).
pub fn phasekit() -> Command {
    match std::env::var_os("PHASEKIT_BIN") {
        Some(bin) => Command::new(bin),
        None => Command::cargo_bin("phasekit").expect("the phasekit binary is built"),
    }
}

/// The path of the binary [`phasekit`] runs.
pub fn phasekit_path() -> PathBuf {
    match std::env::var_os("PHASEKIT_BIN") {
        Some(bin) => PathBuf::from(bin),
        None => assert_cmd::cargo::cargo_bin("phasekit"),
    }
}

/// Fits `method` to the folder `data` into `model` (quietly), asserting success.
pub fn fit_model(data: &Path, method: &str, model: &Path) {
    phasekit()
        .args(["fit", "--method", method, "--data"])
        .arg(data)
        .arg("-o")
        .arg(model)
        .assert()
        .success();
}

/// Writes `frames` (`T × 6`, the columns of [`synthetic::COLUMNS`]) as a CSV
/// file with a header, cell `(t, k)` written as `cell(t, k, value)`.
pub fn write_frames(
    path: &Path,
    frames: &[f64],
    cell: &mut impl FnMut(usize, usize, f64) -> String,
) {
    let mut s = synthetic::COLUMNS.join(",") + "\n";
    for (t, f) in frames.chunks_exact(6).enumerate() {
        let row: Vec<String> = f.iter().enumerate().map(|(k, v)| cell(t, k, *v)).collect();
        s += &(row.join(",") + "\n");
    }
    std::fs::write(path, s).unwrap();
}

/// Every value as Rust prints it (round-trips exactly).
pub fn plain(_: usize, _: usize, v: f64) -> String {
    v.to_string()
}

/// A folder `data/` in a new temporary directory holding the interactions of
/// `synthetic::generate(n, seed)`: the first `n_train` as `train_NN.csv`, the
/// rest as `test_NN.csv`, cells written by `cell` (see [`write_frames`]).
pub fn interaction_folder(
    n: usize,
    seed: u64,
    n_train: usize,
    mut cell: impl FnMut(usize, usize, f64) -> String,
) -> (TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir(&data).unwrap();
    for (i, demo) in synthetic::generate(n, seed).iter().enumerate() {
        let name = if i < n_train {
            format!("train_{i:02}.csv")
        } else {
            format!("test_{:02}.csv", i - n_train)
        };
        write_frames(&data.join(name), &demo.frames, &mut cell);
    }
    (dir, data)
}

/// The header and the numeric rows of a CSV text.
pub fn parse_csv(text: &str) -> (Vec<String>, Vec<Vec<f64>>) {
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(|c| c.parse().unwrap()).collect())
        .collect();
    (header, rows)
}

/// The header, the numeric rows and the statuses of `phasekit stream`'s
/// output (whose last column is `status`), with or without a header line.
pub fn parse_stream(text: &str, with_header: bool) -> (Vec<String>, Vec<Vec<f64>>, Vec<String>) {
    let mut lines = text.lines();
    let header: Vec<String> = if with_header {
        let h: Vec<String> = lines
            .next()
            .unwrap()
            .split(',')
            .map(str::to_string)
            .collect();
        assert_eq!(h.last().map(String::as_str), Some("status"), "{h:?}");
        h[..h.len() - 1].to_vec()
    } else {
        Vec::new()
    };
    let (mut rows, mut status) = (Vec::new(), Vec::new());
    for l in lines {
        let (values, s) = l.rsplit_once(',').unwrap();
        rows.push(values.split(',').map(|c| c.parse().unwrap()).collect());
        status.push(s.to_string());
    }
    (header, rows, status)
}

/// A model file's JSON.
pub fn model_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The paper's features of the generated interactions: both wrists, with
/// velocities.
pub fn wrist_spec() -> phasekit_cli::data::FeatureSpec {
    phasekit_cli::data::FeatureSpec {
        human: vec!["p1_wrist_*".into()],
        robot: vec!["p2_wrist_*".into()],
        velocity: phasekit_cli::data::Velocity::Both,
    }
}

/// The methods of `labels`, with the default settings.
pub fn methods(labels: &[&str]) -> Vec<phasekit_cli::experiment::NamedMethod> {
    labels
        .iter()
        .map(|m| {
            phasekit_cli::experiment::parse_method(m, &phasekit_tsc::PresetOptions::default())
                .unwrap()
        })
        .collect()
}

/// `evaluate_action` of the action folder `data` with `labels` and `protocol`.
pub fn evaluate_rows(
    data: &Path,
    labels: &[&str],
    protocol: &phasekit_cli::experiment::Protocol,
) -> Vec<phasekit_cli::experiment::Row> {
    let action = phasekit_cli::data::load_action(data).unwrap();
    phasekit_cli::experiment::evaluate_action(
        &action,
        &wrist_spec(),
        &methods(labels),
        protocol,
        &|| {},
    )
    .unwrap()
}

/// The standard output of `cmd`, which must succeed.
pub fn stdout(cmd: &mut Command) -> String {
    let out = cmd.assert().success().get_output().stdout.clone();
    String::from_utf8(out).unwrap()
}
