//! The mean of several models (`Selection::Mean`, `auto:ensemble=K`): its
//! prediction is the moment-matched mixture of its members' (against the
//! formula term by term and against Monte Carlo samples of the mixture),
//! online = batch, a malformed ensemble is refused, and the cross-validated
//! mean is made of the best-ranked candidates, with a held-out row that is
//! the slow obvious one and never worse than its members' average error.

use phasekit_emission::{Frames, SequenceSet};
use phasekit_gmr::{chi_squared_quantile, score_gaussian};
use phasekit_tsc::auto::method_of_spec;
use phasekit_tsc::{
    AutoSettings, Calibration, CrossValidation, FoldPlan, Halving, Method, Model, Predictor,
    PresetOptions, Roles, Selection,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Human 0, robot 1 and 2 (both scored).
fn roles() -> Roles {
    Roles::new(vec![0], vec![1, 2]).unwrap()
}

/// Out-and-back human; the robot moves on (dim 1) and swings (dim 2).
fn phased(n: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let t_len: usize = rng.random_range(36..48);
            let mut v = Vec::with_capacity(3 * t_len);
            for t in 0..t_len {
                let tau = t as f64 / (t_len - 1) as f64;
                let z: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
                v.push(1.0 - (2.0 * tau - 1.0).abs() + 0.02 * z[0]);
                v.push(2.0 * tau + 0.05 * z[1]);
                v.push((6.0 * tau).sin() + 0.05 * z[2]);
            }
            v
        })
        .collect()
}

fn fit(spec: &str, data: &SequenceSet) -> Model {
    method_of_spec(spec, &PresetOptions::default())
        .unwrap()
        .fit(data, &roles())
        .unwrap()
        .0
}

fn human(seq: &[f64]) -> Vec<f64> {
    seq.chunks(3).map(|x| x[0]).collect()
}

const SPECS: [&str; 3] = [
    "hmm:states=5,reg=1e-3",
    "gmm:states=6,reg=1e-3",
    "hmm:states=3,reg=1e-2",
];
const WEIGHTS: [f64; 3] = [0.5, 0.3, 0.2];

fn members(data: &SequenceSet) -> Vec<(String, Model)> {
    SPECS
        .iter()
        .map(|s| (s.to_string(), fit(s, data)))
        .collect()
}

#[test]
fn the_mean_predicts_the_moment_matched_mixture_of_its_members() {
    let seqs = phased(6, 1);
    let data = SequenceSet::new(&seqs, 3).unwrap();
    let members = members(&data);
    let model = Model::ensemble(members.clone(), &WEIGHTS).unwrap();
    let h = human(&seqs[0]);
    let input = Frames::new(&h, 1).unwrap();
    let got = model
        .predictor(&roles())
        .unwrap()
        .predict(input, true)
        .unwrap();
    let parts: Vec<_> = members
        .iter()
        .map(|(_, m)| m.predictor(&roles()).unwrap().predict(input, true).unwrap())
        .collect();
    let cov = got.covariance.as_ref().unwrap();
    for t in 0..h.len() {
        // Term by term: μ = Σ w μ_i, Σ = Σ w (Σ_i + μ_i μ_iᵀ) − μ μᵀ (the
        // second-moment form, not the code's centred one).
        for i in 0..2 {
            let mu: f64 = parts
                .iter()
                .zip(WEIGHTS)
                .map(|(p, w)| w * p.mean[t * 2 + i])
                .sum();
            assert!((got.mean[t * 2 + i] - mu).abs() <= 1e-12, "t {t} dim {i}");
            for j in 0..2 {
                let second: f64 = parts
                    .iter()
                    .zip(WEIGHTS)
                    .map(|(p, w)| {
                        let c = p.covariance.as_ref().unwrap()[t * 4 + i * 2 + j];
                        w * (c + p.mean[t * 2 + i] * p.mean[t * 2 + j])
                    })
                    .sum();
                let mu_j: f64 = parts
                    .iter()
                    .zip(WEIGHTS)
                    .map(|(p, w)| w * p.mean[t * 2 + j])
                    .sum();
                let want = second - mu * mu_j;
                assert!(
                    (cov[t * 4 + i * 2 + j] - want).abs() <= 1e-9 * want.abs().max(1e-3),
                    "t {t} ({i}, {j}): {} vs {want}",
                    cov[t * 4 + i * 2 + j]
                );
            }
        }
    }
    // The evidence is the first member's.
    assert_eq!(got.log_predictive, parts[0].log_predictive);
    assert_eq!(got.rejected, parts[0].rejected);
}

