//! The relative regularisation from the command line (`reg-rel=R`,
//! `reg-units=relative`): the method keys, the model file (version 2, the unit
//! kept through a round trip; absolute files unchanged at version 1) and the
//! fit report's unit in JSON and Markdown.

use crate::common;

use common::{interaction_folder, model_json, phasekit, plain};
use phasekit_cli::experiment::parse_method;
use phasekit_tsc::{Method, PresetOptions, RegUnits};

fn units(m: &Method) -> RegUnits {
    match m {
        Method::CrossValidated(cv) => {
            let all: Vec<RegUnits> = cv
                .candidates()
                .iter()
                .map(|(_, c)| c.regularisation().unwrap().1)
                .collect();
            assert!(all.windows(2).all(|w| w[0] == w[1]), "{all:?}");
            all[0]
        }
        m => m.regularisation().unwrap().1,
    }
}

#[test]
fn method_keys_set_the_unit_and_refuse_contradictions() {
    let d = PresetOptions::default();
    for (spec, want, reg) in [
        ("hmm", RegUnits::Absolute, 1e-2),
        ("hmm:reg-rel=0.05", RegUnits::Relative, 0.05),
        ("hmm:reg=0.05,reg-units=relative", RegUnits::Relative, 0.05),
        ("hmm:reg-units=absolute", RegUnits::Absolute, 1e-2),
        ("hsmm:reg-rel=0.05", RegUnits::Relative, 0.05),
        ("tsc-hmm:reg-rel=0.05", RegUnits::Relative, 0.05),
        ("gmm:reg-rel=0.05", RegUnits::Relative, 0.05),
        ("gmm-tsc:reg-rel=0.05", RegUnits::Relative, 0.05),
        ("hmm-cv:reg-rel=0.05", RegUnits::Relative, 0.05),
        ("tsc-hmm-cv:reg-rel=0.05", RegUnits::Relative, 0.05),
    ] {
        let m = parse_method(spec, &d).unwrap().method;
        assert_eq!(units(&m), want, "{spec}");
        if let Some((r, _, _)) = m.regularisation() {
            assert_eq!(r, reg, "{spec}");
        }
    }
    // auto: the unit passes to every candidate, whose reg the grid chooses.
    let m = parse_method("auto:reg-units=relative,grid=small", &d)
        .unwrap()
        .method;
    assert_eq!(units(&m), RegUnits::Relative);
    let m = parse_method("auto:grid=small", &d).unwrap().method;
    assert_eq!(units(&m), RegUnits::Absolute);
    for (spec, words) in [
        ("hmm:reg=0.1,reg-rel=0.1", "both given"),
        ("hmm:reg-rel=0.1,reg-units=absolute", "both given"),
        ("hmm:reg-units=metres", "absolute, relative"),
        ("hmm:reg-rel=-1", "reg"),
        ("hmm:reg-rel=x", "reg-rel=x"),
        ("auto:reg-rel=0.1", "auto chooses"),
    ] {
        let e = parse_method(spec, &d).unwrap_err();
        assert!(e.contains(words), "{spec}: `{e}` does not say `{words}`");
    }
}

#[test]
fn a_relative_model_file_is_version_2_keeps_its_unit_and_reports_it() {
    let (dir, data) = interaction_folder(6, 3, 5, plain);
    let test = data.join("test_00.csv");
    let rel = dir.path().join("rel.json");
    let report = phasekit()
        .args([
            "fit",
            "--method",
            "hmm:reg-rel=0.05",
            "--format",
            "json",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(&rel)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let report: serde_json::Value = serde_json::from_slice(&report).unwrap();
    assert_eq!(report["regularisation_unit"], "relative");
    assert_eq!(report["regularisation"], 0.05);
    assert_eq!(
        report["regularisation_per_feature"]
            .as_array()
            .unwrap()
            .len(),
        report["features"].as_array().unwrap().len()
    );
    let j = model_json(&rel);
    assert_eq!(j["version"], 2);
    assert_eq!(
        j["method"]["settings"]["reg_units"], "relative",
        "{}",
        j["method"]
    );
    // The file reads back (predict) and its unit survives a round trip.
    phasekit()
        .args(["predict", "--model"])
        .arg(&rel)
        .arg("--data")
        .arg(&test)
        .assert()
        .success();
    let back: phasekit_cli::model_file::ModelFile =
        phasekit_cli::model_file::ModelFile::load(&rel).unwrap();
    assert_eq!(units(&back.method.settings), RegUnits::Relative);
    assert!(!back.fit.regularisation_per_feature.is_empty());
    // Markdown says the unit.
    let md = phasekit()
        .args([
            "fit",
            "--method",
            "hmm:reg-rel=0.05",
            "--format",
            "md",
            "--data",
        ])
        .arg(&data)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let md = String::from_utf8(md).unwrap();
    assert!(md.contains("5e-2 × each feature's variance"), "{md}");
    // The absolute default: version 1, no unit written, reported as data units².
    let abs = dir.path().join("abs.json");
    let md = phasekit()
        .args(["fit", "--method", "hmm", "--format", "md", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&abs)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    assert!(String::from_utf8(md)
        .unwrap()
        .contains("1e-2 data units² on every covariance diagonal"));
    let j = model_json(&abs);
    assert_eq!(j["version"], 1);
    assert!(j["method"]["settings"].get("reg_units").is_none());
}
