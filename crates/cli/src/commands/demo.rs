//! `phasekit demo`: the whole pipeline on generated interactions.

use super::fit::fit_tables;
use crate::bail;
use crate::cli::DemoArgs;
use crate::data::{read_table, FeatureSpec, Table, Velocity};
use crate::error::Result;
use crate::model_file::ModelFile;
use crate::output;
use crate::pipeline::{joint_features_raw, predict_table, predictor, segment_table};
use crate::plot::{default_plane, prediction_svg, segmentation_svg, states_svg};
use phasekit_tsc::synthetic::{self, Interaction};
use phasekit_tsc::PresetOptions;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// The TSC-HMM of the demo: the generated interactions are smooth, so the
/// human-only and joint filters disagree on isolated frames; a dilation of ±2
/// frames makes runs long enough to train the transition HMM on.
pub const DEMO_TSC: &str = "tsc-hmm:window=2";

/// Writes generated interactions as CSV files `{prefix}_NN.csv` in `dir`.
pub fn write_interactions(
    dir: &Path,
    prefix: &str,
    demos: &[Interaction],
) -> Result<Vec<std::path::PathBuf>> {
    let mut paths = Vec::new();
    for (i, demo) in demos.iter().enumerate() {
        let path = dir.join(format!("{prefix}_{i:02}.csv"));
        let mut s = synthetic::COLUMNS.join(",");
        s.push('\n');
        for f in demo.frames.chunks_exact(synthetic::COLUMNS.len()) {
            let line: Vec<String> = f.iter().map(|v| v.to_string()).collect();
            s.push_str(&line.join(","));
            s.push('\n');
        }
        output::write_string(&path, &s)?;
        paths.push(path);
    }
    Ok(paths)
}

/// Results of one method on the test demonstrations.
struct Scores {
    mse: f64,
    boundary_to_transition: Option<f64>,
    boundary_to_state_change: Option<f64>,
    transitions: usize,
}

