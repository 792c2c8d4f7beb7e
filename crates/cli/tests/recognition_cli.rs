//! The library of interactions on the command line: `fit --library`,
//! `recognise`, `stream` with a library, `plot recognition`, `evaluate --task
//! recognition`, and their bad inputs.

use crate::common;

use common::{phasekit, plain, write_frames};
use phasekit_tsc::synthetic::{generate_kind, Kind};
use predicates::prelude::*;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

/// `data/<kind>/{train,test}_NN.csv` for handshake, wave and handover
/// (6 training and 2 test demonstrations each).
fn library_data() -> (TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    for kind in [Kind::Handshake, Kind::Wave, Kind::Handover] {
        let folder = data.join(kind.name());
        std::fs::create_dir_all(&folder).unwrap();
        for (i, demo) in generate_kind(kind, 8, 3).iter().enumerate() {
            let name = if i < 6 {
                format!("train_{i:02}.csv")
            } else {
                format!("test_{:02}.csv", i - 6)
            };
            write_frames(&folder.join(name), &demo.frames, &mut plain);
        }
    }
    (dir, data)
}

fn fit_library(data: &Path, out: &Path) -> serde_json::Value {
    let o = phasekit()
        .args([
            "fit",
            "--library",
            "--method",
            "hmm",
            "--format",
            "json",
            "--data",
        ])
        .arg(data)
        .arg("-o")
        .arg(out)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    serde_json::from_slice(&o).unwrap()
}

/// The human's raw columns of a demonstration file, one CSV line per frame.
fn human_lines(file: &Path) -> Vec<String> {
    std::fs::read_to_string(file)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').take(3).collect::<Vec<_>>().join(","))
        .collect()
}

