//! Degenerate models and bad input, tried one by one: each either works (with
//! what it had to do in the fit report) or fails with an error that names the
//! place and says what to change — never a panic, never NaN parameters, never
//! a partial output file; then the careless and hostile uses of issues 20 and
//! 15 (outputs over inputs, 1e200, the stream's columns, real files, careless
//! arguments). The test builds the table of README.md's
//! "Robustness" section from what phasekit actually did and fails when the
//! README's copy differs; `PHASEKIT_UPDATE_README=1 cargo test -p phasekit-cli
//! --test robustness` rewrites it.

use crate::common;

use common::{phasekit, write_frames};
use phasekit_emission::{CovarianceType, Gaussian, Regularisation, SequenceSet};
use phasekit_hmm::{BaumWelch, Hmm};
use phasekit_tsc::synthetic;
use std::path::{Path, PathBuf};

const HEADER: &str = "p1_wrist_x,p1_wrist_y,p1_wrist_z,p2_wrist_x,p2_wrist_y,p2_wrist_z";

/// Writes demonstrations (`T × 6` each, cells written by `cell`) as `train_NN.csv`.
fn write_set(dir: &Path, demos: &[Vec<f64>], mut cell: impl FnMut(usize, usize, f64) -> String) {
    std::fs::create_dir_all(dir).unwrap();
    for (i, d) in demos.iter().enumerate() {
        write_frames(&dir.join(format!("train_{i:02}.csv")), d, &mut cell);
    }
}

fn demos(n: usize) -> Vec<Vec<f64>> {
    synthetic::generate(n, 21)
        .into_iter()
        .map(|d| d.frames)
        .collect()
}

/// What a command did, in one line (temporary paths removed).
struct Outcome {
    ok: bool,
    text: String,
}

fn first_lines(s: &str, root: &Path) -> String {
    let root = format!("{}/", root.display());
    s.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.replace(&root, "").trim().to_string())
        .collect::<Vec<_>>()
        .join(" ")
}

/// Runs `phasekit args` in `dir`; checks the invariants: exit 0 or 1 (never a
/// panic), no output file on failure, a loadable model with finite parameters
/// on success of a fit.
fn run(dir: &Path, args: &[&str], output: Option<&str>) -> Outcome {
    let out = phasekit().current_dir(dir).args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    let code = out.status.code();
    assert!(
        matches!(code, Some(0) | Some(1)) && !stderr.contains("panicked"),
        "{args:?}: exit {code:?}, stderr {stderr}"
    );
    let ok = code == Some(0);
    if let Some(o) = output {
        let path = dir.join(o);
        assert_eq!(
            path.exists(),
            ok,
            "{args:?}: output file {o} exists = {}",
            path.exists()
        );
        if ok && o.ends_with(".json") {
            // Loading re-validates every parameter (finite, positive definite):
            // a NaN would have been written as `null` and be refused here.
            let text = std::fs::read_to_string(&path).unwrap();
            phasekit_cli::model_file::ModelFile::from_json(&text, &path)
                .unwrap_or_else(|e| panic!("{args:?}: the written model does not load: {e}"));
        }
    }
    let text = if ok {
        let stdout = String::from_utf8_lossy(&out.stdout).to_string();
        match serde_json::from_str::<serde_json::Value>(&stdout) {
            Ok(r) => fit_summary(&r),
            Err(_) => first_lines(&stdout, dir).chars().take(160).collect(),
        }
    } else {
        format!(
            "error: {}",
            first_lines(&stderr, dir).trim_start_matches("phasekit: error: ")
        )
    };
    Outcome { ok, text }
}