#[test]
fn the_means_covariance_is_the_mixtures_by_monte_carlo() {
    let seqs = phased(6, 2);
    let data = SequenceSet::new(&seqs, 3).unwrap();
    let members = members(&data);
    let model = Model::ensemble(members.clone(), &WEIGHTS).unwrap();
    let h = human(&seqs[1]);
    let input = Frames::new(&h, 1).unwrap();
    let got = model
        .predictor(&roles())
        .unwrap()
        .predict(input, true)
        .unwrap();
    let parts: Vec<_> = members
        .iter()
        .map(|(_, m)| m.predictor(&roles()).unwrap().predict(input, true).unwrap())
        .collect();
    // Draw from the mixture Σ w_i N(μ_i, Σ_i) at a frame mid-way, where the
    // members disagree most, and compare the sample moments.
    let t = h.len() / 2;
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let n = 400_000;
    let (mut s1, mut s2) = ([0.0; 2], [[0.0; 2]; 2]);
    for _ in 0..n {
        let u: f64 = rng.random();
        let k = if u < WEIGHTS[0] {
            0
        } else if u < WEIGHTS[0] + WEIGHTS[1] {
            1
        } else {
            2
        };
        let (m, c) = (
            &parts[k].mean[t * 2..t * 2 + 2],
            &parts[k].covariance.as_ref().unwrap()[t * 4..t * 4 + 4],
        );
        // Cholesky of the 2 × 2 covariance.
        let l00 = c[0].sqrt();
        let l10 = c[2] / l00;
        let l11 = (c[3] - l10 * l10).sqrt();
        let (z0, z1): (f64, f64) = (
            StandardNormal.sample(&mut rng),
            StandardNormal.sample(&mut rng),
        );
        let x = [m[0] + l00 * z0, m[1] + l10 * z0 + l11 * z1];
        for i in 0..2 {
            s1[i] += x[i];
            for j in 0..2 {
                s2[i][j] += x[i] * x[j];
            }
        }
    }
    let cov = &got.covariance.as_ref().unwrap()[t * 4..t * 4 + 4];
    for i in 0..2 {
        let mean = s1[i] / n as f64;
        let sd = cov[i * 2 + i].sqrt();
        assert!(
            (mean - got.mean[t * 2 + i]).abs() < 5.0 * sd / (n as f64).sqrt(),
            "mean {i}"
        );
        for j in 0..2 {
            let sample = s2[i][j] / n as f64 - (s1[i] / n as f64) * (s1[j] / n as f64);
            let scale = (cov[i * 2 + i] * cov[j * 2 + j]).sqrt();
            // Sampling error of a second moment: about √(2/n) of its scale, and
            // more for a mixture's heavier tails; 0.02 is over five of those.
            assert!(
                (sample - cov[i * 2 + j]).abs() <= 0.02 * scale,
                "({i}, {j}): sample {sample} vs {}",
                cov[i * 2 + j]
            );
        }
    }
}

#[test]
fn the_means_online_prediction_is_its_batch_prediction() {
    let seqs = phased(6, 3);
    let data = SequenceSet::new(&seqs, 3).unwrap();
    let model = Model::ensemble(members(&data), &WEIGHTS).unwrap();
    let added = [0.01, 0.002, 0.002, 0.02];
    let p = model
        .predictor(&roles())
        .unwrap()
        .with_added_covariance(&added)
        .unwrap()
        .with_covariance_scale(1.7)
        .unwrap();
    let h = human(&seqs[2]);
    let batch = p.predict(Frames::new(&h, 1).unwrap(), true).unwrap();
    let cov = batch.covariance.unwrap();
    let mut online = p.online();
    for _ in 0..2 {
        for (t, x) in h.iter().enumerate() {
            let e = online.step_with_evidence(&[*x], true).unwrap();
            assert_eq!(online.mean(), &batch.mean[t * 2..t * 2 + 2], "frame {t}");
            for (a, b) in online.covariance().iter().zip(&cov[t * 4..t * 4 + 4]) {
                assert!((a - b).abs() <= 1e-12 * b.abs(), "frame {t}: {a} vs {b}");
            }
            // The first member's evidence (its own online and batch sums may
            // round differently in the last bit).
            let want = batch.log_predictive[t];
            assert!(
                (e.log_predictive - want).abs() <= 1e-12 * want.abs().max(1.0),
                "frame {t}"
            );
        }
        // And again after a reset.
        online.reset();
    }
}

