//! The `auto` preset and the cross-validation it runs: it picks the family and
//! size that are clearly right on generated data, uses only the demonstrations
//! it is given, is deterministic (by seed, for any number of threads), reports
//! failed and abandoned candidates, and validates its keys.

use phasekit_emission::{Frames, SequenceSet};
use phasekit_tsc::auto::method_of_spec;
use phasekit_tsc::{
    cross_validate, AutoSettings, CrossValidation, CvRow, FoldPlan, Grid, Halving, Method, Preset,
    PresetOptions, Roles, TscError,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn roles() -> Roles {
    Roles::new(vec![0], vec![1]).unwrap()
}

/// Demonstrations where the robot needs the phase: the human goes out and
/// back (0 → 1 → 0), the robot moves on monotonically (0 → 2), so one human
/// position means two robot positions and only a model with memory (an HMM)
/// can tell them apart. Durations vary per demonstration.
fn phased(n: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let t_len: usize = rng.random_range(36..48);
            let mut v = Vec::with_capacity(2 * t_len);
            for t in 0..t_len {
                let tau = t as f64 / (t_len - 1) as f64;
                let human = 1.0 - (2.0 * tau - 1.0).abs();
                let robot = 2.0 * tau;
                v.push(human + 0.02 * rng.random::<f64>());
                v.push(robot + 0.02 * rng.random::<f64>());
            }
            v
        })
        .collect()
}

/// Demonstrations of a static, nonlinear relation in random order:
/// robot = sin(3·human), human uniform on [−2, 2].
fn static_sine(n: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let mut v = Vec::new();
            for _ in 0..60 {
                let h: f64 = rng.random_range(-2.0..2.0);
                v.push(h);
                v.push((3.0 * h).sin() + 0.01 * rng.random::<f64>());
            }
            v
        })
        .collect()
}

fn set(seqs: &[Vec<f64>]) -> SequenceSet {
    SequenceSet::new(seqs, 2).unwrap()
}

fn auto(settings: &AutoSettings) -> Method {
    settings.method(&PresetOptions::default()).unwrap()
}

/// The table without its timings, which are the only thing allowed to vary.
fn untimed(table: &[CvRow]) -> Vec<CvRow> {
    table
        .iter()
        .map(|r| {
            let mut r = r.clone();
            r.fit_seconds = 0.0;
            r
        })
        .collect()
}

#[test]
fn auto_chooses_an_hmm_when_the_robot_depends_on_the_phase() {
    let data = set(&phased(10, 1));
    let s = AutoSettings::builder()
        .grid(Grid::Small)
        .families(["hmm", "gmm"])
        .ensemble(1)
        .build()
        .unwrap();
    let (model, summary) = auto(&s).fit(&data, &roles()).unwrap();
    let chosen = summary.chosen.clone().unwrap();
    assert!(
        chosen.starts_with("hmm:"),
        "chose {chosen}: {:?}",
        summary.cv_table
    );
    // Every candidate of the families is in the table; the GMMs lost clearly.
    assert_eq!(summary.cv_table.len(), 7);
    let best_gmm = summary
        .cv_table
        .iter()
        .filter(|r| r.label.starts_with("gmm"))
        .map(|r| r.mse)
        .fold(f64::INFINITY, f64::min);
    let best = summary.cv_table.iter().find(|r| r.label == chosen).unwrap();
    assert!(best.mse * 2.0 < best_gmm, "{:?}", summary.cv_table);
    assert!(model.n_states() >= 5);
}

#[test]
fn cross_validation_chooses_enough_components_for_a_static_nonlinear_relation() {
    let data = set(&static_sine(6, 2));
    let base = PresetOptions::default();
    let candidates: Vec<(String, Method)> =
        ["hmm:states=2", "gmm:states=2", "gmm:states=10,reg=1e-3"]
            .iter()
            .map(|s| (s.to_string(), method_of_spec(s, &base).unwrap()))
            .collect();
    let cv = Method::CrossValidated(CrossValidation::new(candidates, 3).unwrap());
    let (_, summary) = cv.fit(&data, &roles()).unwrap();
    assert_eq!(summary.chosen.as_deref(), Some("gmm:states=10,reg=1e-3"));
}

