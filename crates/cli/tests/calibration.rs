//! The calibration columns of `phasekit evaluate` (issue "Better than the
//! paper"): coverage of the predicted 95 % region and the negative log
//! predictive density, in every format, with the same numbers, and in the
//! units asked for. (The formulas are tested against hand-computed cases and
//! Monte Carlo in `phasekit-gmr`'s `calibration` tests.)

use crate::common;

use common::{interaction_folder, phasekit, plain};
use std::path::Path;

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

/// Column `name` of every line of an evaluate CSV.
fn column(csv: &str, name: &str) -> Vec<String> {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let c = header
        .iter()
        .position(|h| *h == name)
        .unwrap_or_else(|| panic!("no column {name} in {header:?}"));
    lines
        .map(|l| l.split(',').nth(c).unwrap().to_string())
        .collect()
}

#[test]
fn evaluate_reports_coverage_and_nlpd_in_every_format() {
    let (_dir, data) = interaction_folder(8, 3, 6, plain);
    let args = ["evaluate", "--methods", "hmm,gmm", "--seeds", "3"];
    let csv = stdout_of(&[&args[..], &["--format", "csv"]].concat(), &data);
    let methods = column(&csv, "method");
    let coverage = column(&csv, "coverage95_mean");
    let nlpd = column(&csv, "nlpd_mean");
    assert_eq!(methods, ["hmm", "gmm", "constant-mean"], "{csv}");
    for i in 0..2 {
        let c: f64 = coverage[i].parse().unwrap();
        assert!((0.0..=1.0).contains(&c) && c > 0.0, "{csv}");
        assert!(nlpd[i].parse::<f64>().unwrap().is_finite(), "{csv}");
        assert!(column(&csv, "coverage95_std")[i].parse::<f64>().unwrap() >= 0.0);
        assert!(column(&csv, "fit_seconds_std")[i].parse::<f64>().unwrap() >= 0.0);
    }
    // The constant-mean baseline has no uncertainty: empty, not 0.
    assert_eq!(coverage[2], "");
    assert_eq!(nlpd[2], "");
    assert_eq!(column(&csv, "nlpd_unit")[0], "cm");
    // JSON: the same numbers (null for the baseline).
    let json = stdout_of(&[&args[..], &["--format", "json"]].concat(), &data);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    for i in 0..2 {
        let r = &v["results"][i];
        assert_eq!(
            r["coverage_mean"].as_f64().unwrap().to_string(),
            coverage[i]
        );
        assert_eq!(r["nlpd_mean"].as_f64().unwrap().to_string(), nlpd[i]);
    }
    assert!(v["results"][2]["coverage_mean"].is_null());
    assert!(v["metric"].as_str().unwrap().contains("χ²"));
    // Markdown: the columns with their units, mean ± sd over seeds, in %.
    let md = stdout_of(&args, &data);
    assert!(
        md.contains("| coverage 95 % (%) | NLPD (nats) | fit (s) |"),
        "{md}"
    );
    let row: Vec<&str> = md
        .lines()
        .find(|l| l.split('|').nth(2).map(str::trim) == Some("hmm"))
        .unwrap()
        .split('|')
        .map(str::trim)
        .collect();
    let shown: f64 = row[8].split(" ± ").next().unwrap().parse().unwrap();
    let c: f64 = coverage[0].parse().unwrap();
    assert!((shown - 100.0 * c).abs() <= 0.051, "{} vs {c}", row[8]);
    assert!(row[10].contains(" ± "), "{}", row[10]);
}

#[test]
fn nlpd_moves_with_the_unit_by_the_jacobian_and_coverage_does_not() {
    // The same fits reported in metres (scale 1) and in cm (scale 100): the
    // density per cm³ is the density per m³ / 100³, so the NLPD grows by
    // 3 ln 100 (three position columns); the ellipsoid test does not depend on units.
    let (_dir, data) = interaction_folder(8, 3, 6, plain);
    let args = [
        "evaluate",
        "--methods",
        "hmm",
        "--seeds",
        "2",
        "--format",
        "csv",
    ];
    let cm = stdout_of(&args, &data);
    let m = stdout_of(&[&args[..], &["--unit", "m"]].concat(), &data);
    let nlpd = |csv: &str| column(csv, "nlpd_mean")[0].parse::<f64>().unwrap();
    let shift = nlpd(&cm) - nlpd(&m);
    assert!((shift - 3.0 * 100f64.ln()).abs() < 1e-9, "{shift}");
    assert_eq!(
        column(&cm, "coverage95_mean")[0],
        column(&m, "coverage95_mean")[0]
    );
}