#[test]
fn a_malformed_ensemble_is_refused_by_name() {
    let seqs = phased(4, 4);
    let data = SequenceSet::new(&seqs, 3).unwrap();
    let m = members(&data);
    let err = |r: phasekit_tsc::Result<Model>| r.unwrap_err().to_string();
    assert!(err(Model::ensemble(m.clone(), &[0.5, 0.3, 0.3])).contains("sum to"));
    assert!(err(Model::ensemble(m.clone(), &[0.5, 0.5, 0.0])).contains("weight 0"));
    assert!(err(Model::ensemble(m.clone(), &[0.5, 0.5])).contains("3 members and 2 weights"));
    assert!(err(Model::ensemble(Vec::new(), &[])).contains("no member"));
    let inner = Model::ensemble(m.clone(), &WEIGHTS).unwrap();
    let nested = vec![("inner".to_string(), inner), m[0].clone()];
    assert!(err(Model::ensemble(nested, &[0.5, 0.5])).contains("itself an ensemble"));
    // A member of another frame dimension (a fourth column).
    let wider: Vec<Vec<f64>> = seqs
        .iter()
        .map(|q| {
            q.chunks(3)
                .flat_map(|x| [x[0], x[1], x[2], x[1] - x[2]])
                .collect()
        })
        .collect();
    let (wide, _) = method_of_spec("gmm:states=2", &PresetOptions::default())
        .unwrap()
        .fit(
            &SequenceSet::new(&wider, 4).unwrap(),
            &Roles::new(vec![0], vec![1, 2, 3]).unwrap(),
        )
        .unwrap();
    let mixed = vec![m[0].clone(), ("wide".to_string(), wide)];
    assert!(err(Model::ensemble(mixed, &[0.5, 0.5])).contains("dimension"));
    // A file whose weights were edited is refused when read.
    let good = Model::ensemble(m, &WEIGHTS).unwrap();
    let mut json = serde_json::to_value(&good).unwrap();
    json["members"][1]["weight"] = serde_json::json!(0.9);
    let read: Result<Model, _> = serde_json::from_value(json);
    assert!(read.unwrap_err().to_string().contains("sum to"));
    // And a good one reads back to the same predictions.
    let back: Model = serde_json::from_str(&serde_json::to_string(&good).unwrap()).unwrap();
    let h = human(&seqs[0]);
    let input = Frames::new(&h, 1).unwrap();
    let (a, b) = (
        good.predictor(&roles())
            .unwrap()
            .predict(input, true)
            .unwrap(),
        back.predictor(&roles())
            .unwrap()
            .predict(input, true)
            .unwrap(),
    );
    assert_eq!(a.mean, b.mean);
    assert_eq!(a.covariance, b.covariance);
}

#[test]
fn an_empty_predictor_ensemble_is_refused() {
    assert!(Predictor::ensemble(Vec::new()).is_err());
}

fn grid() -> Vec<(String, Method)> {
    crate::candidates::candidates(&[
        "hmm:states=3,reg=1e-2",
        "hmm:states=5,reg=1e-3",
        "hmm:states=8,reg=1e-3",
        "gmm:states=4,reg=1e-2",
        "gmm:states=8,reg=1e-3",
        "tsc-hmm:states=3,reg=1e-3",
    ])
}