#[test]
fn the_table_is_the_slow_obvious_cross_validation() {
    // Pooled squared error over the held-out frames of every fold, computed
    // here by hand with Method::fit and Predictor::predict.
    let seqs = phased(6, 3);
    let data = set(&seqs);
    let base = PresetOptions::default();
    let method = method_of_spec("hmm:states=5,reg=1e-3", &base).unwrap();
    let folds = 3;
    let (mut se, mut frames) = (0.0, 0usize);
    for f in 0..folds {
        let train: Vec<usize> = (0..6).filter(|k| k % folds != f).collect();
        let (model, _) = method.fit(&data.subset(&train).unwrap(), &roles()).unwrap();
        let p = model.predictor(&roles()).unwrap();
        for k in (0..6).filter(|k| k % folds == f) {
            let human: Vec<f64> = seqs[k].chunks(2).map(|x| x[0]).collect();
            let pred = p.predict(Frames::new(&human, 1).unwrap(), false).unwrap();
            for (t, x) in seqs[k].chunks(2).enumerate() {
                se += (pred.mean[t] - x[1]).powi(2);
                frames += 1;
            }
        }
    }
    let got = cross_validate(&[("m".into(), method)], folds, &data, &roles()).unwrap();
    let got = *got[0].as_ref().unwrap();
    let want = se / frames as f64;
    assert!((got - want).abs() <= 1e-12 * want, "{got} vs {want}");
}

#[test]
fn same_seed_same_choice_and_table_for_one_or_two_threads() {
    let data = set(&phased(8, 4));
    let s = AutoSettings::builder()
        .grid(Grid::Small)
        .folds(4)
        .build()
        .unwrap();
    let fit_in = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| auto(&s).fit(&data, &roles()).unwrap().1)
    };
    let one = fit_in(1);
    let two = fit_in(2);
    let again = fit_in(2);
    assert_eq!(one.chosen, two.chosen);
    assert_eq!(untimed(&one.cv_table), untimed(&two.cv_table));
    assert_eq!(untimed(&two.cv_table), untimed(&again.cv_table));
    assert_eq!(one.log_likelihood, two.log_likelihood);
}

#[test]
fn folds_are_shuffled_by_seed_and_use_only_the_given_demonstrations() {
    let a = FoldPlan::new(10, 3, Some(7)).unwrap();
    assert_eq!(a, FoldPlan::new(10, 3, Some(7)).unwrap());
    assert_ne!(a, FoldPlan::new(10, 3, Some(8)).unwrap());
    // Balanced: fold sizes differ by at most one.
    let mut sizes = [0; 3];
    a.fold_of().iter().for_each(|&f| sizes[f] += 1);
    assert_eq!(sizes.iter().max().unwrap() - sizes.iter().min().unwrap(), 1);
    assert_eq!(
        FoldPlan::new(5, 2, None).unwrap().fold_of(),
        &[0, 1, 0, 1, 0]
    );
    assert_eq!(FoldPlan::new(3, 10, None).unwrap().folds(), 3);
    assert!(FoldPlan::new(1, 2, None).is_err());

    // The choice is a function of the training demonstrations alone: the
    // fit sees nothing else, so held-out data drawn differently cannot move
    // it; and the same training set gives the same table.
    let train = set(&phased(8, 5));
    let s = AutoSettings::builder().grid(Grid::Small).build().unwrap();
    let (_, first) = auto(&s).fit(&train, &roles()).unwrap();
    let (_, second) = auto(&s).fit(&train, &roles()).unwrap();
    assert_eq!(untimed(&first.cv_table), untimed(&second.cv_table));
}

#[test]
fn a_failing_candidate_is_reported_with_its_reason() {
    // 40 states cannot be fitted to demonstrations of fewer than 40 frames.
    let data = set(&phased(6, 6));
    let base = PresetOptions::default();
    let candidates: Vec<(String, Method)> = ["hmm:states=60", "hmm:states=5"]
        .iter()
        .map(|s| (s.to_string(), method_of_spec(s, &base).unwrap()))
        .collect();
    let cv = Method::CrossValidated(CrossValidation::new(candidates, 3).unwrap());
    let (_, summary) = cv.fit(&data, &roles()).unwrap();
    assert_eq!(summary.chosen.as_deref(), Some("hmm:states=5"));
    let failed = &summary.cv_table[0];
    assert_eq!(failed.label, "hmm:states=60");
    assert!(!failed.abandoned);
    let reason = failed.failure.as_deref().unwrap();
    assert!(reason.contains("fold 1 of 3"), "{reason}");
    assert_eq!(summary.cv_failures.len(), 1);
    assert!(summary.cv_table[1].failure.is_none());
    assert_eq!(summary.cv_table[1].folds_scored, 3);
}