/// The interesting part of a `fit --format json` report.
fn fit_summary(r: &serde_json::Value) -> String {
    let n = r["states"].as_u64().unwrap_or(0);
    let converged = r["stop"] == "converged";
    let mut parts = vec![format!(
        "fits: {n} state{}, {} iterations{}",
        if n == 1 { "" } else { "s" },
        r["iterations"],
        if converged { ", converged" } else { "" }
    )];
    if let Some(ll) = r["log_likelihood"]
        .as_array()
        .and_then(|v| v.last())
        .and_then(|v| v.as_f64())
    {
        assert!(ll.is_finite(), "log-likelihood {ll}");
    }
    parts.push(format!(
        "reg {:e}",
        r["regularisation"].as_f64().unwrap_or(0.0)
    ));
    if let Some(j) = r["jittered_states"].as_array().filter(|j| !j.is_empty()) {
        parts.push(format!(
            "jitter {:.1e} on states {}",
            r["jitter"].as_f64().unwrap_or(0.0),
            serde_json::to_string(j).unwrap()
        ));
    }
    if let Some(e) = r["empty_states"].as_array().filter(|e| !e.is_empty()) {
        parts.push(format!(
            "states {} received no frame",
            serde_json::to_string(e).unwrap()
        ));
    }
    if let Some(m) = r["missing_values"].as_u64().filter(|m| *m > 0) {
        parts.push(format!(
            "{m} missing feature values (their expected statistics used)"
        ));
    }
    if let Some(s) = r["transition_segments"].as_u64() {
        parts.push(format!("{s} transition segments"));
    }
    if r["stop"] == "log-likelihood fell" {
        parts.push("stopped because the log-likelihood fell".into());
    }
    if let Some(w) = r["warnings"].as_array() {
        parts.extend(
            w.iter()
                .map(|w| format!("warns: {}", w.as_str().unwrap_or(""))),
        );
    }
    parts.join("; ")
}

/// `fit` of the paper's HMM (or the method in `extra`) with a JSON report.
fn fit_args(data: &str, extra: &[&str]) -> Vec<String> {
    let mut v = vec!["fit", "--format", "json", "-o", "m.json", "--data", data];
    if !extra.contains(&"--method") {
        v.extend(["--method", "hmm"]);
    }
    v.extend_from_slice(extra);
    v.into_iter().map(str::to_string).collect()
}

/// One row: (case, input, outcome).
type Row = (String, String, String);

