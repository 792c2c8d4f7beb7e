//! What a researcher sees: the evaluate table and its formats, the fit report,
//! the demo and the plots say what they measure, in the units of the data, and
//! never hide a failure (issue "What a researcher sees", "Plots and reports that
//! mislead").

use crate::common;

use common::{interaction_folder, phasekit, plain};
use predicates::prelude::*;
use std::path::Path;

/// A folder `data/` with 6 training and 2 test demonstrations.
fn small_dataset() -> (tempfile::TempDir, std::path::PathBuf) {
    interaction_folder(8, 3, 6, plain)
}

fn stdout_of(args: &[&str], data: &Path) -> String {
    let out = phasekit()
        .args(args)
        .arg("--data")
        .arg(data)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    String::from_utf8(out).unwrap()
}

/// Significant digits of a number as printed (`0.004312` → 4, `59.06` → 4, `633.74` → 5).
fn significant_digits(s: &str) -> usize {
    let mantissa = s.split(['e', 'E']).next().unwrap();
    let digits: String = mantissa.chars().filter(char::is_ascii_digit).collect();
    digits.trim_start_matches('0').len()
}

/// The cells of the Markdown row of `method` (first action).
fn md_row<'a>(md: &'a str, method: &str) -> Vec<&'a str> {
    md.lines()
        .find(|l| l.split('|').nth(2).map(str::trim) == Some(method))
        .unwrap_or_else(|| panic!("no row {method} in\n{md}"))
        .split('|')
        .map(str::trim)
        .collect()
}

#[test]
fn evaluate_units_follow_the_unit_flags() {
    let (_dir, data) = small_dataset();
    let args = ["evaluate", "--methods", "hmm", "--seeds", "2"];
    // The default: data in metres reported in cm.
    let md = stdout_of(&args, &data);
    assert!(md.contains("| MSE (cm²) | RMSE (cm) |"), "{md}");
    // Scale 1 without a unit name: the data's own units, never cm.
    let md = stdout_of(&[&args[..], &["--unit-scale", "1"]].concat(), &data);
    assert!(!md.contains("cm"), "{md}");
    assert!(md.contains("MSE ((data units)²)"), "{md}");
    // A named unit (joint angles in radians): the table, the metric and the JSON say rad.
    let md = stdout_of(
        &[&args[..], &["--unit", "rad", "--unit-scale", "1"]].concat(),
        &data,
    );
    assert!(md.contains("| MSE (rad²) | RMSE (rad) |"), "{md}");
    assert!(!md.contains("cm"), "{md}");
    let json = stdout_of(
        &[
            &args[..],
            &["--unit", "rad", "--unit-scale", "1", "--format", "json"],
        ]
        .concat(),
        &data,
    );
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["protocol"]["unit"], "rad");
    assert_eq!(v["protocol"]["unit_scale"], 1.0);
    // A length name alone sets the factor from metres.
    let mm = stdout_of(
        &[&args[..], &["--unit", "mm", "--format", "json"]].concat(),
        &data,
    );
    let v: serde_json::Value = serde_json::from_str(&mm).unwrap();
    assert_eq!(v["protocol"]["unit_scale"], 1000.0);
    // Any other name needs its factor.
    phasekit()
        .args(args)
        .args(["--unit", "rad", "--data"])
        .arg(&data)
        .assert()
        .failure()
        .stderr(predicate::str::contains("--unit-scale"));
}

#[test]
fn evaluate_prints_four_significant_digits_whatever_the_magnitude() {
    let (_dir, data) = small_dataset();
    // In metres the MSEs are of the order of 1e-3 m².
    let md = stdout_of(
        &[
            "evaluate",
            "--methods",
            "hmm,hmm:states=5",
            "--seeds",
            "3",
            "--unit-scale",
            "1",
        ],
        &data,
    );
    for method in ["hmm", "hmm:states=5", "constant-mean"] {
        let row = md_row(&md, method);
        for cell in [row[4], row[5]] {
            let mean = cell.split(" ± ").next().unwrap();
            assert!(
                significant_digits(mean) >= 4,
                "{method}: `{cell}` has fewer than 4 significant digits\n{md}"
            );
        }
    }
    // The same run in cm: the numbers are 10⁴ times larger and keep their digits.
    let md = stdout_of(
        &["evaluate", "--methods", "hmm,hmm:states=5", "--seeds", "3"],
        &data,
    );
    let row = md_row(&md, "hmm");
    let (mean, std) = row[4].split_once(" ± ").unwrap();
    assert!(significant_digits(mean) >= 4, "{}", row[4]);
    // The spread has the mean's decimals.
    assert_eq!(
        mean.split('.').nth(1).map(str::len),
        std.split('.').nth(1).map(str::len),
        "{}",
        row[4]
    );
}