#[test]
fn fit_a_library_recognise_and_stream() {
    let (dir, data) = library_data();
    let lib = dir.path().join("lib.json");
    let report = fit_library(&data, &lib);
    let names: Vec<&str> = report["actions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["action"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["handover", "handshake", "wave"]);
    assert_eq!(report["library"], true);
    assert!(report["calibration"]["likelihood_per_frame"].is_number());
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&lib).unwrap()).unwrap();
    assert_eq!(file["format"], "phasekit-library");
    assert_eq!(file["version"], 1);

    // recognise: per-frame posterior and decision.
    let wave = data.join("wave/test_00.csv");
    let out = phasekit()
        .args(["recognise", "--model"])
        .arg(&lib)
        .arg("--data")
        .arg(&wave)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let text = String::from_utf8(out).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "file,frame,decision,p_handover,p_handshake,p_wave"
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), human_lines(&wave).len());
    let last = rows.last().unwrap();
    assert_eq!(last[2], "wave");
    let p: Vec<f64> = last[3..].iter().map(|v| v.parse().unwrap()).collect();
    assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-9 && p[2] > 0.99);

    // JSON, the composed HMM and the robot's prediction.
    let out = phasekit()
        .args(["recognise", "--composed", "--robot", "--json", "--model"])
        .arg(&lib)
        .arg("--data")
        .arg(&wave)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let j: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(j["actions"].as_array().unwrap().len(), 3);
    // The composed HMM: wave during the motion; at its end the hand rests again.
    let decisions = j["decision"].as_array().unwrap();
    assert_eq!(decisions[decisions.len() / 2], "wave");
    assert!(["wave", "rest"].contains(&decisions.last().unwrap().as_str().unwrap()));
    assert_eq!(j["robot_features"][0], "p2_wrist_x");
    assert_eq!(j["rest"].as_array().unwrap().len(), rows.len());

    // stream: one line per frame with the decision, p_<action> and the robot's frame.
    let mut input = vec!["p1_wrist_x,p1_wrist_y,p1_wrist_z".to_string()];
    input.extend(human_lines(&wave));
    input.insert(20, "1,2".into());
    // A glitch no state of any action explains: rejected, taken as not observed.
    input.insert(40, "1e200,0,0".into());
    // The stream's input safety holds for a library: a line that is not a
    // frame stops it by default, naming the line…
    phasekit()
        .args(["stream", "--quiet", "--model"])
        .arg(&lib)
        .write_stdin(input.join("\n") + "\n")
        .assert()
        .failure()
        .stderr(predicate::str::contains(
            "stdin line 21: 2 values, expected 3",
        ));
    // …a header without the library's human columns is refused…
    phasekit()
        .args(["stream", "--quiet", "--model"])
        .arg(&lib)
        .write_stdin("p1_wrist_x,p1_wrist_y,p1_elbow_z\n0,0,0\n")
        .assert()
        .failure()
        .stderr(predicate::str::contains(
            "lacks the model's human columns `p1_wrist_z`",
        ));
    // …and --on-bad-line missing goes on with a frame with nothing observed.
    let assert = phasekit()
        .args([
            "stream",
            "--quiet",
            "--recogniser",
            "per-action",
            "--on-bad-line",
            "missing",
            "--model",
        ])
        .arg(&lib)
        .write_stdin(input.join("\n") + "\n")
        .assert()
        .success()
        .stderr(predicate::str::contains(
            "stdin line 21: 2 values, expected 3",
        ));
    let text = String::from_utf8(assert.get_output().stdout.clone()).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "frame,decision,p_handover,p_handshake,p_wave,p2_wrist_x,p2_wrist_y,p2_wrist_z,d_p2_wrist_x,d_p2_wrist_y,d_p2_wrist_z,status"
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(
        rows.len(),
        input.len() - 1,
        "every frame (the bad line as a frame with nothing observed)"
    );
    assert!(rows[19].ends_with(",unobserved"), "{}", rows[19]);
    assert!(rows[39].ends_with(",rejected"), "{}", rows[39]);
    for r in &rows {
        let cells: Vec<&str> = r.split(',').collect();
        assert_eq!(cells.len(), 12, "{r}");
        assert!(
            cells[2..11]
                .iter()
                .all(|v| v.parse::<f64>().unwrap().is_finite()),
            "{r}"
        );
    }
    // The glitch does not derail the recognition.
    assert!(rows[45].contains(",wave,"), "{}", rows[45]);
    // Wave through the motion (the filters reset themselves when it ends).
    assert!(
        rows[rows.len() / 2].contains(",wave,"),
        "{}",
        rows[rows.len() / 2]
    );
    assert!(rows.iter().filter(|r| r.contains(",wave,")).count() > rows.len() / 2);
    // The composed HMM (the default with a library) adds p_rest.
    phasekit()
        .args(["stream", "--quiet", "--no-header", "--model"])
        .arg(&lib)
        .write_stdin(human_lines(&wave)[..30].join("\n") + "\n")
        .assert()
        .success()
        .stdout(predicate::function(|s: &str| {
            s.lines().count() == 30 && s.lines().all(|l| l.split(',').count() == 13)
        }));

    // Pictures.
    phasekit()
        .args(["plot", "recognition", "--model"])
        .arg(&lib)
        .arg("--data")
        .arg(&wave)
        .arg("-o")
        .arg(dir.path().join("posterior.svg"))
        .assert()
        .success();
    let svg = std::fs::read_to_string(dir.path().join("posterior.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("p(action | frames so far)"));
}

#[test]
fn libraries_and_single_models_refuse_each_other() {
    let (dir, data) = library_data();
    let lib = dir.path().join("lib.json");
    fit_library(&data, &lib);
    let single = dir.path().join("single.json");
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(data.join("wave"))
        .arg("-o")
        .arg(&single)
        .assert()
        .success();
    let test = data.join("wave/test_00.csv");
    for cmd in [&["predict"][..], &["segment"], &["plot", "prediction"]] {
        let mut c = phasekit();
        c.args(cmd)
            .arg("--model")
            .arg(&lib)
            .arg("--data")
            .arg(&test);
        if cmd[0] == "plot" {
            c.arg("-o").arg(dir.path().join("x.svg"));
        }
        c.assert().failure().stderr(predicate::str::contains(
            "this is a library of interactions (made by `fit --library`), not a single model",
        ));
    }
    phasekit()
        .args(["recognise", "--model"])
        .arg(&single)
        .arg("--data")
        .arg(&test)
        .assert()
        .failure()
        .stderr(predicate::str::contains(
            "this is a single model (made by `phasekit fit`), not a library of interactions",
        ));
    phasekit()
        .args(["stream", "--recogniser", "composed", "--model"])
        .arg(&single)
        .write_stdin("0,0,0\n")
        .assert()
        .failure()
        .stderr(predicate::str::contains("--recogniser needs a library"));
    // A corrupted library: a prior that does not sum to 1.
    let mut j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&lib).unwrap()).unwrap();
    j["library"]["prior"][0] = serde_json::json!(0.9);
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, j.to_string()).unwrap();
    phasekit()
        .args(["recognise", "--model"])
        .arg(&bad)
        .arg("--data")
        .arg(&test)
        .assert()
        .failure()
        .stderr(
            predicate::str::contains("bad.json: corrupted library file").and(
                predicate::str::contains("the prior must hold one positive probability per action"),
            ),
        );
}