fn degenerate_cases(root: &Path) -> Vec<Row> {
    let mut rows = Vec::new();
    let mut case = |name: &str, setup: &dyn Fn(&Path) -> Vec<String>, expect_ok: Option<bool>| {
        let dir = root.join(format!("case{}", rows.len()));
        std::fs::create_dir_all(&dir).unwrap();
        let args = setup(&dir);
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = run(&dir, &a, Some("m.json"));
        if let Some(e) = expect_ok {
            assert_eq!(out.ok, e, "{name}: {}", out.text);
        }
        let shown: Vec<String> = args
            .iter()
            .filter(|s| !["--format", "json", "-o", "m.json", "--data"].contains(&s.as_str()))
            .cloned()
            .collect();
        rows.push((
            name.to_string(),
            format!("`phasekit {}`", shown.join(" ")),
            out.text,
        ));
    };
    let base = demos(8);
    case(
        "constant column (the robot's z never moves), no regularisation",
        &|d| {
            write_set(&d.join("data"), &base, |_, k, v| {
                if k == 5 {
                    "0.25".into()
                } else {
                    v.to_string()
                }
            });
            fit_args("data", &["--reg", "0"])
        },
        Some(false),
    );
    case(
        "constant column, default regularisation",
        &|d| {
            write_set(&d.join("data"), &base, |_, k, v| {
                if k == 5 {
                    "0.25".into()
                } else {
                    v.to_string()
                }
            });
            fit_args("data", &[])
        },
        Some(true),
    );
    case(
        "collinear columns (human y = 2 × human x), no regularisation",
        &|d| {
            let collinear: Vec<Vec<f64>> = base
                .iter()
                .map(|f| {
                    f.chunks_exact(6)
                        .flat_map(|r| [r[0], 2.0 * r[0], r[2], r[3], r[4], r[5]])
                        .collect()
                })
                .collect();
            write_set(&d.join("data"), &collinear, |_, _, v| v.to_string());
            fit_args("data", &["--reg", "0"])
        },
        Some(false),
    );
    case(
        "identical demonstrations (8 copies of one)",
        &|d| {
            write_set(&d.join("data"), &vec![base[0].clone(); 8], |_, _, v| {
                v.to_string()
            });
            fit_args("data", &[])
        },
        Some(true),
    );
    case(
        "TSC-HMM on identical demonstrations",
        &|d| {
            write_set(&d.join("data"), &vec![base[0].clone(); 8], |_, _, v| {
                v.to_string()
            });
            fit_args("data", &["--method", "tsc-hmm"])
        },
        Some(true),
    );
    case(
        "a demonstration shorter than the number of states",
        &|d| {
            let mut set = base.clone();
            set[3].truncate(3 * 6);
            write_set(&d.join("data"), &set, |_, _, v| v.to_string());
            fit_args("data", &[])
        },
        Some(false),
    );
    case(
        "one state",
        &|d| {
            write_set(&d.join("data"), &base, |_, _, v| v.to_string());
            fit_args("data", &["--states", "1"])
        },
        Some(true),
    );
    case(
        "more states than frames",
        &|d| {
            let short: Vec<Vec<f64>> = base.iter().take(2).map(|f| f[..8 * 6].to_vec()).collect();
            write_set(&d.join("data"), &short, |_, _, v| v.to_string());
            fit_args("data", &["--states", "20"])
        },
        Some(false),
    );
    case(
        "data scaled by 1e6",
        &|d| {
            write_set(&d.join("data"), &base, |_, _, v| (v * 1e6).to_string());
            fit_args("data", &[])
        },
        Some(true),
    );
    case(
        "data scaled by 1e-6",
        &|d| {
            write_set(&d.join("data"), &base, |_, _, v| (v * 1e-6).to_string());
            fit_args("data", &[])
        },
        Some(true),
    );
    case(
        "data scaled by 1e-6, standardised",
        &|d| {
            write_set(&d.join("data"), &base, |_, _, v| (v * 1e-6).to_string());
            fit_args("data", &["--standardise"])
        },
        Some(true),
    );
    case(
        "30 % of the values missing (empty cells)",
        &|d| {
            write_set(&d.join("data"), &base, |t, k, v| {
                if (t * 7 + k * 13) % 10 < 3 {
                    String::new()
                } else {
                    v.to_string()
                }
            });
            fit_args("data", &[])
        },
        Some(true),
    );
    case(
        "30 % missing, smaller regularisation",
        &|d| {
            write_set(&d.join("data"), &base, |t, k, v| {
                if (t * 7 + k * 13) % 10 < 3 {
                    String::new()
                } else {
                    v.to_string()
                }
            });
            fit_args("data", &["--reg", "1e-5"])
        },
        Some(true),
    );
    case(
        "a column never observed",
        &|d| {
            write_set(&d.join("data"), &base, |_, k, v| {
                if k == 1 {
                    String::new()
                } else {
                    v.to_string()
                }
            });
            fit_args("data", &[])
        },
        Some(true),
    );
    case(
        "a demonstration with nothing observed",
        &|d| {
            write_set(&d.join("data"), &base, |_, _, v| v.to_string());
            let empty = format!("{HEADER}\n") + &",,,,,\n".repeat(40);
            std::fs::write(d.join("data").join("train_99.csv"), empty).unwrap();
            fit_args("data", &[])
        },
        Some(true),
    );
    case(
        "more mixture components than distinct frames",
        &|d| {
            let flat: Vec<Vec<f64>> = base
                .iter()
                .map(|f| f.iter().map(|v| (v * 10.0).round() / 10.0).collect())
                .collect();
            write_set(&d.join("data"), &flat, |_, _, v| v.to_string());
            fit_args("data", &["--method", "gmm", "--states", "60", "--reg", "0"])
        },
        Some(false),
    );
    rows.push(empty_state_case());
    rows
}

/// A state that receives no weight at all (library level: an initial model
/// with one state far from the data): kept, and reported.
fn empty_state_case() -> Row {
    let data: Vec<Vec<f64>> = demos(6)
        .into_iter()
        .map(|f| f.chunks_exact(6).flat_map(|r| r[..2].to_vec()).collect())
        .collect();
    let set = SequenceSet::new(&data, 2).unwrap();
    let means = vec![0.0, 0.0, 0.3, 0.0, 1e3, 1e3];
    let covs = [0.01, 0.0, 0.0, 0.01].repeat(3);
    let init = Hmm::new(
        vec![0.5, 0.3, 0.2],
        vec![0.8, 0.1, 0.1, 0.1, 0.8, 0.1, 0.1, 0.1, 0.8],
        Gaussian::new(CovarianceType::Full, 2, means, covs).unwrap(),
    )
    .unwrap();
    let bw = BaumWelch::builder()
        .regularisation(Regularisation::add_diagonal(1e-4).unwrap())
        .max_iter(20)
        .build()
        .unwrap();
    let fitted = bw.fit_from(init, &set).unwrap();
    let last = fitted.report.m_steps.last().unwrap();
    let kept: Vec<(usize, f64)> = last
        .events
        .iter()
        .filter_map(|e| match e {
            phasekit_emission::MStepEvent::KeptEmptyState { state, weight, .. } => {
                Some((*state, *weight))
            }
            _ => None,
        })
        .collect();
    assert_eq!(
        kept.len(),
        1,
        "the far state must be reported: {:?}",
        last.events
    );
    assert_eq!(
        fitted.model.emission().mean(2),
        &[1e3, 1e3],
        "it keeps its parameters"
    );
    (
        "a state that receives no frame".into(),
        "library: `BaumWelch::fit_from` with one state's mean 1000 away from the data".into(),
        format!(
            "fits; every M-step reports `KeptEmptyState` for state {} (weight {:.0e}), which keeps its parameters; the command's fit report lists such states as `empty_states`",
            kept[0].0, kept[0].1
        ),
    )
}

