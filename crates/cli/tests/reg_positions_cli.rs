//! The regularisation relative to the positions from the command line
//! (`reg-pos=R`, `reg-units=positions`), the velocity pairs the command
//! records, model-file versions of what version-2 readers do not know (this
//! unit; `auto`'s calibration by left-out demonstrations), files of the
//! calibration flag read back as the rule of the time, and `evaluate` giving
//! the same numbers with and without `--standardise`.

use crate::common;

use common::{interaction_folder, model_json, phasekit, plain};
use phasekit_cli::data::{Layout, Velocity};
use phasekit_cli::experiment::parse_method;
use phasekit_tsc::{Calibration, Method, PresetOptions, RegUnits};

#[test]
fn reg_pos_sets_the_unit_and_refuses_contradictions() {
    let d = PresetOptions::default();
    for spec in [
        "hmm:reg-pos=0.05",
        "hmm:reg=0.05,reg-units=positions",
        "tsc-hmm:reg-pos=0.05",
        "hsmm:reg-pos=0.05",
        "gmm:reg-pos=0.05",
    ] {
        let m = parse_method(spec, &d).unwrap().method;
        assert_eq!(
            m.regularisation().unwrap().0..=m.regularisation().unwrap().0,
            0.05..=0.05,
            "{spec}"
        );
        assert_eq!(m.regularisation().unwrap().1, RegUnits::Positions, "{spec}");
    }
    for (spec, words) in [
        ("hmm:reg-pos=0.1,reg-rel=0.1", "both given"),
        ("hmm:reg=0.1,reg-pos=0.1", "both given"),
        ("hmm:reg-pos=0.1,reg-units=relative", "both given"),
        ("hmm:reg-units=metres", "positions"),
        ("auto:reg-pos=0.1", "auto chooses"),
    ] {
        let e = parse_method(spec, &d).unwrap_err();
        assert!(e.contains(words), "{spec}: `{e}` does not say `{words}`");
    }
}

#[test]
fn the_layout_pairs_each_velocity_with_its_column() {
    let layout = |velocity| Layout {
        human_columns: vec!["a".into(), "b".into()],
        robot_columns: vec!["c".into()],
        features: Vec::new(),
        human: match velocity {
            Velocity::Both | Velocity::Human => vec![0, 1, 2, 3],
            _ => vec![0, 1],
        },
        robot: match velocity {
            Velocity::Both => vec![4, 5],
            Velocity::Human => vec![4],
            Velocity::Robot => vec![2, 3],
            Velocity::None => vec![2],
        },
        robot_positions: vec![0],
        velocity,
    };
    assert_eq!(
        layout(Velocity::Both).velocity_pairs(),
        vec![(2, 0), (3, 1), (5, 4)]
    );
    assert_eq!(
        layout(Velocity::Human).velocity_pairs(),
        vec![(2, 0), (3, 1)]
    );
    assert_eq!(layout(Velocity::Robot).velocity_pairs(), vec![(3, 2)]);
    assert!(layout(Velocity::None).velocity_pairs().is_empty());
    let roles = layout(Velocity::Both).roles().unwrap();
    assert_eq!(roles.velocities(), &[(2, 0), (3, 1), (5, 4)]);
}

/// The `auto` method of a model file's settings.
fn cross_validation(m: &Method) -> &phasekit_tsc::CrossValidation {
    match m {
        Method::CrossValidated(cv) => cv,
        _ => panic!("not a cross-validated method"),
    }
}

