//! End-to-end tests of the `phasekit` command on generated interactions.

use crate::common;

use common::{interaction_folder, parse_csv, phasekit, plain};
use phasekit_cli::data::{read_table, FeatureSpec, Velocity};
use phasekit_cli::model_file::ModelFile;
use phasekit_cli::pipeline::{predict_table, predictor};
use phasekit_tsc::{synthetic, PresetOptions};
use predicates::prelude::*;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

/// The TSC-HMM used in the tests: generated interactions need a dilation to
/// give the transition HMM runs to train on.
const TSC: &str = "tsc-hmm:window=2";

fn write_csv(path: &Path, header: &str, rows: &[Vec<String>]) {
    let mut s = format!("{header}\n");
    for r in rows {
        s.push_str(&r.join(","));
        s.push('\n');
    }
    std::fs::write(path, s).unwrap();
}

fn rows_of(frames: &[f64]) -> Vec<Vec<String>> {
    frames
        .chunks_exact(6)
        .map(|f| f.iter().map(|v| v.to_string()).collect())
        .collect()
}

/// A folder `data/` with 8 training and 3 test demonstrations.
fn dataset() -> (TempDir, PathBuf) {
    interaction_folder(11, 7, 8, plain)
}

fn fit(data: &Path, method: &str, out: &Path) {
    phasekit()
        .args(["fit", "--method", method, "--data"])
        .arg(data)
        .arg("-o")
        .arg(out)
        .assert()
        .success();
}

/// No file but the given ones (and no temporary file) in `dir`.
fn only_files(dir: &Path, expected: &[&str]) {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let mut want: Vec<String> = expected.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(names, want, "files in {}", dir.display());
}