fn bad_input_cases(root: &Path) -> Vec<Row> {
    let dir = root.join("bad");
    std::fs::create_dir_all(&dir).unwrap();
    let good: Vec<String> = demos(2)[0]
        .chunks_exact(6)
        .map(|f| {
            f.iter()
                .map(|v| v.to_string())
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect();
    let write = |name: &str, header: &str, rows: &[String]| {
        std::fs::write(dir.join(name), format!("{header}\n{}\n", rows.join("\n"))).unwrap();
    };
    let with_cell = |name: &str, row: usize, col: usize, cell: &str| {
        let mut rows = good.clone();
        let mut cells: Vec<String> = rows[row].split(',').map(str::to_string).collect();
        cells[col] = cell.into();
        rows[row] = cells.join(",");
        write(name, HEADER, &rows);
    };
    with_cell("text.csv", 3, 1, "abc");
    with_cell("inf.csv", 5, 4, "inf");
    let mut ragged = good.clone();
    ragged[7] = ragged[7].rsplit_once(',').unwrap().0.to_string();
    write("ragged.csv", HEADER, &ragged);
    write(
        "dup.csv",
        "p1_wrist_x,p1_wrist_y,p1_wrist_x,p2_wrist_x,p2_wrist_y,p2_wrist_z",
        &good,
    );
    write(
        "other.csv",
        "p1_wrist_x,p1_wrist_y,p1_wrist_z,p2_wrist_x,p2_wrist_y,p2_elbow_z",
        &good,
    );
    write("good.csv", HEADER, &good);
    std::fs::write(dir.join("empty.csv"), "").unwrap();
    std::fs::write(dir.join("header.csv"), format!("{HEADER}\n")).unwrap();
    let mut npy = b"\x93NUMPY\x01\x00".to_vec();
    let h = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000, 6), }";
    npy.extend((h.len() as u16).to_le_bytes());
    npy.extend(h.as_bytes());
    npy.extend([0u8; 48]);
    std::fs::write(dir.join("huge.npy"), &npy).unwrap();
    // A model, then corrupted copies of it.
    let fit = run(
        &dir,
        &["fit", "-o", "model.json", "--data", "good.csv"],
        Some("model.json"),
    );
    assert!(fit.ok, "{}", fit.text);
    let model = std::fs::read_to_string(dir.join("model.json")).unwrap();
    // Cut before the fit report (whose fit time varies), so the message is reproducible.
    std::fs::write(dir.join("truncated.json"), &model[..400]).unwrap();
    std::fs::write(
        dir.join("v99.json"),
        model.replacen("\"version\": 1", "\"version\": 99", 1),
    )
    .unwrap();
    let i = model.find("\"covariances\": [").unwrap() + "\"covariances\": [".len();
    let j = i + model[i..].find(',').unwrap();
    let mut negative = model.clone();
    negative.replace_range(i..j, "\n -1.0");
    std::fs::write(dir.join("negative.json"), negative).unwrap();

    let mut rows = Vec::new();
    let mut case = |name: &str, args: &[&str], output: Option<&str>| {
        let out = run(&dir, args, output);
        assert!(!out.ok, "{name} must be refused: {}", out.text);
        rows.push((
            name.to_string(),
            format!("`phasekit {}`", args.join(" ")),
            out.text,
        ));
    };
    case(
        "non-numeric cell",
        &["fit", "-o", "m.json", "--data", "text.csv"],
        Some("m.json"),
    );
    case(
        "infinity",
        &["fit", "-o", "m.json", "--data", "inf.csv"],
        Some("m.json"),
    );
    case(
        "ragged row",
        &["fit", "-o", "m.json", "--data", "ragged.csv"],
        Some("m.json"),
    );
    case(
        "duplicate column",
        &["fit", "-o", "m.json", "--data", "dup.csv"],
        Some("m.json"),
    );
    case(
        "unknown column",
        &[
            "fit", "-o", "m.json", "--data", "good.csv", "--human", "nose_*",
        ],
        Some("m.json"),
    );
    case(
        "empty file",
        &["fit", "-o", "m.json", "--data", "empty.csv"],
        Some("m.json"),
    );
    case(
        "header only",
        &["fit", "-o", "m.json", "--data", "header.csv"],
        Some("m.json"),
    );
    case(
        "demonstrations with different columns",
        &["fit", "-o", "m.json", "--data", "good.csv", "other.csv"],
        Some("m.json"),
    );
    case(
        "missing file",
        &["fit", "-o", "m.json", "--data", "nope.csv"],
        Some("m.json"),
    );
    case(
        "NPY header claiming 10⁹ rows",
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "huge.npy",
            "-o",
            "p.csv",
        ],
        Some("p.csv"),
    );
    case(
        "truncated model file",
        &[
            "predict",
            "--model",
            "truncated.json",
            "--data",
            "good.csv",
            "-o",
            "p.csv",
        ],
        Some("p.csv"),
    );
    case(
        "model file of another version",
        &[
            "predict", "--model", "v99.json", "--data", "good.csv", "-o", "p.csv",
        ],
        Some("p.csv"),
    );
    case(
        "model file with a negative variance",
        &[
            "predict",
            "--model",
            "negative.json",
            "--data",
            "good.csv",
            "-o",
            "p.csv",
        ],
        Some("p.csv"),
    );
    case(
        "output folder that does not exist",
        &["fit", "-o", "no/such/dir/m.json", "--data", "good.csv"],
        None,
    );
    rows
}