#[test]
fn bad_libraries_are_refused_with_clear_errors() {
    let (dir, data) = library_data();
    let out = dir.path().join("lib.json");
    // One action.
    let one = dir.path().join("one");
    std::fs::create_dir_all(&one).unwrap();
    std::fs::rename(data.join("wave"), one.join("wave")).unwrap();
    phasekit()
        .args(["fit", "--library", "--data"])
        .arg(&one)
        .arg("-o")
        .arg(&out)
        .assert()
        .failure()
        .stderr(predicate::str::contains(
            "a library needs at least 2 action folders (each with train_* files), found 1 (wave)",
        ));
    // Actions whose columns differ: one action has an extra wrist column.
    let odd = data.join("handover/train_00.csv");
    for f in std::fs::read_dir(data.join("handover")).unwrap() {
        let f = f.unwrap().path();
        let text = std::fs::read_to_string(&f).unwrap();
        let widened: Vec<String> = text
            .lines()
            .enumerate()
            .map(|(i, l)| {
                if i == 0 {
                    format!("{l},p1_wrist_w")
                } else {
                    format!("{l},0")
                }
            })
            .collect();
        std::fs::write(&f, widened.join("\n") + "\n").unwrap();
    }
    assert!(odd.exists());
    phasekit()
        .args(["fit", "--library", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&out)
        .assert()
        .failure()
        .stderr(
            predicate::str::contains("action `handshake`: its features (").and(
                predicate::str::contains("differ from those of action `handover`"),
            ),
        );
    assert!(!out.exists(), "no library written");
    // --action with --library.
    phasekit()
        .args(["fit", "--library", "--action", "wave", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&out)
        .assert()
        .failure()
        .stderr(predicate::str::contains(
            "--library fits every action folder",
        ));
    // Library flags with the prediction task.
    phasekit()
        .args(["evaluate", "--prior", "demonstrations", "--data"])
        .arg(&data)
        .assert()
        .failure()
        .stderr(predicate::str::contains("need --task recognition"));
}

#[test]
fn evaluate_recognition_prints_rows_and_draws_the_accuracy_curve() {
    let (dir, data) = library_data();
    let prefix = dir.path().join("rec");
    let out = phasekit()
        .args([
            "evaluate",
            "--task",
            "recognition",
            "--methods",
            "hmm",
            "--seeds",
            "2",
            "--json",
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
    let j: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(j["task"], "recognition");
    let rows = j["recognition"].as_array().unwrap();
    assert_eq!(rows.len(), 4 * 10, "3 actions and all, 10 fractions");
    for r in rows {
        for key in ["action", "fraction", "accuracy", "seeds"] {
            assert!(r.get(key).is_some(), "{key} in {r}");
        }
        assert_eq!(r["seeds"], 2);
    }
    let all_at_end = rows
        .iter()
        .find(|r| r["action"] == "all" && r["fraction"] == 1.0)
        .unwrap();
    assert_eq!(
        all_at_end["accuracy"], 1.0,
        "generated interactions are all recognised"
    );
    assert_eq!(j["end_to_end"].as_array().unwrap().len(), 4);
    assert!(!j["unknown"].as_array().unwrap().is_empty());
    assert_eq!(j["streams"].as_array().unwrap().len(), 4);
    let md = std::fs::read_to_string(prefix.with_extension("md")).unwrap();
    for heading in [
        "Accuracy after observing",
        "Confusion of hmm after observing a third",
        "End to end",
        "Unknown motions",
        "Continuous streams",
    ] {
        assert!(md.contains(heading), "{heading}");
    }
    phasekit()
        .args(["plot", "recognition", "--results"])
        .arg(prefix.with_extension("json"))
        .arg("-o")
        .arg(dir.path().join("accuracy.svg"))
        .assert()
        .success();
    let svg = std::fs::read_to_string(dir.path().join("accuracy.svg")).unwrap();
    assert!(svg.contains("observed (% of the demonstration)"));
    // The accuracy rows as CSV.
    phasekit()
        .args([
            "evaluate",
            "--task",
            "recognition",
            "--methods",
            "hmm",
            "--seeds",
            "1",
            "--format",
            "csv",
            "--data",
        ])
        .arg(&data)
        .assert()
        .success()
        .stdout(predicate::str::starts_with(
            "method,action,fraction,accuracy,std,seeds\nhmm,handover,0.1,",
        ));
}

#[test]
fn recognition_commands_have_help_with_examples() {
    for cmd in [&["recognise"][..], &["plot", "recognition"]] {
        phasekit()
            .args(cmd)
            .arg("--help")
            .assert()
            .success()
            .stdout(predicate::str::contains("Example"));
    }
}

#[test]
fn a_library_records_the_methods_that_recognise_and_predict() {
    let (dir, data) = library_data();
    let lib = dir.path().join("lib.json");
    let out = phasekit()
        .args([
            "fit",
            "--library",
            "--method",
            "hmm",
            "--recognition-method",
            "hmm:states=3",
            "--action-method",
            "wave=gmm:states=3",
            "--format",
            "json",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(&lib)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let report: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(report["recognition_method"], "hmm:states=3");
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&lib).unwrap()).unwrap();
    assert_eq!(file["recognition_method"], "hmm:states=3");
    let actions = file["actions"].as_array().unwrap();
    let wave = actions.iter().find(|a| a["name"] == "wave").unwrap();
    assert_eq!(wave["method"], "gmm:states=3");
    assert!(actions
        .iter()
        .filter(|a| a["name"] != "wave")
        .all(|a| a.get("method").is_none()));
    // An action the data does not have is refused by name.
    phasekit()
        .args([
            "fit",
            "--library",
            "--action-method",
            "fistbump=hmm",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(dir.path().join("other.json"))
        .assert()
        .failure()
        .stderr(predicate::str::contains("no action `fistbump`"));
    // The picture says what recognised.
    phasekit()
        .args(["plot", "recognition", "--model"])
        .arg(&lib)
        .arg("--data")
        .arg(data.join("wave/test_00.csv"))
        .arg("-o")
        .arg(dir.path().join("p.svg"))
        .assert()
        .success();
    let svg = std::fs::read_to_string(dir.path().join("p.svg")).unwrap();
    assert!(svg.contains("hmm (wave: gmm:states=3), recognised by hmm:states=3"));
}

#[test]
fn a_standardised_library_judges_its_choices_in_the_files_units() {
    // `fit --library --standardise`: the roles carry the deviations as error
    // units (what an action fitted by `auto` is chosen by), one per robot dim.
    let (dir, data) = library_data();
    let lib = dir.path().join("lib.json");
    phasekit()
        .args([
            "fit",
            "--library",
            "--standardise",
            "--method",
            "hmm",
            "--data",
        ])
        .arg(&data)
        .arg("-o")
        .arg(&lib)
        .assert()
        .success();
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&lib).unwrap()).unwrap();
    let roles = &file["library"]["roles"];
    let std = file["standardisation"]["std"].as_array().unwrap();
    let robot = roles["robot"].as_array().unwrap();
    let units = roles["error_units"].as_array().unwrap();
    assert_eq!(units.len(), robot.len());
    for (u, r) in units.iter().zip(robot) {
        assert_eq!(u, &std[r.as_u64().unwrap() as usize]);
    }
    // Without --standardise there are none.
    let plain_lib = dir.path().join("plain.json");
    fit_library(&data, &plain_lib);
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&plain_lib).unwrap()).unwrap();
    assert!(file["library"]["roles"].get("error_units").is_none());
}

#[test]
fn a_library_says_by_its_version_what_a_reader_must_know() {
    // Plain hidden-Markov models: version 1, as every library before. One
    // action with a relative regularisation (its own method), or recognised
    // by models with one: version 2, the model files' version for it (a
    // version-1 reader would take the amount as absolute); an action that
    // is a mean of several models: 5. This build reads them, and refuses a
    // newer one by version.
    let (dir, data) = library_data();
    let fit = |extra: &[&str], name: &str| {
        let lib = dir.path().join(name);
        phasekit()
            .args(["fit", "--library", "--method", "hmm"])
            .args(extra)
            .arg("--data")
            .arg(&data)
            .arg("-o")
            .arg(&lib)
            .assert()
            .success();
        let j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&lib).unwrap()).unwrap();
        (lib, j)
    };
    assert_eq!(fit(&[], "hmm.json").1["version"], 1);
    let (_, j) = fit(&["--action-method", "wave=hmm:reg-rel=0.01"], "own.json");
    assert_eq!(j["version"], 2);
    let (_, j) = fit(
        &["--recognition-method", "hmm:states=3,reg-rel=0.01"],
        "second.json",
    );
    assert_eq!(j["version"], 2);
    let (own, j) = fit(
        &[
            "--action-method",
            "wave=auto:grid=small,families=hmm,ensemble=2",
        ],
        "mean.json",
    );
    assert_eq!(j["version"], 5);
    phasekit()
        .args(["recognise", "--model"])
        .arg(&own)
        .arg("--data")
        .arg(data.join("wave/test_00.csv"))
        .assert()
        .success();
    let max = phasekit_cli::library_file::VERSION;
    let mut newer = j.clone();
    newer["version"] = (max + 1).into();
    let path = dir.path().join("newer.json");
    std::fs::write(&path, serde_json::to_string(&newer).unwrap()).unwrap();
    phasekit()
        .args(["recognise", "--model"])
        .arg(&path)
        .arg("--data")
        .arg(data.join("wave/test_00.csv"))
        .assert()
        .failure()
        .stderr(predicate::str::contains(format!(
            "library file version {} is not supported",
            max + 1
        )))
        .stderr(predicate::str::contains(format!(
            "reads versions 1 to {max}"
        )));
}