#[test]
fn the_cross_validated_mean_is_the_best_ranked_candidates_and_its_row_the_slow_obvious_one() {
    let seqs = phased(6, 5);
    let data = SequenceSet::new(&seqs, 3).unwrap();
    let (folds, k) = (3, 3);
    let cv = CrossValidation::new(grid(), folds)
        .unwrap()
        .with_fold_seed(11)
        .with_selection(Selection::Mean(k));
    let (model, summary) = Method::CrossValidated(cv.clone())
        .fit(&data, &roles())
        .unwrap();
    let table = &summary.cv_table;
    assert_eq!(table.len(), grid().len() + 1, "the mean's row is appended");
    let mut order: Vec<usize> = (0..grid().len()).collect();
    order.sort_by(|&a, &b| table[a].mse.total_cmp(&table[b].mse));
    let labels: Vec<&str> = order[..k]
        .iter()
        .map(|&c| table[c].label.as_str())
        .collect();
    let Model::Ensemble(members) = &model else {
        panic!("the mean of {k} is an ensemble, got {model:?}");
    };
    assert_eq!(
        members.iter().map(|m| m.label.as_str()).collect::<Vec<_>>(),
        labels
    );
    assert!(members
        .iter()
        .all(|m| (m.weight - 1.0 / k as f64).abs() < 1e-15));
    let row = table.last().unwrap();
    assert_eq!(summary.chosen.as_deref(), Some(row.label.as_str()));
    assert_eq!(row.label, format!("mean of 3: {}", labels.join(" + ")));
    // The row by hand: each member fitted without the fold, the mean of their
    // predictions scored on the held-out demonstrations.
    let plan = FoldPlan::new(6, folds, Some(11)).unwrap();
    let methods: Vec<Method> = labels
        .iter()
        .map(|l| method_of_spec(l, &PresetOptions::default()).unwrap())
        .collect();
    let limit = chi_squared_quantile(0.95, 2).unwrap();
    let (mut se, mut frames, mut inside, mut nlpd) = (0.0, 0usize, 0usize, 0.0);
    let mut members_se = 0.0;
    let mut m2 = Vec::new();
    let mut scratch = [0.0; 6];
    for f in 0..folds {
        let train: Vec<usize> = (0..6).filter(|&d| plan.fold_of()[d] != f).collect();
        let sub = data.subset(&train).unwrap();
        let fitted: Vec<(String, Model)> = methods
            .iter()
            .zip(&labels)
            .map(|(m, l)| (l.to_string(), m.fit(&sub, &roles()).unwrap().0))
            .collect();
        let mean = Model::ensemble(fitted.clone(), &[1.0 / 3.0; 3]).unwrap();
        let p = mean.predictor(&roles()).unwrap();
        for d in (0..6).filter(|&d| plan.fold_of()[d] == f) {
            let h = human(&seqs[d]);
            let input = Frames::new(&h, 1).unwrap();
            let pred = p.predict(input, true).unwrap();
            let cov = pred.covariance.unwrap();
            let singles: Vec<_> = fitted
                .iter()
                .map(|(_, m)| {
                    m.predictor(&roles())
                        .unwrap()
                        .predict(input, false)
                        .unwrap()
                })
                .collect();
            for (t, x) in seqs[d].chunks(3).enumerate() {
                let r = [x[1] - pred.mean[t * 2], x[2] - pred.mean[t * 2 + 1]];
                se += r[0] * r[0] + r[1] * r[1];
                for s in &singles {
                    members_se +=
                        (x[1] - s.mean[t * 2]).powi(2) + (x[2] - s.mean[t * 2 + 1]).powi(2);
                }
                let sc = score_gaussian(&r, &cov[t * 4..t * 4 + 4], &mut scratch).unwrap();
                inside += usize::from(sc.mahalanobis2 <= limit);
                nlpd -= sc.log_density;
                m2.push(sc.mahalanobis2);
                frames += 1;
            }
        }
    }
    let n = frames as f64;
    assert!(
        (row.mse - se / n).abs() <= 1e-9 * row.mse,
        "{} vs {}",
        row.mse,
        se / n
    );
    assert_eq!(row.coverage, Some(inside as f64 / n));
    assert!((row.nlpd.unwrap() - nlpd / n).abs() <= 1e-8, "{row:?}");
    // The mean is calibrated on these frames, its own (not its first member's).
    let (_, calibrated) = Method::CrossValidated(cv.with_calibration(Calibration::Frames))
        .fit(&data, &roles())
        .unwrap();
    let c = calibrated.covariance_calibration.unwrap();
    assert_eq!(c.frames, frames);
    let want = phasekit_gmr::coverage_scale(&m2, 2, 0.95).unwrap();
    assert!(
        (c.scale - want).abs() <= 1e-9 * want,
        "{} vs {want}",
        c.scale
    );
    // What the mean is for: its error is never above its members' average
    // (Jensen: |Σ w r_i|² ≤ Σ w |r_i|²), and here strictly below.
    let members_mse = members_se / (3.0 * n);
    let average: f64 = order[..k].iter().map(|&c| table[c].mse).sum::<f64>() / k as f64;
    assert!((members_mse - average).abs() <= 1e-9 * average);
    assert!(row.mse < average, "{} vs {average}", row.mse);
}

