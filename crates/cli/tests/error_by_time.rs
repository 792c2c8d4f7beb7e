//! The error against normalised time of `phasekit evaluate` (issue 17): the
//! binning of frames by `τ = t / (T − 1)`, the per-seed decomposition of the MSE
//! into bins, and the files `-o` writes (CSV, JSON, one SVG per action).

use crate::common;

use common::{evaluate_rows, interaction_folder, methods, phasekit, plain, wrist_spec};
use phasekit_cli::data::load_action;
use phasekit_cli::experiment::{evaluate_action, percentile, time_bin, Protocol, Row};
use std::path::Path;

fn evaluate(data: &Path, labels: &[&str], seeds: usize, bins: usize) -> Vec<Row> {
    let protocol = Protocol {
        seeds,
        time_bins: bins,
        ..Protocol::default()
    };
    evaluate_rows(data, labels, &protocol)
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs())
}

/// The bin by its definition: the `i` with `i/B ≤ τ < (i+1)/B` (the last bin
/// closed), tested in exact rationals (`τ = t / (T − 1)`).
fn bin_by_definition(t: usize, frames: usize, bins: usize) -> usize {
    if frames == 1 {
        return 0;
    }
    let (num, den) = (t as u128 * bins as u128, frames as u128 - 1);
    (0..bins)
        .find(|&i| {
            let lo = i as u128 * den <= num;
            let hi = num < (i as u128 + 1) * den || i == bins - 1;
            lo && hi
        })
        .unwrap()
}

#[test]
fn frames_fall_in_the_bins_of_their_normalised_time() {
    // T = 1: τ = 0, the first bin, whatever B.
    for b in [1, 2, 20] {
        assert_eq!(time_bin(0, 1, b), 0);
    }
    // τ = 1 (the last frame) is in the last bin, which is closed.
    for (frames, b) in [(2, 1), (2, 20), (21, 20), (100, 7), (5, 20)] {
        assert_eq!(
            time_bin(frames - 1, frames, b),
            b - 1,
            "T = {frames}, B = {b}"
        );
    }
    // B = 1: every frame in the one bin.
    assert!((0..57).all(|t| time_bin(t, 57, 1) == 0));
    // Frames on the edges: T = 21, B = 20 puts frame t (τ = t/20) in bin t, the
    // last two frames both in bin 19; 3 × 0.1 is not 0.3 in floating point, but
    // frame 6 of T = 21 at B = 10 (τ = 0.3 exactly) is in bin 3.
    assert!((0..20).all(|t| time_bin(t, 21, 20) == t));
    assert_eq!(time_bin(20, 21, 20), 19);
    assert_eq!(time_bin(6, 21, 10), 3);
    // Against the definition, every frame of many lengths and bin counts.
    for frames in 1..60 {
        for b in [1, 2, 3, 7, 20, 64, 100] {
            for t in 0..frames {
                assert_eq!(
                    time_bin(t, frames, b),
                    bin_by_definition(t, frames, b),
                    "t = {t}, T = {frames}, B = {b}"
                );
            }
        }
    }
}

#[test]
fn percentiles_interpolate_between_order_statistics() {
    // NumPy: np.percentile([4, 1, 3, 2], [5, 95]) = [1.15, 3.85].
    let v = [4.0, 1.0, 3.0, 2.0];
    assert!((percentile(&v, 0.05) - 1.15).abs() < 1e-12);
    assert!((percentile(&v, 0.95) - 3.85).abs() < 1e-12);
    assert_eq!(percentile(&v, 0.0), 1.0);
    assert_eq!(percentile(&v, 1.0), 4.0);
    assert_eq!(percentile(&[2.5], 0.05), 2.5);
    assert!(percentile(&[], 0.5).is_nan());
}

