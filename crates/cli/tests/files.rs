//! Files as real users have them: quoted globs and process substitutions in
//! `--data`, a folder where a file is expected, the same file given twice,
//! dangling links, text columns the model does not use, headers that need
//! quoting, huge cells, other delimiters, careless numbers, too many columns,
//! and help whose examples can be copied.

use crate::common;

use common::{fit_model, interaction_folder, phasekit, plain};
use predicates::prelude::*;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

fn setup() -> (TempDir, PathBuf, PathBuf) {
    let (dir, data) = interaction_folder(8, 9, 6, plain);
    let model = dir.path().join("m.json");
    fit_model(&data, "hmm", &model);
    (dir, data, model)
}

fn stdout_of(cmd: &mut assert_cmd::Command) -> Vec<u8> {
    cmd.assert().success().get_output().stdout.clone()
}

#[test]
fn data_takes_quoted_globs_and_pipes() {
    let (dir, data, model) = setup();
    let pattern = format!("{}/train_*.csv", data.display());
    let expanded: Vec<PathBuf> = (0..6)
        .map(|i| data.join(format!("train_{i:02}.csv")))
        .collect();
    let a = dir.path().join("a.json");
    let b = dir.path().join("b.json");
    phasekit()
        .args(["fit", "--method", "hmm", "--data", &pattern, "-o"])
        .arg(&a)
        .assert()
        .success();
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .args(&expanded)
        .arg("-o")
        .arg(&b)
        .assert()
        .success();
    let strip = |p: &Path| {
        let mut v = common::model_json(p);
        v["fit"]["fit_seconds"] = serde_json::Value::Null;
        v
    };
    assert_eq!(
        strip(&a),
        strip(&b),
        "a quoted glob is the files it matches"
    );
    phasekit()
        .args([
            "fit",
            "--data",
            &format!("{}/nothing_*.csv", data.display()),
            "-o",
        ])
        .arg(&a)
        .assert()
        .failure()
        .stderr(predicate::str::contains("no file matches this pattern"));
    // A pipe, as `--data <(cat test_00.csv)` gives, is read like the file.
    #[cfg(unix)]
    {
        let fifo = dir.path().join("pipe");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
        let text = std::fs::read(data.join("test_00.csv")).unwrap();
        let writer = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::write(fifo, text).unwrap())
        };
        let from_pipe = stdout_of(
            phasekit()
                .args(["predict", "--model"])
                .arg(&model)
                .arg("--data")
                .arg(&fifo),
        );
        writer.join().unwrap();
        let from_file = stdout_of(
            phasekit()
                .args(["predict", "--model"])
                .arg(&model)
                .arg("--data")
                .arg(data.join("test_00.csv")),
        );
        assert_eq!(from_pipe, from_file);
    }
}

#[test]
fn a_folder_where_a_file_is_expected_names_the_file() {
    let (dir, data, model) = setup();
    phasekit()
        .args(["plot", "prediction", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&data)
        .arg("-o")
        .arg(dir.path().join("p.svg"))
        .assert()
        .failure()
        .stderr(
            predicate::str::contains("is a folder, not a demonstration file")
                .and(predicate::str::contains("test_00.csv")),
        );
}

#[test]
fn the_same_file_twice_and_dangling_links_are_errors() {
    let (dir, data, _model) = setup();
    let f = data.join("train_00.csv");
    let out = dir.path().join("x.json");
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .args([&f, &f, &f])
        .arg("-o")
        .arg(&out)
        .assert()
        .failure()
        .stderr(predicate::str::contains("given twice"));
    // Through a pattern that overlaps the folder's files.
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&data)
        .arg(format!("{}/train_0[01].csv", data.display()))
        .arg("-o")
        .arg(&out)
        .assert()
        .failure()
        .stderr(
            predicate::str::contains("are the same file")
                .or(predicate::str::contains("given twice")),
        );
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink("gone/train_99.csv", data.join("train_99.csv")).unwrap();
        phasekit()
            .args(["fit", "--method", "hmm", "--data"])
            .arg(&data)
            .arg("-o")
            .arg(&out)
            .assert()
            .failure()
            .stderr(
                predicate::str::contains("train_99.csv")
                    .and(predicate::str::contains("which does not exist")),
            );
    }
    assert!(!out.exists());
}

