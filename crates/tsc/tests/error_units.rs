//! The unit a cross-validated choice judges the error in
//! ([`Roles::with_error_units`]): on z-scored data with the standard
//! deviations as units, every candidate's row (error, coverage, NLPD) and the
//! choice are those on the data in the user's units; without them the errors
//! differ (the scored dims are reweighted), so the check can fail.

use phasekit_emission::SequenceSet;
use phasekit_tsc::cross_validation::cv_table;
use phasekit_tsc::{Calibration, CrossValidation, Halving, Method, Roles, Selection};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Human 0 (and its velocity 1), robot 2 (metres) and 3 (millimetres).
fn roles() -> Roles {
    Roles::new(vec![0, 1], vec![2, 3]).unwrap()
}

/// A reach whose robot answers in two very different units.
fn demonstrations(n: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let t_len: usize = rng.random_range(30..40);
            let mut v = Vec::with_capacity(4 * t_len);
            let mut last = 0.0;
            for t in 0..t_len {
                let tau = t as f64 / (t_len - 1) as f64;
                let z: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
                let h = (3.0 * tau).sin() + 0.03 * z[0];
                v.push(h);
                v.push(if t == 0 { 0.0 } else { h - last });
                last = h;
                // Metres with fine structure; millimetres, smooth and noisy.
                v.push(0.3 * (12.0 * tau).sin() + 0.04 * z[1]);
                v.push(1000.0 * ((2.0 * tau).cos() * 0.2 + 0.08 * z[2]));
            }
            v
        })
        .collect()
}

/// Per dim, the population mean and standard deviation of all frames.
fn moments(seqs: &[Vec<f64>], d: usize) -> (Vec<f64>, Vec<f64>) {
    let frames: Vec<&[f64]> = seqs.iter().flat_map(|s| s.chunks(d)).collect();
    let n = frames.len() as f64;
    let mean: Vec<f64> = (0..d)
        .map(|k| frames.iter().map(|f| f[k]).sum::<f64>() / n)
        .collect();
    let std = (0..d)
        .map(|k| (frames.iter().map(|f| (f[k] - mean[k]).powi(2)).sum::<f64>() / n).sqrt())
        .collect();
    (mean, std)
}

fn grid() -> Vec<(String, Method)> {
    crate::candidates::candidates(&[
        "hmm:states=3,reg-rel=0.03",
        "hmm:states=6,reg-rel=0.01",
        "hsmm:states=4,reg-rel=0.03",
        "gmm:states=5,reg-rel=0.1",
        "tsc-hmm:states=3,reg-rel=0.03",
    ])
}