#[test]
fn fit_predict_evaluate_round_trip() {
    let (dir, data) = dataset();
    let model = dir.path().join("model.json");
    let out = phasekit()
        .args(["fit", "--method", TSC, "--format", "json", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    let iterations = report["iterations"].as_u64().unwrap();
    assert!(iterations >= 1);
    assert!(report["log_likelihood"].as_array().unwrap().len() as u64 >= iterations);
    assert!(report["fit_seconds"].as_f64().unwrap() >= 0.0);
    assert_eq!(report["states"], 7);
    assert_eq!(
        report["demonstrations"].as_array().unwrap().len(),
        8,
        "a folder means its train_* files"
    );

    let text = std::fs::read_to_string(&model).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(json["format"], "phasekit-model");
    assert_eq!(json["version"], 1);
    for key in [
        "layout",
        "feature_spec",
        "standardisation",
        "roles",
        "method",
        "model",
    ] {
        assert!(json.get(key).is_some(), "model file has `{key}`");
    }

    // One input to stdout: frames and robot features.
    let test0 = data.join("test_00.csv");
    let out = phasekit()
        .args(["predict", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test0)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let (header, rows) = parse_csv(&String::from_utf8(out).unwrap());
    assert_eq!(
        header,
        [
            "frame",
            "p2_wrist_x",
            "p2_wrist_y",
            "p2_wrist_z",
            "d_p2_wrist_x",
            "d_p2_wrist_y",
            "d_p2_wrist_z"
        ]
    );
    assert_eq!(rows.len(), read_table(&test0).unwrap().n_rows());
    assert!(rows
        .iter()
        .enumerate()
        .all(|(t, r)| r[0] == t as f64 && r.iter().all(|v| v.is_finite())));

    // Several inputs into a folder, with covariance.
    let preds = dir.path().join("preds");
    let tests: Vec<PathBuf> = (0..3)
        .map(|i| data.join(format!("test_{i:02}.csv")))
        .collect();
    phasekit()
        .args(["predict", "--covariance", "--model"])
        .arg(&model)
        .arg("--data")
        .args(&tests)
        .arg("-o")
        .arg(&preds)
        .assert()
        .success();
    only_files(
        &preds,
        &[
            "test_00.predicted.csv",
            "test_01.predicted.csv",
            "test_02.predicted.csv",
        ],
    );
    let (header, rows) =
        parse_csv(&std::fs::read_to_string(preds.join("test_01.predicted.csv")).unwrap());
    assert_eq!(header.len(), 1 + 6 + 21);
    assert!(
        header.contains(&"var_p2_wrist_x".to_string())
            && header.contains(&"cov_p2_wrist_x_p2_wrist_y".to_string())
    );
    assert!(rows.iter().all(|r| r[7] > 0.0), "variances are positive");

    // Evaluate with few seeds, JSON on stdout, Markdown and JSON files.
    let prefix = dir.path().join("results");
    let out = phasekit()
        .args([
            "evaluate",
            "--methods",
            &format!("hmm,{TSC}"),
            "--seeds",
            "3",
            "--format",
            "json",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(&prefix)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert!(report["metric"]
        .as_str()
        .unwrap()
        .contains("squared Euclidean error"));
    assert_eq!(report["protocol"]["seeds"], 3);
    let results = report["results"].as_array().unwrap();
    assert_eq!(results.len(), 3, "two methods and the constant baseline");
    for r in results {
        for key in [
            "action",
            "method",
            "mse_mean",
            "mse_std",
            "rmse_mean",
            "rmse_std",
            "seeds",
        ] {
            assert!(r.get(key).is_some(), "row has `{key}`");
        }
    }
    assert_eq!(results[0]["method"], "hmm");
    assert_eq!(results[0]["seeds"], 3);
    assert_eq!(results[1]["method"], TSC);
    assert!(results[1]["paired_change"].is_number() && results[1]["paired_won"].is_number());
    assert_eq!(results[2]["method"], "constant-mean");
    assert!(results[0]["mse_mean"].as_f64().unwrap() < results[2]["mse_mean"].as_f64().unwrap());
    let md = std::fs::read_to_string(dir.path().join("results.md")).unwrap();
    assert!(md.starts_with("| action | method | states | MSE (cm²)"));
    assert!(md.contains("| data | constant-mean |"));
    let saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("results.json")).unwrap())
            .unwrap();
    assert_eq!(saved, report);

    // The default output is the Markdown table.
    phasekit()
        .args(["evaluate", "--methods", "hmm", "--seeds", "2", "--data"])
        .arg(&data)
        .assert()
        .success()
        .stdout(
            predicate::str::starts_with("| action | method |")
                .and(predicate::str::contains("| data | hmm | 4 |")),
        );
}

#[test]
fn model_file_round_trips() {
    let (dir, data) = dataset();
    let model = dir.path().join("m.json");
    phasekit()
        .args(["fit", "--method", TSC, "--standardise", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();

    // The same fit in-process.
    let train: Vec<_> = (0..8)
        .map(|i| read_table(&data.join(format!("train_{i:02}.csv"))).unwrap())
        .collect();
    let spec = FeatureSpec {
        human: vec!["p1_wrist_*".into()],
        robot: vec!["p2_wrist_*".into()],
        velocity: Velocity::Both,
    };
    let fitted = phasekit_cli::commands::fit::fit_tables(
        &train,
        &spec,
        false,
        TSC,
        &PresetOptions::default(),
        true,
    )
    .unwrap();
    let loaded = ModelFile::load(&model).unwrap();
    assert!(loaded.standardisation.is_some());
    let without_time = |m: &ModelFile| {
        let mut v: serde_json::Value = serde_json::from_str(&m.to_json().unwrap()).unwrap();
        v["fit"]["fit_seconds"] = serde_json::Value::Null;
        v
    };
    assert!(
        without_time(&loaded) == without_time(&fitted),
        "the saved and loaded model is the one fitted in-process"
    );

    let test = read_table(&data.join("test_02.csv")).unwrap();
    let a = predict_table(&fitted, &predictor(&fitted).unwrap(), &test, true).unwrap();
    let b = predict_table(&loaded, &predictor(&loaded).unwrap(), &test, true).unwrap();
    assert_eq!(
        a, b,
        "a loaded model predicts bit for bit as the fitted one"
    );

    let out = phasekit()
        .args(["predict", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test.path)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let (_, rows) = parse_csv(&String::from_utf8(out).unwrap());
    for (t, r) in rows.iter().enumerate() {
        assert_eq!(&r[1..], &a.mean[t * 6..(t + 1) * 6], "frame {t}");
    }
}

#[test]
fn segment_output_is_well_formed() {
    let (dir, data) = dataset();
    let model = dir.path().join("m.json");
    fit(&data, TSC, &model);
    let files: Vec<PathBuf> = (0..2)
        .map(|i| data.join(format!("test_{i:02}.csv")))
        .collect();
    let out = phasekit()
        .args(["segment", "--model"])
        .arg(&model)
        .arg("--data")
        .args(&files)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let text = String::from_utf8(out).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("file,frame,state,transition,cluster"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let lens: Vec<usize> = files
        .iter()
        .map(|f| read_table(f).unwrap().n_rows())
        .collect();
    assert_eq!(rows.len(), lens.iter().sum::<usize>());
    let mut transitions = 0;
    for (k, f) in files.iter().enumerate() {
        let mine: Vec<&Vec<&str>> = rows
            .iter()
            .filter(|r| Path::new(r[0]) == f.as_path())
            .collect();
        assert_eq!(mine.len(), lens[k]);
        for (t, r) in mine.iter().enumerate() {
            assert_eq!(r.len(), 5);
            assert_eq!(r[1].parse::<usize>().unwrap(), t);
            // The states of the model that predicts: the union's 4 + 3.
            assert!(r[2].parse::<usize>().unwrap() < 7, "union states 0..7");
            match r[3] {
                "0" => assert_eq!(r[4], "", "a cluster only on transition frames"),
                "1" => {
                    transitions += 1;
                    assert!(r[4].is_empty() || r[4].parse::<usize>().unwrap() < 3);
                }
                other => panic!("transition flag {other}"),
            }
        }
    }
    assert!(transitions > 0, "some transition frames are found");

    let seg = dir.path().join("seg.json");
    phasekit()
        .args(["segment", "--format", "json", "--model"])
        .arg(&model)
        .arg("--data")
        .args(&files)
        .arg("-o")
        .arg(&seg)
        .assert()
        .success()
        .stdout("");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&seg).unwrap()).unwrap();
    let v = v.as_array().unwrap();
    assert_eq!(v.len(), 2);
    for (k, s) in v.iter().enumerate() {
        assert_eq!(s["states"].as_array().unwrap().len(), lens[k]);
        assert_eq!(s["frames"], lens[k]);
        assert_eq!(
            s["transitions"].as_array().unwrap().len(),
            s["clusters"].as_array().unwrap().len()
        );
    }
}

#[test]
fn stream_matches_predict_and_survives_bad_lines() {
    let (dir, data) = dataset();
    let model = dir.path().join("m.json");
    fit(&data, TSC, &model);
    let test = data.join("test_01.csv");
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
    let (header, batch) = parse_csv(&String::from_utf8(out).unwrap());

    // Full rows with a header (the human's columns are picked by name), a
    // `#reset` line (a new demonstration) and a comment before them.
    let raw = std::fs::read_to_string(&test).unwrap();
    let mut input: Vec<&str> = raw.lines().collect();
    input.insert(20, "# a comment");
    input.insert(1, "#reset");
    let out = phasekit()
        .args(["stream", "--covariance", "--model"])
        .arg(&model)
        .write_stdin(input.join("\n") + "\n")
        .assert()
        .success()
        .stderr(predicate::str::contains("p99").and(predicate::str::contains("warning").not()))
        .get_output()
        .stdout
        .clone();
    let (sheader, streamed, status) = common::parse_stream(&String::from_utf8(out).unwrap(), true);
    assert_eq!(sheader, header);
    assert!(status.iter().all(|s| s == "ok"), "{status:?}");
    assert_eq!(streamed.len(), batch.len());
    for (a, b) in batch.iter().zip(&streamed) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-9 * (1.0 + x.abs()), "{x} vs {y}");
        }
    }

    // Just the human's values, no header.
    let human: String = raw
        .lines()
        .skip(1)
        .map(|l| l.split(',').take(3).collect::<Vec<_>>().join(",") + "\n")
        .collect();
    let out = phasekit()
        .args(["stream", "--quiet", "--no-header", "--model"])
        .arg(&model)
        .write_stdin(human)
        .assert()
        .success()
        .stderr("")
        .get_output()
        .stdout
        .clone();
    let (_, streamed, _) = common::parse_stream(&String::from_utf8(out).unwrap(), false);
    assert_eq!(streamed.len(), batch.len());
    for (a, b) in batch.iter().zip(&streamed) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-9 * (1.0 + x.abs()));
        }
    }
}