#[test]
fn the_mean_of_one_is_the_best_and_the_mean_is_calibrated_on_its_own_held_out_frames() {
    let seqs = phased(6, 6);
    let data = SequenceSet::new(&seqs, 3).unwrap();
    let base = CrossValidation::new(grid(), 3)
        .unwrap()
        .with_halving(Halving::default());
    let (best, sb) = Method::CrossValidated(base.clone())
        .fit(&data, &roles())
        .unwrap();
    let (one, s1) = Method::CrossValidated(base.clone().with_selection(Selection::Mean(1)))
        .fit(&data, &roles())
        .unwrap();
    assert_eq!(sb.chosen, s1.chosen);
    assert_eq!(
        sb.cv_table,
        s1.cv_table
            .iter()
            .map(|r| {
                let mut r = r.clone();
                r.fit_seconds = sb
                    .cv_table
                    .iter()
                    .find(|x| x.label == r.label)
                    .unwrap()
                    .fit_seconds;
                r
            })
            .collect::<Vec<_>>()
    );
    assert_eq!(
        serde_json::to_string(&best).unwrap(),
        serde_json::to_string(&one).unwrap()
    );
    // With calibration (on the mean's own held-out frames: the test above),
    // 95 % of them are inside after it.
    let cv = base
        .with_selection(Selection::Mean(3))
        .with_calibration(Calibration::Frames);
    let (_, s) = Method::CrossValidated(cv).fit(&data, &roles()).unwrap();
    let c = s.covariance_calibration.as_ref().unwrap();
    assert!((c.coverage_after - 0.95).abs() < 0.02, "{c:?}");
    // Only the survivors of halving are averaged.
    let members = &s.chosen.as_ref().unwrap();
    for l in members.trim_start_matches("mean of 3: ").split(" + ") {
        let r = s.cv_table.iter().find(|r| r.label == l).unwrap();
        assert!(!r.abandoned && r.failure.is_none());
    }
}

#[test]
fn the_ensemble_key_sets_the_mean_and_refuses_what_contradicts_it() {
    let d = AutoSettings::default();
    assert_eq!(d.selection(), Selection::Mean(5));
    assert_eq!(d.grid().to_string(), "unit-free");
    let set = |pairs: &[(&str, &str)]| {
        pairs
            .iter()
            .try_fold(AutoSettings::builder(), |b, (k, v)| {
                AutoSettings::set(b, k, v)
            })
            .and_then(|b| b.build())
    };
    assert_eq!(
        set(&[("ensemble", "3")]).unwrap().selection(),
        Selection::Mean(3)
    );
    assert_eq!(
        set(&[("ensemble", "1")]).unwrap().selection(),
        Selection::Best
    );
    assert_eq!(
        set(&[("choose", "best")]).unwrap().selection(),
        Selection::Best
    );
    assert_eq!(
        set(&[("choose", "one-se")]).unwrap().selection(),
        Selection::OneStandardError
    );
    assert_eq!(
        set(&[("ensemble", "1"), ("choose", "one-se")])
            .unwrap()
            .selection(),
        Selection::OneStandardError
    );
    for (one, order) in [
        ("one-se", [("choose", "one-se"), ("ensemble", "4")]),
        ("one-se", [("ensemble", "4"), ("choose", "one-se")]),
        ("best", [("choose", "best"), ("ensemble", "4")]),
        ("best", [("ensemble", "4"), ("choose", "best")]),
    ] {
        let e = set(&order).unwrap_err().to_string();
        assert!(e.contains(one) && e.contains("ensemble=4"), "{e}");
    }
    // The grid's name is the same in files as on the command line.
    assert!(serde_json::to_string(&d)
        .unwrap()
        .contains(r#""grid":"unit-free""#));
    assert!(set(&[("ensemble", "0")])
        .unwrap_err()
        .to_string()
        .contains("at least 1"));
    assert!(set(&[("ensemble", "many")])
        .unwrap_err()
        .to_string()
        .contains("`many`"));
    // Settings written before the mean existed read as the single best.
    let mut old = serde_json::to_value(AutoSettings::default()).unwrap();
    old.as_object_mut().unwrap().remove("choose");
    let read: AutoSettings = serde_json::from_value(old).unwrap();
    assert_eq!(read.selection(), Selection::Best);
    // A mean of 0 is refused when fitted, and in a file.
    let seqs = phased(4, 9);
    let zero = CrossValidation::new(grid(), 2)
        .unwrap()
        .with_selection(Selection::Mean(0));
    let e = Method::CrossValidated(zero)
        .fit(&SequenceSet::new(&seqs, 3).unwrap(), &roles())
        .unwrap_err();
    assert!(e.to_string().contains("at least 1"), "{e}");
    let cv = CrossValidation::new(grid(), 3)
        .unwrap()
        .with_selection(Selection::Mean(0));
    let mut json = serde_json::to_value(&cv).unwrap();
    json["selection"] = serde_json::json!({"mean": 0});
    assert!(serde_json::from_value::<CrossValidation>(json).is_err());
}