#[test]
fn the_bins_of_every_seed_decompose_its_mse() {
    // Some robot positions unobserved (every 7th frame's x): those frames are not
    // scored, in the MSE nor in any bin.
    let (_dir, data) = interaction_folder(8, 3, 6, |t, k, v| {
        if k == 3 && t % 7 == 3 {
            String::new()
        } else {
            v.to_string()
        }
    });
    let action = load_action(&data).unwrap();
    let scored: usize = action
        .test
        .iter()
        .map(|t| t.n_rows() - (t.n_rows() + 3) / 7)
        .sum();
    let rows = evaluate(&data, &["hmm", "gmm"], 3, 7);
    for row in &rows {
        assert_eq!(row.per_seed_time_bins.len(), 3);
        assert_eq!(row.error_by_time.len(), 7);
        for (s, bins) in row.per_seed_time_bins.iter().enumerate() {
            let bins = bins.as_ref().expect("every seed fits");
            let mse = row.per_seed_mse[s].unwrap();
            let frames: usize = bins.frames.iter().sum();
            assert_eq!(frames, scored, "{} seed {s}", row.method);
            // The frame-weighted mean of the bins' MSE is the seed's MSE.
            let weighted = (0..bins.len())
                .filter(|&b| bins.frames[b] > 0)
                .map(|b| bins.frames[b] as f64 * bins.mse(b))
                .sum::<f64>()
                / frames as f64;
            assert!(
                close(weighted, mse, 1e-12),
                "{} seed {s}: {weighted} vs {mse}",
                row.method
            );
            assert!(bins.frames.iter().all(|&n| n > 0), "{:?}", bins.frames);
        }
        // The summary over seeds: mean, percentiles and frames of the seeds' bins.
        for (b, sum) in row.error_by_time.iter().enumerate() {
            let v: Vec<f64> = row
                .per_seed_time_bins
                .iter()
                .map(|x| x.as_ref().unwrap().mse(b))
                .collect();
            assert_eq!(sum.bin, b);
            assert_eq!(sum.time_from, b as f64 / 7.0);
            assert_eq!(sum.time_to, (b + 1) as f64 / 7.0);
            assert!(close(sum.mse_mean, v.iter().sum::<f64>() / 3.0, 1e-12));
            let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            assert!(lo <= sum.mse_p05 && sum.mse_p05 <= sum.mse_p95 && sum.mse_p95 <= hi);
            assert_eq!(sum.mse_p05, percentile(&v, 0.05));
            assert_eq!(sum.mse_p95, percentile(&v, 0.95));
            assert_eq!(
                sum.frames,
                3 * row.per_seed_time_bins[0].as_ref().unwrap().frames[b]
            );
        }
        // Coverage decomposes too (the same frames every seed): the frame-weighted
        // mean over bins of the mean coverage is the table's mean coverage.
        let total: usize = row.error_by_time.iter().map(|b| b.frames).sum();
        let coverage = row
            .error_by_time
            .iter()
            .map(|b| b.frames as f64 * b.coverage_mean)
            .sum::<f64>()
            / total as f64;
        assert!(row.coverage_mean.is_finite());
        assert!(
            close(coverage, row.coverage_mean, 1e-12),
            "{coverage} vs {}",
            row.coverage_mean
        );
    }
}

#[test]
fn one_bin_is_the_table() {
    let (_dir, data) = interaction_folder(8, 3, 6, plain);
    for row in evaluate(&data, &["hmm"], 3, 1) {
        let [bin] = &row.error_by_time[..] else {
            panic!("one bin: {:?}", row.error_by_time)
        };
        assert_eq!((bin.time_from, bin.time_to), (0.0, 1.0));
        assert!(close(bin.mse_mean, row.mse_mean, 1e-12), "{bin:?} {row:?}");
        assert!(close(bin.mse_sd, row.mse_std, 1e-9), "{bin:?} {row:?}");
        assert!(close(bin.coverage_mean, row.coverage_mean, 1e-12));
    }
}

#[test]
fn zero_time_bins_is_an_error() {
    let (_dir, data) = interaction_folder(8, 3, 6, plain);
    let action = load_action(&data).unwrap();
    let protocol = Protocol {
        seeds: 1,
        time_bins: 0,
        ..Protocol::default()
    };
    let e = evaluate_action(
        &action,
        &wrist_spec(),
        &methods(&["hmm"]),
        &protocol,
        &|| {},
    )
    .err()
    .unwrap();
    assert!(e.contains("time bins"), "{e}");
    let out = phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm",
            "--seeds",
            "1",
            "--time-bins",
            "0",
        ])
        .arg("--data")
        .arg(&data)
        .assert()
        .failure()
        .get_output()
        .stderr
        .clone();
    let err = String::from_utf8(out).unwrap();
    assert!(err.contains("--time-bins"), "{err}");
}

/// The text elements of an SVG, trimmed.
fn svg_texts(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|s| {
            let body = &s[s.find('>')? + 1..];
            Some(body[..body.find("</text>")?].trim().to_string())
        })
        .collect()
}

/// The cells of a CSV line (no quoted fields in these files).
fn cells(line: &str) -> Vec<&str> {
    line.split(',').collect()
}