/// A command that must fail with `message` in stderr, writing nothing.
fn refused(dir: &Path, args: &[&str], message: &[&str]) {
    let before: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    let mut cmd = phasekit();
    cmd.current_dir(dir).args(args);
    let mut assert = cmd.assert().failure().code(1).stdout("");
    for m in message {
        assert = assert.stderr(predicate::str::contains(*m));
    }
    let _ = assert;
    let after: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(before, after, "no file written for {args:?}");
}

#[test]
fn bad_inputs_are_refused_with_located_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let demos = synthetic::generate(3, 1);
    let header = synthetic::COLUMNS.join(",");
    let good = rows_of(&demos[0].frames);
    write_csv(&d.join("good.csv"), &header, &good);
    write_csv(&d.join("good2.csv"), &header, &rows_of(&demos[1].frames));
    let with = |name: &str, row: usize, col: usize, cell: &str| {
        let mut rows = good.clone();
        rows[row][col] = cell.into();
        write_csv(&d.join(name), &header, &rows);
    };
    with("text.csv", 3, 1, "abc");
    with("inf.csv", 5, 4, "inf");
    with("nan.csv", 6, 2, "-infinity");
    let mut ragged = good.clone();
    ragged[7].pop();
    write_csv(&d.join("ragged.csv"), &header, &ragged);
    write_csv(
        &d.join("dup.csv"),
        "p1_wrist_x,p1_wrist_y,p1_wrist_x,p2_wrist_x,p2_wrist_y,p2_wrist_z",
        &good,
    );
    std::fs::write(d.join("empty.csv"), "").unwrap();
    std::fs::write(d.join("header.csv"), format!("{header}\n")).unwrap();
    write_csv(&d.join("short.csv"), &header, &good[..3]);
    write_csv(
        &d.join("other.csv"),
        "p1_wrist_x,p1_wrist_y,p1_wrist_z,p2_wrist_x,p2_wrist_y,p2_elbow_z",
        &good,
    );
    let fit = |file: &str| -> Vec<String> {
        ["fit", "--method", "hmm", "-o", "m.json", "--data", file]
            .iter()
            .map(|s| s.to_string())
            .collect()
    };
    let run = |args: Vec<String>, msg: &[&str]| {
        refused(d, &args.iter().map(String::as_str).collect::<Vec<_>>(), msg)
    };

    run(
        fit("text.csv"),
        &[
            "text.csv",
            "row 5",
            "column 2",
            "p1_wrist_y",
            "not a number",
            "abc",
        ],
    );
    run(
        fit("inf.csv"),
        &["inf.csv", "row 7", "column 5", "not a finite number"],
    );
    run(
        fit("nan.csv"),
        &["nan.csv", "row 8", "column 3", "not a finite number"],
    );
    run(
        fit("ragged.csv"),
        &["ragged.csv", "row 9 has 5 cells, the header has 6"],
    );
    run(
        fit("dup.csv"),
        &["dup.csv", "`p1_wrist_x` appears twice", "columns 1 and 3"],
    );
    run(fit("empty.csv"), &["empty.csv", "no header row"]);
    run(fit("header.csv"), &["header.csv", "no data rows"]);
    run(
        fit("short.csv"),
        &["short.csv", "3 frames, fewer than the 4 states"],
    );
    let mut two = fit("good.csv");
    two.push("other.csv".into());
    run(
        two,
        &[
            "other.csv",
            "columns differ from those of",
            "good.csv",
            "p2_elbow_z",
        ],
    );
    let mut unknown = fit("good.csv");
    unknown.extend([
        "--human".into(),
        "nose_*".into(),
        "--robot".into(),
        "p2_*".into(),
    ]);
    run(
        unknown,
        &["good.csv", "no column matches `nose_*`", "p1_wrist_x"],
    );
    run(fit("missing.csv"), &["missing.csv", "no such file"]);
    run(
        [
            "fit", "--method", "nope", "-o", "m.json", "--data", "good.csv",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect(),
        &["unknown preset `nope`"],
    );

    // Model files: corrupted, foreign, of another version.
    phasekit()
        .current_dir(d)
        .args([
            "fit",
            "--method",
            "hmm",
            "-o",
            "model.json",
            "--data",
            "good.csv",
            "good2.csv",
        ])
        .assert()
        .success();
    let text = std::fs::read_to_string(d.join("model.json")).unwrap();
    std::fs::write(d.join("truncated.json"), &text[..text.len() / 2]).unwrap();
    std::fs::write(
        d.join("foreign.json"),
        r#"{"name": "something else", "weights": [1, 2]}"#,
    )
    .unwrap();
    std::fs::write(
        d.join("v6.json"),
        text.replacen("\"version\": 1", "\"version\": 6", 1),
    )
    .unwrap();
    std::fs::write(
        d.join("broken.json"),
        text.replacen("\"kind\": \"hmm\"", "\"kind\": \"hmmm\"", 1),
    )
    .unwrap();
    let predict = |model: &str| -> Vec<String> {
        [
            "predict", "--model", model, "--data", "good.csv", "-o", "out.csv",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    };
    run(
        predict("truncated.json"),
        &["truncated.json", "not a phasekit model file", "truncated"],
    );
    run(
        predict("foreign.json"),
        &["foreign.json", "not a phasekit model file"],
    );
    run(
        predict("v6.json"),
        &[
            "v6.json",
            "version 6 is not supported",
            "reads versions 1 to 5",
        ],
    );
    run(
        predict("broken.json"),
        &["broken.json", "corrupted model file"],
    );
    run(
        predict("good.csv"),
        &["good.csv", "not a phasekit model file"],
    );
    // Predicting a file without the model's human columns.
    write_csv(
        &d.join("robotonly.csv"),
        "a,b,c",
        &[vec!["1".into(), "2".into(), "3".into()]],
    );
    run(
        [
            "predict",
            "--model",
            "model.json",
            "--data",
            "robotonly.csv",
            "-o",
            "out.csv",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect(),
        &["robotonly.csv", "needs the human's column `p1_wrist_x`"],
    );
    // Usage errors exit with 2.
    phasekit()
        .args(["fit", "--velocity", "sideways", "--data", "x.csv"])
        .assert()
        .failure()
        .code(2);
}

#[test]
fn demo_runs_and_writes_three_pictures() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    phasekit()
        .args(["demo", "--train", "8", "--test", "2", "--seeds", "2", "-o"])
        .arg(&out)
        .assert()
        .success()
        .stdout(
            predicate::str::contains("| constant mean pose |")
                .and(predicate::str::contains("| hmm | 4 |"))
                .and(predicate::str::contains("| hmm:states=7 | 7 |"))
                .and(predicate::str::contains("\nNext (")),
        );
    for svg in ["segmentation.svg", "prediction.svg", "states.svg"] {
        let text = std::fs::read_to_string(out.join(svg)).unwrap();
        assert!(
            text.starts_with("<svg") && text.trim_end().ends_with("</svg>"),
            "{svg} is an SVG"
        );
    }
    for model in ["hmm.json", "hmm7.json", "tsc-hmm.json"] {
        ModelFile::load(&out.join(model)).unwrap();
    }
}

#[test]
fn plots_are_written() {
    let (dir, data) = dataset();
    let model = dir.path().join("m.json");
    fit(&data, TSC, &model);
    let test = data.join("test_00.csv");
    for kind in ["segmentation", "prediction"] {
        let svg = dir.path().join(format!("{kind}.svg"));
        phasekit()
            .args(["plot", kind, "--model"])
            .arg(&model)
            .arg("--data")
            .arg(&test)
            .arg("-o")
            .arg(&svg)
            .assert()
            .success();
        assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
    }
    let svg = dir.path().join("states.svg");
    phasekit()
        .args([
            "plot",
            "states",
            "--x",
            "p1_wrist_x",
            "--y",
            "p1_wrist_y",
            "--model",
        ])
        .arg(&model)
        .arg("--data")
        .arg(&data)
        .arg("-o")
        .arg(&svg)
        .assert()
        .success();
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.contains("transition state 0") && text.contains("state 3"));
    phasekit()
        .args(["plot", "states", "--x", "nope", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&data)
        .arg("-o")
        .arg(dir.path().join("x.svg"))
        .assert()
        .failure()
        .stderr(predicate::str::contains("no feature `nope`"));
    assert!(!dir.path().join("x.svg").exists());
}

#[test]
fn every_command_has_help_with_examples() {
    for cmd in [
        &["fit"][..],
        &["segment"],
        &["predict"],
        &["stream"],
        &["evaluate"],
        &["plot"],
        &["demo"],
        &["plot", "states"],
        &["plot", "segmentation"],
        &["plot", "prediction"],
    ] {
        phasekit()
            .args(cmd)
            .arg("--help")
            .assert()
            .success()
            .stdout(predicate::str::contains("Example"));
    }
    phasekit()
        .arg("--help")
        .assert()
        .success()
        .stdout(predicate::str::contains("phasekit demo"));
}

/// The model file's JSON without the parts that legitimately differ between two fits
/// of the same data (the clock).
fn model_json(path: &Path) -> serde_json::Value {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    v["fit"]["fit_seconds"] = serde_json::Value::Null;
    v
}

/// A minimal NPY v1.0 file: little-endian f8, C order, `rows × cols`.
fn write_npy(path: &Path, rows: usize, cols: usize, data: &[f64]) {
    let mut header =
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    // Magic (6) + version (2) + length (2) + header, padded with spaces to 64, ending in \n.
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in data {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn npy_input_fits_the_same_model_as_the_same_data_in_csv() {
    let dir = tempfile::tempdir().unwrap();
    let (csv, npy) = (dir.path().join("csv"), dir.path().join("npy"));
    std::fs::create_dir(&csv).unwrap();
    std::fs::create_dir(&npy).unwrap();
    // NPY columns are named c0, c1, …: the CSV twin uses the same names.
    let header = "c0,c1,c2,c3,c4,c5";
    for (i, demo) in synthetic::generate(6, 8).iter().enumerate() {
        write_csv(
            &csv.join(format!("train_{i:02}.csv")),
            header,
            &rows_of(&demo.frames),
        );
        write_npy(
            &npy.join(format!("train_{i:02}.npy")),
            demo.frames.len() / 6,
            6,
            &demo.frames,
        );
    }
    let fit_dir = |data: &Path, out: &Path| {
        phasekit()
            .args([
                "fit", "--method", TSC, "--human", "c0,c1,c2", "--robot", "c[3-5]", "--data",
            ])
            .arg(data)
            .arg("-o")
            .arg(out)
            .assert()
            .success();
    };
    let (a, b) = (dir.path().join("a.json"), dir.path().join("b.json"));
    fit_dir(&csv, &a);
    fit_dir(&npy, &b);
    let (ja, jb) = (model_json(&a), model_json(&b));
    assert_eq!(
        ja["layout"]["robot_columns"],
        serde_json::json!(["c3", "c4", "c5"])
    );
    assert!(ja == jb, "the NPY and the CSV data give the same model");
}

#[test]
fn velocity_options_and_glob_lists_select_the_features() {
    let (dir, data) = dataset();
    let test = data.join("test_00.csv");
    for (which, features, robot) in [
        ("both", 12, 6),
        ("human", 9, 3),
        ("robot", 9, 6),
        ("none", 6, 3),
    ] {
        let model = dir.path().join(format!("{which}.json"));
        phasekit()
            .args(["fit", "--method", "hmm", "--velocity", which, "--data"])
            .arg(&data)
            .arg("-o")
            .arg(&model)
            .assert()
            .success();
        let mf = ModelFile::load(&model).unwrap();
        let f = &mf.layout.features;
        assert_eq!(f.len(), features, "--velocity {which}: {f:?}");
        assert_eq!(
            f.iter().any(|n| n == "d_p1_wrist_x"),
            matches!(which, "both" | "human")
        );
        assert_eq!(
            f.iter().any(|n| n == "d_p2_wrist_x"),
            matches!(which, "both" | "robot")
        );
        let out = phasekit()
            .args(["predict", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(&test)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone();
        let (header, _) = parse_csv(&String::from_utf8(out).unwrap());
        assert_eq!(header.len(), 1 + robot, "--velocity {which}: {header:?}");
    }
    // A list of globs selects the same columns, in the same order, as one glob.
    let (one, list) = (dir.path().join("one.json"), dir.path().join("list.json"));
    fit(&data, "hmm", &one);
    phasekit()
        .args([
            "fit",
            "--method",
            "hmm",
            "--human",
            "p1_wrist_x,p1_wrist_[yz]",
            "--robot",
            "p2_wrist_?",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(&list)
        .assert()
        .success();
    let (a, b) = (model_json(&one), model_json(&list));
    assert_eq!(
        b["feature_spec"]["human"],
        serde_json::json!(["p1_wrist_x", "p1_wrist_[yz]"])
    );
    for part in ["layout", "model", "roles"] {
        assert!(a[part] == b[part], "`{part}` differs");
    }
}

#[test]
fn bad_inputs_of_predict_segment_evaluate_and_plot_are_refused() {
    let (dir, data) = dataset();
    let d = dir.path();
    let model = d.join("m.json");
    fit(&data, TSC, &model);
    let header = synthetic::COLUMNS.join(",");
    let mut rows = rows_of(&synthetic::generate(1, 3)[0].frames);
    rows[4][1] = "abc".into();
    write_csv(&d.join("text.csv"), &header, &rows);
    rows[4][1] = "0.1".into();
    // NaN is a missing value; infinity is refused (in a column predict reads: the human's).
    rows[9][1] = "inf".into();
    write_csv(&d.join("nan.csv"), &header, &rows);
    write_csv(
        &d.join("humanonly.csv"),
        "p1_wrist_x,p1_wrist_y,p1_wrist_z",
        &vec![vec!["0.1".into(), "0.2".into(), "0.3".into()]; 5],
    );
    std::fs::copy(data.join("test_00.csv"), d.join("good.csv")).unwrap();
    let args = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let run = |a: Vec<String>, msg: &[&str]| {
        refused(d, &a.iter().map(String::as_str).collect::<Vec<_>>(), msg)
    };
    run(
        args(&[
            "predict", "--model", "m.json", "--data", "text.csv", "-o", "p.csv",
        ]),
        &["text.csv", "row 6", "column 2", "not a number"],
    );
    // Several inputs into a folder: one bad file, and no folder or file is made.
    run(
        args(&[
            "predict", "--model", "m.json", "--data", "good.csv", "nan.csv", "-o", "preds/",
        ]),
        &["nan.csv", "row 11", "column 2", "not a finite number"],
    );
    run(
        args(&[
            "segment",
            "--model",
            "m.json",
            "--data",
            "humanonly.csv",
            "-o",
            "s.csv",
        ]),
        &["humanonly.csv", "needs the robot's column `p2_wrist_x`"],
    );
    run(
        args(&[
            "segment", "--model", "text.csv", "--data", "good.csv", "-o", "s.csv",
        ]),
        &["text.csv", "not a phasekit model file"],
    );
    run(
        args(&[
            "plot",
            "prediction",
            "--model",
            "m.json",
            "--data",
            "nan.csv",
            "-o",
            "p.svg",
        ]),
        &["nan.csv", "row 11", "not a finite number"],
    );
    run(
        args(&[
            "plot",
            "segmentation",
            "--model",
            "m.json",
            "--data",
            "humanonly.csv",
            "-o",
            "s.svg",
        ]),
        &["humanonly.csv", "needs the robot's column"],
    );
    run(
        args(&[
            "plot", "states", "--model", "m.json", "--data", "text.csv", "-o", "st.svg",
        ]),
        &["text.csv", "row 6", "not a number"],
    );
    run(
        args(&[
            "plot",
            "states",
            "--model",
            "m.json",
            "--data",
            "good.csv",
            "--z",
            "p2_wrist_y",
            "-o",
            "st.svg",
        ]),
        &["--z needs --view 3d"],
    );
    // Evaluate: a bad cell in a training file of an action folder.
    let bad = d.join("bad");
    std::fs::create_dir(&bad).unwrap();
    for f in [
        "train_00.csv",
        "train_01.csv",
        "train_02.csv",
        "test_00.csv",
    ] {
        std::fs::copy(data.join(f), bad.join(f)).unwrap();
    }
    std::fs::copy(d.join("text.csv"), bad.join("train_03.csv")).unwrap();
    run(
        args(&[
            "evaluate",
            "--data",
            "bad",
            "--methods",
            "hmm",
            "--seeds",
            "2",
            "-o",
            "res",
        ]),
        &["train_03.csv", "row 6", "column 2", "not a number"],
    );
    run(
        args(&[
            "evaluate",
            "--data",
            "bad",
            "--methods",
            "hmm,nope",
            "-o",
            "res",
        ]),
        &["unknown preset `nope`"],
    );
    run(
        args(&["evaluate", "--data", "good.csv", "--methods", "hmm"]),
        &["good.csv", "needs a folder"],
    );
    run(
        args(&[
            "evaluate",
            "--data",
            "bad",
            "--methods",
            "hmm",
            "-o",
            "no/such/prefix",
        ]),
        &["folder no/such does not exist"],
    );
    // Windows: a dilation as long as a demonstration, gmm-tsc windows beyond 64 frames
    // or a demonstration's length, and a window that would overflow.
    let n = read_table(&data.join("train_00.csv"))
        .unwrap()
        .n_rows()
        .min(
            (1..8)
                .map(|i| {
                    read_table(&data.join(format!("train_{i:02}.csv")))
                        .unwrap()
                        .n_rows()
                })
                .min()
                .unwrap(),
        );
    let data_arg = data.display().to_string();
    run(
        args(&[
            "fit",
            "--method",
            "tsc-hmm",
            "--window",
            &n.to_string(),
            "-o",
            "w.json",
            "--data",
            &data_arg,
        ]),
        &["dilates every transition frame", "use a window below"],
    );
    run(
        args(&[
            "fit",
            "--method",
            "tsc-hmm",
            "--window",
            "18446744073709551615",
            "-o",
            "w.json",
            "--data",
            &data_arg,
        ]),
        &["dilates every transition frame"],
    );
    run(
        args(&[
            "fit",
            "--method",
            "gmm-tsc:window=65",
            "-o",
            "w.json",
            "--data",
            &data_arg,
        ]),
        &["1..=64"],
    );
    let short = d.join("short");
    std::fs::create_dir(&short).unwrap();
    write_csv(
        &short.join("train_00.csv"),
        &header,
        &rows_of(&synthetic::generate(1, 5)[0].frames)[..20],
    );
    run(
        args(&[
            "fit",
            "--method",
            "gmm-tsc:window=30",
            "-o",
            "w.json",
            "--data",
            "short",
        ]),
        &["train_00.csv", "20 frames", "stacks 30 frames"],
    );
    // A model file whose union composition lost its union HMM.
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    assert!(v["model"]["model"]["union"].is_object());
    v["model"]["model"]["union"] = serde_json::Value::Null;
    std::fs::write(d.join("nounion.json"), v.to_string()).unwrap();
    run(
        args(&[
            "predict",
            "--model",
            "nounion.json",
            "--data",
            "good.csv",
            "-o",
            "p.csv",
        ]),
        &["nounion.json", "corrupted model file", "no union HMM"],
    );
    // The fit hint names a larger window than the one that failed.
    let out = phasekit()
        .args([
            "fit",
            "--method",
            "tsc-hmm:tsc-states=40,window=2",
            "-o",
            "h.json",
            "--data",
        ])
        .arg(&data)
        .current_dir(d)
        .assert()
        .failure()
        .get_output()
        .stderr
        .clone();
    let err = String::from_utf8(out).unwrap();
    assert!(
        err.contains("larger window than ±2 (e.g. --window 4)"),
        "{err}"
    );
    assert!(!d.join("h.json").exists());
}

#[test]
fn automatic_state_counts_from_the_command_line() {
    let (dir, data) = dataset();
    let model = dir.path().join("auto.json");
    let out = phasekit()
        .args([
            "fit",
            "--method",
            "hmm",
            "--states",
            "auto",
            "--max-states",
            "6",
            "--format",
            "json",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    let bic = report["bic"].as_array().unwrap();
    assert_eq!(bic.len(), 5, "BIC of 2..=6 states: {bic:?}");
    let best = bic
        .iter()
        .min_by(|a, b| a[1].as_f64().unwrap().total_cmp(&b[1].as_f64().unwrap()))
        .unwrap()[0]
        .as_u64()
        .unwrap();
    assert_eq!(report["states"].as_u64().unwrap(), best);
    assert_eq!(report["chosen"], format!("states={best} (BIC)"));
    assert_eq!(ModelFile::load(&model).unwrap().n_states() as u64, best);
    // The same through a method key, in evaluate, and gmm-tsc by G-means.
    let out = phasekit()
        .args([
            "evaluate",
            "--methods",
            // G-means finds about 20 Gaussian clusters in these trajectories: room for them.
            "hmm:states=auto,max-states=6,gmm-tsc:states=auto,select=gmeans,max-states=40,window=1,tsc-states=auto",
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
    let rows = report["results"].as_array().unwrap();
    assert_eq!(rows[0]["seeds"], 2);
    assert!((2..=6).contains(&rows[0]["states"].as_u64().unwrap()));
    assert_eq!(rows[1]["seeds"], 2, "{}", rows[1]);
    // G-means for HMM states: on these trajectories it finds more Gaussian clusters
    // than --max-states (10) allows, so its count would only be the cap: refused,
    // saying so and what to do. Refused clearly too: states=auto for the CV presets.
    phasekit()
        .args([
            "fit", "--method", "hmm", "--states", "auto", "--select", "gmeans", "--format", "json",
            "--data",
        ])
        .arg(&data)
        .assert()
        .failure()
        .stderr(predicate::str::contains(
            "more than the 10 HMM states allowed",
        ))
        .stderr(predicate::str::contains("(--max-states)"))
        .stderr(predicate::str::contains("(--select bic)"));
    phasekit()
        .args([
            "fit", "--method", "hmm-cv", "--states", "auto", "-o", "x.json", "--data",
        ])
        .arg(&data)
        .assert()
        .failure()
        .stderr(predicate::str::contains("states=auto is offered for"));
}

#[test]
fn evaluate_prints_the_metric_compares_twice_and_fails_loudly() {
    let (dir, data) = dataset();
    let out = phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm,hmm:states=5,hmm:states=6",
            "--seeds",
            "2",
            "--data",
        ])
        .arg(&data)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let md = String::from_utf8(out).unwrap();
    assert!(md.starts_with("| action | method |"));
    assert!(
        md.contains("MSE: per frame, squared Euclidean error"),
        "{md}"
    );
    let out = phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm,hmm:states=5,hmm:states=6",
            "--seeds",
            "2",
            "--format",
            "csv",
            "--data",
        ])
        .arg(&data)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let text = String::from_utf8(out).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| {
        header
            .iter()
            .position(|h| *h == n)
            .unwrap_or_else(|| panic!("{n}"))
    };
    let third: Vec<&str> = lines.nth(2).unwrap().split(',').collect();
    assert_eq!(third[col("method")], "hmm:states=6");
    assert_eq!(third[col("reference")], "hmm");
    assert_eq!(third[col("second_reference")], "hmm:states=5");
    for c in [
        "paired_change",
        "paired_won",
        "paired_change_second",
        "paired_won_second",
    ] {
        assert!(third[col(c)].parse::<f64>().unwrap().is_finite(), "{c}");
    }

    // -o DIR/ writes DIR/evaluate.md and DIR/evaluate.json (the folder is made), and
    // the error over time beside them.
    let outs = dir.path().join("outs");
    phasekit()
        .args(["evaluate", "--methods", "hmm", "--seeds", "2", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(format!("{}/", outs.display()))
        .assert()
        .success();
    only_files(
        &outs,
        &[
            "evaluate.json",
            "evaluate.md",
            "evaluate_by_test_demonstration.csv",
            "evaluate_error_by_time.csv",
            "evaluate_error_by_time_data.svg",
        ],
    );
    assert!(std::fs::read_to_string(outs.join("evaluate.md"))
        .unwrap()
        .contains("MSE: per frame"));
    // An existing folder without the slash, too.
    phasekit()
        .args(["evaluate", "--methods", "hmm", "--seeds", "2", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&outs)
        .assert()
        .success();
    only_files(
        &outs,
        &[
            "evaluate.json",
            "evaluate.md",
            "evaluate_by_test_demonstration.csv",
            "evaluate_error_by_time.csv",
            "evaluate_error_by_time_data.svg",
        ],
    );

    // A method that fails on every seed (λ_T with more states than any transition
    // segment has frames): the table is printed and written, the exit status is 1.
    let prefix = dir.path().join("failing");
    let out = phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm,tsc-hmm:tsc-states=40,window=0",
            "--seeds",
            "2",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(&prefix)
        .assert()
        .failure()
        .code(1)
        .stderr(predicate::str::contains("failed on every seed"))
        .get_output()
        .stdout
        .clone();
    let md = String::from_utf8(out).unwrap();
    let row = md
        .lines()
        .find(|l| l.starts_with("| data | tsc-hmm:tsc-states=40"))
        .unwrap();
    assert!(row.contains("| – | – | 0 | 2 | – | – |"), "{row}");
    assert!(!md.contains("-0.000"));
    assert!(dir.path().join("failing.md").exists() && dir.path().join("failing.json").exists());
    // The CI guard.
    phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm",
            "--seeds",
            "2",
            "--fail-above",
            "0.001",
            "--data",
        ])
        .arg(&data)
        .assert()
        .failure()
        .code(1)
        .stderr(
            predicate::str::contains("--fail-above 0.001")
                .and(predicate::str::contains("data / hmm")),
        );
    phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm",
            "--seeds",
            "2",
            "--fail-above",
            "1e9",
            "--data",
        ])
        .arg(&data)
        .assert()
        .success();
}

#[test]
fn prediction_plot_has_the_two_sigma_band_and_states_plot_the_predicting_model() {
    let (dir, data) = dataset();
    let model = dir.path().join("m.json");
    fit(&data, TSC, &model);
    let test = data.join("test_00.csv");
    let n = read_table(&test).unwrap().n_rows();
    let svg = dir.path().join("p.svg");
    phasekit()
        .args(["plot", "prediction", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test)
        .arg("-o")
        .arg(&svg)
        .assert()
        .success();
    let text = std::fs::read_to_string(&svg).unwrap();
    // One ±2σ band per robot position column: a polygon of the upper and the lower
    // edge, 2 points per frame.
    let bands: Vec<usize> = text
        .split("<polygon")
        .skip(1)
        .map(|p| {
            let pts = p
                .split("points=\"")
                .nth(1)
                .unwrap()
                .split('"')
                .next()
                .unwrap();
            pts.split_whitespace().count()
        })
        .collect();
    assert_eq!(
        bands.iter().filter(|&&k| k == 2 * n).count(),
        3,
        "{bands:?}"
    );
    assert!(text.contains("±2σ"));

    // The states plot draws the union's re-trained Gaussians, λ_T's as transition states.
    let mf = ModelFile::load(&model).unwrap();
    let phasekit_tsc::Model::TscHmm { model: m, .. } = &mf.model else {
        panic!()
    };
    let union = m.union().unwrap();
    let dims = [
        mf.layout
            .features
            .iter()
            .position(|f| f == "p2_wrist_x")
            .unwrap(),
        5 + 6,
    ];
    let e = phasekit_cli::plot::model_ellipses(&mf, dims);
    assert_eq!(e.len(), 7);
    for (i, el) in e.iter().enumerate() {
        assert_eq!(
            el.mean,
            [
                union.emission().mean(i)[dims[0]],
                union.emission().mean(i)[dims[1]]
            ]
        );
        assert_eq!(el.transition, i >= 4, "state {i}");
    }
    assert_ne!(
        union.emission().mean(0),
        m.base().emission().mean(0),
        "the union's Gaussians are re-trained, not λ's"
    );
    let svg = dir.path().join("s3.svg");
    phasekit()
        .args(["plot", "states", "--view", "3d", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&data)
        .arg("-o")
        .arg(&svg)
        .assert()
        .success();
    let text = std::fs::read_to_string(&svg).unwrap();
    for s in [
        "oblique 3-D view",
        "p2_wrist_x",
        "p2_wrist_y",
        "p2_wrist_z",
        "transition state 2",
        "state 3",
    ] {
        assert!(text.contains(s), "{s}");
    }
}

#[test]
fn stream_writes_each_frame_before_the_input_ends() {
    use std::io::{BufRead, BufReader, Write};
    let (dir, data) = dataset();
    let model = dir.path().join("m.json");
    fit(&data, "hmm", &model);
    let mut child = std::process::Command::new(assert_cmd::cargo::cargo_bin("phasekit"))
        .args(["stream", "--quiet", "--no-header", "--model"])
        .arg(&model)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            if tx.send(line.unwrap()).is_err() {
                break;
            }
        }
    });
    let timeout = std::time::Duration::from_secs(30);
    for frame in ["0.01,0.02,0.03", "0.02,0.03,0.04"] {
        // One line in, with stdin still open: its prediction must come out now.
        writeln!(stdin, "{frame}").unwrap();
        stdin.flush().unwrap();
        let line = rx
            .recv_timeout(timeout)
            .expect("a predicted frame is written before the input ends");
        assert_eq!(line.split(',').count(), 1 + 6 + 1, "{line}"); // frame, robot, status
    }
    drop(stdin);
    assert!(child.wait().unwrap().success());
    reader.join().unwrap();
    assert!(rx.try_recv().is_err(), "nothing more after the two frames");
}