#[test]
fn evaluate_csv_leaves_the_comparison_of_a_reference_with_itself_empty() {
    let (_dir, data) = small_dataset();
    let args = [
        "evaluate",
        "--methods",
        "hmm,hmm:states=5,hmm:states=6",
        "--seeds",
        "2",
    ];
    let csv = stdout_of(&[&args[..], &["--format", "csv"]].concat(), &data);
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let first = &rows[0];
    assert_eq!(first[col("method")], "hmm");
    for c in ["paired_change", "paired_won", "paired_seeds"] {
        assert_eq!(first[col(c)], "", "{c} of the reference row: {csv}");
    }
    assert_ne!(first[col("paired_change_second")], "");
    let second = &rows[1];
    for c in ["paired_change_second", "paired_won_second"] {
        assert_eq!(second[col(c)], "", "{c} of the second reference row: {csv}");
    }
    assert_ne!(second[col("paired_change")], "");
    // The same numbers in every format: JSON says null where CSV is empty.
    let json = stdout_of(&[&args[..], &["--format", "json"]].concat(), &data);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert!(
        v["results"][0]["paired_won"].is_null(),
        "{}",
        v["results"][0]
    );
    assert!(v["results"][1]["paired_won_second"].is_null());
    assert!(v["results"][2]["paired_won"].is_number());
}

#[test]
fn evaluate_overflowed_mse_is_a_failure() {
    let (_dir, data) = small_dataset();
    let out = phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm",
            "--seeds",
            "2",
            "--unit-scale",
            "1e200",
            "--format",
            "json",
            "--data",
        ])
        .arg(&data)
        .assert()
        .failure()
        .code(1)
        .stderr(predicate::str::contains("not finite"))
        .get_output()
        .stdout
        .clone();
    let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
    let row = &v["results"][0];
    assert_eq!(row["seeds"], 0, "{row}");
    assert_eq!(row["failures"].as_array().unwrap().len(), 2, "{row}");
}

#[test]
fn a_method_key_given_twice_is_refused() {
    let (dir, data) = small_dataset();
    phasekit()
        .args(["evaluate", "--methods", "hmm:states=3,states=5", "--data"])
        .arg(&data)
        .assert()
        .failure()
        .code(1)
        .stderr(predicate::str::contains("`states`").and(predicate::str::contains("twice")));
    phasekit()
        .args(["fit", "--method", "hmm:reg=0.1,reg=0.2", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(dir.path().join("m.json"))
        .assert()
        .failure()
        .stderr(predicate::str::contains("`reg`").and(predicate::str::contains("twice")));
    assert!(!dir.path().join("m.json").exists());
}

#[test]
fn evaluate_with_too_few_training_demonstrations_says_what_is_needed() {
    let (_dir, data) = interaction_folder(2, 1, 1, plain);
    phasekit()
        .args(["evaluate", "--methods", "hmm", "--seeds", "2", "--data"])
        .arg(&data)
        .assert()
        .failure()
        .code(1)
        .stderr(
            predicate::str::contains("1 training demonstration")
                .and(predicate::str::contains("--train-size"))
                .and(predicate::str::contains("subset of size 0").not()),
        );
    // As the message says: all of them, one run.
    phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm",
            "--seeds",
            "2",
            "--train-size",
            "1",
            "--data",
        ])
        .arg(&data)
        .assert()
        .success();
}