#[test]
fn on_z_scores_with_the_deviations_as_units_every_row_and_the_choice_are_the_users() {
    let d = 4;
    let seqs = demonstrations(6, 3);
    let (mean, std) = moments(&seqs, d);
    let z: Vec<Vec<f64>> = seqs
        .iter()
        .map(|s| {
            s.chunks(d)
                .flat_map(|f| {
                    (0..d)
                        .map(|k| (f[k] - mean[k]) / std[k])
                        .collect::<Vec<_>>()
                })
                .collect()
        })
        .collect();
    let (user, standard) = (
        SequenceSet::new(&seqs, d).unwrap(),
        SequenceSet::new(&z, d).unwrap(),
    );
    let units = roles().with_error_units(vec![std[2], std[3]]).unwrap();
    let cv = CrossValidation::new(grid(), 3).unwrap().with_fold_seed(7);
    let want = cv_table(&cv, &user, &roles()).unwrap();
    let got = cv_table(&cv, &standard, &units).unwrap();
    let plain = cv_table(&cv, &standard, &roles()).unwrap();
    assert_eq!(want.len(), grid().len());
    let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol * a.abs().max(1.0);
    for ((w, g), p) in want.iter().zip(&got).zip(&plain) {
        assert!(w.failure.is_none(), "{w:?}");
        assert!(
            close(w.mse, g.mse, 1e-8),
            "{}: {} vs {}",
            w.label,
            w.mse,
            g.mse
        );
        assert!(close(w.mse_sd, g.mse_sd, 1e-8), "{}", w.label);
        assert_eq!(w.coverage, g.coverage, "{}", w.label);
        assert!(
            close(w.nlpd.unwrap(), g.nlpd.unwrap(), 1e-8),
            "{}: {:?} vs {:?}",
            w.label,
            w.nlpd,
            g.nlpd
        );
        // Without the units the millimetres no longer dominate: another error.
        assert!(
            !close(w.mse, p.mse, 1e-3),
            "{}: {} = {}",
            w.label,
            w.mse,
            p.mse
        );
        assert_eq!(p.coverage, g.coverage, "coverage does not depend on units");
    }
    // The choice (the mean of the best two, after halving) and its own row
    // and calibration: the user's, under every calibration rule.
    for rule in [
        Calibration::Predictive,
        Calibration::Demonstrations,
        Calibration::Frames,
    ] {
        let mean_of_two = Method::CrossValidated(
            cv.clone()
                .with_halving(Halving::new(2, 2, 2).unwrap())
                .with_selection(Selection::Mean(2))
                .with_calibration(rule),
        );
        let (_, a) = mean_of_two.fit(&user, &roles()).unwrap();
        let (_, b) = mean_of_two.fit(&standard, &units).unwrap();
        assert_eq!(a.chosen, b.chosen, "{rule:?}");
        assert!(a.cv_table.iter().any(|r| r.abandoned), "halving abandons");
        let (ra, rb) = (a.cv_table.last().unwrap(), b.cv_table.last().unwrap());
        assert!(close(ra.mse, rb.mse, 1e-8), "{ra:?} vs {rb:?}");
        assert!(
            close(ra.nlpd.unwrap(), rb.nlpd.unwrap(), 1e-8),
            "{ra:?} vs {rb:?}"
        );
        let (sa, sb) = (
            a.covariance_calibration.unwrap(),
            b.covariance_calibration.unwrap(),
        );
        for (x, y) in [
            (sa.scale, sb.scale),
            (sa.nlpd_before, sb.nlpd_before),
            (sa.nlpd_after, sb.nlpd_after),
            (sa.coverage_before, sb.coverage_before),
            (sa.coverage_after, sb.coverage_after),
            (sa.residual_weight, sb.residual_weight),
        ] {
            assert!(close(x, y, 1e-8), "{rule:?}: {sa:?} vs {sb:?}");
        }
        // Without the units the z-scores' error ranks the candidates: on
        // these data (the millimetres dominate the user's sum) another mean.
        let (_, c) = mean_of_two.fit(&standard, &roles()).unwrap();
        assert_ne!(a.chosen, c.chosen, "{rule:?}");
    }
}

#[test]
fn error_units_are_one_per_robot_dim_finite_and_positive_also_when_read() {
    for (units, words) in [
        (vec![1.0], "1 error units for the robot's 2"),
        (vec![1.0, 0.0], "dimension 3 is 0"),
        (vec![f64::NAN, 1.0], "dimension 2 is NaN"),
        (vec![1.0, -2.0], "dimension 3 is -2"),
    ] {
        let e = roles().with_error_units(units).unwrap_err().to_string();
        assert!(e.contains(words), "`{e}` does not say `{words}`");
    }
    let r = roles()
        .with_scored(vec![3])
        .unwrap()
        .with_error_units(vec![2.0, 5.0])
        .unwrap();
    assert_eq!(r.scored_error_units(), vec![5.0]);
    assert_eq!(roles().scored_error_units(), vec![1.0, 1.0]);
    let json = serde_json::to_string(&r).unwrap();
    assert_eq!(serde_json::from_str::<Roles>(&json).unwrap(), r);
    // Without units a file reads as before; a bad unit in a file is refused.
    assert!(!serde_json::to_string(&roles())
        .unwrap()
        .contains("error_units"));
    let bad = json.replace("5.0", "-5.0");
    assert!(serde_json::from_str::<Roles>(&bad).is_err(), "{bad}");
}
