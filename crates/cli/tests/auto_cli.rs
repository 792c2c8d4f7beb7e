//! The `auto` preset on the command line: the fit report and the model file
//! carry the cross-validation table, evaluate names the choice per seed and
//! the choice depends on the training demonstrations only, keys are validated.

use crate::common::{interaction_folder, phasekit, plain, write_frames};
use phasekit_tsc::synthetic;

fn stdout(cmd: &mut assert_cmd::Command) -> String {
    let out = cmd.assert().success().get_output().stdout.clone();
    String::from_utf8(out).unwrap()
}

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
    assert_eq!(table.len(), 9, "{fit}");
    let chosen = fit["chosen"].as_str().unwrap();
    let row = table.iter().find(|r| r["label"] == chosen).unwrap();
    assert_eq!(row["folds_scored"], 3);
    assert_eq!(row["abandoned"], false);
    assert!(table.iter().any(|r| r["abandoned"] == true), "{fit}");
    // The model file keeps the same table.
    let file = std::fs::read_to_string(&model).unwrap();
    assert!(file.contains("\"cv_table\""));
    assert!(file.contains(chosen));

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
        md.contains("Chosen by auto:grid=small,families=gmm on data (1 seeds): gmm:"),
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