#[test]
fn files_say_version_3_for_what_version_2_readers_do_not_know() {
    let (dir, data) = interaction_folder(6, 3, 5, plain);
    let test = data.join("test_00.csv");
    let fit = |method: &str, name: &str| {
        let path = dir.path().join(name);
        phasekit()
            .args(["fit", "--method", method, "--data"])
            .arg(&data)
            .arg("-o")
            .arg(&path)
            .assert()
            .success();
        phasekit()
            .args(["predict", "--model"])
            .arg(&path)
            .arg("--data")
            .arg(&test)
            .assert()
            .success();
        path
    };
    // reg-pos: version 3, the unit and the velocity pairs in the file.
    let j = model_json(&fit("hmm:reg-pos=0.1", "pos.json"));
    assert_eq!(j["version"], 3);
    assert_eq!(j["method"]["settings"]["reg_units"], "positions");
    assert_eq!(j["roles"]["velocities"].as_array().unwrap().len(), 6);
    // auto calibrates for a new demonstration by default: version 4, by
    // name; by left-out demonstrations version 3, by name; with
    // calibrate=frames the flag of version 2, which older readers know.
    let predictive = model_json(&fit(
        "auto:grid=small,folds=3,halving=off,ensemble=1",
        "auto4.json",
    ));
    assert_eq!(predictive["version"], 4);
    assert_eq!(
        predictive["method"]["settings"]["calibration"],
        "predictive"
    );
    let auto = fit(
        "auto:grid=small,folds=3,halving=off,calibrate=demonstrations,ensemble=1",
        "auto.json",
    );
    let j = model_json(&auto);
    assert_eq!(j["version"], 3);
    assert_eq!(j["method"]["settings"]["calibration"], "demonstrations");
    let lambda = j["fit"]["covariance_calibration"]["demonstration_inflation"]
        .as_f64()
        .unwrap();
    assert!(lambda >= 1.0);
    let frames = fit(
        "auto:grid=small,folds=3,halving=off,calibrate=frames,ensemble=1",
        "frames.json",
    );
    let jf = model_json(&frames);
    assert_eq!(jf["version"], 2);
    assert_eq!(jf["method"]["settings"]["calibration"], true);
    assert_eq!(
        jf["fit"]["covariance_calibration"]["demonstration_inflation"],
        1.0
    );
    // Same folds, same choice: the widened factor is the pooled one × λ.
    let scale = |j: &serde_json::Value| {
        j["fit"]["covariance_calibration"]["scale"]
            .as_f64()
            .unwrap()
    };
    assert_eq!(scale(&j), scale(&jf) * lambda);
    // A file written when the calibration was a flag (no λ): the pooled rule,
    // λ = 1, and it predicts as it did.
    let mut old = jf.clone();
    old["fit"]["covariance_calibration"]
        .as_object_mut()
        .unwrap()
        .remove("demonstration_inflation");
    let old_path = dir.path().join("old.json");
    std::fs::write(&old_path, serde_json::to_string(&old).unwrap()).unwrap();
    let back = phasekit_cli::model_file::ModelFile::load(&old_path).unwrap();
    assert_eq!(
        cross_validation(&back.method.settings).calibration(),
        Calibration::Frames
    );
    let c = back.fit.covariance_calibration.unwrap();
    assert_eq!(c.demonstration_inflation, 1.0);
    let predict = |model: &std::path::Path| {
        phasekit()
            .args(["predict", "--covariance", "--model"])
            .arg(model)
            .arg("--data")
            .arg(&test)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone()
    };
    assert_eq!(predict(&old_path), predict(&frames));
    // A version-2 file cannot claim what needs 3.
    let mut lying = j.clone();
    lying["version"] = 2.into();
    let lying_path = dir.path().join("lying.json");
    std::fs::write(&lying_path, serde_json::to_string(&lying).unwrap()).unwrap();
    let e = phasekit_cli::model_file::ModelFile::load(&lying_path).unwrap_err();
    assert!(e.message.contains("need version 3"), "{}", e.message);
}

/// `evaluate --format json` rows: (method, per-seed MSE).
fn per_seed(args: &[&str], data: &std::path::Path) -> Vec<(String, Vec<f64>)> {
    let out = phasekit()
        .args(["evaluate", "--seeds", "3", "--format", "json", "--data"])
        .arg(data)
        .args(args)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let j: serde_json::Value = serde_json::from_slice(&out).unwrap();
    j["results"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["baseline"] == false)
        .map(|r| {
            (
                r["method"].as_str().unwrap().to_string(),
                r["per_seed_mse"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect(),
            )
        })
        .collect()
}

#[test]
fn evaluate_gives_the_same_numbers_with_and_without_standardise() {
    // The same demonstrations, each feature z-scored by --standardise: reg-pos
    // fits the same model (to rounding), so every seed's MSE is the same;
    // the absolute unit with this amount does not agree.
    let (_dir, data) = interaction_folder(8, 4, 6, plain);
    let methods = "hmm:states=5,reg-pos=0.1,hmm:states=5,reg=0.001";
    let metres = per_seed(&["--methods", methods], &data);
    let z = per_seed(&["--methods", methods, "--standardise"], &data);
    let names = |rows: &[(String, Vec<f64>)]| rows.iter().map(|r| r.0.clone()).collect::<Vec<_>>();
    assert_eq!(metres.len(), 2, "{:?}", names(&metres));
    assert_eq!(names(&metres), names(&z));
    assert!(metres.iter().all(|(_, mse)| !mse.is_empty()));
    for ((name, a), (_, b)) in metres.iter().zip(&z) {
        let worst = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs() / x)
            .fold(0.0, f64::max);
        if name.contains("reg-pos") {
            assert!(worst < 1e-9, "{name}: {worst:e}");
        } else {
            assert!(worst > 1e-3, "{name}: only {worst:e}");
        }
    }
}

