//! `phasekit stream` refuses input it does not understand: columns are mapped
//! by name, a line that is not a frame stops the stream unless
//! `--on-bad-line` says otherwise, every frame gives exactly one line with a
//! status, and a frame no state explains does not derail the next ones.

use crate::common;

use common::{fit_model, interaction_folder, parse_stream, phasekit, plain};
use predicates::prelude::*;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

/// A fitted HMM on generated demonstrations, and one test demonstration's text.
fn setup() -> (TempDir, PathBuf, String) {
    let (dir, data) = interaction_folder(9, 11, 7, plain);
    let model = dir.path().join("m.json");
    fit_model(&data, "hmm", &model);
    let text = std::fs::read_to_string(data.join("test_00.csv")).unwrap();
    (dir, model, text)
}

/// The columns `cols` (0-based) of a CSV text, header included.
fn cut(text: &str, cols: &[usize]) -> String {
    text.lines()
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            cols.iter().map(|&c| cells[c]).collect::<Vec<_>>().join(",") + "\n"
        })
        .collect()
}

fn stream(model: &Path, args: &[&str], input: &str) -> assert_cmd::assert::Assert {
    phasekit()
        .arg("stream")
        .args(args)
        .arg("--model")
        .arg(model)
        .write_stdin(input.to_string())
        .assert()
}

fn stdout(a: &assert_cmd::assert::Assert) -> String {
    String::from_utf8(a.get_output().stdout.clone()).unwrap()
}

#[test]
fn a_header_that_does_not_name_the_model_columns_is_an_error_before_any_output() {
    let (_dir, model, text) = setup();
    // The shoulder columns instead of the wrist the model was fitted on: here,
    // the robot's columns (the file has no shoulders), three of them as the model needs.
    let wrong = cut(&text, &[3, 4, 5]);
    stream(&model, &[], &wrong)
        .failure()
        .code(1)
        .stdout("")
        .stderr(
            predicate::str::contains("stdin line 1")
                .and(predicate::str::contains("lacks the model's human columns"))
                .and(predicate::str::contains("p1_wrist_x"))
                .and(predicate::str::contains("--columns")),
        );
    // An explicit mapping overrides: then they are read as the model's columns.
    let mapped = stream(
        &model,
        &["--columns", "p2_wrist_x,p2_wrist_y,p2_wrist_z"],
        &wrong,
    )
    .success();
    let (_, rows, _) = parse_stream(&stdout(&mapped), true);
    assert_eq!(rows.len(), text.lines().count() - 1);
    // Numbers map columns of a file without a header, or with one.
    let by_number = stream(&model, &["--columns", "4,5,6"], &text).success();
    assert_eq!(stdout(&by_number), stdout(&mapped));
}

#[test]
fn columns_are_mapped_by_name_not_position() {
    let (_dir, model, text) = setup();
    let straight = stdout(&stream(&model, &["--quiet"], &cut(&text, &[0, 1, 2])).success());
    // Reordered, with a byte order mark as spreadsheets write it, and with
    // more columns than the model needs: the same predictions.
    let reordered = format!("\u{feff}{}", cut(&text, &[5, 2, 1, 0, 3]));
    let got = stdout(&stream(&model, &["--quiet"], &reordered).success());
    assert_eq!(got, straight);
    // Another case is not the same name: refused, with a hint, before any output.
    let upper = text.replacen("p1_wrist_x", "P1_WRIST_X", 1);
    stream(&model, &[], &upper).failure().stdout("").stderr(
        predicate::str::contains("`P1_WRIST_X` is not `p1_wrist_x`")
            .and(predicate::str::contains("case included")),
    );
}

