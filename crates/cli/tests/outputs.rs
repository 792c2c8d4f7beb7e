//! Outputs that cannot destroy inputs: `-o` naming an input is refused before
//! any work; symbolic links are written through, devices and pipes written
//! directly, read-only files refused, hard links kept; `-o -` is stdout; an
//! interrupted write leaves no temporary file; the extension picks the format
//! (NPY) or is refused.

#![cfg(unix)]

use crate::common;

use common::{fit_model, interaction_folder, parse_csv, phasekit, phasekit_path, plain};
use predicates::prelude::*;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use tempfile::TempDir;

fn setup() -> (TempDir, PathBuf, PathBuf) {
    let (dir, data) = interaction_folder(8, 5, 6, plain);
    let model = dir.path().join("m.json");
    fit_model(&data, "hmm", &model);
    (dir, data, model)
}

fn predict(model: &Path, data: &Path, out: &Path) -> assert_cmd::assert::Assert {
    phasekit()
        .args(["predict", "--model"])
        .arg(model)
        .arg("--data")
        .arg(data)
        .arg("-o")
        .arg(out)
        .assert()
}

fn temporaries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

#[test]
fn an_output_that_is_an_input_is_refused_before_any_work() {
    let (dir, data, model) = setup();
    let d = dir.path();
    let test = d.join("a.csv");
    std::fs::copy(data.join("test_00.csv"), &test).unwrap();
    let before = std::fs::read(&test).unwrap();
    let model_before = std::fs::read(&model).unwrap();
    // The data file itself, a symbolic link to it, a hard link to it.
    std::os::unix::fs::symlink(&test, d.join("link.csv")).unwrap();
    std::fs::hard_link(&test, d.join("hard.csv")).unwrap();
    for out in ["a.csv", "link.csv", "hard.csv"] {
        predict(&model, &test, &d.join(out))
            .failure()
            .stderr(predicate::str::contains("is also an input of this command"));
    }
    // segment … -o over the model file.
    phasekit()
        .args(["segment", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test)
        .arg("-o")
        .arg(&model)
        .assert()
        .failure()
        .stderr(predicate::str::contains("is also an input"));
    // fit over a training file (named .json, so that only the collision is wrong).
    let train = d.join("train.json");
    std::fs::copy(data.join("train_00.csv"), &train).unwrap();
    let train_before = std::fs::read(&train).unwrap();
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&train)
        .arg(data.join("train_01.csv"))
        .arg("-o")
        .arg(&train)
        .assert()
        .failure()
        .stderr(predicate::str::contains("is also an input"));
    // plot over the model, through a link.
    std::os::unix::fs::symlink(&model, d.join("model.svg")).unwrap();
    phasekit()
        .args(["plot", "prediction", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test)
        .arg("-o")
        .arg(d.join("model.svg"))
        .assert()
        .failure()
        .stderr(predicate::str::contains("is also an input"));
    assert_eq!(std::fs::read(&test).unwrap(), before);
    assert_eq!(std::fs::read(&model).unwrap(), model_before);
    assert_eq!(std::fs::read(&train).unwrap(), train_before);
    assert!(temporaries(d).is_empty());
}

#[test]
fn a_symbolic_link_is_written_through_and_keeps_its_target_mode() {
    let (dir, data, model) = setup();
    let d = dir.path();
    let target = d.join("target.csv");
    std::fs::write(&target, "old\n").unwrap();
    std::fs::set_permissions(&target, std::fs::Permissions::from_mode(0o640)).unwrap();
    let link = d.join("out.csv");
    std::os::unix::fs::symlink("target.csv", &link).unwrap();
    predict(&model, &data.join("test_00.csv"), &link).success();
    assert!(
        std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink(),
        "the link stays a link"
    );
    let text = std::fs::read_to_string(&target).unwrap();
    assert!(text.starts_with("frame,"), "the target has the prediction");
    assert_eq!(
        std::fs::metadata(&target).unwrap().permissions().mode() & 0o777,
        0o640
    );
    // A link to nothing is refused, as cp does.
    let dangling = d.join("dangling.csv");
    std::os::unix::fs::symlink("nowhere/x.csv", &dangling).unwrap();
    predict(&model, &data.join("test_00.csv"), &dangling)
        .failure()
        .stderr(predicate::str::contains(
            "which does not exist: not writing through it",
        ));
    assert!(temporaries(d).is_empty());
}

#[test]
fn pipes_and_stdout_are_written_directly() {
    let (dir, data, model) = setup();
    let d = dir.path();
    // A named pipe: its reader gets the prediction, and it stays a pipe.
    let fifo = d.join("fifo");
    let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read_to_string(fifo).unwrap())
    };
    predict(&model, &data.join("test_00.csv"), &fifo).success();
    let got = reader.join().unwrap();
    assert!(got.starts_with("frame,") && got.lines().count() > 50);
    use std::os::unix::fs::FileTypeExt;
    assert!(std::fs::symlink_metadata(&fifo)
        .unwrap()
        .file_type()
        .is_fifo());
    // `-o -` and a link to this process's stdout (/proc/self/fd/1) reach stdout.
    let want = phasekit()
        .args(["predict", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(data.join("test_00.csv"))
        .output()
        .unwrap()
        .stdout;
    for out in ["-", "/proc/self/fd/1"] {
        let got = predict(&model, &data.join("test_00.csv"), Path::new(out))
            .success()
            .get_output()
            .stdout
            .clone();
        assert_eq!(got, want, "-o {out}");
    }
    assert!(temporaries(d).is_empty());
}

#[test]
fn a_read_only_target_is_refused_and_hard_links_are_kept() {
    let (dir, data, model) = setup();
    let d = dir.path();
    let ro = d.join("ro.csv");
    std::fs::write(&ro, "keep me\n").unwrap();
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o444)).unwrap();
    // Refused even for root: no write permission means someone made it read-only.
    predict(&model, &data.join("test_00.csv"), &ro)
        .failure()
        .stderr(predicate::str::contains("read-only"));
    assert_eq!(std::fs::read_to_string(&ro).unwrap(), "keep me\n");
    // A file with two names: both see the new content (the link is not split).
    let a = d.join("a.csv");
    let b = d.join("b.csv");
    std::fs::write(&a, "old\n").unwrap();
    std::fs::hard_link(&a, &b).unwrap();
    predict(&model, &data.join("test_00.csv"), &a).success();
    let (ma, mb) = (
        std::fs::metadata(&a).unwrap(),
        std::fs::metadata(&b).unwrap(),
    );
    assert_eq!(ma.ino(), mb.ino(), "still one file");
    assert!(std::fs::read_to_string(&b).unwrap().starts_with("frame,"));
    assert!(temporaries(d).is_empty());
}