#[test]
fn auto_chooses_the_same_with_and_without_standardise() {
    // On z-scores `auto` judges the held-out error in the file's units (the
    // deviations are the error units), and its candidates are unit-free: the
    // same members, the same predictions, every seed. The robot's last
    // column in millimetres, so that its error dominates the file's sum and
    // not the z-scores' (without the units the MSE of a seed differs by 5 %
    // even with every column in metres).
    let (_dir, data) = interaction_folder(8, 4, 6, |_, k, v: f64| {
        if k == 5 {
            (v * 1000.0).to_string()
        } else {
            v.to_string()
        }
    });
    let methods = "auto:grid=relative,families=hmm+gmm,ensemble=2";
    let metres = per_seed(&["--methods", methods], &data);
    let z = per_seed(&["--methods", methods, "--standardise"], &data);
    assert_eq!(metres.len(), 1);
    assert_eq!(metres[0].1.len(), 3);
    for (a, b) in metres[0].1.iter().zip(&z[0].1) {
        assert!((a - b).abs() <= 1e-6 * a, "{a} vs {b}");
    }
    // `fit` records the units in the model file and its table is in the file's units.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("auto.json");
    let report = phasekit()
        .args([
            "fit",
            "--standardise",
            "--format",
            "md",
            "--method",
            methods,
        ])
        .arg("--data")
        .arg(&data)
        .arg("-o")
        .arg(&out)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let report = String::from_utf8(report).unwrap();
    assert!(
        report.contains("per held-out frame, data units²"),
        "{report}"
    );
    let units = &model_json(&out)["roles"]["error_units"];
    let stds = &model_json(&out)["standardisation"]["std"];
    let robot = model_json(&out)["roles"]["robot"].clone();
    assert_eq!(
        units.as_array().unwrap().len(),
        robot.as_array().unwrap().len()
    );
    for (u, r) in units
        .as_array()
        .unwrap()
        .iter()
        .zip(robot.as_array().unwrap())
    {
        assert_eq!(u, &stds[r.as_u64().unwrap() as usize]);
    }
}

#[test]
fn the_fit_report_names_the_positions_unit() {
    let (dir, data) = interaction_folder(5, 4, 6, plain);
    let out = dir.path().join("pos.json");
    let report = |method: &str, format: &str| {
        let o = phasekit()
            .args(["fit", "--method", method, "--format", format, "--data"])
            .arg(&data)
            .arg("-o")
            .arg(&out)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone();
        String::from_utf8(o).unwrap()
    };
    let json: serde_json::Value = serde_json::from_str(&report("hmm:reg-pos=0.2", "json")).unwrap();
    assert_eq!(json["regularisation_unit"], "positions");
    assert_eq!(json["regularisation"], 0.2);
    let text = report("hmm:reg-pos=0.2", "md");
    assert!(text.contains("each position's variance"), "{text}");
    // `auto` reports the unit of the candidate it chose (every candidate of
    // this grid and family is in positions' variances).
    let json: serde_json::Value = serde_json::from_str(&report(
        "auto:grid=positions,families=hmm,folds=2,halving=off",
        "json",
    ))
    .unwrap();
    assert!(
        json["chosen"].as_str().unwrap().contains("reg-pos"),
        "{json}"
    );
    assert_eq!(json["regularisation_unit"], "positions");
}
