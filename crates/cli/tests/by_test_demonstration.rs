//! `phasekit evaluate`'s scores per test demonstration (issue 17): every
//! action's test files are the same on every seed, so its MSE and coverage
//! are frame-weighted means of two or three demonstrations' own; and how many
//! distinct training subsets the seeds drew.

use crate::common;

use common::{evaluate_rows, interaction_folder, phasekit, plain, stdout};
use phasekit_cli::experiment::{distinct_subsets, subset, Protocol, Row};
use phasekit_cli::units::mean_pm;
use std::collections::HashSet;
use std::path::Path;

fn evaluate(data: &Path, labels: &[&str], seeds: usize) -> Vec<Row> {
    let protocol = Protocol {
        seeds,
        ..Protocol::default()
    };
    evaluate_rows(data, labels, &protocol)
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs())
}

#[test]
fn the_test_demonstrations_decompose_the_actions_scores() {
    // Every 5th frame of the robot's x unobserved: not scored anywhere.
    let (_dir, data) = interaction_folder(9, 4, 6, |t, k, v| {
        if k == 3 && t % 5 == 2 {
            String::new()
        } else {
            v.to_string()
        }
    });
    let rows = evaluate(&data, &["hmm", "gmm"], 4);
    for row in &rows {
        let names: Vec<&str> = row
            .by_test_demonstration
            .iter()
            .map(|d| d.name.as_str())
            .collect();
        assert_eq!(names, ["test_00.csv", "test_01.csv", "test_02.csv"]);
        let frames: usize = row.by_test_demonstration.iter().map(|d| d.frames).sum();
        let weighted = |f: fn(&phasekit_cli::experiment::TestDemonstrationSummary) -> f64| {
            row.by_test_demonstration
                .iter()
                .map(|d| d.frames as f64 * f(d))
                .sum::<f64>()
                / frames as f64
        };
        assert!(
            close(weighted(|d| d.mse_mean), row.mse_mean, 1e-12),
            "{}: {} vs {}",
            row.method,
            weighted(|d| d.mse_mean),
            row.mse_mean
        );
        assert!(row.coverage_mean.is_finite() && row.nlpd_mean.is_finite());
        assert!(close(
            weighted(|d| d.coverage_mean),
            row.coverage_mean,
            1e-12
        ));
        assert!(close(weighted(|d| d.nlpd_mean), row.nlpd_mean, 1e-12));
        // The demonstrations differ (else the split would prove nothing).
        let m: Vec<f64> = row
            .by_test_demonstration
            .iter()
            .map(|d| d.mse_mean)
            .collect();
        assert!(m.windows(2).any(|w| !close(w[0], w[1], 1e-6)), "{m:?}");
    }
}

#[test]
fn one_test_demonstrations_scores_are_those_of_a_run_on_it_alone() {
    // The same training files with only the second test file: the same fits
    // (training does not see the test files), so its row is that
    // demonstration's line of the full run; an index mixed up fails here.
    let (dir, data) = interaction_folder(9, 4, 6, plain);
    let alone = dir.path().join("alone");
    std::fs::create_dir(&alone).unwrap();
    for entry in std::fs::read_dir(&data).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        if name.starts_with("train_") || name == "test_01.csv" {
            std::fs::copy(data.join(&name), alone.join(&name)).unwrap();
        }
    }
    let full = evaluate(&data, &["hmm"], 3);
    let one = evaluate(&alone, &["hmm"], 3);
    let d = &full[0].by_test_demonstration[1];
    assert_eq!(d.name, "test_01.csv");
    let row = &one[0];
    assert_eq!(row.by_test_demonstration.len(), 1);
    assert!(close(d.mse_mean, row.mse_mean, 1e-12), "{d:?} {row:?}");
    assert!(close(d.mse_std, row.mse_std, 1e-9));
    assert!(close(d.coverage_mean, row.coverage_mean, 1e-12));
    assert!(close(d.coverage_std, row.coverage_std, 1e-9));
    assert!(close(d.nlpd_mean, row.nlpd_mean, 1e-12));
    assert_eq!(row.by_test_demonstration[0], *d);
}

