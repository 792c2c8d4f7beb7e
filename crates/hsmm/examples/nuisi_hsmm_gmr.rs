//! HSMM-GMR against HMM-GMR on the NuiSI demonstrations, in the paper's
//! setting (`../shared/PROTOCOL.md`): human = p1 wrist + velocity, robot =
//! p2 wrist + velocity, metres, `reg = 1e-2` added to every covariance, all
//! training demonstrations, the robot's hand predicted frame by frame from
//! the human's by the causal forward filter, squared error of the 3 position
//! coordinates in cm² averaged over the test frames.
//!
//! ```text
//! cargo run --release -p phasekit-hsmm --example nuisi_hsmm_gmr [-- DATA_DIR]
//! ```
//!
//! One deterministic run per action (no seeds): a first look at whether
//! durations help, not the evaluation (that is `phasekit evaluate`'s job).

use phasekit_emission::{CovarianceType, Frames, Gaussian, Regularisation, SequenceSet, Shape};
use phasekit_gmr::{HmmRegression, Regression};
use phasekit_hmm::{BaumWelch, Convergence, HmmInit};
use phasekit_hsmm::{
    suggested_max_duration, AnyDuration, Censoring, DurationRegularisation, GaussianDuration, Hsmm,
    HsmmEm, HsmmFilter, HsmmInit, NonParametricDuration, PoissonDuration, Structure,
};
use std::path::{Path, PathBuf};

const HUMAN: [usize; 6] = [0, 1, 2, 3, 4, 5];
const ROBOT_POS: [usize; 3] = [6, 7, 8];

/// `T × 12`: p1 wrist, its velocity, p2 wrist, its velocity.
fn read(path: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(path).expect("read csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect("column");
    let cols: Vec<usize> = [
        "p1_wrist_x",
        "p1_wrist_y",
        "p1_wrist_z",
        "p2_wrist_x",
        "p2_wrist_y",
        "p2_wrist_z",
    ]
    .iter()
    .map(|c| col(c))
    .collect();
    let rows: Vec<Vec<f64>> = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l
                .split(',')
                .map(|x| x.trim().parse().expect("number"))
                .collect();
            cols.iter().map(|&c| v[c]).collect()
        })
        .collect();
    let mut out = Vec::with_capacity(rows.len() * 12);
    for t in 0..rows.len() {
        let p = t.saturating_sub(1);
        for side in [0, 3] {
            out.extend_from_slice(&rows[t][side..side + 3]);
            out.extend((0..3).map(|k| rows[t][side + k] - rows[p][side + k]));
        }
    }
    out
}

fn files(dir: &Path, prefix: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("data folder")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(prefix) && n.ends_with(".csv"))
        })
        .collect();
    v.sort();
    v
}

/// Squared error (cm², summed over x, y, z) of predictions from per-frame weights.
fn squared_error(
    regression: &Regression,
    demo: &[f64],
    mut weights: impl FnMut(usize, &[f64]) -> Vec<f64>,
) -> (f64, usize) {
    let k = regression.n_states();
    let (mut mean, mut scratch) = (vec![0.0; 6], vec![0.0; k * 6]);
    let mut se = 0.0;
    let n = demo.len() / 12;
    for t in 0..n {
        let x = &demo[t * 12..t * 12 + 6];
        let h = weights(t, x);
        regression
            .mix_into(x, &h, &mut mean, None, &mut scratch)
            .unwrap();
        for (q, &c) in ROBOT_POS.iter().enumerate() {
            se += (1e2 * (mean[q] - demo[t * 12 + c])).powi(2);
        }
    }
    (se, n)
}

fn main() {
    let root = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/nuisi")
        });
    let reg = Regularisation::add_diagonal(1e-2).unwrap();
    println!("| action | states | HMM-GMR MSE (cm²) | HSMM-GMR non-parametric | HSMM-GMR Poisson | HSMM-GMR Gaussian | HSMM fit (s) |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for action in ["handshake", "parachute", "rocket", "waving"] {
        let dir = root.join(action);
        if !dir.is_dir() {
            eprintln!(
                "{}: not found (give the NuiSI folder as the first argument)",
                dir.display()
            );
            return;
        }
        let train: Vec<Vec<f64>> = files(&dir, "train_").iter().map(|p| read(p)).collect();
        let test: Vec<Vec<f64>> = files(&dir, "test_").iter().map(|p| read(p)).collect();
        let data = SequenceSet::new(&train, 12).unwrap();
        for s in [4, 7] {
            let template = Gaussian::standard(
                CovarianceType::Full,
                Shape {
                    n_states: s,
                    dim: 12,
                },
            )
            .unwrap();
            let hmm = BaumWelch::builder()
                .max_iter(40)
                .tol(1e-4)
                .convergence(Convergence::MeanPerSequence)
                .regularisation(reg)
                .init(HmmInit::KBins { smoothing: 0.01 })
                .build()
                .unwrap()
                .fit(&template, &data)
                .unwrap()
                .model;
            let hmm_gmr = HmmRegression::new(&hmm, &HUMAN, &[6, 7, 8, 9, 10, 11]).unwrap();
            let (mut se, mut n) = (0.0, 0);
            for demo in &test {
                let human: Vec<f64> = demo.chunks(12).flat_map(|f| f[..6].to_vec()).collect();
                let pred = hmm_gmr
                    .predict(Frames::new(&human, 6).unwrap(), false)
                    .unwrap();
                for t in 0..demo.len() / 12 {
                    for q in 0..3 {
                        se += (1e2 * (pred.mean[t * 6 + q] - demo[t * 12 + 6 + q])).powi(2);
                    }
                }
                n += demo.len() / 12;
            }
            let hmm_mse = se / n as f64;
            let dm = suggested_max_duration(&data, s);
            let mut cells = Vec::new();
            let mut seconds = 0.0;
            for family in 0..3 {
                let durations: AnyDuration = match family {
                    0 => NonParametricDuration::uniform(s, dm).unwrap().into(),
                    1 => PoissonDuration::template(s, dm).unwrap().into(),
                    _ => GaussianDuration::template(s, dm).unwrap().into(),
                };
                let fit = HsmmEm::builder()
                    .max_iter(40)
                    .tol(1e-4)
                    .convergence(Convergence::MeanPerSequence)
                    .regularisation(reg)
                    .duration_regularisation(
                        DurationRegularisation::none()
                            .with_pseudo_count(1e-2)
                            .unwrap(),
                    )
                    .init(HsmmInit::KBins { smoothing: 0.01 })
                    .structure(Structure::Ergodic)
                    .censoring(Censoring::RightCensored)
                    .build()
                    .unwrap()
                    .fit(&template, &durations, &data);
                let fit = match fit {
                    Ok(f) => f,
                    Err(e) => {
                        cells.push(format!("failed: {e}"));
                        continue;
                    }
                };
                seconds += fit.report.fit_seconds;
                let model: Hsmm<Gaussian> = fit.model;
                let regression =
                    Regression::new(model.emission(), &HUMAN, &[6, 7, 8, 9, 10, 11]).unwrap();
                let (mut se, mut n) = (0.0, 0);
                for demo in &test {
                    let mut filter = HsmmFilter::on_dims(&model, &HUMAN).unwrap();
                    let (e, k) =
                        squared_error(&regression, demo, |_, x| filter.step(x).unwrap().to_vec());
                    se += e;
                    n += k;
                }
                cells.push(format!("{:.2}", se / n as f64));
            }
            println!(
                "| {action} | {s} | {hmm_mse:.2} | {} | {:.2} |",
                cells.join(" | "),
                seconds / 3.0
            );
        }
    }
}