#[test]
fn an_interrupted_write_leaves_no_temporary_file() {
    let (dir, data, model) = setup();
    let d = dir.path();
    for (sig, name) in [(libc::SIGINT, "int.csv"), (libc::SIGTERM, "term.csv")] {
        let out = d.join(name);
        // Debug builds hold the complete temporary file this long before the rename.
        let mut child = std::process::Command::new(phasekit_path())
            .env("PHASEKIT_TEST_HOLD_TEMPORARY_MS", "20000")
            .args(["predict", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(data.join("test_00.csv"))
            .arg("-o")
            .arg(&out)
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        while temporaries(d).is_empty() {
            assert!(
                start.elapsed().as_secs() < 30 && child.try_wait().unwrap().is_none(),
                "no temporary file appeared while writing {name}"
            );
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        // SAFETY: signals a child process this test started.
        assert_eq!(unsafe { libc::kill(child.id() as i32, sig) }, 0);
        let status = child.wait().unwrap();
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(status.signal(), Some(sig), "ends by the signal: {status:?}");
        assert!(temporaries(d).is_empty(), "{:?}", temporaries(d));
        assert!(!out.exists());
    }
}

#[test]
fn the_extension_chooses_npy_or_is_refused() {
    let (dir, data, model) = setup();
    let d = dir.path();
    let test = data.join("test_00.csv");
    let csv = predict(&model, &test, &d.join("p.csv")).success();
    let _ = csv;
    let (header, rows) = parse_csv(&std::fs::read_to_string(d.join("p.csv")).unwrap());
    predict(&model, &test, &d.join("p.npy")).success();
    let npy = phasekit_cli::data::read_table(&d.join("p.npy")).unwrap();
    assert_eq!(npy.columns.len(), header.len());
    assert_eq!(npy.n_rows(), rows.len());
    assert_eq!(npy.data, rows.concat(), "the same numbers as the CSV");
    // segment writes NPY too: file index, frame, state, transition, cluster.
    phasekit()
        .args(["segment", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test)
        .arg(data.join("test_01.csv"))
        .arg("-o")
        .arg(d.join("s.npy"))
        .assert()
        .success();
    let seg = phasekit_cli::data::read_table(&d.join("s.npy")).unwrap();
    assert_eq!(seg.columns.len(), 5);
    assert_eq!(
        seg.column(0).iter().filter(|f| **f == 1.0).count() + rows.len(),
        seg.n_rows()
    );
    // Extensions that do not fit.
    phasekit()
        .args(["fit", "--method", "hmm", "--data"])
        .arg(&data)
        .arg("-o")
        .arg(d.join("model.npy"))
        .assert()
        .failure()
        .stderr(predicate::str::contains("a model file is JSON"));
    predict(&model, &test, &d.join("p.svg"))
        .failure()
        .stderr(predicate::str::contains(
            "writes csv, json or npy, not .svg",
        ));
    phasekit()
        .args(["predict", "--format", "csv", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test)
        .arg("-o")
        .arg(d.join("q.npy"))
        .assert()
        .failure()
        .stderr(predicate::str::contains(
            "the extension .npy does not fit --format csv",
        ));
    phasekit()
        .args(["plot", "prediction", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&test)
        .arg("-o")
        .arg(d.join("p.png"))
        .assert()
        .failure()
        .stderr(predicate::str::contains("plot writes SVG"));
    assert!(
        !d.join("model.npy").exists() && !d.join("p.svg").exists() && !d.join("q.npy").exists()
    );
}