fn nearest(frames: &[usize], b: usize) -> Option<f64> {
    frames
        .iter()
        .map(|&t| (t as f64 - b as f64).abs())
        .min_by(f64::total_cmp)
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn score(mf: &ModelFile, tests: &[Table], truth: &[Interaction]) -> Result<Scores> {
    let p = predictor(mf)?;
    let d = mf.layout.features.len();
    let l = &mf.layout;
    let (mut se, mut frames) = (0.0, 0usize);
    let (mut to_transition, mut to_change) = (Vec::new(), Vec::new());
    let mut transitions = 0;
    for (t, inter) in tests.iter().zip(truth) {
        let pred = predict_table(mf, &p, t, false)?;
        let joint = joint_features_raw(mf, t)?;
        for (k, f) in joint.chunks_exact(d).enumerate() {
            for &j in &l.robot_positions {
                se += ((pred.mean[k * pred.n_out + j] - f[l.robot[j]]) * 100.0).powi(2);
            }
            frames += 1;
        }
        let seg = segment_table(mf, t)?;
        transitions += seg.transitions.len();
        let changes: Vec<usize> = (1..seg.labels.len())
            .filter(|&k| seg.labels[k] != seg.labels[k - 1])
            .collect();
        for &b in &inter.boundaries {
            to_transition.extend(nearest(&seg.transitions, b));
            to_change.extend(nearest(&changes, b));
        }
    }
    Ok(Scores {
        mse: se / frames as f64,
        boundary_to_transition: mean(&to_transition),
        boundary_to_state_change: mean(&to_change),
        transitions,
    })
}

/// What an HMM learned, one row per state: the mean positions of both hands
/// (cm), the expected stay `1 / (1 − a_ii)` (frames) and the true phase of
/// most test frames Viterbi assigns to the state.
fn learned_table(mf: &ModelFile, tests: &[Table], truth: &[Interaction]) -> Result<String> {
    let phasekit_tsc::Model::Hmm(h) = &mf.model else {
        return Ok(String::new());
    };
    const PHASES: [&str; 5] = ["idle", "reach", "shake", "retract", "rest"];
    let s = h.n_states();
    let l = &mf.layout;
    let mut votes = vec![[0usize; 5]; s];
    for (t, inter) in tests.iter().zip(truth) {
        let seg = segment_table(mf, t)?;
        for (&z, &p) in seg.labels.iter().zip(&inter.phases) {
            votes[z][p] += 1;
        }
    }
    let cm = |dims: &[usize], i: usize| {
        dims.iter()
            // `+ 0.0` turns a rounded −0 into 0.
            .map(|&k| format!("{:.0}", (100.0 * h.emission().mean(i)[k]).round() + 0.0))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let human: Vec<usize> = l.human[..l.human_columns.len()].to_vec();
    let robot: Vec<usize> = l.robot_positions.iter().map(|&j| l.robot[j]).collect();
    let mut out = String::from(
        "| state | human hand x, y, z (cm) | robot hand x, y, z (cm) | expected stay (frames) | true phases of its test frames |\n|---:|---|---|---:|---|\n",
    );
    for i in 0..s {
        let stay = 1.0 / (1.0 - h.transition()[i * s + i]).max(1e-12);
        let total: usize = votes[i].iter().sum();
        // Every phase with at least a fifth of the state's frames, largest first.
        let mut shares: Vec<(usize, usize)> = votes[i]
            .iter()
            .copied()
            .enumerate()
            .filter(|(_, n)| total > 0 && 5 * n >= total)
            .collect();
        shares.sort_by_key(|(p, n)| (std::cmp::Reverse(*n), *p));
        let phase = if shares.is_empty() {
            "–".to_string()
        } else {
            shares
                .iter()
                .map(|(p, n)| format!("{} {:.0} %", PHASES[*p], 100.0 * *n as f64 / total as f64))
                .collect::<Vec<_>>()
                .join(", ")
        };
        out += &format!(
            "| {i} | {} | {} | {stay:.0} | {phase} |\n",
            cm(&human, i),
            cm(&robot, i)
        );
    }
    Ok(out)
}

fn constant_mse(train: &[Table], test: &[Table]) -> f64 {
    let pos = |t: &Table| -> Vec<[f64; 3]> {
        t.data.chunks_exact(6).map(|r| [r[3], r[4], r[5]]).collect()
    };
    let all: Vec<[f64; 3]> = train.iter().flat_map(pos).collect();
    let m: Vec<f64> = (0..3)
        .map(|k| all.iter().map(|p| p[k]).sum::<f64>() / all.len() as f64)
        .collect();
    let errs: Vec<f64> = test
        .iter()
        .flat_map(pos)
        .map(|p| (0..3).map(|k| ((p[k] - m[k]) * 100.0).powi(2)).sum())
        .collect();
    errs.iter().sum::<f64>() / errs.len() as f64
}

/// Runs `phasekit demo`.
pub fn run(a: &DemoArgs) -> Result<()> {
    if a.train < 2 || a.test < 1 {
        bail!("the demo needs at least 2 training and 1 test demonstrations");
    }
    let clock = Instant::now();
    let dir = &a.output;
    let data_dir = dir.join("data");
    output::create_dir(&data_dir)?;
    let demos = synthetic::generate(a.train + a.test, a.seed);
    let (train_demos, test_demos) = demos.split_at(a.train);
    let train_files = write_interactions(&data_dir, "train", train_demos)?;
    let test_files = write_interactions(&data_dir, "test", test_demos)?;
    let read = |files: &[std::path::PathBuf]| {
        files
            .iter()
            .map(|f| read_table(f))
            .collect::<crate::data::Result<Vec<_>>>()
    };
    let train = read(&train_files)?;
    let test = read(&test_files)?;
    let spec = FeatureSpec {
        human: vec!["p1_wrist_*".into()],
        robot: vec!["p2_wrist_*".into()],
        velocity: Velocity::Both,
    };
    let options = PresetOptions::builder().seed(a.seed).build()?;
    let mut out = String::new();
    let frames: usize = train.iter().map(Table::n_rows).sum();
    let _ = writeln!(
        out,
        "phasekit demo: {} generated handshake-like interactions (idle → reach → shake → retract → rest; human hand p1_wrist_xyz,\nrobot hand p2_wrist_xyz, metres); {} to train ({frames} frames), {} to test; seed {}.\n",
        a.train + a.test,
        a.train,
        a.test,
        a.seed
    );
    let _ = writeln!(
        out,
        "Settings: the paper-compatible defaults of `phasekit fit` (4 base states, 3 transition states, reg 1e-2, ≤ 40 EM\niterations), features p1/p2_wrist_xyz and their velocities; TSC-HMM with transition frames dilated by ±2 frames.\n"
    );
    let mut rows = Vec::new();
    let mut models = Vec::new();
    for (method, file) in [("hmm", "hmm"), (DEMO_TSC, "tsc-hmm")] {
        let mf = fit_tables(&train, &spec, false, method, &options, false)?;
        let path = dir.join(format!("{file}.json"));
        mf.save(&path)?;
        let s = score(&mf, &test, test_demos)?;
        rows.push((method, mf.n_states(), mf.fit.fit_seconds, s));
        models.push((mf, path));
    }
    let base = constant_mse(&train, &test);
    let opt = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.1}"));
    let _ = writeln!(out, "| method | states | MSE (cm²) | RMSE (cm) | fit (s) | transition frames | boundary → nearest transition (frames) | boundary → nearest state change (frames) |");
    let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|---:|---:|");
    let _ = writeln!(
        out,
        "| constant mean pose | – | {base:.2} | {:.2} | – | – | – | – |",
        base.sqrt()
    );
    for (m, states, secs, s) in &rows {
        let _ = writeln!(
            out,
            "| {m} | {states} | {:.2} | {:.2} | {secs:.2} | {} | {} | {} |",
            s.mse,
            s.mse.sqrt(),
            s.transitions,
            opt(s.boundary_to_transition),
            opt(s.boundary_to_state_change)
        );
    }
    let _ = writeln!(
        out,
        "\nMSE: squared error of the robot's hand position per frame, mean over the {} test demonstrations' frames, predicted\ncausally from the human's hand alone. Boundaries: the 4 true phase changes of each test demonstration; distance in\nframes to the nearest transition frame found (TSC) and to the nearest change of Viterbi state.",
        a.test
    );
    let _ = writeln!(
        out,
        "\nWhat the 4-state HMM learned (state means of both hands; expected stay 1/(1 − a_ii); the true phases of the test\nframes its Viterbi path gives to the state, those with at least 20 %):\n\n{}",
        learned_table(&models[0].0, &test, test_demos)?
    );
    // Plots with the TSC-HMM.
    let (mf, model_path) = &models[1];
    let seg_svg = dir.join("segmentation.svg");
    let pred_svg = dir.join("prediction.svg");
    let states_path = dir.join("states.svg");
    output::write_string(&seg_svg, &segmentation_svg(mf, &test[0])?)?;
    output::write_string(&pred_svg, &prediction_svg(mf, &test[0])?)?;
    output::write_string(&states_path, &states_svg(mf, &train, default_plane(mf))?)?;
    let d = dir.display();
    let m = model_path.display();
    let _ = writeln!(
        out,
        "\nWrote to {d}/: data/ (train_*.csv, test_*.csv), hmm.json and tsc-hmm.json (model files), segmentation.svg,\nprediction.svg and states.svg (tsc-hmm on test_00 and the training data). Done in {:.1} s.\n",
        clock.elapsed().as_secs_f64()
    );
    let _ = writeln!(
        out,
        "Next:\n  phasekit segment --model {m} --data {d}/data/test_00.csv\n  phasekit predict  --model {m} --data {d}/data/test_00.csv --covariance\n  \
         cut -d, -f1-3 {d}/data/test_00.csv | phasekit stream --model {m}\n  phasekit fit --data {d}/data --method hmm:states=7 -o {d}/hmm7.json\n  \
         phasekit evaluate --data {d}/data --methods hmm,hmm:states=7,{DEMO_TSC} --seeds 10\n  \
         phasekit evaluate --data YOUR_DATA   # folders of train_*/test_* CSVs; see phasekit evaluate --help"
    );
    output::print_stdout(&out)
}
