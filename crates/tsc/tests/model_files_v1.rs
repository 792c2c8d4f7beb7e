//! Model files of version 1, written by `phasekit fit` before the settings
//! became validated builders (commit 672501d; `fixtures/model_files_v1/generate.sh`),
//! still load: for every preset kind, the fitted model, the method's settings,
//! the roles and the fit summary are read, serialised back to the same JSON
//! (the same field names and values), and predict and segment a test
//! demonstration exactly as the binary that wrote them did.

use phasekit_emission::Frames;
use phasekit_tsc::{FitSummary, Method, Model, Roles};
use serde_json::Value;
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/model_files_v1")
        .join(name)
}

/// The rows of a CSV file after its header, split at commas.
fn rows(name: &str) -> Vec<Vec<String>> {
    std::fs::read_to_string(fixture(name))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

fn numbers(row: &[String]) -> Vec<f64> {
    row.iter().map(|v| v.parse().unwrap()).collect()
}

const FILES: [&str; 9] = [
    "hmm",
    "hmm-auto",
    "tsc-hmm",
    "tsc-hmm-gated",
    "tsc-hmm-frozen",
    "gmm",
    "gmm-tsc",
    "gmm-tsc-auto",
    "hmm-cv",
];

#[test]
fn version_1_model_files_load_round_trip_and_predict_as_written() {
    // test_00.csv: p1_wrist_x, y, z (the human), p2_wrist_x, y, z (the robot).
    let test: Vec<f64> = rows("test_00.csv")
        .iter()
        .flat_map(|r| numbers(r))
        .collect();
    let seq = Frames::new(&test, 6).unwrap();
    let human: Vec<f64> = test.chunks_exact(6).flat_map(|f| f[..3].to_vec()).collect();
    let human = Frames::new(&human, 3).unwrap();
    for name in FILES {
        let text = std::fs::read_to_string(fixture(&format!("{name}.json"))).unwrap();
        let file: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(file["version"], 1, "{name}");

        let model: Model = serde_json::from_value(file["model"].clone())
            .unwrap_or_else(|e| panic!("{name}: model: {e}"));
        let method: Method = serde_json::from_value(file["method"]["settings"].clone())
            .unwrap_or_else(|e| panic!("{name}: settings: {e}"));
        let roles: Roles = serde_json::from_value(file["roles"].clone()).unwrap();
        let fit: FitSummary = serde_json::from_value(file["fit"].clone()).unwrap();
        assert_eq!(roles, Roles::new(vec![0, 1, 2], vec![3, 4, 5]).unwrap());

        // Written back, every part is the JSON it was read from.
        assert_eq!(
            serde_json::to_value(&model).unwrap(),
            file["model"],
            "{name}: model"
        );
        assert_eq!(
            serde_json::to_value(&method).unwrap(),
            file["method"]["settings"],
            "{name}: settings"
        );
        assert_eq!(
            serde_json::to_value(&roles).unwrap(),
            file["roles"],
            "{name}: roles"
        );
        // The fit summary too, except that version 1's `converged` and
        // `stopped_on_decrease` are written back as the one `stop` they mean.
        let mut fit_v1 = file["fit"].clone();
        let obj = fit_v1.as_object_mut().unwrap();
        let converged = obj.remove("converged").unwrap().as_bool().unwrap();
        let fell = obj
            .remove("stopped_on_decrease")
            .is_some_and(|v| v.as_bool().unwrap());
        let stop = match (converged, fell) {
            (false, _) => "max-iter",
            (true, true) => "log-likelihood fell",
            (true, false) => "converged",
        };
        obj.insert("stop".into(), stop.into());
        assert_eq!(serde_json::to_value(&fit).unwrap(), fit_v1, "{name}: fit");

        // The same predictions, bit for bit.
        let predicted = model
            .predictor(&roles)
            .unwrap()
            .predict(human, false)
            .unwrap();
        let written = rows(&format!("{name}.predicted.csv"));
        assert_eq!(written.len(), human.len(), "{name}");
        for (t, row) in written.iter().enumerate() {
            let want = numbers(&row[1..]);
            assert_eq!(
                predicted.mean[t * 3..(t + 1) * 3],
                want[..],
                "{name}: frame {t}"
            );
        }

        // The same segmentation: the written states are λ's for a TSC-HMM
        // (now `base_labels`, the labels being the predicting union's).
        let seg = model.segment(seq, &roles).unwrap();
        let states = seg.base_labels.as_ref().unwrap_or(&seg.labels);
        let mut transitions = Vec::new();
        let mut clusters = Vec::new();
        for (t, row) in rows(&format!("{name}.segment.csv")).iter().enumerate() {
            assert_eq!(row[1].parse::<usize>().unwrap(), t);
            assert_eq!(
                states[t],
                row[2].parse::<usize>().unwrap(),
                "{name}: frame {t}"
            );
            if row[3] == "1" {
                transitions.push(t);
                clusters.push(row[4].parse::<usize>().ok());
            }
        }
        assert_eq!(seg.transitions, transitions, "{name}");
        assert_eq!(seg.clusters, clusters, "{name}");
    }
}