#[test]
fn successive_halving_abandons_the_worst_and_says_so() {
    let h = Halving::default();
    assert_eq!(h.rungs(5), [2, 4, 5]);
    assert_eq!(h.rungs(2), [2]);
    assert_eq!(Halving::new(1, 2, 1).unwrap().rungs(5), [1, 2, 4, 5]);
    assert_eq!(h.kept(19), 7);
    assert_eq!(h.kept(4), 3);
    assert_eq!(h.kept(2), 2);
    assert!(Halving::new(0, 3, 1).is_err());
    assert!(Halving::new(2, 1, 1).is_err());

    let data = set(&phased(10, 7));
    let s = AutoSettings::builder()
        .grid(Grid::Small)
        .ensemble(1)
        .build()
        .unwrap();
    let (_, summary) = auto(&s).fit(&data, &roles()).unwrap();
    let t = &summary.cv_table;
    assert_eq!(t.len(), SMALL);
    // 9 candidates: rung 0 scores all on 2 folds, 3 go on to 4 folds, then 3 to 5.
    let abandoned: Vec<&CvRow> = t.iter().filter(|r| r.abandoned).collect();
    assert_eq!(abandoned.len(), 6, "{t:?}");
    assert!(abandoned.iter().all(|r| r.folds_scored == 2));
    let full: Vec<&CvRow> = t.iter().filter(|r| r.folds_scored == 5).collect();
    assert_eq!(full.len(), 3);
    // Every survivor was at least as good on rung 0 as every abandoned one,
    // and the winner is the best of the survivors.
    let chosen = summary.chosen.unwrap();
    let best = full.iter().map(|r| r.mse).fold(f64::INFINITY, f64::min);
    assert_eq!(full.iter().find(|r| r.label == chosen).unwrap().mse, best);

    // Without halving every candidate is scored on every fold.
    let off = s.to_builder().halving(false).build().unwrap();
    let (_, all) = auto(&off).fit(&data, &roles()).unwrap();
    assert!(all
        .cv_table
        .iter()
        .all(|r| r.folds_scored == 5 && !r.abandoned));
}

const SMALL: usize = 9;

