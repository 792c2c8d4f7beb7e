//! Input the model cannot explain is reported, never silently predicted from:
//! human data unlike the training demonstrations (another coordinate frame,
//! millimetres given to a metre model) is flagged out of distribution by a
//! threshold calibrated at fit time; a value no state can explain (1e200) is
//! taken as not observed, and later frames are predicted and segmented as if
//! it had been missing; a model whose means are 1e200 is refused.

use crate::common;

use common::{
    fit_model, interaction_folder, parse_csv, parse_stream, phasekit, plain, write_frames,
};
use phasekit_tsc::synthetic;
use predicates::prelude::*;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

fn setup(method: &str) -> (TempDir, PathBuf, PathBuf) {
    let (dir, data) = interaction_folder(10, 3, 8, plain);
    let model = dir.path().join("m.json");
    fit_model(&data, method, &model);
    (dir, data, model)
}

/// `predict --json` of a file: (frames, out-of-distribution frames, rejected frames, stderr).
fn predict_json(model: &Path, file: &Path) -> (usize, Vec<usize>, Vec<usize>, String) {
    let out = phasekit()
        .args(["predict", "--json", "--model"])
        .arg(model)
        .arg("--data")
        .arg(file)
        .assert()
        .success()
        .get_output()
        .clone();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let list = |k: &str| -> Vec<usize> {
        v[k].as_array()
            .unwrap_or_else(|| panic!("no {k} in {v}"))
            .iter()
            .map(|x| x.as_u64().unwrap() as usize)
            .collect()
    };
    (
        v["mean"].as_array().unwrap().len(),
        list("out_of_distribution"),
        list("rejected"),
        String::from_utf8(out.stderr).unwrap(),
    )
}

/// Generated demonstrations seen in another coordinate frame (rotated a
/// quarter turn about the vertical axis and moved 0.8 m, as NuiSI's skeletons
/// are relative to the generated data's), or in other units.
fn transformed(dir: &Path, name: &str, f: impl Fn([f64; 3]) -> [f64; 3]) -> PathBuf {
    let demo = &synthetic::generate(2, 99)[1];
    let frames: Vec<f64> = demo
        .frames
        .chunks_exact(6)
        .flat_map(|r| {
            let (a, b) = (f([r[0], r[1], r[2]]), f([r[3], r[4], r[5]]));
            [a, b].concat()
        })
        .collect();
    let path = dir.join(name);
    write_frames(&path, &frames, &mut plain);
    path
}

#[test]
fn data_in_another_coordinate_frame_is_flagged_and_the_models_own_test_data_is_not() {
    let (dir, data, model) = setup("hmm");
    let calib = &common::model_json(&model)["novelty"];
    assert!(calib["threshold"].as_f64().unwrap() < calib["low"].as_f64().unwrap());
    assert!(calib["frames"].as_u64().unwrap() > 500);
    for i in 0..2 {
        let (n, ood, rejected, stderr) =
            predict_json(&model, &data.join(format!("test_{i:02}.csv")));
        assert!(n > 50);
        assert!(
            ood.is_empty() && rejected.is_empty(),
            "test_{i:02}: {ood:?}"
        );
        assert!(!stderr.contains("warning"), "{stderr}");
    }
    let other = transformed(dir.path(), "other_frame.csv", |[x, y, z]| {
        [0.8 - y, x + 0.3, z + 0.9]
    });
    let (n, ood, _, stderr) = predict_json(&model, &other);
    assert!(ood.len() * 10 >= n * 9, "{} of {n} flagged", ood.len());
    assert!(stderr.contains("out of distribution") && stderr.contains("another coordinate frame"));
    // Millimetres given to a metre model (the robot was predicted ~92 m away): flagged.
    let mm = transformed(dir.path(), "millimetres.csv", |v| v.map(|c| c * 1000.0));
    let (n, ood, _, _) = predict_json(&model, &mm);
    assert!(ood.len() * 10 >= n * 9, "{} of {n} flagged", ood.len());
    // The stream says so on every such frame.
    let text = std::fs::read_to_string(&other).unwrap();
    let human: String = text
        .lines()
        .map(|l| l.split(',').take(3).collect::<Vec<_>>().join(",") + "\n")
        .collect();
    let out = phasekit()
        .args(["stream", "--model"])
        .arg(&model)
        .write_stdin(human)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let (_, rows, status) = parse_stream(&String::from_utf8(out).unwrap(), true);
    assert_eq!(rows.len(), n);
    assert_eq!(status.iter().filter(|s| *s == "ood").count(), {
        let (_, ood, _, _) = predict_json(&model, &other);
        ood.len()
    });
}

