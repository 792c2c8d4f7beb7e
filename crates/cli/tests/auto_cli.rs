//! The `auto` preset on the command line: the fit report and the model file
//! carry the cross-validation table, evaluate names the choice per seed and
//! the choice depends on the training demonstrations only, keys are validated.

use crate::common::{
    interaction_folder, parse_csv, parse_stream, phasekit, plain, stdout, write_frames,
};
use phasekit_tsc::synthetic;

fn stderr_of_failure(cmd: &mut assert_cmd::Command) -> String {
    let out = cmd.assert().failure().get_output().stderr.clone();
    String::from_utf8(out).unwrap()
}

#[test]
fn fit_auto_reports_the_cross_validation_table_and_keeps_it_in_the_model_file() {
    let (dir, data) = interaction_folder(6, 3, 6, plain);
    let model = dir.path().join("auto.json");
    let report: serde_json::Value = serde_json::from_str(&stdout(
        phasekit()
            .args([
                "fit",
                "--method",
                "auto:grid=small,folds=3",
                "--format",
                "json",
                "--data",
            ])
            .arg(&data)
            .arg("-o")
            .arg(&model),
    ))
    .unwrap();
    let fit = &report; // the summary is flattened into the report
    let table = fit["cv_table"].as_array().unwrap();
    // The 9 candidates and the mean of the best (by default), its row last.
    assert_eq!(table.len(), 10, "{fit}");
    let chosen = fit["chosen"].as_str().unwrap();
    assert!(chosen.starts_with("mean of 3: "), "{chosen}");
    assert_eq!(table[9]["label"], chosen);
    let row = table.iter().find(|r| r["label"] == chosen).unwrap();
    assert_eq!(row["folds_scored"], 3);
    assert_eq!(row["abandoned"], false);
    assert!(table.iter().any(|r| r["abandoned"] == true), "{fit}");
    // The model file keeps the same table.
    let file = std::fs::read_to_string(&model).unwrap();
    assert!(file.contains("\"cv_table\""));
    assert!(file.contains(chosen));
    // A version-4 reader does not know the mean of several models: version 5.
    let v: serde_json::Value = serde_json::from_str(&file).unwrap();
    assert_eq!(v["version"], 5);
    assert_eq!(v["model"]["kind"], "ensemble");
    assert_eq!(v["model"]["members"].as_array().unwrap().len(), 3);

    let md = stdout(
        phasekit()
            .args([
                "fit",
                "--method",
                "auto:grid=small,folds=3",
                "--format",
                "md",
                "--data",
            ])
            .arg(&data),
    );
    assert!(md.contains("| candidate | folds scored | CV MSE |"), "{md}");
    assert!(md.contains(&format!("| {chosen} | 3 |")), "{md}");
    assert!(md.contains("**chosen**") && md.contains("abandoned (successive halving)"));
}

/// The `per_seed_chosen` of the (only) auto row of an evaluate JSON report.
fn choices(report: &serde_json::Value) -> Vec<serde_json::Value> {
    let rows = report["results"].as_array().unwrap();
    let row = rows
        .iter()
        .find(|r| r["method"].as_str().unwrap().starts_with("auto"))
        .unwrap();
    row["per_seed_chosen"].as_array().unwrap().clone()
}

#[test]
fn evaluate_names_the_choice_per_seed_and_the_test_set_does_not_move_it() {
    let (_dir, data) = interaction_folder(8, 5, 6, plain);
    // The same training demonstrations, other test demonstrations.
    let (_dir2, other) = interaction_folder(8, 5, 6, plain);
    for (i, demo) in synthetic::generate(2, 77).iter().enumerate() {
        write_frames(
            &other.join(format!("test_{i:02}.csv")),
            &demo.frames,
            &mut plain,
        );
    }
    let run = |folder: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&stdout(
            phasekit()
                .args([
                    "evaluate",
                    "--methods",
                    "auto:grid=small,families=hmm+gmm,folds=3",
                    "--seeds",
                    "2",
                    "--format",
                    "json",
                    "--data",
                ])
                .arg(folder),
        ))
        .unwrap()
    };
    let (a, b) = (run(&data), run(&other));
    let (ca, cb) = (choices(&a), choices(&b));
    assert_eq!(ca.len(), 2);
    assert!(ca.iter().all(|c| c.is_string()), "{ca:?}");
    assert_eq!(ca, cb);
    // The test set did change what is measured.
    let mse = |r: &serde_json::Value| r["results"][0]["mse_mean"].as_f64().unwrap();
    assert_ne!(mse(&a), mse(&b));

    let md = stdout(
        phasekit()
            .args([
                "evaluate",
                "--methods",
                "hmm,auto:grid=small,families=gmm",
                "--seeds",
                "1",
                "--data",
            ])
            .arg(&data),
    );
    assert!(
        md.contains("Chosen by auto:grid=small,families=gmm on data (1 seeds): mean of 2: gmm:"),
        "{md}"
    );
}