#[test]
fn a_line_with_the_wrong_number_of_values_stops_the_stream_by_default() {
    let (_dir, model, text) = setup();
    // Two values per line without a header; the model needs three.
    let two: String = cut(&text, &[0, 1])
        .lines()
        .skip(1)
        .map(|l| l.to_string() + "\n")
        .collect();
    stream(&model, &[], &two)
        .failure()
        .code(1)
        .stdout("")
        .stderr(
            predicate::str::contains("stdin line 1: 2 values, expected 3")
                .and(predicate::str::contains("--on-bad-line")),
        );
    let n = two.lines().count();
    // missing: every line a frame with nothing observed, said so on its line.
    let a = stream(&model, &["--on-bad-line", "missing"], &two).success();
    let (_, rows, status) = parse_stream(&stdout(&a), true);
    assert_eq!(rows.len(), n);
    assert!(status.iter().all(|s| s == "unobserved"));
    // skip: no frame at all.
    let a = stream(&model, &["--on-bad-line", "skip"], &two).success();
    assert_eq!(stdout(&a).lines().count(), 1, "the header only");
    // A bad line in the middle: the frames before it are out, then the error.
    let mut lines: Vec<String> = cut(&text, &[0, 1, 2]).lines().map(str::to_string).collect();
    lines.insert(6, "0.1,0.2".into());
    let a = stream(&model, &[], &(lines.join("\n") + "\n"))
        .failure()
        .stderr(predicate::str::contains(
            "stdin line 7: 2 values, expected 3",
        ));
    assert_eq!(stdout(&a).lines().count(), 1 + 5);
}

#[test]
fn one_output_line_per_frame_and_a_glitch_does_not_derail_the_next_frames() {
    let (dir, model, text) = setup();
    let human = cut(&text, &[0, 1, 2]);
    let mut lines: Vec<String> = human.lines().map(str::to_string).collect();
    let n = lines.len() - 1;
    // Frame 3 holds 1e200: before, it failed and the next valid line was dropped too.
    lines[4] = lines[4].replacen(lines[4].split(',').next().unwrap(), "1e200", 1);
    let glitch = stream(&model, &[], &(lines.join("\n") + "\n")).success();
    let (_, rows, status) = parse_stream(&stdout(&glitch), true);
    assert_eq!(rows.len(), n, "one line per frame");
    assert_eq!(
        rows.iter().map(|r| r[0] as usize).collect::<Vec<_>>(),
        (0..n).collect::<Vec<_>>(),
        "frame numbers match the input"
    );
    assert_eq!(status[3], "rejected");
    assert!(
        status.iter().enumerate().all(|(t, s)| t == 3 || s == "ok"),
        "{status:?}"
    );
    // Exactly as with that frame not observed (its cells empty).
    lines[4] = ",,".into();
    let empty = stream(&model, &[], &(lines.join("\n") + "\n")).success();
    let (_, want, _) = parse_stream(&stdout(&empty), true);
    for (t, (a, b)) in rows.iter().zip(&want).enumerate() {
        for (x, y) in a.iter().zip(b) {
            assert!(
                (x - y).abs() <= 1e-12 * (1.0 + y.abs()),
                "frame {t}: {x} vs {y}"
            );
        }
        assert!(a[1..].iter().any(|v| *v != 0.0), "frame {t} is not zeroed");
    }
    drop(dir);
}

#[test]
fn banners_and_blank_lines_follow_the_policy() {
    let (_dir, model, text) = setup();
    let body = cut(&text, &[0, 1, 2]);
    let input = format!("Recorded with a tracker\n\n{body}");
    stream(&model, &[], &input)
        .failure()
        .stdout("")
        .stderr(predicate::str::contains(
            "stdin line 1: \"Recorded with a tracker\" is neither a header nor a frame",
        ));
    let skipped = stream(&model, &["--on-bad-line", "skip"], &input)
        .success()
        .stderr(predicate::str::contains(
            "stdin line 2: a blank line; skipped",
        ));
    let plain = stream(&model, &[], &body).success();
    assert_eq!(stdout(&skipped), stdout(&plain));
    // Before the first frame a line cannot be a frame: `missing` skips it too.
    let missing = stream(&model, &["--on-bad-line", "missing"], &input).success();
    assert_eq!(stdout(&missing), stdout(&plain));
    // A semicolon-separated stream is named as such.
    stream(&model, &[], &body.replace(',', ";"))
        .failure()
        .stderr(predicate::str::contains("separated by semicolons"));
}

#[test]
fn the_summary_counts_statuses_and_latency_comes_from_the_sketch() {
    let (_dir, model, text) = setup();
    let body = cut(&text, &[0, 1, 2]);
    let frames = body.lines().count() - 1;
    stream(
        &model,
        &[],
        &(body.clone()
            + ",,\n#reset\n"
            + &body.lines().skip(1).collect::<Vec<_>>().join("\n")
            + "\n"),
    )
    .success()
    .stderr(
        predicate::str::contains(format!(
            "{} frames ({} ok, 1 unobserved)",
            2 * frames + 1,
            2 * frames
        ))
        .and(predicate::str::contains("p99")),
    );
}
