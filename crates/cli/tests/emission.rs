//! The emission chosen at run time: `--emission NAME` on `fit` and
//! `evaluate`, `emission=NAME` as a method key. The model file records it and
//! every command that reads a model (predict, segment, stream, plot) uses it;
//! a model file with no emission recorded is a full Gaussian.

use crate::common;

use common::{interaction_folder, model_json, parse_csv, parse_stream, phasekit, plain, stdout};
use predicates::prelude::*;
use std::path::Path;

const EMISSIONS: [&str; 6] = ["full", "diag", "spherical", "tied", "student-t", "gmm-2"];

fn fit(data: &Path, model: &Path, args: &[&str]) {
    phasekit()
        .arg("fit")
        .args(args)
        .arg("--data")
        .arg(data)
        .arg("-o")
        .arg(model)
        .assert()
        .success();
}

/// The first three columns (the human's wrist) of a CSV text, header included.
fn human_columns(text: &str) -> String {
    text.lines()
        .map(|l| l.split(',').take(3).collect::<Vec<_>>().join(",") + "\n")
        .collect()
}

#[test]
fn every_emission_is_recorded_and_read_back_by_every_command() {
    let (dir, data) = interaction_folder(8, 5, 6, plain);
    let test = data.join("test_00.csv");
    for name in EMISSIONS {
        for method in ["hmm", "tsc-hmm"] {
            let model = dir.path().join(format!("{method}-{name}.json"));
            fit(&data, &model, &["--method", method, "--emission", name]);
            let j = model_json(&model);
            // HMM states of any of these emissions were in version 1 already.
            assert_eq!(j["version"], 1, "{method} {name}");
            // The settings record the choice (the default is not written, so
            // that full-Gaussian files stay as they were).
            let recorded = if method == "hmm" {
                &j["method"]["settings"]["emission"]
            } else {
                &j["method"]["settings"]["base"]["emission"]
            };
            if name == "full" {
                assert!(recorded.is_null(), "{name}: {recorded}");
            } else {
                assert_eq!(recorded, name, "{method} {name}");
            }
            // The fitted emission says what it is.
            let emission = if method == "hmm" {
                &j["model"]["emission"]
            } else {
                &j["model"]["model"]["base"]["emission"]
            };
            match name {
                "student-t" | "gmm-2" => assert_eq!(emission["emission"], name, "{emission}"),
                _ => assert!(
                    emission["covariance_type"].is_string(),
                    "{name}: {emission}"
                ),
            }

            let predicted = stdout(
                phasekit()
                    .args(["predict", "--covariance", "--model"])
                    .arg(&model)
                    .arg("--data")
                    .arg(&test),
            );
            let (_, rows) = parse_csv(&predicted);
            assert!(rows.len() > 10);
            assert!(
                rows.iter().flatten().all(|v| v.is_finite()),
                "{method} {name}: a prediction is not finite"
            );
            let segmented = stdout(
                phasekit()
                    .args(["segment", "--model"])
                    .arg(&model)
                    .arg("--data")
                    .arg(&test),
            );
            assert_eq!(segmented.lines().count(), rows.len() + 1);

            // Online = batch: the stream's predictions are the batch ones.
            let text = std::fs::read_to_string(&test).unwrap();
            let streamed = phasekit()
                .args(["stream", "--quiet", "--model"])
                .arg(&model)
                .write_stdin(human_columns(&text))
                .assert()
                .success()
                .get_output()
                .stdout
                .clone();
            let (_, srows, status) = parse_stream(&String::from_utf8(streamed).unwrap(), true);
            assert_eq!(srows.len(), rows.len());
            assert!(
                status.iter().all(|s| s == "ok"),
                "{method} {name}: {status:?}"
            );
            for (a, b) in srows.iter().zip(&rows) {
                for (x, y) in a.iter().zip(b) {
                    assert!(
                        (x - y).abs() <= 1e-9 * (1.0 + y.abs()),
                        "{method} {name}: stream {x} vs predict {y}"
                    );
                }
            }

            for plot in ["segmentation", "prediction", "states"] {
                let svg = dir.path().join(format!("{method}-{name}-{plot}.svg"));
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
    }
}

#[test]
fn the_emission_key_and_flag_agree_and_bad_names_are_refused() {
    let (dir, data) = interaction_folder(6, 2, 4, plain);
    let by_key = dir.path().join("key.json");
    let by_flag = dir.path().join("flag.json");
    fit(&data, &by_key, &["--method", "hmm:emission=student-t"]);
    fit(
        &data,
        &by_flag,
        &["--method", "hmm", "--emission", "student-t"],
    );
    assert_eq!(model_json(&by_key)["model"], model_json(&by_flag)["model"]);

    for bad in ["gauss", "gmm-0", "gmm-x", "student"] {
        phasekit()
            .args(["fit", "--method", "hmm", "--emission", bad, "--data"])
            .arg(&data)
            .arg("-o")
            .arg(dir.path().join("bad.json"))
            .assert()
            .failure()
            .stderr(predicate::str::contains("emission"));
        phasekit()
            .args(["fit", "--method", &format!("hmm:emission={bad}"), "--data"])
            .arg(&data)
            .arg("-o")
            .arg(dir.path().join("bad.json"))
            .assert()
            .failure()
            .stderr(predicate::str::contains("emission"));
    }
    assert!(!dir.path().join("bad.json").exists());
    // gmm and gmm-tsc take the emission too: their mixtures' components are
    // of it, and the model file says so.
    for method in ["gmm", "gmm-tsc"] {
        let model = dir.path().join(format!("{method}-student-t.json"));
        fit(
            &data,
            &model,
            &["--method", method, "--emission", "student-t"],
        );
        let j = model_json(&model);
        let (settings, mixture) = if method == "gmm" {
            (&j["method"]["settings"], &j["model"]["components"])
        } else {
            (
                &j["method"]["settings"]["gmm"],
                &j["model"]["mixture"]["components"],
            )
        };
        assert_eq!(settings["emission"], "student-t", "{method}: {settings}");
        // Version-1 readers know Gaussian mixtures only: the file says it needs 2.
        assert_eq!(j["version"], 2, "{method}");
        assert_eq!(mixture["emission"], "student-t", "{method}: {mixture}");
        if method == "gmm-tsc" {
            assert_eq!(j["method"]["settings"]["tsc"]["emission"], "student-t");
            assert_eq!(
                j["model"]["tsc"]["mixture"]["components"]["emission"],
                "student-t"
            );
        }
        let test = data.join("test_00.csv");
        let predicted = stdout(
            phasekit()
                .args(["predict", "--model"])
                .arg(&model)
                .arg("--data")
                .arg(&test),
        );
        assert!(predicted.lines().count() > 2, "{method}: {predicted}");
    }
}

#[test]
fn evaluate_ablates_emissions_by_method_key() {
    let (_dir, data) = interaction_folder(6, 9, 4, plain);
    let table = stdout(
        phasekit()
            .args([
                "evaluate",
                "--methods",
                "hmm,hmm:emission=student-t,hmm:emission=gmm-2,tsc-hmm:emission=diag",
                "--seeds",
                "2",
                "--data",
            ])
            .arg(&data),
    );
    for label in [
        "| hmm |",
        "| hmm:emission=student-t |",
        "| hmm:emission=gmm-2 |",
        "| tsc-hmm:emission=diag |",
    ] {
        assert!(table.contains(label), "{label} missing from\n{table}");
    }
    // No method failed on any seed (the results table: up to its first blank line).
    for line in table
        .lines()
        .take_while(|l| !l.is_empty())
        .filter(|l| l.starts_with("| data | "))
    {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells[2] != "constant-mean" {
            assert_eq!(cells[7], "0", "{line}");
        }
    }
}

/// `tests/fixtures/hmmlearn_gmmhmm_cases.json` (made by
/// `tests/fixtures/generate.py`): 10 sequences whose three states each emit
/// from two well-separated Gaussians, with hmmlearn's results on them.
fn gmmhmm_fixture() -> serde_json::Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/fixtures/hmmlearn_gmmhmm_cases.json"
    );
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Log-likelihood per frame of the model `phasekit fit` wrote (the last
/// E-step of its report is the returned model's).
fn fitted_ll_per_frame(data: &Path, model: &Path, emission: &str) -> f64 {
    let out = stdout(
        phasekit()
            .args([
                "fit",
                "--human",
                "h",
                "--robot",
                "r",
                "--velocity",
                "none",
                "--method",
                "hmm",
                "--states",
                "3",
                "--emission",
                emission,
                "--restarts",
                "5",
                "--reg",
                "1e-6",
                "--max-iter",
                "200",
                "--tol",
                "1e-6",
                "--format",
                "json",
                "--data",
            ])
            .arg(data)
            .arg("-o")
            .arg(model),
    );
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    let ll = report["log_likelihood"].as_array().unwrap();
    ll.last().unwrap().as_f64().unwrap() / report["frames"].as_f64().unwrap()
}

#[test]
fn gmm_2_at_the_command_line_reaches_hmmlearns_gmmhmm_and_beats_one_gaussian() {
    let f = gmmhmm_fixture();
    let c = &f["multimodal"];
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir(&data).unwrap();
    for (i, seq) in c["sequences"].as_array().unwrap().iter().enumerate() {
        let mut text = String::from("h,r\n");
        for frame in seq.as_array().unwrap() {
            let v: Vec<String> = frame
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap().to_string())
                .collect();
            text += &(v.join(",") + "\n");
        }
        std::fs::write(data.join(format!("train_{i:02}.csv")), text).unwrap();
    }
    let best = |key: &str| {
        c[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let hmmlearn = best("hmmlearn_gmmhmm_log_likelihood_per_frame");
    let gmm2 = fitted_ll_per_frame(&data, &dir.path().join("gmm2.json"), "gmm-2");
    let full = fitted_ll_per_frame(&data, &dir.path().join("full.json"), "full");
    println!(
        "log-likelihood per frame (nats): phasekit --emission gmm-2 {gmm2:.6}, --emission full {full:.6}, \
         hmmlearn GMMHMM best of 5 seeds {hmmlearn:.6}"
    );
    assert!(
        gmm2 >= hmmlearn - 1e-6,
        "gmm-2 {gmm2} below hmmlearn's best {hmmlearn}"
    );
    assert!(
        gmm2 > full + 0.5,
        "gmm-2 {gmm2} not clearly above full {full}"
    );
}

#[test]
fn the_fit_report_names_the_emission_in_every_format() {
    let (dir, data) = interaction_folder(6, 5, 6, plain);
    for (method, name) in [
        ("hmm", "student-t"),
        ("tsc-hmm", "diag"),
        ("hmm", "full"),
        ("gmm", "student-t"),
        ("gmm-tsc", "diag"),
    ] {
        let model = dir.path().join(format!("report-{method}-{name}.json"));
        let json = stdout(
            phasekit()
                .args([
                    "fit",
                    "--method",
                    method,
                    "--emission",
                    name,
                    "--format",
                    "json",
                ])
                .arg("--data")
                .arg(&data)
                .arg("-o")
                .arg(&model),
        );
        let j: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(j["emission"], name, "{method}: {json}");
        let md = stdout(
            phasekit()
                .args([
                    "fit",
                    "--method",
                    method,
                    "--emission",
                    name,
                    "--format",
                    "md",
                ])
                .arg("--data")
                .arg(&data),
        );
        assert!(md.contains(&format!("| emission | {name} |")), "{md}");
    }
}