#[test]
fn evaluate_writes_the_error_over_time_as_csv_json_and_svg() {
    let (dir, data) = interaction_folder(8, 3, 6, plain);
    let prefix = dir.path().join("run");
    let md = phasekit()
        .args([
            "evaluate",
            "--methods",
            "hmm,gmm",
            "--seeds",
            "2",
            "--time-bins",
            "5",
        ])
        .arg("--data")
        .arg(&data)
        .arg("-o")
        .arg(&prefix)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let md = String::from_utf8(md).unwrap();
    let csv_path = dir.path().join("run_error_by_time.csv");
    let svg_path = dir.path().join("run_error_by_time_data.svg");
    // One line of the Markdown names the files (not a table).
    let line: Vec<&str> = md.lines().filter(|l| l.contains("error_by_time")).collect();
    assert_eq!(line.len(), 1, "{md}");
    assert!(
        line[0].contains("run_error_by_time.csv") && line[0].contains("run_error_by_time_data.svg"),
        "{md}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.path().join("run.md")).unwrap(),
        md
    );

    let csv = std::fs::read_to_string(&csv_path).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next().unwrap(),
        "action,method,bin,time_from,time_to,frames,mse_mean_cm2,mse_sd_cm2,mse_p05_cm2,mse_p95_cm2,coverage_mean"
    );
    let rows: Vec<Vec<&str>> = lines.map(cells).collect();
    assert_eq!(rows.len(), 2 * 5, "{csv}");

    // The JSON: the same rows, the same numbers.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("run.json")).unwrap())
            .unwrap();
    let arr = json["error_by_time"].as_array().unwrap();
    assert_eq!(arr.len(), rows.len());
    let keys = [
        "action",
        "method",
        "bin",
        "time_from",
        "time_to",
        "frames",
        "mse_mean",
        "mse_sd",
        "mse_p05",
        "mse_p95",
        "coverage_mean",
    ];
    for (r, j) in rows.iter().zip(arr) {
        for (cell, key) in r.iter().zip(keys) {
            let v = &j[key];
            let text = match v {
                serde_json::Value::String(s) => s.clone(),
                serde_json::Value::Number(n) if n.is_u64() => n.to_string(),
                serde_json::Value::Number(n) => n.as_f64().unwrap().to_string(),
                other => panic!("{key}: {other}"),
            };
            assert_eq!(*cell, text, "{key} in {r:?}");
        }
    }
    // Per method, the frame-weighted mean of the bins' mean MSE is the table's MSE
    // (every seed scores the same frames, so the decomposition survives the mean).
    for (i, method) in ["hmm", "gmm"].iter().enumerate() {
        let mine: Vec<&Vec<&str>> = rows.iter().filter(|r| r[1] == *method).collect();
        assert_eq!(mine.len(), 5);
        let frames: f64 = mine.iter().map(|r| r[5].parse::<f64>().unwrap()).sum();
        let weighted = mine
            .iter()
            .map(|r| r[5].parse::<f64>().unwrap() * r[6].parse::<f64>().unwrap())
            .sum::<f64>()
            / frames;
        let table = json["results"][i]["mse_mean"].as_f64().unwrap();
        assert_eq!(json["results"][i]["method"], *method);
        assert!(close(weighted, table, 1e-12), "{weighted} vs {table}");
        assert_eq!(mine[4][4], "1");
    }
    assert_eq!(json["protocol"]["time_bins"], 5, "{}", json["protocol"]);

    // The SVG: its unit, every method, the seeds.
    let texts = svg_texts(&std::fs::read_to_string(&svg_path).unwrap());
    assert!(
        texts.iter().any(|t| t == "MSE (cm²)"),
        "no unit on the axis: {texts:?}"
    );
    assert!(texts.iter().any(|t| t.starts_with("normalised time")));
    for m in ["hmm", "gmm"] {
        assert!(
            texts.iter().any(|t| t == m),
            "no legend entry {m}: {texts:?}"
        );
    }
    assert!(texts
        .iter()
        .any(|t| t.starts_with("data: MSE against normalised time, 2 seeds")));
}

#[test]
fn without_files_nothing_more_is_printed_and_units_name_the_columns() {
    let (dir, data) = interaction_folder(8, 3, 6, plain);
    let run = |extra: &[&str]| {
        let out = phasekit()
            .args(["evaluate", "--methods", "hmm", "--seeds", "1"])
            .args(extra)
            .arg("--data")
            .arg(&data)
            .assert()
            .success()
            .get_output()
            .stdout
            .clone();
        String::from_utf8(out).unwrap()
    };
    let md = run(&[]);
    assert!(
        !md.contains("error_by_time") && !md.contains("normalised time"),
        "{md}"
    );
    let json = run(&["--format", "json"]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert!(v.get("error_by_time").is_none());
    // Another unit names the CSV's columns.
    let prefix = dir.path().join("m");
    run(&["--unit", "m", "-o", prefix.to_str().unwrap()]);
    let csv = std::fs::read_to_string(dir.path().join("m_error_by_time.csv")).unwrap();
    assert!(
        csv.starts_with("action,method,bin,time_from,time_to,frames,mse_mean_m2,"),
        "{csv}"
    );
    let texts =
        svg_texts(&std::fs::read_to_string(dir.path().join("m_error_by_time_data.svg")).unwrap());
    assert!(texts.iter().any(|t| t == "MSE (m²)"), "{texts:?}");
    assert!(
        texts
            .iter()
            .any(|t| t.starts_with("data: MSE against normalised time, 1 seed (")),
        "the title says 1 seed: {texts:?}"
    );
}
