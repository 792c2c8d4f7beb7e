//! The `hsmm` preset from the command line: fit, predict, segment, stream,
//! plot and evaluate; the model file records it as version 2 while every
//! other model is still written (and read) as version 1.

use crate::common;

use common::{interaction_folder, model_json, parse_csv, parse_stream, phasekit, plain, stdout};
use std::path::Path;

fn fit(data: &Path, model: &Path, method: &str) {
    phasekit()
        .args(["fit", "--method", method, "--data"])
        .arg(data)
        .arg("-o")
        .arg(model)
        .assert()
        .success();
}

#[test]
fn hsmm_runs_in_every_command_and_streams_what_it_predicts() {
    let (dir, data) = interaction_folder(8, 5, 6, plain);
    let test = data.join("test_00.csv");
    for method in ["hsmm", "hsmm:states=3,duration=poisson,emission=diag"] {
        let model = dir.path().join("hsmm.json");
        fit(&data, &model, method);
        let j = model_json(&model);
        assert_eq!(j["version"], 2, "{method}");
        assert_eq!(j["model"]["kind"], "hsmm", "{method}");
        let predicted = stdout(
            phasekit()
                .args(["predict", "--covariance", "--model"])
                .arg(&model)
                .arg("--data")
                .arg(&test),
        );
        let (_, rows) = parse_csv(&predicted);
        assert!(rows.len() > 10);
        assert!(rows.iter().flatten().all(|v| v.is_finite()), "{method}");
        let segmented = stdout(
            phasekit()
                .args(["segment", "--model"])
                .arg(&model)
                .arg("--data")
                .arg(&test),
        );
        assert_eq!(segmented.lines().count(), rows.len() + 1);
        // Online = batch.
        let text = std::fs::read_to_string(&test).unwrap();
        let human: String = text
            .lines()
            .map(|l| l.split(',').take(3).collect::<Vec<_>>().join(",") + "\n")
            .collect();
        let streamed = phasekit()
            .args(["stream", "--quiet", "--model"])
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
    // evaluate: an hsmm row with its calibration.
    let csv = stdout(
        phasekit()
            .args([
                "evaluate",
                "--methods",
                "hmm,hsmm",
                "--seeds",
                "2",
                "--format",
                "csv",
                "--data",
            ])
            .arg(&data),
    );
    let line = csv.lines().find(|l| l.contains(",hsmm,")).unwrap();
    assert!(!line.contains("NaN"), "{csv}");
}

#[test]
fn model_file_versions_say_what_the_file_needs() {
    let (dir, data) = interaction_folder(7, 6, 6, plain);
    let hmm = dir.path().join("hmm.json");
    fit(&data, &hmm, "hmm");
    // A model an older phasekit can read is still written as version 1.
    assert_eq!(model_json(&hmm)["version"], 1);
    let hsmm = dir.path().join("hsmm.json");
    fit(&data, &hsmm, "hsmm");
    let test = data.join("test_00.csv");
    let predict = |m: &Path| {
        phasekit()
            .args(["predict", "--model"])
            .arg(m)
            .arg("--data")
            .arg(&test)
            .assert()
    };
    predict(&hmm).success();
    predict(&hsmm).success();
    // An hsmm model in a file that claims version 1, or a version from the future: refused.
    for (v, says) in [
        (1, "version 1 does not describe its model"),
        (6, "version 6 is not supported"),
    ] {
        let mut j = model_json(&hsmm);
        j["version"] = v.into();
        let bad = dir.path().join(format!("v{v}.json"));
        std::fs::write(&bad, serde_json::to_string(&j).unwrap()).unwrap();
        let out = predict(&bad).failure().get_output().stderr.clone();
        let err = String::from_utf8(out).unwrap();
        assert!(err.contains(says), "{err}");
    }
    // Duration settings belong to hsmm.
    phasekit()
        .args(["fit", "--method", "hmm:duration=poisson", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(dir.path().join("x.json"))
        .assert()
        .failure();
}

#[test]
fn a_maximum_duration_too_large_to_allocate_is_an_error_not_an_abort() {
    let (dir, data) = interaction_folder(4, 5, 6, plain);
    let out = phasekit()
        .args([
            "fit",
            "--method",
            "hsmm:max-duration=1000000000000",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(dir.path().join("huge.json"))
        .assert()
        .failure()
        .get_output()
        .clone();
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("max"), "{err}");
    assert!(
        !err.contains("panicked") && !err.contains("memory allocation"),
        "{err}"
    );
    assert!(!dir.path().join("huge.json").exists());
}