/// What a command given as a careless or hostile user would did: `works`
/// (with its first warning, if any) or its error, in one line; never a panic,
/// exit 0, 1 or 2 (a usage error).
fn hostile_run(dir: &Path, args: &[&str], stdin: Option<&str>) -> (bool, String) {
    let mut cmd = phasekit();
    cmd.current_dir(dir).args(args);
    if let Some(s) = stdin {
        cmd.write_stdin(s.to_string());
    }
    let out = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    let code = out.status.code();
    assert!(
        matches!(code, Some(0..=2)) && !stderr.contains("panicked"),
        "{args:?}: exit {code:?}, stderr {stderr}"
    );
    let root = format!("{}/", dir.display());
    let clean = |l: &str| {
        let l = l.replace(&root, "");
        let l = l.trim();
        if l.chars().count() > 300 {
            l.chars().take(300).collect::<String>() + "…"
        } else {
            l.to_string()
        }
    };
    if code == Some(0) {
        let warning = stderr
            .lines()
            .find_map(|l| l.strip_prefix("phasekit: warning: "))
            .map(|w| format!("; warns: {}", clean(w)))
            .unwrap_or_default();
        (true, format!("works{warning}"))
    } else {
        let first = stderr
            .lines()
            .map(|l| {
                l.trim_start_matches("phasekit: ")
                    .trim_start_matches("error: ")
            })
            .find(|l| !l.trim().is_empty())
            .unwrap_or("");
        (false, format!("error: {}", clean(first)))
    }
}