#[test]
fn auto_keys_are_validated() {
    let (_dir, data) = interaction_folder(4, 1, 4, plain);
    for (method, expected) in [
        ("auto:folds=1", "folds"),
        ("auto:grid=huge", "unknown grid `huge`"),
        ("auto:families=hmm+lstm", "`lstm` is not a family"),
        ("auto:states=7", "auto chooses `states`"),
        ("hmm:grid=small", "unknown key `grid`"),
    ] {
        let err = stderr_of_failure(
            phasekit()
                .args(["fit", "--method", method, "--format", "json", "--data"])
                .arg(&data),
        );
        assert!(err.contains(expected), "{method}: {err}");
    }
}

/// `auto` calibrates its predictive covariance on its folds, says so in the
/// report and the model file, and `predict --covariance` applies the added
/// covariance and the factor, `scale · (Σ + A)`, to every covariance and
/// never to the mean (against the same choice with `calibrate=off`).
#[test]
fn predict_applies_autos_calibration_to_the_covariance_only() {
    let (dir, data) = interaction_folder(6, 3, 6, plain);
    let fit = |spec: &str, name: &str| {
        let model = dir.path().join(name);
        let report: serde_json::Value = serde_json::from_str(&stdout(
            phasekit()
                .args(["fit", "--method", spec, "--format", "json", "--data"])
                .arg(&data)
                .arg("-o")
                .arg(&model),
        ))
        .unwrap();
        (model, report)
    };
    let (on, r_on) = fit("auto:grid=small,folds=3,ensemble=1", "on.json");
    let (off, r_off) = fit(
        "auto:grid=small,folds=3,calibrate=off,ensemble=1",
        "off.json",
    );
    assert_eq!(r_on["chosen"], r_off["chosen"]);
    assert!(r_off.get("covariance_calibration").is_none(), "{r_off}");
    let cal = &r_on["covariance_calibration"];
    let scale = cal["scale"].as_f64().unwrap();
    assert!(scale > 0.0 && (scale - 1.0).abs() > 1e-6, "{cal}");
    // The held-out frames inside after calibration: at least 95 % unless the
    // factor for a new demonstration narrowed the pooled one (f < 1).
    let after = cal["coverage_after"].as_f64().unwrap();
    let f = cal["demonstration_inflation"].as_f64().unwrap();
    assert!(after >= 0.95 || f < 1.0, "{cal}");
    assert!(cal["residual_weight"].as_f64().unwrap() > 0.0, "{cal}");
    // Every scored candidate has its held-out coverage in the table.
    let table = r_on["cv_table"].as_array().unwrap();
    assert!(table
        .iter()
        .filter(|r| r["abandoned"] == false)
        .all(|r| r["coverage"].as_f64().is_some()));
    let file = std::fs::read_to_string(&on).unwrap();
    assert!(file.contains("\"covariance_calibration\""));
    // A version-1 reader would ignore the factor, a version-2 reader does
    // not know a rule by name, a version-3 reader not the `predictive` rule
    // (nor the covariance it adds): the file says version 4.
    let v: serde_json::Value = serde_json::from_str(&file).unwrap();
    assert_eq!(v["version"], 4);
    // A file whose calibration it does not describe, or whose added
    // covariance is not one, is refused by name before any prediction.
    let n = v["fit"]["covariance_calibration"]["added_covariance"]
        .as_array()
        .unwrap()
        .len();
    let o = (n as f64).sqrt() as usize;
    let mut indefinite = vec![0.0; n];
    indefinite[1] = 1.0; // (0, 1) and (1, 0): [[0, 1], [1, 0]] on the first two dims
    indefinite[o] = 1.0;
    for (name, edit, says) in [
        (
            "v3.json",
            ("version", serde_json::json!(3)),
            "an added covariance needs version 4",
        ),
        (
            "short.json",
            ("added_covariance", serde_json::json!([1.0, 0.0])),
            "added_covariance",
        ),
        (
            "indefinite.json",
            ("added_covariance", serde_json::json!(indefinite)),
            "not positive semi-definite",
        ),
    ] {
        let mut bad = v.clone();
        match edit.0 {
            // A version-3 rule with the added covariance of version 4.
            "version" => {
                bad["version"] = edit.1;
                bad["method"]["settings"]["calibration"] = "demonstrations".into();
            }
            key => bad["fit"]["covariance_calibration"][key] = edit.1,
        }
        let path = dir.path().join(name);
        std::fs::write(&path, serde_json::to_string(&bad).unwrap()).unwrap();
        let one = std::fs::read_dir(&data)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.extension().is_some_and(|x| x == "csv"))
            .unwrap();
        let out = phasekit()
            .args(["predict", "--model"])
            .arg(&path)
            .arg("--data")
            .arg(&one)
            .assert()
            .failure()
            .get_output()
            .stderr
            .clone();
        let err = String::from_utf8(out).unwrap();
        assert!(err.contains(name) && err.contains(says), "{name}: {err}");
    }

    let test = std::fs::read_dir(&data)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|x| x == "csv"))
        .unwrap();
    let predict = |model: &std::path::Path, out: &str| {
        let out = dir.path().join(out);
        phasekit()
            .args(["predict", "--covariance", "--model"])
            .arg(model)
            .arg("--data")
            .arg(&test)
            .arg("-o")
            .arg(&out)
            .assert()
            .success();
        let text = std::fs::read_to_string(&out).unwrap();
        let mut lines = text.lines();
        let header: Vec<String> = lines
            .next()
            .unwrap()
            .split(',')
            .map(str::to_string)
            .collect();
        let rows: Vec<Vec<f64>> = lines
            .map(|l| {
                l.split(',')
                    .map(|v| v.parse().unwrap_or(f64::NAN))
                    .collect()
            })
            .collect();
        (header, rows)
    };
    let (h_on, p_on) = predict(&on, "on.csv");
    let (h_off, p_off) = predict(&off, "off.csv");
    assert_eq!(h_on, h_off);
    // A (robot dims × robot dims, nonzero on the scored positions' block
    // only), in the order of the covariance columns: (i, j ≥ i).
    let o = h_on.iter().filter(|n| n.starts_with("var_")).count();
    let added: Vec<f64> = cal["added_covariance"].as_array().map_or_else(
        || vec![0.0; o * o],
        |a| a.iter().map(|v| v.as_f64().unwrap()).collect(),
    );
    assert_eq!(added.len(), o * o);
    let upper: Vec<f64> = (0..o)
        .flat_map(|i| (i..o).map(move |j| (i, j)))
        .map(|(i, j)| added[i * o + j])
        .collect();
    let mut checked = 0;
    for (a, b) in p_on.iter().zip(&p_off) {
        let mut c = 0;
        for (k, name) in h_on.iter().enumerate() {
            if name.starts_with("var_") || name.starts_with("cov_") {
                let want = (b[k] + upper[c]) * scale;
                assert!(
                    (a[k] - want).abs() <= 1e-9 * want.abs().max(1e-12),
                    "{name}: {} vs ({} + {}) × {scale}",
                    a[k],
                    b[k],
                    upper[c]
                );
                c += 1;
                checked += 1;
            } else if !a[k].is_nan() {
                assert_eq!(a[k], b[k], "{name}: the mean must not move");
            }
        }
    }
    assert!(checked > 0, "no covariance column in {h_on:?}");
}