#[test]
fn keys_are_validated_and_errors_name_them() {
    let name = |r: Result<AutoSettings, TscError>| match r {
        Err(TscError::InvalidSetting { name, .. }) => name,
        other => panic!("expected an invalid setting, got {other:?}"),
    };
    let b = AutoSettings::builder;
    let set_key = |k: &str, v: &str| AutoSettings::set(b(), k, v).and_then(|b| b.build());
    assert_eq!(name(set_key("folds", "1")), "folds");
    assert_eq!(name(set_key("folds", "many")), "folds");
    assert_eq!(name(set_key("grid", "huge")), "grid");
    assert_eq!(name(set_key("families", "hmm+lstm")), "families");
    assert_eq!(name(set_key("halving", "maybe")), "halving");
    assert_eq!(name(set_key("choose", "worst")), "choose");
    assert_eq!(name(set_key("calibrate", "loosely")), "calibrate");
    assert_eq!(name(set_key("colour", "blue")), "method");
    use phasekit_tsc::{Calibration, Selection};
    let d = AutoSettings::default();
    assert_eq!(
        (d.selection(), d.calibration()),
        (Selection::Mean(5), Calibration::Predictive)
    );
    assert_eq!(
        set_key("choose", "one-se").unwrap().selection(),
        Selection::OneStandardError
    );
    assert_eq!(
        set_key("calibrate", "on").unwrap().calibration(),
        Calibration::Predictive
    );
    assert_eq!(
        set_key("calibrate", "demonstrations")
            .unwrap()
            .calibration(),
        Calibration::Demonstrations
    );
    // The rule reaches the method, and a file of the settings reads back the same.
    let one_se = set_key("choose", "one-se").unwrap();
    let Method::CrossValidated(cv) = one_se.method(&PresetOptions::default()).unwrap() else {
        panic!("auto is a cross-validated choice");
    };
    assert_eq!(cv.selection(), Selection::OneStandardError);
    let back: AutoSettings =
        serde_json::from_str(&serde_json::to_string(&one_se).unwrap()).unwrap();
    assert_eq!(back, one_se);
    // The single best is not written (the files of before); the default mean is.
    let best = set_key("ensemble", "1").unwrap();
    assert!(!serde_json::to_string(&best).unwrap().contains("choose"));
    assert!(serde_json::to_string(&d)
        .unwrap()
        .contains(r#""choose":{"mean":5}"#));
    let ok = set_key("families", "hmm+tsc-hmm").unwrap();
    assert_eq!(ok.families().unwrap(), ["hmm", "tsc-hmm"]);
    let cands = ok.candidates(&PresetOptions::default()).unwrap();
    assert!(cands
        .iter()
        .all(|(l, _)| l.starts_with("hmm:") || l.starts_with("tsc-hmm:")));
    assert!(AutoSettings::is_key("grid") && !AutoSettings::is_key("states"));

    // Every specification of every grid makes a method; `auto` is a preset.
    for grid in [
        Grid::Small,
        Grid::Default,
        Grid::Relative,
        Grid::Positions,
        Grid::Mixed,
    ] {
        let s = AutoSettings::builder().grid(grid).build().unwrap();
        assert_eq!(
            s.candidates(&PresetOptions::default()).unwrap().len(),
            grid.specs().len()
        );
    }
    // The mixed grid is the positions grid and more.
    assert!(Grid::Mixed.specs().starts_with(&Grid::Positions.specs()));
    assert!(Grid::Mixed.specs().len() > Grid::Positions.specs().len());
    let m = Method::preset("auto".parse::<Preset>().unwrap(), &PresetOptions::default()).unwrap();
    assert!(matches!(m, Method::CrossValidated(_)));
    assert!(method_of_spec("hmm:states=x", &PresetOptions::default()).is_err());
    assert!(method_of_spec("hmm:colour=1", &PresetOptions::default()).is_err());
}

/// A table whose survivors all failed on a later rung: the abandoned
/// candidates (scored on fewer folds) never win, and the best survivor
/// scored on the most folds does when one is left.
#[test]
fn an_abandoned_candidate_never_wins() {
    let row = |label: &str, folds: usize, mse: f64, abandoned: bool, failed: bool| -> CvRow {
        let mut v = serde_json::json!({
            "label": label, "folds_scored": folds, "mse": mse, "mse_sd": 0.0,
            "fit_seconds": 0.0, "abandoned": abandoned,
        });
        if failed {
            v["failure"] = "fold 3 of 5: diverged".into();
        }
        serde_json::from_value(v).unwrap()
    };
    let all_failed = [
        row("a", 2, 1.0, true, false),
        row("b", 2, 5.0, false, true),
        row("c", 2, 4.0, false, true),
    ];
    assert_eq!(phasekit_tsc::cross_validation::winner(&all_failed), None);
    let late_failure = [
        row("a", 2, 1.0, true, false),
        row("b", 3, 5.0, false, true),
        row("c", 4, 4.0, false, false),
        row("d", 2, 3.0, false, false),
    ];
    assert_eq!(
        phasekit_tsc::cross_validation::winner(&late_failure),
        Some(2)
    );
}

/// The one-standard-error rule against its definition worked by hand: the
/// standard error of the lowest error, the candidates within it, the most
/// regularised of them (then the fewest states, then the earlier); the
/// abandoned and the failed are never eligible; `Best` is `winner`.
#[test]
fn the_one_standard_error_rule_takes_the_most_regularised_within_one_se() {
    use phasekit_tsc::cross_validation::{winner, winner_by};
    use phasekit_tsc::Selection;
    let row = |label: &str, mse: f64, sd: f64, abandoned: bool, failed: bool| -> CvRow {
        let mut v = serde_json::json!({
            "label": label, "folds_scored": 5, "mse": mse, "mse_sd": sd,
            "fit_seconds": 0.0, "abandoned": abandoned,
        });
        if failed {
            v["failure"] = "fold 3 of 5: diverged".into();
        }
        serde_json::from_value(v).unwrap()
    };
    let specs = [
        "hmm:states=7,reg=1e-3", // the lowest error: 100 ± 8 over 5 folds, SE 8 / 2 = 4
        "hmm:states=7,reg=1e-2", // 103.9: within, reg 1e-2
        "gmm:states=5,reg=1e-2", // 104.0: within, reg 1e-2 and fewer states: chosen
        "hmm:states=5,reg=3e-2", // 104.1: just outside
        "hmm:states=4,reg=1e-1", // 101: abandoned
        "hmm:states=3,reg=1e-1", // 101: failed
    ];
    let candidates: Vec<(String, Method)> = crate::candidates::candidates(&specs);
    let table = [
        row(specs[0], 100.0, 8.0, false, false),
        row(specs[1], 103.9, 1.0, false, false),
        row(specs[2], 104.0, 30.0, false, false),
        row(specs[3], 104.1, 1.0, false, false),
        row(specs[4], 101.0, 1.0, true, false),
        row(specs[5], 101.0, 1.0, false, true),
    ];
    // The abandoned row was scored on fewer folds in a real table.
    let mut table = table;
    table[4].folds_scored = 2;
    assert_eq!(winner(&table), Some(0));
    assert_eq!(winner_by(&table, &candidates, Selection::Best), Some(0));
    assert_eq!(
        winner_by(&table, &candidates, Selection::OneStandardError),
        Some(2)
    );
    // A wider spread of the lowest error takes in the stronger regulariser.
    table[0].mse_sd = 10.0; // SE 5: 104.1 is within
    assert_eq!(
        winner_by(&table, &candidates, Selection::OneStandardError),
        Some(3)
    );
    // No spread: the lowest error itself.
    table[0].mse_sd = 0.0;
    assert_eq!(
        winner_by(&table, &candidates, Selection::OneStandardError),
        Some(0)
    );
}

/// `auto:grid=relative` is a setting that means the same in any unit: the
/// data with the human in centimetres and the robot in kilometres give the
/// same choice, the same table (errors scaled by the robot's unit²) and the
/// same predictions in the new units; the default grid, in absolute units,
/// does not.
#[test]
fn the_relative_grid_chooses_the_same_in_any_unit() {
    let seqs = phased(8, 21);
    let a = [100.0, 1e-3];
    let scaled: Vec<Vec<f64>> = seqs
        .iter()
        .map(|q| q.iter().enumerate().map(|(i, v)| v * a[i % 2]).collect())
        .collect();
    let fit = |grid: Grid, data: &[Vec<f64>]| {
        let s = AutoSettings::builder()
            .grid(grid)
            .families(["hmm", "gmm"])
            .build()
            .unwrap();
        auto(&s).fit(&set(data), &roles()).unwrap()
    };
    let (m1, s1) = fit(Grid::Relative, &seqs);
    let (m2, s2) = fit(Grid::Relative, &scaled);
    assert_eq!(s1.chosen, s2.chosen);
    for (r1, r2) in s1.cv_table.iter().zip(&s2.cv_table) {
        assert_eq!(r1.label, r2.label);
        if r1.mse.is_finite() {
            let want = r1.mse * a[1] * a[1];
            assert!((r2.mse - want).abs() <= 1e-7 * want, "{r1:?} vs {r2:?}");
        }
    }
    let human: Vec<f64> = seqs[0].chunks(2).map(|x| x[0]).collect();
    let human2: Vec<f64> = human.iter().map(|v| v * a[0]).collect();
    let p1 = m1
        .predictor(&roles())
        .unwrap()
        .predict(Frames::new(&human, 1).unwrap(), false)
        .unwrap();
    let p2 = m2
        .predictor(&roles())
        .unwrap()
        .predict(Frames::new(&human2, 1).unwrap(), false)
        .unwrap();
    for (x, y) in p1.mean.iter().zip(&p2.mean) {
        assert!(
            (x * a[1] - y).abs() <= 1e-7 * (x * a[1]).abs().max(1e-9),
            "{x} vs {y}"
        );
    }
    // The absolute grid's regularisation is in data units: on the rescaled
    // data it is another model.
    let (_, d1) = fit(Grid::Default, &seqs);
    let (_, d2) = fit(Grid::Default, &scaled);
    let ratio: Vec<f64> = d1
        .cv_table
        .iter()
        .zip(&d2.cv_table)
        .filter(|(x, y)| x.mse.is_finite() && y.mse.is_finite())
        .map(|(x, y)| y.mse / (x.mse * a[1] * a[1]))
        .collect();
    assert!(
        ratio.iter().any(|r| (r - 1.0).abs() > 1e-3),
        "the absolute grid should not be unit-free: {ratio:?}"
    );
}