/// The cases of issues 20 and 15: outputs that could destroy inputs, numbers
/// that could overflow into zeros, a stream that could read the wrong columns,
/// files as real users have them, careless arguments.
fn hostile_cases(root: &Path) -> Vec<Row> {
    let dir = root.join("hostile");
    let data = dir.join("data");
    write_set(&data, &demos(6), |_, _, v| v.to_string());
    let good = std::fs::read_to_string(data.join("train_00.csv")).unwrap();
    std::fs::write(dir.join("good.csv"), &good).unwrap();
    let fit = hostile_run(
        &dir,
        &[
            "fit",
            "--method",
            "hmm",
            "--data",
            "data",
            "-o",
            "model.json",
        ],
        None,
    );
    assert!(fit.0, "{}", fit.1);
    let lines: Vec<&str> = good.lines().collect();
    let edit = |name: &str, f: &dyn Fn(usize, &str) -> String| {
        let text: Vec<String> = lines.iter().enumerate().map(|(i, l)| f(i, l)).collect();
        std::fs::write(dir.join(name), text.join("\n") + "\n").unwrap();
    };
    edit("glitch.csv", &|i, l| {
        if i == 4 {
            l.replacen(l.split(',').next().unwrap(), "1e200", 1)
        } else {
            l.to_string()
        }
    });
    edit("millimetres.csv", &|i, l| {
        if i == 0 {
            l.to_string()
        } else {
            l.split(',')
                .map(|c| (c.parse::<f64>().unwrap() * 1000.0).to_string())
                .collect::<Vec<_>>()
                .join(",")
        }
    });
    edit("annotated.csv", &|i, l| {
        if i == 0 {
            format!("timestamp,label,{l}")
        } else {
            format!("10:00:{i:02},shake,{l}")
        }
    });
    edit("semicolons.csv", &|_, l| l.replace(',', ";"));
    edit("huge_cell.csv", &|i, l| {
        if i == 3 {
            format!("{}x,0,0,0,0,0", "9".repeat(5_000_000))
        } else {
            l.to_string()
        }
    });
    let column = |cols: &[usize], skip: usize| -> String {
        lines
            .iter()
            .skip(skip)
            .map(|l| {
                let c: Vec<&str> = l.split(',').collect();
                cols.iter().map(|&k| c[k]).collect::<Vec<_>>().join(",") + "\n"
            })
            .collect()
    };
    let shoulders = column(&[3, 4, 5], 0).replace("p2_wrist", "p1_shoulder");
    let two_values = column(&[0, 1], 1);
    let reordered = format!("\u{feff}{}", column(&[2, 1, 0], 0));
    let upper = column(&[0, 1, 2], 0).replacen("p1_wrist_x", "P1_WRIST_X", 1);
    let glitch_stream = column(&[0, 1, 2], 0)
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 4 {
                "1e200,0,0".to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n";
    let model = common::model_json(&dir.join("model.json"));
    let mut huge = model.clone();
    huge["model"]["emission"]["means"][0] = serde_json::json!(1e200);
    std::fs::write(
        dir.join("huge_means.json"),
        serde_json::to_string(&huge).unwrap(),
    )
    .unwrap();
    std::fs::write(dir.join("target.csv"), "old\n").unwrap();
    std::fs::write(dir.join("read_only.csv"), "keep\n").unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::os::unix::fs::symlink("target.csv", dir.join("link.csv")).unwrap();
        std::os::unix::fs::symlink("gone.csv", data.join("train_09.csv")).unwrap();
        std::fs::set_permissions(
            dir.join("read_only.csv"),
            std::fs::Permissions::from_mode(0o444),
        )
        .unwrap();
    }
    // 19,970 columns and 230 frames.
    let wide_cols = 19_970;
    let names: Vec<String> = (0..wide_cols)
        .map(|c| {
            if c < wide_cols / 2 {
                format!("h{c}")
            } else {
                format!("r{c}")
            }
        })
        .collect();
    let wide = names.join(",") + "\n" + &(vec!["0"; wide_cols].join(",") + "\n").repeat(230);
    std::fs::write(dir.join("wide.csv"), wide).unwrap();

    let mut rows = Vec::new();
    let mut case =
        |name: &str, shown: &str, args: &[&str], stdin: Option<&str>, ok: bool, note: &str| {
            let (worked, text) = hostile_run(&dir, args, stdin);
            assert_eq!(worked, ok, "{name}: {text}");
            rows.push((
                name.to_string(),
                format!("`{shown}`"),
                format!("{text}{note}"),
            ));
        };
    let p = |args: &str| format!("phasekit {args}");
    case(
        "`-o` naming an input",
        &p("predict --model model.json --data good.csv -o good.csv"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "good.csv",
            "-o",
            "good.csv",
        ],
        None,
        false,
        "",
    );
    case(
        "`-o` naming the model",
        &p("segment --model model.json --data good.csv -o model.json"),
        &[
            "segment",
            "--model",
            "model.json",
            "--data",
            "good.csv",
            "-o",
            "model.json",
        ],
        None,
        false,
        "",
    );
    case(
        "output through a symbolic link",
        &p("predict --model model.json --data good.csv -o link.csv"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "good.csv",
            "-o",
            "link.csv",
        ],
        None,
        true,
        "; target.csv gets the prediction, link.csv stays a link",
    );
    case(
        "read-only output file",
        &p("predict --model model.json --data good.csv -o read_only.csv"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "good.csv",
            "-o",
            "read_only.csv",
        ],
        None,
        false,
        "",
    );
    case(
        "output to a link to stdout",
        &p("predict --model model.json --data good.csv -o /proc/self/fd/1"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "good.csv",
            "-o",
            "/proc/self/fd/1",
        ],
        None,
        true,
        "; written directly to stdout (devices and pipes are never replaced)",
    );
    case(
        "a human value of 1e200",
        &p("predict --model model.json --data glitch.csv -o p.csv"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "glitch.csv",
            "-o",
            "p.csv",
        ],
        None,
        true,
        "",
    );
    case(
        "a human value of 1e200, segmented",
        &p("segment --model model.json --data glitch.csv -o s.csv"),
        &[
            "segment",
            "--model",
            "model.json",
            "--data",
            "glitch.csv",
            "-o",
            "s.csv",
        ],
        None,
        true,
        "",
    );
    case(
        "millimetres given to a metre model",
        &p("predict --model model.json --data millimetres.csv -o mm.csv"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "millimetres.csv",
            "-o",
            "mm.csv",
        ],
        None,
        true,
        "",
    );
    case(
        "a model file whose means are 1e200",
        &p("predict --model huge_means.json --data good.csv"),
        &[
            "predict",
            "--model",
            "huge_means.json",
            "--data",
            "good.csv",
        ],
        None,
        false,
        "",
    );
    case(
        "stream: a header naming other columns",
        &p("stream --model model.json < shoulders.csv"),
        &["stream", "--model", "model.json"],
        Some(&shoulders),
        false,
        "",
    );
    case(
        "stream: two values per line, no header",
        &p("stream --model model.json < two_values.csv"),
        &["stream", "--model", "model.json"],
        Some(&two_values),
        false,
        "",
    );
    case(
        "stream: the same, leniently",
        &p("stream --model model.json --on-bad-line missing < two_values.csv"),
        &[
            "stream",
            "--model",
            "model.json",
            "--on-bad-line",
            "missing",
        ],
        Some(&two_values),
        true,
        "; one line per input line, status `unobserved`",
    );
    case(
        "stream: header reordered (z, y, x) with a byte order mark",
        &p("stream --model model.json < reordered.csv"),
        &["stream", "--model", "model.json"],
        Some(&reordered),
        true,
        "; columns picked by name",
    );
    case(
        "stream: header `P1_WRIST_X`",
        &p("stream --model model.json < upper.csv"),
        &["stream", "--model", "model.json"],
        Some(&upper),
        false,
        "",
    );
    case("stream: a frame of 1e200", &p("stream --model model.json < glitch.csv"),
        &["stream", "--model", "model.json"], Some(&glitch_stream), true,
        "; one line per frame, that frame's status `rejected`, the next frames as if it were missing");
    case(
        "quoted glob in `--data`",
        &p("fit --method hmm --data 'data/train_0[0-5].csv' -o m.json"),
        &[
            "fit",
            "--method",
            "hmm",
            "--data",
            "data/train_0[0-5].csv",
            "-o",
            "m.json",
        ],
        None,
        true,
        "",
    );
    case(
        "the same file three times",
        &p("fit --data good.csv good.csv good.csv -o m.json"),
        &[
            "fit", "--data", "good.csv", "good.csv", "good.csv", "-o", "m.json",
        ],
        None,
        false,
        "",
    );
    case(
        "a dangling `train_*.csv` link",
        &p("fit --method hmm --data data -o m.json"),
        &["fit", "--method", "hmm", "--data", "data", "-o", "m.json"],
        None,
        false,
        "",
    );
    case(
        "text columns the model does not use",
        &p("predict --model model.json --data annotated.csv -o a.csv"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "annotated.csv",
            "-o",
            "a.csv",
        ],
        None,
        true,
        "",
    );
    case(
        "semicolon-separated file",
        &p("predict --model model.json --data semicolons.csv -o s2.csv"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "semicolons.csv",
            "-o",
            "s2.csv",
        ],
        None,
        true,
        "",
    );
    case(
        "a 5 MB cell",
        &p("fit --data huge_cell.csv -o m.json"),
        &["fit", "--data", "huge_cell.csv", "-o", "m.json"],
        None,
        false,
        "",
    );
    case(
        "a folder where one file is expected",
        &p("plot prediction --model model.json --data data -o p.svg"),
        &[
            "plot",
            "prediction",
            "--model",
            "model.json",
            "--data",
            "data",
            "-o",
            "p.svg",
        ],
        None,
        false,
        "",
    );
    case(
        "a model file named .npy",
        &p("fit --data good.csv -o m.npy"),
        &["fit", "--data", "good.csv", "-o", "m.npy"],
        None,
        false,
        "",
    );
    case(
        "NPY output",
        &p("predict --model model.json --data good.csv -o p.npy"),
        &[
            "predict",
            "--model",
            "model.json",
            "--data",
            "good.csv",
            "-o",
            "p.npy",
        ],
        None,
        true,
        "; a T × 7 float array (frame and the robot's features, as the CSV's columns)",
    );
    case(
        "negative regularisation",
        &p("fit --data good.csv --reg -1 -o m.json"),
        &["fit", "--data", "good.csv", "--reg", "-1", "-o", "m.json"],
        None,
        false,
        "",
    );
    case(
        "huge regularisation",
        &p("fit --data good.csv --reg 1e308 -o m.json"),
        &[
            "fit", "--data", "good.csv", "--reg", "1e308", "-o", "m.json",
        ],
        None,
        false,
        "",
    );
    case(
        "100,000 threads",
        &p("fit --data good.csv --threads 100000 -o m.json"),
        &[
            "fit",
            "--data",
            "good.csv",
            "--threads",
            "100000",
            "-o",
            "m.json",
        ],
        None,
        false,
        "",
    );
    case(
        "19,970 feature columns and 230 frames",
        &p("fit --method hmm --human 'h*' --robot 'r*' --data wide.csv -o m.json"),
        &[
            "fit", "--method", "hmm", "--human", "h*", "--robot", "r*", "--data", "wide.csv", "-o",
            "m.json",
        ],
        None,
        false,
        "",
    );
    let text = std::fs::read_to_string(dir.join("target.csv")).unwrap();
    assert!(text.starts_with("frame,"), "written through the link");
    assert_eq!(
        std::fs::read_to_string(dir.join("good.csv")).unwrap(),
        good,
        "the input is intact"
    );
    assert!(
        !dir.join("m.npy").exists() && !dir.join("m.json").exists() || dir.join("m.json").exists()
    );
    rows
}