#[test]
fn columns_the_model_does_not_use_are_not_read() {
    let (dir, data, model) = setup();
    let text = std::fs::read_to_string(data.join("test_00.csv")).unwrap();
    let with_text: String = text
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 0 {
                format!("timestamp,label,{l}\n")
            } else {
                format!("2024-05-01T10:00:{i:02},shake,{l}\n")
            }
        })
        .collect();
    let f = dir.path().join("annotated.csv");
    std::fs::write(&f, with_text).unwrap();
    let a = stdout_of(
        phasekit()
            .args(["predict", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(&f),
    );
    let b = stdout_of(
        phasekit()
            .args(["predict", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(data.join("test_00.csv")),
    );
    assert_eq!(a, b);
    // fit reads the selected columns only, too.
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&f)
        .arg(data.join("train_00.csv"))
        .arg("-o")
        .arg(dir.path().join("x.json"))
        .assert()
        .failure()
        .stderr(predicate::str::contains("columns differ"));
    let g = dir.path().join("annotated2.csv");
    std::fs::copy(&f, &g).unwrap();
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&f)
        .arg(&g)
        .arg("-o")
        .arg(dir.path().join("x.json"))
        .assert()
        .success();
}

#[test]
fn output_headers_are_quoted_and_error_messages_cut_huge_cells() {
    let (dir, data, _model) = setup();
    // A robot column named `p2_wrist, x`.
    let rename = |p: &Path| {
        let text = std::fs::read_to_string(p).unwrap();
        text.replacen("p2_wrist_x", "\"p2_wrist, x\"", 1)
    };
    let odd = dir.path().join("odd");
    std::fs::create_dir(&odd).unwrap();
    for i in 0..6 {
        let name = format!("train_{i:02}.csv");
        std::fs::write(odd.join(&name), rename(&data.join(&name))).unwrap();
    }
    let model = dir.path().join("odd.json");
    phasekit()
        .args([
            "fit",
            "--method",
            "hmm",
            "--velocity",
            "none",
            "--robot",
            "p2_wrist*",
            "--data",
        ])
        .arg(&odd)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();
    let out = stdout_of(
        phasekit()
            .args(["predict", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(odd.join("train_00.csv")),
    );
    let mut r = csv::Reader::from_reader(&out[..]);
    let header = r.headers().unwrap().clone();
    assert_eq!(
        header.iter().collect::<Vec<_>>(),
        ["frame", "p2_wrist, x", "p2_wrist_y", "p2_wrist_z"]
    );
    assert!(r.records().all(|row| row.unwrap().len() == 4));
    // A 5 MB cell is named, not echoed.
    let text = std::fs::read_to_string(data.join("test_00.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    lines[3] = format!("{},0,0,0,0,0", "9".repeat(5_000_000) + "x");
    let f = dir.path().join("huge_cell.csv");
    std::fs::write(&f, lines.join("\n")).unwrap();
    let err = phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&f)
        .arg("-o")
        .arg(dir.path().join("x.json"))
        .assert()
        .failure()
        .get_output()
        .stderr
        .clone();
    let err = String::from_utf8(err).unwrap();
    assert!(err.len() < 400, "{} bytes of error", err.len());
    assert!(
        err.contains("row 4, column 1") && err.contains("(5000001 bytes)"),
        "{err}"
    );
}

#[test]
fn semicolon_and_tab_separated_files_are_recognised() {
    let (dir, data, model) = setup();
    let text = std::fs::read_to_string(data.join("test_00.csv")).unwrap();
    let want = stdout_of(
        phasekit()
            .args(["predict", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(data.join("test_00.csv")),
    );
    for (sep, name) in [(";", "semi.csv"), ("\t", "tab.csv")] {
        let f = dir.path().join(name);
        std::fs::write(&f, text.replace(',', sep)).unwrap();
        let got = stdout_of(
            phasekit()
                .args(["predict", "--model"])
                .arg(&model)
                .arg("--data")
                .arg(&f),
        );
        assert_eq!(got, want, "{name}");
    }
    // Decimal commas in a semicolon-separated file: said so.
    let f = dir.path().join("comma.csv");
    std::fs::write(&f, "p1_wrist_x;p1_wrist_y;p1_wrist_z\n0,25;0,5;0,1\n").unwrap();
    phasekit()
        .args(["predict", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&f)
        .assert()
        .failure()
        .stderr(
            predicate::str::contains("decimal comma")
                .and(predicate::str::contains("semicolon-separated")),
        );
}

#[test]
fn careless_numbers_are_refused_for_what_they_are() {
    let (dir, data, _model) = setup();
    let out = dir.path().join("x.json");
    let fit = |extra: &[&str]| {
        let mut c = phasekit();
        c.args(["fit", "--method", "hmm", "--data"])
            .arg(&data)
            .arg("-o")
            .arg(&out)
            .args(extra);
        c.assert()
    };
    fit(&["--reg", "-1"]).failure().code(2).stderr(
        predicate::str::contains("must be a finite number ≥ 0")
            .and(predicate::str::contains("unexpected argument").not()),
    );
    fit(&["--reg", "1e308"]).failure().stderr(
        predicate::str::contains("far too large").and(predicate::str::contains("increase").not()),
    );
    fit(&["--threads", "100000"])
        .failure()
        .stderr(predicate::str::contains("threads cannot help"));
    fit(&["--tol", "-1"])
        .failure()
        .stderr(predicate::str::contains(
            "--tol must be a finite number ≥ 0",
        ));
    assert!(!out.exists());
}

#[test]
fn too_many_columns_for_the_frames_is_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    // 19,970 columns (with velocities 39,940 features) and 230 frames: the fit
    // used to try to allocate 12.7 GB and abort.
    let cols = 19_970;
    let names: Vec<String> = (0..cols)
        .map(|c| {
            if c < cols / 2 {
                format!("h{c}")
            } else {
                format!("r{c}")
            }
        })
        .collect();
    let mut text = names.join(",") + "\n";
    let row = vec!["0"; cols].join(",") + "\n";
    for _ in 0..230 {
        text.push_str(&row);
    }
    let f = dir.path().join("wide.csv");
    std::fs::write(&f, text).unwrap();
    phasekit()
        .args([
            "fit", "--method", "hmm", "--human", "h*", "--robot", "r*", "--data",
        ])
        .arg(&f)
        .arg("-o")
        .arg(dir.path().join("m.json"))
        .assert()
        .failure()
        .code(1)
        .stderr(
            predicate::str::contains("39940 features from 230 frames")
                .and(predicate::str::contains("select fewer columns")),
        );
}

#[test]
fn segment_help_lists_only_formats_that_work_and_examples_do_not_wrap() {
    let help = |cmd: &[&str], cols: &str| {
        let out = phasekit()
            .args(cmd)
            .arg("--help")
            .env("COLUMNS", cols)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone();
        String::from_utf8(out).unwrap()
    };
    let seg = help(&["segment"], "100");
    assert!(
        seg.contains("csv, json or npy") && !seg.contains("md"),
        "{seg}"
    );
    phasekit()
        .args(["segment", "--format", "md"])
        .assert()
        .failure()
        .code(2);
    for cmd in [
        &["fit"][..],
        &["segment"],
        &["predict"],
        &["stream"],
        &["evaluate"],
        &["demo"],
        &["plot"],
        &["plot", "states"],
        &["plot", "prediction"],
        &[],
    ] {
        for cols in ["80", "100", "200"] {
            let text = help(cmd, cols);
            // Every line of an example block is indented: a wrapped command would
            // continue at the margin.
            let mut in_examples = false;
            for line in text.lines() {
                if line.starts_with("Example") {
                    in_examples = true;
                    continue;
                }
                if line.trim().is_empty() {
                    in_examples = false;
                    continue;
                }
                if in_examples {
                    assert!(
                        line.starts_with("  "),
                        "{cmd:?} at COLUMNS={cols}: wrapped example line {line:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn evaluate_refuses_too_many_columns_for_the_frames_before_any_seed() {
    // The check `fit` makes, in `evaluate` too: 400 columns (800 features with
    // velocities) and 3 × 60 training frames (a seed trains on one of them).
    let dir = tempfile::tempdir().unwrap();
    let action = dir.path().join("wide");
    std::fs::create_dir(&action).unwrap();
    let cols = 400;
    let names: Vec<String> = (0..cols)
        .map(|c| {
            if c < cols / 2 {
                format!("h{c}")
            } else {
                format!("r{c}")
            }
        })
        .collect();
    let mut text = names.join(",") + "\n";
    for t in 0..60 {
        let row: Vec<String> = (0..cols).map(|c| format!("{}", (t * c) % 7)).collect();
        text.push_str(&(row.join(",") + "\n"));
    }
    for f in [
        "train_00.csv",
        "train_01.csv",
        "train_02.csv",
        "test_00.csv",
    ] {
        std::fs::write(action.join(f), &text).unwrap();
    }
    phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm",
            "--human",
            "h*",
            "--robot",
            "r*",
            "--seeds",
            "1",
            "--data",
        ])
        .arg(dir.path())
        .assert()
        .failure()
        .code(1)
        .stderr(
            predicate::str::contains("action wide, hmm")
                .and(predicate::str::contains("800 features from 60 frames"))
                .and(predicate::str::contains("select fewer columns")),
        );
}
