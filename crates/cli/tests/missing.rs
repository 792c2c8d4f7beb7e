//! Missing values through the command: empty cells, `NaN` and `NA` are "not
//! observed"; `stream --on-bad-line missing` takes empty or malformed lines as
//! frames with nothing observed and keeps going (by default such a line stops
//! the stream: see `tests/stream.rs`).

use crate::common;

use common::{interaction_folder, parse_csv, parse_stream, phasekit};
use predicates::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

/// A folder `data/` with 8 training and 3 test demonstrations, about `frac`
/// of their cells emptied (and, on every fifth row, one cell written as `NaN`
/// and one as `NA`).
fn dataset(frac: f64) -> (TempDir, PathBuf) {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    interaction_folder(11, 7, 8, move |t, k, v| {
        if frac > 0.0 && t % 5 == 4 && k == 1 {
            "NaN".into()
        } else if frac > 0.0 && t % 5 == 4 && k == 4 {
            "NA".into()
        } else if rng.random::<f64>() < frac {
            String::new()
        } else {
            v.to_string()
        }
    })
}

fn rows(text: &str) -> Vec<Vec<f64>> {
    parse_csv(text).1
}

#[test]
fn fit_predict_evaluate_accept_missing_cells() {
    let (dir, data) = dataset(0.1);
    let model = dir.path().join("m.json");
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();
    let test = data.join("test_00.csv");
    let out = phasekit()
        .args(["predict", "--covariance", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let pred = rows(&String::from_utf8(out).unwrap());
    let n_frames = std::fs::read_to_string(&test).unwrap().lines().count() - 1;
    assert_eq!(
        pred.len(),
        n_frames,
        "one prediction per frame, missing or not"
    );
    assert!(pred.iter().flatten().all(|v| v.is_finite()));
    let out = phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm",
            "--seeds",
            "2",
            "--format",
            "json",
            "--data",
        ])
        .arg(&data)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    let mse = report["results"][0]["mse_mean"].as_f64().unwrap();
    assert!(mse.is_finite() && mse > 0.0, "{report}");
    phasekit()
        .args(["segment", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test)
        .assert()
        .success();
}

#[test]
fn missing_cells_predict_close_to_complete_ones() {
    let (dir, complete) = dataset(0.0);
    let (_dir2, dropped) = dataset(0.1);
    let fit_eval = |data: &Path| -> f64 {
        let out = phasekit()
            .args([
                "evaluate",
                "--methods",
                "hmm",
                "--train-size",
                "100",
                "--format",
                "json",
                "--data",
            ])
            .arg(data)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone();
        let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
        report["results"][0]["mse_mean"].as_f64().unwrap()
    };
    let (a, b) = (fit_eval(&complete), fit_eval(&dropped));
    assert!(b < 1.5 * a, "10 % missing cells: MSE {b} vs complete {a}");
    drop(dir);
}

#[test]
fn stream_takes_bad_lines_as_frames_with_nothing_observed() {
    let (dir, data) = dataset(0.0);
    let model = dir.path().join("m.json");
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();
    let raw = std::fs::read_to_string(data.join("test_01.csv")).unwrap();
    let lines: Vec<&str> = raw.lines().collect();
    // The same demonstration with bad lines in it, and as a CSV with those
    // frames empty: the stream must predict exactly what `predict` does on it.
    let mut input: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    let mut table: Vec<String> = input.clone();
    let empty = ",,,,,";
    for (at, bad) in [
        (12, "0.1,oops,0.3,0.1,0.2,0.3"),
        (20, "0.1,0.2"),
        (31, ""),
        (40, "1,2,inf,4,5,6"),
    ] {
        input.insert(at, bad.to_string());
        table.insert(at, empty.to_string());
    }
    // A partially observed frame is used with what it has, silently.
    let partial = lines[50]
        .split(',')
        .enumerate()
        .map(|(k, c)| if k == 1 { "" } else { c })
        .collect::<Vec<_>>()
        .join(",");
    input[54] = partial.clone();
    table[54] = partial;
    let file = dir.path().join("with_gaps.csv");
    std::fs::write(&file, table.join("\n") + "\n").unwrap();
    let batch = phasekit()
        .args(["predict", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&file)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let batch = rows(&String::from_utf8(batch).unwrap());
    let out = phasekit()
        .args(["stream", "--on-bad-line", "missing", "--model"])
        .arg(&model)
        .write_stdin(input.join("\n") + "\n")
        .assert()
        .success()
        .stderr(
            predicate::str::contains("stdin line 13: column 2 (`p1_wrist_y`): not a number")
                .and(predicate::str::contains(
                    "stdin line 21: 2 values, expected 6",
                ))
                .and(predicate::str::contains("stdin line 32: a blank line"))
                .and(predicate::str::contains("stdin line 41: column 3"))
                .and(predicate::str::contains(
                    "taken as a frame with nothing observed",
                ))
                .and(predicate::str::contains(
                    "4 bad lines taken as frames with nothing observed",
                ))
                .and(predicate::str::contains("line 55").not()),
        )
        .get_output()
        .stdout
        .clone();
    let (_, streamed, status) = parse_stream(&String::from_utf8(out).unwrap(), true);
    assert_eq!(streamed.len(), batch.len());
    assert_eq!(streamed.len(), lines.len() - 1 + 4);
    for (a, b) in batch.iter().zip(&streamed) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-9 * (1.0 + x.abs()), "{x} vs {y}");
        }
    }
    // The frames made of bad lines say so; the partially observed one is ok.
    for (t, s) in status.iter().enumerate() {
        let bad = [11, 19, 30, 39].contains(&t);
        assert_eq!(s, if bad { "unobserved" } else { "ok" }, "frame {t}");
    }
}

#[test]
fn infinity_is_still_refused() {
    let (dir, data) = dataset(0.0);
    let file = data.join("train_00.csv");
    let mut text: Vec<String> = std::fs::read_to_string(&file)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect();
    text[3] = "0,1,inf,0,0,0".into();
    std::fs::write(&file, text.join("\n")).unwrap();
    phasekit()
        .args(["fit", "--method", "hmm", "-o"])
        .arg(dir.path().join("m.json"))
        .arg("--data")
        .arg(&data)
        .assert()
        .failure()
        .stderr(
            predicate::str::contains("train_00.csv")
                .and(predicate::str::contains("row 4"))
                .and(predicate::str::contains("infinity")),
        );
    assert!(!dir.path().join("m.json").exists());
}

#[test]
fn removing_nothing_is_bit_identical_to_the_plain_path() {
    let (_dir, data) = dataset(0.0);
    let per_seed = |extra: &[&str]| -> Vec<serde_json::Value> {
        let out = phasekit()
            .args([
                "evaluate",
                "--methods",
                "hmm,tsc-hmm:window=2",
                "--seeds",
                "3",
                "--format",
                "json",
            ])
            .args(extra)
            .arg("--data")
            .arg(&data)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone();
        let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
        report["results"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["per_seed_mse"].clone())
            .collect()
    };
    let plain = per_seed(&[]);
    assert_eq!(plain, per_seed(&["--missing", "0"]));
    // And removing something changes the numbers (the option is not a no-op).
    assert_ne!(plain, per_seed(&["--missing", "0.2"]));
}
