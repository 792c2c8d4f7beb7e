//! `--json` is `--format json` on every command that prints for machines.

use crate::common;

use common::{interaction_folder, phasekit, plain};

#[test]
fn json_flag_equals_format_json() {
    let (dir, data) = interaction_folder(6, 2, 4, plain);
    let model = dir.path().join("m.json");
    let keys = |out: Vec<u8>| -> Vec<String> {
        let v: serde_json::Value = serde_json::from_slice(&out).expect("JSON on stdout");
        let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
        k.sort();
        k
    };
    let run = |args: &[&str]| {
        phasekit()
            .args(args)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone()
    };
    let m = model.to_str().unwrap();
    let d = data.to_str().unwrap();
    let test = data.join("test_00.csv");
    let t = test.to_str().unwrap();
    let a = keys(run(&[
        "fit", "--method", "hmm", "--json", "-o", m, "--data", d,
    ]));
    let b = keys(run(&[
        "fit", "--method", "hmm", "--format", "json", "-o", m, "--data", d,
    ]));
    assert_eq!(a, b);
    assert!(a.contains(&"iterations".to_string()) && a.contains(&"fit_seconds".to_string()));
    for cmd in [["predict"], ["segment"]] {
        let a = run(&[cmd[0], "--json", "--model", m, "--data", t]);
        let b = run(&[cmd[0], "--format", "json", "--model", m, "--data", t]);
        assert_eq!(a, b, "{}", cmd[0]);
    }
    let a = keys(run(&[
        "evaluate",
        "--methods",
        "hmm",
        "--seeds",
        "2",
        "--json",
        "--data",
        d,
    ]));
    let b = keys(run(&[
        "evaluate",
        "--methods",
        "hmm",
        "--seeds",
        "2",
        "--format",
        "json",
        "--data",
        d,
    ]));
    assert_eq!(a, b);
    assert!(a.contains(&"results".to_string()));
    phasekit()
        .args(["fit", "--json", "--format", "md", "-o", m, "--data", d])
        .assert()
        .failure();
}