#[test]
fn the_seeds_draw_at_most_every_subset_once() {
    // By enumeration: every subset of size 4 of 6 (C(6, 4) = 15) as a bit mask.
    let all: HashSet<u32> = (0u32..64).filter(|m| m.count_ones() == 4).collect();
    assert_eq!(all.len(), 15);
    let drawn: HashSet<u32> = (0..200)
        .map(|s| subset(s, 6, 4).iter().map(|&i| 1u32 << i).sum())
        .collect();
    assert!(drawn.is_subset(&all));
    assert_eq!(distinct_subsets(200, 6, 4), drawn.len());
    // 200 seeds draw all 15 (each missed with probability (14/15)^200 < 1e-5).
    assert_eq!(drawn.len(), 15);
    assert_eq!(distinct_subsets(3, 9, 7), 3);
    assert_eq!(distinct_subsets(50, 5, 5), 1);
    let (_dir, data) = interaction_folder(8, 3, 6, plain);
    let rows = evaluate(&data, &["hmm"], 5);
    assert_eq!(rows[0].training_subsets, distinct_subsets(5, 6, 4));
}

#[test]
fn evaluate_writes_the_scores_by_test_demonstration_in_every_format() {
    let (dir, data) = interaction_folder(8, 3, 6, plain);
    let prefix = dir.path().join("run");
    let md = stdout(
        phasekit()
            .args(["evaluate", "--methods", "hmm,gmm", "--seeds", "3"])
            .arg("--data")
            .arg(&data)
            .arg("-o")
            .arg(&prefix),
    );
    assert!(md.contains("By test demonstration"), "{md}");
    assert!(
        md.contains(&format!(
            "distinct training subsets: data: {} in 3 seeds)",
            distinct_subsets(3, 6, 4)
        )),
        "{md}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("run.json")).unwrap())
            .unwrap();
    let csv = std::fs::read_to_string(dir.path().join("run_by_test_demonstration.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next().unwrap(),
        "action,method,test_demonstration,frames,seeds,mse_mean_cm2,mse_sd_cm2,coverage_mean,coverage_sd,nlpd_mean"
    );
    let lines: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(lines.len(), 2 * 2, "{csv}");
    let methods: Vec<&serde_json::Value> = json["results"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["baseline"] == false)
        .collect();
    let mut i = 0;
    for r in methods {
        for d in r["by_test_demonstration"].as_array().unwrap() {
            let cells = &lines[i];
            assert_eq!(cells[1], r["method"].as_str().unwrap());
            assert_eq!(cells[2], d["name"].as_str().unwrap());
            assert_eq!(cells[3], d["frames"].to_string());
            assert_eq!(cells[4], d["seeds"].to_string());
            assert_eq!(cells[4], "3");
            let keys = [
                "mse_mean",
                "mse_std",
                "coverage_mean",
                "coverage_std",
                "nlpd_mean",
            ];
            for (cell, key) in cells[5..].iter().zip(keys) {
                assert_eq!(*cell, d[key].as_f64().unwrap().to_string(), "{key}");
            }
            // The Markdown line shows the same numbers, rounded as printed.
            let line = format!(
                "| data | {} | {} | {} | {} |",
                cells[1], cells[2], cells[3], cells[4]
            );
            let md_line = md.lines().find(|l| l.starts_with(&line)).expect(&line);
            let f = |key: &str| d[key].as_f64().unwrap();
            let expected = format!(
                "{line} {} | {:.1} ± {:.1} | {:.3} |",
                mean_pm(f("mse_mean"), f("mse_std"), true),
                100.0 * f("coverage_mean"),
                100.0 * f("coverage_std"),
                f("nlpd_mean")
            );
            assert_eq!(md_line, expected);
            i += 1;
        }
    }
    assert_eq!(i, lines.len());
    // The rows read back.
    for r in json["results"].as_array().unwrap() {
        let row: Row = serde_json::from_value(r.clone()).unwrap();
        if r["baseline"] == false {
            assert_eq!(row.by_test_demonstration.len(), 2);
            assert_eq!(row.training_subsets, distinct_subsets(3, 6, 4));
        }
    }
}

#[test]
fn a_method_that_fails_on_every_seed_scores_no_test_demonstration() {
    // λ_T with more states than any transition segment has frames: every seed
    // fails; its lines say so (no frame, no seed) rather than look like zeros.
    let (_dir, data) = interaction_folder(8, 3, 6, plain);
    let rows = evaluate(&data, &["tsc-hmm:tsc-states=40,window=0"], 2);
    assert_eq!(rows[0].seeds, 0, "{:?}", rows[0].failures);
    assert_eq!(rows[0].by_test_demonstration.len(), 2);
    for d in &rows[0].by_test_demonstration {
        assert_eq!((d.frames, d.seeds), (0, 0));
        assert!(d.mse_mean.is_nan() && d.coverage_mean.is_nan() && d.nlpd_mean.is_nan());
    }
}