fn table(rows: &[Row]) -> String {
    let mut s = String::from("| case | input | what phasekit did |\n|---|---|---|\n");
    for (a, b, c) in rows {
        let esc = |x: &str| x.replace('|', "\\|");
        s += &format!("| {} | {} | {} |\n", esc(a), esc(b), esc(c));
    }
    s
}

const START: &str = "<!-- robustness-table: made by crates/cli/tests/robustness.rs -->\n";
const END: &str = "<!-- robustness-table end -->";

#[test]
fn degenerate_models_and_bad_input_give_results_or_located_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let mut rows = degenerate_cases(tmp.path());
    rows.extend(bad_input_cases(tmp.path()));
    rows.extend(hostile_cases(tmp.path()));
    let got = table(&rows);
    let readme_path: PathBuf = [env!("CARGO_MANIFEST_DIR"), "..", "..", "README.md"]
        .iter()
        .collect();
    let readme = std::fs::read_to_string(&readme_path).unwrap();
    let (Some(a), Some(b)) = (readme.find(START), readme.find(END)) else {
        panic!("README.md has no robustness table markers; the table is:\n{got}");
    };
    let current = &readme[a + START.len()..b];
    if current != got {
        if std::env::var_os("PHASEKIT_UPDATE_README").is_some() {
            let updated = format!("{}{START}{got}{}", &readme[..a], &readme[b..]);
            std::fs::write(&readme_path, updated).unwrap();
        } else {
            panic!(
                "README.md's robustness table is out of date; rerun with PHASEKIT_UPDATE_README=1. It should be:\n{got}"
            );
        }
    }
}
