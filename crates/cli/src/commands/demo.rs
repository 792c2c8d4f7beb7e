//! `phasekit demo`: the whole pipeline on generated interactions.

use super::fit::fit_tables;
use crate::bail;
use crate::cli::DemoArgs;
use crate::data::{read_table, Action, FeatureSpec, Table, Velocity};
use crate::error::{CliError, Result};
use crate::experiment::{evaluate_action, paired, parse_method, Protocol};
use crate::model_file::ModelFile;
use crate::output;
use crate::pipeline::{joint_features_raw, predict_table, predictor, segment_table};
use crate::plot::{default_plane, prediction_svg, segmentation_svg, states_svg};
use crate::units::{mean_pm, sig4, Unit};
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
    for (i, votes) in votes.iter().enumerate() {
        let stay = 1.0 / (1.0 - h.transition()[i * s + i]).max(1e-12);
        let total: usize = votes.iter().sum();
        // Every phase with at least a fifth of the state's frames, largest first.
        let mut shares: Vec<(usize, usize)> = votes
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

/// Most generated demonstrations of either kind: the demo is a showcase that runs in
/// seconds (about 140 frames each; 1000 fit in well under a minute and 100 MB).
pub const MAX_DEMONSTRATIONS: usize = 1000;

/// The methods the demo compares, and their model files: the 4-state HMM, the
/// TSC-HMM, and the 7-state HMM as the control with as many states as the
/// TSC-HMM (a gain of the TSC-HMM over the 4-state HMM alone could be its extra states).
pub const DEMO_METHODS: [(&str, &str); 3] = [
    ("hmm", "hmm"),
    ("hmm:states=7", "hmm7"),
    (DEMO_TSC, "tsc-hmm"),
];

/// Names the demo writes into its folder: only these may be replaced by a new run.
fn is_demo_output(name: &str) -> bool {
    DEMO_METHODS
        .iter()
        .any(|(_, f)| name == format!("{f}.json"))
        || ["data", "segmentation.svg", "prediction.svg", "states.svg"].contains(&name)
}

/// Whether `dir` can be replaced by a new demo: absent, empty, or an earlier demo's
/// output (its files and a `data/` folder of `train_*`/`test_*` files only).
fn check_replaceable(dir: &Path) -> Result<()> {
    let Ok(meta) = std::fs::symlink_metadata(dir) else {
        return Ok(());
    };
    let foreign = |what: String| {
        CliError::new(format!(
            "-o {}: {what}; the demo replaces only a folder it wrote itself: choose another folder",
            dir.display()
        ))
    };
    if !meta.is_dir() {
        return Err(foreign("exists and is not a folder".into()));
    }
    let names = |d: &Path| -> Result<Vec<(String, bool)>> {
        std::fs::read_dir(d)
            .map_err(|e| CliError::new(format!("{}: cannot read folder: {e}", d.display())))?
            .map(|e| {
                let e = e.map_err(|e| CliError::new(format!("{}: {e}", d.display())))?;
                let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
                Ok((e.file_name().to_string_lossy().into_owned(), is_dir))
            })
            .collect()
    };
    for (name, is_dir) in names(dir)? {
        if !is_demo_output(&name) || (name == "data") != is_dir {
            return Err(foreign(format!(
                "holds `{name}`, which the demo does not write"
            )));
        }
        if name == "data" {
            for (f, sub) in names(&dir.join("data"))? {
                let ours = !sub
                    && (f.starts_with("train_") || f.starts_with("test_"))
                    && f.ends_with(".csv");
                if !ours {
                    return Err(foreign(format!(
                        "holds `data/{f}`, which the demo does not write"
                    )));
                }
            }
        }
    }
    Ok(())
}

/// Puts the finished folder `tmp` at `dir`, replacing an earlier demo's folder
/// there (checked by [`check_replaceable`]): nothing half-written is ever at `dir`.
fn put_in_place(tmp: tempfile::TempDir, dir: &Path) -> Result<()> {
    let cannot = |e: std::io::Error| CliError::new(format!("{}: cannot write: {e}", dir.display()));
    if std::fs::symlink_metadata(dir).is_ok() {
        check_replaceable(dir)?;
        // Swap: the old folder moves aside, the new one in, then the old one goes.
        let parent = tmp.path().parent().unwrap_or(Path::new("."));
        let old = tempfile::Builder::new()
            .prefix(".phasekit-demo-old")
            .tempdir_in(parent)
            .map_err(cannot)?;
        let aside = old.path().join("old");
        std::fs::rename(dir, &aside).map_err(cannot)?;
        if let Err(e) = std::fs::rename(tmp.path(), dir) {
            // Put the old folder back; the new one is removed with `tmp`.
            let _ = std::fs::rename(&aside, dir);
            return Err(cannot(e));
        }
        drop(old);
    } else {
        std::fs::rename(tmp.path(), dir).map_err(cannot)?;
    }
    // The folder now lives at `dir`: nothing left for the guard to remove.
    let _ = tmp.keep();
    Ok(())
}

/// How to call this executable in a printed command: `phasekit` when that name on
/// the PATH is this executable, else its path (relative to the current folder when
/// inside it, as `target/release/phasekit` after `cargo run --release`).
pub fn command_name() -> String {
    let Ok(exe) = std::env::current_exe().and_then(|e| e.canonicalize()) else {
        return "phasekit".into();
    };
    let on_path = std::env::var_os("PATH").is_some_and(|p| {
        std::env::split_paths(&p).any(|d| d.join("phasekit").canonicalize().is_ok_and(|c| c == exe))
    });
    if on_path {
        return "phasekit".into();
    }
    let shown = std::env::current_dir()
        .ok()
        .and_then(|cwd| cwd.canonicalize().ok())
        .and_then(|cwd| exe.strip_prefix(&cwd).ok().map(Path::to_path_buf))
        .map(|rel| {
            if rel.components().count() > 1 {
                rel
            } else {
                Path::new(".").join(rel)
            }
        })
        .unwrap_or(exe);
    shell_word(&shown.to_string_lossy())
}

/// `s` quoted for a POSIX shell when it needs it.
pub fn shell_word(s: &str) -> String {
    let plain = !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+:,@%=".contains(c));
    if plain {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// The comparison over `seeds` random training subsets (all but two demonstrations
/// each, the protocol of `evaluate`): one fit can flatter a method, the spread over
/// subsets and the paired comparison with the 7-state control say how much.
fn over_seeds(
    train: &[Table],
    test: &[Table],
    spec: &FeatureSpec,
    options: &PresetOptions,
    seeds: usize,
) -> Result<String> {
    let action = Action {
        name: "demo".into(),
        train: train.to_vec(),
        test: test.to_vec(),
    };
    let methods = DEMO_METHODS
        .iter()
        .map(|(m, _)| parse_method(m, options).map_err(CliError::new))
        .collect::<Result<Vec<_>>>()?;
    let protocol = Protocol {
        seeds,
        ..Protocol::default()
    };
    let rows =
        evaluate_action(&action, spec, &methods, &protocol, &|| {}).map_err(CliError::new)?;
    let control = &rows[1];
    let mut out = format!(
        "\nOver {seeds} random training subsets (each all but two of the {} training demonstrations; the `evaluate` line below):\n\n\
         | method | states | MSE (cm²), mean ± std | Δ MSE vs {c} | seeds won against {c} |\n|---|---:|---:|---:|---:|\n",
        train.len(),
        c = control.method
    );
    for (i, r) in rows.iter().enumerate() {
        let (change, won) = match paired(r, control).filter(|_| i != 1) {
            Some((c, w, _)) => (
                format!("{:+.1} %", 100.0 * c),
                format!("{:.0} %", 100.0 * w),
            ),
            None => ("–".into(), "–".into()),
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {change} | {won} |",
            r.method,
            r.states,
            mean_pm(r.mse_mean, r.mse_std, r.seeds > 1)
        );
    }
    Ok(out)
}

/// Runs `phasekit demo`.
pub fn run(a: &DemoArgs) -> Result<()> {
    if a.train < 2 || a.test < 1 {
        bail!("the demo needs at least 2 training and 1 test demonstrations");
    }
    if a.train > MAX_DEMONSTRATIONS || a.test > MAX_DEMONSTRATIONS {
        bail!(
            "--train {} --test {}: the demo generates at most {MAX_DEMONSTRATIONS} demonstrations of each kind \
             (it is a showcase that runs in seconds); for larger experiments generate data with \
             phasekit_tsc::synthetic::generate and use `fit` and `evaluate`",
            a.train,
            a.test
        );
    }
    let clock = Instant::now();
    let dir = &a.output;
    check_replaceable(dir)?;
    // Everything is written into a temporary folder beside the target and moved
    // into place when complete: a failure leaves no partial folder.
    let parent = match dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        Some(p) => p.to_path_buf(),
        None => std::path::PathBuf::from("."),
    };
    output::create_dir(&parent)?;
    let tmp = tempfile::Builder::new()
        .prefix(".phasekit-demo")
        .tempdir_in(&parent)
        .map_err(|e| CliError::new(format!("{}: cannot write: {e}", parent.display())))?;
    let work = tmp.path().to_path_buf();
    let data_dir = work.join("data");
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
    for (method, file) in DEMO_METHODS {
        let mf = fit_tables(&train, &spec, false, method, &options, false)?;
        mf.save(&work.join(format!("{file}.json")))?;
        let s = score(&mf, &test, test_demos)?;
        rows.push((method, mf.n_states(), mf.fit.fit_seconds, s));
        models.push((mf, dir.join(format!("{file}.json"))));
    }
    let base = constant_mse(&train, &test);
    let opt = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.1}"));
    let _ = writeln!(out, "| method | states | MSE (cm²) | RMSE (cm) | fit (s) | transition frames | boundary → nearest transition (frames) | boundary → nearest state change (frames) |");
    let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|---:|---:|");
    let _ = writeln!(
        out,
        "| constant mean pose | – | {} | {} | – | – | – | – |",
        sig4(base),
        sig4(base.sqrt())
    );
    for (m, states, secs, s) in &rows {
        let _ = writeln!(
            out,
            "| {m} | {states} | {} | {} | {secs:.2} | {} | {} | {} |",
            sig4(s.mse),
            sig4(s.mse.sqrt()),
            s.transitions,
            opt(s.boundary_to_transition),
            opt(s.boundary_to_state_change)
        );
    }
    let _ = writeln!(
        out,
        "\nMSE: squared error of the robot's hand position per frame, mean over the {} test demonstrations' frames, predicted\ncausally from the human's hand alone (one fit, seed {}; `evaluate` below repeats it over random training subsets).\nhmm:states=7 is the control for the TSC-HMM: as many states, no transition states; a gain of the TSC-HMM over the\n4-state HMM that the 7-state HMM also has comes from the number of states, not from transition states.\nBoundaries: the 4 true phase changes of each test demonstration; distance in frames to the nearest transition frame\nfound (TSC) and to the nearest change of Viterbi state.",
        a.test, a.seed
    );
    if a.seeds > 0 && a.train > 2 {
        out += &over_seeds(&train, &test, &spec, &options, a.seeds)?;
    }
    let _ = writeln!(
        out,
        "\nWhat the 4-state HMM learned (state means of both hands; expected stay 1/(1 − a_ii); the true phases of the test\nframes its Viterbi path gives to the state, those with at least 20 %):\n\n{}",
        learned_table(&models[0].0, &test, test_demos)?
    );
    // Plots with the TSC-HMM.
    let (mf, model_path) = &models[2];
    let unit = Unit::default();
    output::write_string(
        &work.join("segmentation.svg"),
        &segmentation_svg(mf, &test[0], &unit)?,
    )?;
    output::write_string(
        &work.join("prediction.svg"),
        &prediction_svg(mf, &test[0], &unit)?,
    )?;
    output::write_string(
        &work.join("states.svg"),
        &states_svg(mf, &train, default_plane(mf), &unit)?,
    )?;
    put_in_place(tmp, dir)?;
    let _ = writeln!(
        out,
        "\nWrote to {}/: data/ (train_*.csv, test_*.csv), hmm.json, hmm7.json and tsc-hmm.json (model files),\nsegmentation.svg, prediction.svg and states.svg (tsc-hmm on test_00 and the training data). Done in {:.1} s.\n",
        dir.display(),
        clock.elapsed().as_secs_f64()
    );
    // Commands that work as printed: this executable's path unless it is on the PATH.
    let p = command_name();
    let d = shell_word(&dir.to_string_lossy());
    let test_00 = shell_word(&dir.join("data").join("test_00.csv").to_string_lossy());
    let m = shell_word(&model_path.to_string_lossy());
    let _ = writeln!(
        out,
        "Next (your own data: {p} evaluate --help):\n  {p} segment --model {m} --data {test_00}\n  {p} predict --model {m} --data {test_00} --covariance\n  \
         cut -d, -f1-3 {test_00} | {p} stream --model {m}\n  \
         {p} evaluate --data {d}/data --methods hmm,hmm:states=7,{DEMO_TSC} --seeds 10"
    );
    output::print_stdout(&out)
}