#[test]
fn a_model_file_without_the_calibration_still_loads() {
    let (_dir, data, model) = setup("hmm");
    let mut v = common::model_json(&model);
    v.as_object_mut().unwrap().remove("novelty");
    std::fs::write(&model, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    phasekit()
        .args(["predict", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(data.join("test_00.csv"))
        .assert()
        .success()
        .stderr(predicate::str::contains("no out-of-distribution threshold"));
}

/// A copy of `file` with the human's value `(row, col)` replaced by `cell`,
/// and one with the whole row (`whole`) or the human's part empty.
fn with_cell(file: &Path, out: &Path, row: usize, col: usize, cell: &str) {
    let mut lines: Vec<String> = std::fs::read_to_string(file)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect();
    let mut cells: Vec<String> = lines[row + 1].split(',').map(str::to_string).collect();
    cells[col] = cell.into();
    lines[row + 1] = cells.join(",");
    std::fs::write(out, lines.join("\n") + "\n").unwrap();
}

fn with_empty_row(file: &Path, out: &Path, row: usize, cols: usize) {
    let mut lines: Vec<String> = std::fs::read_to_string(file)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect();
    let mut cells: Vec<String> = lines[row + 1].split(',').map(str::to_string).collect();
    cells[..cols].iter_mut().for_each(|c| c.clear());
    lines[row + 1] = cells.join(",");
    std::fs::write(out, lines.join("\n") + "\n").unwrap();
}

fn run_csv(args: &[&str], model: &Path, file: &Path) -> (Vec<Vec<f64>>, String) {
    let out = phasekit()
        .args(args)
        .arg("--model")
        .arg(model)
        .arg("--data")
        .arg(file)
        .assert()
        .success()
        .get_output()
        .clone();
    (
        parse_csv(&String::from_utf8(out.stdout).unwrap()).1,
        String::from_utf8(out.stderr).unwrap(),
    )
}

#[test]
fn a_huge_value_is_taken_as_not_observed_and_later_frames_recover() {
    for method in ["hmm", "tsc-hmm", "gmm"] {
        let (dir, data, model) = setup(method);
        let test = data.join("test_00.csv");
        let (big, empty) = (dir.path().join("big.csv"), dir.path().join("empty.csv"));
        with_cell(&test, &big, 3, 0, "1e200");
        with_empty_row(&test, &empty, 3, 3);
        let (got, stderr) = run_csv(&["predict", "--covariance"], &model, &big);
        let (want, _) = run_csv(&["predict", "--covariance"], &model, &empty);
        assert!(
            stderr.contains("frame 3 has density zero under every state"),
            "{method}: {stderr}"
        );
        assert_eq!(got.len(), want.len());
        for (t, (a, b)) in got.iter().zip(&want).enumerate() {
            assert!(
                a[1..4].iter().any(|v| *v != 0.0),
                "{method}: frame {t} zeroed"
            );
            for (x, y) in a.iter().zip(b) {
                assert!(
                    (x - y).abs() <= 1e-9 * (1.0 + y.abs()),
                    "{method}: frame {t}: {x} vs {y}"
                );
            }
        }
        // Segmentation: every frame labelled as with that frame missing, not state 0 ever after.
        with_empty_row(&test, &empty, 3, 6);
        let seg = |f: &Path| {
            let out = phasekit()
                .args(["segment", "--json", "--model"])
                .arg(&model)
                .arg("--data")
                .arg(f)
                .assert()
                .success()
                .get_output()
                .clone();
            let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            (
                v[0]["states"].clone(),
                String::from_utf8(out.stderr).unwrap(),
            )
        };
        let ((a, warn), (b, _)) = (seg(&big), seg(&empty));
        assert_eq!(a, b, "{method}");
        assert!(
            warn.contains("frame 3 has density zero"),
            "{method}: {warn}"
        );
        let states: Vec<u64> = a
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s.as_u64().unwrap())
            .collect();
        assert!(
            states[10..].iter().any(|s| *s != states[10]),
            "{method}: one state ever after: {states:?}"
        );
    }
}

#[test]
fn a_model_whose_means_are_1e200_is_refused() {
    let (dir, data, model) = setup("hmm");
    let mut v = common::model_json(&model);
    let means = &mut v["model"]["emission"]["means"];
    let first = means
        .as_array_mut()
        .map(|a| &mut a[0])
        .expect("an array of means");
    *first = serde_json::json!(1e200);
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, serde_json::to_string(&v).unwrap()).unwrap();
    phasekit()
        .args(["predict", "--model"])
        .arg(&bad)
        .arg("--data")
        .arg(data.join("test_00.csv"))
        .assert()
        .failure()
        .stdout("")
        .stderr(
            predicate::str::contains("bad.json: corrupted model file")
                .and(predicate::str::contains("state 0, dimension 0: mean 1e200")),
        );
}