/// `auto`'s default, the mean of the best candidates, in every command:
/// `predict` gives finite means and covariances, `stream` the same frame by
/// frame (online = batch, calibration included), `segment` and the plots run
/// on its first member.
#[test]
fn the_mean_of_the_best_runs_in_every_command_and_streams_what_it_predicts() {
    let (dir, data) = interaction_folder(7, 3, 6, plain);
    let test = data.join("test_00.csv");
    let model = dir.path().join("mean.json");
    phasekit()
        .args([
            "fit",
            "--method",
            "auto:grid=small,folds=3,ensemble=3",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();
    let predicted = stdout(
        phasekit()
            .args(["predict", "--covariance", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(&test),
    );
    let (_, rows) = parse_csv(&predicted);
    assert!(rows.len() > 10);
    assert!(rows.iter().flatten().all(|v| v.is_finite()));
    let segmented = stdout(
        phasekit()
            .args(["segment", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(&test),
    );
    assert_eq!(segmented.lines().count(), rows.len() + 1);
    let text = std::fs::read_to_string(&test).unwrap();
    let human: String = text
        .lines()
        .map(|l| l.split(',').take(3).collect::<Vec<_>>().join(",") + "\n")
        .collect();
    let streamed = phasekit()
        .args(["stream", "--quiet", "--covariance", "--model"])
        .arg(&model)
        .write_stdin(human)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let (_, srows, status) = parse_stream(&String::from_utf8(streamed).unwrap(), true);
    assert_eq!(srows.len(), rows.len());
    assert!(status.iter().all(|s| s == "ok"), "{status:?}");
    for (a, b) in srows.iter().zip(&rows) {
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            assert!(
                (x - y).abs() <= 1e-9 * (1.0 + y.abs()),
                "stream {x} vs predict {y}"
            );
        }
    }
    for plot in ["segmentation", "prediction", "states"] {
        let svg = dir.path().join(format!("{plot}.svg"));
        phasekit()
            .args(["plot", plot, "--model"])
            .arg(&model)
            .arg("--data")
            .arg(&test)
            .arg("-o")
            .arg(&svg)
            .assert()
            .success();
        assert!(std::fs::metadata(&svg).unwrap().len() > 1000);
    }
}