#[test]
fn evaluate_action_reads_only_the_selected_action() {
    let (dir, data) = small_dataset();
    let root = dir.path().join("root");
    std::fs::create_dir(&root).unwrap();
    std::fs::rename(&data, root.join("good")).unwrap();
    let broken = root.join("broken");
    std::fs::create_dir(&broken).unwrap();
    std::fs::write(broken.join("train_00.csv"), "a,b\n1,x\n").unwrap();
    phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm",
            "--seeds",
            "2",
            "--action",
            "good",
            "--data",
        ])
        .arg(&root)
        .assert()
        .success()
        .stdout(predicate::str::contains("| good | hmm |"));
    // Without --action the broken folder is an error, and says where.
    phasekit()
        .args(["evaluate", "--methods", "hmm", "--seeds", "2", "--data"])
        .arg(&root)
        .assert()
        .failure()
        .stderr(predicate::str::contains("train_00.csv"));
    // An unknown action still lists the actions.
    phasekit()
        .args(["evaluate", "--action", "nope", "--data"])
        .arg(&root)
        .assert()
        .failure()
        .stderr(predicate::str::contains("broken, good"));
}

/// The generated interactions scaled by 1e-6: the regularisation swamps them and
/// the first M-step already lowers the log-likelihood.
fn tiny_dataset() -> (tempfile::TempDir, std::path::PathBuf) {
    interaction_folder(8, 3, 6, |_, _, v| (v * 1e-6).to_string())
}

#[test]
fn the_fit_report_has_one_stop_field_and_the_same_notes_in_every_format() {
    let (dir, data) = tiny_dataset();
    let model = dir.path().join("m.json");
    let run = |format: &str| {
        let out = phasekit()
            .args(["fit", "--method", "hmm", "--format", format, "--data"])
            .arg(&data)
            .arg("-o")
            .arg(&model)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone();
        String::from_utf8(out).unwrap()
    };
    let json: serde_json::Value = serde_json::from_str(&run("json")).unwrap();
    assert_eq!(json["stop"], "log-likelihood fell", "{json}");
    assert!(json.get("converged").is_none() && json.get("stopped_on_decrease").is_none());
    let notes: Vec<&str> = json["notes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap())
        .collect();
    assert!(
        notes.iter().any(|n| n.contains("log-likelihood fell")
            && n.contains("--reg")
            && n.contains("--standardise")),
        "{notes:?}"
    );
    assert!(notes.iter().any(|n| n.contains("exceeds the variance")));
    // Markdown: the same stop and every note.
    let md = run("md");
    assert!(
        md.contains("| stop | stopped because the log-likelihood fell |"),
        "{md}"
    );
    for n in &notes {
        assert!(md.contains(n), "md lacks the note {n}:\n{md}");
    }
    // The model file records the same reason.
    let mf = phasekit_cli::model_file::ModelFile::load(&model).unwrap();
    assert_eq!(mf.fit.stop, phasekit_tsc::FitStop::LogLikelihoodFell);
    // The notes are those the terminal prints (the text report).
    assert_eq!(phasekit_cli::commands::fit::notes(&mf.fit), notes);

    // Converged and max-iter.
    let (_dir2, data2) = small_dataset();
    for (extra, stop) in [
        (&[][..], "converged"),
        (&["--max-iter", "1"][..], "max-iter"),
    ] {
        let out = phasekit()
            .args(["fit", "--method", "hmm", "--format", "json", "--data"])
            .arg(&data2)
            .args(extra)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone();
        let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
        assert_eq!(v["stop"], stop, "{v}");
    }
}

#[test]
fn model_files_with_the_old_stop_fields_still_load() {
    let (dir, data) = small_dataset();
    let model = dir.path().join("m.json");
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();
    let text = std::fs::read_to_string(&model).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    for (converged, fell, want) in [
        (true, true, phasekit_tsc::FitStop::LogLikelihoodFell),
        (true, false, phasekit_tsc::FitStop::Converged),
        (false, false, phasekit_tsc::FitStop::MaxIter),
    ] {
        let fit = v["fit"].as_object_mut().unwrap();
        fit.remove("stop");
        fit.insert("converged".into(), converged.into());
        fit.insert("stopped_on_decrease".into(), fell.into());
        let old = dir.path().join("old.json");
        std::fs::write(&old, serde_json::to_string(&v).unwrap()).unwrap();
        let mf = phasekit_cli::model_file::ModelFile::load(&old).unwrap();
        assert_eq!(mf.fit.stop, want);
        // And predicts as the model it was.
        phasekit()
            .args(["predict", "--model"])
            .arg(&old)
            .arg("--data")
            .arg(data.join("test_00.csv"))
            .assert()
            .success();
    }
    // Files older still (no stopped_on_decrease) read as well.
    v["fit"]
        .as_object_mut()
        .unwrap()
        .remove("stopped_on_decrease");
    let old = dir.path().join("older.json");
    std::fs::write(&old, serde_json::to_string(&v).unwrap()).unwrap();
    assert_eq!(
        phasekit_cli::model_file::ModelFile::load(&old)
            .unwrap()
            .fit
            .stop,
        phasekit_tsc::FitStop::MaxIter
    );
}

/// The lines after `Next` in the demo's output: shell commands.
fn next_commands(out: &str) -> Vec<String> {
    out.lines()
        .skip_while(|l| !l.starts_with("Next"))
        .skip(1)
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(str::to_string)
        .collect()
}

#[test]
fn the_demo_shows_the_seven_state_control_and_commands_that_work_as_printed() {
    let dir = tempfile::tempdir().unwrap();
    let out = phasekit()
        .current_dir(dir.path())
        .args([
            "demo", "--train", "6", "--test", "2", "--seeds", "3", "-o", "my demo",
        ])
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let out = String::from_utf8(out).unwrap();
    for row in [
        "| hmm | 4 |",
        "| hmm:states=7 | 7 |",
        "| tsc-hmm:window=2 | 7 |",
    ] {
        assert_eq!(out.matches(row).count(), 2, "{row} in both tables:\n{out}");
    }
    assert!(out.contains("Over 3 random training subsets"), "{out}");
    assert!(out.contains("Δ MSE vs hmm:states=7"), "{out}");
    // The binary is not on the PATH here: the commands name it by its path, and
    // every one of them runs as printed.
    let commands = next_commands(&out);
    assert!(commands.len() >= 4, "{out}");
    for c in &commands {
        assert!(!c.starts_with("phasekit "), "{c}");
        let status = std::process::Command::new("sh")
            .current_dir(dir.path())
            .args(["-c", &format!("{c} > /dev/null")])
            .status()
            .unwrap();
        assert!(status.success(), "`{c}` failed");
    }
    // With the binary on the PATH the short name is printed, and works.
    let bin = assert_cmd::cargo::cargo_bin("phasekit");
    let path = format!(
        "{}:{}",
        bin.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let out = phasekit()
        .current_dir(dir.path())
        .env("PATH", &path)
        .args([
            "demo", "--train", "4", "--test", "1", "--seeds", "0", "-o", "my demo",
        ])
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let out = String::from_utf8(out).unwrap();
    let commands = next_commands(&out);
    assert!(
        commands[0].starts_with("phasekit segment --model 'my demo/tsc-hmm.json'"),
        "{out}"
    );
    let status = std::process::Command::new("sh")
        .current_dir(dir.path())
        .env("PATH", &path)
        .args(["-c", &format!("{} > /dev/null", commands[0])])
        .status()
        .unwrap();
    assert!(status.success());
}

#[test]
fn the_demo_refuses_what_it_cannot_do_and_never_leaves_a_partial_folder() {
    let dir = tempfile::tempdir().unwrap();
    let names = || -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    phasekit()
        .current_dir(dir.path())
        .args(["demo", "--train", "1000000", "-o", "big"])
        .assert()
        .failure()
        .code(1)
        .stderr(predicate::str::contains("at most 1000"));
    assert!(names().is_empty(), "{:?}", names());
    // A folder with files the demo did not write is not touched.
    let mine = dir.path().join("mine");
    std::fs::create_dir(&mine).unwrap();
    std::fs::write(mine.join("thesis.tex"), "keep me").unwrap();
    phasekit()
        .current_dir(dir.path())
        .args([
            "demo", "--train", "4", "--test", "1", "--seeds", "0", "-o", "mine",
        ])
        .assert()
        .failure()
        .stderr(predicate::str::contains("thesis.tex"));
    assert_eq!(names(), ["mine"]);
    assert_eq!(
        std::fs::read_dir(&mine).unwrap().count(),
        1,
        "nothing written into it"
    );
    // An earlier demo's folder is replaced as a whole (no stale data files).
    for train in ["6", "4"] {
        phasekit()
            .current_dir(dir.path())
            .args([
                "demo", "--train", train, "--test", "1", "--seeds", "0", "-o", "demo",
            ])
            .assert()
            .success();
    }
    assert_eq!(names(), ["demo", "mine"], "no temporary folder left");
    let mut data: Vec<String> = std::fs::read_dir(dir.path().join("demo/data"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    data.sort();
    assert_eq!(
        data,
        [
            "test_00.csv",
            "train_00.csv",
            "train_01.csv",
            "train_02.csv",
            "train_03.csv"
        ]
    );
}

/// The text elements of an SVG: `(x, y, text)`.
fn svg_texts(svg: &str) -> Vec<(f64, f64, String)> {
    svg.split("<text")
        .skip(1)
        .map(|t| {
            let attr = |name: &str| -> f64 {
                t.split(&format!(" {name}=\""))
                    .nth(1)
                    .and_then(|v| v.split('"').next())
                    .and_then(|v| v.parse().ok())
                    .unwrap_or(f64::NAN)
            };
            let body = t.split_once('>').unwrap().1;
            let body = body.split("</text>").next().unwrap().trim();
            (attr("x"), attr("y"), body.to_string())
        })
        .collect()
}

/// Every point of every polyline of an SVG.
fn svg_line_points(svg: &str) -> Vec<(f64, f64)> {
    svg.split("<polyline")
        .skip(1)
        .flat_map(|p| {
            let pts = p
                .split("points=\"")
                .nth(1)
                .unwrap()
                .split('"')
                .next()
                .unwrap();
            pts.split_whitespace()
                .map(|xy| {
                    let (x, y) = xy.split_once(',').unwrap();
                    (x.parse().unwrap(), y.parse().unwrap())
                })
                .collect::<Vec<(f64, f64)>>()
        })
        .collect()
}

/// No tick label reads `-0`, `-0.0`, `-0.00`, …
fn assert_no_minus_zero(svg: &str) {
    for (_, _, t) in svg_texts(svg) {
        let minus_zero =
            t.starts_with('-') && t.len() > 1 && t[1..].chars().all(|c| c == '0' || c == '.');
        assert!(!minus_zero, "tick label `{t}`");
    }
}

fn plot(kind: &[&str], model: &Path, data: &Path, out: &Path, extra: &[&str]) -> String {
    phasekit()
        .arg("plot")
        .args(kind)
        .arg("--model")
        .arg(model)
        .arg("--data")
        .arg(data)
        .arg("-o")
        .arg(out)
        .args(extra)
        .assert()
        .success();
    std::fs::read_to_string(out).unwrap()
}

#[test]
fn the_prediction_plot_says_its_units_and_what_the_band_is_made_of() {
    let (dir, data) = small_dataset();
    let model = dir.path().join("m.json");
    phasekit()
        .args(["fit", "--method", "tsc-hmm:window=2", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();
    let test = data.join("test_00.csv");
    let svg = plot(
        &["prediction"],
        &model,
        &test,
        &dir.path().join("p.svg"),
        &[],
    );
    let texts: Vec<String> = svg_texts(&svg).into_iter().map(|t| t.2).collect();
    let all = texts.join("\n");
    // The title's MSE in the table's unit, with four significant digits.
    let title = texts.iter().find(|t| t.contains("MSE")).unwrap();
    assert!(
        title.contains(" cm², ±2σ bands)") && !title.contains("data units"),
        "{title}"
    );
    let mse = title
        .split("MSE ")
        .nth(1)
        .unwrap()
        .split(' ')
        .next()
        .unwrap();
    assert!(mse.trim_start_matches(['0', '.']).len() >= 4, "{title}");
    for axis in [
        "p2_wrist_x (cm)",
        "p2_wrist_y (cm)",
        "p2_wrist_z (cm)",
        "frame",
    ] {
        assert!(texts.iter().any(|t| t == axis), "axis label {axis}:\n{all}");
    }
    // The regularisation: its value, the width it alone gives, its share of each band.
    assert!(all.contains("regularisation r = 1e-2"), "{all}");
    assert!(all.contains("±2√r = ±20.00 cm"), "{all}");
    assert_eq!(
        all.matches("of this band's variance").count(),
        0,
        "wrapped: {all}"
    );
    assert_eq!(
        texts
            .iter()
            .filter(|t| t.starts_with("Regularisation:"))
            .count(),
        3,
        "{all}"
    );
    assert_no_minus_zero(&svg);
    // The legend sits beside the curves, never on them.
    let lines = svg_line_points(&svg);
    let right = lines.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
    let legend: Vec<(f64, f64, String)> = svg_texts(&svg)
        .into_iter()
        .filter(|t| ["true", "predicted"].contains(&t.2.as_str()))
        .collect();
    assert_eq!(legend.len(), 2);
    assert!(
        legend.iter().all(|t| t.0 > right),
        "legend at {legend:?}, curves up to x = {right}"
    );
    // Another unit: the same picture in mm.
    let svg = plot(
        &["prediction"],
        &model,
        &test,
        &dir.path().join("mm.svg"),
        &["--unit", "mm"],
    );
    assert!(svg.contains("p2_wrist_x (mm)") && svg.contains(" mm², ±2σ bands)"));
    assert!(svg.contains("±2√r = ±200.00 mm"), "{svg}");
}

#[test]
fn long_demonstrations_are_drawn_decimated_and_say_so() {
    let (dir, data) = small_dataset();
    let model = dir.path().join("m.json");
    phasekit()
        .args(["fit", "--method", "tsc-hmm:window=2", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();
    // 30,000 frames: a test demonstration played over and over.
    let text = std::fs::read_to_string(data.join("test_00.csv")).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let rows: Vec<&str> = lines.collect();
    let mut long = format!("{header}\n");
    for k in 0..30_000 {
        long.push_str(rows[k % rows.len()]);
        long.push('\n');
    }
    let long_csv = dir.path().join("long.csv");
    std::fs::write(&long_csv, long).unwrap();
    for kind in ["prediction", "segmentation"] {
        let svg = plot(&[kind], &model, &long_csv, &dir.path().join("l.svg"), &[]);
        assert!(svg.len() < 600_000, "{kind}: {} bytes", svg.len());
        let all: String = svg_texts(&svg).into_iter().map(|t| t.2 + " ").collect();
        assert!(
            all.contains("30000 frames, drawn as 1000 buckets of 30 frames"),
            "{kind}: {all}"
        );
        let points = svg_line_points(&svg).len();
        assert!(points < 30_000, "{kind}: {points} points drawn");
    }
    // The states plot draws every k-th frame of long trajectories.
    let svg = plot(
        &["states"],
        &model,
        &long_csv,
        &dir.path().join("s.svg"),
        &[],
    );
    assert!(svg.len() < 1_500_000, "states: {} bytes", svg.len());
    let all: String = svg_texts(&svg).into_iter().map(|t| t.2 + " ").collect();
    assert!(
        all.contains("30000 frames: trajectories drawn at one frame in 2"),
        "states: {all}"
    );
}

#[test]
fn the_states_plots_have_units_a_scale_and_say_what_the_regularisation_does() {
    let (dir, data) = small_dataset();
    let model = dir.path().join("m.json");
    phasekit()
        .args(["fit", "--method", "tsc-hmm:window=2", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(&model)
        .assert()
        .success();
    let svg = plot(&["states"], &model, &data, &dir.path().join("s.svg"), &[]);
    let all: String = svg_texts(&svg).into_iter().map(|t| t.2 + " ").collect();
    assert!(
        all.contains("p2_wrist_x (cm)") && all.contains("p2_wrist_z (cm)"),
        "{all}"
    );
    assert!(all.contains("2√r = 20.00 cm"), "{all}");
    assert_no_minus_zero(&svg);
    let svg = plot(
        &["states", "--view", "3d"],
        &model,
        &data,
        &dir.path().join("s3.svg"),
        &[],
    );
    let texts = svg_texts(&svg);
    for axis in ["p2_wrist_x (cm)", "p2_wrist_y (cm)", "p2_wrist_z (cm)"] {
        assert!(texts.iter().any(|t| t.2 == axis), "{axis}");
    }
    // A scale: round tick values along the axes.
    let ticks = texts
        .iter()
        .filter(|t| t.2.parse::<f64>().is_ok_and(|v| v.fract() == 0.0))
        .count();
    assert!(ticks >= 6, "{ticks} tick labels: {texts:?}");
    assert_no_minus_zero(&svg);
    let segmentation = plot(
        &["segmentation"],
        &model,
        &data.join("test_00.csv"),
        &dir.path().join("g.svg"),
        &[],
    );
    assert!(
        segmentation.contains("robot&apos;s position (cm)")
            || segmentation.contains("robot's position (cm)")
    );
    assert_no_minus_zero(&segmentation);
}
